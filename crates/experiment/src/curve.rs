//! Error against time from a run's `log.jsonl`: the mean PSNR over the channels against training
//! seconds (evaluation excluded, like `metrics.json`'s `wall_s`).
//!
//! * A spectral stage (channel `all`) scores every channel at once: its records are the curve.
//! * Per-channel stages (R²-Gaussian, channel = a label) train one channel after another. The
//!   curve's point for evaluation iteration i is every channel stopped at iteration i: the sum of
//!   each channel's seconds up to i (its initialisation included) against the mean of their PSNRs.
//!   This is an early stop of the configured schedule, not a run planned for that budget.
//! * 4D-SG's stage 1 (channel `structural`) is scored against the mean reference, a different
//!   quantity: it is kept apart ([`Curve::structural`]).

use crate::{Error, Result};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Deserialize)]
struct Record {
    channel: String,
    iter: usize,
    train_s: f64,
    psnr: Option<f64>,
}

/// A run's curves: `(seconds, PSNR dB)` points in time order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Curve {
    /// Mean PSNR over the channels.
    pub mean: Vec<(f64, f64)>,
    /// 4D-SG stage 1 against the mean reference.
    pub structural: Vec<(f64, f64)>,
}

impl Curve {
    /// Read `log.jsonl` of a run directory (empty curves for a method that writes none).
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join("log.jsonl");
        if !path.exists() {
            return Ok(Curve::default());
        }
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let records = text
            .lines()
            .filter(|l| !l.trim().is_empty())
            .enumerate()
            .map(|(i, l)| {
                serde_json::from_str::<Record>(l)
                    .map_err(|e| Error::field(&path, format!("line {}", i + 1), e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self::from_records(&records))
    }

    fn from_records(records: &[Record]) -> Self {
        let mut curve = Curve::default();
        // Per-channel stages: channel → [(iter, seconds since the channel started, psnr)].
        let mut channels: BTreeMap<&str, Vec<(usize, f64, f64)>> = BTreeMap::new();
        let mut order: Vec<&str> = Vec::new();
        let mut start = 0.0;
        let mut last_end = 0.0;
        for r in records {
            let Some(p) = r.psnr.filter(|p| p.is_finite()) else {
                continue;
            };
            match r.channel.as_str() {
                "all" => curve.mean.push((r.train_s, p)),
                "structural" => curve.structural.push((r.train_s, p)),
                c => {
                    if !channels.contains_key(c) {
                        start = last_end;
                        order.push(c);
                    }
                    channels
                        .entry(c)
                        .or_default()
                        .push((r.iter, r.train_s - start, p));
                }
            }
            last_end = r.train_s;
        }
        if !order.is_empty() {
            let iters: Vec<usize> = channels[order[0]].iter().map(|q| q.0).collect();
            for it in iters {
                let pts: Vec<(f64, f64)> = order
                    .iter()
                    .filter_map(|c| channels[c].iter().find(|q| q.0 == it).map(|q| (q.1, q.2)))
                    .collect();
                if pts.len() == order.len() {
                    let secs = pts.iter().map(|q| q.0).sum();
                    let psnr = pts.iter().map(|q| q.1).sum::<f64>() / pts.len() as f64;
                    curve.mean.push((secs, psnr));
                }
            }
        }
        curve
    }

    /// The mean PSNR at `seconds`, linearly interpolated; None before the first point, the last
    /// value after it.
    pub fn at(&self, seconds: f64) -> Option<f64> {
        let c = &self.mean;
        let first = c.first()?;
        if seconds < first.0 {
            return None;
        }
        for w in c.windows(2) {
            let ((t0, p0), (t1, p1)) = (w[0], w[1]);
            if seconds <= t1 {
                let f = if t1 > t0 {
                    (seconds - t0) / (t1 - t0)
                } else {
                    1.0
                };
                return Some(p0 + f * (p1 - p0));
            }
        }
        c.last().map(|q| q.1)
    }

    /// The training time at which the mean PSNR first reaches `fraction` of its last value
    /// (dB), linearly interpolated between evaluations; the first point's time when it is
    /// already there; `None` for an empty curve.
    pub fn time_to(&self, fraction: f64) -> Option<f64> {
        let c = &self.mean;
        let target = fraction * c.last()?.1;
        let hit = c.iter().position(|q| q.1 >= target)?;
        if hit == 0 {
            return Some(c[0].0);
        }
        let ((t0, p0), (t1, p1)) = (c[hit - 1], c[hit]);
        Some(t0 + (target - p0) / (p1 - p0) * (t1 - t0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(channel: &str, iter: usize, train_s: f64, psnr: f64) -> Record {
        Record {
            channel: channel.into(),
            iter,
            train_s,
            psnr: Some(psnr),
        }
    }

    #[test]
    fn per_channel_stages_add_their_times_and_average_their_psnr() {
        // Two channels of 2 evaluations each, the second starting at 10 s.
        let c = Curve::from_records(&[
            rec("40keV", 50, 4.0, 30.0),
            rec("40keV", 100, 10.0, 34.0),
            rec("70keV", 50, 13.0, 28.0),
            rec("70keV", 100, 21.0, 30.0),
        ]);
        assert_eq!(c.mean, vec![(7.0, 29.0), (21.0, 32.0)]);
        assert!(c.structural.is_empty());
        assert_eq!(c.at(14.0), Some(30.5));
        assert_eq!(c.at(1.0), None);
        assert_eq!(c.at(99.0), Some(32.0));
    }

    #[test]
    fn time_to_quality_is_the_first_crossing_of_a_fraction_of_the_last_psnr() {
        let c = Curve {
            mean: vec![
                (1.0, 10.0),
                (2.0, 20.0),
                (4.0, 30.0),
                (5.0, 29.0),
                (8.0, 31.0),
            ],
            structural: Vec::new(),
        };
        // 95 % of 31 dB = 29.45 dB, first reached between 2 s (20 dB) and 4 s (30 dB); 99 % =
        // 30.69 dB only between 5 s (29 dB, after a dip) and 8 s.
        let t95 = c.time_to(0.95).unwrap();
        assert!((t95 - (2.0 + 9.45 / 10.0 * 2.0)).abs() < 1e-12, "{t95}");
        let t99 = c.time_to(0.99).unwrap();
        assert!((t99 - (5.0 + 1.69 / 2.0 * 3.0)).abs() < 1e-12, "{t99}");
        assert_eq!(c.time_to(0.1), Some(1.0));
        assert_eq!(c.time_to(1.0), Some(8.0));
        assert_eq!(Curve::default().time_to(0.95), None);
    }

    #[test]
    fn a_spectral_run_keeps_its_structural_stage_apart() {
        let c = Curve::from_records(&[
            rec("structural", 10, 1.0, 40.0),
            rec("all", 10, 2.0, 35.0),
            rec("all", 20, 3.0, 36.0),
        ]);
        assert_eq!(c.structural, vec![(1.0, 40.0)]);
        assert_eq!(c.mean, vec![(2.0, 35.0), (3.0, 36.0)]);
    }
}
