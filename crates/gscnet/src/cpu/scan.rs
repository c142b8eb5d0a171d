//! The fused selective scan (see [`crate::ssm`] for the recurrence) and its adjoint.
//!
//! Layouts (row-major, f32): `x`, `delta` `[K, M, E]`; `a_log` `[E, N]`; `b`, `c` `[K, M, N]`;
//! `d` `[E]`; output and its gradient `[K, M, E]`.
//!
//! The kernels take 8 consecutive features e of one Gaussian at a time as lane vectors (B and C
//! are shared by the features), so the loops over the state index n are vertical arithmetic that
//! vectorises; the decays Ā use a branch-free polynomial `exp` (`cpu::math`). Each rayon block runs
//! either a portable build or one compiled with AVX2 + FMA, chosen at run time per scan call.
//!
//! Forward: one pass over m per (k, feature chunk) with the N state vectors in scratch.
//! Backward (reverse-time adjoint): recompute h_1..h_M for (k, feature chunk) (cheaper than
//! storing K·M·E·N floats), then for m = M..1 with the state adjoint λ (λ_{M+1} = 0):
//!
//! ```text
//! λ_m   = C_m ḡ_m + Ā_{m+1} ⊙ λ_{m+1}          (ḡ_m = ∂L/∂y_m, a scalar per (k, m, e))
//! ∂x_m  = D ḡ_m + Δ_m Σ_n λ_mn B_mn
//! ∂Δ_m  = Σ_n λ_mn (B_mn x_m + A_n Ā_mn h_{m−1,n})
//! ∂B_mn += λ_mn Δ_m x_m,   ∂C_mn += ḡ_m h_mn       (summed over e)
//! ∂A_n  += λ_mn Δ_m Ā_mn h_{m−1,n},  ∂A_log = A ⊙ ∂A,   ∂D += ḡ_m x_m   (summed over k, m)
//! ```
//!
//! With [`ScanInputs::softplus`] set, `delta` holds the raw step z and Δ = softplus(z) is applied
//! inside the kernel (∂z = σ(z) ∂Δ), which saves the activation's separate passes over K·M·E.

use rayon::prelude::*;

use super::math::{self, MulAdd, Separate};
use super::{BLOCK, has_avx2, sum_partials};

/// Sizes of one scan: K Gaussians, M channels (sequence length), E features, N state size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanDims {
    pub k: usize,
    pub m: usize,
    pub e: usize,
    pub n: usize,
}

/// The scan's inputs as borrowed slices (layouts in the module docs).
#[derive(Debug, Clone, Copy)]
pub struct ScanInputs<'a> {
    pub dims: ScanDims,
    pub x: &'a [f32],
    pub delta: &'a [f32],
    pub a_log: &'a [f32],
    pub b: &'a [f32],
    pub c: &'a [f32],
    pub d: &'a [f32],
    /// `delta` holds raw steps z and Δ = softplus(z) (else `delta` is Δ itself).
    pub softplus: bool,
}

/// softplus(z) = ln(1 + e^z), with z returned above 20 (as Burn's `softplus`: the correction
/// e^{−z} < 2e-9 is below f32 resolution there) and 0 below −87. The kernels' own branch-free
/// version (`cpu::math::softplus`), unfused.
#[inline]
pub fn softplus(z: f32) -> f32 {
    math::softplus::<Separate>(z)
}

/// Gradients of ⟨ḡ, scan(..)⟩ with respect to every input, in the inputs' layouts.
#[derive(Debug, Clone)]
pub struct ScanGrads {
    pub x: Vec<f32>,
    pub delta: Vec<f32>,
    pub a_log: Vec<f32>,
    pub b: Vec<f32>,
    pub c: Vec<f32>,
    pub d: Vec<f32>,
}

/// Features per lane vector: the kernels treat 8 consecutive features e of one (k, m) at once
/// (one AVX2 register). B_m and C_m are shared by the features, so every per-feature quantity
/// (x, Δ, the states h_n, the decays, λ_n, y and the gradients) is one lane vector and the
/// inner loops over the state index n are plain vertical arithmetic that vectorises.
const LANES: usize = 8;

