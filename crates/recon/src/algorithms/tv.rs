//! Total-variation regularised least squares over several channels at once, solved by the
//! diagonally preconditioned primal–dual algorithm (PDHG) of Chambolle & Pock.
//!
//! `min_{x ≥ 0}  Σ_c ½ ‖A_c x_c − b_c‖²_{W_c}  +  λ · Σ_voxels R( w_1 ∇x_1, …, w_C ∇x_C )`
//!
//! * `A_c` is the Joseph projector of channel c at *its own* views (interleaved scans give each
//!   channel different angles), `b_c` its line integrals;
//! * `W_c` weights the rays: 1 ([`Weighting::None`]), or statistical weights for photon-limited
//!   data ([`Weighting::Counts`]): a log-transformed count `b = −ln(I/I₀)` has variance
//!   `≈ 1/E[I] = e^b/I₀` (Poisson), so the weight is `∝ e^{−b}`, normalised to mean 1 over the
//!   channel's rays (penalised weighted least squares, as in Sauer & Bouman 1993; no I₀ needed);
//! * `∇` is the forward-difference gradient ([`super::gradient`]), in mm⁻¹ per voxel step; `w_c`
//!   a channel's weight in the regulariser (the method passes the inverse of the channel's gain,
//!   so channels of different contrast count alike);
//! * `R` couples the channels at a voxel through the 3 × C matrix `J` of their gradients
//!   ([`Coupling`]): the sum of per-channel gradient norms (TV of each channel alone), the
//!   Frobenius norm of `J` (joint or vectorial TV; Sapiro & Ringach 1996, Blomgren & Chan 1998),
//!   or the nuclear norm of `J` (total nuclear variation, Rigie & La Rivière 2015), which favours
//!   gradients that point the same way in every channel.
//!
//! The iteration (Pock & Chambolle 2011, α = 1), with `K = [A_c; w_c ∇]`:
//!
//! ```text
//! p_c ← (p_c + σ_p ⊙ (A_c x̄_c − b_c)) ⊙ W_c / (W_c + σ_p)  σ_p = 1 / (A_c 1)       (ray length)
//! q   ← Π_λ( q + σ_q · w ∇x̄ )                               σ_q = 1 / (2 max_c w_c)
//! x_c⁺ ← P₊( x_c − τ_c ⊙ (A_cᵀ p_c + w_c ∇ᵀ q_c) )          τ_c = 1 / (A_cᵀ 1 + 6 w_c)
//! x̄_c ← 2 x_c⁺ − x_c
//! ```
//!
//! **Directional TV** ([`tv_guided`]; Ehrhardt & Betcke 2016, Cueva et al. 2021): `∇` becomes `P∇`
//! with `P = I − ξξᵀ` at each voxel from a guide image ([`Directions`]), so a gradient along the
//! guide's edges costs little; with channel coupling this is dTV. `P` is symmetric, so the
//! adjoint is `∇ᵀP`; `P∇`'s row and column sums are at most [`Directions::bound`] times `∇`'s, and
//! `σ_q` and the gradient block's share of `τ_c` are scaled by it.
//!
//! `Π_λ` is the projection onto the dual ball of `R` (radius λ in the dual norm): per-channel
//! 3-vectors clipped to length λ, the whole 3·C group clipped to length λ, or `J`'s singular
//! values clipped at λ. The step sizes are the row and column sums of `|K|`, which guarantee
//! convergence without estimating an operator norm; rays shorter than half a voxel get σ = 0, as in
//! SART. Units: λ is in mm (data term: squared line integrals; regulariser: mm⁻¹).

