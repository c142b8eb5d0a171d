//! Functions on predicted raw density curves Δu [K, M]: the smoothness regulariser L_curve
//! (paper eq. `curve_regularizer`) and the piecewise-linear query of an unobserved channel
//! (eq. `target_transform_interpolation`).

use burn::tensor::Tensor;

use crate::grid::SpectralGrid;
use crate::{Error, Result};

/// L_curve = 1/(K(M−1)) Σ_i Σ_{m<M} |Δu_i^(m+1) − Δu_i^(m)| for `delta_u` [K, M], as a `[1]`
/// tensor (differentiable).
///
/// As in the paper, differences are taken between neighbouring grid points irrespective of
/// their spacing: on an uneven grid the term penalises the change per channel step, not the
/// slope dΔu/dτ (the observed channels are the natural unit of the spectral axis and a slope
/// penalty would weight densely sampled regions of the spectrum more).
///
/// Errors: K = 0 (`delta_u`: no Gaussians) or M < 2 (`delta_u`: no neighbouring channels).
pub fn curve_regularizer(delta_u: Tensor<2>) -> Result<Tensor<1>> {
    let [k, m] = delta_u.dims();
    if k == 0 {
        return Err(Error::invalid(
            "delta_u",
            "has no Gaussians (K = 0): L_curve is undefined",
        ));
    }
    if m < 2 {
        return Err(Error::invalid(
            "delta_u",
            format!("has M = {m} channel(s): L_curve needs at least two neighbouring channels"),
        ));
    }
    let next = delta_u.clone().narrow(1, 1, m - 1);
    let prev = delta_u.narrow(1, 0, m - 1);
    Ok(next.sub(prev).abs().mean())
}

/// What [`interpolate_curve`] does for τ* outside [τ_1, τ_M].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Extrapolation {
    /// Return an error naming τ* (default: the paper only interpolates).
    #[default]
    Refuse,
    /// Hold the end value (Δu(τ_1) below the grid, Δu(τ_M) above it).
    Clamp,
    /// Extend the first/last segment linearly (needs M ≥ 2).
    Linear,
}

