//! Fuzzing the readers of user files with bolero: scene directories (`scene.yaml` and its `.npy`
//! arrays), R²-Gaussian case folders (`meta_data.json` and its projections), method configs,
//! scene (simulation) configs, trained models and stage-1 checkpoints (safetensors), import
//! configs (with their images), TIFF stacks, and the resume files of R²-Gaussian and NAF runs.
//! (Prism writes NIfTI and MetaImage but reads neither.)
//!
//! Property: every input is read, or refused with an error that names the file; nothing panics,
//! aborts or allocates what the file does not hold (an abort ends the test process: a failure).
//!
//! Each target runs two bolero checks under `cargo test`:
//! * raw inputs: the committed corpus `tests/__fuzz__/<target>/corpus/` (valid files and the
//!   malformed ones found by hand), then random byte strings;
//! * mutations of a valid seed (built at run time from a tiny simulated scene and run): bytes
//!   set, 8-byte words and text tokens replaced by extreme values (0, −1, 2⁶³, NaN, 1e308, …),
//!   truncation, duplicated spans.
//!
//! `PRISM_FUZZ_ITERATIONS` sets the random inputs per check (default 300, a CI budget of a few
//! seconds per target); `PRISM_FUZZ_SECONDS` instead runs each target that long (bolero prints
//! the inputs tried). Longer runs: `cargo bolero test --engine libfuzzer fuzz_<target>` (nightly),
//! which uses the same corpus.

mod common;

use bolero::TypeGenerator;
use prism_domain::observe::Silent;
use prism_domain::scene::Scene;
use prism_domain::simulate::SimulateConfig;
use prism_recon::MethodConfig;
use prism_recon::device::cpu_device;
use prism_recon::evaluate::Evaluation;
use prism_recon::methods::fourdsg::FourDsgConfig;
use prism_recon::methods::fourdsg::stage1::checkpoint;
use prism_recon::pipeline::run;
use prism_recon::record::RunDir;
use prism_recon::setup::RunOptions;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn iterations() -> usize {
    std::env::var("PRISM_FUZZ_ITERATIONS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(300)
}

/// Each check's inputs and time: `PRISM_FUZZ_SECONDS` (a target's total, split between its two
/// checks) runs for that long whatever the count; otherwise [`iterations`] inputs.
fn budget() -> (usize, std::time::Duration) {
    match std::env::var("PRISM_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
    {
        Some(s) => (usize::MAX, std::time::Duration::from_secs(s.div_ceil(2))),
        None => (iterations(), std::time::Duration::MAX),
    }
}

/// Valid inputs of every reader, made once per test process.
struct Seeds {
    _dir: tempfile::TempDir,
    /// A simulated two-channel scene (12³ grid, 12² detector, 8 views).
    scene: PathBuf,
    /// An R²-Gaussian case folder.
    r2: PathBuf,
    /// A 4D-SG run of the scene (model, stage-1 checkpoint).
    run: PathBuf,
    scene_config: Vec<u8>,
    /// An import: `import.yaml`, its line integrals `p.npy` and flat field `flat.tif`.
    import: PathBuf,
    /// Resume files of a tiny R²-Gaussian run and a tiny NAF run, each stopped after its first
    /// iteration.
    resume: PathBuf,
    naf_resume: PathBuf,
}

fn seeds() -> &'static Seeds {
    static SEEDS: OnceLock<Seeds> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let cfg = common::phantom_config("fuzz", 8, 12, 12, &[40, 70]);
        let cfg_path = dir.path().join("scene-config.yaml");
        std::fs::write(&cfg_path, &cfg).unwrap();
        let scene = dir.path().join("scene");
        prism_domain::simulate::simulate_file(&cfg_path, &Default::default(), &Silent)
            .unwrap()
            .save(&scene)
            .unwrap();
        let r2 = dir.path().join("r2");
        prism_domain::testing::write_r2_case(&r2);
        let run_dir = dir.path().join("run");
        let mut c = tiny_4dsg();
        c.geometry.eval_every = 0;
        let options = RunOptions {
            device: cpu_device(),
            from_geometry: None,
            observer: &Silent,
            evaluation: &Evaluation::default(),
            checkpoint: None,
        };
        let config = MethodConfig::from(c);
        let s = Scene::open(&scene).unwrap();
        run(
            &config,
            &s,
            RunDir::create(&run_dir, false).unwrap(),
            &options,
        )
        .unwrap();
        let import = dir.path().join("import");
        write_import(&import);
        let resume = dir.path().join("r2gs.ckpt");
        let naf_resume = dir.path().join("naf.ckpt");
        for (config, ckpt) in [(tiny_r2gs(), &resume), (tiny_naf(), &naf_resume)] {
            let e = resumed_run(&config, &s, &dir.path().join("stopped"), ckpt, false);
            assert!(e.is_err_and(|e| e.contains("interrupted")) && ckpt.is_file());
        }
        Seeds {
            scene,
            r2,
            run: run_dir,
            scene_config: cfg.into_bytes(),
            import,
            resume,
            naf_resume,
            _dir: dir,
        }
    })
}

