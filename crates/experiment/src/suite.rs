//! Suite files (`configs/suites/*.yaml`): named scenes and methods (a config plus `--set`
//! overrides each), and studies that cross some of them with view counts, noise levels and
//! seeds. Paths are relative to the suite file. See `docs/experiments.md` for the format.

use crate::{Error, Result};
use prism_domain::metrics::RoiSpec;
use prism_domain::yaml::{self, Overrides};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A parsed, checked suite.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Suite {
    pub name: String,
    /// What the suite is for and the regime its figures use (copied into the report).
    #[serde(default)]
    pub description: String,
    #[serde(default)]
    pub evaluation: EvaluationSpec,
    pub scenes: BTreeMap<String, SceneSpec>,
    pub methods: BTreeMap<String, MethodSpec>,
    pub studies: Vec<StudySpec>,
    /// Run cells executed at a time by `prism experiment` (`--jobs` overrides), the machine's
    /// threads split evenly between them. Two single-thread cells keep a 2-core machine busier
    /// than one cell on both threads (whose serial parts leave a core idle).
    #[serde(default = "one_job")]
    pub jobs: usize,
}

fn one_job() -> usize {
    1
}

/// A scene: a scene config (`configs/*.yaml`, simulated) or a measured scan's import config
/// (`configs/real/*.yaml`, `import: true`), and overrides of it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    pub config: PathBuf,
    /// `config` is an import config (`prism import`): a measured scan, its views picked by the
    /// study (`select.views`), with neither noise levels nor seeds.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub import: bool,
    /// Name in tables and figures (default: the key).
    #[serde(default)]
    pub label: Option<String>,
    #[serde(default)]
    pub set: Vec<String>,
    /// Score this scene's runs inside its object mask (overrides `evaluation.roi`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roi: Option<RoiSpec>,
}

/// A method: a reconstruction config (`configs/recon/*.yaml`) and overrides of it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodSpec {
    pub config: PathBuf,
    #[serde(default)]
    pub label: Option<String>,
    #[serde(default)]
    pub set: Vec<String>,
}

/// How every run of the suite is scored (`docs/metrics.md`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvaluationSpec {
    /// Resample both volumes to `grid`³ before scoring (absent: the native grid).
    #[serde(default)]
    pub grid: Option<usize>,
    /// Score z slices only (false) or slices along every axis (true).
    #[serde(default)]
    pub all_slices: bool,
    /// LPIPS weights (`scripts/lpips_weights.py`); absent: no LPIPS column.
    #[serde(default)]
    pub lpips: Option<PathBuf>,
    /// Score inside each scene's object mask (`docs/metrics.md`); absent: the whole grid. A
    /// scene's own `roi` takes precedence.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roi: Option<RoiSpec>,
}

/// What a study measures and therefore which cells it runs and what it reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StudyKind {
    /// The paper's Table II: methods × scenes (PSNR / SSIM / LPIPS and their average), PSNR
    /// against wall time, slice montages, an equal-time comparison.
    Table,
    /// The same table at each noise level, and PSNR against the noise level.
    Noise,
    /// Training time (and PSNR) against the number of channels; the scenes differ in channels.
    Channels,
    /// Stage-2 freezing strategies from one shared stage 1 (`prism ablate freeze`).
    Freeze,
    /// GSC-Net against the MLP from one shared stage 1 (`prism ablate curve-model`).
    CurveModel,
    /// Projections of a channel held out of training: reference, prediction and residual.
    Holdout,
}

impl StudyKind {
    /// Whether the study's cells are stage-2 ablations (one shared stage 1, several variants).
    pub fn is_ablation(self) -> bool {
        matches!(self, StudyKind::Freeze | StudyKind::CurveModel)
    }

    pub fn name(self) -> &'static str {
        match self {
            StudyKind::Table => "table",
            StudyKind::Noise => "noise",
            StudyKind::Channels => "channels",
            StudyKind::Freeze => "freeze",
            StudyKind::CurveModel => "curve-model",
            StudyKind::Holdout => "holdout",
        }
    }
}

