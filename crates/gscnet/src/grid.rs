//! The observed spectral grid: the ordered normalised coordinates τ_1 < … < τ_M of the M
//! observed channels (paper Sec. III-D). τ is expected in [0, 1] (e.g. energy or mixing
//! coefficient mapped linearly), but any finite strictly increasing grid is accepted; spacing may
//! be uneven.

use burn::tensor::{Device, Tensor, TensorData};

use crate::{Error, Result};

/// A validated spectral grid: non-empty, finite, strictly increasing.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralGrid {
    tau: Vec<f32>,
}

impl SpectralGrid {
    /// Validate `tau` (field names: `tau`, `tau[m]`).
    pub fn new(tau: Vec<f32>) -> Result<Self> {
        if tau.is_empty() {
            return Err(Error::invalid(
                "tau",
                "the spectral grid is empty (M = 0): at least one channel is needed",
            ));
        }
        for (m, &t) in tau.iter().enumerate() {
            if !t.is_finite() {
                return Err(Error::invalid(
                    format!("tau[{m}]"),
                    format!("{t} is not finite"),
                ));
            }
            if m > 0 && t <= tau[m - 1] {
                return Err(Error::invalid(
                    format!("tau[{m}]"),
                    format!(
                        "the grid must be strictly increasing, but tau[{m}] = {t} ≤ tau[{}] = {}",
                        m - 1,
                        tau[m - 1]
                    ),
                ));
            }
        }
        Ok(Self { tau })
    }

    /// Number of channels M.
    pub fn len(&self) -> usize {
        self.tau.len()
    }

    /// Always false (a grid has at least one point); present for API symmetry with `len`.
    pub fn is_empty(&self) -> bool {
        self.tau.is_empty()
    }

    /// The grid values τ_1 < … < τ_M.
    pub fn values(&self) -> &[f32] {
        &self.tau
    }

    /// The grid as a `[M]` tensor on `device` (the `tau` input of [`crate::CurveModel::forward`]).
    pub fn to_tensor(&self, device: &Device) -> Tensor<1> {
        Tensor::from_data(TensorData::new(self.tau.clone(), [self.tau.len()]), device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_uneven_increasing_grids() {
        let g = SpectralGrid::new(vec![0.0, 0.1, 0.45, 1.0]).unwrap();
        assert_eq!(g.len(), 4);
        assert_eq!(g.values(), &[0.0, 0.1, 0.45, 1.0]);
        assert!(SpectralGrid::new(vec![0.3]).is_ok());
    }

    #[test]
    fn rejects_empty_non_finite_and_unordered_grids() {
        let e = SpectralGrid::new(vec![]).unwrap_err();
        assert_eq!(e.field(), "tau");
        assert!(e.to_string().contains("M = 0"));
        let e = SpectralGrid::new(vec![0.0, f32::NAN, 1.0]).unwrap_err();
        assert_eq!(e.field(), "tau[1]");
        let e = SpectralGrid::new(vec![0.0, f32::INFINITY]).unwrap_err();
        assert_eq!(e.field(), "tau[1]");
        let e = SpectralGrid::new(vec![0.0, 0.5, 0.5]).unwrap_err();
        assert_eq!(e.field(), "tau[2]");
        assert!(e.to_string().contains("strictly increasing"));
        let e = SpectralGrid::new(vec![1.0, 0.0]).unwrap_err();
        assert_eq!(e.field(), "tau[1]");
    }
}
