//! CubeCL kernels of the render ops for Burn's `CubeBackend` (wgpu: Vulkan, Metal, DX12, and
//! Mesa's lavapipe without a GPU).
//!
//! Same contract as the CPU kernels ([`crate::cpu`]): the prepared projection state is the same
//! `[V, K, PREPARED_WIDTH]` record layout, culling and cut-off rules are the same, and every
//! formula is the f32 port of [`crate::gaussian_math`] ([`math`]). Forward passes own one
//! output tile per cube and compact the tile's Gaussians in index order ([`stage_chunk`]); backward
//! passes own one Gaussian per unit and gather its footprint. Neither needs atomics, so the
//! kernels run unchanged on devices without f32 atomic add and give run-to-run identical
//! results. Nothing is read back to the host: every buffer size follows from the shapes.
//!
//! Exact-mode projection has its own record ([`math::EX_WIDTH`] floats per view and Gaussian,
//! integrated per pixel by [`math::exact_ray`]) and backward ([`project::backward_exact_kernel`]);
//! the forward kernel and its culling are shared.
//!
//! Forward kernels skip whole culling steps whose union box ([`step_bounds_kernel`]) misses the
//! cube's tile or brick, which pays when consecutive Gaussians are spatially close.

// Kernels reject NaN through negated comparisons (`!(x > 0)` is true for NaN); CubeCL has no
// `partial_cmp`, nor `div_ceil`.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::manual_div_ceil)]

pub mod math;
pub mod project;
pub mod voxelize;

#[cfg(test)]
mod tests;

use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::tensor::{DType, Shape, TensorData};
use burn_cubecl::cubecl;
use burn_cubecl::{
    CubeBackend, kernel::into_contiguous, ops::numeric::zeros_client, tensor::CubeTensor,
};
use cubecl::prelude::*;

use crate::camera::{Camera, Projection};
use crate::cpu::PREPARED_WIDTH;
use crate::options::{ProjectOptions, ProjectionMode, VoxelGrid, VoxelizeOptions};
use math::{CAM_WIDTH, EX_BOX, EX_WIDTH};
use project::TILE;

/// Units per cube of the 1D kernels and of the culling scan.
pub const CHUNK: usize = 256;
/// Gaussians each unit tests per culling step of a forward kernel.
pub const PER_UNIT: usize = 4;
/// Gaussians per culling step of a cube: [`CHUNK`] units × [`PER_UNIT`].
pub const STEP: usize = CHUNK * PER_UNIT;

/// One culling step of a forward kernel: unit `t` tested Gaussians `first..first + PER_UNIT`
/// and set bit `i` of `hits` for each one that touches the cube's tile or brick. Their indices
/// are compacted into `ids` in index order (an exclusive prefix sum of the units' hit counts,
/// ping-pong Hillis–Steele over `scan` of `2 · CHUNK` entries: one barrier per step, one scan
/// per `STEP` Gaussians); returns the number of hits. Contains barriers: call it uniformly.
#[cube]
pub fn stage_chunk(
    hits: u32,
    first: usize,
    t: usize,
    scan: &mut Shared<[u32]>,
    ids: &mut Shared<[u32]>,
) -> u32 {
    let mut count = 0u32;
    for i in 0..PER_UNIT {
        count += (hits >> i as u32) & 1u32;
    }
    scan[t] = count;
    sync_cube();
    let mut src = 0usize;
    let mut off = 1usize;
    while off < CHUNK {
        let mut val = scan[src * CHUNK + t];
        if t >= off {
            val += scan[src * CHUNK + t - off];
        }
        src = 1 - src;
        scan[src * CHUNK + t] = val;
        sync_cube();
        off *= 2;
    }
    let total = scan[src * CHUNK + CHUNK - 1];
    let mut slot = (scan[src * CHUNK + t] - count) as usize;
    for i in 0..PER_UNIT {
        if (hits >> i as u32) & 1u32 == 1u32 {
            ids[slot] = (first + i) as u32;
            slot += 1;
        }
    }
    sync_cube();
    total
}

