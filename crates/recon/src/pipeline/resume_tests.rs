//! Interrupted Gaussian and NAF runs, resumed from their checkpoint, end exactly as
//! uninterrupted ones (`crate::gaussians::train::checkpoints`, `crate::methods::naf::resume`); divergence saves the last
//! good state; mismatched resumes are refused.

use super::gaussian_tests::{losses, three_channel_scene, tiny, tiny_r2gs, tiny_spectral};
use super::run;
use super::tests::scene;
use crate::device::cpu_device;
use crate::methods::fourdsg::FourDsgMethod;
use crate::record::RunDir;
use crate::setup::{Checkpointing, RunOptions};
use crate::{Error, MethodConfig, Result};
use prism_domain::observe::Observer;
use prism_domain::scene::Scene;
use prism_domain::testing::edit_metadata;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

/// Sets its flag (the run's stop request) when phase `phase` reaches step `at`.
struct StopAt<'a> {
    phase: &'a str,
    at: u64,
    current: Mutex<String>,
    flag: &'a AtomicBool,
}

impl Observer for StopAt<'_> {
    fn phase(&self, name: &str, _total: u64) {
        *self.current.lock().unwrap() = name.to_string();
    }
    fn progress(&self, done: u64, _status: &str) {
        if *self.current.lock().unwrap() == self.phase && done == self.at {
            self.flag.store(true, Ordering::Relaxed);
        }
    }
}

/// Run `cfg` into `out`, checkpointing to `ckpt` (resuming from it when `resume`), stopped at
/// step `at` of phase `phase` (none when `phase` is empty).
fn run_stopped<C: Clone + Into<MethodConfig>>(
    cfg: &C,
    scene: &Scene,
    out: &Path,
    ckpt: &Path,
    resume: bool,
    stop: (&str, u64),
) -> Result<()> {
    let config: MethodConfig = cfg.clone().into();
    run_method_stopped(&config, scene, out, ckpt, resume, stop)
}

/// [`run_stopped`] for any method.
fn run_method_stopped(
    config: &MethodConfig,
    scene: &Scene,
    out: &Path,
    ckpt: &Path,
    resume: bool,
    (phase, at): (&str, u64),
) -> Result<()> {
    let flag = AtomicBool::new(false);
    let observer = StopAt {
        phase,
        at,
        current: Mutex::default(),
        flag: &flag,
    };
    let options = RunOptions {
        device: cpu_device(),
        from_geometry: None,
        observer: &observer,
        evaluation: &crate::evaluate::Evaluation::default(),
        checkpoint: Some(Checkpointing {
            path: ckpt.to_path_buf(),
            resume,
            stop: Some(&flag),
        }),
    };
    run(config, scene, RunDir::create(out, true)?, &options).map(|_| ())
}

/// The files of a finished run that must be identical: models, volumes and losses.
fn assert_same_results(a: &Path, b: &Path) {
    assert_eq!(losses(a), losses(b), "losses");
    let mut compared = 0;
    for entry in std::fs::read_dir(a).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".npy") || name.starts_with("gaussians") {
            assert!(
                std::fs::read(a.join(&name)).unwrap() == std::fs::read(b.join(&name)).unwrap(),
                "{name} differs"
            );
            compared += 1;
        }
    }
    assert!(compared >= 3, "{compared} files compared");
    let summary = |d: &Path| -> Vec<serde_json::Value> {
        let t: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join(RunDir::TRAIN)).unwrap()).unwrap();
        t["stages"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| {
                let mut s = s.clone();
                let o = s.as_object_mut().unwrap();
                o.remove("train_s");
                o.remove("timing");
                s
            })
            .collect()
    };
    assert_eq!(summary(a), summary(b), "stage summaries (times aside)");
}

