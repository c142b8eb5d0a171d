//! NAF's MLP as one op (forward and hand-written backward), so a CPU iteration runs it as two
//! fused passes over the points instead of Burn's dozen tensor-wide ones.
//!
//! The parameters travel packed in one vector, layer after layer: the weight `[d_in, d_out]`
//! (row-major, Burn's `Linear` layout: `y = x·W + b`) then the bias `[d_out]`. Hidden layers
//! apply LeakyReLU (`x < 0 ↦ slope·x`, Burn's definition, derivative `slope` below 0 and 1
//! from 0 on); the skip layer's input is the previous activation followed by the encoding; the
//! last layer is linear with one output.
//!
//! CPU ([`cpu_forward`], [`cpu_backward`]): tasks of [`TASK`] points on rayon. The backward
//! recomputes its task's forward (the activations of 512 points stay in cache, none is stored
//! between the passes); each worker reuses one `Scratch` for all its tasks. Every product is
//! computed in tiles held in registers over its whole input (`tile`: 2 rows × 32 outputs,
//! 4 × 8 or 8 × 1 on narrower layers). A tile's rows share each load of the other operand and
//! keep 8 independent add chains in flight, and each output is summed in input order, compiled
//! for AVX2 where the CPU has it (no fused multiply-add, so the results are the same without
//! it). Each task's parameter gradient is summed in task order, so results do not depend on
//! the thread count either. Other backends
//! ([`by_ops`]) compose the same function from their own tensor ops.

pub mod by_ops;

use prism_kernel::cpu::sum_partials;
use rayon::prelude::*;

/// Points per parallel task.
pub const TASK: usize = 512;

/// The MLP's shape: encoding width `input`, hidden `width`, `layers` linear layers (the output
/// layer included), the layer `skip` whose input gets the encoding appended, LeakyReLU `slope`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MlpLayout {
    pub input: usize,
    pub width: usize,
    pub layers: usize,
    pub skip: usize,
    pub slope: f32,
}

impl MlpLayout {
    /// The first of layer `l`'s input rows that hold the encoding: 0 for the first layer (its
    /// whole input), `width` for the skip layer (after the previous activation), none for the
    /// other layers.
    pub fn encoding_rows(&self, l: usize) -> Option<usize> {
        match l {
            0 => Some(0),
            l if l == self.skip => Some(self.width),
            _ => None,
        }
    }

    /// Inputs of layer `l`: the previous activation (not the first layer's), then the
    /// encoding where the layer reads it.
    pub fn d_in(&self, l: usize) -> usize {
        let previous = if l == 0 { 0 } else { self.width };
        previous + self.encoding_rows(l).map_or(0, |_| self.input)
    }

    /// Outputs of layer `l`.
    pub fn d_out(&self, l: usize) -> usize {
        if l + 1 == self.layers { 1 } else { self.width }
    }

    /// Where layer `l`'s weight and bias start in the packed parameters.
    pub fn offsets(&self, l: usize) -> (usize, usize) {
        let start: usize = (0..l).map(|j| (self.d_in(j) + 1) * self.d_out(j)).sum();
        (start, start + self.d_in(l) * self.d_out(l))
    }

    /// Length of the packed parameters.
    pub fn params(&self) -> usize {
        self.offsets(self.layers).0
    }

    /// LeakyReLU as a product with its slope (`z · 1 = z` exactly), which compiles to a
    /// select instead of a branch on the sign.
    fn leaky(&self, z: f32) -> f32 {
        z * self.leaky_slope(z)
    }

    fn leaky_slope(&self, z: f32) -> f32 {
        if z < 0.0 { self.slope } else { 1.0 }
    }
}