/// The lower end of an empty step box (WGSL has no infinity literal; any box tests as
/// disjoint from `[EMPTY_LO, −EMPTY_LO)`).
pub const EMPTY_LO: f32 = 3.0e38;

/// Bounding box of each run of [`STEP`] consecutive records (the Gaussians one culling step of a
/// forward kernel tests), so that a cube can skip whole steps whose union box misses its tile or
/// brick. `records` is `[sets, k, width]` (views for projection, one set for voxelization); a
/// record's box on axis `a` is `[lo_at + a·axis_step, hi_at + a·axis_step)`, and records with an
/// empty box (culled) are left out. Writes `[sets, ⌈k / STEP⌉, axes, 2]` as `(lo, hi)` pairs; a
/// step with no live record gets the empty box `(EMPTY_LO, −EMPTY_LO)`.
///
/// Skipping is uniform across a cube (every unit reads the same box), so the barriers of the
/// culling step stay in uniform control flow, and the summation order is unchanged: the output
/// is bit-identical to not skipping. It pays when consecutive indices are spatially close, as
/// they are for Gaussians initialised in raster order (Prism's FDK initialisation) and for the
/// clones densification appends in parent order.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn step_bounds_kernel(
    records: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    sets: u32,
    #[comptime] width: usize,
    #[comptime] axes: usize,
    #[comptime] lo_at: usize,
    #[comptime] hi_at: usize,
    #[comptime] axis_step: usize,
) {
    let kk = k as usize;
    let steps = (kk + STEP - 1) / STEP;
    let idx = ABSOLUTE_POS;
    if idx >= steps * sets as usize {
        terminate!();
    }
    let set = idx / steps;
    let first = (idx % steps) * STEP;
    let end = usize::min(first + STEP, kk);
    let mut lo = Array::<f32>::new(axes);
    let mut hi = Array::<f32>::new(axes);
    for a in 0..axes {
        lo[a] = EMPTY_LO;
        hi[a] = -EMPTY_LO;
    }
    for j in first..end {
        let o = (set * kk + j) * width;
        let mut live = true;
        for a in 0..axes {
            if !(records[o + lo_at + a * axis_step] < records[o + hi_at + a * axis_step]) {
                live = false;
            }
        }
        if live {
            for a in 0..axes {
                lo[a] = f32::min(lo[a], records[o + lo_at + a * axis_step]);
                hi[a] = f32::max(hi[a], records[o + hi_at + a * axis_step]);
            }
        }
    }
    for a in 0..axes {
        out[(idx * axes + a) * 2] = lo[a];
        out[(idx * axes + a) * 2 + 1] = hi[a];
    }
}

/// Where a record kind keeps its box, for [`step_bounds`].
#[derive(Clone, Copy)]
struct BoxLayout {
    width: usize,
    axes: usize,
    lo_at: usize,
    hi_at: usize,
    axis_step: usize,
}

/// Projection records: `[x0, x1, y0, y1]` at 6..10.
const PROJECT_BOXES: BoxLayout = BoxLayout {
    width: PREPARED_WIDTH,
    axes: 2,
    lo_at: 6,
    hi_at: 7,
    axis_step: 2,
};

/// Exact projection records: `[x0, x1, y0, y1]` at [`EX_BOX`].
const EXACT_BOXES: BoxLayout = BoxLayout {
    width: EX_WIDTH,
    axes: 2,
    lo_at: EX_BOX,
    hi_at: EX_BOX + 1,
    axis_step: 2,
};

/// Voxel records: `lo` at 12..15, `hi` at 15..18.
const VOXEL_BOXES: BoxLayout = BoxLayout {
    width: voxelize::VOX_WIDTH,
    axes: 3,
    lo_at: 12,
    hi_at: 15,
    axis_step: 1,
};