fn interrupted(e: Error, ckpt: &Path, stage: &str, iter: usize) {
    match e {
        Error::Interrupted {
            stage: s,
            iter: i,
            checkpoint,
        } => {
            assert_eq!((s.as_str(), i), (stage, iter));
            assert_eq!(checkpoint, ckpt);
            assert!(ckpt.is_file());
        }
        other => panic!("expected an interruption, got {other}"),
    }
}

/// R²-Gaussian stopped in its second channel while densifying (the first channel finished),
/// resumed: the same models, volumes, log and summaries as the uninterrupted run; the
/// checkpoint is gone once the run is published.
#[test]
fn an_interrupted_r2gs_run_resumes_exactly() {
    let scene = scene();
    let cfg = tiny_r2gs();
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let ckpt = tmp.path().join("b.resume.safetensors");
    run_stopped(&cfg, &scene, &a, &tmp.path().join("a.ckpt"), false, ("", 0)).unwrap();
    assert!(!tmp.path().join("a.ckpt").exists(), "no checkpoint left");

    let phase = format!("r2gs {}", scene.channels[1].label);
    let e = run_stopped(&cfg, &scene, &b, &ckpt, false, (&phase, 15)).unwrap_err();
    interrupted(e, &ckpt, &phase, 15);
    assert!(!b.exists(), "an interrupted run publishes nothing");
    run_stopped(&cfg, &scene, &b, &ckpt, true, ("", 0)).unwrap();
    assert_same_results(&a, &b);
    assert!(
        !ckpt.exists(),
        "the checkpoint is removed with the published run"
    );
}

/// 4D-SG stopped twice, in stage 1 while densifying and in the spectral stage (GSC-Net and its
/// Adam restored from Burn's records), resumed each time: the uninterrupted run's results.
#[test]
fn a_4dsg_run_interrupted_in_both_stages_resumes_exactly() {
    let scene = three_channel_scene();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.geometry.iterations = 30;
    cfg.spectral.stage2.iterations = 12;
    cfg.spectral.stage2.curve_model.width = 8;
    cfg.spectral.stage2.curve_model.depth = 1;
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let ckpt = tmp.path().join("b.ckpt");
    run_stopped(&cfg, &scene, &a, &tmp.path().join("a.ckpt"), false, ("", 0)).unwrap();

    let e = run_stopped(&cfg, &scene, &b, &ckpt, false, ("geometry structural", 17)).unwrap_err();
    interrupted(e, &ckpt, "geometry structural", 17);
    let e = run_stopped(&cfg, &scene, &b, &ckpt, true, ("gscnet all", 5)).unwrap_err();
    interrupted(e, &ckpt, "gscnet all", 5);
    run_stopped(&cfg, &scene, &b, &ckpt, true, ("", 0)).unwrap();
    assert_same_results(&a, &b);
}

/// 4D-SG with channel residuals (`stage2.residual`, density columns beside u⁽ᶜ⁾) stopped in the
/// spectral stage and resumed: the uninterrupted run's results (the residuals and their Adam
/// moments are part of the model's state).
#[test]
fn a_4dsg_run_with_channel_residuals_resumes_exactly() {
    use crate::methods::fourdsg::stage2::config::ResidualConfig;
    let scene = three_channel_scene();
    let mut cfg = tiny_spectral(10, 12);
    cfg.spectral.stage2.residual = Some(ResidualConfig { weight: 0.1 });
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let ckpt = tmp.path().join("b.ckpt");
    run_stopped(&cfg, &scene, &a, &tmp.path().join("a.ckpt"), false, ("", 0)).unwrap();
    let e = run_stopped(&cfg, &scene, &b, &ckpt, false, ("gscnet all", 7)).unwrap_err();
    interrupted(e, &ckpt, "gscnet all", 7);
    run_stopped(&cfg, &scene, &b, &ckpt, true, ("", 0)).unwrap();
    assert_same_results(&a, &b);
}

