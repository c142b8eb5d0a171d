//! Voxel-driven backprojector used by FDK/FBP.
//!
//! Every voxel centre is projected onto each view's detector with the view's [`Camera`], the
//! projection is sampled bilinearly at that point (pixel centres at integer coordinates, zero
//! outside the detector), weighted and accumulated. For cone beam the weight is the FDK distance
//! weight `1/U²` with `U = (DSO − ⟨x, ŝ⟩)/DSO` (the voxel's depth along the central ray over DSO);
//! for parallel beam the weight is 1. This is *not* the adjoint of the Joseph projector (use
//! [`super::Joseph::adjoint`] for that); it is the backprojection of the FDK formula.
//!
//! Parallel over z-chunks. The rotation axis is z, so along a voxel column in z the detector
//! column, the depth and the weight stay fixed and the detector row advances by a constant step:
//! each update costs a row step, a bilinear fetch and a multiply-add.

use super::joseph::floorish;
use crate::geometry::{Beam, Camera, Geometry, Projection};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3, Axis};
use rayon::prelude::*;

/// Voxel-driven backprojection of `projections` (`[k][row][col]`, slab `k` from view
/// `views[k]`) with per-view scale factors `scale[k]`; cone beam applies the `1/U²` weight.
pub fn backproject_voxel(
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    scale: &[f64],
) -> Result<Array3<f32>> {
    geometry.validate()?;
    let d = &geometry.detector;
    if views.is_empty() {
        return Err(Error::invalid("views", "the view list is empty"));
    }
    crate::error::ensure_shape(
        "projections",
        projections.shape(),
        &[views.len(), d.rows, d.cols],
        "[views, rows, cols]",
    )?;
    if scale.len() != views.len() {
        return Err(Error::invalid("scale", "needs one factor per view"));
    }
    if let Some(v) = views.iter().find(|&&v| v >= geometry.views()) {
        return Err(Error::invalid("views", format!("view {v} does not exist")));
    }
    let cams: Vec<Camera> = views.iter().map(|&v| geometry.camera(v)).collect();
    let g = &geometry.volume;
    let cone = geometry.beam == Beam::Cone;
    let dso = geometry.dso as f32;
    let slice_len = g.nx * g.ny;
    // Contiguous z-chunks, a few per thread for balance.
    let chunk_z = g.nz.div_ceil(4 * rayon::current_num_threads()).max(1);
    let mut out = Array3::<f32>::zeros(g.shape_zyx());
    out.as_slice_mut()
        .expect("fresh array")
        .par_chunks_mut(chunk_z * slice_len)
        .enumerate()
        .for_each(|(c, chunk)| {
            let z0 = c * chunk_z;
            let nz = chunk.len() / slice_len;
            for (k, cam) in cams.iter().enumerate() {
                let img = projections.index_axis(Axis(0), k);
                let img = img.as_slice().expect("standard layout");
                // The rotation axis is z (docs/geometry.md): moving a voxel along z moves it along
                // y_c only, so u, the depth and the 1/U² weight are constant along a z-column and
                // the detector row is affine in z.
                debug_assert!(cam.rotation[0][2] == 0.0 && cam.rotation[2][2] == 0.0);
                let dyc = (cam.rotation[1][2] * g.dz) as f32;
                for iy in 0..g.ny {
                    for ix in 0..g.nx {
                        let p = cam.to_camera(g.voxel_centre(ix, iy, z0));
                        let column = Column::new(cam, p, dyc, cone, dso);
                        if let Some(column) = column {
                            column.accumulate(
                                img,
                                cam,
                                scale[k] as f32,
                                nz,
                                &mut chunk[iy * g.nx + ix..],
                                slice_len,
                            );
                        }
                    }
                }
            }
        });
    Ok(out)
}

/// One voxel column along z as seen from one view: fixed detector column position and weight,
/// row position `v0 + j·dv` for the `j`-th voxel of the column.
struct Column {
    /// Left detector column and the bilinear weight of the right one.
    iu: i32,
    gu: f32,
    v0: f32,
    dv: f32,
    weight: f32,
}

impl Column {
    /// `None` when the column is behind the source or misses the detector's bilinear footprint.
    fn new(cam: &Camera, p: [f64; 3], dyc: f32, cone: bool, dso: f32) -> Option<Column> {
        debug_assert!(cone == (cam.projection == Projection::Cone));
        let (fx, fy, cx, cy) = (cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32);
        let c = p.map(|x| x as f32);
        let (u, v0, dv, weight) = if cone {
            if c[2].is_nan() || c[2] <= 0.0 {
                return None;
            }
            let inv = 1.0 / c[2];
            let uw = dso * inv;
            (
                fx * c[0] * inv + cx,
                fy * c[1] * inv + cy,
                fy * dyc * inv,
                uw * uw,
            )
        } else {
            (fx * c[0] + cx, fy * c[1] + cy, fy * dyc, 1.0)
        };
        // In the bilinear footprint of the columns (false for NaN).
        if !(u > -1.0 && u < cam.cols as f32) {
            return None;
        }
        let iu = floorish(u);
        Some(Column {
            iu,
            gu: u - iu as f32,
            v0,
            dv,
            weight,
        })
    }