/// Launch [`step_bounds_kernel`] over `records` (`sets · k` records of `layout`).
fn step_bounds(records: &CubeTensor, k: usize, sets: usize, layout: BoxLayout) -> CubeTensor {
    let steps = k.div_ceil(STEP);
    let out = zeros(records, vec![sets, steps, layout.axes, 2]);
    let (count, dim) = linear(sets * steps);
    step_bounds_kernel::launch(
        &records.client,
        count,
        dim,
        records.clone().into_tensor_arg(),
        out.clone().into_tensor_arg(),
        k as u32,
        sets as u32,
        layout.width,
        layout.axes,
        layout.lo_at,
        layout.hi_at,
        layout.axis_step,
    );
    out
}

/// Cameras as `[V · CAM_WIDTH]` f32: rotation (row-major), translation, fx, fy, cx, cy, sdd,
/// cone flag, rows, cols.
pub fn pack_cameras(cams: &[Camera]) -> Vec<f32> {
    let mut out = Vec::with_capacity(cams.len() * CAM_WIDTH);
    for c in cams {
        out.extend(c.rotation.iter().flatten().map(|&v| v as f32));
        out.extend(c.translation.iter().map(|&v| v as f32));
        out.extend([c.fx, c.fy, c.cx, c.cy, c.sdd].map(|v| v as f32));
        out.push(if c.projection == Projection::Cone {
            1.0
        } else {
            0.0
        });
        out.extend([c.rows as f32, c.cols as f32]);
    }
    out
}

fn upload(like: &CubeTensor, values: Vec<f32>) -> CubeTensor {
    let n = values.len();
    CubeBackend::float_from_data(TensorData::new(values, [n]), &like.device)
}

fn zeros(like: &CubeTensor, shape: Vec<usize>) -> CubeTensor {
    zeros_client(
        like.client.clone(),
        like.device.clone(),
        Shape::from(shape),
        DType::F32,
    )
}

fn dims(t: &CubeTensor) -> Vec<usize> {
    t.meta.shape().to_vec()
}

/// One unit per item, 256-unit cubes.
fn linear(n: usize) -> (CubeCount, CubeDim) {
    let n = u32::try_from(n).expect("kernel item count fits in u32");
    (
        CubeCount::Static(n.div_ceil(CHUNK as u32).max(1), 1, 1),
        CubeDim::new_1d(CHUNK as u32),
    )
}

/// The four Gaussian parameter tensors made contiguous.
struct Params {
    means: CubeTensor,
    scales: CubeTensor,
    rotations: CubeTensor,
    densities: CubeTensor,
    k: usize,
    m: usize,
}

impl Params {
    fn new(
        means: CubeTensor,
        scales: CubeTensor,
        rotations: CubeTensor,
        densities: CubeTensor,
    ) -> Self {
        let k = dims(&means)[0];
        let m = dims(&densities)[1];
        Self {
            means: into_contiguous(means),
            scales: into_contiguous(scales),
            rotations: into_contiguous(rotations),
            densities: into_contiguous(densities),
            k,
            m,
        }
    }
}

fn grid_record(grid: &VoxelGrid) -> Vec<f32> {
    let mut v: Vec<f32> = grid.dims.iter().map(|&n| n as f32).collect();
    v.extend(grid.voxel.iter().map(|&x| x as f32));
    v.extend(grid.offset.iter().map(|&x| x as f32));
    v
}

fn voxel_prepare(p: &Params, grid: &CubeTensor, options: &VoxelizeOptions) -> CubeTensor {
    let out = zeros(&p.means, vec![p.k, voxelize::VOX_WIDTH]);
    let (count, dim) = linear(p.k);
    voxelize::prepare_kernel::launch(
        &p.means.client,
        count,
        dim,
        p.means.clone().into_tensor_arg(),
        p.scales.clone().into_tensor_arg(),
        p.rotations.clone().into_tensor_arg(),
        p.densities.clone().into_tensor_arg(),
        grid.clone().into_tensor_arg(),
        out.clone().into_tensor_arg(),
        p.k as u32,
        options.cutoff as f32,
        p.m,
    );
    out
}

