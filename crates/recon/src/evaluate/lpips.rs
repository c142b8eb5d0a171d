//! LPIPS (Zhang et al., CVPR 2018), version 0.1 as the `lpips` package computes it: both images go
//! through a fixed scaling layer and an ImageNet trunk (AlexNet or VGG-16); at five taps (after
//! ReLUs) the features are normalised to unit length over channels, their squared differences are
//! weighted per channel by the calibrated linear layers (1×1 convolutions without bias) and
//! averaged over space; the distance is the sum over taps. Lower is more similar; identical
//! images give 0.
//!
//! Grey slices are replicated to three channels and mapped from [0, 1] to [−1, 1] (the package's
//! `normalize=True`). Weights cannot be downloaded at run time: [`Lpips::load`] reads a
//! safetensors file made by `scripts/lpips_weights.py` from the `lpips` package's linear layers
//! and torchvision's trunk weights (tensors `features.<i>.weight`, `features.<i>.bias` named as
//! in torchvision, `lin.<k>.weight` `[1, C, 1, 1]`; metadata `format: prism-lpips/1`,
//! `net: alex | vgg`).

use crate::{Error, Result};
use burn::module::{Module, Param};
use burn::tensor::activation::relu;
use burn::tensor::module::{conv2d, max_pool2d};
use burn::tensor::ops::{ConvOptions, MaxPoolOptions};
use burn::tensor::{Device, Tensor, TensorData};
use ndarray::ArrayView2;
use safetensors::{Dtype, SafeTensors};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

const FORMAT: &str = "prism-lpips/1";
/// The package's scaling layer: `(x − shift) / scale` per RGB channel.
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// `normalize_tensor`'s ε.
const EPS: f32 = 1e-10;

/// The trunk network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Net {
    /// AlexNet (the package's default; the paper's LPIPS).
    Alex,
    /// VGG-16.
    Vgg,
}

/// One step of a trunk.
#[derive(Clone, Copy, Debug)]
enum Step {
    /// `features.<index>` of torchvision: a convolution to `out` channels (`kernel`, `stride`,
    /// `padding`), then ReLU.
    Conv {
        index: usize,
        out: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
    },
    /// Max pooling (`kernel`, `stride`).
    Pool { kernel: usize, stride: usize },
    /// A feature tap (the package's `relu<k>` outputs).
    Tap,
}

const fn conv(index: usize, out: usize, kernel: usize, stride: usize, padding: usize) -> Step {
    Step::Conv {
        index,
        out,
        kernel,
        stride,
        padding,
    }
}

/// AlexNet's `features` up to `relu5` (torchvision indices), tapped as the package taps it.
const ALEX: &[Step] = &[
    conv(0, 64, 11, 4, 2),
    Step::Tap,
    Step::Pool {
        kernel: 3,
        stride: 2,
    },
    conv(3, 192, 5, 1, 2),
    Step::Tap,
    Step::Pool {
        kernel: 3,
        stride: 2,
    },
    conv(6, 384, 3, 1, 1),
    Step::Tap,
    conv(8, 256, 3, 1, 1),
    Step::Tap,
    conv(10, 256, 3, 1, 1),
    Step::Tap,
];

const P2: Step = Step::Pool {
    kernel: 2,
    stride: 2,
};

/// VGG-16's `features` up to `relu5_3`.
const VGG: &[Step] = &[
    conv(0, 64, 3, 1, 1),
    conv(2, 64, 3, 1, 1),
    Step::Tap,
    P2,
    conv(5, 128, 3, 1, 1),
    conv(7, 128, 3, 1, 1),
    Step::Tap,
    P2,
    conv(10, 256, 3, 1, 1),
    conv(12, 256, 3, 1, 1),
    conv(14, 256, 3, 1, 1),
    Step::Tap,
    P2,
    conv(17, 512, 3, 1, 1),
    conv(19, 512, 3, 1, 1),
    conv(21, 512, 3, 1, 1),
    Step::Tap,
    P2,
    conv(24, 512, 3, 1, 1),
    conv(26, 512, 3, 1, 1),
    conv(28, 512, 3, 1, 1),
    Step::Tap,
];

