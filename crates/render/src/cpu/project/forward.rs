//! The forward pass: one tile per task, every Gaussian binned to it summed in.

use super::*;

pub(super) fn forward(
    g: &GaussianSlices,
    screen: &[f32],
    prepared: Option<&[f32]>,
    cams: &[Camera],
    opts: &ProjectOptions,
) -> Vec<f32> {
    let m = g.channels;
    let Some(first) = cams.first() else {
        return Vec::new();
    };
    let plane = first.rows * first.cols;
    let mut out = vec![0.0f32; cams.len() * m * plane];
    if g.is_empty() || plane == 0 || m == 0 {
        return out;
    }
    let cut2 = opts.cutoff * opts.cutoff;
    for (v, cam) in cams.iter().enumerate() {
        let det = Detector::new(cam);
        let (prep, boxes) = prepare(g, screen, prepared, v, cam, opts);
        let bins = Bins::tile_lists([det.tiles_x, det.tiles_y, 1], &boxes);
        let tiles: Vec<Vec<f32>> = (0..bins.tiles())
            .into_par_iter()
            .map(|t| {
                let r = det.tile_rect(t);
                let n = TILE_PIXELS;
                let mut buf = vec![0.0f32; m * n];
                let list = &bins.tile_gaussians[bins.tile_start[t]..bins.tile_start[t + 1]];
                match &prep {
                    Prepared::Affine(splats) => {
                        let mut w = vec![0.0f32; m];
                        // Gather the tile's splats first: the cache misses of this tight loop
                        // overlap, unlike misses taken inside the pixel loops.
                        let local: Vec<(usize, PixelSplat)> = list
                            .iter()
                            .filter_map(|&gi| splats[gi as usize].map(|s| (gi as usize, s)))
                            .collect();
                        for &(gi, ref s) in &local {
                            let dens = &g.densities[m * gi..m * gi + m];
                            for c in 0..m {
                                w[c] = dens[c] * s.mu;
                            }
                            splat_forward(s, r, cut2 as f32, &w, &mut buf);
                        }
                    }
                    Prepared::Exact(splats) => {
                        let mut acc = vec![0.0f64; m * n];
                        for &gi in list {
                            let gi = gi as usize;
                            let Some((s, px)) = &splats[gi] else { continue };
                            let dens = &g.densities[m * gi..m * gi + m];
                            exact_pixels(px, r, |p, x, y| {
                                let (o, d, len) = camera_ray(cam, x as f64, y as f64);
                                let Some(rt) = ray_terms(&s.ray_gaussian, o, d) else {
                                    return;
                                };
                                if rt.q > cut2 {
                                    return;
                                }
                                let val = gm::line_integral_terms(&rt, len);
                                for c in 0..m {
                                    acc[c * n + p] += dens[c] as f64 * val;
                                }
                            });
                        }
                        for (b, a) in buf.iter_mut().zip(&acc) {
                            *b = *a as f32;
                        }
                    }
                }
                buf
            })
            .collect();
        let view_out = &mut out[v * m * plane..(v + 1) * m * plane];
        for (t, buf) in tiles.iter().enumerate() {
            let r = det.tile_rect(t);
            let tw = r.1 - r.0;
            let n = TILE_PIXELS;
            for c in 0..m {
                for y in r.2..r.3 {
                    let o = c * n + (y - r.2) * TILE;
                    let src = &buf[o..o + tw];
                    let dst = c * plane + y * det.cols + r.0;
                    view_out[dst..dst + tw].copy_from_slice(src);
                }
            }
        }
    }
    out
}
