//! Ray-driven Joseph forward projector and its exact adjoint.
//!
//! One ray per detector-pixel centre (as [`Camera::pixel_ray`]): from the source (cone) or the
//! start plane (parallel) to the detector. The ray is stepped along its *dominant* volume axis (the
//! axis whose voxel index changes fastest along the ray); at every voxel-centre plane of that axis
//! the volume is sampled bilinearly in the other two axes (zero outside the grid) and the sample is
//! weighted by the ray length per plane, `Δt = d_k / |cos|` (mm). A projection is therefore
//! `Σ_i Δt · bilinear(slice_i)`, a line integral in μ·mm units.
//!
//! **Column sheets.** The rotation axis is z and detector columns are parallel to it
//! (`docs/geometry.md`), so the rays through one detector column of one view lie in one vertical
//! plane and share their x/y path. For a ray whose dominant axis is x or y (every ray unless the
//! cone angle exceeds 45°) the plane positions along the dominant axis and along the other
//! horizontal axis are the same for every row of the column; only z differs. Bilinear sampling is
//! separable, so the horizontal interpolation is done once per column: the *sheet*
//! `S[i][z] = (1 − f_i)·V(i, q_i, z) + f_i·V(i, q_i + 1, z)` at plane `i`, for every z. Each ray of
//! the column then costs one linear interpolation in z per plane, which AVX2 (detected at run
//! time) gathers eight planes at a time. Rays whose dominant axis is z take the general per-ray
//! walk. When several views are projected, the forward pass first copies the volume to z-fastest
//! order so that sheets are built from contiguous z-lines. A column of one row (a fan beam) has
//! nothing to share its sheet with: its ray computes the sheet's entries where it reads them, with
//! the same arithmetic, bit for bit the sheet's result.
//!
//! The adjoint is the transpose of the same steps (rays scatter into the sheet, the sheet into the
//! volume, identical sample positions and weights), so `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` up to float rounding,
//! which CGLS needs. It is parallel over detector columns with one accumulator volume per worker
//! (no atomics, no races), reduced at the end.
//!
//! Arrays: volumes `[z][y][x]`, projections `[view][row][col]` (see `docs/geometry.md`).

mod lone;
mod sheet;
mod walk;

use lone::*;
use sheet::*;
use walk::*;
pub(crate) use walk::{MAGIC, floorish, from_yxz};

use crate::geometry::{Camera, Geometry, Projection};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

/// Ray-driven trilinear (Joseph) projector bound to one geometry.
#[derive(Clone, Debug)]
pub struct Joseph {
    geometry: Geometry,
    cameras: Vec<Camera>,
    /// Use the AVX2+FMA sheet sampler (the CPU has it; tests switch it off to cover both paths).
    simd: bool,
    /// Trace rays on column sheets where possible; when false every ray takes the general walk
    /// (the reference the tests compare the sheets against).
    sheets: bool,
    /// Trace a column of one row (a fan beam) without building its sheet ([`LoneRay`]); when
    /// false it builds the sheet as for many rows (the bit-for-bit reference of the tests).
    lone: bool,
}

/// One detector column of one view: the rays of its pixels are traced together (they share their
/// horizontal path, see the module docs).
#[derive(Clone, Copy, Debug)]
struct DetectorColumn<'a> {
    /// The view's camera.
    cam: &'a Camera,
    /// Column index on the detector (0 ≤ col < cols).
    col: usize,
}

/// Projecting at least this many views copies the volume to z-fastest order first (the copy costs
/// about as much as projecting a view or two; single-view calls, as in SART, skip it).
const TRANSPOSE_MIN_VIEWS: usize = 4;

pub(crate) use prism_kernel::simd::has_avx2_fma;

impl Joseph {
    /// Bind a projector to `geometry` (validated).
    pub fn new(geometry: &Geometry) -> Result<Self> {
        geometry.validate()?;
        Ok(Joseph {
            cameras: geometry.cameras(),
            geometry: geometry.clone(),
            simd: has_avx2_fma(),
            sheets: true,
            lone: true,
        })
    }