/// Defines `fn $name(args..)` that runs the task `$task` (`#[inline(always)]`, so its whole
/// body is compiled into both variants) compiled for AVX2 where the kernels' run-time choice
/// allows the wide variants ([`prism_kernel::simd::has_avx2_fma`], which tests and benchmarks
/// can turn off), else for the build's baseline. Only AVX2 is enabled, not FMA: the same
/// operations in the same order, so the results are identical either way.
macro_rules! on_best_simd {
    (fn $name:ident => $task:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?) => {
        fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2")]
            fn wide($($arg: $ty),*) $(-> $ret)? {
                $task($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            if prism_kernel::simd::has_avx2_fma() {
                // SAFETY: `has_avx2_fma` confirmed that the CPU has AVX2 (and FMA).
                return unsafe { wide($($arg),*) };
            }
            $task($($arg),*)
        }
    };
}

on_best_simd!(fn forward_best => forward_task(
    layout: &MlpLayout,
    enc: &[f32],
    params: &[f32],
    out: &mut [f32],
    scratch: &mut Scratch,
));

on_best_simd!(fn backward_best => backward_task(
    layout: &MlpLayout,
    transposed: &[Vec<f32>],
    enc: &[f32],
    params: &[f32],
    grad: &[f32],
    d_enc: &mut [f32],
    scratch: &mut Scratch,
) -> Vec<f32>);

/// Outputs per wide register block: 32 accumulators, four AVX (eight SSE) registers; narrower
/// layers use blocks of 8, then scalars.
const WIDE: usize = 32;
const NARROW: usize = 8;

/// The output blocks `(j0, B)` of a row of `d_out`: wide ones, narrow ones, and the scalar
/// rest as blocks of one.
#[inline(always)]
fn blocks(d_out: usize) -> impl Iterator<Item = (usize, usize)> {
    let wide = d_out / WIDE * WIDE;
    let narrow = wide + (d_out - wide) / NARROW * NARROW;
    (0..wide)
        .step_by(WIDE)
        .map(|j| (j, WIDE))
        .chain((wide..narrow).step_by(NARROW).map(|j| (j, NARROW)))
        .chain((narrow..d_out).map(|j| (j, 1)))
}

/// `acc[r][t] += Σ_s x[r][s·x_stride] · w[s·w_stride + t]` for `s < n`, `t < B`, `r < R`: a
/// tile of `R` rows × `B` outputs held in registers over a whole sum. The rows share each load
/// of `w`, and the tile keeps `R·B` independent add chains in flight (one row alone waits on
/// its adds' latency). Each output is summed in `s` order whatever `R` is.
#[inline(always)]
fn tile<const B: usize, const R: usize>(
    acc: &mut [[f32; B]; R],
    n: usize,
    x: [&[f32]; R],
    x_stride: usize,
    w: &[f32],
    w_stride: usize,
) {
    let mut a = *acc;
    for s in 0..n {
        let ws: &[f32; B] = w[s * w_stride..s * w_stride + B]
            .try_into()
            .expect("a block");
        for (a, x) in a.iter_mut().zip(&x) {
            let xs = x[s * x_stride];
            for (a, &wv) in a.iter_mut().zip(ws) {
                *a += xs * wv;
            }
        }
    }
    *acc = a;
}

/// The accumulator tile of rows `r0 + r` (each `row` floats apart), outputs `j0..j0 + B`.
#[inline(always)]
fn load<const B: usize, const R: usize>(
    out: &[f32],
    r0: usize,
    row: usize,
    j0: usize,
) -> [[f32; B]; R] {
    std::array::from_fn(|r| {
        let at = (r0 + r) * row + j0;
        out[at..at + B].try_into().expect("a block")
    })
}

/// Writes a tile back where [`load`] read it.
#[inline(always)]
fn store<const B: usize, const R: usize>(
    out: &mut [f32],
    r0: usize,
    row: usize,
    j0: usize,
    tile: &[[f32; B]; R],
) {
    for (r, t) in tile.iter().enumerate() {
        let at = (r0 + r) * row + j0;
        out[at..at + B].copy_from_slice(t);
    }
}

/// The left operand of a [`product`]: its row `r` starts at `r · row` and holds `n` values
/// `stride` apart. A row-major `[m, d]` matrix read by rows is `row = d`, `stride = 1`; read by
/// columns (its transpose), `row = 1`, `stride = d`.
#[derive(Clone, Copy)]
struct Rows<'a> {
    values: &'a [f32],
    row: usize,
    stride: usize,
}

impl<'a> Rows<'a> {
    /// The rows of a row-major matrix `d` wide.
    fn of(values: &'a [f32], d: usize) -> Self {
        Rows {
            values,
            row: d,
            stride: 1,
        }
    }

    /// The columns of a row-major matrix `cols` wide, as rows.
    fn columns(values: &'a [f32], cols: usize) -> Self {
        Rows {
            values,
            row: 1,
            stride: cols,
        }
    }
}

