//! The backward pass: one Gaussian per task sums the upstream gradient over its own pixels and
//! chains the sums to its parameters, so nothing is stored per (tile, Gaussian) or gathered.

use super::*;

pub(super) fn backward(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&[f32]>,
    cams: &[Camera],
    opts: &ProjectOptions,
    grad: &[f32],
) -> ProjectGrads {
    let k = g.len();
    let m = g.channels;
    let mut total = ProjectGrads {
        means: zeros(3 * k),
        scales: zeros(3 * k),
        rotations: zeros(4 * k),
        densities: zeros(m * k),
        screen: zeros(2 * k * cams.len()),
    };
    let Some(first) = cams.first() else {
        return total;
    };
    let plane = first.rows * first.cols;
    if k == 0 || plane == 0 || m == 0 {
        return total;
    }
    let cut2 = opts.cutoff * opts.cutoff;
    for (v, cam) in cams.iter().enumerate() {
        let det = Detector::new(cam);
        let gview = &grad[v * m * plane..(v + 1) * m * plane];
        let prep = prepare(g, screen, prepared, v, cam, opts);
        let band = Band::new(&det, 0, det.rows);
        let padded = band.layout.pad(gview);
        let upstream = ViewGrad {
            values: UpstreamGrad {
                values: &padded,
                finite: gview.par_iter().all(|v| v.is_finite()),
            },
            band,
        };
        // Per Gaussian, its sums over its own pixels. Affine: [S_0..S_{M-1}, Σ wG dx, Σ wG dy,
        // Σ wG dx², Σ wG dxdy, Σ wG dy²] with S_c = Σ g_c G and w = Σ_c ρ_c g_c. Exact:
        // [S_c.., g_centre(3), g_prec(6)].
        let stride = match prep {
            Prepared::Affine(..) => m + 5,
            Prepared::Exact(..) => m + 9,
        };
        let gv = upstream.values.values;
        // Sum per Gaussian and chain to its parameters, written straight into the outputs.
        let ProjectGrads {
            means,
            scales,
            rotations,
            densities,
            screen: screens,
        } = &mut total;
        let screen_view = &mut screens[2 * v * k..2 * (v + 1) * k];
        let inputs = ViewInputs {
            g,
            screen,
            view: v,
            cam,
            opts,
        };
        // Groups of F64_LANES Gaussians: each one's pixel sums, then (affine) the group's chain
        // rule at once in f64 lanes.
        grad_rows(means, scales, rotations, densities, m, F64_LANES)
            .zip(screen_view.par_chunks_mut(2 * F64_LANES))
            .enumerate()
            .with_min_len(16)
            .for_each_init(
                || (vec![0.0f64; F64_LANES * stride], vec![[0.0f32; HALF]; m]),
                |(sums, lanes), (group, (mut rows, out_screen))| {
                    let first = group * F64_LANES;
                    let n = rows.len();
                    sums.fill(0.0);
                    let dens = |j: usize| &g.densities[m * (first + j)..m * (first + j + 1)];
                    match &prep {
                        Prepared::Affine(splats) => {
                            let mut live = [false; F64_LANES];
                            let pass = AffineSums {
                                splats,
                                g,
                                cut2: cut2 as f32,
                                upstream,
                            };
                            group_sums(pass, first, n, stride, lanes, sums, &mut live);
                            if !live.contains(&true) {
                                return;
                            }
                            let group = Group {
                                first,
                                live,
                                sums,
                                stride,
                            };
                            chain_affine(inputs, &group, &mut rows, out_screen);
                        }
                        Prepared::Exact(splats) => {
                            for j in 0..n {
                                let i = first + j;
                                let Some((s, px)) = &splats[i] else { continue };
                                let sum = &mut sums[j * stride..(j + 1) * stride];
                                let dens = dens(j);
                                exact_rays(cam, s, px, px[2]..px[3], cut2, |x, y, o, d, len, _| {
                                    let gc = |c: usize| gv[band.at(c, x, y)] as f64;
                                    let w: f64 = (0..m).map(|c| dens[c] as f64 * gc(c)).sum();
                                    let (val, g_c, g_p) =
                                        line_integral_backward(&s.ray_gaussian, o, d, len, w);
                                    for c in 0..m {
                                        sum[c] += gc(c) * val;
                                    }
                                    for q in 0..3 {
                                        sum[m + q] += g_c[q];
                                    }
                                    let gp = sym_pack(&g_p);
                                    for q in 0..6 {
                                        sum[m + 3 + q] += gp[q];
                                    }
                                });
                                let g_centre = [sum[m], sum[m + 1], sum[m + 2]];
                                let gp: [f64; 6] = std::array::from_fn(|q| sum[m + 3 + q]);
                                let (geo, g_screen) = exact_splat_backward(
                                    &g.geom(i),
                                    cam,
                                    inputs.offset(i),
                                    g_centre,
                                    &sym_unpack(&gp),
                                );
                                if !g_screen.iter().all(|x| x.is_finite())
                                    || !rows.add(j, &geo, 1.0, &sum[..m])
                                {
                                    continue;
                                }
                                out_screen[2 * j] = g_screen[0] as f32;
                                out_screen[2 * j + 1] = g_screen[1] as f32;
                            }
                        }
                    }
                },
            );
    }
    total
}

