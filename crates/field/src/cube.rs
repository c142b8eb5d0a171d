//! CubeCL kernels of the hash-grid encoder for Burn's `CubeBackend` (wgpu; lavapipe without a
//! GPU). One unit per (point, level); the same indexing as [`crate::grid`] and the same clamping
//! as [`crate::cpu`].
//!
//! The backward scatter-adds into the table with `Atomic<f32>::fetch_add`: rows are shared by many
//! points (hash collisions included), so a gather formulation would have to search every point.
//! Devices without f32 atomic add (WebGPU in browsers) are refused with a message. Float atomics
//! add in an unspecified order, so gradients agree with the CPU's to rounding, not bit for bit.

// Kernels reject NaN through negated comparisons; CubeCL has no `div_ceil`.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::manual_div_ceil)]

use burn::backend::tensor::FloatTensor;
use burn_cubecl::cubecl;
use burn_cubecl::{CubeBackend, kernel::into_contiguous};
use cubecl::prelude::*;
use prism_kernel::cube::{linear, supports_f32_atomic_add, upload, zeros};

use crate::grid::{HashGrid, PRIMES};
use crate::mlp::{MlpLayout, by_ops};
use crate::ops::FieldOps;

/// Units per cube.
const CUBE: u32 = 256;
/// Floats per level record: scale, vertices per axis, dense flag.
const LEVEL_WIDTH: usize = 3;

/// The first table row of level `l` (the sizes of the levels before it).
#[cube]
fn level_offset(levels: &Tensor<f32>, l: usize, cap: u32) -> u32 {
    let mut offset = 0u32;
    for j in 0..l {
        let res = u32::cast_from(levels[j * LEVEL_WIDTH + 1]);
        if levels[j * LEVEL_WIDTH + 2] > 0.5f32 {
            offset += res * res * res;
        } else {
            offset += cap;
        }
    }
    offset
}

/// One axis of a point: the lower cell vertex and the fraction above it.
#[cube]
fn axis(x: f32, scale: f32, res: u32) -> (u32, f32) {
    let mut v = x;
    // Non-finite coordinates read as 0 (the comparison is false for ±∞ and NaN; `x − x == 0`
    // is folded away by shader compilers), then clamp to [0, 1].
    if !(f32::abs(v) <= 3.0e38f32) {
        v = 0.0f32;
    }
    v = f32::clamp(v, 0.0f32, 1.0f32);
    let pos = v * scale + 0.5f32;
    let c = u32::min(u32::cast_from(f32::floor(pos)), res - 2);
    (c, pos - f32::cast_from(c))
}

/// Vertex `(i, j, k)`'s row within its level.
#[cube]
fn vertex_row(i: u32, j: u32, k: u32, res: u32, dense: bool, cap: u32) -> u32 {
    let hashed = (i ^ (j * PRIMES[0]) ^ (k * PRIMES[1])) & (cap - 1);
    select(dense, i + res * (j + res * k), hashed)
}

/// Point `i`'s cell on level `l`: its lower vertex, the fractions above it, and the level.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
struct Cell {
    cx: u32,
    cy: u32,
    cz: u32,
    fx: f32,
    fy: f32,
    fz: f32,
    offset: u32,
    res: u32,
    dense: bool,
}

#[cube]
fn locate(points: &Tensor<f32>, levels: &Tensor<f32>, i: usize, l: usize, cap: u32) -> Cell {
    let scale = levels[l * LEVEL_WIDTH];
    let res = u32::cast_from(levels[l * LEVEL_WIDTH + 1]);
    let (cx, fx) = axis(points[3 * i], scale, res);
    let (cy, fy) = axis(points[3 * i + 1], scale, res);
    let (cz, fz) = axis(points[3 * i + 2], scale, res);
    Cell {
        cx,
        cy,
        cz,
        fx,
        fy,
        fz,
        offset: level_offset(levels, l, cap),
        res,
        dense: levels[l * LEVEL_WIDTH + 2] > 0.5f32,
    }
}

