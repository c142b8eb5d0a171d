//! `report.html`: the suite's report as a page to browse ([`crate::html`]), with a slice viewer
//! over every scene cell of the Table II studies (`table`, `noise`): the reference and each method
//! run on it, first seed.

use super::REPORT;
use crate::Result;
use crate::html::{Page, Shown, SliceSet, write_page};
use crate::plan::Plan;
use crate::suite::{LoadedSuite, StudyKind};
use prism_domain::observe::Observer;
use prism_recon::record::RunDir;
use prism_recon::report::RunScores;
use std::path::Path;

/// The page's file name in the suite's output directory.
pub const HTML: &str = "report.html";

/// Write `report.html` (and `report-data/`) under `out` from its `report.md` (written first by
/// [`super::write_report`]) and the finished cells' volumes.
pub fn write_html(
    loaded: &LoadedSuite,
    plan: &Plan,
    out: &Path,
    observer: &dyn Observer,
) -> Result<Page> {
    let source = out.join(REPORT);
    let markdown = std::fs::read_to_string(&source).map_err(|e| crate::Error::io(&source, e))?;
    let sets = slice_sets(loaded, plan, out)?;
    write_page(
        &out.join(HTML),
        &format!("Prism experiment suite {}", loaded.suite.name),
        &markdown,
        &source,
        &sets,
        observer,
    )
}

/// One set per scene cell of the Table II studies, in the studies' order; its methods are the
/// finished runs of those studies on it (first seed), each once.
fn slice_sets(loaded: &LoadedSuite, plan: &Plan, out: &Path) -> Result<Vec<SliceSet>> {
    let suite = &loaded.suite;
    let mut cells: Vec<(usize, Vec<usize>)> = Vec::new();
    for st in &plan.studies {
        if !matches!(st.spec.kind, StudyKind::Table | StudyKind::Noise) {
            continue;
        }
        let seed = st.spec.seeds[0];
        for p in st.points.iter().filter(|p| p.seed == seed) {
            let scene = plan.runs[p.run].scene;
            let i = match cells.iter().position(|(s, _)| *s == scene) {
                Some(i) => i,
                None => {
                    cells.push((scene, Vec::new()));
                    cells.len() - 1
                }
            };
            if !cells[i].1.contains(&p.run) {
                cells[i].1.push(p.run);
            }
        }
    }
    let mut sets = Vec::new();
    for (scene, runs) in cells {
        let mut methods = Vec::new();
        for run in runs {
            let dir = plan.run_dir(out, run);
            if !dir.join(RunDir::MANIFEST).exists() {
                continue;
            }
            let label = suite.method_label(&plan.runs[run].method);
            methods.push(Shown::run(label, &RunScores::load(&dir)?));
        }
        let dir = plan.scene_dir(out, scene);
        if methods.is_empty() || !dir.join("scene.yaml").exists() {
            continue;
        }
        let cell = &plan.scenes[scene];
        sets.push(SliceSet {
            title: format!(
                "{}, {} views, noise {}",
                suite.scene_label(&cell.scene),
                cell.views,
                cell.noise
            ),
            scene: Some(dir),
            methods,
        });
    }
    Ok(sets)
}
