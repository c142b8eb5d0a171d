//! Field-of-view check: which voxels does at least one ray see?
//!
//! A voxel is *seen* when its centre projects inside the detector (pixel footprints included) in
//! at least one view. Voxels seen by no ray cannot be reconstructed: a grid that lies wholly
//! outside the field of view is an error, a partial one is reported as the fraction of unseen
//! voxels so the caller can warn.

use crate::geometry::Geometry;
use crate::{Error, Result};
use rayon::prelude::*;

/// At most this many sample voxels per axis (larger grids are subsampled evenly).
const SAMPLES_PER_AXIS: usize = 48;

/// Fraction of voxels (sampled on a ≤ 48³ sub-grid) that project outside the detector in every view.
pub fn unseen_fraction(geometry: &Geometry) -> Result<f64> {
    geometry.validate()?;
    let g = &geometry.volume;
    let cams = geometry.cameras();
    let pick = |n: usize| -> Vec<usize> {
        let m = n.min(SAMPLES_PER_AXIS);
        (0..m)
            .map(|i| (i * n + n / 2) / m)
            .map(|i| i.min(n - 1))
            .collect()
    };
    let (xs, ys, zs) = (pick(g.nx), pick(g.ny), pick(g.nz));
    let unseen: usize = zs
        .par_iter()
        .map(|&iz| {
            let mut count = 0;
            for &iy in &ys {
                for &ix in &xs {
                    let p = g.voxel_centre(ix, iy, iz);
                    let seen = cams.iter().any(|c| {
                        c.project(p).is_some_and(|[u, v]| {
                            u >= -0.5
                                && u <= c.cols as f64 - 0.5
                                && v >= -0.5
                                && v <= c.rows as f64 - 0.5
                        })
                    });
                    count += usize::from(!seen);
                }
            }
            count
        })
        .sum();
    Ok(unseen as f64 / (xs.len() * ys.len() * zs.len()) as f64)
}

/// Error when no voxel is seen by any ray; otherwise the unseen fraction (0 when fully covered).
pub fn check_fov(geometry: &Geometry) -> Result<f64> {
    let f = unseen_fraction(geometry)?;
    if f >= 1.0 {
        return Err(Error::invalid(
            "volume",
            "the volume grid lies outside the detector's field of view in every view",
        ));
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Beam, Detector, VolumeGrid};

    fn geom(offset: [f64; 3], cols: usize) -> Geometry {
        Geometry {
            beam: Beam::Parallel,
            dso: 100.0,
            dsd: 200.0,
            detector: Detector {
                rows: 32,
                cols,
                pitch_u: 1.0,
                pitch_v: 1.0,
                offset_u: 0.0,
                offset_v: 0.0,
            },
            volume: VolumeGrid {
                offset,
                ..VolumeGrid::cube(16, 1.0)
            },
            angles_rad: Geometry::full_turn(8),
            vectors: None,
        }
    }

    #[test]
    fn covered_partial_and_outside() {
        assert_eq!(check_fov(&geom([0.0; 3], 32)).unwrap(), 0.0);
        // A 4 mm wide detector leaves the outer shell of the 16 mm cube unseen.
        let f = check_fov(&geom([0.0; 3], 4)).unwrap();
        assert!(f > 0.0 && f < 1.0, "{f}");
        // Grid shifted along z beyond the detector's ±16 mm rows.
        let e = check_fov(&geom([0.0, 0.0, 40.0], 32))
            .unwrap_err()
            .to_string();
        assert!(e.contains("volume") && e.contains("field of view"), "{e}");
    }

    #[test]
    fn parallel_fraction_matches_geometry() {
        // Detector of width 8 mm, 2 views (0 and 90°): a voxel is seen iff |y| ≤ 4 or |x| ≤ 4
        // (within the 16 mm cube, z fully covered): seen area = 16·8·2 − 8·8 = 192 of 256.
        let mut g = geom([0.0; 3], 8);
        g.angles_rad = vec![0.0, std::f64::consts::FRAC_PI_2];
        let f = unseen_fraction(&g).unwrap();
        assert!((f - 64.0 / 256.0).abs() < 1e-12, "{f}");
    }
}