/// Periodic checkpoints; a resume with other settings, another scene or no file is refused
/// before anything is written, naming what differs.
#[test]
fn checkpoints_are_periodic_and_refused_for_another_run() {
    let scene = scene();
    let mut cfg = tiny_r2gs();
    cfg.geometry.checkpoint_every = 10;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let ckpt = tmp.path().join("run.ckpt");
    let e = run_stopped(&cfg, &scene, &out, &ckpt, false, ("r2gs 40keV", 35));
    // Stopped at 35: the file holds iteration 35 (the stop), written over iteration 30's.
    interrupted(e.unwrap_err(), &ckpt, "r2gs 40keV", 35);

    let mut other = cfg.clone();
    other.geometry.seed = 3;
    let e = run_stopped(&other, &scene, &out, &ckpt, true, ("", 0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("run.ckpt") && e.contains("`seed`"), "{e}");
    // `checkpoint_every` may change between the runs.
    let mut every = cfg.clone();
    every.geometry.checkpoint_every = 0;
    let mut other_scene = scene.clone();
    other_scene.projections[[0, 0, 20, 20]] += 0.01;
    let e = run_stopped(&every, &other_scene, &out, &ckpt, true, ("", 0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("scene"), "{e}");
    assert!(!out.exists());
    let e = run_stopped(&cfg, &scene, &out, &tmp.path().join("none"), true, ("", 0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("none") && e.contains("no checkpoint"), "{e}");
    run_stopped(&every, &scene, &out, &ckpt, true, ("", 0)).unwrap();
    assert!(out.join(RunDir::TRAIN).is_file());
}

/// A stage whose loss overflows saves the state before the failing step and says where.
#[test]
fn a_diverging_run_saves_its_last_good_state() {
    let scene = scene();
    let mut cfg = tiny_r2gs();
    cfg.geometry.densify = None;
    cfg.geometry.lr.density.init = 1e38;
    cfg.geometry.lr.density.end = 1e38;
    let tmp = tempfile::tempdir().unwrap();
    let ckpt = tmp.path().join("run.ckpt");
    let e = run_stopped(&cfg, &scene, &tmp.path().join("run"), &ckpt, false, ("", 0)).unwrap_err();
    let Error::Diverged { iter, detail, .. } = &e else {
        panic!("expected a divergence, got {e}");
    };
    assert!(
        detail.contains(&format!("iteration {}", iter - 1)) && detail.contains("run.ckpt"),
        "{e}"
    );
    assert!(ckpt.is_file());
}

/// NAF stopped in its first channel at a scheduled checkpoint's iteration, then in its second
/// (the first channel's volume saved), resumed each time: the uninterrupted run's volumes and
/// log; a file from other settings is refused.
#[test]
fn an_interrupted_naf_run_resumes_exactly() {
    let scene = scene();
    let yaml = "method: naf\niterations: 30\nrays_per_batch: 64\nsamples_per_ray: 12\n\
                eval_every: 10\ncheckpoint_every: 7\n\
                field: {width: 8, hash_grid: {levels: 3, base_resolution: 4, growth: 2.0, \
                log2_table_size: 8}}\n";
    let config = MethodConfig::from_yaml(yaml, Path::new("naf.yaml")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let ckpt = tmp.path().join("b.ckpt");
    let none = ("", 0);
    run_method_stopped(&config, &scene, &a, &tmp.path().join("a.ckpt"), false, none).unwrap();

    let first = format!("naf {}", scene.channels[0].label);
    let e = run_method_stopped(&config, &scene, &b, &ckpt, false, (&first, 14)).unwrap_err();
    interrupted(e, &ckpt, &first, 14);
    let second = format!("naf {}", scene.channels[1].label);
    let e = run_method_stopped(&config, &scene, &b, &ckpt, true, (&second, 11)).unwrap_err();
    interrupted(e, &ckpt, &second, 11);

    let MethodConfig::Naf(naf) = &config else {
        unreachable!()
    };
    let mut other = naf.as_ref().clone();
    other.samples_per_ray = 13;
    let e = run_method_stopped(
        &MethodConfig::Naf(Box::new(other)),
        &scene,
        &b,
        &ckpt,
        true,
        none,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("b.ckpt") && e.contains("`samples_per_ray`"),
        "{e}"
    );

    run_method_stopped(&config, &scene, &b, &ckpt, true, none).unwrap();
    // The log's records, times aside: iterations, losses, PSNR and SSIM.
    let records = |d: &Path| -> Vec<serde_json::Value> {
        let text = std::fs::read_to_string(d.join(RunDir::LOG)).unwrap();
        text.lines()
            .map(|l| {
                let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
                let o = v.as_object_mut().unwrap();
                o.remove("wall_s");
                o.remove("train_s");
                v
            })
            .collect()
    };
    assert_eq!(records(&a).len(), 6);
    assert_eq!(records(&a), records(&b), "log");
    let mut compared = 0;
    for ch in &scene.channels {
        let name = RunDir::volume_file(&ch.label);
        assert!(
            std::fs::read(a.join(&name)).unwrap() == std::fs::read(b.join(&name)).unwrap(),
            "{name} differs"
        );
        compared += 1;
    }
    assert!(compared >= 2);
    assert!(!ckpt.exists());
}

type Edit = fn(&mut serde_json::Value);

/// Resuming `config` into `out` from each edit of checkpoint `ckpt`'s `current` metadata is
/// refused, naming the edited copy and `metadata.current.<field>`; nothing is published.
fn refused_edits(
    config: &MethodConfig,
    scene: &Scene,
    out: &Path,
    ckpt: &Path,
    cases: &[(&str, Edit)],
) {
    for (field, edit) in cases {
        let bad = ckpt.with_file_name("bad.ckpt");
        edit_metadata(ckpt, &bad, "current", edit);
        let e = run_method_stopped(config, scene, out, &bad, true, ("", 0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad.ckpt") && e.contains(&format!("metadata.current.{field}")),
            "{field}: {e}"
        );
        assert!(!out.exists(), "{field}: nothing published");
    }
}

/// Resume fields out of range are refused, naming the file and the field, before anything is
/// trained or published: an iteration counter beyond the run's end (which used to publish the
/// channel as finished early), a random-stream position beyond the stream, negative or
/// non-finite running sums, a view order that is not one (R²-Gaussian and NAF).
#[test]
fn resume_fields_out_of_range_are_refused() {
    let scene = scene();
    let mut cfg = tiny_r2gs();
    cfg.geometry.checkpoint_every = 10;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let ckpt = tmp.path().join("run.ckpt");
    let e = run_stopped(&cfg, &scene, &out, &ckpt, false, ("r2gs 40keV", 15));
    interrupted(e.unwrap_err(), &ckpt, "r2gs 40keV", 15);
    let cases: [(&str, Edit); 5] = [
        ("progress.iteration", |v| {
            v["progress"]["iteration"] = 1_000_000.into()
        }),
        ("trainer.rng_word_pos", |v| {
            v["trainer"]["rng_word_pos"] = "340282366920938463463374607431768211455".into()
        }),
        ("progress.timing.render", |v| {
            v["progress"]["timing"]["render"] = (-1.0).into()
        }),
        ("progress.window_n", |v| {
            v["progress"]["window_n"] = 99.into()
        }),
        ("progress.last.total", |v| {
            v["progress"]["last"]["total"] = (-0.5).into()
        }),
    ];
    let config: MethodConfig = cfg.clone().into();
    refused_edits(&config, &scene, &out, &ckpt, &cases);

    let yaml = "method: naf\niterations: 30\nrays_per_batch: 64\nsamples_per_ray: 12\n\
                eval_every: 10\ncheckpoint_every: 7\n\
                field: {width: 8, hash_grid: {levels: 3, base_resolution: 4, growth: 2.0, \
                log2_table_size: 8}}\n";
    let config = MethodConfig::from_yaml(yaml, Path::new("naf.yaml")).unwrap();
    let first = format!("naf {}", scene.channels[0].label);
    let naf_ckpt = tmp.path().join("naf.ckpt");
    let e = run_method_stopped(&config, &scene, &out, &naf_ckpt, false, (&first, 9));
    interrupted(e.unwrap_err(), &naf_ckpt, &first, 9);
    let cases: [(&str, Edit); 4] = [
        ("iteration", |v| v["iteration"] = 31.into()),
        ("order", |v| v["order"] = serde_json::json!([0])),
        ("loss_sum", |v| v["loss_sum"] = (-1.0).into()),
        ("rng_word_pos", |v| v["rng_word_pos"] = "x".into()),
    ];
    refused_edits(&config, &scene, &out, &naf_ckpt, &cases);
    run_method_stopped(&config, &scene, &out, &naf_ckpt, true, ("", 0)).unwrap();
}

/// The network and optimiser records of a NAF checkpoint, overwritten 8 bytes at a time with
/// extreme words at every position: restoring them gives the state or an error naming the
/// file, never a panic (`fuzz_naf_resume` found Burn's reader asserting on some malformed
/// optimiser records).
#[test]
fn malformed_network_records_are_refused_without_a_panic() {
    use crate::record::resume::NetState;
    use crate::record::tensors::TensorFile;
    let scene = scene();
    let yaml = "method: naf\niterations: 12\nrays_per_batch: 32\nsamples_per_ray: 8\n\
                eval_every: 100\nfield: {width: 8, hash_grid: {levels: 2, base_resolution: 4, \
                growth: 2.0, log2_table_size: 6}}\n";
    let config = MethodConfig::from_yaml(yaml, Path::new("naf.yaml")).unwrap();
    let MethodConfig::Naf(naf) = &config else {
        unreachable!()
    };
    let tmp = tempfile::tempdir().unwrap();
    let ckpt = tmp.path().join("naf.ckpt");
    let first = format!("naf {}", scene.channels[0].label);
    let e = run_method_stopped(
        &config,
        &scene,
        &tmp.path().join("run"),
        &ckpt,
        false,
        (&first, 3),
    );
    interrupted(e.unwrap_err(), &ckpt, &first, 3);
    let f = TensorFile::open(&ckpt, "prism-naf-resume/1").unwrap();
    let saved = NetState::read(&f, "current.").unwrap();
    let device = cpu_device().autodiff();
    let (mut panics, mut refused) = (Vec::new(), 0);
    for (which, record) in [("net", &saved.net), ("optim", &saved.optim)] {
        for at in 0..record.len().saturating_sub(8) {
            for word in [u64::MAX, 0] {
                let mut m = record.clone();
                m[at..at + 8].copy_from_slice(&word.to_le_bytes());
                let state = if which == "net" {
                    NetState {
                        net: m,
                        optim: saved.optim.clone(),
                    }
                } else {
                    NetState {
                        net: saved.net.clone(),
                        optim: m,
                    }
                };
                let mut field = naf.field.init(0, &device).unwrap();
                let mut optim = burn::optim::AdamConfig::new().init();
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    state.restore(&mut field, &mut optim, &ckpt, "current.")
                }));
                match r {
                    Err(_) => panics.push(format!("{which} byte {at} = {word:#x}")),
                    Ok(Err(e)) => {
                        let e = e.to_string();
                        assert!(e.contains("naf.ckpt") && e.contains(which), "{e}");
                        refused += 1;
                    }
                    Ok(Ok(())) => {}
                }
            }
        }
    }
    assert!(
        panics.is_empty(),
        "{} panics: {:?}",
        panics.len(),
        &panics[..panics.len().min(5)]
    );
    assert!(refused > 0, "no edit was refused");
}
