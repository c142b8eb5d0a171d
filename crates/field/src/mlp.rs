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
//! between the passes). Every product sums a block of 32 (or 8) outputs in registers over its
//! whole input, each output in input order, compiled for AVX2 where the CPU has it (no fused
//! multiply-add, so the results are the same without it). Each task's parameter gradient is
//! summed in task order, so results do not depend on the thread count either. Other backends
//! ([`by_ops`]) compose the same function from their own tensor ops.

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

    fn leaky(&self, z: f32) -> f32 {
        if z < 0.0 { z * self.slope } else { z }
    }

    fn leaky_slope(&self, z: f32) -> f32 {
        if z < 0.0 { self.slope } else { 1.0 }
    }
}

/// Runs a task function compiled for AVX2 where the kernels' run-time choice allows the wide
/// variants ([`prism_kernel::simd::has_avx2_fma`], which tests and benchmarks can turn off),
/// else for the build's baseline. Only AVX2 is enabled, not FMA: the same operations in the same
/// order, so the results are identical either way.
macro_rules! on_best_simd {
    ($task:ident($($arg:expr),*)) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn wide(f: impl FnOnce()) {
                f()
            }
            if prism_kernel::simd::has_avx2_fma() {
                // SAFETY: `has_avx2_fma` confirmed that the CPU has AVX2 (and FMA).
                let mut result = None;
                unsafe { wide(|| result = Some($task($($arg),*))) };
                result.expect("the task ran")
            } else {
                $task($($arg),*)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            $task($($arg),*)
        }
    }};
}

/// Outputs per wide register block: 32 accumulators, four independent AVX (eight SSE) add
/// chains, enough to hide the adds' latency; narrower layers use blocks of 8, then scalars.
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

/// `acc[t] += Σ_k x[k·x_stride] · w[k·w_stride + t]` for `k < n`, `t < B`: one block of
/// outputs held in registers over a whole sum (each output summed in `k` order).
#[inline(always)]
fn block_sum<const B: usize>(
    acc: &mut [f32],
    n: usize,
    x: &[f32],
    x_stride: usize,
    w: &[f32],
    w_stride: usize,
) {
    let mut a: [f32; B] = acc.try_into().expect("a block");
    for k in 0..n {
        let xk = x[k * x_stride];
        let wk: &[f32; B] = w[k * w_stride..k * w_stride + B]
            .try_into()
            .expect("a block");
        for (a, &wv) in a.iter_mut().zip(wk) {
            *a += xk * wv;
        }
    }
    acc.copy_from_slice(&a);
}

/// [`block_sum`] on a block of [`blocks`]' widths (`acc.len()`).
#[inline(always)]
fn block_sum_of(acc: &mut [f32], n: usize, x: &[f32], x_stride: usize, w: &[f32], w_stride: usize) {
    match acc.len() {
        WIDE => block_sum::<WIDE>(acc, n, x, x_stride, w, w_stride),
        NARROW => block_sum::<NARROW>(acc, n, x, x_stride, w, w_stride),
        _ => block_sum::<1>(acc, n, x, x_stride, w, w_stride),
    }
}

/// `out += x · w` for a row `x` `[d_in]` and `w` `[d_in, d_out]` (row-major).
#[inline(always)]
fn row_times(x: &[f32], w: &[f32], out: &mut [f32]) {
    let d_out = out.len();
    for (j0, b) in blocks(d_out) {
        block_sum_of(&mut out[j0..j0 + b], x.len(), x, 1, &w[j0..], d_out);
    }
}

/// `dw[k][j] += Σ_i x[i][k] · dz[i][j]`: a layer's weight gradient rows `dw` `[cols, d_out]`
/// over a task's `m` points, from inputs `x` `[m, cols]` (row-major) and the pre-activation
/// gradients `dz` `[m, d_out]`.
#[inline(always)]
fn input_times(x: &[f32], dz: &[f32], m: usize, dw: &mut [f32]) {
    let d_out = dz.len() / m.max(1);
    let cols = x.len() / m.max(1);
    for (k, row) in dw.chunks_exact_mut(d_out).enumerate() {
        for (j0, b) in blocks(d_out) {
            block_sum_of(&mut row[j0..j0 + b], m, &x[k..], cols, &dz[j0..], d_out);
        }
    }
}

/// A task's pre-activations `z[l]` `[n, d_out(l)]` and hidden activations `a[l]` `[n, width]`.
#[derive(Default)]
struct Pass {
    z: Vec<Vec<f32>>,
    a: Vec<Vec<f32>>,
}

