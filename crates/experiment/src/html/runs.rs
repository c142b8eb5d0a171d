//! `prism report --html`: finished runs compared on one page, the per-channel table of
//! `prism report`, mean PSNR against training time, and the slice viewer over their volumes
//! (against the scene's references when the scene is given).

use super::{Page, Shown, SliceSet, data_dir, write_page};
use crate::Result;
use crate::curve::Curve;
use crate::figures::charts::{Lines, Panel, Series};
use crate::figures::plot::save;
use prism_domain::observe::Observer;
use prism_recon::report::{RunScores, column_names, table};
use std::fmt::Write as _;
use std::path::Path;

/// Write `page` comparing `runs`; `scene` is the scene directory they reconstructed.
pub fn write_runs_page(
    runs: &[RunScores],
    scene: Option<&Path>,
    page: &Path,
    observer: &dyn Observer,
) -> Result<Page> {
    let names = column_names(runs);
    let mut md = String::from("# Runs\n\n");
    for (r, name) in runs.iter().zip(&names) {
        let _ = writeln!(
            md,
            "- **{name}**: `{}`, method `{}`, {:.1} s of training",
            r.dir.display(),
            r.method,
            r.seconds
        );
    }
    let _ = writeln!(
        md,
        "\n## Scores\n\n3-D PSNR (dB) and SSIM of each channel against the scene's reference \
         (`metrics.json`; `docs/metrics.md`).\n\n{}",
        table(runs)
    );
    let mut series = Vec::new();
    for (i, (r, name)) in runs.iter().zip(&names).enumerate() {
        let curve = Curve::load(&r.dir)?;
        if !curve.mean.is_empty() {
            series.push(Series {
                markers: true,
                ..Series::line(name.clone(), i, curve.mean)
            });
        }
    }
    if !series.is_empty() {
        let fig = Lines {
            title: "Mean PSNR against training time".into(),
            cols: 1,
            panel: (640, 400),
            panels: vec![Panel::psnr_time("", series)],
        };
        let data = data_dir(page);
        std::fs::create_dir_all(&data).map_err(|e| crate::Error::io(&data, e))?;
        let [png, _] = save(&data.join("psnr-time"), &fig)?;
        let rel = png
            .strip_prefix(page.parent().unwrap_or(Path::new("")))
            .unwrap_or(&png);
        let _ = writeln!(
            md,
            "## PSNR against time\n\n![Mean PSNR against training time]({})\n",
            rel.display()
        );
    }
    let set = SliceSet {
        title: match scene {
            Some(s) => format!("{} runs on {}", runs.len(), s.display()),
            None => format!("{} runs (no scene given: no reference)", runs.len()),
        },
        scene: scene.map(Path::to_path_buf),
        methods: runs
            .iter()
            .zip(&names)
            .map(|(r, n)| Shown::run(n.clone(), r))
            .collect(),
    };
    write_page(page, "Prism runs", &md, page, &[set], observer)
}
