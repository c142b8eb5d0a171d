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
        let n_bands = det.rows.div_ceil(BAND);
        let band = |b: usize| Band::new(&det, b * BAND, ((b + 1) * BAND).min(det.rows));
        // The bands a box's rows `[start, end)` cover.
        let bands_of = |r: std::ops::Range<usize>| TileBox {
            lo: [0, r.start / BAND, 0],
            hi: [1, (r.end - 1) / BAND + 1, 1],
        };
        let bands: Vec<Vec<f32>> = match prepare(g, screen, prepared, v, cam, opts) {
            Prepared::Affine(splats) => {
                // Each band's splats binned with their index, in the order the band reads them.
                let bins = Bins::from_fn([1, n_bands, 1], g.len(), |i| {
                    let s = splats.get(i)?;
                    Some((bands_of(s.rows()), (i as u32, s)))
                });
                each_band(n_bands, m, &band, |b, band, buf| {
                    band_forward(&bins, b, g, band, cut2 as f32, buf)
                })
            }
            Prepared::Exact(splats) => {
                let bins = Bins::from_fn([1, n_bands, 1], g.len(), |i| {
                    let (_, px) = splats[i].as_ref()?;
                    Some((bands_of(px[2]..px[3]), i as u32))
                });
                each_band(n_bands, m, &band, |b, band, buf| {
                    let mut acc = vec![0.0f64; buf.len()];
                    for &gi in bins.of(b) {
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
                })
            }
        };
        let view_out = &mut out[v * m * plane..(v + 1) * m * plane];
        for (b, buf) in bands.iter().enumerate() {
            let band = band(b);
            band.layout.unpad_into(buf, view_out, det.rows, band.y0);
        }
    }
    out
}

dispatched! {
    /// The affine splats of band `b` (each with its Gaussian's index, in index order) summed
    /// into the band's buffer `buf`, with weights `ρ_c μ`.
    fn band_forward(
        bins: &Bins<(u32, PixelSplat)>,
        b: usize,
        g: &GaussianSlices<'_>,
        band: Band,
        cut2: f32,
        buf: &mut [f32],
    ) {
        let m = g.channels;
        let mut w = vec![0.0f32; m];
        for &(gi, ref s) in bins.of(b) {
            let gi = gi as usize;
            let dens = &g.densities[m * gi..m * gi + m];
            for c in 0..m {
                w[c] = dens[c] * s.mu;
            }
            splat_forward::<L>(s, band, cut2, &w, buf);
        }
    }
}

/// Every band's padded buffer of `m` channels, zeroed and filled by `fill(b, band, buf)`, one
/// task per band.
fn each_band(
    n_bands: usize,
    m: usize,
    band: &(impl Fn(usize) -> Band + Sync),
    fill: impl Fn(usize, Band, &mut [f32]) + Sync,
) -> Vec<Vec<f32>> {
    (0..n_bands)
        .into_par_iter()
        .map(|b| {
            let band = band(b);
            let mut buf = band.layout.zeros(m);
            fill(b, band, &mut buf);
            buf
        })
        .collect()
}