impl crate::ops::GaussianOps for CubeBackend {
    fn gaussian_project_prepare(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let p = Params::new(means, scales, rotations, densities);
        let exact = options.mode == ProjectionMode::Exact;
        let width = if exact { EX_WIDTH } else { PREPARED_WIDTH };
        let out = zeros(&p.means, vec![cameras.len(), p.k, width]);
        let Some(first) = cameras.first() else {
            return out;
        };
        if p.k == 0 {
            return out;
        }
        let cams = upload(&p.means, pack_cameras(&cameras));
        let (count, dim) = linear(p.k * cameras.len());
        if exact {
            project::prepare_exact_kernel::launch(
                &p.means.client,
                count,
                dim,
                p.means.clone().into_tensor_arg(),
                p.scales.into_tensor_arg(),
                p.rotations.into_tensor_arg(),
                p.densities.into_tensor_arg(),
                into_contiguous(screen).into_tensor_arg(),
                cams.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                p.k as u32,
                cameras.len() as u32,
                first.rows as u32,
                first.cols as u32,
                options.cutoff as f32,
                p.m,
            );
            return out;
        }
        project::prepare_kernel::launch(
            &p.means.client,
            count,
            dim,
            p.means.clone().into_tensor_arg(),
            p.scales.into_tensor_arg(),
            p.rotations.into_tensor_arg(),
            p.densities.into_tensor_arg(),
            into_contiguous(screen).into_tensor_arg(),
            cams.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            p.k as u32,
            cameras.len() as u32,
            first.rows as u32,
            first.cols as u32,
            options.cutoff as f32,
            options.near_fraction as f32,
            p.m,
        );
        out
    }

    fn gaussian_project(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
    ) -> FloatTensor<Self> {
        let _ = (scales, rotations, screen);
        let exact = options.mode == ProjectionMode::Exact;
        let k = dims(&means)[0];
        let m = dims(&densities)[1];
        let (rows, cols) = cameras.first().map_or((0, 0), |c| (c.rows, c.cols));
        let out = zeros(&means, vec![cameras.len(), m, rows, cols]);
        if k == 0 || m == 0 || rows == 0 || cols == 0 {
            return out;
        }
        let prepared = into_contiguous(prepared);
        let layout = if exact { EXACT_BOXES } else { PROJECT_BOXES };
        let bounds = step_bounds(&prepared, k, cameras.len(), layout);
        let cams = upload(&means, pack_cameras(&cameras));
        let count = CubeCount::Static(
            (cols as u32).div_ceil(TILE),
            (rows as u32).div_ceil(TILE),
            cameras.len() as u32,
        );
        project::forward_kernel::launch(
            &means.client,
            count,
            CubeDim::new_2d(TILE, TILE),
            prepared.into_tensor_arg(),
            bounds.into_tensor_arg(),
            into_contiguous(densities).into_tensor_arg(),
            cams.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            k as u32,
            rows as u32,
            cols as u32,
            (options.cutoff * options.cutoff) as f32,
            m,
            exact,
        );
        out
    }

