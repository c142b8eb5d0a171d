//! Per-channel comparison of finished runs (`prism report`): one row per channel, one PSNR/SSIM
//! column pair per run, from each run directory's `metrics.json` (fitted channels) and
//! `holdout.json` (channels a spectral model predicted without training data).

use crate::Result;
use crate::evaluate::Metrics;
use crate::record::RunDir;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One channel's scores in one run.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelScore {
    pub label: String,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// Predicted from the other channels (held out of training).
    pub held_out: bool,
    /// The channel's volume (`<label>.npy`, mm⁻¹).
    pub volume: PathBuf,
}

/// What `prism report` reads from one run directory.
#[derive(Clone, Debug, PartialEq)]
pub struct RunScores {
    pub dir: PathBuf,
    pub method: String,
    /// Training / reconstruction seconds (evaluation excluded).
    pub seconds: f64,
    pub channels: Vec<ChannelScore>,
}

impl RunScores {
    /// Read `dir/metrics.json` and, when present, `dir/holdout.json`.
    pub fn load(dir: &Path) -> Result<Self> {
        let metrics: Metrics = RunDir::read_json(&dir.join(RunDir::METRICS))?;
        let volume = |label: &str| dir.join(RunDir::volume_file(label));
        let mut channels: Vec<ChannelScore> = metrics
            .channels
            .iter()
            .map(|c| ChannelScore {
                label: c.label.clone(),
                psnr: Some(c.scores.psnr),
                ssim: Some(c.scores.ssim),
                held_out: false,
                volume: volume(&c.label),
            })
            .collect();
        channels.extend(
            crate::methods::fourdsg::query::holdout::read_scores(dir)?
                .into_iter()
                .map(|s| ChannelScore {
                    volume: volume(&s.label),
                    label: s.label,
                    psnr: s.volume.as_ref().map(|v| v.psnr),
                    ssim: s.volume.as_ref().map(|v| v.ssim),
                    held_out: true,
                }),
        );
        Ok(RunScores {
            dir: dir.to_path_buf(),
            method: metrics.method,
            seconds: metrics.wall_s,
            channels,
        })
    }
}

/// Each run's column name: its method, with its directory's name when two runs share a method
/// (two FDK runs with different settings), with the directory's path when those collide too.
/// Characters that would break a Markdown row (control characters, `|`) are escaped.
pub fn column_names(runs: &[RunScores]) -> Vec<String> {
    let count = |f: &dyn Fn(&RunScores) -> String, r: &RunScores| {
        runs.iter().filter(|o| f(o) == f(r)).count()
    };
    let name = |r: &RunScores| {
        r.dir.file_name().map_or_else(
            || r.dir.display().to_string(),
            |n| n.to_string_lossy().into(),
        )
    };
    runs.iter()
        .map(|r| {
            let label = if count(&|o| o.method.clone(), r) == 1 {
                r.method.clone()
            } else if count(&|o| format!("{} {}", o.method, name(o)), r) == 1 {
                format!("{} ({})", r.method, name(r))
            } else {
                format!("{} ({})", r.method, r.dir.display())
            };
            label
                .chars()
                .flat_map(|c| match c {
                    '|' => "\\|".chars().collect::<Vec<_>>(),
                    c if c.is_control() => c.escape_default().collect(),
                    c => vec![c],
                })
                .collect()
        })
        .collect()
}

