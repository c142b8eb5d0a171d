//! Voxel-driven backprojector used by FDK/FBP.
//!
//! Every voxel centre is projected onto each view's detector with the view's [`Camera`], the
//! projection is sampled bilinearly at that point (pixel centres at integer coordinates, zero
//! outside the detector), weighted and accumulated. For cone beam the weight is the FDK distance
//! weight `1/U²` with `U = (DSO − ⟨x, ŝ⟩)/DSO` (the voxel's depth along the central ray over DSO);
//! for parallel beam the weight is 1. This is *not* the adjoint of the Joseph projector (use
//! [`super::Joseph::adjoint`] for that); it is the backprojection of the FDK formula.
//!
//! Parallel over z-slices; along x the camera coordinates are updated incrementally, so each
//! update costs one reciprocal, a bilinear fetch and a multiply-add.

use crate::geometry::{Beam, Camera, Geometry, Projection};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView2, ArrayView3, Axis};
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
    if projections.shape() != [views.len(), d.rows, d.cols] {
        return Err(Error::invalid(
            "projections",
            format!(
                "shape {:?} does not match [views, rows, cols] = {:?}",
                projections.shape(),
                [views.len(), d.rows, d.cols]
            ),
        ));
    }
    if scale.len() != views.len() {
        return Err(Error::invalid("scale", "needs one factor per view"));
    }
    if let Some(v) = views.iter().find(|&&v| v >= geometry.views()) {
        return Err(Error::invalid("views", format!("view {v} does not exist")));
    }
    let cams: Vec<Camera> = views.iter().map(|&v| geometry.camera(v)).collect();
    let g = &geometry.volume;
    let cone = geometry.beam == Beam::Cone;
    let dso = geometry.dso;
    let mut out = Array3::<f32>::zeros(g.shape_zyx());
    out.as_slice_mut()
        .expect("fresh array")
        .par_chunks_mut(g.nx * g.ny)
        .enumerate()
        .for_each(|(iz, slice)| {
            for (k, cam) in cams.iter().enumerate() {
                let img = projections.index_axis(Axis(0), k);
                let s = scale[k] as f32;
                for iy in 0..g.ny {
                    let p0 = cam.to_camera(g.voxel_centre(0, iy, iz));
                    // Camera-frame step for one voxel along +x.
                    let r = &cam.rotation;
                    let dx = [r[0][0] * g.dx, r[1][0] * g.dx, r[2][0] * g.dx];
                    let line = &mut slice[iy * g.nx..(iy + 1) * g.nx];
                    accumulate_line(line, img, cam, p0, dx, cone, dso, s);
                }
            }
        });
    Ok(out)
}

/// Accumulate one x-line of voxels from one view.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn accumulate_line(
    line: &mut [f32],
    img: ArrayView2<f32>,
    cam: &Camera,
    p0: [f64; 3],
    dx: [f64; 3],
    cone: bool,
    dso: f64,
    scale: f32,
) {
    let (rows, cols) = (cam.rows as i64, cam.cols as i64);
    let img = img.as_slice().expect("standard layout");
    let (fx, fy, cx, cy) = (cam.fx, cam.fy, cam.cx, cam.cy);
    debug_assert!(cone == (cam.projection == Projection::Cone));
    for (ix, out) in line.iter_mut().enumerate() {
        let t = ix as f64;
        let c = [p0[0] + t * dx[0], p0[1] + t * dx[1], p0[2] + t * dx[2]];
        let (u, v, w) = if cone {
            if c[2] <= 0.0 {
                continue;
            }
            let inv = 1.0 / c[2];
            let uw = dso * inv;
            (fx * c[0] * inv + cx, fy * c[1] * inv + cy, (uw * uw) as f32)
        } else {
            (fx * c[0] + cx, fy * c[1] + cy, 1.0f32)
        };
        // Outside the detector's bilinear footprint (also rejects NaN).
        if !(u > -1.0 && u < cols as f64 && v > -1.0 && v < rows as f64) {
            continue;
        }
        // floor() without a libm call: u, v > −1 here, so truncation of u + 1 is floor(u) + 1.
        let (iu, iv) = ((u + 1.0) as i64 - 1, (v + 1.0) as i64 - 1);
        let (fu, fv) = ((u - iu as f64) as f32, (v - iv as f64) as f32);
        let val = if iu >= 0 && iu + 1 < cols && iv >= 0 && iv + 1 < rows {
            let b = (iv * cols + iu) as usize;
            let c = cols as usize;
            let a0 = img[b] + fu * (img[b + 1] - img[b]);
            let a1 = img[b + c] + fu * (img[b + c + 1] - img[b + c]);
            a0 + fv * (a1 - a0)
        } else {
            let mut acc = 0.0f32;
            for (dv, wv) in [(0i64, 1.0 - fv), (1, fv)] {
                for (du, wu) in [(0i64, 1.0 - fu), (1, fu)] {
                    let (ru, rv) = (iu + du, iv + dv);
                    if ru >= 0 && ru < cols && rv >= 0 && rv < rows {
                        acc += wu * wv * img[(rv * cols + ru) as usize];
                    }
                }
            }
            acc
        };
        *out += scale * w * val;
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
