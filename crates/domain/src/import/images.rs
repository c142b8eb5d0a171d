//! Measured images as `f32` stacks `[n][rows][cols]`: `.npy` (any integer or float type),
//! TIFF (one grayscale page per image; 8/16/32-bit integers or 32/64-bit floats), HDF5 and MATLAB
//! v7.3 datasets ([`super::hdf5`]), headerless raw files, and directories of one image per file.
//! Errors name the file.

use super::config::{ImageSource, RawLayout, RawType};
use crate::{Error, Result};
use ndarray::{Array3, ArrayD, Axis, IxDyn};
use std::io::BufReader;
use std::path::{Path, PathBuf};
use tiff::decoder::{Decoder, DecodingResult};

/// Read `source` (paths relative to `base`) as a stack `[n][rows][cols]`; a single image is a
/// stack of one. With `image` (the detector's `[rows, cols]`), a TIFF page of another size is
/// refused as its header is read, before it is decoded.
pub fn read_stack(
    source: &ImageSource,
    base: &Path,
    image: Option<[usize; 2]>,
) -> Result<Array3<f32>> {
    let path = base.join(&source.path);
    if path.is_dir() {
        if source.raw.is_some() {
            return Err(Error::field(
                &path,
                "raw",
                "a directory of images cannot be read as one raw file",
            ));
        }
        return read_dir(&path, image);
    }
    if source.dataset.is_some() || super::hdf5::is_hdf5(&path) {
        if source.raw.is_some() {
            return Err(Error::field(
                &path,
                "raw",
                "an HDF5 file has its own layout",
            ));
        }
        let Some(name) = &source.dataset else {
            return Err(Error::field(
                &path,
                "dataset",
                "an HDF5 file needs the dataset's path (`dataset: /exchange/data`)",
            ));
        };
        let a = super::hdf5::read_stack(&path, name, source.axes.as_deref())?;
        return as_stack(a, &path);
    }
    if source.axes.is_some() {
        return Err(Error::field(
            &path,
            "axes",
            "only HDF5 datasets take `axes`",
        ));
    }
    read_file(&path, source.raw.as_ref(), image)
}

/// One file: a stack, or a single image as a stack of one.
fn read_file(
    path: &Path,
    raw: Option<&RawLayout>,
    image: Option<[usize; 2]>,
) -> Result<Array3<f32>> {
    let a = match raw {
        Some(layout) => read_raw(path, layout)?,
        None => match extension(path).as_str() {
            "npy" => crate::scene::npy::read_npy_any(path, "images")?,
            "tif" | "tiff" => read_tiff(path, image)?.into_dyn(),
            other => {
                return Err(Error::field(
                    path,
                    "path",
                    format!(
                        "unknown image format `.{other}` (.npy, .tif, .tiff, or give `raw:` with dtype and shape)"
                    ),
                ));
            }
        },
    };
    as_stack(a, path)
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

fn as_stack(a: ArrayD<f32>, path: &Path) -> Result<Array3<f32>> {
    let a = match a.ndim() {
        2 => a.insert_axis(Axis(0)),
        3 => a,
        n => {
            return Err(Error::field(
                path,
                "shape",
                format!("expected images [rows, cols] or a stack [n, rows, cols], found {n} axes"),
            ));
        }
    };
    let a: Array3<f32> = a
        .into_dimensionality()
        .map_err(|e| Error::field(path, "shape", e.to_string()))?;
    if let Some((i, _)) = a.indexed_iter().find(|(_, v)| !v.is_finite()) {
        return Err(Error::field(
            path,
            format!("[{}][{}][{}]", i.0, i.1, i.2),
            "is not finite",
        ));
    }
    Ok(a)
}

/// Every `.npy` / `.tif` / `.tiff` file of `dir`, in file-name order, one image (or stack) each.
fn read_dir(dir: &Path, image: Option<[usize; 2]>) -> Result<Array3<f32>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| matches!(extension(p).as_str(), "npy" | "tif" | "tiff"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::field(dir, "path", "holds no .npy or .tif images"));
    }
    let stacks: Vec<Array3<f32>> = files
        .iter()
        .map(|f| read_file(f, None, image))
        .collect::<Result<_>>()?;
    let first = stacks[0].shape()[1..].to_vec();
    if let Some(k) = stacks.iter().position(|s| s.shape()[1..] != first[..]) {
        return Err(Error::field(
            &files[k],
            "shape",
            format!(
                "images are {:?}, but {} has {first:?}",
                &stacks[k].shape()[1..],
                files[0].display()
            ),
        ));
    }
    let views: Vec<_> = stacks.iter().map(|s| s.view()).collect();
    ndarray::concatenate(Axis(0), &views).map_err(|e| Error::field(dir, "images", e.to_string()))
}