fn tiny_4dsg() -> FourDsgConfig {
    let mut c = FourDsgConfig::default();
    c.geometry.iterations = 2;
    c.geometry.init.n_points = 40;
    c.geometry.densify = None;
    let s2 = &mut c.spectral.stage2;
    s2.iterations = 1;
    s2.curve_model.width = 4;
    s2.curve_model.depth = 1;
    c
}

fn tiny_r2gs() -> MethodConfig {
    MethodConfig::from_yaml(
        "method: r2gs\niterations: 6\ninit: { n_points: 40 }\ndensify: null\neval_every: 0\n",
        Path::new("r2gs.yaml"),
    )
    .unwrap()
}

fn tiny_naf() -> MethodConfig {
    MethodConfig::from_yaml(
        "method: naf\niterations: 6\nrays_per_batch: 32\nsamples_per_ray: 8\neval_every: 100\n\
         field: {width: 8, hash_grid: {levels: 2, base_resolution: 4, growth: 2.0, \
         log2_table_size: 6}}\n",
        Path::new("naf.yaml"),
    )
    .unwrap()
}

/// Run `config` on `scene` into `out` with the checkpoint `ckpt`: stopped after its first
/// iteration (`resume` false), or resumed from it; Ok or the error's text.
fn resumed_run(
    config: &MethodConfig,
    scene: &Scene,
    out: &Path,
    ckpt: &Path,
    resume: bool,
) -> Result<(), String> {
    let stop = std::sync::atomic::AtomicBool::new(!resume);
    let options = RunOptions {
        device: cpu_device(),
        from_geometry: None,
        observer: &Silent,
        evaluation: &Evaluation::default(),
        checkpoint: Some(prism_recon::setup::Checkpointing {
            path: ckpt.to_path_buf(),
            resume,
            stop: Some(&stop),
        }),
    };
    let dir = RunDir::create(out, true).map_err(|e| e.to_string())?;
    run(config, scene, dir, &options)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// An import of a 6-view line-integral scan (12 × 12 detector) with a two-page TIFF flat field.
fn write_import(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let p =
        ndarray::Array3::<f32>::from_shape_fn((6, 12, 12), |(v, r, c)| 0.01 * (v + r + c) as f32);
    ndarray_npy::write_npy(dir.join("p.npy"), &p).unwrap();
    let flat = std::fs::File::create(dir.join("flat.tif")).unwrap();
    let mut tif = tiff::encoder::TiffEncoder::new(flat).unwrap();
    for _ in 0..2 {
        tif.write_image::<tiff::encoder::colortype::Gray16>(12, 12, &[1000u16; 144])
            .unwrap();
    }
    std::fs::write(
        dir.join("import.yaml"),
        "name: imported\ngeometry: {prism: {beam: cone, dso: 1000.0, dsd: 1500.0, detector: \
         {rows: 12, cols: 12, pitch_u: 40.0, pitch_v: 40.0, offset_u: 0.0, offset_v: 0.0}, \
         volume: {nx: 12, ny: 12, nz: 12, dx: 20.0, dy: 20.0, dz: 20.0, offset: [0.0, 0.0, 0.0]}}}\n\
         angles: {count: 6, start_deg: 0.0, span_deg: 360.0}\nflat: {path: flat.tif}\n\
         channels:\n  - {label: a, coordinate: {kind: energy, kev: 60.0}, line_integrals: {path: p.npy}}\n\
         select: {views: 4, test_views: 1, reference: none}\n",
    )
    .unwrap();
}

/// One reader under test: the file it reads, made from `bytes` in a directory of its own.
struct Target {
    /// The corpus directory's name (`tests/__fuzz__/<name>/corpus/`).
    name: &'static str,
    /// The seed file this target varies.
    seed: fn(&Seeds) -> Vec<u8>,
    /// Read `bytes` as the target's file in `dir` (a fresh copy of its other inputs); Ok or the
    /// error's text.
    read: fn(&Path, &[u8]) -> Result<(), String>,
}

impl Target {
    /// Read `bytes`; a refusal must name a file of this input's directory.
    fn check(&self, work: &Path, bytes: &[u8]) {
        let case = work.join("case");
        let _ = std::fs::remove_dir_all(&case);
        std::fs::create_dir_all(&case).unwrap();
        if let Err(e) = (self.read)(&case, bytes) {
            assert!(
                e.contains(case.to_str().unwrap()),
                "the error names no file: {e}"
            );
        }
    }

    fn fuzz(&self) {
        let work = tempfile::tempdir().unwrap();
        let (n, time) = budget();
        bolero::check!(name = self.name)
            .with_iterations(n)
            .with_test_time(time)
            .for_each(|bytes: &[u8]| self.check(work.path(), bytes));
        let seed = (self.seed)(seeds());
        bolero::check!(name = format!("{}_mutations", self.name))
            .with_type::<Vec<Edit>>()
            .with_iterations(n)
            .with_test_time(time)
            .for_each(|edits: &Vec<Edit>| self.check(work.path(), &mutate(&seed, edits)));
    }
}

/// One mutation of a seed file; positions wrap around its length.
#[derive(Clone, Debug, TypeGenerator)]
enum Edit {
    /// Set one byte.
    Byte { at: u32, value: u8 },
    /// Replace the text token at `at` (a run of letters, digits, `.+-_`) by an extreme literal.
    Token { at: u32, which: u8 },
    /// Overwrite 8 bytes at `at` with an extreme little-endian u64 / f64.
    Word { at: u32, which: u8 },
    /// Cut the file at `at`.
    Truncate { at: u32 },
    /// Insert a copy of `len` bytes from `from` at `at`.
    Duplicate { from: u32, len: u8, at: u32 },
}

const TOKENS: [&str; 16] = [
    "0",
    "-1",
    "1e308",
    "-1e308",
    ".nan",
    ".inf",
    "nan",
    "1e-320",
    "4294967296",
    "18446744073709551616",
    "9223372036854775807",
    "100000",
    "\"\"",
    "null",
    "[]",
    "{}",
];

fn words() -> [u64; 8] {
    [
        0,
        u64::MAX,
        1 << 40,
        1 << 63,
        f64::NAN.to_bits(),
        f64::INFINITY.to_bits(),
        (-1.0f64).to_bits(),
        u32::MAX as u64,
    ]
}

fn mutate(seed: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut b = seed.to_vec();
    let token = |c: u8| c.is_ascii_alphanumeric() || b".+-_".contains(&c);
    for e in edits.iter().take(8) {
        if b.is_empty() {
            break;
        }
        let n = b.len();
        let at = |p: u32| p as usize % n;
        match *e {
            Edit::Byte { at: p, value } => b[at(p)] = value,
            Edit::Token { at: p, which } => {
                let i = at(p);
                let (mut s, mut t) = (i, i);
                while s > 0 && token(b[s - 1]) {
                    s -= 1;
                }
                while t < n && token(b[t]) {
                    t += 1;
                }
                let lit = TOKENS[which as usize % TOKENS.len()].as_bytes();
                b.splice(s..t, lit.iter().copied());
            }
            Edit::Word { at: p, which } => {
                let w = words()[which as usize % 8].to_le_bytes();
                let i = at(p).min(n.saturating_sub(8));
                let end = (i + 8).min(n);
                b[i..end].copy_from_slice(&w[..end - i]);
            }
            Edit::Truncate { at: p } => b.truncate(at(p)),
            Edit::Duplicate { from, len, at: p } => {
                let s = at(from);
                let span: Vec<u8> = b[s..(s + len as usize).min(n)].to_vec();
                let i = at(p);
                b.splice(i..i, span);
            }
        }
    }
    b
}

/// Copy the files of `from` into `to`.
fn copy_dir(from: &Path, to: &Path) {
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(&dst).unwrap();
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// Open the scene directory `dir` with `file` replaced by `bytes`; a scene that opens must
/// validate.
fn open_with(dir: &Path, from: &Path, file: &str, bytes: &[u8]) -> Result<(), String> {
    copy_dir(from, dir);
    std::fs::write(dir.join(file), bytes).unwrap();
    let s = Scene::open(dir).map_err(|e| e.to_string())?;
    if let Err(e) = s.validate() {
        panic!("an opened scene fails validation: {e}");
    }
    Ok(())
}

fn read_file(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}

const SCENE_YAML: Target = Target {
    name: "fuzz_scene_yaml",
    seed: |s| read_file(&s.scene.join("scene.yaml")),
    read: |dir, b| open_with(dir, &seeds().scene, "scene.yaml", b),
};

const SCENE_NPY: Target = Target {
    name: "fuzz_scene_npy",
    seed: |s| read_file(&s.scene.join("projections.npy")),
    read: |dir, b| open_with(dir, &seeds().scene, "projections.npy", b),
};

const R2_META: Target = Target {
    name: "fuzz_r2_meta",
    seed: |s| read_file(&s.r2.join("meta_data.json")),
    read: |dir, b| open_with(dir, &seeds().r2, "meta_data.json", b),
};

const R2_NPY: Target = Target {
    name: "fuzz_r2_npy",
    seed: |s| read_file(&s.r2.join("proj_train/proj_train_0000.npy")),
    read: |dir, b| open_with(dir, &seeds().r2, "proj_train/proj_train_0000.npy", b),
};

const METHOD_CONFIG: Target = Target {
    name: "fuzz_method_config",
    seed: |_| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/recon/4dsg.yaml");
        read_file(&root)
    },
    read: |dir, b| {
        let path = dir.join("config.yaml");
        let text = String::from_utf8_lossy(b);
        MethodConfig::from_yaml(&text, &path)
            .map(|_| ())
            .map_err(|e| e.to_string())
    },
};

const SCENE_CONFIG: Target = Target {
    name: "fuzz_scene_config",
    seed: |s| s.scene_config.clone(),
    read: |dir, b| {
        let path = dir.join("scene-config.yaml");
        std::fs::write(&path, b).unwrap();
        let c = SimulateConfig::load(&path).map_err(|e| e.to_string())?;
        // What `prism simulate` does before simulating: sizes and memory.
        c.footprint()
            .map(|_| ())
            .map_err(|e| format!("{}: {e}", path.display()))
    },
};

const MODEL: Target = Target {
    name: "fuzz_model",
    seed: |s| read_file(&s.run.join("gaussians.safetensors")),
    read: |dir, b| {
        let path = dir.join("gaussians.safetensors");
        std::fs::write(&path, b).unwrap();
        prism_recon::gaussians::io::load_model(&path, &cpu_device())
            .map(|_| ())
            .map_err(|e| e.to_string())
    },
};

const GEOMETRY: Target = Target {
    name: "fuzz_geometry_checkpoint",
    seed: |s| read_file(&s.run.join("geometry.safetensors")),
    read: |dir, b| {
        let path = dir.join("geometry.safetensors");
        std::fs::write(&path, b).unwrap();
        let scene = Scene::open(&seeds().scene).unwrap();
        let wanted = checkpoint::fingerprint(&tiny_4dsg(), &scene).unwrap();
        checkpoint::load(&path, &wanted, &scene, &cpu_device())
            .map(|_| ())
            .map_err(|e| e.to_string())
    },
};

const IMPORT_CONFIG: Target = Target {
    name: "fuzz_import_config",
    seed: |s| read_file(&s.import.join("import.yaml")),
    read: |dir, b| {
        copy_dir(&seeds().import, dir);
        let path = dir.join("import.yaml");
        std::fs::write(&path, b).unwrap();
        let text = String::from_utf8_lossy(b);
        let config: prism_domain::import::config::ImportConfig =
            prism_domain::yaml::parse_with(&text, &path, &Default::default())
                .map_err(|e| e.to_string())?;
        // What `prism import` does: the estimate first, then (within a small budget) the import.
        let peak = prism_domain::import::footprint(&config, dir)
            .map_err(|e| e.in_file(&path).to_string())?;
        if peak.total() > 1 << 30 {
            return Err(format!("{}: larger than the fuzz budget", path.display()));
        }
        prism_recon::methods::classic::import::import_scene(&config, dir, &text, None, &Silent)
            .map(|_| ())
            .map_err(|e| e.in_file(&path).to_string())
    },
};

const TIFF: Target = Target {
    name: "fuzz_tiff",
    seed: |s| read_file(&s.import.join("flat.tif")),
    read: |dir, b| {
        std::fs::write(dir.join("images.tif"), b).unwrap();
        let source = prism_domain::import::config::ImageSource {
            path: "images.tif".into(),
            raw: None,
            dataset: None,
            axes: None,
        };
        prism_domain::import::images::read_stack(&source, dir, Some([12, 12]))
            .map(|_| ())
            .map_err(|e| e.to_string())
    },
};

/// Resume a tiny run of `config` from `bytes` as its checkpoint.
fn resume_from(dir: &Path, bytes: &[u8], config: &MethodConfig) -> Result<(), String> {
    let ckpt = dir.join("run.ckpt");
    std::fs::write(&ckpt, bytes).unwrap();
    let scene = Scene::open(&seeds().scene).unwrap();
    resumed_run(config, &scene, &dir.join("run"), &ckpt, true)
}

const RESUME: Target = Target {
    name: "fuzz_resume",
    seed: |s| read_file(&s.resume),
    read: |dir, b| resume_from(dir, b, &tiny_r2gs()),
};

const NAF_RESUME: Target = Target {
    name: "fuzz_naf_resume",
    seed: |s| read_file(&s.naf_resume),
    read: |dir, b| resume_from(dir, b, &tiny_naf()),
};

#[test]
fn fuzz_import_config() {
    IMPORT_CONFIG.fuzz();
}

#[test]
fn fuzz_tiff() {
    TIFF.fuzz();
}

#[test]
fn fuzz_resume() {
    RESUME.fuzz();
}

#[test]
fn fuzz_naf_resume() {
    NAF_RESUME.fuzz();
}

#[test]
fn fuzz_scene_yaml() {
    SCENE_YAML.fuzz();
}

#[test]
fn fuzz_scene_npy() {
    SCENE_NPY.fuzz();
}

#[test]
fn fuzz_r2_meta() {
    R2_META.fuzz();
}

#[test]
fn fuzz_r2_npy() {
    R2_NPY.fuzz();
}

#[test]
fn fuzz_method_config() {
    METHOD_CONFIG.fuzz();
}

#[test]
fn fuzz_scene_config() {
    SCENE_CONFIG.fuzz();
}

#[test]
fn fuzz_model() {
    MODEL.fuzz();
}

#[test]
fn fuzz_geometry_checkpoint() {
    GEOMETRY.fuzz();
}

/// Write the seeds and the hand-made malformed inputs to the corpus directories
/// (`PRISM_FUZZ_WRITE_CORPUS=1 cargo test --test fuzz_readers write_corpus`); without the
/// variable it checks that every target has a committed corpus.
#[test]
fn write_corpus() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/__fuzz__");
    let targets: [(&Target, Vec<(&str, &str)>); 12] = [
        (
            &SCENE_YAML,
            vec![("n: 12", "n: 100000"), ("views: 8", "views: 1000000000000")],
        ),
        (&SCENE_NPY, vec![("'shape': (", "'shape': (2000000000, ")]),
        (&R2_META, vec![("[6,8]", "[4294967296,8]")]),
        (&R2_NPY, vec![("'shape': (", "'shape': (600000000, ")]),
        (
            &METHOD_CONFIG,
            vec![("method: 4dsg", "method: 4dsg\niterations: -1")],
        ),
        (&SCENE_CONFIG, vec![("n: 12", "n: 100000")]),
        (
            &MODEL,
            vec![("\"density_scale\":\"", "\"density_scale\":\"-")],
        ),
        (&GEOMETRY, vec![("\"steps\":\"[", "\"steps\":\"[-")]),
        (
            &IMPORT_CONFIG,
            vec![
                ("count: 6", "count: 1000000000000"),
                ("views: 4", "views: 4, every: 2"),
                ("p.npy}", "p.npy}, views: [1, 1, 2, 3, 4, 5]"),
            ],
        ),
        (&TIFF, vec![("\x0c\0\0\0", "\x00\x7d\0\0")]),
        (
            &RESUME,
            vec![("\\\"iteration\\\":", "\\\"iteration\\\":99")],
        ),
        (
            &NAF_RESUME,
            vec![("\\\"iteration\\\":", "\\\"iteration\\\":99")],
        ),
    ];
    let write = std::env::var_os("PRISM_FUZZ_WRITE_CORPUS").is_some();
    for (target, bad) in targets {
        let name = target.name;
        let dir = root.join(name).join("corpus");
        if !write {
            let n = std::fs::read_dir(&dir).map_or(0, |d| d.count());
            assert!(n > bad.len(), "{}: {n} corpus files", dir.display());
            continue;
        }
        std::fs::create_dir_all(&dir).unwrap();
        let seed = (target.seed)(seeds());
        std::fs::write(dir.join("seed"), &seed).unwrap();
        for (i, (from, to)) in bad.iter().enumerate() {
            let text = String::from_utf8_lossy(&seed);
            let from_at = seed
                .windows(from.len())
                .position(|w| w == from.as_bytes())
                .unwrap_or_else(|| panic!("{name}: `{from}` not in the seed: {text}"));
            let mut b = seed[..from_at].to_vec();
            b.extend_from_slice(to.as_bytes());
            b.extend_from_slice(&seed[from_at + from.len()..]);
            std::fs::write(dir.join(format!("malformed-{i}")), b).unwrap();
        }
    }
}
