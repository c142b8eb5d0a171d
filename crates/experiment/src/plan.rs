//! A suite expanded into cells: every (scene, views, noise, seed) a study needs is one
//! [`SceneCell`], simulated once into `scenes/<key>/`; every (scene cell, method) one
//! [`RunCell`], a run directory `runs/<scene key>/<method>/` (an ablation cell holds one run
//! directory per variant). Studies share cells with the same key, so the table's runs also serve
//! the noise study's `shipped` level.

use crate::suite::{LoadedSuite, SceneSpec, StudyKind, StudySpec};
use crate::{Error, Result};
use prism_domain::import::ImportConfig;
use prism_domain::metrics::RoiSpec;
use prism_domain::simulate::SimulateConfig;
use prism_domain::yaml::Overrides;
use prism_recon::methods::fourdsg::ablation::Study;
use prism_recon::{Method, MethodConfig};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A scene's voxels along x, y, z, its channel count and configured training views, from its
/// config with `overrides`.
fn scene_shape(spec: &SceneSpec, overrides: &Overrides) -> prism_domain::Result<SceneShape> {
    if spec.import {
        let c: ImportConfig = prism_domain::yaml::read_with(&spec.config, overrides)?;
        let base = spec.config.parent().unwrap_or(Path::new("."));
        let (g, _) = c.scan_geometry(base)?;
        let (train, _) = c.pick_views(g.views())?;
        let v = &g.volume;
        Ok(([v.nx, v.ny, v.nz], c.channels.len(), train.len()))
    } else {
        let c = SimulateConfig::load_with(&spec.config, overrides)?;
        let n = c.geometry.volume.n;
        Ok(([n; 3], c.channels.len(), c.geometry.views))
    }
}

/// Voxels along x, y, z; channels; training views.
type SceneShape = ([usize; 3], usize, usize);

impl SceneCell {
    /// The grid as tables print it: `64³` for a cube, `512×512×1` otherwise.
    pub fn grid_label(&self) -> String {
        let [x, y, z] = self.grid;
        if x == y && y == z {
            format!("{x}³")
        } else {
            format!("{x}×{y}×{z}")
        }
    }

    /// The peak memory of making this scene (simulating it, or importing the scan with its
    /// references).
    pub fn footprint(&self) -> prism_domain::Result<u64> {
        let f = if self.import {
            let c: ImportConfig = prism_domain::yaml::read_with(&self.config, &self.overrides)?;
            prism_domain::import::footprint(&c, self.config.parent().unwrap_or(Path::new(".")))?
        } else {
            SimulateConfig::load_with(&self.config, &self.overrides)?.footprint()?
        };
        Ok(f.total())
    }
}

/// Where the cells live under the output directory.
pub const SCENES: &str = "scenes";
pub const RUNS: &str = "runs";

/// A scene at one view count, noise level and seed.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneCell {
    /// `<scene>-v<views>-<noise>-s<seed>`, its directory under `scenes/`.
    pub key: String,
    /// Key of the suite's scene.
    pub scene: String,
    pub views: usize,
    pub noise: String,
    pub seed: u64,
    /// Edge of the volume grid (voxels; a slice's larger side) and number of channels.
    pub n: usize,
    /// Voxels along x, y, z.
    pub grid: [usize; 3],
    pub channels: usize,
    pub config: PathBuf,
    /// `config` is an import config (a measured scan), not a simulation's.
    pub import: bool,
    /// The scene's `set`, the noise level's, then `geometry.views` and `seed` (an imported
    /// scene: its `set`, then `select.views`).
    pub overrides: Overrides,
    /// The object mask its runs are scored in (the scene's `roi`, else the suite's).
    pub roi: Option<RoiSpec>,
}

/// What a run cell does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellKind {
    /// `prism recon`.
    Run,
    /// `prism ablate`: one shared stage 1, one run directory per stage-2 variant.
    Ablation(Study),
}

/// One method on one scene cell.
#[derive(Clone, Debug, PartialEq)]
pub struct RunCell {
    /// `<scene cell>/<method>` (`.freeze` / `.curve-model` appended for ablations), its directory
    /// under `runs/`.
    pub key: String,
    /// Index into [`Plan::scenes`].
    pub scene: usize,
    /// Key of the suite's method.
    pub method: String,
    pub kind: CellKind,
    pub config: PathBuf,
    /// The method's `set`, then `seed`.
    pub overrides: Overrides,
}

/// One point of a study: a run cell at its axes' values.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyPoint {
    /// Index into [`Plan::runs`].
    pub run: usize,
    pub scene: String,
    pub method: String,
    pub views: usize,
    pub noise: String,
    pub seed: u64,
}

