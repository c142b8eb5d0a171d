//! Voxel-driven backprojector used by FDK/FBP.
//!
//! Every voxel centre is projected onto each view's detector with the view's [`Camera`], the
//! projection is sampled bilinearly at that point (pixel centres at integer coordinates, zero
//! outside the detector), weighted and accumulated. For cone beam the weight is the FDK distance
//! weight `1/U²` with `U = (DSO − ⟨x, ŝ⟩)/DSO` (the voxel's depth along the view axis over the
//! isocentre's, the view's own for per-view vectors); for parallel beam the weight is 1. This is *not* the adjoint of the Joseph projector (use
//! [`super::Joseph::adjoint`] for that); it is the backprojection of the FDK formula.
//!
//! The rotation axis is z, so along a voxel column in z the detector column, the depth and the
//! weight stay fixed and the detector row advances by a constant step. Per view and column the
//! two detector columns around `u` are first blended into one line `L(v)` over the rows the
//! column reaches (contiguous, since each view is stored column-major with a zero border); each
//! voxel then costs one linear interpolation in `L` and a multiply-add. The volume is accumulated
//! z-fastest, in parallel over blocks of y, and reordered to `[z][y][x]` at the end. The inner loops are
//! compiled twice, for the baseline target and for AVX2+FMA, chosen at run time. A view whose
//! columns do not run along z (per-view vectors with a tilted detector or orbit) projects and
//! samples each voxel on its own ([`Column::general`]).

use super::joseph::{floorish, from_yxz, has_avx2_fma};
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
    backproject_with(geometry, projections, views, scale, has_avx2_fma())
}

/// [`backproject_voxel`] with the AVX2 kernels (`simd`, only if the CPU has them) or without.
fn backproject_with(
    geometry: &Geometry,
    projections: ArrayView3<f32>,
    views: &[usize],
    scale: &[f64],
    simd: bool,
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
    let (rows, cols) = (d.rows, d.cols);
    // Each view column-major with a zero border: `img[(c + 1)·(rows + 2) + r + 1]` = p[r][c].
    let padded = (rows + 2) * (cols + 2);
    let mut imgs = vec![0.0f32; views.len() * padded];
    imgs.par_chunks_mut(padded)
        .enumerate()
        .for_each(|(k, dst)| {
            for ((r, c), &v) in projections.index_axis(Axis(0), k).indexed_iter() {
                dst[(c + 1) * (rows + 2) + r + 1] = v;
            }
        });
    let simd = simd && has_avx2_fma();
    let (nx, nz) = (g.nx, g.nz);
    // Accumulate `[y][x][z]` in blocks of `YB` y-slabs per task (256 KiB at 128³, within L2),
    // views outermost: neighbouring slabs read nearly the same detector columns.
    const YB: usize = 4;
    let mut acc = vec![0.0f32; g.len()];
    acc.par_chunks_mut(YB * nx * nz)
        .enumerate()
        .for_each_init(Vec::new, |line, (b, block)| {
            for (k, cam) in cams.iter().enumerate() {
                let img = &imgs[k * padded..(k + 1) * padded];
                // The isocentre's depth along the view axis.
                let iso = cam.translation[2] as f32;
                let w = scale[k] as f32;
                // On a circular orbit the rotation axis is z (docs/geometry.md): moving a voxel
                // along z moves it along y_c only, so u, the depth and the 1/U² weight are
                // constant along a z-column and the detector row is affine in z.
                let vertical = cam.rotation[0][2] == 0.0 && cam.rotation[2][2] == 0.0;
                let dyc = (cam.rotation[1][2] * g.dz) as f32;
                for (dy, slab) in block.chunks_mut(nx * nz).enumerate() {
                    let iy = b * YB + dy;
                    for (ix, out) in slab.chunks_mut(nz).enumerate() {
                        let p = cam.to_camera(g.voxel_centre(ix, iy, 0));
                        if !vertical {
                            Column::general(cam, p, g.dz, cone, iso, img, rows + 2, w, out);
                        } else if let Some(column) = Column::new(cam, p, dyc, cone, iso, nz) {
                            column.accumulate(img, rows + 2, w, line, out, simd);
                        }
                    }
                }
            }
        });
    let out = from_yxz(&acc, [g.nx, g.ny, g.nz]);
    Ok(Array3::from_shape_vec(g.shape_zyx(), out).expect("grid shape"))
}