/// How many training views a scene gets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ViewsSpec {
    Count(usize),
    Regime(Regime),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Regime {
    /// The scene config's own view count.
    Shipped,
    /// The paper's angular undersampling at the scene's grid: round(50·n/256) views for an n³
    /// volume (64³ → 13, 128³ → 25, 256³ → 50).
    Undersampled,
    /// The undersampled count for every channel: C·round(50·n/256) distinct angles for C
    /// channels (64³, 3 channels → 39). With `acquisition={views: interleaved}` each channel is
    /// measured at its own undersampled set of angles; with every channel at every angle it is
    /// the full-data reference of such a scan.
    UndersampledPerChannel,
}

impl ViewsSpec {
    /// The training views for a scene of `n`³ voxels and `channels` channels configured with
    /// `shipped` views.
    pub fn resolve(self, n: usize, channels: usize, shipped: usize) -> usize {
        match self {
            ViewsSpec::Count(v) => v,
            ViewsSpec::Regime(Regime::Shipped) => shipped,
            ViewsSpec::Regime(Regime::Undersampled) => undersampled_views(n),
            ViewsSpec::Regime(Regime::UndersampledPerChannel) => {
                undersampled_views(n) * channels.max(1)
            }
        }
    }
}

/// The paper's angular sampling (50 views for a 256³ volume) at an `n`³ volume: the view count
/// that leaves the same fraction of the ~n·π/2 views full sampling needs, round(50·n/256), at
/// least 2.
pub fn undersampled_views(n: usize) -> usize {
    ((50.0 * n as f64 / 256.0).round() as usize).max(2)
}

/// A named noise level: overrides of the scene config (`noise={i0: 1e5}`, or `noise=` for none).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSpec {
    pub name: String,
    #[serde(default)]
    pub set: Vec<String>,
}

impl NoiseSpec {
    /// The scene config's own noise (no override).
    pub fn shipped() -> Self {
        NoiseSpec {
            name: "shipped".into(),
            set: Vec::new(),
        }
    }
}

/// One study: its kind and the axes it crosses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudySpec {
    pub name: String,
    pub kind: StudyKind,
    #[serde(default)]
    pub description: String,
    /// Keys of `scenes` (columns of a table, points of the channel study).
    pub scenes: Vec<String>,
    /// Keys of `methods` (rows of a table); ablations take exactly one `4dsg` method.
    pub methods: Vec<String>,
    #[serde(default = "default_views")]
    pub views: Vec<ViewsSpec>,
    /// Named overrides of the scene config: noise levels, and acquisitions (interleaved views,
    /// split photons); `acquisitions:` is the same axis.
    #[serde(default = "default_noise", alias = "acquisitions")]
    pub noise: Vec<NoiseSpec>,
    #[serde(default = "default_seeds")]
    pub seeds: Vec<u64>,
}

fn default_views() -> Vec<ViewsSpec> {
    vec![ViewsSpec::Regime(Regime::Shipped)]
}

fn default_noise() -> Vec<NoiseSpec> {
    vec![NoiseSpec::shipped()]
}

fn default_seeds() -> Vec<u64> {
    vec![0]
}

/// A suite with the directory its relative paths start from.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedSuite {
    pub suite: Suite,
    /// The suite file.
    pub file: PathBuf,
    /// Overrides of the suite file itself (`prism experiment --set`).
    pub overrides: Overrides,
}

impl LoadedSuite {
    /// Read and check a suite file with `overrides` applied to it.
    pub fn load(file: &Path, overrides: &Overrides) -> Result<Self> {
        let mut suite: Suite = yaml::read_with(file, overrides)?;
        let base = file.parent().unwrap_or(Path::new("."));
        for s in suite.scenes.values_mut() {
            s.config = base.join(&s.config);
        }
        for m in suite.methods.values_mut() {
            m.config = base.join(&m.config);
        }
        if let Some(l) = &mut suite.evaluation.lpips {
            *l = base.join(&*l);
        }
        suite.validate().map_err(|e| e.in_file(file))?;
        Ok(LoadedSuite {
            suite,
            file: file.to_path_buf(),
            overrides: overrides.clone(),
        })
    }
}

fn key_ok(k: &str) -> bool {
    !k.is_empty()
        && k.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        && !k.starts_with('.')
}