/// Markdown table: rows are the channels of the first run (in its order, then any channel only
/// later runs have), columns PSNR (dB) / SSIM per run; predicted (held-out) values are marked
/// `*`. The last rows give the mean over fitted channels and the time.
pub fn table(runs: &[RunScores]) -> String {
    let mut labels: Vec<&str> = Vec::new();
    for r in runs {
        for c in &r.channels {
            if !labels.contains(&c.label.as_str()) {
                labels.push(&c.label);
            }
        }
    }
    let mut s = String::from("| channel |");
    for name in column_names(runs) {
        let _ = write!(s, " {name} PSNR | {name} SSIM |");
    }
    s.push_str("\n|---|");
    s.push_str(&"---|---|".repeat(runs.len()));
    s.push('\n');
    let cell = |v: Option<f64>, digits: usize, held: bool| match v {
        Some(x) => format!("{x:.digits$}{}", if held { "*" } else { "" }),
        None => "–".to_string(),
    };
    for l in &labels {
        let _ = write!(s, "| {l} |");
        for r in runs {
            match r.channels.iter().find(|c| c.label == *l) {
                Some(c) => {
                    let _ = write!(
                        s,
                        " {} | {} |",
                        cell(c.psnr, 2, c.held_out),
                        cell(c.ssim, 4, c.held_out)
                    );
                }
                None => s.push_str(" – | – |"),
            }
        }
        s.push('\n');
    }
    s.push_str("| mean (fitted) |");
    for r in runs {
        let fitted: Vec<&ChannelScore> = r.channels.iter().filter(|c| !c.held_out).collect();
        let mean = |f: fn(&ChannelScore) -> Option<f64>| {
            let v: Vec<f64> = fitted.iter().filter_map(|c| f(c)).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        let _ = write!(
            s,
            " {} | {} |",
            cell(mean(|c| c.psnr), 2, false),
            cell(mean(|c| c.ssim), 4, false)
        );
    }
    s.push_str("\n| time (s) |");
    for r in runs {
        let _ = write!(s, " {:.1} | |", r.seconds);
    }
    s.push('\n');
    if runs.iter().any(|r| r.channels.iter().any(|c| c.held_out)) {
        s.push_str("\n`*` predicted by the spectral model for a channel held out of training.\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: &str, channels: &[(&str, f64, bool)]) -> RunScores {
        RunScores {
            dir: PathBuf::from(method),
            method: method.into(),
            seconds: 1.5,
            channels: channels
                .iter()
                .map(|&(l, p, held_out)| ChannelScore {
                    label: l.into(),
                    psnr: Some(p),
                    ssim: Some(p / 100.0),
                    held_out,
                    volume: PathBuf::from(format!("{l}.npy")),
                })
                .collect(),
        }
    }

    #[test]
    fn the_table_aligns_channels_marks_predictions_and_averages_fitted_ones() {
        let a = run("sart", &[("40keV", 30.0, false), ("70keV", 32.0, false)]);
        let b = run("4dsg", &[("40keV", 34.0, false), ("70keV", 29.0, true)]);
        let t = table(&[a, b]);
        assert!(
            t.contains("| 40keV | 30.00 | 0.3000 | 34.00 | 0.3400 |"),
            "{t}"
        );
        assert!(
            t.contains("| 70keV | 32.00 | 0.3200 | 29.00* | 0.2900* |"),
            "{t}"
        );
        // The held-out channel is not in 4dsg's mean.
        assert!(
            t.contains("| mean (fitted) | 31.00 | 0.3100 | 34.00 | 0.3400 |"),
            "{t}"
        );
        assert!(t.contains("predicted by the spectral model"));
    }

    #[test]
    fn a_volume_identical_to_its_reference_reads_back_as_infinite() {
        use crate::evaluate::{Evaluation, score};
        use ndarray::Array3;
        // The PSNR of an identical volume is +∞; metrics.json writes it as "inf" (JSON has no
        // infinity), and the report reads it back.
        let truth = Array3::from_shape_fn((12, 12, 12), |(z, y, x)| (z + y + x) as f32 + 1.0);
        let scores = score(truth.view(), truth.view(), &Evaluation::default(), None).unwrap();
        assert_eq!(scores.psnr, f64::INFINITY);
        let json = serde_json::to_string(&scores).unwrap();
        assert!(json.contains(r#""psnr":"inf""#), "{json}");
        let back: crate::evaluate::Scores = serde_json::from_str(&json).unwrap();
        assert_eq!(back, scores);
        let t = table(&[RunScores {
            channels: vec![ChannelScore {
                psnr: Some(back.psnr),
                ..run("fdk", &[("40keV", 0.0, false)]).channels[0].clone()
            }],
            ..run("fdk", &[])
        }]);
        assert!(t.contains("| 40keV | inf |"), "{t}");
    }

    #[test]
    fn runs_of_one_method_are_told_apart_by_their_directories() {
        let at = |method: &str, dir: &str| RunScores {
            dir: PathBuf::from(dir),
            ..run(method, &[("40keV", 30.0, false)])
        };
        let runs = [
            at("fdk", "out/fdk-hann"),
            at("fdk", "out/fdk-ram-lak"),
            at("sart", "out/sart"),
            at("tv", "a/tv"),
            at("tv", "b/tv"),
            at("cgls", "x/a|b\nc"),
        ];
        assert_eq!(
            column_names(&runs),
            [
                "fdk (fdk-hann)",
                "fdk (fdk-ram-lak)",
                "sart",
                "tv (a/tv)",
                "tv (b/tv)",
                "cgls"
            ]
        );
        let t = table(&runs[..2]);
        assert!(t.starts_with("| channel | fdk (fdk-hann) PSNR |"), "{t}");
        let odd = [at("fdk", "a|b\nc"), at("fdk", "d")];
        let names = column_names(&odd);
        assert_eq!(names[0], "fdk (a\\|b\\nc)", "{names:?}");
    }

    #[test]
    fn a_missing_metrics_file_names_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let e = RunScores::load(dir.path()).unwrap_err().to_string();
        assert!(e.contains("metrics.json"), "{e}");
    }
}
