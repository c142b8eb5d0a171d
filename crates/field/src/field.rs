//! NAF's attenuation field: the hash-grid encoding of a point followed by a small MLP with one
//! skip connection (Zha et al. 2022): `enc → width → … → [concat enc] → width → 1`, LeakyReLU
//! (slope 0.01) on hidden layers and a sigmoid output in (0, 1) (callers scale it to their
//! attenuation range).

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{FieldError, Result};
use crate::grid::{HashGrid, HashGridConfig};
use crate::mlp::MlpLayout;
use crate::ops::{encode, mlp};

/// LeakyReLU's negative slope.
const SLOPE: f64 = 0.01;
/// Half-width of the table's uniform initialisation (torch-ngp's).
const TABLE_INIT: f32 = 1e-4;

/// The field's hyper-parameters (NAF's defaults: 4 layers of width 32, skip at layer 2).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FieldConfig {
    pub hash_grid: HashGridConfig,
    /// Hidden width.
    pub width: usize,
    /// Linear layers, the output layer included.
    pub layers: usize,
    /// The layer whose input is the previous activation concatenated with the encoding.
    pub skip: usize,
    /// The table is stored divided by this factor and multiplied back in the forward pass, so
    /// Adam (whose steps do not depend on the gradient's scale) moves the table this many times
    /// faster than the MLP at one learning rate. 1 is NAF (one rate for all); hash-grid
    /// trainers such as instant-NGP give the table about 10× the MLP's rate.
    pub table_lr_scale: f64,
}

impl Default for FieldConfig {
    fn default() -> Self {
        FieldConfig {
            hash_grid: HashGridConfig::default(),
            width: 32,
            layers: 4,
            skip: 2,
            table_lr_scale: 1.0,
        }
    }
}

impl FieldConfig {
    /// Check every field; errors name it under `field` (e.g. `field`).
    pub fn validate(&self, field: &str) -> Result<()> {
        self.hash_grid.validate(&format!("{field}.hash_grid"))?;
        if !(1..=1024).contains(&self.width) {
            return Err(FieldError::invalid(
                format!("{field}.width"),
                format!("must be in 1..=1024, got {}", self.width),
            ));
        }
        if !(2..=16).contains(&self.layers) {
            return Err(FieldError::invalid(
                format!("{field}.layers"),
                format!("must be in 2..=16, got {}", self.layers),
            ));
        }
        if !(1..self.layers).contains(&self.skip) {
            return Err(FieldError::invalid(
                format!("{field}.skip"),
                format!(
                    "must be in 1..{} (a hidden layer), got {}",
                    self.layers, self.skip
                ),
            ));
        }
        if !(self.table_lr_scale.is_finite() && self.table_lr_scale > 0.0) {
            return Err(FieldError::invalid(
                format!("{field}.table_lr_scale"),
                format!("must be finite and > 0, got {}", self.table_lr_scale),
            ));
        }
        Ok(())
    }

    /// A field with PyTorch's default layer initialisation and torch-ngp's table
    /// initialisation, drawn from `seed`.
    pub fn init(&self, seed: u64, device: &Device) -> Result<NeuralField> {
        self.validate("field")?;
        let grid = self.hash_grid.layout();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let kappa = self.table_lr_scale as f32;
        let table = uniform(
            &mut rng,
            [grid.rows(), grid.features],
            TABLE_INIT / kappa,
            device,
        );
        let enc = grid.width();
        let layers = (0..self.layers)
            .map(|l| {
                let d_in = match l {
                    0 => enc,
                    l if l == self.skip => self.width + enc,
                    _ => self.width,
                };
                let d_out = if l + 1 == self.layers { 1 } else { self.width };
                linear(&mut rng, d_in, d_out, device)
            })
            .collect();
        Ok(NeuralField {
            table,
            layers,
            skip: self.skip,
            table_scale: kappa,
            grid,
        })
    }
}

/// A trainable attenuation field over the unit cube.
#[derive(Module, Debug)]
pub struct NeuralField {
    /// The hash table `[rows, F]`, divided by `table_scale`.
    pub table: Param<Tensor<2>>,
    pub layers: Vec<Linear>,
    #[module(skip)]
    skip: usize,
    #[module(skip)]
    table_scale: f32,
    #[module(skip)]
    grid: HashGrid,
}

impl NeuralField {
    /// The field's values in (0, 1) at `points` `[N, 3]` (unit cube): `[N]`.
    pub fn forward(&self, points: Tensor<2>) -> Result<Tensor<1>> {
        let n = points.dims()[0];
        let enc = self.encode(points)?;
        Ok(sigmoid(self.decode(enc)?).reshape([n]))
    }

    /// The hash-grid encodings `[N, L·F]` of `points`.
    pub fn encode(&self, points: Tensor<2>) -> Result<Tensor<2>> {
        let table = self.table.val();
        let table = if self.table_scale == 1.0 {
            table
        } else {
            table.mul_scalar(self.table_scale)
        };
        encode(points, table, &self.grid)
    }

    /// The MLP on encodings `[N, L·F]`: pre-sigmoid outputs `[N, 1]`. One op
    /// ([`crate::ops::mlp`]) on the layers' parameters packed in order (a layer without a bias
    /// packs zeros), so gradients reach each `Linear` as before.
    pub fn decode(&self, enc: Tensor<2>) -> Result<Tensor<2>> {
        let layout = self.layout();
        let packed: Vec<Tensor<1>> = self
            .layers
            .iter()
            .enumerate()
            .flat_map(|(l, layer)| {
                let w = layer.weight.val();
                let size = w.dims().iter().product::<usize>();
                let bias = match &layer.bias {
                    Some(b) => b.val(),
                    None => Tensor::zeros([layout.d_out(l)], &w.device()),
                };
                [w.reshape([size]), bias]
            })
            .collect();
        mlp(enc, Tensor::cat(packed, 0), layout)
    }

    /// The MLP's shape as [`crate::ops::mlp`] takes it.
    pub fn layout(&self) -> MlpLayout {
        MlpLayout {
            input: self.grid.width(),
            width: self.layers[0].weight.dims()[1],
            layers: self.layers.len(),
            skip: self.skip,
            slope: SLOPE as f32,
        }
    }

    /// The table layout.
    pub fn grid(&self) -> &HashGrid {
        &self.grid
    }

    /// Trainable parameters (table and MLP).
    pub fn parameters(&self) -> usize {
        self.num_params()
    }
}

fn uniform<const D: usize>(
    rng: &mut ChaCha8Rng,
    shape: [usize; D],
    bound: f32,
    device: &Device,
) -> Param<Tensor<D>> {
    let n = shape.iter().product();
    let values: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..=bound)).collect();
    Param::from_tensor(Tensor::from_data(TensorData::new(values, shape), device))
}

/// PyTorch's default `nn.Linear` initialisation: weight and bias uniform in ±1/√d_in.
fn linear(rng: &mut ChaCha8Rng, d_in: usize, d_out: usize, device: &Device) -> Linear {
    let bound = 1.0 / (d_in as f32).sqrt();
    Linear {
        weight: uniform(rng, [d_in, d_out], bound, device),
        bias: Some(uniform(rng, [d_out], bound, device)),
    }
}
