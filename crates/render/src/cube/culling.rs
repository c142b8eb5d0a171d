//! Culling shared by the forward kernels: the compaction of one culling step's hits in index
//! order ([`stage_chunk`]), and the union box of each step's records ([`step_bounds_kernel`]), so
//! that a cube skips whole steps that miss its tile or brick.

use burn_cubecl::cubecl;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::host::{linear, zeros};
use super::{exact, project, voxelize};

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
pub fn step_bounds_kernel(
    records: &Tensor<f32>,
    out: &mut Tensor<f32>,
    k: u32,
    sets: u32,
    #[comptime] layout: BoxLayout,
) {
    let width = comptime![layout.width];
    let axes = comptime![layout.axes];
    let lo_at = comptime![layout.lo_at];
    let hi_at = comptime![layout.hi_at];
    let axis_step = comptime![layout.axis_step];
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

/// Where a record kind keeps its box, for [`step_bounds_kernel`] (a compile-time argument: one
/// kernel per record kind). Offsets in floats from the start of a record.
#[derive(Clone, Copy, Debug, Hash, PartialEq, Eq)]
pub struct BoxLayout {
    /// Floats per record.
    pub width: usize,
    /// Box axes (2 for pixel boxes, 3 for voxel boxes).
    pub axes: usize,
    /// Offset of the first axis's low end.
    pub lo_at: usize,
    /// Offset of the first axis's high end.
    pub hi_at: usize,
    /// Offset from one axis's end to the next axis's.
    pub axis_step: usize,
}

/// Affine projection records ([`AffineRecord`](super::project::AffineRecord)): `[x0, x1, y0, y1]`.
pub(super) const AFFINE_BOXES: BoxLayout = BoxLayout {
    width: project::AFFINE_WIDTH,
    axes: 2,
    lo_at: project::AFFINE_BOX,
    hi_at: project::AFFINE_BOX + 1,
    axis_step: 2,
};

/// Exact projection records ([`ExactRecord`](super::exact::ExactRecord)): `[x0, x1, y0, y1]`.
pub(super) const EXACT_BOXES: BoxLayout = BoxLayout {
    width: exact::EXACT_WIDTH,
    axes: 2,
    lo_at: exact::EXACT_BOX,
    hi_at: exact::EXACT_BOX + 1,
    axis_step: 2,
};

/// Voxel records ([`VoxelRecord`](super::voxelize::VoxelRecord)): `lo` (3), then `hi` (3).
pub(super) const VOXEL_BOXES: BoxLayout = BoxLayout {
    width: voxelize::VOXEL_WIDTH,
    axes: 3,
    lo_at: voxelize::VOXEL_LO,
    hi_at: voxelize::VOXEL_HI,
    axis_step: 1,
};

/// Launch [`step_bounds_kernel`] over `records` (`sets · k` records of `layout`).
pub(super) fn step_bounds(
    records: &CubeTensor,
    k: usize,
    sets: usize,
    layout: BoxLayout,
) -> CubeTensor {
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
        layout,
    );
    out
}