/// `out[r][j] += Σ_{s < n} x_r[s] · w[s][j]` for every row `r` of `out` `[rows, d_out]`, with
/// `w` `[n, d_out]` row-major: each block of outputs in tiles of 2 × 32, 4 × 8 or 8 × 1, then
/// the rows left over one at a time. Layers use it for `z += a · W`, the input gradient
/// `dx = dz · Wᵀ` (`w` the transposed weight) and the weight gradient `dW += aᵀ · dz` (`x` the
/// activations read by columns).
#[inline(always)]
fn product(out: &mut [f32], d_out: usize, x: Rows, n: usize, w: &[f32]) {
    #[inline(always)]
    fn tile_at<const B: usize, const R: usize>(
        out: &mut [f32],
        d_out: usize,
        j0: usize,
        r0: usize,
        x: Rows,
        n: usize,
        w: &[f32],
    ) {
        let mut t = load::<B, R>(out, r0, d_out, j0);
        let xs = std::array::from_fn(|r| &x.values[(r0 + r) * x.row..]);
        tile(&mut t, n, xs, x.stride, &w[j0..], d_out);
        store(out, r0, d_out, j0, &t);
    }
    #[inline(always)]
    fn tiles<const B: usize, const R: usize>(
        out: &mut [f32],
        d_out: usize,
        j0: usize,
        x: Rows,
        n: usize,
        w: &[f32],
    ) {
        let rows = out.len() / d_out;
        let mut r0 = 0;
        while r0 + R <= rows {
            tile_at::<B, R>(out, d_out, j0, r0, x, n, w);
            r0 += R;
        }
        for r0 in r0..rows {
            tile_at::<B, 1>(out, d_out, j0, r0, x, n, w);
        }
    }
    for (j0, b) in blocks(d_out) {
        match b {
            WIDE => tiles::<WIDE, 2>(out, d_out, j0, x, n, w),
            NARROW => tiles::<NARROW, 4>(out, d_out, j0, x, n, w),
            _ => tiles::<1, 8>(out, d_out, j0, x, n, w),
        }
    }
}

/// A task's pre-activations `z[l]` `[n, d_out(l)]` and hidden activations `a[l]` `[n, width]`,
/// and the backward's layer gradients `dz` and `dx`: buffers a worker reuses task after task.
#[derive(Default)]
struct Scratch {
    z: Vec<Vec<f32>>,
    a: Vec<Vec<f32>>,
    dz: Vec<f32>,
    dx: Vec<f32>,
}

/// `buffer` holding `len` values, its contents unspecified (every caller writes before reading).
fn sized(buffer: &mut Vec<f32>, len: usize) -> &mut [f32] {
    buffer.resize(len, 0.0);
    &mut buffer[..len]
}

impl Scratch {
    /// The forward pass of `n` points with encodings `enc` `[n, input]`, into `z` and `a`.
    #[inline(always)]
    fn run(&mut self, layout: &MlpLayout, enc: &[f32], params: &[f32]) {
        let (e, width) = (layout.input, layout.width);
        let n = enc.len() / e;
        self.z.resize_with(layout.layers, Vec::new);
        self.a.resize_with(layout.layers - 1, Vec::new);
        for l in 0..layout.layers {
            let d_out = layout.d_out(l);
            let (wo, bo) = layout.offsets(l);
            let bias = &params[bo..bo + d_out];
            let z = sized(&mut self.z[l], n * d_out);
            for row in z.chunks_exact_mut(d_out) {
                row.copy_from_slice(bias);
            }
            if l > 0 {
                product(
                    z,
                    d_out,
                    Rows::of(&self.a[l - 1], width),
                    width,
                    &params[wo..],
                );
            }
            if let Some(from) = layout.encoding_rows(l) {
                product(z, d_out, Rows::of(enc, e), e, &params[wo + from * d_out..]);
            }
            if l + 1 < layout.layers {
                let a = sized(&mut self.a[l], n * d_out);
                for (a, &z) in a.iter_mut().zip(z.iter()) {
                    *a = layout.leaky(z);
                }
            }
        }
    }
}

/// The MLP's outputs `[N]` (before any output activation) at encodings `enc` `[N, input]`.
pub fn cpu_forward(layout: &MlpLayout, enc: &[f32], params: &[f32]) -> Vec<f32> {
    let e = layout.input;
    let n = enc.len() / e;
    let mut out = vec![0f32; n];
    out.par_chunks_mut(TASK)
        .zip(enc.par_chunks(TASK * e))
        .for_each_init(Scratch::default, |scratch, (out, enc)| {
            forward_best(layout, enc, params, out, scratch)
        });
    out
}