impl Net {
    fn steps(self) -> &'static [Step] {
        match self {
            Net::Alex => ALEX,
            Net::Vgg => VGG,
        }
    }

    /// Channels at each tap: the output channels of the convolution before it.
    pub fn channels(self) -> Vec<usize> {
        let mut last = 0;
        let mut out = Vec::new();
        for step in self.steps() {
            match *step {
                Step::Conv { out: c, .. } => last = c,
                Step::Tap => out.push(last),
                Step::Pool { .. } => {}
            }
        }
        out
    }

    pub fn name(self) -> &'static str {
        match self {
            Net::Alex => "alex",
            Net::Vgg => "vgg",
        }
    }
}

/// A trunk convolution's parameters.
#[derive(Module, Debug)]
struct ConvLayer {
    weight: Param<Tensor<4>>,
    bias: Param<Tensor<1>>,
}

/// The LPIPS network with its weights (see the module docs).
#[derive(Module, Debug)]
pub struct Lpips {
    convs: Vec<ConvLayer>,
    /// The linear layers `[1, C, 1, 1]`, one per tap.
    lins: Vec<Param<Tensor<4>>>,
    #[module(skip)]
    net: Net,
}

/// Named f32 tensors: `(values, shape)`.
pub type Tensors = HashMap<String, (Vec<f32>, Vec<usize>)>;

impl Lpips {
    /// Read the weights file `path` (see the module docs); errors name the file and the tensor.
    pub fn load(path: &Path, device: &Device) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let st = SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::field(path, ".", format!("not a safetensors file: {e}")))?;
        let (_, header) = SafeTensors::read_metadata(&bytes)
            .map_err(|e| Error::field(path, ".", format!("unreadable header: {e}")))?;
        let meta = header.metadata().clone().unwrap_or_default();
        let get = |k: &str| {
            meta.get(k)
                .cloned()
                .ok_or_else(|| Error::field(path, format!("metadata.{k}"), "missing"))
        };
        let format = get("format")?;
        if format != FORMAT {
            return Err(Error::field(
                path,
                "metadata.format",
                format!("expected `{FORMAT}` (made by scripts/lpips_weights.py), got `{format}`"),
            ));
        }
        let net: Net = serde_json::from_value(serde_json::Value::String(get("net")?))
            .map_err(|e| Error::field(path, "metadata.net", e.to_string()))?;
        let mut tensors = Tensors::new();
        for (name, t) in st.tensors() {
            if t.dtype() != Dtype::F32 {
                return Err(Error::field(
                    path,
                    name,
                    format!("expected f32, got {:?}", t.dtype()),
                ));
            }
            let values = t
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            tensors.insert(name, (values, t.shape().to_vec()));
        }
        Self::from_tensors(net, &tensors, device).map_err(|e| e.in_file(path))
    }

    /// The network from named tensors (see the module docs for the names and shapes).
    pub fn from_tensors(net: Net, tensors: &Tensors, device: &Device) -> Result<Self> {
        let take = |name: &str, shape: &[usize]| -> Result<TensorData> {
            let (values, got) = tensors
                .get(name)
                .ok_or_else(|| Error::invalid(name, "missing"))?;
            if got != shape {
                return Err(Error::invalid(
                    name,
                    format!("expected shape {shape:?}, got {got:?}"),
                ));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(Error::invalid(name, format!("entry {i} is not finite")));
            }
            Ok(TensorData::new(values.clone(), shape.to_vec()))
        };
        let mut convs = Vec::new();
        let mut channels = 3;
        for step in net.steps() {
            if let Step::Conv {
                index, out, kernel, ..
            } = *step
            {
                let w = take(
                    &format!("features.{index}.weight"),
                    &[out, channels, kernel, kernel],
                )?;
                let b = take(&format!("features.{index}.bias"), &[out])?;
                convs.push(ConvLayer {
                    weight: Param::from_tensor(Tensor::from_data(w, device)),
                    bias: Param::from_tensor(Tensor::from_data(b, device)),
                });
                channels = out;
            }
        }
        let lins = net
            .channels()
            .iter()
            .enumerate()
            .map(|(k, &c)| {
                let w = take(&format!("lin.{k}.weight"), &[1, c, 1, 1])?;
                Ok(Param::from_tensor(Tensor::from_data(w, device)))
            })
            .collect::<Result<_>>()?;
        Ok(Lpips { convs, lins, net })
    }

    pub fn net(&self) -> Net {
        self.net
    }

    /// The five tap features of images `x` `[N, 3, H, W]` (already scaled).
    fn features(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let mut h = x;
        let mut taps = Vec::new();
        let mut convs = self.convs.iter();
        for step in self.net.steps() {
            match *step {
                Step::Conv {
                    stride, padding, ..
                } => {
                    let c = convs.next().expect("one layer per convolution");
                    let opts = ConvOptions::new([stride; 2], [padding; 2], [1, 1], 1);
                    h = relu(conv2d(h, c.weight.val(), Some(c.bias.val()), opts));
                }
                Step::Pool { kernel, stride } => {
                    h = max_pool2d(h, MaxPoolOptions::new([kernel; 2]).with_stride([stride; 2]));
                }
                Step::Tap => taps.push(h.clone()),
            }
        }
        taps
    }

    /// LPIPS between the grey images `a[i]` and `b[i]` (values in [0, 1], all of one shape).
    pub fn distances(&self, a: &[ArrayView2<f32>], b: &[ArrayView2<f32>]) -> Result<Vec<f64>> {
        if a.len() != b.len() {
            return Err(Error::invalid(
                "lpips",
                format!("{} images against {}", a.len(), b.len()),
            ));
        }
        let Some(first) = a.first() else {
            return Ok(Vec::new());
        };
        let (h, w) = first.dim();
        if a.iter().chain(b).any(|x| x.dim() != (h, w)) {
            return Err(Error::invalid("lpips", "images of different shapes"));
        }
        let device = self.lins[0].val().device();
        let n = a.len();
        let batch = |imgs: &[ArrayView2<f32>]| -> Tensor<4> {
            let mut values = Vec::with_capacity(n * 3 * h * w);
            for img in imgs {
                for c in 0..3 {
                    values.extend(img.iter().map(|&v| (2.0 * v - 1.0 - SHIFT[c]) / SCALE[c]));
                }
            }
            Tensor::from_data(TensorData::new(values, [n, 3, h, w]), &device)
        };
        let (fa, fb) = (self.features(batch(a)), self.features(batch(b)));
        let mut total: Option<Tensor<1>> = None;
        for ((x, y), lin) in fa.into_iter().zip(fb).zip(&self.lins) {
            let d = (unit(x) - unit(y)).powi_scalar(2);
            let r = conv2d(
                d,
                lin.val(),
                None,
                ConvOptions::new([1, 1], [0, 0], [1, 1], 1),
            );
            let [_, _, rh, rw] = r.dims();
            let s = r.reshape([n, rh * rw]).mean_dim(1).reshape([n]);
            total = Some(match total {
                Some(t) => t + s,
                None => s,
            });
        }
        let values = crate::device::host_values(&total.expect("five taps"));
        Ok(values.into_iter().map(f64::from).collect())
    }
}

