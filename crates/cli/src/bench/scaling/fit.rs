//! Power laws fitted to measured costs: `y ≈ a·xᵇ` by least squares on `(ln x, ln y)`.

use serde::Serialize;

/// A fitted power law `y ≈ a·xᵇ`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PowerLaw {
    pub exponent: f64,
    pub coefficient: f64,
    /// Coefficient of determination of the fit in log-log space (1 when the points are on the line;
    /// absent when every `ln y` is the same).
    pub r2: Option<f64>,
}

/// The least-squares power law through `points` (`x, y > 0`; others are left out); `None` with
/// fewer than two distinct `x`.
pub fn power_law(points: &[(f64, f64)]) -> Option<PowerLaw> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = logs.len() as f64;
    let mx = logs.iter().map(|p| p.0).sum::<f64>() / n;
    let my = logs.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = logs.iter().map(|p| (p.1 - my).powi(2)).sum();
    if logs.len() < 2 || sxx <= 1e-12 {
        return None;
    }
    let b = sxy / sxx;
    let residual: f64 = logs
        .iter()
        .map(|p| (p.1 - my - b * (p.0 - mx)).powi(2))
        .sum();
    Some(PowerLaw {
        exponent: b,
        coefficient: (my - b * mx).exp(),
        r2: (syy > 0.0).then(|| 1.0 - residual / syy),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_power_law_is_recovered_exactly() {
        let pts: Vec<(f64, f64)> = [1e4, 3e4, 1e5, 5e5]
            .iter()
            .map(|&x: &f64| (x, 2.5e-6 * x.powf(0.8)))
            .collect();
        let f = power_law(&pts).unwrap();
        assert!((f.exponent - 0.8).abs() < 1e-12, "{f:?}");
        assert!((f.coefficient / 2.5e-6 - 1.0).abs() < 1e-9, "{f:?}");
        assert!((f.r2.unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_constant_has_exponent_zero_and_scatter_lowers_r2() {
        let flat = power_law(&[(1.0, 3.0), (10.0, 3.0), (100.0, 3.0)]).unwrap();
        assert_eq!(flat.exponent, 0.0);
        assert_eq!(flat.r2, None);
        // ln y = ln x ± 0.1 alternately: slope ≈ 1, R² below 1.
        let pts: Vec<(f64, f64)> = (0..6)
            .map(|i| {
                let x = 10f64.powi(i);
                (x, x * if i % 2 == 0 { 1.1 } else { 0.9 })
            })
            .collect();
        let f = power_law(&pts).unwrap();
        assert!((f.exponent - 1.0).abs() < 0.02, "{f:?}");
        assert!(f.r2.unwrap() < 1.0 && f.r2.unwrap() > 0.99, "{f:?}");
    }

    #[test]
    fn one_abscissa_or_bad_values_give_no_fit() {
        assert_eq!(power_law(&[(5.0, 1.0), (5.0, 2.0)]), None);
        assert_eq!(power_law(&[(1.0, 1.0), (0.0, 2.0), (2.0, -1.0)]), None);
    }
}
