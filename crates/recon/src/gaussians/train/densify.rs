//! Adaptive density control (R²-Gaussian / 3DGS): clone small Gaussians and split large ones
//! where the view-space positional gradient is large, then prune faint or escaped ones.

use crate::gaussians::config::DensifyConfig;
use crate::gaussians::host::{HostGaussians, ScaleBounds, inverse_softplus, softplus};
use prism_render::gaussian_math::quat_to_rotation;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// What one densification did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DensifyCounts {
    pub cloned: usize,
    pub split: usize,
    pub pruned: usize,
}

/// Densify and prune `g` with per-Gaussian scores (mean gradient norm, NDC units). Returns the new
/// Gaussians, the source row of each new row (`None` for new Gaussians, whose optimiser state
/// starts at zero) and the counts. `bbox` is the volume's box in normalised units; centres
/// outside it are pruned.
pub fn densify_and_prune(
    g: &HostGaussians,
    scores: &[f32],
    bounds: &ScaleBounds,
    bbox: ([f64; 3], [f64; 3]),
    config: &DensifyConfig,
    rng: &mut impl Rng,
) -> (HostGaussians, Vec<Option<usize>>, DensifyCounts) {
    let k = g.len();
    let m = g.channels;
    let mut counts = DensifyCounts::default();
    let max_scale = |i: usize| -> f64 {
        (0..3)
            .map(|a| bounds.activate(g.scales[3 * i + a] as f64))
            .fold(0.0, f64::max)
    };
    let limit = config.clone_max_scale * 2.0;
    let mut hot: Vec<usize> = (0..k)
        .filter(|&i| scores[i].is_finite() && scores[i] as f64 >= config.grad_threshold)
        .collect();
    // Respect the cap: the highest scores first, only as many as fit (a split adds one net).
    let room = config.max_gaussians.saturating_sub(k);
    if hot.len() > room {
        hot.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
        hot.truncate(room);
        hot.sort_unstable();
    }
    let mut clone = vec![false; k];
    let mut split = vec![false; k];
    for &i in &hot {
        if max_scale(i) <= limit {
            clone[i] = true;
        } else {
            split[i] = true;
        }
    }
    let half = |raw: &[f32]| -> Vec<f32> {
        raw.iter()
            .map(|&r| inverse_softplus(softplus(r as f64) / 2.0) as f32)
            .collect()
    };
    let mut out = HostGaussians::empty(m);
    let mut src = Vec::with_capacity(k);
    let mut extra = HostGaussians::empty(m);
    for i in 0..k {
        if split[i] {
            counts.split += 1;
            let s: Vec<f64> = (0..3)
                .map(|a| bounds.activate(g.scales[3 * i + a] as f64))
                .collect();
            let r = rotation_matrix(&g.rotations[4 * i..4 * i + 4]);
            for _ in 0..2 {
                let z: [f64; 3] =
                    std::array::from_fn(|a| s[a] * rng.sample::<f64, _>(StandardNormal));
                let mut child = g.select(&[i]);
                for a in 0..3 {
                    let off: f64 = (0..3).map(|b| r[a][b] * z[b]).sum();
                    child.means[a] = (g.means[3 * i + a] as f64 + off) as f32;
                    child.scales[a] = bounds.raw(s[a] / 1.6) as f32;
                }
                child.densities = half(&child.densities);
                extra.push_from(&child, 0);
            }
            continue;
        }
        out.push_from(g, i);
        src.push(Some(i));
        if clone[i] {
            counts.cloned += 1;
            let d = half(&g.densities[m * i..m * (i + 1)]);
            let n = out.densities.len();
            out.densities[n - m..].copy_from_slice(&d);
            extra.push_from(&out, out.len() - 1);
        }
    }
    for j in 0..extra.len() {
        out.push_from(&extra, j);
        src.push(None);
    }
    // Prune faint Gaussians and centres outside the volume box.
    let keep: Vec<usize> = (0..out.len())
        .filter(|&i| {
            let dens_ok = out.densities[m * i..m * (i + 1)]
                .iter()
                .any(|&r| softplus(r as f64) >= config.min_density);
            let inside = (0..3).all(|a| {
                let p = out.means[3 * i + a] as f64;
                p >= bbox.0[a] && p <= bbox.1[a]
            });
            dens_ok && inside
        })
        .collect();
    counts.pruned = out.len() - keep.len();
    let pruned = out.select(&keep);
    let src = keep.iter().map(|&i| src[i]).collect();
    (pruned, src, counts)
}

