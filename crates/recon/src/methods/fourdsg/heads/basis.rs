//! The basis-material head in training (4D-SG stage 2 with `stage2.basis`), in place of the curve
//! model ([`super::CurveFit`]): every Gaussian carries one density per basis material (water, cortical bone, iodine by
//! default) instead of a curve, and each channel's projection is formed from them the way the
//! simulator forms it ([`ChannelSpec::nodes`]): `p_c = −ln Σ_n w_n·exp(−Σ_b μ_b(E_n)·L_b)`, with
//! `L_b` the rendered path length of material b, which is linear (`Σ_b μ_b·L_b`) for mono and
//! mixed channels and models beam hardening for polychromatic and window channels. The
//! attenuation is then `μ(x, E) = Σ_b f_b(x)·μ_b(E)` at every energy the attenuation table covers,
//! and the fractions `f_b` are the material maps.
//!
//! **Units.** Gaussian column b holds `v_b = f_b·μ̂_b / density_scale` (normalised attenuation),
//! with `μ̂_b` the mean over the channels of material b's effective μ ([`BasisHead::reference_mu`]):
//! every column is O(1) like a normalised density, and since the channels' mean coefficient of
//! every column is 1, `Σ_b v_b` is the channel-mean attenuation that stage 1 fitted. Stage 2
//! starts from that: the first material takes `1 − (B−1)·init_share` of the stage-1 density and
//! every other `init_share`.

use crate::Result;
use crate::device::{host_values, upload};
use crate::gaussians::World;
use crate::gaussians::host::{inverse_softplus, softplus};
use crate::gaussians::model::GaussianModel;
use crate::gaussians::train::ChannelMix;
use crate::methods::fourdsg::stage2::config::BasisConfig;
use burn::tensor::{Device, Tensor, s};
use prism_domain::decompose::{Basis, Decomposition};
use prism_domain::physics::ChannelSpec;
use std::ops::Range;

/// The basis head prepared for a scene's channels in a world.
pub struct BasisHead {
    basis: Basis,
    /// μ̂_b, mm⁻¹ (see the module docs).
    reference_mu: Vec<f64>,
    /// `[channel][basis]`: effective μ / μ̂_b (the channels' reference volumes per unit v_b).
    effective: Vec<Vec<f64>>,
    /// Physical line integral per normalised one: `density_scale / world scale`.
    k: f64,
    /// `[B, N]` μ_b(E_n) / μ̂_b over every channel's nodes; `[1, N]` ln w_n.
    nodes: Tensor<2>,
    log_weights: Tensor<2>,
    /// Each channel's columns of `nodes`; a single node (of weight 1) is a linear channel.
    segments: Vec<Range<usize>>,
    channel_kev: Vec<f64>,
    /// Share of the stage-1 density each basis material starts with.
    init_shares: Vec<f64>,
}

impl BasisHead {
    /// The head of `config` for channels `specs` in `world`, its tensors on `device` (the
    /// autodiff form when it trains). Refused when the channels cannot separate the basis
    /// ([`Decomposition::new`]).
    pub fn new(
        config: &BasisConfig,
        section: &str,
        specs: &[ChannelSpec],
        world: &World,
        device: &Device,
    ) -> Result<BasisHead> {
        let basis = config.validate(section)?;
        let dec = Decomposition::new(basis.clone(), specs).map_err(|e| e.under(section))?;
        let mats = basis.materials();
        let m = specs.len() as f64;
        let reference_mu: Vec<f64> = (0..mats.len())
            .map(|b| dec.matrix().iter().map(|row| row[b]).sum::<f64>() / m)
            .collect();
        let effective = dec
            .matrix()
            .iter()
            .map(|row| row.iter().zip(&reference_mu).map(|(a, r)| a / r).collect())
            .collect();
        let mut columns: Vec<Vec<f64>> = Vec::new();
        let mut log_w = Vec::new();
        let mut segments = Vec::new();
        for (i, spec) in specs.iter().enumerate() {
            let nodes = spec
                .nodes(mats)
                .map_err(|e| e.under(&format!("channels[{i}]")))?;
            let start = columns.len();
            segments.push(start..start + nodes.len());
            for (w, mu) in nodes {
                log_w.push(w.ln() as f32);
                columns.push(mu.iter().zip(&reference_mu).map(|(u, r)| u / r).collect());
            }
        }
        let channel_kev = specs
            .iter()
            .enumerate()
            .map(|(i, s)| s.mean_kev().map_err(|e| e.under(&format!("channels[{i}]"))))
            .collect::<prism_domain::Result<_>>()?;
        let (b, n) = (mats.len(), columns.len());
        let g: Vec<f32> = (0..b)
            .flat_map(|row| columns.iter().map(move |c| c[row] as f32))
            .collect();
        let init_shares = (0..b)
            .map(|i| match i {
                0 => 1.0 - (b - 1) as f64 * config.init_share,
                _ => config.init_share,
            })
            .collect();
        Ok(BasisHead {
            k: world.density_scale / world.scale,
            nodes: upload(g, n, device),
            log_weights: upload(log_w, n, device),
            init_shares,
            basis,
            reference_mu,
            effective,
            segments,
            channel_kev,
        })
    }

    pub fn basis(&self) -> &Basis {
        &self.basis
    }

    /// μ̂_b per basis material, mm⁻¹.
    pub fn reference_mu(&self) -> &[f64] {
        &self.reference_mu
    }

    /// Number of channels the head renders.
    pub fn channels(&self) -> usize {
        self.segments.len()
    }

