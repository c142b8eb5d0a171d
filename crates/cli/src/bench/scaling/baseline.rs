//! `--baseline <previous prism>`: every point is measured by this binary and then by the
//! previous one, alternately in the same sweep (so both see the same machine load), and the
//! ratios this / previous of each time series and of the peak memory are reported. A ratio above
//! `1 +` [`REGRESSION`] must repeat to count: the point is measured again by both binaries, and
//! each series keeps the smaller of its two ratios ([`confirmed`]). A regression that remains
//! ends the sweep with an error, so a script (or a reviewer) sees it.

use super::point::Measured;
use super::series_times;
use prism_domain::metrics::quantile;
use serde::Serialize;
use std::collections::BTreeMap;

/// A series this much slower (or a peak this much larger) than the previous binary's is a
/// regression: above the ±15 % one 10-iteration window reads on a shared 2-core machine.
pub const REGRESSION: f64 = 0.25;

/// One point's ratios, this binary over the previous one.
#[derive(Debug, Serialize)]
pub struct Ratio {
    pub point: super::point::Point,
    pub method: &'static str,
    /// Per time series (`r2gs`, `4dsg stage 1`, …): seconds per iteration, this / previous.
    pub time: BTreeMap<String, f64>,
    /// Peak resident memory, this / previous (absent where either is unknown).
    pub peak: Option<f64>,
}

/// One point's ratios, `new` (this binary) over `old` (the baseline).
pub fn ratio(new: &Measured, old: &Measured) -> Ratio {
    let before: BTreeMap<String, f64> = series_times(old).into_iter().collect();
    let time = series_times(new)
        .into_iter()
        .filter_map(|(s, t)| before.get(&s).map(|&b| (s, t / b)))
        .collect();
    let peak = match (new.peak_rss_bytes, old.peak_rss_bytes) {
        (Some(n), Some(o)) if o > 0 => Some(n as f64 / o as f64),
        _ => None,
    };
    Ratio {
        point: new.point,
        method: new.method.name(),
        time,
        peak,
    }
}

/// A point's ratios after a second pair of measurements: per series (and the peak) the smaller
/// of the two, so a ratio over the margin stays one only if both pairs read it. A slower binary
/// reads slower every time; a noisy window (this machine's 10-iteration windows reach 25 %)
/// seldom twice in a row.
pub fn confirmed(first: Ratio, second: &Ratio) -> Ratio {
    let time = first
        .time
        .into_iter()
        .map(|(s, v)| {
            let again = second.time.get(&s).copied().unwrap_or(v);
            (s, v.min(again))
        })
        .collect();
    let peak = match (first.peak, second.peak) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    Ratio {
        time,
        peak,
        ..first
    }
}

/// Per series (and `peak <method>`), the median ratio over the points: the headline figure.
pub fn medians(ratios: &[Ratio]) -> BTreeMap<String, f64> {
    let mut all: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for r in ratios {
        for (s, &v) in &r.time {
            all.entry(format!("time {s}")).or_default().push(v);
        }
        if let Some(p) = r.peak {
            all.entry(format!("peak {}", r.method)).or_default().push(p);
        }
    }
    all.into_iter()
        .map(|(s, v)| (s, quantile(v.iter().map(|&x| x as f32), 0.5) as f64))
        .collect()
}

/// The regressions: `series at point: ratio` for every ratio above `1 + REGRESSION`.
pub fn regressions(ratios: &[Ratio]) -> Vec<String> {
    let mut out = Vec::new();
    for r in ratios {
        let at = super::describe(&r.point);
        for (s, &v) in &r.time {
            if v > 1.0 + REGRESSION {
                out.push(format!("time {s} at {at}: {v:.2}×"));
            }
        }
        if let Some(p) = r.peak.filter(|&p| p > 1.0 + REGRESSION) {
            out.push(format!("peak {} at {at}: {p:.2}×", r.method));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::scaling::point::{Method, Point, StageCost};

    fn measured(method: Method, times: &[f64], peak: u64) -> Measured {
        Measured {
            point: Point {
                gaussians: 1000,
                views: 8,
                detector: 32,
                grid: 32,
                channels: 2,
            },
            method,
            stages: times
                .iter()
                .enumerate()
                .map(|(i, &t)| StageCost {
                    stage: format!("s{i}"),
                    gaussians: None,
                    iteration_s: t,
                })
                .collect(),
            peak_rss_bytes: Some(peak),
            estimate_bytes: 0,
            run_s: 1.0,
        }
    }

    #[test]
    fn ratios_follow_each_series_and_flag_what_grew_past_the_margin() {
        // 4D-SG: stage 1 halved, stage 2 1.5× slower; the peak 10 % larger.
        let new = measured(Method::FourDsg, &[0.05, 0.3], 110);
        let old = measured(Method::FourDsg, &[0.1, 0.2], 100);
        // R²-Gaussian: the median of its channels' stages, 0.2 → 0.1 s.
        let new_r = measured(Method::R2gs, &[0.1, 0.1, 0.3], 100);
        let old_r = measured(Method::R2gs, &[0.2, 0.2, 0.1], 100);
        let r = [ratio(&new, &old), ratio(&new_r, &old_r)];
        assert!((r[0].time["4dsg stage 1"] - 0.5).abs() < 1e-12);
        assert!((r[0].time["4dsg stage 2"] - 1.5).abs() < 1e-12);
        assert!((r[0].peak.unwrap() - 1.1).abs() < 1e-12);
        assert!((r[1].time["r2gs"] - 0.5).abs() < 1e-12);
        let m = medians(&r);
        assert!((m["peak 4dsg"] - 1.1).abs() < 1e-6);
        let bad = regressions(&r);
        assert_eq!(bad.len(), 1, "{bad:?}");
        assert!(bad[0].starts_with("time 4dsg stage 2 at K 1000") && bad[0].ends_with("1.50×"));
    }

    #[test]
    fn a_regression_counts_only_if_the_second_pair_reads_it_too() {
        let old = measured(Method::FourDsg, &[0.1, 0.2], 100);
        let first = || ratio(&measured(Method::FourDsg, &[0.1, 0.3], 140), &old);
        // Noise: the second pair reads stage 2 at 0.95× and the peak as before.
        let noise = ratio(&measured(Method::FourDsg, &[0.11, 0.19], 100), &old);
        let c = confirmed(first(), &noise);
        assert!(
            regressions(std::slice::from_ref(&c)).is_empty(),
            "{:?}",
            c.time
        );
        assert!((c.time["4dsg stage 1"] - 1.0).abs() < 1e-12);
        assert!((c.time["4dsg stage 2"] - 0.95).abs() < 1e-12);
        // A slower binary: the second pair reads stage 2 at 1.4× and the peak at 1.3×.
        let slow = ratio(&measured(Method::FourDsg, &[0.1, 0.28], 130), &old);
        let c = confirmed(first(), &slow);
        let bad = regressions(std::slice::from_ref(&c));
        assert_eq!(bad.len(), 2, "{bad:?}");
        assert!(
            bad[0].ends_with("1.40×") && bad[1].ends_with("1.30×"),
            "{bad:?}"
        );
    }
}