/// Rotation matrix of a (not necessarily unit) quaternion `w, x, y, z` (the identity when it
/// is zero or not finite).
fn rotation_matrix(q: &[f32]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let unit = if n > 0.0 && n.is_finite() {
        [0, 1, 2, 3].map(|c| q[c] as f64 / n)
    } else {
        [1.0, 0.0, 0.0, 0.0]
    };
    quat_to_rotation(unit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn gaussians(scales: &[f64], dens: &[f64], bounds: &ScaleBounds) -> HostGaussians {
        let mut g = HostGaussians::empty(1);
        for (i, (&s, &d)) in scales.iter().zip(dens).enumerate() {
            g.means.extend_from_slice(&[0.1 * i as f32, 0.0, 0.0]);
            let r = bounds.raw(s) as f32;
            g.scales.extend_from_slice(&[r, r, r]);
            g.rotations.extend_from_slice(&[1.0, 0.0, 0.0, 0.0]);
            g.densities.push(inverse_softplus(d) as f32);
        }
        g
    }

    #[test]
    fn clone_split_prune_and_source_rows() {
        let b = ScaleBounds {
            min: 0.001,
            max: 1.0,
        };
        // 0: hot + small → clone; 1: hot + large → split; 2: cold; 3: faint → pruned.
        let g = gaussians(&[0.05, 0.4, 0.05, 0.05], &[0.8, 0.6, 0.5, 1e-7], &b);
        let scores = [1e-3f32, 1e-3, 0.0, 0.0];
        let cfg = DensifyConfig::default();
        let bbox = ([-1.0; 3], [1.0; 3]);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let (out, src, counts) = densify_and_prune(&g, &scores, &b, bbox, &cfg, &mut rng);
        assert_eq!(
            counts,
            DensifyCounts {
                cloned: 1,
                split: 1,
                pruned: 1
            }
        );
        // Kept 0 (halved), 2; then the clone of 0 and the two children of 1.
        assert_eq!(out.len(), 5);
        assert_eq!(src, vec![Some(0), Some(2), None, None, None]);
        out.validate().unwrap();
        let d = |i: usize| softplus(out.densities[i] as f64);
        assert!((d(0) - 0.4).abs() < 1e-6 && (d(2) - 0.4).abs() < 1e-6);
        assert!((d(3) - 0.3).abs() < 1e-6 && (d(4) - 0.3).abs() < 1e-6);
        let s_child = b.activate(out.scales[9] as f64);
        assert!((s_child - 0.4 / 1.6).abs() < 1e-5, "{s_child}");
        // A split child whose scale would fall below the bound stays finite (clamped raw).
        let tiny = gaussians(
            &[0.3],
            &[0.5],
            &ScaleBounds {
                min: 0.29,
                max: 1.0,
            },
        );
        let cfg_split = DensifyConfig {
            clone_max_scale: 0.01,
            ..cfg
        };
        let (out, _, _) = densify_and_prune(
            &tiny,
            &[1.0],
            &ScaleBounds {
                min: 0.29,
                max: 1.0,
            },
            bbox,
            &cfg_split,
            &mut rng,
        );
        assert_eq!(out.len(), 2);
        out.validate().unwrap();
    }

    #[test]
    fn the_cap_limits_growth() {
        let b = ScaleBounds {
            min: 0.001,
            max: 1.0,
        };
        let g = gaussians(&[0.05; 4], &[0.5; 4], &b);
        let cfg = DensifyConfig {
            max_gaussians: 5,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let (out, _, c) = densify_and_prune(
            &g,
            &[1e-3, 2e-3, 3e-3, 4e-3],
            &b,
            ([-1.0; 3], [1.0; 3]),
            &cfg,
            &mut rng,
        );
        assert_eq!(c.cloned, 1);
        assert_eq!(out.len(), 5);
    }
}