/// One value per feature of a lane chunk.
type Lanes = [f32; LANES];

/// A lane vector from `f(j)` for each lane j.
#[inline(always)]
fn lanes(f: impl Fn(usize) -> f32) -> Lanes {
    std::array::from_fn(f)
}

/// The first `s.len()` (≤ [`LANES`]) lanes from `s`, the rest 0.
#[inline(always)]
fn load(s: &[f32]) -> Lanes {
    match <Lanes>::try_from(s) {
        Ok(v) => v,
        Err(_) => {
            let mut v = [0.0; LANES];
            v[..s.len()].copy_from_slice(s);
            v
        }
    }
}

/// The first [`LANES`] values of `s` (a zero-padded row: always long enough).
#[inline(always)]
fn load_padded(s: &[f32]) -> Lanes {
    let mut v = [0.0; LANES];
    v.copy_from_slice(&s[..LANES]);
    v
}

/// Stores the first `out.len()` (≤ [`LANES`]) lanes of `v`.
#[inline(always)]
fn store(v: &Lanes, out: &mut [f32]) {
    let w = out.len();
    out.copy_from_slice(&v[..w]);
}

/// Σ of the lanes in a fixed order (pairwise: lanes j and j + 4, then j + 2, then j + 1).
#[inline(always)]
fn sum_lanes(v: &Lanes) -> f32 {
    let mut a = *v;
    let mut w = LANES / 2;
    while w > 0 {
        for j in 0..w {
            a[j] += a[j + w];
        }
        w /= 2;
    }
    a[0]
}

/// Call-wide constants in lane layout. Features are padded to E' = E rounded up to [`LANES`];
/// padded features have A = 0 (decay 1), D = 0 and zero x, Δ and ḡ, so for finite B and C they
/// contribute exact zeros to every sum over features.
struct Shared {
    /// A = −exp(A_log), `[E, N]`.
    a: Vec<f32>,
    /// A transposed and padded, `[N, E']`.
    at: Vec<f32>,
    /// D padded, `[E']`.
    d: Vec<f32>,
    /// E'.
    ep: usize,
}

impl ScanInputs<'_> {
    fn shared(&self) -> Shared {
        let ScanDims { e, n, .. } = self.dims;
        let ep = e.div_ceil(LANES) * LANES;
        let a: Vec<f32> = self.a_log.iter().map(|v| -v.exp()).collect();
        let mut at = vec![0.0f32; n * ep];
        for (ei, row) in a.chunks_exact(n.max(1)).enumerate() {
            for (ni, &v) in row.iter().enumerate() {
                at[ni * ep + ei] = v;
            }
        }
        let mut d = vec![0.0f32; ep];
        d[..e].copy_from_slice(self.d);
        Shared { a, at, d, ep }
    }

    /// Panics unless every slice has the length its dims imply (the op builds them).
    fn check(&self) {
        let ScanDims { k, m, e, n } = self.dims;
        assert_eq!(self.x.len(), k * m * e, "scan: x length");
        assert_eq!(self.delta.len(), k * m * e, "scan: Δ length");
        assert_eq!(self.a_log.len(), e * n, "scan: A_log length");
        assert_eq!(self.b.len(), k * m * n, "scan: B length");
        assert_eq!(self.c.len(), k * m * n, "scan: C length");
        assert_eq!(self.d.len(), e, "scan: D length");
    }
}

/// One Gaussian's tile: rows `[M, E]` of x and Δ, `[M, N]` of B and C.
struct Tile<'a> {
    x: &'a [f32],
    delta: &'a [f32],
    b: &'a [f32],
    c: &'a [f32],
    softplus: bool,
}

impl Tile<'_> {
    /// The tile's steps Δ `[M, E]`: `delta` itself, or its softplus written into `buf` (one flat
    /// loop over the tile, which vectorises better than per-chunk lanes).
    #[inline(always)]
    fn steps<'b, F: MulAdd>(&'b self, buf: &'b mut [f32]) -> &'b [f32] {
        if !self.softplus {
            return self.delta;
        }
        for (s, &z) in buf.iter_mut().zip(self.delta) {
            *s = math::softplus::<F>(z);
        }
        buf
    }
}