/// Every page of a TIFF file (grayscale, one sample per pixel). Each page's size is checked as
/// its header is read, against `image` (`[rows, cols]`) when given and against the memory
/// available, before the page is decoded (a small compressed file can declare gigabytes).
fn read_tiff(path: &Path, image: Option<[usize; 2]>) -> Result<Array3<f32>> {
    let bad = |m: String| Error::field(path, "tiff", m);
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut d = Decoder::new(BufReader::new(file)).map_err(|e| bad(e.to_string()))?;
    let mut pages: Vec<f32> = Vec::new();
    let mut shape: Option<(u32, u32)> = None;
    let mut n = 0;
    loop {
        let dims = d.dimensions().map_err(|e| bad(e.to_string()))?;
        if let Some(s) = shape
            && s != dims
        {
            return Err(bad(format!(
                "page {n} is {}×{}, page 0 {}×{}",
                dims.0, dims.1, s.0, s.1
            )));
        }
        if let Some([rows, cols]) = image
            && (dims.1 as usize, dims.0 as usize) != (rows, cols)
        {
            return Err(bad(format!(
                "page {n} is {}×{} (width × height); the detector is {cols}×{rows}",
                dims.0, dims.1
            )));
        }
        let page = crate::memory::bytes(dims.0 as usize * dims.1 as usize, 4);
        let held = crate::memory::bytes(pages.len(), 4);
        if let Some(a) =
            crate::memory::exceeds_available(held.saturating_add(page.saturating_mul(2)))
        {
            return Err(bad(format!(
                "page {n} ({}×{}) would take the pages read past the {} of memory available",
                dims.0,
                dims.1,
                crate::memory::human(a)
            )));
        }
        shape = Some(dims);
        let colour = d.colortype().map_err(|e| bad(e.to_string()))?;
        if !matches!(colour, tiff::ColorType::Gray(_)) {
            return Err(bad(format!(
                "page {n} is {colour:?}; only grayscale images are projections"
            )));
        }
        let values: Vec<f32> = match d.read_image().map_err(|e| bad(e.to_string()))? {
            DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::U32(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::I8(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::F32(v) => v,
            DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
            _ => return Err(bad(format!("page {n}: unsupported sample type"))),
        };
        pages.extend(values);
        n += 1;
        if !d.more_images() {
            break;
        }
        d.next_image().map_err(|e| bad(e.to_string()))?;
    }
    let (w, h) = shape.unwrap_or((0, 0));
    Array3::from_shape_vec((n, h as usize, w as usize), pages).map_err(|e| bad(e.to_string()))
}

/// A headerless file of `layout`; its size must match the shape exactly.
fn read_raw(path: &Path, layout: &RawLayout) -> Result<ArrayD<f32>> {
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    let count = layout
        .shape
        .iter()
        .try_fold(1u64, |a, &n| a.checked_mul(n as u64));
    let need = count
        .and_then(|c| c.checked_mul(layout.dtype.size() as u64))
        .and_then(|b| b.checked_add(layout.header_bytes));
    if need != Some(len) {
        return Err(Error::field(
            path,
            "raw.shape",
            format!(
                "{:?} of {:?} after {} header bytes needs {} bytes; the file has {len}",
                layout.shape,
                layout.dtype,
                layout.header_bytes,
                need.map_or("more than 2⁶⁴".into(), |n| n.to_string())
            ),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let data = &bytes[layout.header_bytes as usize..];
    let size = layout.dtype.size();
    let big = layout.big_endian;
    let values: Vec<f32> = data
        .chunks_exact(size)
        .map(|c| {
            let mut b = [0u8; 8];
            b[..size].copy_from_slice(c);
            if big {
                b[..size].reverse();
            }
            match layout.dtype {
                RawType::U8 => b[0] as f32,
                RawType::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
                RawType::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
                RawType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                RawType::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                RawType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                RawType::F64 => f64::from_le_bytes(b) as f32,
            }
        })
        .collect();
    ArrayD::from_shape_vec(IxDyn(&layout.shape), values)
        .map_err(|e| Error::field(path, "raw.shape", e.to_string()))
}