/// One voxel column along z as seen from one view: detector column position `u` (pixels), row
/// position `v0 + j·dv` of its `j`-th voxel for `j` in `j0..=j1` (the voxels inside the detector's
/// bilinear footprint), and the distance weight.
struct Column {
    u: f32,
    v0: f32,
    dv: f32,
    j0: usize,
    j1: usize,
    weight: f32,
}

impl Column {
    /// `None` when the column is behind the source or misses the detector's bilinear footprint;
    /// `iso` is the isocentre's depth along the view axis (DSO on a circular orbit).
    fn new(cam: &Camera, p: [f64; 3], dyc: f32, cone: bool, iso: f32, nz: usize) -> Option<Column> {
        debug_assert!(cone == (cam.projection == Projection::Cone));
        let (fx, fy, cx, cy) = (cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32);
        let c = p.map(|x| x as f32);
        let (u, v0, dv, weight) = if cone {
            if c[2].is_nan() || c[2] <= 0.0 {
                return None;
            }
            let inv = 1.0 / c[2];
            let uw = iso * inv;
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
        // Voxels whose row lies in (−1, rows); rounding at the ends is absorbed by the zero
        // border and the clamps in `accumulate`.
        let last = (nz - 1) as f64;
        let (vmin, vmax) = (-1.0, cam.rows as f64);
        let (j0, j1) = if dv == 0.0 {
            if !(v0 > -1.0 && (v0 as f64) < vmax) {
                return None;
            }
            (0.0, last)
        } else {
            let (ja, jb) = (
                (vmin - v0 as f64) / dv as f64,
                (vmax - v0 as f64) / dv as f64,
            );
            (ja.min(jb).ceil().max(0.0), ja.max(jb).floor().min(last))
        };
        if j0 > j1 {
            return None;
        }
        Some(Column {
            u,
            v0,
            dv,
            j0: j0 as usize,
            j1: j1 as usize,
            weight,
        })
    }

    /// A column along z for a camera whose columns do not run along z: every voxel `j` (camera
    /// position `p + j·dz·ẑ_c`) projected, weighted and sampled bilinearly on its own, into
    /// `out[j]`; `img` is padded as in [`Column::accumulate`].
    #[allow(clippy::too_many_arguments)]
    fn general(
        cam: &Camera,
        p: [f64; 3],
        dz: f64,
        cone: bool,
        iso: f32,
        img: &[f32],
        rp: usize,
        scale: f32,
        out: &mut [f32],
    ) {
        let step = [0, 1, 2].map(|a| cam.rotation[a][2] * dz);
        let cp = img.len() / rp;
        let (fx, fy, cx, cy) = (cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32);
        for (j, o) in out.iter_mut().enumerate() {
            let c = [0, 1, 2].map(|a| (p[a] + j as f64 * step[a]) as f32);
            let (u, v, weight) = if cone {
                if c[2].is_nan() || c[2] <= 0.0 {
                    continue;
                }
                let inv = 1.0 / c[2];
                let uw = iso * inv;
                (fx * c[0] * inv + cx, fy * c[1] * inv + cy, uw * uw)
            } else {
                (fx * c[0] + cx, fy * c[1] + cy, 1.0)
            };
            // Padded coordinates; outside (−1, cols) × (−1, rows) every neighbour is zero.
            let (uu, vv) = (u + 1.0, v + 1.0);
            if !(uu > 0.0 && uu < (cp - 1) as f32 && vv > 0.0 && vv < (rp - 1) as f32) {
                continue;
            }
            let (iu, iv) = (floorish(uu) as usize, floorish(vv) as usize);
            let (iu, iv) = (iu.min(cp - 2), iv.min(rp - 2));
            let (gu, gv) = (uu - iu as f32, vv - iv as f32);
            let at = |a: usize, b: usize| img[a * rp + b];
            let top = at(iu, iv) + gu * (at(iu + 1, iv) - at(iu, iv));
            let bottom = at(iu, iv + 1) + gu * (at(iu + 1, iv + 1) - at(iu, iv + 1));
            *o += scale * weight * (top + gv * (bottom - top));
        }
    }

    /// Add `scale · weight · bilinear(img, u, v_j)` to `out[j]` for the column's voxels; `img`
    /// is one view, column-major with `rp` padded rows and a zero border; `line` is scratch.
    fn accumulate(
        &self,
        img: &[f32],
        rp: usize,
        scale: f32,
        line: &mut Vec<f32>,
        out: &mut [f32],
        simd: bool,
    ) {
        #[cfg(target_arch = "x86_64")]
        if simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { self.accumulate_avx2(img, rp, scale, line, out) };
        }
        let _ = simd;
        self.accumulate_body(img, rp, scale, line, out)
    }