use super::gradient::Gradient;
use super::guide::Directions;
use super::nuclear::{clip_singular_values, gram, sym3_eigen};
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use prism_domain::projector::Joseph;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How the regulariser couples the channels at a voxel (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Coupling {
    /// Each channel's own TV: no coupling (`Σ_c ‖w_c ∇x_c‖`).
    Channel,
    /// Joint (vectorial) TV: the Frobenius norm of the gradients of all channels.
    Joint,
    /// Total nuclear variation: the nuclear norm (sum of singular values) of the 3 × C Jacobian.
    #[default]
    Nuclear,
}

impl Coupling {
    /// The YAML name (`tv.coupling`).
    pub fn name(self) -> &'static str {
        match self {
            Coupling::Channel => "channel",
            Coupling::Joint => "joint",
            Coupling::Nuclear => "nuclear",
        }
    }
}

/// How the data term weights the rays (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Weighting {
    /// Every ray alike: least squares.
    #[default]
    None,
    /// Statistical weights `∝ e^{−b}` (the expected counts), mean 1 per channel: weighted least
    /// squares for photon-limited data.
    Counts,
}

impl Weighting {
    /// The weights of `b`'s rays.
    pub fn weights(self, b: ArrayView3<f32>) -> Array3<f32> {
        match self {
            Weighting::None => Array3::ones(b.raw_dim()),
            Weighting::Counts => {
                // Relative to the least attenuated ray, so e^{−b} cannot overflow.
                let lo = b.iter().fold(f32::INFINITY, |a, &v| a.min(v));
                let w = b.mapv(|v| (lo - v).exp());
                let mean = w.iter().map(|&v| v as f64).sum::<f64>() / w.len().max(1) as f64;
                if mean > 0.0 && mean.is_finite() {
                    w.mapv(|v| (v as f64 / mean) as f32)
                } else {
                    Array3::ones(b.raw_dim())
                }
            }
        }
    }
}

/// Options of [`tv`].
#[derive(Clone, Debug, PartialEq)]
pub struct TvOptions {
    /// PDHG iterations, ≥ 1.
    pub iterations: usize,
    /// Regularisation weight λ ≥ 0 (mm); 0 gives non-negative least squares.
    pub weight: f64,
    pub coupling: Coupling,
    /// The data term's ray weights.
    pub weighting: Weighting,
    /// Clip negative values (the constraint x ≥ 0).
    pub nonneg: bool,
}

impl TvOptions {
    /// Check ranges; errors name the field.
    pub fn validate(&self) -> Result<()> {
        if self.iterations == 0 {
            return Err(Error::invalid("iterations", "must be at least 1"));
        }
        prism_domain::error::ensure_non_negative("tv.weight", self.weight)?;
        Ok(())
    }
}

/// One channel's data: the projector at its views, its line integrals `[view][row][col]` at those
/// views, its weight `w_c > 0` in the regulariser, and where its iterate starts (zero if `None`).
pub struct ChannelData<'a> {
    pub projector: &'a Joseph,
    pub projections: ArrayView3<'a, f32>,
    pub weight: f32,
    pub start: Option<ArrayView3<'a, f32>>,
}

/// Reconstruct every channel jointly from its start (zero by default); `progress(k)` after
/// iteration k.
pub fn tv(
    channels: &[ChannelData],
    opts: &TvOptions,
    progress: &mut dyn FnMut(usize),
) -> Result<Vec<Array3<f32>>> {
    tv_guided(channels, opts, None, progress)
}