impl<'a> ScanInputs<'a> {
    fn tile(&self, k: usize) -> Tile<'a> {
        let ScanDims { m, e, n, .. } = self.dims;
        Tile {
            x: &self.x[k * m * e..(k + 1) * m * e],
            delta: &self.delta[k * m * e..(k + 1) * m * e],
            b: &self.b[k * m * n..(k + 1) * m * n],
            c: &self.c[k * m * n..(k + 1) * m * n],
            softplus: self.softplus,
        }
    }
}

/// Forward scan of one Gaussian, features `e0..e0 + LANES` at a time: writes its `[M, E]`
/// outputs. `h` is scratch for the N state vectors.
#[inline(always)]
fn forward_tile<F: MulAdd>(
    t: &Tile,
    dims: ScanDims,
    sh: &Shared,
    (h, buf): (&mut [Lanes], &mut [f32]),
    y: &mut [f32],
) {
    let ScanDims { m, e, n, .. } = dims;
    let steps = t.steps::<F>(buf);
    for e0 in (0..e).step_by(LANES) {
        let e1 = (e0 + LANES).min(e);
        let dv = load_padded(&sh.d[e0..]);
        for mi in 0..m {
            let r = mi * e + e0..mi * e + e1;
            let xv = load(&t.x[r.clone()]);
            let dt = load(&steps[r.clone()]);
            let dx = lanes(|j| dt[j] * xv[j]);
            let mut acc = lanes(|j| dv[j] * xv[j]);
            let (b, c) = (&t.b[mi * n..(mi + 1) * n], &t.c[mi * n..(mi + 1) * n]);
            if mi == 0 {
                for ((h, &b), &c) in h.iter_mut().zip(b).zip(c) {
                    *h = lanes(|j| dx[j] * b);
                    acc = lanes(|j| F::mul_add(c, h[j], acc[j]));
                }
            } else {
                let at = sh.at.chunks_exact(sh.ep);
                for (((h, a), &b), &c) in h.iter_mut().zip(at).zip(b).zip(c) {
                    let a = load_padded(&a[e0..]);
                    let decay = lanes(|j| math::exp::<F>(dt[j] * a[j]));
                    *h = lanes(|j| F::mul_add(decay[j], h[j], dx[j] * b));
                    acc = lanes(|j| F::mul_add(c, h[j], acc[j]));
                }
            }
            store(&acc, &mut y[r]);
        }
    }
}

/// Forward of the tiles of one rayon block (`ys` holds their outputs, the first is Gaussian
/// `first`).
#[inline(always)]
fn forward_block<F: MulAdd>(inp: &ScanInputs, sh: &Shared, first: usize, ys: &mut [f32]) {
    let ScanDims { m, e, n, .. } = inp.dims;
    let mut h = vec![[0.0f32; LANES]; n];
    let mut buf = vec![0.0f32; m * e];
    for (j, yk) in ys.chunks_mut(m * e).enumerate() {
        let scratch = (&mut h[..], &mut buf[..]);
        forward_tile::<F>(&inp.tile(first + j), inp.dims, sh, scratch, yk);
    }
}

dispatched! {
    /// [`forward_block`], 8-wide with fused multiply-adds when `wide`.
    fn forward_block_on => forward_block(inp: &ScanInputs, sh: &Shared, first: usize, ys: &mut [f32])
}

/// Runs the scan: `y` `[K, M, E]`.
pub fn scan_forward(inp: &ScanInputs) -> Vec<f32> {
    scan_forward_on(inp, has_avx2())
}

/// [`scan_forward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
fn scan_forward_on(inp: &ScanInputs, wide: bool) -> Vec<f32> {
    inp.check();
    let ScanDims { k, m, e, .. } = inp.dims;
    let mut y = vec![0.0f32; k * m * e];
    if m * e == 0 {
        return y;
    }
    let sh = inp.shared();
    y.par_chunks_mut(BLOCK * m * e)
        .enumerate()
        .for_each(|(blk, ys)| forward_block_on(wide, inp, &sh, blk * BLOCK, ys));
    y
}

