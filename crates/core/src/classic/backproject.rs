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

use super::joseph::floorish;
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

/// Accumulate one x-line of voxels from one view. Batches of voxels are projected first (f32, a
/// loop the compiler vectorises), then the detector is sampled.
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
    const BATCH: usize = 64;
    let (rows, cols) = (cam.rows, cam.cols);
    let img = img.as_slice().expect("standard layout");
    let (fx, fy, cx, cy) = (cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32);
    let p = p0.map(|x| x as f32);
    let d = dx.map(|x| x as f32);
    let dso = dso as f32;
    let (colsf, rowsf) = (cols as f32, rows as f32);
    let (lim_u, lim_v) = ((cols - 1) as u32, (rows - 1) as u32);
    debug_assert!(cone == (cam.projection == Projection::Cone));
    let mut iu = [0i32; BATCH];
    let mut iv = [0i32; BATCH];
    let mut fu = [0f32; BATCH];
    let mut fv = [0f32; BATCH];
    let mut wt = [0f32; BATCH];
    let mut valid = [false; BATCH];
    let mut inside = [false; BATCH];
    for (b, chunk) in line.chunks_mut(BATCH).enumerate() {
        for t in 0..chunk.len() {
            let x = (b * BATCH + t) as f32;
            let c = [p[0] + x * d[0], p[1] + x * d[1], p[2] + x * d[2]];
            let (u, v, w) = if cone {
                let inv = 1.0 / c[2];
                let uw = dso * inv;
                (fx * c[0] * inv + cx, fy * c[1] * inv + cy, uw * uw)
            } else {
                (fx * c[0] + cx, fy * c[1] + cy, 1.0)
            };
            // In the detector's bilinear footprint and in front of the source (false for NaN).
            let ok = (!cone || c[2] > 0.0) & (u > -1.0) & (u < colsf) & (v > -1.0) & (v < rowsf);
            let (a, bq) = (floorish(u), floorish(v));
            iu[t] = a;
            iv[t] = bq;
            fu[t] = u - a as f32;
            fv[t] = v - bq as f32;
            wt[t] = w;
            valid[t] = ok;
            inside[t] = ok & ((a as u32) < lim_u) & ((bq as u32) < lim_v);
        }
        for (t, out) in chunk.iter_mut().enumerate() {
            if !valid[t] {
                continue;
            }
            let (gu, gv) = (fu[t], fv[t]);
            let val = if inside[t] {
                let base = iv[t] as usize * cols + iu[t] as usize;
                let cell = &img[base..=base + cols + 1];
                let a0 = cell[0] + gu * (cell[1] - cell[0]);
                let a1 = cell[cols] + gu * (cell[cols + 1] - cell[cols]);
                a0 + gv * (a1 - a0)
            } else {
                let mut acc = 0.0f32;
                for (dv, wv) in [(0i32, 1.0 - gv), (1, gv)] {
                    for (du, wu) in [(0i32, 1.0 - gu), (1, gu)] {
                        let (ru, rv) = (iu[t] + du, iv[t] + dv);
                        if ru >= 0 && (ru as usize) < cols && rv >= 0 && (rv as usize) < rows {
                            acc += wu * wv * img[rv as usize * cols + ru as usize];
                        }
                    }
                }
                acc
            };
            *out += scale * wt[t] * val;
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
