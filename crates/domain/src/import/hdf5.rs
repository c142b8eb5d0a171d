//! HDF5 inputs (`.h5`, `.hdf5`, `.nxs`, MATLAB v7.3 `.mat`): one numeric dataset read as an
//! image stack or a vector, with the `hdf5-reader` crate (pure Rust, read-only, bounded reads).
//!
//! Stored axis orders differ between writers: Data Exchange files say theirs in an `axes`
//! attribute (`theta:y:x`), and MATLAB writes its arrays column-major, so a MATLAB
//! `views × cols` sinogram reads as `cols × views` (`x:theta`). The config names the order when
//! the file does not (`axes`); the stack comes out `[theta][y][x]` = `[views][rows][cols]`, a
//! missing `theta` or `y` axis of length 1.

use crate::{Error, Result};
use hdf5_reader::{Dataset, Datatype, Hdf5File, OpenOptions};
use ndarray::{ArrayD, IxDyn};
use std::path::Path;

/// Whether `path` names an HDF5 container by its extension.
pub fn is_hdf5(path: &Path) -> bool {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .is_some_and(|e| matches!(e.as_str(), "h5" | "hdf5" | "hdf" | "nxs" | "mat"))
}

/// Dataset `name` of the HDF5 file `path` as a stack `[theta][y][x]`. `axes` names the stored
/// axes in order (`x:theta`, `theta:y:x`), else the dataset's own `axes` attribute, else
/// `theta:y:x` (three axes) or `y:x` (two).
pub fn read_stack(path: &Path, name: &str, axes: Option<&str>) -> Result<ArrayD<f32>> {
    let file = open(path)?;
    let ds = dataset(&file, path, name)?;
    let stored = match axes {
        Some(a) => a.to_string(),
        None => match ds.attribute("axes").and_then(|a| a.read_string()) {
            Ok(a) => a,
            Err(_) if ds.ndim() == 3 => "theta:y:x".into(),
            Err(_) => "y:x".into(),
        },
    };
    let order = parse_axes(&stored, ds.ndim()).map_err(|m| Error::field(path, "axes", m))?;
    let a = read_f32(&ds, path, name)?;
    // `order[k]` is the stored axis holding output axis k (theta, y, x), if stored.
    let shape: Vec<usize> = order
        .iter()
        .map(|o| o.map_or(1, |k| a.shape()[k]))
        .collect();
    let perm: Vec<usize> = order.iter().flatten().copied().collect();
    let standard = a
        .permuted_axes(IxDyn(&perm))
        .as_standard_layout()
        .into_owned();
    standard
        .into_shape_with_order(IxDyn(&shape))
        .map_err(|e| Error::field(path, name, e.to_string()))
}

/// Dataset `name` of the HDF5 file `path` as a flat vector (angles: any shape, C order).
pub fn read_vector(path: &Path, name: &str) -> Result<Vec<f64>> {
    let file = open(path)?;
    let ds = dataset(&file, path, name)?;
    read_f32_or_f64(&ds, path, name)
}

/// Dataset `name` of the HDF5 file `path` as rows of `width` numbers, one per view (f64; per-view
/// geometry vectors). A 2-D dataset stored views first (`axes` `theta:x`, the default) or numbers
/// first (`x:theta`: how MATLAB -v7.3 stores a views × width matrix, column-major).
pub fn read_rows(
    path: &Path,
    name: &str,
    axes: Option<&str>,
    width: usize,
) -> Result<Vec<Vec<f64>>> {
    let file = open(path)?;
    let ds = dataset(&file, path, name)?;
    let shape: Vec<usize> = ds.shape().iter().map(|&n| n as usize).collect();
    if shape.len() != 2 {
        return Err(Error::field(
            path,
            name,
            format!("has shape {shape:?}; per-view vectors are a 2-D [views, {width}] dataset"),
        ));
    }
    // The stack's axis names: `theta` the views, `x` the numbers of a row.
    let stored = axes.unwrap_or("theta:x");
    let views_first = match parse_axes(stored, 2).map_err(|m| Error::field(path, "axes", m))? {
        [Some(t), None, Some(_)] => t == 0,
        _ => {
            return Err(Error::field(
                path,
                "axes",
                format!(
                    "`{stored}`: vectors are stored `theta:x` (views first) or `x:theta` (MATLAB)"
                ),
            ));
        }
    };
    let (views, numbers) = if views_first {
        (shape[0], shape[1])
    } else {
        (shape[1], shape[0])
    };
    if numbers != width {
        let hint = if views == width {
            "; the other axis has that length: set `axes` (theta:x or x:theta)"
        } else {
            ""
        };
        return Err(Error::field(
            path,
            name,
            format!("has shape {shape:?}: {numbers} numbers per view, not {width}{hint}"),
        ));
    }
    let values = read_f32_or_f64(&ds, path, name)?;
    Ok((0..views)
        .map(|v| {
            (0..width)
                .map(|j| {
                    if views_first {
                        values[v * width + j]
                    } else {
                        values[j * views + v]
                    }
                })
                .collect()
        })
        .collect())
}