/// [`tv`] with directional TV: every channel's gradient `∇x_c` replaced by `P∇x_c`, `P` the
/// projection of `directions` at each voxel ([`Directions`]; `K`'s gradient block becomes
/// `s w_c P∇`, its steps scaled by [`Directions::bound`]). `None` is [`tv`].
pub fn tv_guided(
    channels: &[ChannelData],
    opts: &TvOptions,
    directions: Option<&Directions>,
    progress: &mut dyn FnMut(usize),
) -> Result<Vec<Array3<f32>>> {
    opts.validate()?;
    let shape = check(channels)?;
    let grad = Gradient::new(shape);
    let n = grad.voxels();
    check_directions(directions, n)?;
    let nc = channels.len();
    let w_max = channels.iter().map(|c| c.weight).fold(0.0f32, f32::max);
    let columns: Vec<Vec<f32>> = channels
        .iter()
        .map(|ch| column_sums(ch.projector))
        .collect::<Result<_>>()?;
    let scale = balance(&columns, w_max);
    let bound = directions.map_or(1.0, Directions::bound);
    let sigma_q = 1.0 / (2.0 * scale * w_max * bound);
    // R is positively homogeneous: λ R(y) at y = s w ∇x has its dual ball at radius λ / s.
    let radius = opts.weight as f32 / scale;
    let mut state: Vec<Primal> = channels
        .iter()
        .zip(columns)
        .map(|(ch, cols)| Primal::new(ch, cols, scale * ch.weight * bound, opts.weighting))
        .collect::<Result<_>>()?;
    let mut q = vec![0.0f32; 3 * nc * n];
    // `P q` where a guide projects the gradients (`∇ᵀ P q` is the adjoint's input).
    let mut pq = directions.map(|_| vec![0.0f32; 3 * nc * n]);
    for k in 0..opts.iterations {
        // Data duals.
        for (ch, s) in channels.iter().zip(state.iter_mut()) {
            let r = ch.projector.forward(view(&s.xbar, shape))?;
            let b = ch.projections.as_standard_layout();
            s.p.as_slice_mut()
                .expect("standard layout")
                .par_iter_mut()
                .zip(r.as_slice().expect("standard layout").par_iter())
                .zip(b.as_slice().expect("standard layout").par_iter())
                .zip(s.sigma_p.as_slice().expect("standard layout").par_iter())
                .zip(s.weights.as_slice().expect("standard layout").par_iter())
                .for_each(|((((p, &ax), &b), &sg), &w)| {
                    let d = w + sg;
                    *p = if d > 0.0 {
                        (*p + sg * (ax - b)) * (w / d)
                    } else {
                        0.0
                    };
                });
        }
        // Gradient duals, projected group by group.
        let xbars: Vec<&[f32]> = state.iter().map(|s| &s.xbar[..]).collect();
        let dual = |i: usize, group: &mut [f32]| {
            for (c, (x, ch)) in xbars.iter().zip(channels).enumerate() {
                let g = guided(directions, i, grad.at(x, i));
                for d in 0..3 {
                    group[3 * c + d] += sigma_q * scale * ch.weight * g[d];
                }
            }
            project(group, opts.coupling, radius);
        };
        match (pq.as_mut(), directions) {
            // With a guide, `P q` of the voxel in the same pass.
            (Some(pq), Some(dir)) => q
                .par_chunks_mut(3 * nc)
                .zip(pq.par_chunks_mut(3 * nc))
                .enumerate()
                .for_each(|(i, (group, out))| {
                    dual(i, group);
                    for (o, g) in out.chunks_mut(3).zip(group.chunks(3)) {
                        o.copy_from_slice(&dir.project(i, [g[0], g[1], g[2]]));
                    }
                }),
            _ => q
                .par_chunks_mut(3 * nc)
                .enumerate()
                .for_each(|(i, group)| dual(i, group)),
        }
        // Primal steps.
        for (c, (ch, s)) in channels.iter().zip(state.iter_mut()).enumerate() {
            let atp = ch.projector.adjoint(s.p.view())?;
            let atp = atp.as_slice().expect("standard layout");
            let (q, w, nonneg) = (pq.as_ref().unwrap_or(&q), scale * ch.weight, opts.nonneg);
            s.x.par_iter_mut()
                .zip(s.xbar.par_iter_mut())
                .zip(s.tau.par_iter())
                .enumerate()
                .for_each(|(i, ((x, xbar), &tau))| {
                    let step = atp[i] + w * grad.adjoint_at(q, nc, c, i);
                    let mut next = *x - tau * step;
                    if nonneg {
                        next = next.max(0.0);
                    }
                    *xbar = 2.0 * next - *x;
                    *x = next;
                });
        }
        progress(k + 1);
    }
    Ok(state
        .into_iter()
        .map(|s| Array3::from_shape_vec(shape, s.x).expect("grid shape"))
        .collect())
}