/// Δu(τ*) [K] from curves `delta_u` [K, M] on `grid` by piecewise-linear interpolation between
/// the neighbouring grid points τ_k ≤ τ* ≤ τ_{k+1}:
/// Δu(τ*) = (τ_{k+1} − τ*)/(τ_{k+1} − τ_k) Δu^(k) + (τ* − τ_k)/(τ_{k+1} − τ_k) Δu^(k+1).
/// Exact at grid points (the weights are exactly 1 and 0 there). Differentiable in `delta_u`.
///
/// Errors: `delta_u` not [K, M] for this grid, non-finite τ*, or τ* outside the grid under
/// [`Extrapolation::Refuse`] (and under `Linear` when M = 1); errors name `tau_star`.
pub fn interpolate_curve(
    delta_u: Tensor<2>,
    grid: &SpectralGrid,
    tau_star: f32,
    extrapolation: Extrapolation,
) -> Result<Tensor<1>> {
    let tau = grid.values();
    let m = tau.len();
    let [k, m_curve] = delta_u.dims();
    if m_curve != m {
        return Err(Error::invalid(
            "delta_u",
            format!("has {m_curve} channels but the grid has M = {m}"),
        ));
    }
    if !tau_star.is_finite() {
        return Err(Error::invalid(
            "tau_star",
            format!("τ* = {tau_star} is not finite"),
        ));
    }
    let column = |j: usize| delta_u.clone().narrow(1, j, 1).reshape([k]);
    let (first, last) = (tau[0], tau[m - 1]);
    let outside = tau_star < first || tau_star > last;
    if outside {
        match extrapolation {
            Extrapolation::Refuse => {
                return Err(Error::invalid(
                    "tau_star",
                    format!(
                        "τ* = {tau_star} lies outside the observed grid [{first}, {last}]; \
                         extrapolation is refused (allow it with Extrapolation::Clamp or ::Linear)"
                    ),
                ));
            }
            Extrapolation::Clamp => {
                return Ok(column(if tau_star < first { 0 } else { m - 1 }));
            }
            Extrapolation::Linear if m < 2 => {
                return Err(Error::invalid(
                    "tau_star",
                    format!(
                        "τ* = {tau_star} lies outside a one-point grid {{{first}}}: \
                         linear extrapolation needs M ≥ 2"
                    ),
                ));
            }
            Extrapolation::Linear => {}
        }
    }
    if m == 1 {
        // Inside a one-point grid means τ* = τ_1.
        return Ok(column(0));
    }
    // Segment k with τ_k ≤ τ* ≤ τ_{k+1}; the end segments also serve linear extrapolation.
    let seg = tau[1..m - 1].iter().take_while(|&&t| t <= tau_star).count();
    let (t0, t1) = (f64::from(tau[seg]), f64::from(tau[seg + 1]));
    let ts = f64::from(tau_star);
    let w0 = ((t1 - ts) / (t1 - t0)) as f32;
    let w1 = ((ts - t0) / (t1 - t0)) as f32;
    Ok(column(seg)
        .mul_scalar(w0)
        .add(column(seg + 1).mul_scalar(w1)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_into_vec().unwrap()
    }

    fn curves(device: &Device) -> (Tensor<2>, SpectralGrid) {
        // K = 2 curves on an uneven grid of M = 4.
        let grid = SpectralGrid::new(vec![0.0, 0.1, 0.5, 1.0]).unwrap();
        let du = Tensor::from_data(
            TensorData::new(vec![1.0f32, 3.0, -1.0, 0.5, 0.25, 0.25, 2.0, -4.0], [2, 4]),
            device,
        );
        (du, grid)
    }

    #[test]
    fn interpolation_is_exact_at_grid_points_and_linear_between() {
        let device = crate::test_util::cpu();
        let (du, grid) = curves(&device);
        let rows = [[1.0f32, 3.0, -1.0, 0.5], [0.25, 0.25, 2.0, -4.0]];
        for (m, &t) in grid.values().iter().enumerate() {
            let v = values(interpolate_curve(du.clone(), &grid, t, Extrapolation::Refuse).unwrap());
            assert_eq!(v, vec![rows[0][m], rows[1][m]], "τ* = τ_{m}");
        }
        // Between τ_2 = 0.1 and τ_3 = 0.5: weights 0.75 / 0.25 at 0.2, checked by hand.
        let v = values(interpolate_curve(du.clone(), &grid, 0.2, Extrapolation::Refuse).unwrap());
        let expect = [0.75 * 3.0 - 0.25, 0.75 * 0.25 + 0.25 * 2.0];
        for (a, b) in v.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        // Linear in τ* within a segment: the midpoint value is the mean of the ends.
        let at =
            |t| values(interpolate_curve(du.clone(), &grid, t, Extrapolation::Refuse).unwrap());
        let (a, b, mid) = (at(0.6), at(0.9), at(0.75));
        for ((mid, a), b) in mid.iter().zip(&a).zip(&b) {
            assert!((mid - 0.5 * (a + b)).abs() < 1e-6);
        }
    }

    #[test]
    fn extrapolation_is_refused_unless_allowed() {
        let device = crate::test_util::cpu();
        let (du, grid) = curves(&device);
        let e = interpolate_curve(du.clone(), &grid, 1.25, Extrapolation::Refuse).unwrap_err();
        assert_eq!(e.field(), "tau_star");
        assert!(e.to_string().contains("1.25"), "{e}");
        let e = interpolate_curve(du.clone(), &grid, -0.5, Extrapolation::default()).unwrap_err();
        assert!(e.to_string().contains("-0.5"), "{e}");
        let e = interpolate_curve(du.clone(), &grid, f32::NAN, Extrapolation::Linear).unwrap_err();
        assert_eq!(e.field(), "tau_star");

        let v = values(interpolate_curve(du.clone(), &grid, 1.25, Extrapolation::Clamp).unwrap());
        assert_eq!(v, vec![0.5, -4.0]);
        // Last segment (0.5, 1.0) extended: slope (0.5 − (−1))/0.5 = 3 and (−4 − 2)/0.5 = −12.
        let v = values(interpolate_curve(du.clone(), &grid, 1.25, Extrapolation::Linear).unwrap());
        for (a, b) in v.iter().zip([0.5 + 3.0 * 0.25, -4.0 - 12.0 * 0.25]) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        let one = SpectralGrid::new(vec![0.3]).unwrap();
        let col = Tensor::<2>::from_data(TensorData::new(vec![7.0f32], [1, 1]), &device);
        assert_eq!(
            values(interpolate_curve(col.clone(), &one, 0.3, Extrapolation::Refuse).unwrap()),
            vec![7.0]
        );
        assert!(interpolate_curve(col, &one, 0.4, Extrapolation::Linear).is_err());
        let e = interpolate_curve(du, &one, 0.3, Extrapolation::Refuse).unwrap_err();
        assert_eq!(e.field(), "delta_u");
    }

    #[test]
    fn curve_regularizer_matches_the_paper_definition() {
        let device = crate::test_util::cpu();
        let constant = Tensor::<2>::ones([3, 5], &device).mul_scalar(-2.5);
        assert_eq!(values(curve_regularizer(constant).unwrap()), vec![0.0]);
        // By hand: |3−1| + |−1−3| + |0.5+1| = 7.5 and 0 + 1.75 + 6 = 7.75; /(K(M−1)) = /6.
        let (du, _) = curves(&device);
        let l = values(curve_regularizer(du).unwrap())[0];
        assert!((l - (7.5 + 7.75) / 6.0).abs() < 1e-6, "{l}");
        let e = curve_regularizer(Tensor::<2>::zeros([4, 1], &device)).unwrap_err();
        assert_eq!(e.field(), "delta_u");
        assert!(curve_regularizer(Tensor::<2>::zeros([0, 3], &device)).is_err());
    }

    #[test]
    fn curve_regularizer_gradient_is_the_sign_of_the_differences() {
        let device = crate::test_util::cpu().autodiff();
        let du = Tensor::<2>::from_data(TensorData::new(vec![0.0f32, 1.0, 0.5], [1, 3]), &device)
            .require_grad();
        let grads = curve_regularizer(du.clone()).unwrap().backward();
        // L = (|1 − 0| + |0.5 − 1|)/2 ⇒ ∂L/∂Δu = (−1, 1 + 1, −1)/2.
        assert_eq!(values(du.grad(&grads).unwrap()), vec![-0.5, 1.0, -0.5]);
    }
}
