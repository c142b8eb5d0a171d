//! `prism._prism`: the native half of the `prism` Python package (`python/prism`).
//!
//! Arrays cross as NumPy `float32`, C order, in the project's axis orders (`docs/geometry.md`):
//! volumes `[z][y][x]` of μ in mm⁻¹, projections `[view][row][col]` of line integrals. The
//! Python layer checks dtype, order and shape first and names the argument; this module reads a
//! checked array in place (no copy) and hands results back without a copy (`PyArray::from_vec`).
//! A geometry crosses as the JSON of Prism's `Geometry` (the `geometry:` block of a `scene.yaml`),
//! so its errors name the same fields as the CLI's. Compute runs with the GIL released.
//!
//! Here: the classic operators (`project`, `backproject`, `fdk`, `sart`, `cgls`) and the geometry
//! checks; [`run`]: any method through the run pipeline (`reconstruct`); [`query`]: a trained
//! spectral run at any point of its axis.

mod query;
mod run;

use ndarray::{Array3, ArrayView3};
use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use prism_domain::geometry::{Geometry, TigreGeometry};
use prism_domain::import::config::{FanGeometry, VectorGeometry};
use prism_domain::projector::Joseph;
use prism_recon::algorithms::{self, Order, SartOptions, Window};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

/// A Prism error as the Python exception the package raises: bad input is a `ValueError` with
/// the CLI's message.
pub(crate) fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The geometry in `json` (Prism's `Geometry` fields), validated.
pub(crate) fn geometry(json: &str) -> PyResult<Geometry> {
    let g: Geometry =
        serde_json::from_str(json).map_err(|e| value_error(format!("geometry: {e}")))?;
    g.validate().map_err(value_error)?;
    Ok(g)
}

/// A checked C-order float32 array as an `ndarray` view of its buffer.
fn view<'a>(name: &str, a: &'a PyReadonlyArray3<'_, f32>) -> PyResult<ArrayView3<'a, f32>> {
    let shape = a.shape();
    let shape = [shape[0], shape[1], shape[2]];
    let values = a.as_slice().map_err(|_| {
        value_error(format!(
            "{name}: must be C-contiguous (numpy.ascontiguousarray)"
        ))
    })?;
    ArrayView3::from_shape(shape, values).map_err(value_error)
}

/// `values` as a new NumPy array, without a copy (a strided array is made contiguous first).
pub(crate) fn to_numpy(py: Python<'_>, values: Array3<f32>) -> PyResult<Bound<'_, PyArray3<f32>>> {
    let values = if values.is_standard_layout() {
        values
    } else {
        values.as_standard_layout().into_owned()
    };
    let shape = values.dim();
    let (flat, offset) = values.into_raw_vec_and_offset();
    debug_assert!(offset.unwrap_or(0) == 0);
    PyArray1::from_vec(py, flat).reshape([shape.0, shape.1, shape.2])
}

/// The path every operator takes: the geometry read and checked, the array `name` viewed in
/// place, `op` run with the GIL released, its result handed back without a copy.
fn apply<'py, E: std::fmt::Display + Send>(
    py: Python<'py>,
    geometry_json: &str,
    name: &str,
    array: &PyReadonlyArray3<'py, f32>,
    op: impl FnOnce(&Geometry, ArrayView3<f32>) -> Result<Array3<f32>, E> + Send,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let g = geometry(geometry_json)?;
    let a = view(name, array)?;
    let out = py.detach(|| op(&g, a)).map_err(value_error)?;
    to_numpy(py, out)
}

/// Forward projection (Joseph) of `volume` through `geometry_json`.
#[pyfunction]
fn project<'py>(
    py: Python<'py>,
    volume: PyReadonlyArray3<'py, f32>,
    geometry_json: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    apply(py, geometry_json, "volume", &volume, |g, v| {
        Joseph::new(g)?.forward(v)
    })
}

/// The exact adjoint of [`project`] (Joseph's transpose).
#[pyfunction]
fn backproject<'py>(
    py: Python<'py>,
    projections: PyReadonlyArray3<'py, f32>,
    geometry_json: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    apply(py, geometry_json, "projections", &projections, |g, p| {
        Joseph::new(g)?.adjoint(p)
    })
}

/// FDK (cone) or FBP (parallel) with the ramp `window`.
#[pyfunction]
fn fdk<'py>(
    py: Python<'py>,
    projections: PyReadonlyArray3<'py, f32>,
    geometry_json: &str,
    window: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let window: Window = window
        .parse()
        .map_err(|e| value_error(format!("window: {e}")))?;
    apply(py, geometry_json, "projections", &projections, |g, p| {
        algorithms::fdk(g, p, window)
    })
}