/// The objective `Σ_c ½‖A_c x_c − b_c‖²_W + λ Σ_voxels R(w ∇x)` at `volumes` (f64 sums).
pub fn objective(
    channels: &[ChannelData],
    volumes: &[Array3<f32>],
    opts: &TvOptions,
) -> Result<f64> {
    objective_guided(channels, volumes, opts, None)
}

/// [`objective`] of [`tv_guided`]: `∇` replaced by `P∇` where `directions` are given.
pub fn objective_guided(
    channels: &[ChannelData],
    volumes: &[Array3<f32>],
    opts: &TvOptions,
    directions: Option<&Directions>,
) -> Result<f64> {
    let shape = check(channels)?;
    let grad = Gradient::new(shape);
    check_directions(directions, grad.voxels())?;
    let mut data = 0.0f64;
    for (ch, x) in channels.iter().zip(volumes) {
        let r = ch.projector.forward(x.view())?;
        let w = opts.weighting.weights(ch.projections);
        data += r
            .iter()
            .zip(ch.projections.iter())
            .zip(w.iter())
            .map(|((&a, &b), &w)| 0.5 * w as f64 * ((a - b) as f64).powi(2))
            .sum::<f64>();
    }
    let nc = channels.len();
    let slices: Vec<&[f32]> = volumes
        .iter()
        .map(|x| x.as_slice().expect("standard layout"))
        .collect();
    let reg: f64 = (0..grad.voxels())
        .into_par_iter()
        .map_init(
            || vec![0.0f32; 3 * nc],
            |group, i| {
                for (c, (x, ch)) in slices.iter().zip(channels).enumerate() {
                    let g = guided(directions, i, grad.at(x, i));
                    for d in 0..3 {
                        group[3 * c + d] = ch.weight * g[d];
                    }
                }
                norm(group, opts.coupling)
            },
        )
        .sum();
    Ok(data + opts.weight * reg)
}

/// A channel's primal state and step sizes.
struct Primal {
    x: Vec<f32>,
    xbar: Vec<f32>,
    /// Primal steps τ (per voxel).
    tau: Vec<f32>,
    /// Data dual `p`, its steps σ_p and the rays' weights.
    p: Array3<f32>,
    sigma_p: Array3<f32>,
    weights: Array3<f32>,
}

impl Primal {
    /// `columns`: `A_cᵀ 1`; `reg_weight`: the channel's weight in `K`'s gradient block, `s w_c`.
    fn new(
        ch: &ChannelData,
        columns: Vec<f32>,
        reg_weight: f32,
        weighting: Weighting,
    ) -> Result<Self> {
        let a = ch.projector;
        let views: Vec<usize> = (0..a.views()).collect();
        let grid = &a.geometry().volume;
        let min_len = (grid.dx.min(grid.dy).min(grid.dz) / 2.0) as f32;
        let sigma_p = a
            .ray_lengths(&views)?
            .mapv(|l| if l > min_len { 1.0 / l } else { 0.0 });
        let reg_columns = 6.0 * reg_weight;
        let tau: Vec<f32> = columns
            .into_iter()
            .map(|v| {
                let s = v + reg_columns;
                if s > 1e-6 { 1.0 / s } else { 0.0 }
            })
            .collect();
        let n = grid.len();
        let x = match ch.start {
            Some(v) if v.len() == n => v.iter().copied().collect(),
            Some(v) => {
                return Err(Error::invalid(
                    "start",
                    format!("{:?} voxels, the grid has {n}", v.shape()),
                ));
            }
            None => vec![0.0; n],
        };
        Ok(Primal {
            xbar: x.clone(),
            x,
            tau,
            p: Array3::zeros(sigma_p.raw_dim()),
            sigma_p,
            weights: weighting.weights(ch.projections),
        })
    }
}

