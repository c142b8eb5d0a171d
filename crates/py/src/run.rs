//! `reconstruct`: any method of `prism recon` on projections held in NumPy arrays, through the same
//! pipeline (`prism_recon::pipeline::run`) into a run directory, which the Python layer reads
//! back (`prism.load_run`).
//!
//! Progress goes to an optional Python callable, `callback(kind, name_or_done, total_or_status)`
//! (`("phase", name, total)`, `("progress", done, status)`, `("note", level, text)`), called with
//! the GIL taken back for the call. Ctrl-C: the run works on its own thread while the calling
//! (main) thread checks Python's signals every 50 ms; a pending `KeyboardInterrupt` stops a
//! training method at its next step (its state is saved, as the CLI's SIGINT does), and the call
//! then raises `KeyboardInterrupt`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use ndarray::{Array2, ArrayView2, ArrayView4};
use numpy::{PyReadonlyArray2, PyReadonlyArray4, PyUntypedArrayMethods};
use prism_domain::observe::{Level, Observer};
use prism_domain::scene::{Channel, Provenance, Scene, SpectralCoordinate, Split, normalise_tau};
use prism_recon::evaluate::Evaluation;
use prism_recon::pipeline;
use prism_recon::record::RunDir;
use prism_recon::setup::{Checkpointing, RunOptions};
use prism_recon::{Error, MethodConfig};
use pyo3::exceptions::PyKeyboardInterrupt;
use pyo3::prelude::*;

use crate::{geometry, value_error};

/// How often the calling thread looks for a pending Ctrl-C while a run works.
const WATCH: Duration = Duration::from_millis(50);

/// Reports to a Python callable; its stop flag is the run's (set by Ctrl-C, see [`reconstruct`]).
struct PyObserver {
    callback: Option<Py<PyAny>>,
    stop: AtomicBool,
}

impl PyObserver {
    fn report<A, B>(&self, kind: &str, a: A, b: B)
    where
        A: for<'py> IntoPyObject<'py>,
        B: for<'py> IntoPyObject<'py>,
    {
        if self.callback.is_none() {
            return;
        }
        Python::attach(|py| {
            if let Some(f) = &self.callback
                && let Err(e) = f.call1(py, (kind, a, b))
            {
                // A failing callback stops the run as Ctrl-C does; its error is shown.
                e.print(py);
                self.stop.store(true, Ordering::Relaxed);
            }
        });
    }
}

impl Observer for PyObserver {
    fn phase(&self, name: &str, total: u64) {
        self.report("phase", name, total);
    }

    fn progress(&self, done: u64, status: &str) {
        self.report("progress", done, status);
    }

    fn note(&self, level: Level, text: &str) {
        let level = match level {
            Level::Info => "info",
            Level::Warning => "warning",
        };
        self.report("note", level, text);
    }
}

/// A channel as the caller names it (a `scene.yaml` channel without its derived `tau`).
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ChannelSpec {
    label: String,
    coordinate: SpectralCoordinate,
}

fn view4<'a>(name: &str, a: &'a PyReadonlyArray4<'_, f32>) -> PyResult<ArrayView4<'a, f32>> {
    let s = a.shape();
    let values = a
        .as_slice()
        .map_err(|_| value_error(format!("{name}: must be C-contiguous")))?;
    ArrayView4::from_shape([s[0], s[1], s[2], s[3]], values).map_err(value_error)
}