/// Per-Gaussian gradient slices (`[M, E]` for x and Δ, `[M, N]` for B and C) and the block's
/// partial sums for A (`[N, E']`, w.r.t. A itself) and D (`[E']`).
struct TileGrads<'a> {
    x: &'a mut [f32],
    delta: &'a mut [f32],
    b: &'a mut [f32],
    c: &'a mut [f32],
    a: &'a mut [f32],
    d: &'a mut [f32],
}

/// Scratch of the adjoint pass: the tile's steps Δ and σ(z) `[M, E]` (with softplus), and for one
/// lane chunk x and steps `[M]`, states and decays `[M, N]`, state adjoint λ `[N]`, and the tile's
/// per-lane partial sums of ∂B and ∂C `[M, N]`.
struct Scratch {
    dt: Vec<f32>,
    sig: Vec<f32>,
    xs: Vec<Lanes>,
    steps: Vec<Lanes>,
    hs: Vec<Lanes>,
    decay: Vec<Lanes>,
    lambda: Vec<Lanes>,
    gb: Vec<Lanes>,
    gc: Vec<Lanes>,
}

impl Scratch {
    fn new(m: usize, e: usize, n: usize) -> Self {
        let v = |len| vec![[0.0f32; LANES]; len];
        Scratch {
            dt: vec![0.0; m * e],
            sig: vec![0.0; m * e],
            xs: v(m),
            steps: v(m),
            hs: v(m * n),
            decay: v(m * n),
            lambda: v(n),
            gb: v(m * n),
            gc: v(m * n),
        }
    }
}

/// x_1..x_M and Δ_1..Δ_M, states h_1..h_M and decays Ā_m = exp(Δ_m A) `[M, N]` of features
/// `e0..e1` of one tile (Ā_1 is unused: h_0 = 0).
#[inline(always)]
fn states<F: MulAdd>(
    t: &Tile,
    dims: ScanDims,
    (e0, e1): (usize, usize),
    (sh, steps): (&Shared, &[f32]),
    s: &mut Scratch,
) {
    let ScanDims { m, e, n, .. } = dims;
    for mi in 0..m {
        let r = mi * e + e0..mi * e + e1;
        let xv = load(&t.x[r.clone()]);
        let dt = load(&steps[r]);
        s.xs[mi] = xv;
        s.steps[mi] = dt;
        let dx = lanes(|j| dt[j] * xv[j]);
        let b = &t.b[mi * n..(mi + 1) * n];
        let (prev, cur) = s.hs.split_at_mut(mi * n);
        let cur = &mut cur[..n];
        let decay = &mut s.decay[mi * n..(mi + 1) * n];
        if mi == 0 {
            decay.fill([1.0; LANES]);
            for (h, &b) in cur.iter_mut().zip(b) {
                *h = lanes(|j| dx[j] * b);
            }
        } else {
            let prev = &prev[(mi - 1) * n..];
            let at = sh.at.chunks_exact(sh.ep);
            for ((((h, ab), hp), &b), a) in cur.iter_mut().zip(decay).zip(prev).zip(b).zip(at) {
                let a = load_padded(&a[e0..]);
                *ab = lanes(|j| math::exp::<F>(dt[j] * a[j]));
                *h = lanes(|j| F::mul_add(ab[j], hp[j], dx[j] * b));
            }
        }
    }
}