/// `Aᵀ 1`: the column sums of a projector (each voxel's summed intersection lengths, mm).
fn column_sums(a: &Joseph) -> Result<Vec<f32>> {
    let ones = Array3::<f32>::ones(a.projection_shape(a.views()));
    Ok(a.adjoint(ones.view())?.iter().copied().collect())
}

/// The scale `s` of `K`'s gradient block, `s w_c ∇`: the mean column sum of the projectors (over
/// the voxels that rays reach) over the gradient block's largest column sum `6 w_max`, so both
/// blocks weigh alike in the primal steps. Scaling a block of `K` (and the regulariser's dual
/// ball with it) leaves the problem and the convergence guarantee unchanged; it balances the
/// primal and dual steps. With `s = 1` the gradient duals grow by about `|∇x| / 2` per
/// iteration toward a ball of radius λ, a few hundred iterations for λ of 1 mm and μ of
/// soft tissue, and the regulariser acts only as a linear damping until they reach it.
fn balance(columns: &[Vec<f32>], w_max: f32) -> f32 {
    let (sum, count) = columns
        .iter()
        .flatten()
        .filter(|&&v| v > 0.0)
        .fold((0.0f64, 0usize), |(s, n), &v| (s + v as f64, n + 1));
    if count == 0 || w_max.is_nan() || w_max <= 0.0 {
        return 1.0;
    }
    ((sum / count as f64) / (6.0 * w_max as f64)).max(1e-6) as f32
}

/// A gradient at voxel `i`, projected where a guide is given.
#[inline]
fn guided(directions: Option<&Directions>, i: usize, g: [f32; 3]) -> [f32; 3] {
    match directions {
        Some(d) => d.project(i, g),
        None => g,
    }
}

/// The guide's grid must be the volumes'.
fn check_directions(directions: Option<&Directions>, voxels: usize) -> Result<()> {
    match directions {
        Some(d) if d.voxels() != voxels => Err(Error::invalid(
            "tv.guide",
            format!(
                "the guide has {} voxels, the volume grid {voxels}",
                d.voxels()
            ),
        )),
        _ => Ok(()),
    }
}

fn view(x: &[f32], shape: [usize; 3]) -> ArrayView3<'_, f32> {
    ArrayView3::from_shape(shape, x).expect("grid shape")
}

/// Check the channels share one grid, have data of their projector's shape and positive
/// weights; the grid shape `[nz, ny, nx]`.
fn check(channels: &[ChannelData]) -> Result<[usize; 3]> {
    let Some(first) = channels.first() else {
        return Err(Error::invalid("channels", "no channel to reconstruct"));
    };
    let shape = first.projector.geometry().volume.shape_zyx();
    for (c, ch) in channels.iter().enumerate() {
        let field = format!("channels[{c}]");
        if ch.projector.geometry().volume.shape_zyx() != shape {
            return Err(Error::invalid(
                field,
                "every channel must share one volume grid",
            ));
        }
        let want = ch.projector.projection_shape(ch.projector.views());
        prism_domain::error::ensure_shape(
            &format!("{field}.projections"),
            ch.projections.shape(),
            &want,
            "[views, rows, cols]",
        )?;
        if !(ch.weight.is_finite() && ch.weight > 0.0) {
            return Err(Error::invalid(
                format!("{field}.weight"),
                format!("must be finite and > 0 (got {})", ch.weight),
            ));
        }
    }
    Ok(shape)
}

/// `R` at one voxel's gradient group (`[channel][axis]`, 3·C values).
fn norm(group: &[f32], coupling: Coupling) -> f64 {
    let sq = |v: &[f32]| v.iter().map(|&a| (a as f64).powi(2)).sum::<f64>();
    match coupling {
        Coupling::Channel => group.chunks(3).map(|g| sq(g).sqrt()).sum(),
        Coupling::Joint => sq(group).sqrt(),
        Coupling::Nuclear => {
            let (eig, _) = sym3_eigen(gram(group));
            eig.iter().map(|&e| e.max(0.0).sqrt()).sum()
        }
    }
}