/// Features divided by their length over channels (`+ ε`), as the package's `normalize_tensor`.
fn unit(x: Tensor<4>) -> Tensor<4> {
    let norm = x.clone().powi_scalar(2).sum_dim(1).sqrt() + EPS;
    x / norm
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use ndarray::Array2;

    /// The fixture's network (random trunk, the package's linear layers) on the CPU.
    pub(crate) fn fixture_model(net: Net) -> Lpips {
        Lpips::from_tensors(net, &fixture_net(net), &crate::device::cpu_device()).unwrap()
    }

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/lpips")
            .join(name)
    }

    /// `u = splitmix64(fnv1a(name) + i) >> 11 / 2⁵³` as in `make_lpips_fixture.py`.
    fn hashed(name: &str, n: usize, fan_in: usize) -> Vec<f32> {
        let mut h: u64 = 0xCBF2_9CE4_8422_2325;
        for b in name.bytes() {
            h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3);
        }
        let bound = 1.0 / (fan_in as f64).sqrt();
        (0..n as u64)
            .map(|i| {
                let mut x = h.wrapping_add(i).wrapping_add(0x9E37_79B9_7F4A_7C15);
                x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                x ^= x >> 31;
                let u = (x >> 11) as f64 / (1u64 << 53) as f64;
                ((2.0 * u - 1.0) * bound) as f32
            })
            .collect()
    }

    fn read_safetensors(path: &Path) -> Tensors {
        let bytes = std::fs::read(path).unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        st.tensors()
            .into_iter()
            .map(|(name, t)| {
                let v = t
                    .data()
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect();
                (name, (v, t.shape().to_vec()))
            })
            .collect()
    }

    /// The fixture's network: the hashed trunk and the package's linear layers.
    fn fixture_net(net: Net) -> Tensors {
        let mut t = read_safetensors(&fixture(&format!("lin_{}.safetensors", net.name())));
        let mut channels = 3;
        for step in net.steps() {
            if let Step::Conv {
                index, out, kernel, ..
            } = *step
            {
                let fan_in = channels * kernel * kernel;
                let name = |p: &str| format!("{}.features.{index}.{p}", net.name());
                let w = hashed(&name("weight"), out * fan_in, fan_in);
                let b = hashed(&name("bias"), out, fan_in);
                t.insert(
                    format!("features.{index}.weight"),
                    (w, vec![out, channels, kernel, kernel]),
                );
                t.insert(format!("features.{index}.bias"), (b, vec![out]));
                channels = out;
            }
        }
        t
    }

    #[test]
    fn distances_match_the_lpips_package() {
        let reference: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(fixture("reference.json")).unwrap())
                .unwrap();
        let pairs = read_safetensors(&fixture("pairs.safetensors"));
        let image = |name: String| -> Array2<f32> {
            let (v, s) = &pairs[&name];
            Array2::from_shape_vec((s[0], s[1]), v.clone()).unwrap()
        };
        let device = crate::device::cpu_device();
        let n = reference["pairs"].as_u64().unwrap() as usize;
        for net in [Net::Alex, Net::Vgg] {
            let model = Lpips::from_tensors(net, &fixture_net(net), &device).unwrap();
            let want = reference[net.name()].as_array().unwrap();
            let (mut worst_abs, mut worst_rel) = (0.0f64, 0.0f64);
            for i in 0..n {
                let (a, b) = (image(format!("a{i}")), image(format!("b{i}")));
                let got = model.distances(&[a.view()], &[b.view()]).unwrap()[0];
                let want = want[i].as_f64().unwrap();
                let abs = (got - want).abs();
                worst_abs = worst_abs.max(abs);
                if want > 0.0 {
                    worst_rel = worst_rel.max(abs / want);
                }
                assert!(abs <= 1e-5, "{net:?} pair {i}: {got} vs {want}");
            }
            // f32 convolutions in a different order: a few ulp of the features, amplified by
            // the normalisation, stay far below the values' own size.
            assert!(worst_rel <= 1e-3, "{net:?}: relative {worst_rel:e}");
            println!(
                "LPIPS {net:?} vs the lpips package: max |Δ| {worst_abs:.2e}, relative {worst_rel:.2e}"
            );
        }
    }

    #[test]
    fn a_batch_gives_each_pairs_distance_and_bad_weights_are_named() {
        let device = crate::device::cpu_device();
        let model = Lpips::from_tensors(Net::Alex, &fixture_net(Net::Alex), &device).unwrap();
        let pairs = read_safetensors(&fixture("pairs.safetensors"));
        let img = |name: &str| {
            let (v, s) = &pairs[name];
            Array2::from_shape_vec((s[0], s[1]), v.clone()).unwrap()
        };
        let (a0, b0, a1, b1) = (img("a0"), img("b0"), img("a3"), img("b3"));
        let batch = model
            .distances(&[a0.view(), a1.view()], &[b0.view(), b1.view()])
            .unwrap();
        let one = model.distances(&[a0.view()], &[b0.view()]).unwrap()[0];
        assert!(
            (batch[0] - one).abs() <= 1e-9 * one.max(1e-9),
            "{batch:?} {one}"
        );
        assert!(batch[1].abs() < 1e-12, "identical images: {}", batch[1]);
        let mut t = fixture_net(Net::Alex);
        t.remove("lin.2.weight");
        let e = Lpips::from_tensors(Net::Alex, &t, &device)
            .unwrap_err()
            .to_string();
        assert!(e.contains("lin.2.weight") && e.contains("missing"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("w.safetensors");
        std::fs::write(&bad, b"not weights").unwrap();
        let e = Lpips::load(&bad, &device).unwrap_err().to_string();
        assert!(e.contains("w.safetensors"), "{e}");
    }
}