/// A study and its points, in the order of its axes (scenes outermost, methods innermost).
#[derive(Clone, Debug, PartialEq)]
pub struct StudyPlan {
    pub spec: StudySpec,
    pub points: Vec<StudyPoint>,
}

/// Every cell of a suite.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub scenes: Vec<SceneCell>,
    pub runs: Vec<RunCell>,
    pub studies: Vec<StudyPlan>,
    /// The method (`sart`, `r2gs`, `4dsg`, …) of every suite method a study uses.
    pub methods: BTreeMap<String, Method>,
}

impl Plan {
    /// Expand `suite`: read every scene config (for its grid, view count and channels) and
    /// method config (an ablation's must be `4dsg`), with their overrides applied.
    pub fn new(suite: &LoadedSuite) -> Result<Self> {
        let s = &suite.suite;
        let mut scenes: Vec<SceneCell> = Vec::new();
        let mut scene_index: BTreeMap<String, usize> = BTreeMap::new();
        let mut runs: Vec<RunCell> = Vec::new();
        let mut run_index: BTreeMap<String, usize> = BTreeMap::new();
        let mut shipped: BTreeMap<&str, (usize, usize, usize)> = BTreeMap::new();
        let edge = |g: [usize; 3]| g[0].max(g[1]).max(g[2]);
        let mut methods: BTreeMap<&str, Method> = BTreeMap::new();
        let mut studies = Vec::new();
        for (i, st) in s.studies.iter().enumerate() {
            let field = |x: &str| format!("studies[{i}].{x}");
            let mut points = Vec::new();
            for scene in &st.scenes {
                let spec = &s.scenes[scene];
                let base = Overrides::parse(&spec.set)?;
                let (n, channels, views0) = match shipped.get(scene.as_str()) {
                    Some(&v) => v,
                    None => {
                        let (grid, channels, views) = scene_shape(spec, &base)
                            .map_err(|e| Error::from(e).in_cell(format!("scenes.{scene}")))?;
                        let v = (edge(grid), channels, views);
                        shipped.insert(scene, v);
                        v
                    }
                };
                for &views in &st.views {
                    let views = views.resolve(n, channels, views0);
                    for noise in &st.noise {
                        for &seed in &st.seeds {
                            let key = format!("{scene}-v{views}-{}-s{seed}", noise.name);
                            let si = match scene_index.get(&key) {
                                Some(&si) => si,
                                None => {
                                    let overrides = if spec.import {
                                        if !noise.set.is_empty() {
                                            return Err(Error::from(prism_domain::Error::invalid(
                                                field("noise"),
                                                format!(
                                                    "scene `{scene}` is a measured scan: \
                                                         its noise is its own (noise level \
                                                         `{}` sets {:?})",
                                                    noise.name, noise.set
                                                ),
                                            )));
                                        }
                                        base.then(&Overrides::parse([format!(
                                            "select.views={views}"
                                        )])?)
                                    } else {
                                        base.then(&Overrides::parse(&noise.set)?).then(
                                            &Overrides::parse([
                                                format!("geometry.views={views}"),
                                                format!("seed={seed}"),
                                            ])?,
                                        )
                                    };
                                    let (grid, channels, _) = scene_shape(spec, &overrides)
                                        .map_err(|e| Error::from(e).in_cell(&key))?;
                                    scenes.push(SceneCell {
                                        key: key.clone(),
                                        scene: scene.clone(),
                                        views,
                                        noise: noise.name.clone(),
                                        seed,
                                        n: edge(grid),
                                        grid,
                                        channels,
                                        config: spec.config.clone(),
                                        import: spec.import,
                                        overrides,
                                        roi: spec.roi.clone().or_else(|| s.evaluation.roi.clone()),
                                    });
                                    scene_index.insert(key.clone(), scenes.len() - 1);
                                    scenes.len() - 1
                                }
                            };
                            for method in &st.methods {
                                let m = &s.methods[method];
                                let overrides = Overrides::parse(&m.set)?
                                    .then(&Overrides::parse([format!("seed={seed}")])?);
                                let kind = cell_kind(st.kind);
                                if !methods.contains_key(method.as_str()) {
                                    let c = MethodConfig::load_with(&m.config, &overrides)
                                        .map_err(|e| {
                                            Error::from(e).in_cell(format!("methods.{method}"))
                                        })?;
                                    methods.insert(method, c.method());
                                }
                                if kind != CellKind::Run
                                    && methods[method.as_str()] != Method::FourDsg
                                {
                                    return Err(Error::invalid(
                                        field("methods"),
                                        format!(
                                            "`{method}` is `{}`; a `{}` study varies stage 2 of \
                                             a `4dsg` method",
                                            methods[method.as_str()].name(),
                                            st.kind.name()
                                        ),
                                    )
                                    .in_file(&suite.file));
                                }
                                let rkey = match kind {
                                    CellKind::Run => format!("{key}/{method}"),
                                    CellKind::Ablation(study) => {
                                        format!("{key}/{method}.{}", study.name())
                                    }
                                };
                                let ri = *run_index.entry(rkey.clone()).or_insert_with(|| {
                                    runs.push(RunCell {
                                        key: rkey,
                                        scene: si,
                                        method: method.clone(),
                                        kind,
                                        config: m.config.clone(),
                                        overrides,
                                    });
                                    runs.len() - 1
                                });
                                points.push(StudyPoint {
                                    run: ri,
                                    scene: scene.clone(),
                                    method: method.clone(),
                                    views,
                                    noise: noise.name.clone(),
                                    seed,
                                });
                            }
                        }
                    }
                }
            }
            studies.push(StudyPlan {
                spec: st.clone(),
                points,
            });
        }
        let methods = methods
            .into_iter()
            .map(|(k, m)| (k.to_string(), m))
            .collect();
        Ok(Plan {
            scenes,
            runs,
            studies,
            methods,
        })
    }

