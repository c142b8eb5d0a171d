//! CGLS (conjugate gradients on the normal equations) for `min ‖A x − b‖²`.
//!
//! Uses the Joseph projector and its *exact* adjoint, so no restarts are needed (TIGRE restarts
//! because its backprojector is only approximately matched). Scalars are accumulated in f64.
//! Stops early when the gradient of the normal equations vanishes.

use super::par_zip;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView3};
use prism_domain::projector::{Joseph, dot};

/// CGLS from `x0` (zeros when `None`) for `iterations` (≥ 1) steps; `progress(k)` after each step.
pub fn cgls(
    a: &Joseph,
    b: ArrayView3<f32>,
    x0: Option<Array3<f32>>,
    iterations: usize,
    progress: &mut dyn FnMut(usize),
) -> Result<Array3<f32>> {
    if iterations == 0 {
        return Err(Error::invalid("iterations", "must be at least 1"));
    }
    let shape = a.projection_shape(a.views());
    prism_domain::error::ensure_shape("projections", b.shape(), &shape, "[views, rows, cols]")?;
    let grid = a.geometry().volume.shape_zyx();
    let mut x = match x0 {
        Some(x) if x.shape() == grid => x,
        Some(x) => {
            return Err(Error::invalid(
                "x0",
                format!("shape {:?} does not match the grid {grid:?}", x.shape()),
            ));
        }
        None => Array3::zeros(grid),
    };
    let mut r = &b - &a.forward(x.view())?;
    let mut p = a.adjoint(r.view())?;
    let mut gamma = dot(p.view(), p.view());
    for k in 0..iterations {
        if gamma == 0.0 || !gamma.is_finite() {
            progress(k + 1);
            continue;
        }
        let q = a.forward(p.view())?;
        let qq = dot(q.view(), q.view());
        if qq == 0.0 {
            progress(k + 1);
            continue;
        }
        let alpha = (gamma / qq) as f32;
        par_zip(&mut x, &p, |x, p| x + alpha * p);
        par_zip(&mut r, &q, |r, q| r - alpha * q);
        let s = a.adjoint(r.view())?;
        let gamma_new = dot(s.view(), s.view());
        let beta = (gamma_new / gamma) as f32;
        par_zip(&mut p, &s, |p, s| s + beta * p);
        gamma = gamma_new;
        progress(k + 1);
    }
    Ok(x)
}