/// A task's outputs.
#[inline(always)]
fn forward_task(
    layout: &MlpLayout,
    enc: &[f32],
    params: &[f32],
    out: &mut [f32],
    scratch: &mut Scratch,
) {
    scratch.run(layout, enc, params);
    out.copy_from_slice(&scratch.z[layout.layers - 1][..out.len()]);
}

/// The gradients of `⟨grad, mlp(enc, params)⟩` (`grad` `[N]`): with respect to the encodings
/// `[N, input]` and to the packed parameters `[params]`.
pub fn cpu_backward(
    layout: &MlpLayout,
    enc: &[f32],
    params: &[f32],
    grad: &[f32],
) -> (Vec<f32>, Vec<f32>) {
    let e = layout.input;
    let n = enc.len() / e;
    // Every weight transposed once, `[d_out, d_in]`: the input gradient is then an axpy per
    // output too.
    let transposed: Vec<Vec<f32>> = (0..layout.layers)
        .map(|l| {
            let (d_in, d_out) = (layout.d_in(l), layout.d_out(l));
            let w = &params[layout.offsets(l).0..];
            let mut t = vec![0f32; d_in * d_out];
            for k in 0..d_in {
                for j in 0..d_out {
                    t[j * d_in + k] = w[k * d_out + j];
                }
            }
            t
        })
        .collect();
    let mut d_enc = vec![0f32; n * e];
    let task_params: Vec<Vec<f32>> = d_enc
        .par_chunks_mut(TASK * e)
        .zip(enc.par_chunks(TASK * e))
        .zip(grad.par_chunks(TASK))
        .map_init(Scratch::default, |scratch, ((d_enc, enc), grad)| {
            backward_best(layout, &transposed, enc, params, grad, d_enc, scratch)
        })
        .collect();
    (d_enc, sum_partials(task_params, layout.params()))
}

/// A task's gradient of the packed parameters; its encodings' gradient is added to `d_enc`.
#[inline(always)]
fn backward_task(
    layout: &MlpLayout,
    transposed: &[Vec<f32>],
    enc: &[f32],
    params: &[f32],
    grad: &[f32],
    d_enc: &mut [f32],
    scratch: &mut Scratch,
) -> Vec<f32> {
    let (e, width) = (layout.input, layout.width);
    scratch.run(layout, enc, params);
    let Scratch { z, a, dz, dx } = scratch;
    let mut d_params = vec![0f32; layout.params()];
    let m = grad.len();
    // The output layer's pre-activation gradient is `grad` itself (one output).
    sized(dz, m).copy_from_slice(grad);
    for l in (0..layout.layers).rev() {
        let (d_in, d_out) = (layout.d_in(l), layout.d_out(l));
        let (wo, bo) = layout.offsets(l);
        let dz_l = &dz[..m * d_out];
        // The weight's rows: the previous activation's, then the encoding's.
        let reads_enc = layout.encoding_rows(l);
        let (dw, db) = d_params[wo..bo + d_out].split_at_mut(bo - wo);
        let (dw_prev, dw_enc) = dw.split_at_mut(reads_enc.unwrap_or(d_in) * d_out);
        if l > 0 {
            product(dw_prev, d_out, Rows::columns(&a[l - 1], width), m, dz_l);
        }
        if reads_enc.is_some() {
            product(dw_enc, d_out, Rows::columns(enc, e), m, dz_l);
        }
        for g in dz_l.chunks_exact(d_out) {
            for (b, &v) in db.iter_mut().zip(g) {
                *b += v;
            }
        }
        // The input gradient, row by row: `dx = dz · Wᵀ`.
        let dx = sized(dx, m * d_in);
        dx.fill(0.0);
        product(dx, d_in, Rows::of(dz_l, d_out), d_out, &transposed[l]);
        if let Some(from) = reads_enc {
            for (de, row) in d_enc.chunks_exact_mut(e).zip(dx.chunks_exact(d_in)) {
                for (a, &b) in de.iter_mut().zip(&row[from..]) {
                    *a += b;
                }
            }
        }
        if l > 0 {
            let z = &z[l - 1][..m * width];
            for ((out, row), z) in sized(dz, m * width)
                .chunks_exact_mut(width)
                .zip(dx.chunks_exact(d_in))
                .zip(z.chunks_exact(width))
            {
                for ((o, &d), &z) in out.iter_mut().zip(row).zip(z) {
                    *o = d * layout.leaky_slope(z);
                }
            }
        }
    }
    d_params
}

#[cfg(test)]
mod tests;