/// Corner `c` of `cell` (bit a of c set: +1 on axis a): its table row and trilinear weight.
#[cube]
fn corner(cell: Cell, c: u32, cap: u32) -> (usize, f32) {
    let (ux, uy, uz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
    let w = select(ux == 1, cell.fx, 1.0f32 - cell.fx)
        * select(uy == 1, cell.fy, 1.0f32 - cell.fy)
        * select(uz == 1, cell.fz, 1.0f32 - cell.fz);
    let (i, j, k) = (cell.cx + ux, cell.cy + uy, cell.cz + uz);
    let row = cell.offset + vertex_row(i, j, k, cell.res, cell.dense, cap);
    (row as usize, w)
}

/// The encoding's forward (`out` zeroed by the host): one unit per (point, level).
#[cube(launch)]
fn encode_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    levels: &Tensor<f32>,
    out: &mut Tensor<f32>,
    n: u32,
    n_levels: u32,
    cap: u32,
    #[comptime] features: usize,
) {
    let idx = ABSOLUTE_POS;
    let nl = n_levels as usize;
    if idx >= n as usize * nl {
        terminate!();
    }
    let (i, l) = (idx / nl, idx % nl);
    let cell = locate(points, levels, i, l, cap);
    let base = i * nl * features + l * features;
    for c in 0..8u32 {
        let (row, w) = corner(cell, c, cap);
        #[unroll]
        for f in 0..features {
            out[base + f] += w * table[row * features + f];
        }
    }
}

/// The table's gradient: scatter-add of `grad` through the same weights (`out` zeroed).
#[cube(launch)]
fn encode_backward_kernel(
    points: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<f32>,
    out: &mut Tensor<Atomic<f32>>,
    n: u32,
    n_levels: u32,
    cap: u32,
    #[comptime] features: usize,
) {
    let idx = ABSOLUTE_POS;
    let nl = n_levels as usize;
    if idx >= n as usize * nl {
        terminate!();
    }
    let (i, l) = (idx / nl, idx % nl);
    let cell = locate(points, levels, i, l, cap);
    let base = i * nl * features + l * features;
    for c in 0..8u32 {
        let (row, w) = corner(cell, c, cap);
        #[unroll]
        for f in 0..features {
            let g = grad[base + f];
            if g != 0.0f32 {
                out[row * features + f].fetch_add(w * g);
            }
        }
    }
}

/// Levels as `[L · LEVEL_WIDTH]` floats (exact: dense levels have `res³ ≤ 2^24`).
fn pack_levels(grid: &HashGrid) -> Vec<f32> {
    grid.levels
        .iter()
        .flat_map(|l| [l.scale, l.res as f32, if l.dense { 1.0 } else { 0.0 }])
        .collect()
}

/// The hashed levels' table size (dense levels only: any power of two; unused).
fn hash_cap(grid: &HashGrid) -> u32 {
    grid.levels
        .iter()
        .find(|l| !l.dense)
        .map_or(1 << 24, |l| l.size)
}

impl FieldOps for CubeBackend {
    fn hash_grid_encode(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: HashGrid,
    ) -> FloatTensor<Self> {
        let (points, table) = (into_contiguous(points), into_contiguous(table));
        let n = points.meta.shape()[0];
        let out = zeros(&points, vec![n, grid.width()]);
        if n == 0 {
            return out;
        }
        let levels = upload(&points, pack_levels(&grid));
        let (count, dim) = linear(n * grid.levels.len(), CUBE);
        encode_kernel::launch(
            &points.client.clone(),
            count,
            dim,
            points.into_tensor_arg(),
            table.into_tensor_arg(),
            levels.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            n as u32,
            grid.levels.len() as u32,
            hash_cap(&grid),
            grid.features,
        );
        out
    }

    fn hash_grid_encode_backward(
        points: FloatTensor<Self>,
        grid: HashGrid,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let (points, grad) = (into_contiguous(points), into_contiguous(grad));
        let n = points.meta.shape()[0];
        let out = zeros(&points, vec![grid.rows(), grid.features]);
        if n == 0 {
            return out;
        }
        assert!(
            supports_f32_atomic_add(&points),
            "the hash-grid encoder's backward needs f32 atomic add, which this wgpu device does \
             not offer (train NAF on the CPU)"
        );
        let levels = upload(&points, pack_levels(&grid));
        let (count, dim) = linear(n * grid.levels.len(), CUBE);
        encode_backward_kernel::launch(
            &points.client.clone(),
            count,
            dim,
            points.into_tensor_arg(),
            grad.into_tensor_arg(),
            levels.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            n as u32,
            grid.levels.len() as u32,
            hash_cap(&grid),
            grid.features,
        );
        out
    }

    fn field_mlp(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
    ) -> FloatTensor<Self> {
        by_ops::forward::<Self>(&layout, enc, params)
    }

    fn field_mlp_backward(
        enc: FloatTensor<Self>,
        params: FloatTensor<Self>,
        layout: MlpLayout,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        by_ops::backward::<Self>(&layout, enc, params, grad)
    }
}
