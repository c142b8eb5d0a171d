//! Reading `.npy` arrays safely: the header's declared size is checked against the file and the
//! memory available before anything is allocated, any common numeric type can be widened to
//! f32, and every error names the file and the field. Every `.npy` a command reads goes through
//! here; [`npy_bytes`] is the writing side.

use crate::{Error, Result};
use ndarray::{Array, ArrayD, Dimension};
use ndarray_npy::{ReadNpyError, ReadNpyExt, ReadableElement, WriteNpyExt};
use std::fs;
use std::io::BufReader;
use std::path::Path;

/// What an `.npy` read failed on, as a field error of `path`.
pub(super) fn npy_error(path: &Path, key: &str, want: &str, e: ReadNpyError) -> Error {
    let msg = match e {
        ReadNpyError::WrongDescriptor(found) => {
            format!("wrong dtype: expected {want}, found {found}")
        }
        other => format!("not a readable {want} .npy array: {other}"),
    };
    Error::field(path, key, msg)
}

/// Read a `.npy` of any shape and any common numeric type (f32, f64, u8, u16, u32, i16, i32)
/// as f32; errors name `path` and `field`.
pub fn read_npy_any(path: &Path, field: &str) -> Result<ArrayD<f32>> {
    fn widen<T: ReadableElement + Copy>(
        path: &Path,
        f: impl Fn(T) -> f32,
    ) -> std::result::Result<ArrayD<f32>, ReadNpyError> {
        read_npy::<T>(path).map(|a| a.mapv(f))
    }
    type Attempt = fn(&Path) -> std::result::Result<ArrayD<f32>, ReadNpyError>;
    let attempts: [Attempt; 7] = [
        |p| read_npy::<f32>(p),
        |p| widen::<f64>(p, |x| x as f32),
        |p| widen::<u16>(p, f32::from),
        |p| widen::<u8>(p, f32::from),
        |p| widen::<i16>(p, f32::from),
        |p| widen::<u32>(p, |x| x as f32),
        |p| widen::<i32>(p, |x| x as f32),
    ];
    let want = "f32, f64, u8, u16, u32, i16 or i32";
    for attempt in attempts {
        match attempt(path) {
            Err(ReadNpyError::WrongDescriptor(_)) => continue,
            other => return other.map_err(|e| npy_error(path, field, want, e)),
        }
    }
    Err(Error::field(path, field, format!("not a {want} array")))
}

/// Read an f32 `.npy` of any shape; errors name `path` and `field` (and the dtype found).
pub fn read_npy_f32(path: &Path, field: &str) -> Result<ArrayD<f32>> {
    read_npy::<f32>(path).map_err(|e| npy_error(path, field, "f32 ('<f4')", e))
}

/// Read a `.npy` of element type `T` and dimension `D` (e.g. `Array3<f32>`); errors name `path`
/// and `field`, with the dtype or the number of axes found.
pub fn read_array<T: ReadableElement, D: Dimension>(
    path: &Path,
    field: &str,
) -> Result<Array<T, D>> {
    let want = std::any::type_name::<T>();
    let a = read_npy::<T>(path).map_err(|e| npy_error(path, field, want, e))?;
    let found = a.ndim();
    a.into_dimensionality::<D>().map_err(|_| {
        Error::field(
            path,
            field,
            format!(
                "expected a {}-D array, found {found}-D",
                D::NDIM.map_or("n".into(), |n| n.to_string())
            ),
        )
    })
}

/// The `.npy` file of `array` (for [`crate::staged::publish_file`]).
pub fn npy_bytes<A: WriteNpyExt + ?Sized>(array: &A) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    array
        .write_npy(&mut out)
        .map_err(|e| Error::invalid("array", format!("cannot be written as .npy: {e}")))?;
    Ok(out)
}

pub(super) fn read_npy<T: ReadableElement>(
    path: &Path,
) -> std::result::Result<ArrayD<T>, ReadNpyError> {
    ArrayD::<T>::read_npy(open_checked(path).map_err(ReadNpyError::Io)?)
}

/// `path` opened for a `.npy` reader once its header's declared size is checked against the
/// file and the memory available ([`check_npy_size`]).
pub(crate) fn open_checked(path: &Path) -> std::io::Result<BufReader<fs::File>> {
    let mut f = fs::File::open(path)?;
    check_npy_size(&mut f)?;
    Ok(BufReader::new(f))
}

/// Refuse a `.npy` whose header declares more data than the file holds before anything is
/// allocated for it (ndarray-npy allocates the declared size, so a 200-byte file claiming
/// terabytes would abort the process). Headers this cannot parse are left to ndarray-npy's
/// own errors. Leaves the file at its start.
fn check_npy_size(f: &mut fs::File) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let bad = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidData, m);
    let file_len = f.metadata()?.len();
    let mut pre = [0u8; 12];
    if file_len < 12 || f.read_exact(&mut pre).is_err() || &pre[..6] != b"\x93NUMPY" {
        return f.seek(SeekFrom::Start(0)).map(|_| ());
    }
    let (header_len, prefix) = if pre[6] == 1 {
        (u64::from(u16::from_le_bytes([pre[8], pre[9]])), 10)
    } else {
        (
            u64::from(u32::from_le_bytes([pre[8], pre[9], pre[10], pre[11]])),
            12,
        )
    };
    const MAX_HEADER: u64 = 1 << 20;
    if header_len > MAX_HEADER || prefix + header_len > file_len {
        return Err(bad(format!(
            "its header claims {header_len} bytes; the file has {file_len}"
        )));
    }
    let mut header = vec![0u8; header_len as usize];
    f.seek(SeekFrom::Start(prefix))?;
    f.read_exact(&mut header)?;
    f.seek(SeekFrom::Start(0))?;
    let text = String::from_utf8_lossy(&header);
    let after = |key: &str| text.find(key).map(|i| &text[i + key.len()..]);
    let descr = after("'descr':").and_then(|t| t.split('\'').nth(1));
    let shape = after("'shape':").and_then(|t| {
        let t = &t[t.find('(')? + 1..];
        let inner = &t[..t.find(')')?];
        inner
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<u64>().ok())
            .collect::<Option<Vec<u64>>>()
    });
    let (Some(descr), Some(shape)) = (descr, shape) else {
        return Ok(());
    };
    let digits: String = descr.chars().skip_while(|c| !c.is_ascii_digit()).collect();
    let Ok(item) = digits.parse::<u64>() else {
        return Ok(());
    };
    let data = shape.iter().try_fold(item, |a, &n| a.checked_mul(n));
    let held = file_len - prefix - header_len;
    match data {
        // Read, then widened to f32 at most: twice the data in the worst case.
        Some(bytes) if bytes <= held => {
            match crate::memory::exceeds_available(bytes.saturating_mul(2)) {
                Some(a) => Err(bad(format!(
                    "its {} of data do not fit the {} of memory available",
                    crate::memory::human(bytes),
                    crate::memory::human(a)
                ))),
                _ => Ok(()),
            }
        }
        _ => Err(bad(format!(
            "its header declares shape {shape:?} of {descr} ({} bytes of data); the file holds {held} after its header",
            data.map_or("more than 2⁶⁴".to_string(), |b| b.to_string()),
        ))),
    }
}