    /// The directory of scene cell `i` under `out`.
    pub fn scene_dir(&self, out: &Path, i: usize) -> PathBuf {
        out.join(SCENES).join(&self.scenes[i].key)
    }

    /// The directory of run cell `i` under `out`.
    pub fn run_dir(&self, out: &Path, i: usize) -> PathBuf {
        out.join(RUNS).join(&self.runs[i].key)
    }

    /// The scene cell of run cell `i`.
    pub fn scene_of(&self, i: usize) -> &SceneCell {
        &self.scenes[self.runs[i].scene]
    }
}

fn cell_kind(kind: StudyKind) -> CellKind {
    match kind {
        StudyKind::Freeze => CellKind::Ablation(Study::Freeze),
        StudyKind::CurveModel => CellKind::Ablation(Study::CurveModel),
        _ => CellKind::Run,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A suite of two scenes (one with a view override) and two methods in two studies that
    /// share cells.
    fn suite(dir: &Path) -> LoadedSuite {
        let scene = prism_domain::testing::phantom_config_yaml("p", 50, 32, 16, &[40, 70]);
        std::fs::write(dir.join("p.yaml"), scene).unwrap();
        std::fs::write(dir.join("sart.yaml"), "method: sart\n").unwrap();
        std::fs::write(dir.join("4dsg.yaml"), "method: 4dsg\niterations: 5\n").unwrap();
        let text = "name: t\nscenes:\n  p: { config: p.yaml }\n  q: { config: p.yaml, set: [geometry.volume.n=64] }\n\
                    methods:\n  sart: { config: sart.yaml }\n  g: { config: 4dsg.yaml }\n\
                    studies:\n\
                    \x20 - { name: main, kind: table, scenes: [p, q], methods: [sart, g], views: [undersampled] }\n\
                    \x20 - { name: noise, kind: noise, scenes: [p], methods: [sart], views: [undersampled],\n\
                    \x20     noise: [{name: shipped}, {name: hi, set: [\"noise={i0: 1.0e4}\"]}], seeds: [0, 1] }\n\
                    \x20 - { name: fr, kind: freeze, scenes: [p], methods: [g], views: [undersampled, 20] }\n";
        std::fs::write(dir.join("s.yaml"), text).unwrap();
        LoadedSuite::load(&dir.join("s.yaml"), &Overrides::default()).unwrap()
    }

    #[test]
    fn studies_expand_into_shared_cells_with_their_overrides() {
        let dir = tempfile::tempdir().unwrap();
        let plan = Plan::new(&suite(dir.path())).unwrap();
        let keys: Vec<&str> = plan.scenes.iter().map(|s| s.key.as_str()).collect();
        // 32³ → 6 views, 64³ → 13; the noise study's shipped seed-0 scene is the table's.
        assert_eq!(
            keys,
            [
                "p-v6-shipped-s0",
                "q-v13-shipped-s0",
                "p-v6-shipped-s1",
                "p-v6-hi-s0",
                "p-v6-hi-s1",
                "p-v20-shipped-s0"
            ]
        );
        let hi = &plan.scenes[3];
        assert_eq!(
            hi.overrides.texts(),
            ["noise={i0: 1.0e4}", "geometry.views=6", "seed=0"]
        );
        assert_eq!((hi.n, hi.channels, hi.views), (32, 2, 6));
        let runs: Vec<&str> = plan.runs.iter().map(|r| r.key.as_str()).collect();
        assert_eq!(
            runs,
            [
                "p-v6-shipped-s0/sart",
                "p-v6-shipped-s0/g",
                "q-v13-shipped-s0/sart",
                "q-v13-shipped-s0/g",
                "p-v6-shipped-s1/sart",
                "p-v6-hi-s0/sart",
                "p-v6-hi-s1/sart",
                "p-v6-shipped-s0/g.freeze",
                "p-v20-shipped-s0/g.freeze"
            ]
        );
        assert_eq!(plan.runs[4].overrides.texts(), ["seed=1"]);
        assert_eq!(plan.studies[1].points.len(), 4);
        assert_eq!(plan.studies[1].points[0].run, 0, "shared with the table");
        assert_eq!(plan.runs[7].kind, CellKind::Ablation(Study::Freeze));
        assert_eq!(plan.scene_of(3).key, "q-v13-shipped-s0");
    }

    #[test]
    fn an_ablation_of_a_classic_method_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = suite(dir.path());
        s.suite.studies[2].methods = vec!["sart".into()];
        let e = Plan::new(&s).unwrap_err().to_string();
        assert!(
            e.contains("studies[2].methods") && e.contains("`sart` is `sart`"),
            "{e}"
        );
        assert!(e.contains("s.yaml"), "{e}");
    }

    #[test]
    fn a_measured_scan_gets_its_views_by_select_and_refuses_noise() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // 24 views of a 1 × 8 detector line, as headerless f32.
        std::fs::write(d.join("li.raw"), vec![0u8; 24 * 8 * 4]).unwrap();
        std::fs::write(
            d.join("scan.yaml"),
            "name: m\ngeometry:\n  fan: { dso: 50.0, dsd: 80.0, cols: 8, pitch: 1.0, nx: 10, ny: 12, dx: 0.5, dy: 0.5 }\n\
             angles: { count: 24 }\nchannels:\n\
             \x20 - { label: a, coordinate: { kind: tube_voltage, kvp: 50 },\n\
             \x20     line_integrals: { path: li.raw, raw: { dtype: f32, shape: [24, 1, 8] } } }\n\
             select: { views: 12 }\n",
        )
        .unwrap();
        std::fs::write(d.join("sart.yaml"), "method: sart\n").unwrap();
        let text = "name: t\nscenes:\n  m: { config: scan.yaml, import: true }\n\
                    methods:\n  sart: { config: sart.yaml }\n\
                    studies:\n  - { name: v, kind: table, scenes: [m], methods: [sart], views: [shipped, 6] }\n";
        std::fs::write(d.join("s.yaml"), text).unwrap();
        let suite = LoadedSuite::load(&d.join("s.yaml"), &Overrides::default()).unwrap();
        let plan = Plan::new(&suite).unwrap();
        let keys: Vec<&str> = plan.scenes.iter().map(|s| s.key.as_str()).collect();
        assert_eq!(keys, ["m-v12-shipped-s0", "m-v6-shipped-s0"]);
        let m = &plan.scenes[1];
        assert!(m.import);
        assert_eq!(m.overrides.texts(), ["select.views=6"]);
        assert_eq!((m.n, m.channels, m.views), (12, 1, 6));
        assert_eq!(m.grid_label(), "10×12×1");
        // A noise level is the simulator's: a measured scan has its own.
        let noisy = text.replace(
            "views: [shipped, 6] }",
            "noise: [{name: hi, set: [\"noise={i0: 1.0e4}\"]}] }",
        );
        std::fs::write(d.join("s.yaml"), noisy).unwrap();
        let suite = LoadedSuite::load(&d.join("s.yaml"), &Overrides::default()).unwrap();
        let e = Plan::new(&suite).unwrap_err().to_string();
        assert!(e.contains("measured scan"), "{e}");
        // More views than the scan has: refused at planning, naming the field.
        let many = text.replace("views: [shipped, 6]", "views: [30]");
        std::fs::write(d.join("s.yaml"), many).unwrap();
        let suite = LoadedSuite::load(&d.join("s.yaml"), &Overrides::default()).unwrap();
        let e = Plan::new(&suite).unwrap_err().to_string();
        assert!(e.contains("select.views"), "{e}");
    }
}
