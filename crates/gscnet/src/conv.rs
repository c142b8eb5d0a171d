//! The depthwise convolution over neighbouring spectral channels, fused with SiLU
//! (Φ_conv in [`crate::block`]).
//!
//! The parameters stay in Burn's [`Conv1d`] (depthwise, centred, zero padded, as built by the
//! block), so the module's record layout is unchanged; the computation runs as one fused op on
//! the `[K, M, E]` tokens ([`crate::cpu::conv`]) instead of transposing to `[K, E, M]` for a
//! grouped `Conv1d` with tiny length M and a separate SiLU.

use burn::nn::{PaddingConfig1d, conv::Conv1d};
use burn::tensor::Tensor;

/// SiLU(depthwise_conv_m(u)) for tokens `u` `[K, M, E]`, with the taps and bias of `conv`
/// (weight `[E, 1, J]`, J odd, `groups = E`, stride 1, dilation 1, padding (J − 1)/2; a missing
/// bias is zero). Panics if `conv` is not such a convolution (internal API: the block builds it).
pub fn spectral_conv_silu(u: Tensor<3>, conv: &Conv1d) -> Tensor<3> {
    let [_, _, e] = u.dims();
    let [e_out, per_group, taps] = conv.weight.val().dims();
    assert!(
        e_out == e && per_group == 1 && conv.groups == e && taps % 2 == 1,
        "spectral_conv_silu: needs a depthwise conv over {e} channels with an odd kernel, \
         got weight [{e_out}, {per_group}, {taps}] in {} groups",
        conv.groups
    );
    let r = taps / 2;
    assert!(
        conv.stride == 1
            && conv.dilation == 1
            && match conv.padding {
                PaddingConfig1d::Same => true,
                PaddingConfig1d::Explicit(left, right) => left == r && right == r,
                PaddingConfig1d::Valid => false,
            },
        "spectral_conv_silu: needs stride 1, dilation 1 and centred zero padding {r}"
    );
    let w = conv.weight.val().reshape([e, taps]);
    let bias = match &conv.bias {
        Some(b) => b.val(),
        None => Tensor::zeros([e], &u.device()),
    };
    crate::ops::fused_conv_silu(u, w, bias)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::{self, SeedStream};
    use burn::tensor::activation::silu;
    use burn::tensor::{Device, TensorData};

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_into_vec().unwrap()
    }

    fn random<const D: usize>(
        rng: &mut SeedStream,
        shape: [usize; D],
        device: &Device,
    ) -> Tensor<D> {
        let n = shape.iter().product();
        let v: Vec<f32> = (0..n).map(|_| rng.range(-2.0, 2.0) as f32).collect();
        Tensor::from_data(TensorData::new(v, shape), device)
    }

    /// The formulation this op replaces: Burn's grouped `Conv1d` on the `[K, E, M]` transpose.
    fn conv1d_silu(u: Tensor<3>, conv: &Conv1d) -> Tensor<3> {
        silu(conv.forward(u.swap_dims(1, 2)).swap_dims(1, 2))
    }

    fn max_abs(v: &[f32]) -> f32 {
        v.iter().fold(0.0f32, |a, x| a.max(x.abs()))
    }

    /// Forward values and the gradients of u, taps and bias agree with `Conv1d` + SiLU through
    /// Burn's autodiff, for kernels shorter than, equal to and longer than the sequence.
    #[test]
    fn fused_conv_matches_burn_conv1d_and_its_gradients() {
        let device = crate::test_util::cpu().autodiff();
        let (k, e) = (5, 4);
        for (m, taps) in [(2, 3), (3, 3), (8, 3), (3, 5), (4, 1), (2, 7)] {
            let mut rng = SeedStream::new(100 + (m * 10 + taps) as u64);
            let conv = init::depthwise_conv1d(&mut rng, e, taps, &device);
            let u = random(&mut rng, [k, m, e], &device).require_grad();
            let r = random(&mut rng, [k, m, e], &device);

            let ours = spectral_conv_silu(u.clone(), &conv);
            let theirs = conv1d_silu(u.clone(), &conv);
            // Same sums of ≤ J+1 terms of size ≲ 2 in a different order: |Δ| ≲ J·ε_f32·4 < 1e-6.
            let (a, b) = (values(ours.clone()), values(theirs.clone()));
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-6, "M = {m}, J = {taps}: {x} vs {y}");
            }

            let g_ours = ours.mul(r.clone()).sum().backward();
            let g_theirs = theirs.mul(r).sum().backward();
            let pairs = [
                (u.grad(&g_ours), u.grad(&g_theirs), "u"),
                (
                    conv.weight.val().grad(&g_ours),
                    conv.weight.val().grad(&g_theirs),
                    "weight",
                ),
            ];
            for (ours, theirs, name) in pairs {
                let (a, b) = (values(ours.unwrap()), values(theirs.unwrap()));
                // Sums over up to K·M terms: relative round-off ≲ K·M·ε_f32 ≈ 5e-6.
                let tol = 1e-5 * max_abs(&b).max(1.0);
                for (x, y) in a.iter().zip(&b) {
                    assert!(
                        (x - y).abs() <= tol,
                        "M = {m}, J = {taps}, ∂{name}: {x} vs {y}"
                    );
                }
            }
            let bias = conv.bias.as_ref().unwrap().val();
            let (a, b) = (
                values(bias.grad(&g_ours).unwrap()),
                values(bias.grad(&g_theirs).unwrap()),
            );
            let tol = 1e-5 * max_abs(&b).max(1.0);
            for (x, y) in a.iter().zip(&b) {
                assert!(
                    (x - y).abs() <= tol,
                    "M = {m}, J = {taps}, ∂bias: {x} vs {y}"
                );
            }
        }
    }

    #[test]
    fn fused_conv_runs_without_autodiff_and_with_empty_batches() {
        let device = crate::test_util::cpu();
        let mut rng = SeedStream::new(7);
        let conv = init::depthwise_conv1d(&mut rng, 3, 3, &device);
        let u = random(&mut rng, [4, 6, 3], &device);
        let (a, b) = (
            values(spectral_conv_silu(u.clone(), &conv)),
            values(conv1d_silu(u, &conv)),
        );
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-6));
        let empty = spectral_conv_silu(Tensor::zeros([0, 6, 3], &device), &conv);
        assert_eq!(empty.dims(), [0, 6, 3]);
    }
}