/// `Ok` when `text` has no control character (newline, carriage return, tab…), else an error
/// naming `field`: such text would break a line of a generated script or report.
pub fn plain_text(field: &str, text: &str) -> Result<()> {
    match text.chars().find(|c| c.is_control()) {
        Some(c) => Err(Error::invalid(
            field,
            format!("{text:?} holds the control character {c:?}: give it on one line"),
        )),
        None => Ok(()),
    }
}

impl Suite {
    /// Names, references between sections and axis values; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: String, msg: String| Err(Error::invalid(field, msg));
        if !key_ok(&self.name) {
            return bad("name".into(), "letters, digits, `-`, `_` or `.`".into());
        }
        if self.jobs == 0 {
            return bad("jobs".into(), "at least 1".into());
        }
        for (section, keys) in [
            ("scenes", self.scenes.keys().collect::<Vec<_>>()),
            ("methods", self.methods.keys().collect()),
        ] {
            if keys.is_empty() {
                return bad(section.into(), "at least one entry is required".into());
            }
            if let Some(k) = keys.iter().find(|k| !key_ok(k)) {
                return bad(
                    format!("{section}.{k}"),
                    "keys are directory names: letters, digits, `-`, `_` or `.`".into(),
                );
            }
        }
        for (k, s) in &self.scenes {
            Overrides::parse(&s.set).map_err(|e| e.under(&format!("scenes.{k}.set")))?;
            if s.label.as_deref() == Some("") {
                return bad(format!("scenes.{k}.label"), "must not be empty".into());
            }
            plain_text(
                &format!("scenes.{k}.label"),
                s.label.as_deref().unwrap_or(""),
            )?;
            if let Some(r) = &s.roi {
                r.validate()
                    .map_err(|e| e.under(&format!("scenes.{k}.roi")))?;
            }
        }
        for (k, m) in &self.methods {
            Overrides::parse(&m.set).map_err(|e| e.under(&format!("methods.{k}.set")))?;
            plain_text(
                &format!("methods.{k}.label"),
                m.label.as_deref().unwrap_or(""),
            )?;
        }
        if let Some(r) = &self.evaluation.roi {
            r.validate().map_err(|e| e.under("evaluation.roi"))?;
        }
        prism_recon::evaluate::Protocol::check_grid(self.evaluation.grid, "evaluation.grid")?;
        if self.studies.is_empty() {
            return bad("studies".into(), "at least one study is required".into());
        }
        let mut names = std::collections::BTreeSet::new();
        for (i, st) in self.studies.iter().enumerate() {
            let f = |x: &str| format!("studies[{i}].{x}");
            if !key_ok(&st.name) || !names.insert(&st.name) {
                return bad(
                    f("name"),
                    format!("`{}`: unique, a directory name", st.name),
                );
            }
            for (axis, empty) in [
                ("scenes", st.scenes.is_empty()),
                ("methods", st.methods.is_empty()),
                ("views", st.views.is_empty()),
                ("noise", st.noise.is_empty()),
                ("seeds", st.seeds.is_empty()),
            ] {
                if empty {
                    return bad(f(axis), "must not be empty".into());
                }
            }
            for (axis, keys) in [("scenes", &st.scenes), ("methods", &st.methods)] {
                let unique: std::collections::BTreeSet<_> = keys.iter().collect();
                if unique.len() != keys.len() {
                    return bad(f(axis), "an entry is listed twice".into());
                }
            }
            if let Some(s) = st.scenes.iter().find(|s| !self.scenes.contains_key(*s)) {
                return bad(f("scenes"), format!("`{s}` is not a key of `scenes`"));
            }
            if let Some(m) = st.methods.iter().find(|m| !self.methods.contains_key(*m)) {
                return bad(f("methods"), format!("`{m}` is not a key of `methods`"));
            }
            if st.kind.is_ablation() && st.methods.len() != 1 {
                return bad(
                    f("methods"),
                    format!(
                        "a `{}` study varies stage 2 of one `4dsg` method; give exactly one",
                        st.kind.name()
                    ),
                );
            }
            if let Some(v) = st
                .views
                .iter()
                .find(|v| matches!(v, ViewsSpec::Count(c) if *c < 2))
            {
                return bad(f("views"), format!("{v:?}: at least 2 views"));
            }
            let mut levels = std::collections::BTreeSet::new();
            for n in &st.noise {
                if !key_ok(&n.name) || !levels.insert(&n.name) {
                    return bad(
                        f("noise"),
                        format!("`{}`: unique, a directory name", n.name),
                    );
                }
                Overrides::parse(&n.set).map_err(|e| e.under(&f("noise")))?;
            }
        }
        Ok(())
    }

    /// The label of scene `key` in tables and figures.
    pub fn scene_label<'a>(&'a self, key: &'a str) -> &'a str {
        self.scenes
            .get(key)
            .and_then(|s| s.label.as_deref())
            .unwrap_or(key)
    }

    /// The label of method `key` in tables and figures.
    pub fn method_label<'a>(&'a self, key: &'a str) -> &'a str {
        self.methods
            .get(key)
            .and_then(|m| m.label.as_deref())
            .unwrap_or(key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SUITE: &str = "name: t\nscenes:\n  a: { config: scene.yaml }\nmethods:\n  sart: { config: sart.yaml, set: [iterations=1] }\nstudies:\n  - { name: main, kind: table, scenes: [a], methods: [sart], views: [undersampled, 7] }\n";

    fn load(text: &str, set: &[&str]) -> Result<LoadedSuite> {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("suite.yaml");
        std::fs::write(&f, text).unwrap();
        LoadedSuite::load(&f, &Overrides::parse(set).unwrap())
    }

    #[test]
    fn the_undersampled_regime_scales_the_papers_views_with_the_grid() {
        assert_eq!(undersampled_views(256), 50);
        assert_eq!(undersampled_views(128), 25);
        assert_eq!(undersampled_views(64), 13);
        assert_eq!(undersampled_views(32), 6);
        assert_eq!(undersampled_views(4), 2);
        let s = load(SUITE, &[]).unwrap();
        let v = &s.suite.studies[0].views;
        assert_eq!(v[0].resolve(64, 3, 50), 13);
        assert_eq!(v[1].resolve(64, 3, 50), 7);
        assert_eq!(ViewsSpec::Regime(Regime::Shipped).resolve(64, 3, 50), 50);
        let each = ViewsSpec::Regime(Regime::UndersampledPerChannel);
        assert_eq!(
            (each.resolve(64, 3, 50), each.resolve(64, 8, 50)),
            (39, 104)
        );
        // Paths are relative to the suite file; defaults fill the axes.
        assert!(s.suite.scenes["a"].config.is_absolute());
        assert_eq!(s.suite.studies[0].seeds, vec![0]);
        assert_eq!(s.suite.studies[0].noise, vec![NoiseSpec::shipped()]);
    }

    #[test]
    fn bad_suites_name_the_field() {
        for (text, set, needle) in [
            (
                SUITE,
                "studies.0.scenes=[b]",
                "`b` is not a key of `scenes`",
            ),
            (
                SUITE,
                "studies.0.methods=[fdk]",
                "`fdk` is not a key of `methods`",
            ),
            (SUITE, "studies.0.views=[1]", "at least 2 views"),
            (SUITE, "studies.0.views=[many]", "studies[0].views"),
            (SUITE, "studies.0.methods=[sart, sart]", "listed twice"),
            (SUITE, "studies.0.seeds=[]", "studies[0].seeds"),
            (SUITE, "methods.sart.set=[iterations]", "methods.sart.set"),
            (SUITE, "scenes.a/b={config: x}", "scenes.a/b"),
            (SUITE, "studies.0.kind=movie", "studies[0].kind"),
            // A label reaches the report and figures: one line only.
            (
                SUITE,
                "methods.sart.label=\"SART\\nrm -rf ~\"",
                "holds the control character '\\n'",
            ),
            (
                SUITE,
                "evaluation.roi={threshold: 2}",
                "evaluation.roi.threshold",
            ),
            (
                SUITE,
                "scenes.a.roi={erode_mm: -1}",
                "scenes.a.roi.erode_mm",
            ),
            (
                SUITE,
                "scenes.a.roi={region: field_of_view, smooth_mm: 2}",
                "scenes.a.roi.smooth_mm",
            ),
            (
                SUITE,
                "evaluation.roi={region: everywhere}",
                "evaluation.roi",
            ),
        ] {
            let e = load(text, &[set]).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("suite.yaml"), "{set}: {e}");
        }
    }
}
