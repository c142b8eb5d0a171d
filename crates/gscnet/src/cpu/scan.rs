//! The fused selective scan (see [`crate::ssm`] for the recurrence) and its adjoint.
//!
//! Layouts (row-major, f32): `x`, `delta` `[K, M, E]`; `a_log` `[E, N]`; `b`, `c` `[K, M, N]`;
//! `d` `[E]`; output and its gradient `[K, M, E]`.
//!
//! Forward: one pass over m per (k, e) with the N-vector state h in a small scratch buffer.
//! Backward (reverse-time adjoint): recompute h_1..h_M for (k, e) (cheaper than storing
//! K·M·E·N floats), then for m = M..1 with the state adjoint λ (λ_{M+1} = 0):
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

use super::{BLOCK, sigmoid, sum_partials};

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
/// e^{−z} < 2e-9 is below f32 resolution there).
#[inline]
pub fn softplus(z: f32) -> f32 {
    if z > 20.0 { z } else { ln_1p(z.exp()) }
}

/// ln(1 + u) for u ≥ 0 to a few ulp, with one `ln` (Goldberg's correction: w = fl(1 + u) and
/// ln(w)·u/(w − 1) cancels the rounding of w). `f32::ln_1p` is about 4× slower in glibc.
#[inline]
fn ln_1p(u: f32) -> f32 {
    let w = 1.0 + u;
    if w == 1.0 {
        u
    } else {
        w.ln() * (u / (w - 1.0))
    }
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

impl ScanInputs<'_> {
    /// A = −exp(A_log), `[E, N]`.
    fn a(&self) -> Vec<f32> {
        self.a_log.iter().map(|v| -v.exp()).collect()
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
    /// The step Δ at flat index `i` of the `[M, E]` tile.
    #[inline]
    fn step(&self, i: usize) -> f32 {
        let z = self.delta[i];
        if self.softplus { softplus(z) } else { z }
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

/// The steps Δ_1..Δ_M `[M]`, states h_1..h_M `[M, N]` and decays Ā_m = exp(Δ_m A) `[M, N]` of
/// feature `ei` of one tile (Ā_1 is unused: h_0 = 0).
fn states(t: &Tile, dims: ScanDims, ei: usize, a: &[f32], s: &mut Scratch) {
    let ScanDims { m, e, n, .. } = dims;
    for mi in 0..m {
        let dt = t.step(mi * e + ei);
        s.steps[mi] = dt;
        let dx = dt * t.x[mi * e + ei];
        let b = &t.b[mi * n..(mi + 1) * n];
        let (prev, cur) = s.hs.split_at_mut(mi * n);
        let cur = &mut cur[..n];
        let decay = &mut s.decay[mi * n..(mi + 1) * n];
        if mi == 0 {
            decay.fill(1.0);
            for (h, &b) in cur.iter_mut().zip(b) {
                *h = dx * b;
            }
        } else {
            let prev = &prev[(mi - 1) * n..];
            for ((((h, ab), &hp), &b), &a) in cur.iter_mut().zip(decay).zip(prev).zip(b).zip(a) {
                *ab = (dt * a).exp();
                *h = *ab * hp + dx * b;
            }
        }
    }
}

/// Forward scan of one Gaussian: writes its `[M, E]` outputs.
fn forward_tile(t: &Tile, dims: ScanDims, a: &[f32], d: &[f32], h: &mut [f32], y: &mut [f32]) {
    let ScanDims { m, e, n, .. } = dims;
    for ei in 0..e {
        let a = &a[ei * n..(ei + 1) * n];
        h.fill(0.0);
        for mi in 0..m {
            let dt = t.step(mi * e + ei);
            let xm = t.x[mi * e + ei];
            let dx = dt * xm;
            let b = &t.b[mi * n..(mi + 1) * n];
            let c = &t.c[mi * n..(mi + 1) * n];
            let mut acc = d[ei] * xm;
            if mi == 0 {
                for ((h, &b), &c) in h.iter_mut().zip(b).zip(c) {
                    *h = dx * b;
                    acc += c * *h;
                }
            } else {
                for (((h, &a), &b), &c) in h.iter_mut().zip(a).zip(b).zip(c) {
                    *h = (dt * a).exp() * *h + dx * b;
                    acc += c * *h;
                }
            }
            y[mi * e + ei] = acc;
        }
    }
}

/// Runs the scan: `y` `[K, M, E]`.
pub fn scan_forward(inp: &ScanInputs) -> Vec<f32> {
    inp.check();
    let ScanDims { k, m, e, n } = inp.dims;
    let a = inp.a();
    let mut y = vec![0.0f32; k * m * e];
    if m * e == 0 {
        return y;
    }
    y.par_chunks_mut(BLOCK * m * e)
        .enumerate()
        .for_each(|(blk, ys)| {
            let mut h = vec![0.0f32; n];
            for (j, yk) in ys.chunks_mut(m * e).enumerate() {
                let t = inp.tile(blk * BLOCK + j);
                forward_tile(&t, inp.dims, &a, inp.d, &mut h, yk);
            }
        });
    y
}

/// Per-Gaussian gradient slices (`[M, E]` for x and Δ, `[M, N]` for B and C) and the block's
/// partial sums for A (`[E, N]`, w.r.t. A itself) and D (`[E]`).
struct TileGrads<'a> {
    x: &'a mut [f32],
    delta: &'a mut [f32],
    b: &'a mut [f32],
    c: &'a mut [f32],
    a: &'a mut [f32],
    d: &'a mut [f32],
}

/// Scratch of the adjoint pass: steps `[M]`, states and decays `[M, N]`, state adjoint λ `[N]`.
struct Scratch {
    steps: Vec<f32>,
    hs: Vec<f32>,
    decay: Vec<f32>,
    lambda: Vec<f32>,
}

#[allow(clippy::too_many_arguments)]
fn backward_tile(
    t: &Tile,
    dims: ScanDims,
    a: &[f32],
    d: &[f32],
    gy: &[f32],
    s: &mut Scratch,
    g: &mut TileGrads,
) {
    let ScanDims { m, e, n, .. } = dims;
    for ei in 0..e {
        let a = &a[ei * n..(ei + 1) * n];
        states(t, dims, ei, a, s);
        s.lambda.fill(0.0);
        let ga = &mut g.a[ei * n..(ei + 1) * n];
        for mi in (0..m).rev() {
            let i = mi * e + ei;
            let (gm, xm, dt) = (gy[i], t.x[i], s.steps[mi]);
            g.d[ei] += gm * xm;
            let row = mi * n..(mi + 1) * n;
            let (b, c, h) = (&t.b[row.clone()], &t.c[row.clone()], &s.hs[row.clone()]);
            let (gb, gc) = (&mut g.b[row.clone()], &mut g.c[row.clone()]);
            let dtx = dt * xm;
            let mut lb = 0.0f32; // Σ_n λ_n B_n
            for ((((l, gb), gc), (&b, &c)), &h) in s
                .lambda
                .iter_mut()
                .zip(gb)
                .zip(gc)
                .zip(b.iter().zip(c))
                .zip(h)
            {
                *l += gm * c;
                *gc += gm * h;
                *gb += *l * dtx;
                lb += *l * b;
            }
            let mut gdt_decay = 0.0f32; // Σ_n λ_n A_n Ā_n h_{m−1,n}
            if mi > 0 {
                let prev = &s.hs[(mi - 1) * n..mi * n];
                let decay = &s.decay[row];
                for ((((l, ga), &a), &ab), &hp) in s
                    .lambda
                    .iter_mut()
                    .zip(ga.iter_mut())
                    .zip(a)
                    .zip(decay)
                    .zip(prev)
                {
                    let q = *l * ab * hp;
                    gdt_decay += q * a;
                    *ga += q * dt;
                    *l *= ab;
                }
            }
            g.x[i] = d[ei] * gm + dt * lb;
            let gdt = xm * lb + gdt_decay;
            g.delta[i] = if t.softplus {
                gdt * sigmoid(t.delta[i])
            } else {
                gdt
            };
        }
    }
}

/// Gradients of ⟨`gy`, scan(inp)⟩ (`gy` `[K, M, E]`).
pub fn scan_backward(inp: &ScanInputs, gy: &[f32]) -> ScanGrads {
    inp.check();
    let ScanDims { k, m, e, n } = inp.dims;
    assert_eq!(gy.len(), k * m * e, "scan: output gradient length");
    let a = inp.a();
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
                let mut ga = vec![0.0f32; e * n];
                let mut gd = vec![0.0f32; e];
                let mut s = Scratch {
                    steps: vec![0.0; m],
                    hs: vec![0.0; mn],
                    decay: vec![0.0; mn],
                    lambda: vec![0.0; n],
                };
                for j in 0..count {
                    let kk = blk * BLOCK + j;
                    let mut g = TileGrads {
                        x: &mut gx[j * me..(j + 1) * me],
                        delta: &mut gdelta[j * me..(j + 1) * me],
                        b: &mut gb[j * mn..(j + 1) * mn],
                        c: &mut gc[j * mn..(j + 1) * mn],
                        a: &mut ga,
                        d: &mut gd,
                    };
                    let gy = &gy[kk * me..(kk + 1) * me];
                    backward_tile(&inp.tile(kk), inp.dims, &a, inp.d, gy, &mut s, &mut g);
                }
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
    let ga = sum_partials(ga, e * n);
    let a_log = ga.iter().zip(&a).map(|(g, a)| g * a).collect();
    ScanGrads {
        x: gx,
        delta: gdelta,
        a_log,
        b: gb,
        c: gc,
        d: sum_partials(gd, e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::SeedStream;

    fn sample(rng: &mut SeedStream, n: usize, lo: f64, hi: f64) -> Vec<f32> {
        (0..n).map(|_| rng.range(lo, hi) as f32).collect()
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
        let mut rng = SeedStream::new(5);
        let x = sample(&mut rng, k * m * e, -1.0, 1.0);
        let delta = sample(&mut rng, k * m * e, 0.05, 1.5);
        let a_log = sample(&mut rng, e * n, -0.5, 1.0);
        let b = sample(&mut rng, k * m * n, -1.0, 1.0);
        let c = sample(&mut rng, k * m * n, -1.0, 1.0);
        let d = sample(&mut rng, e, 0.5, 1.5);
        let gy = sample(&mut rng, k * m * e, -1.0, 1.0);
        let inp = ScanInputs {
            dims,
            x: &x,
            delta: &delta,
            a_log: &a_log,
            b: &b,
            c: &c,
            d: &d,
            softplus: false,
        };
        let y = scan_forward(&inp);
        let g = scan_backward(&inp, &gy);
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
        let again = scan_backward(&inp, &gy);
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

    /// softplus against f64 ln(1 + e^z) over [−40, 40]: Goldberg's log1p is accurate to a few
    /// ulp (bound 5 ε_f32 ≈ 6e-7 relative, including the rounding of e^z).
    #[test]
    fn softplus_is_accurate_in_both_tails() {
        let mut worst = 0.0f64;
        for i in 0..=8000 {
            let z = -40.0 + i as f32 * 0.01;
            let exact = f64::from(z).exp().ln_1p();
            let rel = (f64::from(softplus(z)) - exact).abs() / exact;
            worst = worst.max(rel);
        }
        println!("softplus: max relative error {worst:.2e}");
        assert!(worst <= 6e-7, "{worst}");
    }
}