/// Project one voxel's dual group onto the ball of radius λ in `R`'s dual norm.
fn project(group: &mut [f32], coupling: Coupling, lambda: f32) {
    let clip = |v: &mut [f32]| {
        let n = v.iter().map(|&a| a * a).sum::<f32>().sqrt();
        if n > lambda {
            let f = lambda / n;
            v.iter_mut().for_each(|a| *a *= f);
        }
    };
    match coupling {
        Coupling::Channel => group.chunks_mut(3).for_each(clip),
        Coupling::Joint => clip(group),
        Coupling::Nuclear => clip_singular_values(group, lambda as f64),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nuclear_clipping_bounds_the_spectral_norm_and_keeps_what_is_inside() {
        // J (3 × 2) with singular values 5 and 1: clipping at 2 leaves 2 and 1, same vectors.
        let mut group = [3.0f32, 4.0, 0.0, 0.0, 0.0, 1.0]; // columns (3,4,0) and (0,0,1)
        clip_singular_values(&mut group, 2.0);
        let want = [1.2f32, 1.6, 0.0, 0.0, 0.0, 1.0];
        for (a, b) in group.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{group:?}");
        }
        let inside = [0.3f32, -0.2, 0.1, 0.05, 0.4, -0.3];
        let mut g = inside;
        clip_singular_values(&mut g, 2.0);
        assert_eq!(g, inside);
        // The nuclear norm is the sum of singular values (5 + 1).
        let n = norm(&[3.0, 4.0, 0.0, 0.0, 0.0, 1.0], Coupling::Nuclear);
        assert!((n - 6.0).abs() < 1e-9, "{n}");
    }

    #[test]
    fn every_coupling_agrees_on_one_channel_and_rank_one_jacobians() {
        // One channel: all three are the gradient's length. Parallel gradients (rank-one J):
        // the nuclear and Frobenius norms agree, and the per-channel sum is their upper bound.
        let one = [0.3f32, -0.4, 1.2];
        let n = norm(&one, Coupling::Channel);
        for c in [Coupling::Joint, Coupling::Nuclear] {
            assert!((norm(&one, c) - n).abs() < 1e-9);
        }
        let rank1 = [0.3f32, -0.4, 1.2, 0.6, -0.8, 2.4];
        let (j, nu) = (
            norm(&rank1, Coupling::Joint),
            norm(&rank1, Coupling::Nuclear),
        );
        assert!((j - nu).abs() < 1e-6, "{j} vs {nu}");
        assert!(norm(&rank1, Coupling::Channel) > j);
        // Orthogonal gradients: nuclear = channel sum > Frobenius.
        let orth = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0];
        assert!((norm(&orth, Coupling::Nuclear) - 2.0).abs() < 1e-9);
        assert!((norm(&orth, Coupling::Joint) - 2f64.sqrt()).abs() < 1e-9);
        // Each projection lands in its own dual ball.
        for c in [Coupling::Channel, Coupling::Joint, Coupling::Nuclear] {
            let mut g = [3.0f32, 4.0, 0.0, 0.0, 0.0, 1.0];
            project(&mut g, c, 0.5);
            let dual = match c {
                Coupling::Channel => g
                    .chunks(3)
                    .map(|v| norm(v, Coupling::Joint))
                    .fold(0.0, f64::max),
                Coupling::Joint => norm(&g, Coupling::Joint),
                Coupling::Nuclear => sym3_eigen(gram(&g))
                    .0
                    .iter()
                    .fold(0.0f64, |a, &e| a.max(e))
                    .sqrt(),
            };
            assert!(dual <= 0.5 + 1e-6, "{c:?}: {dual}");
        }
    }
}
