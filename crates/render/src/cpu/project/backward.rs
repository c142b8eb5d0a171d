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
        means: vec![0.0; 3 * k],
        scales: vec![0.0; 3 * k],
        rotations: vec![0.0; 4 * k],
        densities: vec![0.0; m * k],
        screen: vec![0.0; 2 * k * cams.len()],
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
        let near = opts.near_fraction * cam.sdd;
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
        grad_rows(means, scales, rotations, densities, m)
            .zip(screen_view.par_chunks_mut(2))
            .enumerate()
            .with_min_len(64)
            .for_each_init(
                || (vec![0.0f64; stride], vec![[0.0f32; HALF]; m]),
                |(sum, lanes), (i, (mut row, out_screen))| {
                    sum.fill(0.0);
                    let dens = &g.densities[m * i..m * i + m];
                    match &prep {
                        Prepared::Affine(splats) => {
                            let Some(s) = &splats[i] else { return };
                            splat_backward(s, cut2 as f32, upstream, dens, lanes, sum);
                        }
                        Prepared::Exact(splats) => {
                            let Some((s, px)) = &splats[i] else { return };
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
                        }
                    }
                    let geom: GaussianGeom = g.geom(i);
                    let off = screen_offset(screen, k, v, i);
                    // ∂L/∂ρ_c = dens_scale · S_c.
                    let (geo, dens_scale, g_screen) = match &prep {
                        Prepared::Affine(_) => {
                            let mut mu = 0.0;
                            let image_grad = |sp: &gm::Splat| {
                                mu = sp.mu;
                                let [ca, cb, cc] = sp.conic_mat;
                                let mu = sp.mu;
                                let (wx, wy) = (sum[m], sum[m + 1]);
                                SplatGrad {
                                    mean: [mu * (ca * wx + cb * wy), mu * (cb * wx + cc * wy)],
                                    conic: [
                                        -0.5 * mu * sum[m + 2],
                                        -0.5 * mu * sum[m + 3],
                                        -0.5 * mu * sum[m + 4],
                                    ],
                                    mu: (0..m).map(|c| dens[c] as f64 * sum[c]).sum(),
                                }
                            };
                            let Some((geo, sg)) = gm::splat_backward_with(
                                &geom,
                                cam,
                                off,
                                opts.cutoff,
                                near,
                                image_grad,
                            ) else {
                                return;
                            };
                            (geo, mu, sg.mean)
                        }
                        Prepared::Exact(_) => {
                            let g_centre = [sum[m], sum[m + 1], sum[m + 2]];
                            let gp: [f64; 6] = std::array::from_fn(|q| sum[m + 3 + q]);
                            let (geo, g_screen) =
                                exact_splat_backward(&geom, cam, off, g_centre, &sym_unpack(&gp));
                            (geo, 1.0, g_screen)
                        }
                    };
                    if !g_screen.iter().all(|x| x.is_finite())
                        || !row.add(&geo, dens_scale, &sum[..m])
                    {
                        return;
                    }
                    out_screen[0] = g_screen[0] as f32;
                    out_screen[1] = g_screen[1] as f32;
                },
            );
    }
    total
}