    fn gaussian_project_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen: FloatTensor<Self>,
        prepared: FloatTensor<Self>,
        cameras: Vec<Camera>,
        options: ProjectOptions,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        let p = Params::new(means, scales, rotations, densities);
        let (k, m) = (p.k, p.m);
        let v = cameras.len();
        let g = (
            zeros(&p.means, vec![k, 3]),
            zeros(&p.means, vec![k, 3]),
            zeros(&p.means, vec![k, 4]),
            zeros(&p.means, vec![k, m]),
            zeros(&p.means, vec![v, k, 2]),
        );
        let Some(first) = cameras.first() else {
            return g;
        };
        if k == 0 || m == 0 || first.rows == 0 || first.cols == 0 {
            return g;
        }
        let cams = upload(&p.means, pack_cameras(&cameras));
        let (count, dim) = linear(k);
        if options.mode == ProjectionMode::Exact {
            project::backward_exact_kernel::launch(
                &p.means.client,
                count,
                dim,
                p.means.clone().into_tensor_arg(),
                p.scales.into_tensor_arg(),
                p.rotations.into_tensor_arg(),
                p.densities.into_tensor_arg(),
                into_contiguous(screen).into_tensor_arg(),
                cams.into_tensor_arg(),
                into_contiguous(prepared).into_tensor_arg(),
                into_contiguous(grad).into_tensor_arg(),
                g.0.clone().into_tensor_arg(),
                g.1.clone().into_tensor_arg(),
                g.2.clone().into_tensor_arg(),
                g.3.clone().into_tensor_arg(),
                g.4.clone().into_tensor_arg(),
                k as u32,
                v as u32,
                first.rows as u32,
                first.cols as u32,
                options.cutoff as f32,
                m,
            );
            return g;
        }
        project::backward_kernel::launch(
            &p.means.client,
            count,
            dim,
            p.means.clone().into_tensor_arg(),
            p.scales.into_tensor_arg(),
            p.rotations.into_tensor_arg(),
            p.densities.into_tensor_arg(),
            into_contiguous(screen).into_tensor_arg(),
            cams.into_tensor_arg(),
            into_contiguous(prepared).into_tensor_arg(),
            into_contiguous(grad).into_tensor_arg(),
            g.0.clone().into_tensor_arg(),
            g.1.clone().into_tensor_arg(),
            g.2.clone().into_tensor_arg(),
            g.3.clone().into_tensor_arg(),
            g.4.clone().into_tensor_arg(),
            k as u32,
            v as u32,
            first.rows as u32,
            first.cols as u32,
            options.cutoff as f32,
            options.near_fraction as f32,
            m,
        );
        g
    }

    fn gaussian_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
    ) -> FloatTensor<Self> {
        let p = Params::new(means, scales, rotations, densities);
        let [nx, ny, nz] = grid.dims;
        let out = zeros(&p.means, vec![p.m, nz, ny, nx]);
        if p.k == 0 || p.m == 0 || grid.is_empty() {
            return out;
        }
        let grid_t = upload(&p.means, grid_record(&grid));
        let prepared = voxel_prepare(&p, &grid_t, &options);
        let bounds = step_bounds(&prepared, p.k, 1, VOXEL_BOXES);
        let count = CubeCount::Static(
            (nx as u32).div_ceil(voxelize::BX),
            (ny as u32).div_ceil(voxelize::BY),
            (nz as u32).div_ceil(voxelize::BZ),
        );
        voxelize::forward_kernel::launch(
            &p.means.client,
            count,
            CubeDim::new_3d(voxelize::BX, voxelize::BY, voxelize::BZ),
            prepared.into_tensor_arg(),
            bounds.into_tensor_arg(),
            p.densities.into_tensor_arg(),
            grid_t.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            p.k as u32,
            (options.cutoff * options.cutoff) as f32,
            p.m,
        );
        out
    }

    fn gaussian_voxelize_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        options: VoxelizeOptions,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    ) {
        let p = Params::new(means, scales, rotations, densities);
        let (k, m) = (p.k, p.m);
        let g = (
            zeros(&p.means, vec![k, 3]),
            zeros(&p.means, vec![k, 3]),
            zeros(&p.means, vec![k, 4]),
            zeros(&p.means, vec![k, m]),
        );
        if k == 0 || m == 0 || grid.is_empty() {
            return g;
        }
        let grid_t = upload(&p.means, grid_record(&grid));
        let prepared = voxel_prepare(&p, &grid_t, &options);
        let (count, dim) = linear(k);
        voxelize::backward_kernel::launch(
            &p.means.client,
            count,
            dim,
            p.means.clone().into_tensor_arg(),
            p.scales.into_tensor_arg(),
            p.rotations.into_tensor_arg(),
            p.densities.into_tensor_arg(),
            grid_t.into_tensor_arg(),
            prepared.into_tensor_arg(),
            into_contiguous(grad).into_tensor_arg(),
            g.0.clone().into_tensor_arg(),
            g.1.clone().into_tensor_arg(),
            g.2.clone().into_tensor_arg(),
            g.3.clone().into_tensor_arg(),
            k as u32,
            (options.cutoff * options.cutoff) as f32,
            m,
        );
        g
    }
}