/// Adjoint of one Gaussian, features `e0..e0 + LANES` at a time.
#[inline(always)]
fn backward_tile<F: MulAdd>(
    t: &Tile,
    dims: ScanDims,
    sh: &Shared,
    gy: &[f32],
    s: &mut Scratch,
    g: &mut TileGrads,
) {
    let ScanDims { m, e, n, .. } = dims;
    let zero = [0.0f32; LANES];
    s.gb.fill(zero);
    s.gc.fill(zero);
    let mut dt_buf = std::mem::take(&mut s.dt);
    let steps = t.steps::<F>(&mut dt_buf);
    if t.softplus {
        for (g, &z) in s.sig.iter_mut().zip(t.delta) {
            *g = math::sigmoid::<F>(z);
        }
    }
    for e0 in (0..e).step_by(LANES) {
        let e1 = (e0 + LANES).min(e);
        states::<F>(t, dims, (e0, e1), (sh, steps), s);
        s.lambda.fill(zero);
        let dv = load_padded(&sh.d[e0..]);
        let mut gd = load_padded(&g.d[e0..]);
        for mi in (0..m).rev() {
            let r = mi * e + e0..mi * e + e1;
            let gm = load(&gy[r.clone()]);
            let (xm, dt) = (s.xs[mi], s.steps[mi]);
            gd = lanes(|j| F::mul_add(gm[j], xm[j], gd[j]));
            let row = mi * n..(mi + 1) * n;
            let (b, c, h) = (&t.b[row.clone()], &t.c[row.clone()], &s.hs[row.clone()]);
            let (gb, gc) = (&mut s.gb[row.clone()], &mut s.gc[row.clone()]);
            let dtx = lanes(|j| dt[j] * xm[j]);
            let mut lb = zero; // Σ_n λ_n B_n
            for ((((l, gb), gc), (&b, &c)), h) in s
                .lambda
                .iter_mut()
                .zip(gb)
                .zip(gc)
                .zip(b.iter().zip(c))
                .zip(h)
            {
                *l = lanes(|j| F::mul_add(gm[j], c, l[j]));
                *gc = lanes(|j| F::mul_add(gm[j], h[j], gc[j]));
                *gb = lanes(|j| F::mul_add(l[j], dtx[j], gb[j]));
                lb = lanes(|j| F::mul_add(l[j], b, lb[j]));
            }
            let mut gdt_decay = zero; // Σ_n λ_n A_n Ā_n h_{m−1,n}
            if mi > 0 {
                let prev = &s.hs[(mi - 1) * n..mi * n];
                let decay = &s.decay[row];
                let at = sh.at.chunks_exact(sh.ep);
                let ga = g.a.chunks_exact_mut(sh.ep);
                for ((((l, ga), a), ab), hp) in
                    s.lambda.iter_mut().zip(ga).zip(at).zip(decay).zip(prev)
                {
                    let a = load_padded(&a[e0..]);
                    let q = lanes(|j| l[j] * ab[j] * hp[j]);
                    gdt_decay = lanes(|j| F::mul_add(q[j], a[j], gdt_decay[j]));
                    let ga = &mut ga[e0..e0 + LANES];
                    let sum = lanes(|j| F::mul_add(q[j], dt[j], ga[j]));
                    ga.copy_from_slice(&sum);
                    *l = lanes(|j| l[j] * ab[j]);
                }
            }
            let gx = lanes(|j| F::mul_add(dv[j], gm[j], dt[j] * lb[j]));
            store(&gx, &mut g.x[r.clone()]);
            let gdt = lanes(|j| F::mul_add(xm[j], lb[j], gdt_decay[j]));
            let gdt = if t.softplus {
                let sig = load(&s.sig[r.clone()]);
                lanes(|j| gdt[j] * sig[j])
            } else {
                gdt
            };
            store(&gdt, &mut g.delta[r]);
        }
        g.d[e0..e0 + LANES].copy_from_slice(&gd);
    }
    s.dt = dt_buf;
    for (out, v) in g.b.iter_mut().zip(&s.gb) {
        *out = sum_lanes(v);
    }
    for (out, v) in g.c.iter_mut().zip(&s.gc) {
        *out = sum_lanes(v);
    }
}

/// The block's gradient outputs: `x`, `delta` `[count, M, E]` and `b`, `c` `[count, M, N]` of its
/// Gaussians, partial sums `a` `[N, E']` and `d` `[E']`.
struct BlockGrads<'a> {
    x: &'a mut [f32],
    delta: &'a mut [f32],
    b: &'a mut [f32],
    c: &'a mut [f32],
    a: &'a mut [f32],
    d: &'a mut [f32],
}