/// What the affine backward's pixel sums of one view read: its splats, the Gaussians (for
/// their densities), the cut-off and the view's upstream gradient.
#[derive(Clone, Copy)]
struct AffineSums<'a> {
    splats: &'a AffineSplats<'a>,
    g: &'a GaussianSlices<'a>,
    cut2: f32,
    upstream: ViewGrad<'a>,
}

dispatched! {
    /// The pixel sums of Gaussians `first..first + n` (`stride` values each, zero on entry,
    /// see [`backward`]) into `sums`, and which of them have a splat (`live`); `lanes` is the
    /// kernels' scratch.
    fn group_sums(
        pass: AffineSums<'_>,
        first: usize,
        n: usize,
        stride: usize,
        lanes: &mut [[f32; HALF]],
        sums: &mut [f64],
        live: &mut [bool; F64_LANES],
    ) {
        let m = pass.g.channels;
        for j in 0..n {
            let i = first + j;
            let Some(s) = pass.splats.get(i) else {
                continue;
            };
            let dens = &pass.g.densities[m * i..m * (i + 1)];
            let sum = &mut sums[j * stride..(j + 1) * stride];
            splat_backward::<L>(&s, pass.cut2, pass.upstream, dens, lanes, sum);
            live[j] = true;
        }
    }
}

/// A group of up to [`F64_LANES`] consecutive Gaussians in the backward pass: which have a
/// splat, and their pixel sums (`stride` values each, see [`backward`]).
struct Group<'a> {
    first: usize,
    live: [bool; F64_LANES],
    sums: &'a [f64],
    stride: usize,
}

dispatched! {
    /// The affine chain rule of a group of Gaussians in `view`, in f64 lanes (the same
    /// operations as one at a time, see [`gm::Real`]): their image-space gradients from their
    /// pixel sums through [`gm::splat_backward_masked`] into `rows` and the screen offsets'
    /// gradients `out_screen`.
    fn chain_affine(view: ViewInputs<'_>, group: &Group, rows: &mut GradRow, out_screen: &mut [f32]) {
        let (g, first, n, m) = (view.g, group.first, rows.len(), view.g.channels);
        // Lanes past the group's end repeat its last Gaussian; their results are not used.
        let at = |j: usize| first + j.min(n - 1);
        let sum = |j: usize| &group.sums[j.min(n - 1) * group.stride..][..group.stride];
        let geom = GaussianGeom::lanes(|j| g.geom(at(j)));
        let off = F64x4::gather(|j| view.offset(at(j)));
        // The image-space gradient from the pixel sums; the splats' μ kept, which scales
        // ∂L/∂ρ_c = μ · S_c.
        let mut mu = F64x4::default();
        let image_grad = |sp: &gm::Splat<F64x4>| {
            let [ca, cb, cc] = sp.conic_mat;
            mu = sp.mu;
            let mu = sp.mu;
            let moment = |q: usize| F64x4::from_fn(|j| sum(j)[m + q]);
            let (wx, wy) = (moment(0), moment(1));
            let half = F64x4::splat(-0.5);
            SplatGrad {
                mean: [mu * (ca * wx + cb * wy), mu * (cb * wx + cc * wy)],
                conic: [
                    half * mu * moment(2),
                    half * mu * moment(3),
                    half * mu * moment(4),
                ],
                mu: F64x4::from_fn(|j| {
                    let d = &g.densities[m * at(j)..m * (at(j) + 1)];
                    (0..m).map(|c| d[c] as f64 * sum(j)[c]).sum()
                }),
            }
        };
        let (geo, sg, ok) = gm::splat_backward_masked(
            &geom,
            view.cam,
            off,
            view.opts.cutoff,
            view.near(),
            image_grad,
        );
        for j in (0..n).filter(|&j| group.live[j] && ok.lane(j)) {
            let g_screen = [sg.mean[0].0[j], sg.mean[1].0[j]];
            if !g_screen.iter().all(|x| x.is_finite())
                || !rows.add(j, &geo.lane(j), mu.0[j], &sum(j)[..m])
            {
                continue;
            }
            out_screen[2 * j] = g_screen[0] as f32;
            out_screen[2 * j + 1] = g_screen[1] as f32;
        }
    }
}
