//! The backward pass: per-(tile, Gaussian) partial sums written to disjoint slices, then gathered
//! and chained per Gaussian.

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
        let (prep, boxes) = prepare(g, screen, prepared, v, cam, opts);
        let bins = Bins::new([det.tiles_x, det.tiles_y, 1], &boxes);
        // Per-slot partial sums. Affine: [S_0..S_{M-1}, Σ wG dx, Σ wG dy, Σ wG dx², Σ wG dxdy,
        // Σ wG dy²] with S_c = Σ g_c G and w = Σ_c ρ_c g_c. Exact: [S_c.., g_centre(3), g_prec(6)].
        let stride = match prep {
            Prepared::Affine(..) => m + 5,
            Prepared::Exact(..) => m + 9,
        };
        let mut slots = vec![0.0f64; bins.isects() * stride];
        let per_tile = bins.split_per_tile(&mut slots, stride);
        per_tile.into_par_iter().enumerate().for_each(|(t, out)| {
            let r = det.tile_rect(t);
            let tw = r.1 - r.0;
            let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
            // The tile's upstream gradient, gathered once: [M][pixels].
            let n = TILE_PIXELS;
            let mut gt = vec![0.0f32; m * n];
            for c in 0..m {
                for y in r.2..r.3 {
                    let src = c * plane + y * det.cols + r.0;
                    let o = c * n + (y - r.2) * TILE;
                    gt[o..o + tw].copy_from_slice(&gview[src..src + tw]);
                }
            }
            let tile_grad = TileGrad::new(&gt);
            let mut rows = [[0.0f32; HALF]; TILE];
            // Gather the tile's affine splats first (see the forward pass).
            let local: Vec<Option<PixelSplat>> = match &prep {
                Prepared::Affine(splats) => list.iter().map(|&gi| splats[gi as usize]).collect(),
                Prepared::Exact(_) => Vec::new(),
            };
            for (j, &gi) in list.iter().enumerate() {
                let gi = gi as usize;
                let acc = &mut out[j * stride..(j + 1) * stride];
                let dens = &g.densities[m * gi..m * gi + m];
                match &prep {
                    Prepared::Affine(..) => {
                        let Some(s) = &local[j] else { continue };
                        splat_backward(s, r, cut2 as f32, tile_grad, dens, &mut rows, acc);
                    }
                    Prepared::Exact(splats) => {
                        let Some((s, px)) = &splats[gi] else { continue };
                        exact_pixels(px, r, |p, x, y| {
                            let (o, d, len) = camera_ray(cam, x as f64, y as f64);
                            let Some(rt) = ray_terms(&s.ray_gaussian, o, d) else {
                                return;
                            };
                            if rt.q > cut2 {
                                return;
                            }
                            let mut w = 0.0f64;
                            for c in 0..m {
                                w += dens[c] as f64 * gt[c * n + p] as f64;
                            }
                            let (val, g_c, g_p) =
                                line_integral_backward(&s.ray_gaussian, o, d, len, w);
                            for c in 0..m {
                                acc[c] += gt[c * n + p] as f64 * val;
                            }
                            for q in 0..3 {
                                acc[m + q] += g_c[q];
                            }
                            let gp = sym_pack(&g_p);
                            for q in 0..6 {
                                acc[m + 3 + q] += gp[q];
                            }
                        });
                    }
                }
            }
        });
        // Gather per Gaussian and chain to its parameters, written straight into the outputs.
        let screen_view = &mut total.screen[2 * v * k..2 * (v + 1) * k];
        total
            .means
            .par_chunks_mut(3)
            .zip(total.scales.par_chunks_mut(3))
            .zip(total.rotations.par_chunks_mut(4))
            .zip(total.densities.par_chunks_mut(m))
            .zip(screen_view.par_chunks_mut(2))
            .enumerate()
            .with_min_len(64)
            .for_each_init(
                || vec![0.0f64; stride],
                |sum, (i, ((((out_mean, out_scale), out_rot), out_dens), out_screen))| {
                    // A Gaussian's slots lie in different tiles' runs (cache misses the f64
                    // chain below would otherwise wait for): fetch those of a later one now.
                    if let Some(&[from, to, ..]) = bins.gaussian_start.get(i + PREFETCH_AHEAD..) {
                        for &slot in &bins.gaussian_isects[from..to] {
                            prefetch(&slots[slot * stride]);
                        }
                    }
                    let isects =
                        &bins.gaussian_isects[bins.gaussian_start[i]..bins.gaussian_start[i + 1]];
                    if isects.is_empty() {
                        return;
                    }
                    sum.fill(0.0);
                    for &slot in isects {
                        for (a, b) in sum
                            .iter_mut()
                            .zip(&slots[slot * stride..(slot + 1) * stride])
                        {
                            *a += b;
                        }
                    }
                    let geom: GaussianGeom = g.geom(i);
                    let dens = &g.densities[m * i..m * i + m];
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
                    let finite = geo
                        .mean
                        .iter()
                        .chain(&geo.scale)
                        .chain(&geo.quat)
                        .chain(&g_screen)
                        .all(|x| x.is_finite())
                        && sum[..m].iter().all(|x| (dens_scale * x).is_finite());
                    if !finite {
                        return;
                    }
                    for q in 0..3 {
                        out_mean[q] += geo.mean[q] as f32;
                        out_scale[q] += geo.scale[q] as f32;
                    }
                    for q in 0..4 {
                        out_rot[q] += geo.quat[q] as f32;
                    }
                    for c in 0..m {
                        out_dens[c] += (dens_scale * sum[c]) as f32;
                    }
                    out_screen[0] = g_screen[0] as f32;
                    out_screen[1] = g_screen[1] as f32;
                },
            );
    }
    total
}

/// How many Gaussians ahead the backward's per-Gaussian gather prefetches its slots.
pub(super) const PREFETCH_AHEAD: usize = 4;

/// Hint the CPU to load the cache line holding `v` (no effect on results; no-op off x86-64).
#[inline(always)]
pub(super) fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults nor changes memory, and `v` is a valid reference.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>((v as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}
