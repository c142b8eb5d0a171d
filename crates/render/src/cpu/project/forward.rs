//! The forward pass: one band of detector rows per task, every Gaussian binned to it summed in
//! (in index order, so every pixel's sum has the same order however the detector is split).

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
        let prep = prepare(g, screen, prepared, v, cam, opts);
        let n_bands = det.rows.div_ceil(BAND);
        let band = |b: usize| Band::new(&det, b * BAND, ((b + 1) * BAND).min(det.rows));
        let bins = Bins::from_fn([1, n_bands, 1], g.len(), |i| {
            prep.rows(i).map(|r| TileBox {
                lo: [0, r.start / BAND, 0],
                hi: [1, (r.end - 1) / BAND + 1, 1],
            })
        });
        let bands: Vec<Vec<f32>> = (0..n_bands)
            .into_par_iter()
            .map(|b| {
                let band = band(b);
                let mut buf = band.layout.zeros(m);
                let list = bins.of(b);
                match &prep {
                    Prepared::Affine(splats) => {
                        let mut w = vec![0.0f32; m];
                        // Gather the band's splats first: the cache misses of this tight loop
                        // overlap, unlike misses taken inside the pixel loops.
                        let local: Vec<(usize, PixelSplat)> = list
                            .iter()
                            .filter_map(|&gi| splats.get(gi as usize).map(|s| (gi as usize, s)))
                            .collect();
                        for &(gi, ref s) in &local {
                            let dens = &g.densities[m * gi..m * gi + m];
                            for c in 0..m {
                                w[c] = dens[c] * s.mu;
                            }
                            splat_forward(s, band, cut2 as f32, &w, &mut buf);
                        }
                    }
                    Prepared::Exact(splats) => {
                        let mut acc = vec![0.0f64; buf.len()];
                        for &gi in list {
                            let gi = gi as usize;
                            let Some((s, px)) = &splats[gi] else { continue };
                            let dens = &g.densities[m * gi..m * gi + m];
                            let rows = px[2].max(band.y0)..px[3].min(band.y1);
                            exact_rays(cam, s, px, rows, cut2, |x, y, _, _, len, rt| {
                                let val = gm::line_integral_terms(rt, len);
                                for c in 0..m {
                                    acc[band.at(c, x, y)] += dens[c] as f64 * val;
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
        for (b, buf) in bands.iter().enumerate() {
            let band = band(b);
            band.layout.unpad_into(buf, view_out, det.rows, band.y0);
        }
    }
    out
}
