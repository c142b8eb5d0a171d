//! `query`: a trained spectral run (`4dsg`, `4dsg-stage1`) at any point of its spectral axis, as
//! `prism query` answers it (`prism_recon::methods::fourdsg::query::SpectralModel`).

use std::path::PathBuf;

use numpy::PyArray3;
use prism_recon::device::cpu_device;
use prism_recon::methods::fourdsg::query::{Ask, SpectralModel};
use prism_recon::record::RunDir;
use pyo3::prelude::*;

use crate::{to_numpy, value_error};

/// The volume `[z][y][x]` (or, with `projections`, the line integrals at every view of the run's
/// geometry) at exactly one of `coordinate`, `tau` or `kev`; with the answer's warning (an
/// extrapolated energy) and its one-line summary.
#[pyfunction]
#[pyo3(signature = (run_dir, coordinate=None, tau=None, kev=None, projections=false, extrapolate=false))]
#[allow(clippy::type_complexity)]
pub fn query(
    py: Python<'_>,
    run_dir: PathBuf,
    coordinate: Option<f64>,
    tau: Option<f64>,
    kev: Option<f64>,
    projections: bool,
    extrapolate: bool,
) -> PyResult<(Bound<'_, PyArray3<f32>>, Option<String>, String)> {
    let ask = match (coordinate, tau, kev) {
        (Some(c), None, None) => Ask::Coordinate(c),
        (None, Some(t), None) => Ask::Tau(t),
        (None, None, Some(e)) => Ask::Kev(e),
        _ => {
            return Err(value_error(
                "query: give exactly one of coordinate, tau or kev",
            ));
        }
    };
    let answer = py
        .detach(|| {
            let path = RunDir::spectral_model(&run_dir)?;
            SpectralModel::open(&path, ask, &cpu_device())?.answer(ask, projections, extrapolate)
        })
        .map_err(value_error)?;
    Ok((to_numpy(py, answer.data)?, answer.warning, answer.summary))
}