/// Adjoint of the tiles of one rayon block (the first is Gaussian `first`).
#[inline(always)]
fn backward_block<F: MulAdd>(
    inp: &ScanInputs,
    sh: &Shared,
    gy: &[f32],
    first: usize,
    g: BlockGrads,
) {
    let ScanDims { m, e, n, .. } = inp.dims;
    let (me, mn) = (m * e, m * n);
    let mut s = Scratch::new(m, e, n);
    let tiles = g.x.chunks_mut(me).zip(g.delta.chunks_mut(me));
    for (j, (gx, gdelta)) in tiles.enumerate() {
        let kk = first + j;
        let mut tg = TileGrads {
            x: gx,
            delta: gdelta,
            b: &mut g.b[j * mn..(j + 1) * mn],
            c: &mut g.c[j * mn..(j + 1) * mn],
            a: &mut *g.a,
            d: &mut *g.d,
        };
        let gy = &gy[kk * me..(kk + 1) * me];
        backward_tile::<F>(&inp.tile(kk), inp.dims, sh, gy, &mut s, &mut tg);
    }
}

dispatched! {
    /// [`backward_block`], 8-wide with fused multiply-adds when `wide`.
    fn backward_block_on => backward_block(
        inp: &ScanInputs,
        sh: &Shared,
        gy: &[f32],
        first: usize,
        g: BlockGrads,
    )
}

/// Gradients of ⟨`gy`, scan(inp)⟩ (`gy` `[K, M, E]`).
pub fn scan_backward(inp: &ScanInputs, gy: &[f32]) -> ScanGrads {
    scan_backward_on(inp, gy, has_avx2())
}