    /// [`Column::accumulate`] with AVX2+FMA: the line blend vectorises, voxels go eight at a
    /// time with two gathers from the line (same positions as the scalar path).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn accumulate_avx2(
        &self,
        img: &[f32],
        rp: usize,
        scale: f32,
        line: &mut Vec<f32>,
        out: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let span = self.blend(img, rp, line);
        let LineSpan { v0, lo, hi } = span;
        let w = scale * self.weight;
        let end = self.j1 + 1;
        assert!(end <= out.len() && line.len() == (hi - lo) as usize + 2);
        let lane = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (v0v, dv, wv) = (
            _mm256_set1_ps(v0),
            _mm256_set1_ps(self.dv),
            _mm256_set1_ps(w),
        );
        let half = _mm256_set1_ps(0.5);
        let magic = _mm256_set1_ps(super::joseph::MAGIC);
        let magic_bits = _mm256_set1_epi32(super::joseph::MAGIC.to_bits() as i32);
        let (lov, hiv) = (_mm256_set1_epi32(lo), _mm256_set1_epi32(hi));
        let ptr = line.as_ptr();
        let mut j = self.j0;
        while j + LANES <= end {
            let jf = _mm256_add_ps(_mm256_set1_ps(j as f32), lane);
            let v = _mm256_add_ps(v0v, _mm256_mul_ps(jf, dv));
            let t = _mm256_add_ps(_mm256_sub_ps(v, half), magic);
            let q = _mm256_sub_epi32(_mm256_castps_si256(t), magic_bits);
            let q = _mm256_min_epi32(_mm256_max_epi32(q, lov), hiv);
            let f = _mm256_sub_ps(v, _mm256_cvtepi32_ps(q));
            let i = _mm256_sub_epi32(q, lov);
            // SAFETY: 0 ≤ i ≤ hi − lo, so i + 1 < line.len() (asserted above); j + 8 ≤ out.len().
            unsafe {
                let p = _mm256_i32gather_ps::<4>(ptr, i);
                let n = _mm256_i32gather_ps::<4>(ptr.add(1), i);
                let val = _mm256_fmadd_ps(f, _mm256_sub_ps(n, p), p);
                let o = out.as_mut_ptr().add(j);
                _mm256_storeu_ps(o, _mm256_fmadd_ps(wv, val, _mm256_loadu_ps(o)));
            }
            j += LANES;
        }
        self.tail(span, w, line, out, j);
    }

    /// Blend the two detector columns around `u` over the rows the column reaches into `line`;
    /// returns where the voxels fall on it.
    #[inline(always)]
    fn blend(&self, img: &[f32], rp: usize, line: &mut Vec<f32>) -> LineSpan {
        // Padded coordinates: U = u + 1 ∈ (0, cols + 1), V = v + 1 ∈ (0, rows + 1).
        let cp = img.len() / rp;
        let uu = self.u + 1.0;
        let iu = floorish(uu).clamp(0, cp as i32 - 2) as usize;
        let gu = uu - iu as f32;
        let v0 = self.v0 + 1.0;
        let (va, vb) = (v0 + self.j0 as f32 * self.dv, v0 + self.j1 as f32 * self.dv);
        // Rows lo..=hi + 1 hold every lower and upper neighbour (floorish is monotone).
        let rmax = rp as i32 - 2;
        let lo = floorish(va.min(vb)).clamp(0, rmax);
        let hi = floorish(va.max(vb)).clamp(lo, rmax);
        let (r0, r1) = (lo as usize, hi as usize + 1);
        let a = &img[iu * rp + r0..=iu * rp + r1];
        let b = &img[(iu + 1) * rp + r0..=(iu + 1) * rp + r1];
        line.clear();
        line.extend(a.iter().zip(b).map(|(&a, &b)| a + gu * (b - a)));
        LineSpan { v0, lo, hi }
    }

    /// Voxels `from..=j1`, one at a time: `out[j] += w · line(v_j)` with `line` blended by
    /// [`Column::blend`] into `span`.
    #[inline(always)]
    fn tail(&self, span: LineSpan, w: f32, line: &[f32], out: &mut [f32], from: usize) {
        let LineSpan { v0, lo, hi } = span;
        for (j, o) in out.iter_mut().enumerate().take(self.j1 + 1).skip(from) {
            let v = v0 + j as f32 * self.dv;
            let q = floorish(v).clamp(lo, hi);
            let f = v - q as f32;
            let i = (q - lo) as usize;
            let (p, n) = (line[i], line[i + 1]);
            *o += w * (p + f * (n - p));
        }
    }

    /// The scalar path.
    fn accumulate_body(
        &self,
        img: &[f32],
        rp: usize,
        scale: f32,
        line: &mut Vec<f32>,
        out: &mut [f32],
    ) {
        let span = self.blend(img, rp, line);
        self.tail(span, scale * self.weight, line, out, self.j0);
    }
}