    /// The start of stage 2 from the stage-1 raw densities `[K]`: raw basis columns `[K, B]`
    /// (see the module docs).
    pub fn initial_raw(&self, structural: &[f32]) -> Vec<f32> {
        let shares = &self.init_shares;
        structural
            .iter()
            .flat_map(|&u| {
                let d = softplus(u as f64);
                shares.iter().map(move |s| inverse_softplus(d * s) as f32)
            })
            .collect()
    }

    /// Raw densities `[K, 1]` of a channel the head was not trained on (a held-out one), from
    /// the same physics as [`ChannelMix::channel_raw`]: its reference attenuation
    /// `Σ_b v_b·μ̄_b(spec)/μ̂_b` (normalised), with μ̄_b(spec) the effective attenuation of
    /// material b in that channel ([`ChannelSpec::effective_mu`]). Errors name `spec`'s field.
    pub fn unseen_raw(&self, spec: &ChannelSpec, model: &GaussianModel) -> Result<Tensor<2>> {
        let coef: Vec<f64> = self
            .basis
            .materials()
            .iter()
            .zip(&self.reference_mu)
            .map(|(&m, r)| Ok(spec.effective_mu(m)? / r))
            .collect::<prism_domain::Result<_>>()?;
        Ok(mix_raw(&model.densities.value, |v, out| {
            out.push(coef.iter().zip(v).map(|(a, v)| a * v).sum());
        }))
    }

    /// Raw common densities `[K, 1]` of a model whose density columns are the raw basis columns:
    /// the channels' mean attenuation `Σ_b v_b·mean_c(μ̄_cb/μ̂_b)` (normalised), through the
    /// inverse softplus; the density a structural stage would have fitted.
    pub fn common_raw(&self, model: &GaussianModel) -> Tensor<2> {
        let m = self.effective.len() as f64;
        let mean: Vec<f64> = (0..self.reference_mu.len())
            .map(|b| self.effective.iter().map(|row| row[b]).sum::<f64>() / m)
            .collect();
        mix_raw(&model.densities.value, |v, out| {
            out.push(mean.iter().zip(v).map(|(a, v)| a * v).sum());
        })
    }

    /// The energy each channel is centred on, keV ([`ChannelSpec::mean_kev`]).
    pub fn channel_kev(&self) -> &[f64] {
        &self.channel_kev
    }
}

/// The head as the training loop sees it: basis columns in, channels out.
impl ChannelMix for BasisHead {
    fn shape(&self) -> (usize, usize) {
        (self.channels(), self.basis.materials().len())
    }

    /// Channel line integrals `[V, M, rows, cols]` (normalised) from the rendered basis columns
    /// `[V, B, rows, cols]` (normalised path integrals of v_b).
    fn project(&self, rendered: Tensor<4>) -> Tensor<4> {
        let [v, b, rows, cols] = rendered.dims();
        let p = v * rows * cols;
        let y = rendered
            .permute([0, 2, 3, 1])
            .reshape([p, b])
            .matmul(self.nodes.clone());
        let m = self.segments.len();
        // Every channel linear (one node each): the nodes are the channels.
        let channels = if y.dims()[1] == m {
            y
        } else {
            let k = self.k as f32;
            let out: Vec<Tensor<2>> = self
                .segments
                .iter()
                .map(|r| {
                    let y = y.clone().slice(s![.., r.clone()]);
                    if r.len() == 1 {
                        return y;
                    }
                    // −(1/k)·ln Σ_n exp(ln w_n − k·y_n), shifted by the (constant) largest
                    // exponent.
                    let z = y * (-k) + self.log_weights.clone().slice(s![.., r.clone()]);
                    let top = z.clone().max_dim(1).detach();
                    ((z - top.clone()).exp().sum_dim(1).log() + top) * (-1.0 / k)
                })
                .collect();
            Tensor::cat(out, 1)
        };
        channels.reshape([v, rows, cols, m]).permute([0, 3, 1, 2])
    }

    /// Raw per-channel densities `[K, M]` of a model whose density columns are the raw basis
    /// columns: each channel's reference attenuation `Σ_b v_b·μ̄_cb/μ̂_b` (normalised), through
    /// the inverse softplus. The channels' volumes are these Gaussians voxelized.
    fn channel_raw(&self, model: &GaussianModel) -> Tensor<2> {
        let coef = &self.effective;
        mix_raw(&model.densities.value, |v, out| {
            for row in coef {
                out.push(row.iter().zip(v).map(|(a, v)| a * v).sum());
            }
        })
    }
}

/// Raw columns `[K, n]` built from each Gaussian's activated basis densities `v` (softplus of
/// the raw basis columns `raw` `[K, B]`) by `mix`, which pushes n activated values; through the
/// inverse softplus, on `raw`'s device.
pub(crate) fn mix_raw(raw: &Tensor<2>, mix: impl Fn(&[f64], &mut Vec<f64>)) -> Tensor<2> {
    let b = raw.dims()[1];
    let values = host_values(raw);
    let mut v = vec![0.0; b];
    let mut cols = Vec::new();
    let mut out = Vec::with_capacity(values.len());
    let mut n = 0;
    for g in values.chunks(b) {
        for (v, &r) in v.iter_mut().zip(g) {
            *v = softplus(r as f64);
        }
        cols.clear();
        mix(&v, &mut cols);
        n = cols.len();
        out.extend(cols.iter().map(|&d| inverse_softplus(d) as f32));
    }
    upload(out, n.max(1), &raw.device())
}

#[cfg(test)]
mod tests;
