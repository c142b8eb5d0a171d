//! Field-of-view check: which voxels does at least one ray see, and which does every view see?
//!
//! A voxel is *seen* by a view when its centre projects inside the detector (pixel footprints
//! included). Voxels seen by no ray cannot be reconstructed: a grid that lies wholly outside the
//! field of view is an error, a partial one is reported as the fraction of unseen voxels so the
//! caller can warn. Voxels seen by some views but not all (outside a fan or cone beam's field-of-
//! view disc, radius `dso · sin(half fan angle)` on a full turn) are a limited-angle problem: the
//! complete-data region, [`seen_by_every_view`], is where the data determine the volume.

use crate::geometry::{Camera, Geometry};
use crate::{Error, Result};
use ndarray::Array3;
use rayon::prelude::*;

/// Whether the point `p` (mm) projects onto `camera`'s detector, pixel footprints included.
fn on_detector(camera: &Camera, p: [f64; 3]) -> bool {
    camera.project(p).is_some_and(|[u, v]| {
        u >= -0.5 && u <= camera.cols as f64 - 0.5 && v >= -0.5 && v <= camera.rows as f64 - 0.5
    })
}

/// `[z][y][x]`: true where the voxel's centre projects onto the detector in every view of
/// `geometry` (the complete-data region: the field-of-view disc of a full-turn fan beam).
pub fn seen_by_every_view(geometry: &Geometry) -> Result<Array3<bool>> {
    geometry.validate()?;
    let g = &geometry.volume;
    let cams = geometry.cameras();
    let seen: Vec<bool> = (0..g.nz)
        .into_par_iter()
        .flat_map_iter(|iz| {
            let cams = &cams;
            (0..g.ny).flat_map(move |iy| {
                (0..g.nx).map(move |ix| {
                    let p = g.voxel_centre(ix, iy, iz);
                    cams.iter().all(|c| on_detector(c, p))
                })
            })
        })
        .collect();
    let mask = Array3::from_shape_vec((g.nz, g.ny, g.nx), seen)
        .expect("one flag per voxel, in [z][y][x] order");
    Ok(mask)
}

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
                    count += usize::from(!cams.iter().any(|c| on_detector(c, p)));
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

    #[test]
    fn a_full_turn_fan_beam_sees_its_field_of_view_disc_in_every_view() {
        // Fan beam (one detector row, one slice), dso 100, dsd 200, 40 columns of 1 mm: the
        // rays' largest distance from the axis is dso·sin(atan(20/200)) = 9.950 mm, so on a
        // 1 mm grid of 32² every voxel centre within that radius is seen by every view of a
        // full turn and none beyond it (720 views: the angular gaps miss the disc by < 1e-4 mm).
        let mut g = geom([0.0; 3], 40);
        g.beam = Beam::Cone;
        g.detector.rows = 1;
        g.volume = VolumeGrid {
            nx: 32,
            ny: 32,
            nz: 1,
            ..VolumeGrid::cube(32, 1.0)
        };
        g.angles_rad = Geometry::full_turn(720);
        let radius = 100.0 * (20.0f64 / 200.0).atan().sin();
        let mask = seen_by_every_view(&g).unwrap();
        let mut inside = 0;
        for ((_, iy, ix), &m) in mask.indexed_iter() {
            let [x, y, _] = g.volume.voxel_centre(ix, iy, 0);
            let r = x.hypot(y);
            if (r - radius).abs() > 0.01 {
                assert_eq!(m, r < radius, "voxel ({ix}, {iy}) at r = {r}");
            }
            inside += usize::from(m);
        }
        // The disc of radius 9.95 holds about π·9.95² ≈ 311 unit voxels.
        assert!((inside as f64 - 311.0).abs() < 20.0, "{inside}");
        // Every voxel is seen by some view, so the grid's corners are limited-angle, not unseen.
        assert_eq!(unseen_fraction(&g).unwrap(), 0.0);
    }

    #[test]
    fn a_parallel_beam_as_wide_as_the_grid_sees_all_of_it_in_every_view() {
        let mut g = geom([0.0; 3], 32);
        g.volume = VolumeGrid::cube(8, 1.0);
        let mask = seen_by_every_view(&g).unwrap();
        assert!(mask.iter().all(|&m| m));
        // Two views, 0 and 90°, of an 8 mm wide detector on the 16 mm cube: |x| ≤ 4 and |y| ≤ 4.
        let mut g = geom([0.0; 3], 8);
        g.angles_rad = vec![0.0, std::f64::consts::FRAC_PI_2];
        let mask = seen_by_every_view(&g).unwrap();
        assert_eq!(mask.iter().filter(|&&m| m).count(), 8 * 8 * 16);
    }
}