/// Where a column's voxels fall on its blended detector line ([`Column::blend`]): voxel `j` at
/// padded row `v0 + j·dv`, its lower neighbour row clamped to `[lo, hi]`; line entry 0 is row
/// `lo`.
#[derive(Clone, Copy, Debug)]
struct LineSpan {
    v0: f32,
    lo: i32,
    hi: i32,
}

/// Voxels per AVX2 step.
const LANES: usize = 8;

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
            vectors: None,
        }
    }

    /// A detector image that is affine in (col, row) is reproduced exactly by bilinear sampling,
    /// so each voxel receives `Σ_k scale_k · w_k · (a + b·col_k + c·row_k)`, computed here from
    /// `Camera::project` directly.
    #[test]
    fn matches_direct_projection_of_voxel_centres() {
        // Circular scans take the column path; disturbed per-view vectors (columns not along z)
        // the per-voxel one, weighted by the isocentre's depth along each view's axis.
        let disturbed = |beam| crate::testing::wobbled(&geom(beam));
        for g in [
            geom(Beam::Cone),
            geom(Beam::Parallel),
            disturbed(Beam::Cone),
            disturbed(Beam::Parallel),
        ] {
            let beam = g.beam;
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
                        Beam::Cone => (cam.to_camera([0.0; 3])[2] / cam.to_camera(p)[2]).powi(2),
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
    fn scalar_and_avx2_kernels_agree() {
        // Same sample positions on both paths; only the rounding of the fused multiply-adds
        // differs (f32, a few ulps per term).
        for beam in [Beam::Cone, Beam::Parallel] {
            let g = geom(beam);
            let d = &g.detector;
            let proj = Array3::from_shape_fn((g.views(), d.rows, d.cols), |(k, r, c)| {
                ((k * 31 + r * 7 + c * 3) as f32 * 0.173).sin()
            });
            let views: Vec<usize> = (0..g.views()).collect();
            let scale = vec![0.7; g.views()];
            let a = backproject_with(&g, proj.view(), &views, &scale, false).unwrap();
            let b = backproject_with(&g, proj.view(), &views, &scale, true).unwrap();
            let peak = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-5 * peak, "{beam:?}: {x} vs {y}");
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