/// SART / OS-SART / SIRT (`block_size` views per update).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn sart<'py>(
    py: Python<'py>,
    projections: PyReadonlyArray3<'py, f32>,
    geometry_json: &str,
    iterations: usize,
    block_size: usize,
    relaxation: f64,
    relaxation_decay: f64,
    nonneg: bool,
    order: &str,
    seed: u64,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let order: Order = serde_json::from_value(serde_json::Value::String(order.into()))
        .map_err(|e| value_error(format!("order: {e}")))?;
    let opts = SartOptions {
        iterations,
        block_size,
        lambda: relaxation,
        lambda_decay: relaxation_decay,
        nonneg,
        order,
        seed,
    };
    apply(py, geometry_json, "projections", &projections, |g, p| {
        algorithms::sart(&Joseph::new(g)?, p, None, &opts, &mut |_| {})
    })
}

/// CGLS for `iterations` steps from zero.
#[pyfunction]
fn cgls<'py>(
    py: Python<'py>,
    projections: PyReadonlyArray3<'py, f32>,
    geometry_json: &str,
    iterations: usize,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    apply(py, geometry_json, "projections", &projections, |g, p| {
        algorithms::cgls(&Joseph::new(g)?, p, None, iterations, &mut |_| {})
    })
}

/// The geometry JSON validated and written back in full (defaults filled in).
#[pyfunction]
fn check_geometry(geometry_json: &str) -> PyResult<String> {
    let g = geometry(geometry_json)?;
    serde_json::to_string(&g).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// Prism's geometry JSON for TIGRE's fields (`tigre_json`: `mode`, `DSD`, `DSO`, `nDetector`,
/// `dDetector`, `offDetector`, `nVoxel`, `dVoxel`, `offOrigin`, TIGRE's orders) and angles.
#[pyfunction]
fn geometry_from_tigre(tigre_json: &str, angles_rad: Vec<f64>) -> PyResult<String> {
    let t: TigreGeometry = serde_json::from_str(tigre_json)
        .map_err(|e| value_error(format!("TIGRE geometry: {e}")))?;
    let g = t.to_geometry(angles_rad).map_err(value_error)?;
    serde_json::to_string(&g).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// Prism's geometry JSON for the `fan:` fields of an import config (`dso`, `dsd`, `cols`, `pitch`,
/// `offset_u`, `nx`, `ny`, `dx`, `dy`, `offset`; docs/import.md) and angles: a one-row cone beam
/// over a one-voxel-thick slice.
#[pyfunction]
fn geometry_from_fan(fan_json: &str, angles_rad: Vec<f64>) -> PyResult<String> {
    let f: FanGeometry =
        serde_json::from_str(fan_json).map_err(|e| value_error(format!("fan geometry: {e}")))?;
    let g = f.to_geometry(angles_rad).map_err(value_error)?;
    serde_json::to_string(&g).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// Prism's geometry JSON for per-view vectors (ASTRA's rows, docs/geometry.md): `spec_json` holds
/// an import config's `vectors:` fields but the file (`beam`, `rows`, `cols`, `volume`),
/// `view_rows` the 12 (cone, parallel) or 6 (fan) numbers of each view; angles are derived when
/// not given.
#[pyfunction]
#[pyo3(signature = (spec_json, view_rows, angles_rad=None))]
fn geometry_from_vectors(
    spec_json: &str,
    view_rows: Vec<Vec<f64>>,
    angles_rad: Option<Vec<f64>>,
) -> PyResult<String> {
    let mut spec: serde_json::Value =
        serde_json::from_str(spec_json).map_err(|e| value_error(format!("vectors: {e}")))?;
    // The rows come from the caller's array, not from a file.
    spec["file"] = serde_json::Value::String("(array)".into());
    let v: VectorGeometry =
        serde_json::from_value(spec).map_err(|e| value_error(format!("vectors: {e}")))?;
    let g = v.to_geometry(&view_rows, angles_rad).map_err(value_error)?;
    serde_json::to_string(&g).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

#[pymodule]
fn _prism(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(project, m)?)?;
    m.add_function(wrap_pyfunction!(backproject, m)?)?;
    m.add_function(wrap_pyfunction!(fdk, m)?)?;
    m.add_function(wrap_pyfunction!(sart, m)?)?;
    m.add_function(wrap_pyfunction!(cgls, m)?)?;
    m.add_function(wrap_pyfunction!(run::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(query::query, m)?)?;
    m.add_function(wrap_pyfunction!(check_geometry, m)?)?;
    m.add_function(wrap_pyfunction!(geometry_from_tigre, m)?)?;
    m.add_function(wrap_pyfunction!(geometry_from_fan, m)?)?;
    m.add_function(wrap_pyfunction!(geometry_from_vectors, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