/// [`scan_backward`] on the AVX2 path (`wide`, only when the CPU has it) or the portable one.
fn scan_backward_on(inp: &ScanInputs, gy: &[f32], wide: bool) -> ScanGrads {
    inp.check();
    let ScanDims { k, m, e, n } = inp.dims;
    assert_eq!(gy.len(), k * m * e, "scan: output gradient length");
    let sh = inp.shared();
    let ep = sh.ep;
    let mut gx = vec![0.0f32; k * m * e];
    let mut gdelta = vec![0.0f32; k * m * e];
    let (me, mn) = (m * e, m * n);
    // Per block: its rows of ∂B and ∂C, and its partial sums of ∂A and ∂D.
    let mut partials: Vec<[Vec<f32>; 4]> = Vec::new();
    if k > 0 && me > 0 {
        partials = gx
            .par_chunks_mut(BLOCK * me)
            .zip(gdelta.par_chunks_mut(BLOCK * me))
            .enumerate()
            .map(|(blk, (gx, gdelta))| {
                let count = gx.len() / me;
                let mut gb = vec![0.0f32; count * mn];
                let mut gc = vec![0.0f32; count * mn];
                let mut ga = vec![0.0f32; n * ep];
                let mut gd = vec![0.0f32; ep];
                let g = BlockGrads {
                    x: gx,
                    delta: gdelta,
                    b: &mut gb,
                    c: &mut gc,
                    a: &mut ga,
                    d: &mut gd,
                };
                backward_block_on(wide, inp, &sh, gy, blk * BLOCK, g);
                [gb, gc, ga, gd]
            })
            .collect();
    }
    let mut gb = Vec::with_capacity(k * mn);
    let mut gc = Vec::with_capacity(k * mn);
    let (mut ga, mut gd) = (Vec::new(), Vec::new());
    for [pb, pc, pa, pd] in partials {
        gb.extend(pb);
        gc.extend(pc);
        ga.push(pa);
        gd.push(pd);
    }
    gb.resize(k * mn, 0.0); // M·E = 0: no blocks ran, the gradients are zero
    gc.resize(k * mn, 0.0);
    // ∂A `[N, E']` back to `[E, N]`, then ∂A_log = A ⊙ ∂A.
    let ga = sum_partials(ga, n * ep);
    let mut a_log = vec![0.0f32; e * n];
    for (i, (g, a)) in a_log.iter_mut().zip(&sh.a).enumerate() {
        *g = ga[(i % n) * ep + i / n] * a;
    }
    let mut gd = sum_partials(gd, ep);
    gd.truncate(e);
    ScanGrads {
        x: gx,
        delta: gdelta,
        a_log,
        b: gb,
        c: gc,
        d: gd,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::SeedStream;

    fn sample(rng: &mut SeedStream, n: usize, lo: f64, hi: f64) -> Vec<f32> {
        (0..n).map(|_| rng.range(lo, hi) as f32).collect()
    }

    /// Random scan inputs and an output gradient ḡ, drawn from `seed` in this order: x ∈
    /// [−x_max, x_max], Δ (or raw z) ∈ `steps`, A_log ∈ `a_log`, B, C ∈ [−1, 1], D ∈ [0.5, 1.5],
    /// ḡ ∈ [−1, 1].
    struct Random {
        x: Vec<f32>,
        delta: Vec<f32>,
        a_log: Vec<f32>,
        b: Vec<f32>,
        c: Vec<f32>,
        d: Vec<f32>,
        gy: Vec<f32>,
    }

    impl Random {
        fn new(
            dims: ScanDims,
            seed: u64,
            x_max: f64,
            steps: (f64, f64),
            a_log: (f64, f64),
        ) -> Self {
            let ScanDims { k, m, e, n } = dims;
            let mut rng = SeedStream::new(seed);
            Random {
                x: sample(&mut rng, k * m * e, -x_max, x_max),
                delta: sample(&mut rng, k * m * e, steps.0, steps.1),
                a_log: sample(&mut rng, e * n, a_log.0, a_log.1),
                b: sample(&mut rng, k * m * n, -1.0, 1.0),
                c: sample(&mut rng, k * m * n, -1.0, 1.0),
                d: sample(&mut rng, e, 0.5, 1.5),
                gy: sample(&mut rng, k * m * e, -1.0, 1.0),
            }
        }

        fn inputs(&self, dims: ScanDims, softplus: bool) -> ScanInputs<'_> {
            ScanInputs {
                dims,
                x: &self.x,
                delta: &self.delta,
                a_log: &self.a_log,
                b: &self.b,
                c: &self.c,
                d: &self.d,
                softplus,
            }
        }
    }

    /// Gaussians are independent: a batch spanning several rayon blocks (K = 2.5 blocks) gives
    /// each Gaussian the outputs and gradients of a K = 1 run, and the shared parameters' gradients
    /// are the sums of the single runs' (f64 sum of K terms; the blocked f32 sum differs by
    /// ≲ K·ε_f32 relative ≈ 1e-4 in the worst case, ~√K·ε typically).
    #[test]
    fn blocked_batch_equals_independent_single_gaussian_runs() {
        let dims = ScanDims {
            k: BLOCK * 5 / 2,
            m: 3,
            e: 2,
            n: 3,
        };
        let ScanDims { k, m, e, n } = dims;
        let r = Random::new(dims, 5, 1.0, (0.05, 1.5), (-0.5, 1.0));
        let Random {
            x, delta, b, c, gy, ..
        } = &r;
        let inp = r.inputs(dims, false);
        let y = scan_forward(&inp);
        let g = scan_backward(&inp, gy);
        let (me, mn) = (m * e, m * n);
        let mut ga = vec![0.0f64; e * n];
        let mut gd = vec![0.0f64; e];
        for kk in 0..k {
            let one = ScanInputs {
                dims: ScanDims { k: 1, ..dims },
                x: &x[kk * me..(kk + 1) * me],
                delta: &delta[kk * me..(kk + 1) * me],
                b: &b[kk * mn..(kk + 1) * mn],
                c: &c[kk * mn..(kk + 1) * mn],
                ..inp
            };
            assert_eq!(scan_forward(&one), y[kk * me..(kk + 1) * me]);
            let g1 = scan_backward(&one, &gy[kk * me..(kk + 1) * me]);
            assert_eq!(g1.x, g.x[kk * me..(kk + 1) * me]);
            assert_eq!(g1.delta, g.delta[kk * me..(kk + 1) * me]);
            assert_eq!(g1.b, g.b[kk * mn..(kk + 1) * mn]);
            assert_eq!(g1.c, g.c[kk * mn..(kk + 1) * mn]);
            ga.iter_mut()
                .zip(&g1.a_log)
                .for_each(|(s, v)| *s += f64::from(*v));
            gd.iter_mut()
                .zip(&g1.d)
                .for_each(|(s, v)| *s += f64::from(*v));
        }
        for (sum, blocked) in ga.iter().chain(&gd).zip(g.a_log.iter().chain(&g.d)) {
            let tol = 1e-4 * sum.abs().max(1.0);
            assert!(
                (sum - f64::from(*blocked)).abs() <= tol,
                "{sum} vs {blocked}"
            );
        }
        // Deterministic: a second run is bit-identical.
        let again = scan_backward(&inp, gy);
        assert_eq!((again.a_log, again.d), (g.a_log, g.d));
    }

    #[test]
    fn empty_and_stateless_scans_are_well_formed() {
        for (k, m, e, n) in [(0, 3, 2, 4), (2, 3, 0, 4), (2, 3, 2, 0)] {
            let dims = ScanDims { k, m, e, n };
            let x = vec![0.5f32; k * m * e];
            let (a_log, d) = (vec![0.0f32; e * n], vec![2.0f32; e]);
            let bc = vec![1.0f32; k * m * n];
            let inp = ScanInputs {
                dims,
                x: &x,
                delta: &x,
                a_log: &a_log,
                b: &bc,
                c: &bc,
                d: &d,
                softplus: false,
            };
            let y = scan_forward(&inp);
            // N = 0: no state, y = D x.
            assert!(y.iter().all(|&v| v == 1.0), "{dims:?}: {y:?}");
            let g = scan_backward(&inp, &x);
            assert_eq!(
                [
                    g.x.len(),
                    g.delta.len(),
                    g.a_log.len(),
                    g.b.len(),
                    g.c.len(),
                    g.d.len()
                ],
                [k * m * e, k * m * e, e * n, k * m * n, k * m * n, e],
                "{dims:?}"
            );
        }
    }

    /// The AVX2 + FMA build and the portable one agree on random inputs with partial lane chunks
    /// (E = 11, N = 5) and the fused softplus: FMA rounds once where the portable path rounds
    /// twice, and the exp/ln polynomials differ by a few ulp, so outputs differ by a few ε_f32
    /// times the recurrence's small condition number. Compared element-wise to 1e-5 of the
    /// larger of the value and 1 % of the array's largest magnitude (sums that cancel to near
    /// zero carry the absolute rounding of their terms).
    #[test]
    fn avx2_and_portable_paths_agree() {
        if !has_avx2() {
            println!("note: this CPU lacks AVX2/FMA; only the portable scan path exists here");
            return;
        }
        let dims = ScanDims {
            k: BLOCK + 3,
            m: 4,
            e: 11,
            n: 5,
        };
        let r = Random::new(dims, 17, 2.0, (-4.0, 3.0), (-1.0, 1.5));
        let gy = &r.gy;
        let inp = r.inputs(dims, true);
        let close = |wide: &[f32], portable: &[f32], what: &str| {
            let scale = portable.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            assert!(scale > 0.0, "{what}: all zero");
            let mut worst = 0.0f32;
            for (w, p) in wide.iter().zip(portable) {
                let rel = (w - p).abs() / p.abs().max(0.01 * scale);
                worst = worst.max(rel);
            }
            println!("{what}: max relative difference {worst:.2e}");
            assert!(worst <= 1e-5, "{what}: {worst}");
        };
        close(
            &scan_forward_on(&inp, true),
            &scan_forward_on(&inp, false),
            "y",
        );
        let gw = scan_backward_on(&inp, gy, true);
        let gp = scan_backward_on(&inp, gy, false);
        close(&gw.x, &gp.x, "∂x");
        close(&gw.delta, &gp.delta, "∂z");
        close(&gw.a_log, &gp.a_log, "∂A_log");
        close(&gw.b, &gp.b, "∂B");
        close(&gw.c, &gp.c, "∂C");
        close(&gw.d, &gp.d, "∂D");
    }
}
