//! Scoring a Gaussian model against reference volumes while it trains (the `psnr`/`ssim` of
//! `log.jsonl`), as the run's curves are scored ([`CurveScoring`]).

use crate::Result;
use crate::evaluate::CurveScoring;
use crate::gaussians::volume::{volumes, volumes_with};
use crate::gaussians::{GaussianModel, World};
use burn::tensor::Tensor;
use ndarray::{Array3, Array4, Axis};
use prism_domain::geometry::VolumeGrid;

/// Reference volumes to score a model against during training.
pub struct Evaluator {
    /// Reconstruction grid (millimetres) and the world the model lives in.
    pub grid: VolumeGrid,
    pub world: World,
    /// One reference (mm⁻¹, `[z][y][x]`) per density column.
    pub references: Vec<Array3<f32>>,
    /// Over the whole grid, or inside the run's object mask.
    pub scoring: CurveScoring,
}

impl Evaluator {
    /// Mean PSNR / SSIM over columns, after dividing both volumes by the reference's maximum.
    pub fn score(&self, model: &GaussianModel) -> Result<(f64, f64)> {
        self.score_volumes(volumes(model, &self.grid, &self.world)?)
    }

    /// [`Evaluator::score`] with the model's densities replaced by raw columns `[K, M]`.
    pub fn score_raw(&self, model: &GaussianModel, raw: Tensor<2>) -> Result<(f64, f64)> {
        self.score_volumes(volumes_with(model, raw, &self.grid, &self.world)?)
    }

    fn score_volumes(&self, vols: Array4<f32>) -> Result<(f64, f64)> {
        let (mut p, mut s) = (0.0, 0.0);
        for (c, truth) in self.references.iter().enumerate() {
            let (a, b) = self
                .scoring
                .score(vols.index_axis(Axis(0), c), truth.view())?;
            p += a;
            s += b;
        }
        let n = self.references.len().max(1) as f64;
        Ok((p / n, s / n))
    }
}
