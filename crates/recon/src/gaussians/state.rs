//! A Gaussian model with its optimiser state, on the host: what checkpoints save and restore.
//!
//! In a safetensors file, with a name `prefix`, each parameter group is three float32 tensors
//! `<prefix><group>`, `<prefix><group>.m1`, `<prefix><group>.m2` (value, Adam first and second
//! moments) for the groups `means [K,3]`, `scales_raw [K,3]`, `rotations [K,4]` and
//! `densities_raw [K,C]` (raw values, normalised world, as in [`super::io`]); the Adam step counts
//! and the scale bounds go to the metadata ([`ModelState::meta`]).

use super::GaussianModel;
use super::adam::AdamParam;
use super::host::ScaleBounds;
use crate::device::{host_values, upload};
use crate::record::tensors::{TensorFile, Tensors};
use crate::{Error, Result};
use burn::tensor::Device;
use serde::{Deserialize, Serialize};

/// Tensor names of the parameter groups, in [`GaussianModel`] order.
const GROUPS: [&str; 4] = ["means", "scales_raw", "rotations", "densities_raw"];

/// One parameter group: value and moments (row-major `[K, width]`) and the steps taken.
#[derive(Clone, Debug, PartialEq)]
struct Group {
    value: Vec<f32>,
    m1: Vec<f32>,
    m2: Vec<f32>,
    steps: i32,
}

/// What a [`ModelState`] keeps beside its tensors.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelMeta {
    /// Adam steps per group (means, scales, rotations, densities).
    pub steps: [i32; 4],
    pub bounds: ScaleBounds,
    /// Density columns.
    pub channels: usize,
}

/// A model's raw parameters and Adam state on the host (exact copies of the device tensors).
#[derive(Clone, Debug, PartialEq)]
pub struct ModelState {
    groups: [Group; 4],
    bounds: ScaleBounds,
    channels: usize,
}

impl ModelState {
    /// Copy `model` to the host.
    pub fn of(model: &GaussianModel) -> Self {
        let group = |p: &AdamParam| {
            let (m1, m2, steps) = p.state();
            Group {
                value: host_values(&p.value),
                m1: host_values(m1),
                m2: host_values(m2),
                steps,
            }
        };
        ModelState {
            groups: [
                group(&model.means),
                group(&model.scales),
                group(&model.rotations),
                group(&model.densities),
            ],
            bounds: model.bounds,
            channels: model.channels(),
        }
    }

    /// The model on `device`, optimiser state included.
    pub fn to_model(&self, device: &Device) -> GaussianModel {
        let [means, scales, rotations, densities] = std::array::from_fn(|i| {
            let g = &self.groups[i];
            let w = self.widths()[i];
            AdamParam::with_state(
                upload(g.value.clone(), w, device),
                upload(g.m1.clone(), w, device),
                upload(g.m2.clone(), w, device),
                g.steps,
            )
        });
        GaussianModel {
            means,
            scales,
            rotations,
            densities,
            bounds: self.bounds,
        }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.groups[0].value.len() / 3
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether every value and moment is finite (a state worth saving).
    pub fn is_finite(&self) -> bool {
        self.groups.iter().all(|g| {
            [&g.value, &g.m1, &g.m2]
                .iter()
                .all(|v| v.iter().all(|x| x.is_finite()))
        })
    }

    fn widths(&self) -> [usize; 4] {
        [3, 3, 4, self.channels]
    }

    /// The metadata to store beside [`ModelState::add_to`]'s tensors.
    pub fn meta(&self) -> ModelMeta {
        ModelMeta {
            steps: self.groups.each_ref().map(|g| g.steps),
            bounds: self.bounds,
            channels: self.channels,
        }
    }

    /// Add the tensors `<prefix><group>[.m1|.m2]` to `out`.
    pub(crate) fn add_to(&self, prefix: &str, out: &mut Tensors) {
        let k = self.len();
        for ((name, g), w) in GROUPS.iter().zip(&self.groups).zip(self.widths()) {
            out.f32(format!("{prefix}{name}"), &g.value, [k, w]);
            out.f32(format!("{prefix}{name}.m1"), &g.m1, [k, w]);
            out.f32(format!("{prefix}{name}.m2"), &g.m2, [k, w]);
        }
    }

    /// Read the tensors `<prefix><group>[.m1|.m2]` of `f` with `meta`: every tensor has the same
    /// K ≥ 1 rows and only finite entries; errors name the file and the tensor.
    pub(crate) fn read(f: &TensorFile, prefix: &str, meta: &ModelMeta) -> Result<Self> {
        let path = f.path();
        meta.bounds.validate().map_err(|e| e.in_file(path))?;
        if meta.channels == 0 {
            return Err(Error::field(
                path,
                "metadata",
                "a model needs a density column",
            ));
        }
        if let Some(s) = meta.steps.iter().find(|s| **s < 0) {
            return Err(Error::field(
                path,
                "metadata",
                format!("negative Adam step count {s}"),
            ));
        }
        let widths = [3, 3, 4, meta.channels];
        let first = format!("{prefix}{}", GROUPS[0]);
        let k = f.rows(&first, 3)?.len() / 3;
        if k == 0 {
            return Err(Error::field(path, first, "no Gaussians"));
        }
        let tensor = |name: String, width: usize| -> Result<Vec<f32>> {
            let v = f.rows(&name, width)?;
            if v.len() != k * width {
                return Err(Error::field(
                    path,
                    name,
                    format!("expected {k} rows like `{first}`, got {}", v.len() / width),
                ));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(Error::field(path, name, format!("entry {i} is not finite")));
            }
            Ok(v)
        };
        let mut groups = Vec::with_capacity(4);
        for ((name, w), steps) in GROUPS.iter().zip(widths).zip(meta.steps) {
            groups.push(Group {
                value: tensor(format!("{prefix}{name}"), w)?,
                m1: tensor(format!("{prefix}{name}.m1"), w)?,
                m2: tensor(format!("{prefix}{name}.m2"), w)?,
                steps,
            });
        }
        Ok(ModelState {
            groups: groups
                .try_into()
                .unwrap_or_else(|_| unreachable!("four groups")),
            bounds: meta.bounds,
            channels: meta.channels,
        })
    }
}