impl Pass {
    /// The forward pass of `n` points with encodings `enc` `[n, input]`.
    #[inline(always)]
    fn run(layout: &MlpLayout, enc: &[f32], params: &[f32]) -> Pass {
        let (e, width) = (layout.input, layout.width);
        let n = enc.len() / e;
        let mut pass = Pass::default();
        for l in 0..layout.layers {
            let d_out = layout.d_out(l);
            let (wo, bo) = layout.offsets(l);
            let bias = &params[bo..bo + d_out];
            let mut z = vec![0f32; n * d_out];
            for (i, row) in z.chunks_exact_mut(d_out).enumerate() {
                row.copy_from_slice(bias);
                if l > 0 {
                    let prev = &pass.a[l - 1][i * width..(i + 1) * width];
                    row_times(prev, &params[wo..], row);
                }
                if let Some(from) = layout.encoding_rows(l) {
                    let enc_row = &enc[i * e..(i + 1) * e];
                    row_times(enc_row, &params[wo + from * d_out..], row);
                }
            }
            if l + 1 < layout.layers {
                pass.a.push(z.iter().map(|&v| layout.leaky(v)).collect());
            }
            pass.z.push(z);
        }
        pass
    }
}

/// The MLP's outputs `[N]` (before any output activation) at encodings `enc` `[N, input]`.
pub fn cpu_forward(layout: &MlpLayout, enc: &[f32], params: &[f32]) -> Vec<f32> {
    let e = layout.input;
    let n = enc.len() / e;
    let mut out = vec![0f32; n];
    out.par_chunks_mut(TASK)
        .zip(enc.par_chunks(TASK * e))
        .for_each(|(out, enc)| on_best_simd!(forward_task(layout, enc, params, out)));
    out
}