/// Reconstruct `projections` `[channel][view][row][col]` with the method `config_yaml` describes
/// (a `configs/recon/*.yaml`'s text) into the run directory `out`. `channels_json` lists the
/// channels (`[{label, coordinate: {kind, …}}]`, the `channels:` of a `scene.yaml`);
/// `availability` `[view][channel]` marks which channel was measured at which view (all when
/// `None`); `references` `[channel][z][y][x]` scores the run; `allow_memory` runs even when the
/// estimated peak exceeds the memory available. Returns the published directory.
#[pyfunction]
#[pyo3(signature = (projections, geometry_json, config_yaml, channels_json, out, availability=None, references=None, force=false, callback=None, allow_memory=false))]
#[allow(clippy::too_many_arguments)]
pub fn reconstruct(
    py: Python<'_>,
    projections: PyReadonlyArray4<'_, f32>,
    geometry_json: &str,
    config_yaml: &str,
    channels_json: &str,
    out: PathBuf,
    availability: Option<PyReadonlyArray2<'_, bool>>,
    references: Option<PyReadonlyArray4<'_, f32>>,
    force: bool,
    callback: Option<Py<PyAny>>,
    allow_memory: bool,
) -> PyResult<String> {
    let geometry = geometry(geometry_json)?;
    let config = MethodConfig::from_yaml(config_yaml, std::path::Path::new("config"))
        .map_err(value_error)?;
    let specs: Vec<ChannelSpec> =
        serde_json::from_str(channels_json).map_err(|e| value_error(format!("channels: {e}")))?;
    let mut channels: Vec<Channel> = specs
        .into_iter()
        .map(|c| Channel::new(c.label, c.coordinate))
        .collect();
    normalise_tau(&mut channels).map_err(value_error)?;
    let views = geometry.views();
    let availability = match &availability {
        Some(a) => {
            let s = a.shape();
            let values = a
                .as_slice()
                .map_err(|_| value_error("availability: must be C-contiguous"))?;
            ArrayView2::from_shape([s[0], s[1]], values)
                .map_err(value_error)?
                .to_owned()
        }
        None => Array2::from_elem((views, channels.len()), true),
    };
    let scene = Scene {
        name: out
            .file_name()
            .map_or("python".into(), |n| n.to_string_lossy().into_owned()),
        geometry,
        channels,
        projections: view4("projections", &projections)?.to_owned(),
        availability,
        references: references
            .as_ref()
            .map(|r| view4("references", r).map(|v| v.to_owned()))
            .transpose()?,
        split: Split::all_train(views),
        provenance: Provenance {
            generator: "prism (Python)".into(),
            ..Provenance::default()
        },
        structural: None,
        materials: None,
    };
    scene.validate().map_err(value_error)?;
    let evaluation = Evaluation::default();
    // The run's estimated peak against the memory available, as `prism recon` checks it: a
    // clear error instead of the out-of-memory killer ending the interpreter.
    let what = format!("{} on {views} views", config.method().name());
    pipeline::run_footprint(&config, &scene, &evaluation)
        .check(&what, allow_memory)
        .map_err(value_error)?;
    let observer = PyObserver {
        callback,
        stop: AtomicBool::new(false),
    };
    let checkpoint = if config.method().trains() {
        Some(Checkpointing::default_path(&out).map_err(value_error)?)
    } else {
        None
    };
    let dir = RunDir::create(&out, force).map_err(value_error)?;
    let device = config.device().device().map_err(value_error)?;
    // The run works on a thread of its own while the calling (main) thread watches for Ctrl-C:
    // Python runs signal handlers only on the main thread, and the run's own threads may not
    // report from it for a long time.
    let result = py.detach(|| {
        std::thread::scope(|s| {
            let work = s.spawn(|| {
                let options = RunOptions {
                    device,
                    from_geometry: None,
                    observer: &observer,
                    evaluation: &evaluation,
                    checkpoint: checkpoint.map(|path| Checkpointing {
                        path,
                        resume: false,
                        stop: Some(&observer.stop),
                    }),
                };
                prism_recon::device::on_cpu_workers(|| {
                    pipeline::run(&config, &scene, dir, &options)
                })
            });
            while !work.is_finished() {
                if Python::attach(|py| py.check_signals().is_err()) {
                    observer.stop.store(true, Ordering::Relaxed);
                }
                std::thread::sleep(WATCH);
            }
            work.join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        })
    });
    match result {
        Ok(outcome) => Ok(outcome.dir.to_string_lossy().into_owned()),
        Err(e @ Error::Interrupted { .. }) => Err(PyKeyboardInterrupt::new_err(e.to_string())),
        Err(e) => Err(value_error(e)),
    }
}