    /// Add `scale · weight · bilinear(img, u, v_j)` to `out[j·stride]` for `j < nz`.
    fn accumulate(
        &self,
        img: &[f32],
        cam: &Camera,
        scale: f32,
        nz: usize,
        out: &mut [f32],
        stride: usize,
    ) {
        let (rows, cols) = (cam.rows, cam.cols);
        let w = scale * self.weight;
        let (gu, iu) = (self.gu, self.iu);
        // Both columns on the detector: the common case, no per-sample column checks.
        let both = iu >= 0 && (iu as usize) + 1 < cols;
        let rowsf = rows as f32;
        for j in 0..nz {
            let v = self.v0 + j as f32 * self.dv;
            if !(v > -1.0 && v < rowsf) {
                continue;
            }
            let iv = floorish(v);
            let gv = v - iv as f32;
            let val = if both && iv >= 0 && (iv as usize) + 1 < rows {
                let base = iv as usize * cols + iu as usize;
                let a0 = img[base] + gu * (img[base + 1] - img[base]);
                let a1 = img[base + cols] + gu * (img[base + cols + 1] - img[base + cols]);
                a0 + gv * (a1 - a0)
            } else {
                let mut acc = 0.0f32;
                for (dv, wv) in [(0i32, 1.0 - gv), (1, gv)] {
                    for (du, wu) in [(0i32, 1.0 - gu), (1, gu)] {
                        let (ru, rv) = (iu + du, iv + dv);
                        if ru >= 0 && (ru as usize) < cols && rv >= 0 && (rv as usize) < rows {
                            acc += wu * wv * img[rv as usize * cols + ru as usize];
                        }
                    }
                }
                acc
            };
            out[j * stride] += w * val;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Detector, VolumeGrid};

    fn geom(beam: Beam) -> Geometry {
        Geometry {
            beam,
            dso: 400.0,
            dsd: 600.0,
            detector: Detector {
                rows: 32,
                cols: 40,
                pitch_u: 1.5,
                pitch_v: 1.5,
                offset_u: 1.2,
                offset_v: -0.7,
            },
            volume: VolumeGrid {
                offset: [1.0, -2.0, 0.5],
                ..VolumeGrid::cube(16, 1.0)
            },
            angles_rad: Geometry::full_turn(5),
        }
    }

    /// A detector image that is affine in (col, row) is reproduced exactly by bilinear sampling,
    /// so each voxel receives `Σ_k scale_k · w_k · (a + b·col_k + c·row_k)`, computed here from
    /// `Camera::project` directly.
    #[test]
    fn matches_direct_projection_of_voxel_centres() {
        for beam in [Beam::Cone, Beam::Parallel] {
            let g = geom(beam);
            let d = &g.detector;
            let f = |c: f64, r: f64| 0.5 + 0.01 * c - 0.02 * r;
            let proj = Array3::from_shape_fn((g.views(), d.rows, d.cols), |(_, r, c)| {
                f(c as f64, r as f64) as f32
            });
            let views: Vec<usize> = (0..g.views()).collect();
            let scale: Vec<f64> = (0..g.views()).map(|k| 1.0 + k as f64).collect();
            let bp = backproject_voxel(&g, proj.view(), &views, &scale).unwrap();
            let v = &g.volume;
            for (iz, iy, ix) in [(0, 0, 0), (8, 3, 12), (15, 15, 15), (5, 10, 2)] {
                let p = v.voxel_centre(ix, iy, iz);
                let mut want = 0.0;
                for (k, sk) in scale.iter().enumerate() {
                    let cam = g.camera(k);
                    let [c, r] = cam.project(p).unwrap();
                    assert!(
                        c > 0.0 && c < (d.cols - 1) as f64 && r > 0.0 && r < (d.rows - 1) as f64
                    );
                    let w = match beam {
                        Beam::Cone => (g.dso / cam.to_camera(p)[2]).powi(2),
                        Beam::Parallel => 1.0,
                    };
                    want += sk * w * f(c, r);
                }
                let got = bp[[iz, iy, ix]] as f64;
                assert!(
                    (got - want).abs() < 1e-4 * want.abs(),
                    "{beam:?} {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn rejects_mismatched_inputs() {
        let g = geom(Beam::Cone);
        let p = Array3::<f32>::zeros((2, 32, 40));
        assert!(backproject_voxel(&g, p.view(), &[0], &[1.0]).is_err());
        assert!(backproject_voxel(&g, p.view(), &[0, 9], &[1.0, 1.0]).is_err());
        let e = backproject_voxel(&g, p.view(), &[], &[]).unwrap_err();
        assert!(e.to_string().contains("views"));
    }
}