/// A task's outputs.
#[inline(always)]
fn forward_task(layout: &MlpLayout, enc: &[f32], params: &[f32], out: &mut [f32]) {
    let pass = Pass::run(layout, enc, params);
    out.copy_from_slice(&pass.z[layout.layers - 1]);
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
        .map(|((d_enc, enc), grad)| {
            on_best_simd!(backward_task(layout, &transposed, enc, params, grad, d_enc))
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
) -> Vec<f32> {
    let (e, width) = (layout.input, layout.width);
    let pass = Pass::run(layout, enc, params);
    let mut d_params = vec![0f32; layout.params()];
    let m = grad.len();
    // The output layer's pre-activation gradient is `grad` itself (one output).
    let mut dz = grad.to_vec();
    for l in (0..layout.layers).rev() {
        let (d_in, d_out) = (layout.d_in(l), layout.d_out(l));
        let (wo, bo) = layout.offsets(l);
        // The weight's rows: the previous activation's, then the encoding's.
        let reads_enc = layout.encoding_rows(l);
        let (dw, db) = d_params[wo..bo + d_out].split_at_mut(bo - wo);
        let (dw_prev, dw_enc) = dw.split_at_mut(reads_enc.unwrap_or(d_in) * d_out);
        if l > 0 {
            input_times(&pass.a[l - 1], &dz, m, dw_prev);
        }
        if reads_enc.is_some() {
            input_times(enc, &dz, m, dw_enc);
        }
        for g in dz.chunks_exact(d_out) {
            for (b, &v) in db.iter_mut().zip(g) {
                *b += v;
            }
        }
        // The input gradient, row by row: `dx = dz · Wᵀ`.
        let mut dx = vec![0f32; m * d_in];
        for (g, row) in dz.chunks_exact(d_out).zip(dx.chunks_exact_mut(d_in)) {
            row_times(g, &transposed[l], row);
        }
        if let Some(from) = reads_enc {
            for (de, row) in d_enc.chunks_exact_mut(e).zip(dx.chunks_exact(d_in)) {
                for (a, &b) in de.iter_mut().zip(&row[from..]) {
                    *a += b;
                }
            }
        }
        if l > 0 {
            let z = &pass.z[l - 1];
            dz = vec![0f32; m * width];
            for ((out, row), z) in dz
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

/// The same function composed from a backend's own tensor ops (the backends without a fused
/// kernel: wgpu).
pub mod by_ops {
    use super::MlpLayout;
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{Backend, TensorMetadata, get_or_init_device_settings};
    use burn::tensor::{Shape, Slice};

    type F<B> = FloatTensor<B>;

    fn range<B: Backend>(t: F<B>, start: usize, end: usize) -> F<B> {
        B::float_slice(t, &[Slice::from(start..end)])
    }

    fn columns<B: Backend>(t: F<B>, rows: usize, start: usize, end: usize) -> F<B> {
        B::float_slice(t, &[Slice::from(0..rows), Slice::from(start..end)])
    }

    /// Layer `l`'s weight `[d_in, d_out]` and bias `[1, d_out]`.
    fn layer<B: Backend>(layout: &MlpLayout, params: &F<B>, l: usize) -> (F<B>, F<B>) {
        let (d_in, d_out) = (layout.d_in(l), layout.d_out(l));
        let (wo, bo) = layout.offsets(l);
        let w = B::float_reshape(
            range::<B>(params.clone(), wo, bo),
            Shape::new([d_in, d_out]),
        );
        let b = B::float_reshape(
            range::<B>(params.clone(), bo, bo + d_out),
            Shape::new([1, d_out]),
        );
        (w, b)
    }

    fn leaky<B: Backend>(layout: &MlpLayout, z: F<B>) -> F<B> {
        B::leaky_relu(z, layout.slope.into())
    }

    /// Each layer's input and pre-activation, and the output `[N, 1]`.
    fn pass<B: Backend>(layout: &MlpLayout, enc: &F<B>, params: &F<B>) -> Vec<(F<B>, F<B>)> {
        let mut saved: Vec<(F<B>, F<B>)> = Vec::with_capacity(layout.layers);
        let mut x = enc.clone();
        for l in 0..layout.layers {
            if l > 0 {
                x = leaky::<B>(layout, saved[l - 1].1.clone());
                if layout.encoding_rows(l).is_some() {
                    x = B::float_cat(vec![x, enc.clone()], 1);
                }
            }
            let (w, b) = layer::<B>(layout, params, l);
            let z = B::float_add(B::float_matmul(x.clone(), w), b);
            saved.push((x.clone(), z));
        }
        saved
    }

    /// The outputs `[N, 1]`.
    pub fn forward<B: Backend>(layout: &MlpLayout, enc: F<B>, params: F<B>) -> F<B> {
        let mut saved = pass::<B>(layout, &enc, &params);
        saved.pop().expect("at least two layers").1
    }

    /// The gradients with respect to `enc` `[N, input]` and the packed parameters.
    pub fn backward<B: Backend>(
        layout: &MlpLayout,
        enc: F<B>,
        params: F<B>,
        grad: F<B>,
    ) -> (F<B>, F<B>) {
        let n = enc.shape()[0];
        let saved = pass::<B>(layout, &enc, &params);
        let mut dz = grad;
        let mut d_enc: Option<F<B>> = None;
        let mut pieces: Vec<F<B>> = Vec::with_capacity(2 * layout.layers);
        for l in (0..layout.layers).rev() {
            let (x, _) = &saved[l];
            let (w, _) = layer::<B>(layout, &params, l);
            let dw = B::float_matmul(B::float_transpose(x.clone()), dz.clone());
            let db = B::float_sum_dim(dz.clone(), 0);
            let size = layout.d_in(l) * layout.d_out(l);
            pieces.push(B::float_reshape(db, Shape::new([layout.d_out(l)])));
            pieces.push(B::float_reshape(dw, Shape::new([size])));
            let dx = B::float_matmul(dz, B::float_transpose(w));
            if let Some(from) = layout.encoding_rows(l) {
                let part = columns::<B>(dx.clone(), n, from, from + layout.input);
                d_enc = Some(match d_enc {
                    Some(d) => B::float_add(d, part),
                    None => part,
                });
            }
            if l == 0 {
                break;
            }
            let dx = columns::<B>(dx, n, 0, layout.width);
            let z = saved[l - 1].1.clone();
            let scaled = B::float_mul_scalar(dx.clone(), layout.slope.into());
            let bool_dtype = get_or_init_device_settings::<B>(&z.device()).bool_dtype;
            let below = B::float_lower_elem(z, 0f32.into(), bool_dtype);
            dz = B::float_mask_where(dx, below, scaled);
        }
        pieces.reverse();
        let d_enc = d_enc.expect("layer 0 reads the encoding");
        (d_enc, B::float_cat(pieces, 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::random;

    fn layout() -> MlpLayout {
        MlpLayout {
            input: 6,
            width: 5,
            layers: 4,
            skip: 2,
            slope: 0.01,
        }
    }

    /// The MLP of the module docs, one point at a time, in f64. Each LeakyReLU's branch
    /// (below 0 or not) is read from `branches` when given, else chosen and recorded there: a
    /// finite difference with the branches of the unperturbed point differentiates the piece
    /// of the (piecewise linear) network the point lies on, with no kink inside the step.
    fn reference(
        layout: &MlpLayout,
        enc: &[f32],
        params: &[f32],
        branches: &mut Vec<bool>,
        fixed: bool,
    ) -> Vec<f64> {
        let mut next = 0;
        enc.chunks_exact(layout.input)
            .map(|e| {
                let mut x: Vec<f64> = e.iter().map(|&v| v as f64).collect();
                for l in 0..layout.layers {
                    if l == layout.skip {
                        x.extend(e.iter().map(|&v| v as f64));
                    }
                    let (wo, bo) = layout.offsets(l);
                    let d_out = layout.d_out(l);
                    let mut z: Vec<f64> = (0..d_out).map(|j| params[bo + j] as f64).collect();
                    for (k, xk) in x.iter().enumerate() {
                        for (j, zj) in z.iter_mut().enumerate() {
                            *zj += xk * params[wo + k * d_out + j] as f64;
                        }
                    }
                    if l + 1 == layout.layers {
                        x = z;
                        continue;
                    }
                    x = z
                        .iter()
                        .map(|&v| {
                            if !fixed {
                                branches.push(v < 0.0);
                            }
                            let below = branches[next];
                            next += 1;
                            if below { v * layout.slope as f64 } else { v }
                        })
                        .collect();
                }
                x[0]
            })
            .collect()
    }

    #[test]
    fn the_packed_layout_holds_every_layer_once() {
        let l = layout();
        // 6→5, 5→5, (5+6)→5, 5→1, each with its bias.
        assert_eq!(l.params(), 7 * 5 + 6 * 5 + 12 * 5 + 6);
        assert_eq!(l.offsets(1), (35, 35 + 25));
    }

    #[test]
    fn the_forward_is_the_mlp_of_the_docs() {
        let l = layout();
        // More points than a task, so tasks are split and joined.
        let n = TASK + 37;
        let enc = random(n * l.input, -1.0, 1.0, 11);
        let params = random(l.params(), -0.6, 0.6, 12);
        let out = cpu_forward(&l, &enc, &params);
        let want = reference(&l, &enc, &params, &mut Vec::new(), false);
        for (i, (a, b)) in out.iter().zip(want).enumerate() {
            assert!((*a as f64 - b).abs() < 1e-5, "point {i}: {a} vs {b}");
        }
    }

    #[test]
    fn the_wide_and_baseline_variants_agree_exactly() {
        // Without FMA the AVX2 build performs the same operations in the same order.
        let l = layout();
        let n = TASK + 5;
        let enc = random(n * l.input, -1.0, 1.0, 16);
        let params = random(l.params(), -0.6, 0.6, 17);
        let grad = random(n, -1.0, 1.0, 18);
        let run = |baseline: bool| {
            prism_kernel::simd::force_baseline(baseline);
            let out = (
                cpu_forward(&l, &enc, &params),
                cpu_backward(&l, &enc, &params, &grad),
            );
            prism_kernel::simd::force_baseline(false);
            out
        };
        assert_eq!(run(false), run(true));
    }

    #[test]
    fn the_backward_matches_finite_differences() {
        let l = layout();
        let n = TASK + 9;
        let enc = random(n * l.input, -1.0, 1.0, 13);
        let params = random(l.params(), -0.6, 0.6, 14);
        let grad = random(n, -1.0, 1.0, 15);
        let (d_enc, d_params) = cpu_backward(&l, &enc, &params, &grad);
        // ⟨grad, f⟩ in f64 on the unperturbed point's branches, differentiated centrally over
        // the step actually taken in f32.
        let mut branches = Vec::new();
        reference(&l, &enc, &params, &mut branches, false);
        let loss = |enc: &[f32], params: &[f32]| -> f64 {
            reference(&l, enc, params, &mut branches.clone(), true)
                .iter()
                .zip(&grad)
                .map(|(a, &g)| a * g as f64)
                .sum()
        };
        let h = 1e-3f32;
        for k in (0..params.len()).step_by(3) {
            let (mut up, mut down) = (params.clone(), params.clone());
            up[k] += h;
            down[k] -= h;
            let fd = (loss(&enc, &up) - loss(&enc, &down)) / (up[k] - down[k]) as f64;
            let tol = 1e-4 * fd.abs().max(1.0);
            assert!(
                (fd - d_params[k] as f64).abs() < tol,
                "param {k}: fd {fd} vs {}",
                d_params[k]
            );
        }
        for k in (0..enc.len()).step_by(29) {
            let (mut up, mut down) = (enc.clone(), enc.clone());
            up[k] += h;
            down[k] -= h;
            let fd = (loss(&up, &params) - loss(&down, &params)) / (up[k] - down[k]) as f64;
            assert!(
                (fd - d_enc[k] as f64).abs() < 2e-3,
                "enc {k}: fd {fd} vs {}",
                d_enc[k]
            );
        }
    }
}