    /// The geometry this projector was built for.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.cameras.len()
    }

    /// Shape `[views, rows, cols]` of the projections of `n_views` views.
    pub fn projection_shape(&self, n_views: usize) -> [usize; 3] {
        let d = &self.geometry.detector;
        [n_views, d.rows, d.cols]
    }

    /// Project `volume` (`[z][y][x]`, μ in mm⁻¹) into all views: `[view][row][col]` line integrals.
    pub fn forward(&self, volume: ArrayView3<f32>) -> Result<Array3<f32>> {
        let all: Vec<usize> = (0..self.views()).collect();
        self.forward_views(volume, &all)
    }

    /// Project `volume` into the listed views only; output slab `k` is view `views[k]`.
    pub fn forward_views(&self, volume: ArrayView3<f32>, views: &[usize]) -> Result<Array3<f32>> {
        self.check_volume(volume, "volume")?;
        self.check_views(views)?;
        let dims = self.dims();
        let vol = volume.as_standard_layout();
        let vol = vol.as_slice().expect("standard layout");
        let shape = self.projection_shape(views.len());
        let Some(support) = support(vol, dims) else {
            return Ok(Array3::zeros(shape)); // an all-zero volume projects to zero
        };
        let (rows, cols) = (shape[1], shape[2]);
        let copy;
        let (src, layout) = if views.len() >= TRANSPOSE_MIN_VIEWS {
            copy = to_yxz(vol, dims);
            (&copy[..], Layout::yxz(dims))
        } else {
            (vol, Layout::zyx(dims))
        };
        // Detector columns `[view][col][row]`, one task per column.
        let mut columns = vec![0.0f32; views.len() * cols * rows];
        columns
            .par_chunks_mut(rows)
            .enumerate()
            .for_each_init(Sheet::new, |sheet, (line, out)| {
                let column = DetectorColumn {
                    cam: &self.cameras[views[line / cols]],
                    col: line % cols,
                };
                self.project_column(column, src, layout, &support, sheet, out);
            });
        let out = swap_last(&columns, cols, rows);
        Ok(Array3::from_shape_vec(shape, out).expect("projection shape"))
    }

    /// Exact adjoint of [`Joseph::forward`]: `Aᵀ y` for projections `[view][row][col]` of all views.
    pub fn adjoint(&self, projections: ArrayView3<f32>) -> Result<Array3<f32>> {
        let all: Vec<usize> = (0..self.views()).collect();
        self.adjoint_views(projections, &all)
    }

    /// Exact adjoint of [`Joseph::forward_views`] for the same `views`.
    pub fn adjoint_views(
        &self,
        projections: ArrayView3<f32>,
        views: &[usize],
    ) -> Result<Array3<f32>> {
        self.check_views(views)?;
        let want = self.projection_shape(views.len());
        crate::error::ensure_shape(
            "projections",
            projections.shape(),
            &want,
            "[views, rows, cols]",
        )?;
        let g = &self.geometry.volume;
        let dims = self.dims();
        let n = g.len();
        let proj = projections.as_standard_layout();
        let proj = proj.as_slice().expect("standard layout");
        let (rows, cols) = (want[1], want[2]);
        let columns = swap_last(proj, rows, cols);
        let lines = views.len() * cols;
        let full: Support = ([0; 3], [g.nx - 1, g.ny - 1, g.nz - 1]);
        let transposed = views.len() >= TRANSPOSE_MIN_VIEWS;
        let layout = if transposed {
            Layout::yxz(dims)
        } else {
            Layout::zyx(dims)
        };
        // One accumulator per task over runs of detector columns, one task per thread.
        let min_len = lines.div_ceil(rayon::current_num_threads()).max(1);
        let partial: Vec<Vec<f32>> = (0..lines)
            .into_par_iter()
            .with_min_len(min_len)
            .fold(
                || (vec![0.0f32; n], Sheet::new()),
                |(mut acc, mut sheet), line| {
                    let vals = &columns[line * rows..(line + 1) * rows];
                    if vals.iter().any(|&v| v != 0.0) {
                        let column = DetectorColumn {
                            cam: &self.cameras[views[line / cols]],
                            col: line % cols,
                        };
                        self.adjoint_column(column, vals, &mut acc, layout, &full, &mut sheet);
                    }
                    (acc, sheet)
                },
            )
            .map(|(acc, _)| acc)
            .collect();
        let summed = reduce(partial, n);
        let out = if transposed {
            from_yxz(&summed, dims)
        } else {
            summed
        };
        Ok(Array3::from_shape_vec(g.shape_zyx(), out).expect("grid shape"))
    }

    /// Ray length inside the volume per pixel, `A·1`: the row sums of the system matrix.
    pub fn ray_lengths(&self, views: &[usize]) -> Result<Array3<f32>> {
        let ones = Array3::<f32>::ones(self.geometry.volume.shape_zyx());
        self.forward_views(ones.view(), views)
    }

    /// Grid size `[nx, ny, nz]`.
    fn dims(&self) -> [usize; 3] {
        let g = &self.geometry.volume;
        [g.nx, g.ny, g.nz]
    }

    fn check_volume(&self, volume: ArrayView3<f32>, field: &str) -> Result<()> {
        let want = self.geometry.volume.shape_zyx();
        if volume.shape() != want {
            return Err(Error::invalid(
                field,
                format!(
                    "shape {:?} does not match the grid [nz, ny, nx] = {want:?}",
                    volume.shape()
                ),
            ));
        }
        Ok(())
    }

    fn check_views(&self, views: &[usize]) -> Result<()> {
        if views.is_empty() {
            return Err(Error::invalid("views", "the view list is empty"));
        }
        if let Some(v) = views.iter().find(|&&v| v >= self.views()) {
            return Err(Error::invalid(
                "views",
                format!(
                    "view {v} does not exist (the geometry has {} views)",
                    self.views()
                ),
            ));
        }
        Ok(())
    }

    /// The rays of a detector column in continuous voxel-index space.
    fn column_rays(&self, DetectorColumn { cam, col }: DetectorColumn) -> ColumnRays {
        let grid = &self.geometry.volume;
        let ends = |row: f64| {
            let end = cam.pixel_camera(col as f64, row);
            let start = match cam.projection {
                Projection::Cone => [0.0; 3],
                Projection::Parallel => [end[0], end[1], 0.0],
            };
            let (o, e) = (cam.to_world(start), cam.to_world(end));
            let (a, b) = (grid.world_to_index(o), grid.world_to_index(e));
            (
                a,
                [0, 1, 2].map(|i| b[i] - a[i]),
                [0, 1, 2].map(|i| e[i] - o[i]),
            )
        };
        let (r0, r1) = (ends(0.0), ends(1.0));
        let pair = |p: [f64; 3], q: [f64; 3]| [p, [0, 1, 2].map(|i| q[i] - p[i])];
        ColumnRays {
            a: pair(r0.0, r1.0),
            g: pair(r0.1, r1.1),
            d: pair(r0.2, r1.2),
        }
    }

    /// The horizontal walk shared by column `col`'s rays, clipped to `support` in x and y, or
    /// `None` when sheets are off or the column's rays are not coplanar with z (then every row
    /// takes the general walk: circular orbits always have vertical columns, per-view vectors
    /// with a turned or tilted detector do not).
    fn column_walk(
        &self,
        cam: &Camera,
        rays: &ColumnRays,
        support: &Support,
    ) -> Option<ColumnWalk> {
        if !self.sheets || cam.rotation[1][0] != 0.0 || cam.rotation[1][1] != 0.0 {
            return None;
        }
        let ray = rays.ray(0);
        let (a, g) = (&ray.a, &ray.g);
        let k = if g[0].abs() > g[1].abs() { 0 } else { 1 };
        let j = 1 - k;
        if g[k] == 0.0 {
            return None;
        }
        let (blo, bhi) = (support.0.map(|x| x as f64), support.1.map(|x| x as f64));
        let mut t = clip(a[k], g[k], blo[k] - 0.5, bhi[k] + 0.5, (0.0, 1.0));
        t = clip(a[j], g[j], blo[j] - 1.0, bhi[j] + 1.0, t);
        let (ka, kb) = (a[k] + t.0 * g[k], a[k] + t.1 * g[k]);
        let (lo, hi) = if t.1 <= t.0 {
            (1, 0)
        } else {
            (
                ka.min(kb).ceil().max(blo[k]) as i64,
                (ka.max(kb).floor() as i64).min(bhi[k] as i64),
            )
        };
        let dp = g[j] / g[k];
        Some(ColumnWalk {
            k,
            j,
            lo,
            hi,
            p0: (a[j] + (lo as f64 - a[k]) * dp) as f32,
            dp: dp as f32,
        })
    }

    /// How the ray through (col, row) is traced: on the column sheet when its dominant axis is
    /// the column's horizontal one, else by the general walk.
    fn plan_row(ray: &IndexRay, column: Option<&ColumnWalk>, support: &Support) -> RowPlan {
        let plan = match column {
            Some(c) if ray.g[2].abs() < ray.g[c.k].abs() => {
                if c.lo > c.hi {
                    None
                } else {
                    c.sheet_ray(ray, support.0[2], support.1[2])
                        .map(RowPlan::Sheet)
                }
            }
            _ => walk(ray, dominant(&ray.g), support).map(RowPlan::Walk),
        };
        plan.unwrap_or(RowPlan::Miss)
    }

    /// Forward-project one detector column into `out` (its rows), compiled for AVX2+FMA when
    /// the CPU has them (ray setup, sheet build and sampling all in one function).
    fn project_column(
        &self,
        col: DetectorColumn,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { self.project_column_avx2(col, vol, layout, support, sheet, out) };
        }
        self.project_column_body(col, vol, layout, support, sheet, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn project_column_avx2(
        &self,
        col: DetectorColumn,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        self.project_column_body(col, vol, layout, support, sheet, out)
    }

    #[inline(always)]
    fn project_column_body(
        &self,
        col: DetectorColumn,
        vol: &[f32],
        layout: Layout,
        support: &Support,
        sheet: &mut Sheet,
        out: &mut [f32],
    ) {
        let rays = self.column_rays(col);
        let column = self.column_walk(col.cam, &rays, support);
        // A column of one ray (a fan beam) reads the volume directly, the same sums as its sheet.
        let lone = self.lone && out.len() == 1;
        let mut built = false;
        for (row, o) in out.iter_mut().enumerate() {
            match Self::plan_row(&rays.ray(row), column.as_ref(), support) {
                RowPlan::Sheet(r) => {
                    let c = column.as_ref().expect("sheet rows have a column walk");
                    if lone {
                        *o = LoneRay::new(layout, c, support).sample(vol, &r, self.simd);
                        continue;
                    }
                    if !built {
                        sheet.reset(c.planes(), support.0[2], support.1[2]);
                        sheet.build(vol, layout, c, (support.0[c.j], support.1[c.j]));
                        built = true;
                    }
                    *o = self.sample(sheet, &r);
                }
                RowPlan::Walk(w) => {
                    let mut acc = Gather { vol, sum: 0.0 };
                    run(&w, self.dims(), layout, &mut acc);
                    *o = acc.sum * w.step;
                }
                RowPlan::Miss => {}
            }
        }
    }

    /// Adjoint of [`Joseph::project_column`]: add the column's rows `vals` into `acc`
    /// (compiled for AVX2+FMA when the CPU has them; the arithmetic is the same on both paths).
    fn adjoint_column(
        &self,
        col: DetectorColumn,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { self.adjoint_column_avx2(col, vals, acc, layout, full, sheet) };
        }
        self.adjoint_column_body(col, vals, acc, layout, full, sheet)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn adjoint_column_avx2(
        &self,
        col: DetectorColumn,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        self.adjoint_column_body(col, vals, acc, layout, full, sheet)
    }

    #[inline(always)]
    fn adjoint_column_body(
        &self,
        col: DetectorColumn,
        vals: &[f32],
        acc: &mut [f32],
        layout: Layout,
        full: &Support,
        sheet: &mut Sheet,
    ) {
        let rays = self.column_rays(col);
        let column = self.column_walk(col.cam, &rays, full);
        let lone = self.lone && vals.len() == 1;
        let mut used = false;
        for (row, &val) in vals.iter().enumerate() {
            if val == 0.0 {
                continue;
            }
            match Self::plan_row(&rays.ray(row), column.as_ref(), full) {
                RowPlan::Sheet(r) => {
                    let c = column.as_ref().expect("sheet rows have a column walk");
                    if lone {
                        LoneRay::new(layout, c, full).spread(acc, &r, val);
                        continue;
                    }
                    if !used {
                        sheet.reset(c.planes(), full.0[2], full.1[2]);
                        used = true;
                    }
                    sheet.spread(&r, val);
                }
                RowPlan::Walk(w) => {
                    let mut s = Scatter {
                        acc: &mut *acc,
                        val: val * w.step,
                    };
                    run(&w, self.dims(), layout, &mut s);
                }
                RowPlan::Miss => {}
            }
        }
        if used {
            let c = column.as_ref().expect("sheet rows have a column walk");
            sheet.scatter(acc, layout, c, (full.0[c.j], full.1[c.j]));
        }
    }

    /// One ray's sum over its sheet, with the vector sampler where available.
    fn sample(&self, sheet: &Sheet, r: &SheetRay) -> f32 {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is only set when the CPU has AVX2 and FMA.
            return unsafe { sheet.sample_avx2(r) };
        }
        sheet.sample(r)
    }
}

/// Inner product in f64 of two equally shaped arrays (the adjoint identity
/// `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` is checked with it; CGLS's step sizes use it).
pub fn dot(a: ArrayView3<f32>, b: ArrayView3<f32>) -> f64 {
    a.iter()
        .zip(b.iter())
        .map(|(&p, &q)| p as f64 * q as f64)
        .sum()
}

#[cfg(test)]
mod tests;
