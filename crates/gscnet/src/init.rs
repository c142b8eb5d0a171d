//! Seeded parameter initialisation. Parameters are drawn on the host from a [`SeedStream`], so a
//! model built from the same config, grid and seed is bit-identical on every backend and does
//! not depend on a backend's global RNG (which parallel tests and trainers would share).

use burn::module::Param;
use burn::nn::{Linear, PaddingConfig1d, conv::Conv1d};
use burn::tensor::{Device, Tensor, TensorData};

/// SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): a tiny, well-mixed, seedable 64-bit stream,
/// ample for drawing initial weights. (Kept local rather than pulling `rand` into this crate's
/// dependency set, which changes `rand`'s unified features and forces a rebuild of all of Burn.)
pub(crate) struct SeedStream(u64);

impl SeedStream {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi) (53 random mantissa bits).
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }
}

/// A parameter with values `f(i)` for `i` in row-major order.
pub(crate) fn param_from_fn<const D: usize>(
    shape: [usize; D],
    device: &Device,
    f: impl FnMut(usize) -> f32,
) -> Param<Tensor<D>> {
    let n = shape.iter().product();
    let values: Vec<f32> = (0..n).map(f).collect();
    Param::from_tensor(Tensor::from_data(TensorData::new(values, shape), device))
}

/// A parameter drawn uniformly from [−bound, bound].
pub(crate) fn uniform<const D: usize>(
    rng: &mut SeedStream,
    shape: [usize; D],
    bound: f32,
    device: &Device,
) -> Param<Tensor<D>> {
    param_from_fn(shape, device, |_| {
        if bound > 0.0 {
            rng.range(-f64::from(bound), f64::from(bound)) as f32
        } else {
            0.0
        }
    })
}

/// A dense layer `y = x W + b` (W: [d_in, d_out]) with PyTorch's default bound 1/√d_in times
/// `gain` for both weight and bias. A small `gain` makes an output layer start near zero.
pub(crate) fn linear(
    rng: &mut SeedStream,
    d_in: usize,
    d_out: usize,
    bias: bool,
    gain: f32,
    device: &Device,
) -> Linear {
    let bound = gain / (d_in as f32).sqrt();
    Linear {
        weight: uniform(rng, [d_in, d_out], bound, device),
        bias: bias.then(|| uniform(rng, [d_out], bound, device)),
    }
}

/// `linear` applied to every token of `x` `[K, M, d_in]` → `[K, M, d_out]`, as one 2-D matmul on
/// the `[K·M, d_in]` rows. (Burn's `Linear` on a 3-D input broadcasts the weight over K, and its
/// autodiff then forms a `[K, d_in, d_out]` weight gradient before summing it: ~K times the
/// memory traffic of the 2-D form.)
pub(crate) fn apply_rows(linear: &Linear, x: Tensor<3>) -> Tensor<3> {
    let [k, m, d_in] = x.dims();
    let [_, d_out] = linear.weight.val().dims();
    linear
        .forward(x.reshape([k * m, d_in]))
        .reshape([k, m, d_out])
}

/// A depthwise (one filter per channel), centred, zero-padded 1-D convolution over an odd
/// `kernel` on `[batch, channels, length]`; output length equals input length.
pub(crate) fn depthwise_conv1d(
    rng: &mut SeedStream,
    channels: usize,
    kernel: usize,
    device: &Device,
) -> Conv1d {
    let bound = 1.0 / (kernel as f32).sqrt();
    let half = kernel / 2;
    Conv1d {
        weight: uniform(rng, [channels, 1, kernel], bound, device),
        bias: Some(uniform(rng, [channels], bound, device)),
        stride: 1,
        kernel_size: kernel,
        dilation: 1,
        groups: channels,
        padding: PaddingConfig1d::Explicit(half, half),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_stream_is_splitmix64() {
        // Reference output of SplitMix64 seeded with 0 (Vigna's splitmix64.c).
        let mut s = SeedStream::new(0);
        assert_eq!(s.next_u64(), 0xE220_A839_7B1D_CDAF);
        let mut s = SeedStream::new(42);
        let v: Vec<f64> = (0..1000).map(|_| s.range(-2.0, 3.0)).collect();
        assert!(v.iter().all(|x| (-2.0..3.0).contains(x)));
        let mean = v.iter().sum::<f64>() / 1000.0;
        // Uniform mean 0.5, standard error 5/√12/√1000 ≈ 0.046: allow 4σ.
        assert!((mean - 0.5).abs() < 0.19, "{mean}");
    }
}