/// Where each output axis (theta, y, x) is stored, from a `:`-separated list of stored axis
/// names. Every stored axis must be named once; `theta` and `y` may be absent (length 1).
fn parse_axes(text: &str, ndim: usize) -> std::result::Result<[Option<usize>; 3], String> {
    let names: Vec<&str> = text.split(':').map(str::trim).collect();
    if names.len() != ndim {
        return Err(format!(
            "`{text}` names {} axes; the dataset has {ndim}",
            names.len()
        ));
    }
    let mut order = [None; 3];
    for (k, n) in names.iter().enumerate() {
        let slot = match *n {
            // Data Exchange names the frame axis of flats and darks `theta_white`, `theta_dark`.
            "theta" | "theta_white" | "theta_dark" => 0,
            "y" => 1,
            "x" => 2,
            other => {
                return Err(format!(
                    "unknown axis `{other}` in `{text}` (theta, theta_white or theta_dark: views or frames, y: detector rows, x: columns)"
                ));
            }
        };
        if order[slot].replace(k).is_some() {
            return Err(format!("axis `{n}` named twice in `{text}`"));
        }
    }
    if order[2].is_none() {
        return Err(format!("`{text}` has no `x` (detector columns) axis"));
    }
    Ok(order)
}

fn open(path: &Path) -> Result<Hdf5File> {
    if !path.exists() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    // Bound every read by the memory this machine has, before any allocation.
    let budget = crate::memory::available().map_or(usize::MAX, |b| b as usize);
    let options = OpenOptions::default().with_max_read_bytes(budget);
    Hdf5File::open_with_options(path, options).map_err(|e| {
        let hint = if path.extension().is_some_and(|e| e == "mat") {
            " (MATLAB files before v7.3 are not HDF5: save with `-v7.3`)"
        } else {
            ""
        };
        Error::field(path, "file", format!("not a readable HDF5 file: {e}{hint}"))
    })
}

fn dataset(file: &Hdf5File, path: &Path, name: &str) -> Result<Dataset> {
    file.dataset(name).map_err(|e| {
        let mut found = Vec::new();
        if let Ok(root) = file.root_group() {
            list_datasets(&root, "", &mut found);
        }
        Error::field(
            path,
            "dataset",
            format!(
                "`{name}`: {e}; numeric datasets in the file: {}",
                if found.is_empty() {
                    "none".into()
                } else {
                    found.join(", ")
                }
            ),
        )
    })
}

/// Paths of the numeric datasets under `group`, at most 40.
fn list_datasets(group: &hdf5_reader::group::Group, prefix: &str, out: &mut Vec<String>) {
    let Ok((groups, datasets)) = group.members() else {
        return;
    };
    for d in datasets {
        let numeric = matches!(
            d.dtype(),
            Datatype::FloatingPoint { .. } | Datatype::FixedPoint { .. }
        );
        if out.len() < 40 && numeric {
            out.push(format!("{prefix}/{} {:?}", d.name(), d.shape()));
        }
    }
    for g in groups {
        list_datasets(&g, &format!("{prefix}/{}", g.name()), out);
    }
}

/// The dataset's values as f32, from any integer or floating type.
fn read_f32(ds: &Dataset, path: &Path, name: &str) -> Result<ArrayD<f32>> {
    let bad = |e: hdf5_reader::error::Error| Error::field(path, name, e.to_string());
    macro_rules! cast {
        ($t:ty) => {
            ds.read_array::<$t>().map_err(bad)?.mapv(|v| v as f32)
        };
    }
    Ok(match ds.dtype() {
        Datatype::FloatingPoint { size: 4, .. } => ds.read_array::<f32>().map_err(bad)?,
        Datatype::FloatingPoint { size: 8, .. } => cast!(f64),
        Datatype::FixedPoint { size, signed, .. } => match (size, signed) {
            (1, false) => cast!(u8),
            (1, true) => cast!(i8),
            (2, false) => cast!(u16),
            (2, true) => cast!(i16),
            (4, false) => cast!(u32),
            (4, true) => cast!(i32),
            (8, false) => cast!(u64),
            (8, true) => cast!(i64),
            _ => return Err(unsupported(ds, path, name)),
        },
        _ => return Err(unsupported(ds, path, name)),
    })
}

fn read_f32_or_f64(ds: &Dataset, path: &Path, name: &str) -> Result<Vec<f64>> {
    if let Datatype::FloatingPoint { size: 8, .. } = ds.dtype() {
        let a = ds
            .read_array::<f64>()
            .map_err(|e| Error::field(path, name, e.to_string()))?;
        return Ok(a.iter().copied().collect());
    }
    Ok(read_f32(ds, path, name)?
        .iter()
        .map(|&v| v as f64)
        .collect())
}

fn unsupported(ds: &Dataset, path: &Path, name: &str) -> Error {
    Error::field(
        path,
        name,
        format!(
            "holds {:?}; images and angles must be integers or floats",
            ds.dtype()
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::parse_axes;

    #[test]
    fn axis_names_map_stored_axes_to_views_rows_columns() {
        assert_eq!(parse_axes("theta:y:x", 3), Ok([Some(0), Some(1), Some(2)]));
        // A MATLAB views × cols sinogram, read column-major.
        assert_eq!(parse_axes("x:theta", 2), Ok([Some(1), None, Some(0)]));
        assert_eq!(parse_axes("y:x", 2), Ok([None, Some(0), Some(1)]));
        // Data Exchange flats and darks.
        assert_eq!(
            parse_axes("theta_white:y:x", 3),
            Ok([Some(0), Some(1), Some(2)])
        );
        assert_eq!(
            parse_axes("theta_dark:y:x", 3),
            Ok([Some(0), Some(1), Some(2)])
        );
        assert!(parse_axes("theta:x", 3).unwrap_err().contains("has 3"));
        assert!(parse_axes("x:x", 2).unwrap_err().contains("twice"));
        assert!(parse_axes("theta:y", 2).unwrap_err().contains("no `x`"));
        assert!(
            parse_axes("u:x", 2)
                .unwrap_err()
                .contains("unknown axis `u`")
        );
    }
}
