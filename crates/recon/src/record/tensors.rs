//! Safetensors files whose bytes depend only on their content: the tensors to write
//! ([`Tensors`]), a file of a Prism `format` read back whole with errors that name the file and
//! the key ([`TensorFile`]), JSON metadata entries. Models, stage-1 checkpoints and resume files
//! are written with them.

use crate::{Error, Result};
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fs;
use std::path::Path;

/// A metadata entry: `v` as JSON (errors name `metadata.<key>` of `path`).
pub(crate) fn json_meta<T: Serialize>(path: &Path, key: &str, v: &T) -> Result<String> {
    serde_json::to_string(v)
        .map_err(|e| Error::field(path, format!("metadata.{key}"), e.to_string()))
}

/// Tensors to write to one safetensors file: name, dtype, shape and little-endian bytes.
#[derive(Default)]
pub(crate) struct Tensors(Vec<(String, Dtype, Vec<usize>, Vec<u8>)>);

impl Tensors {
    /// A float32 tensor of `shape` (row-major `values`).
    pub fn f32<const D: usize>(
        &mut self,
        name: impl Into<String>,
        values: &[f32],
        shape: [usize; D],
    ) {
        self.0
            .push((name.into(), Dtype::F32, shape.to_vec(), bytes(values)));
    }

    /// A byte tensor `[n]` (an opaque record, e.g. a network's).
    pub fn u8(&mut self, name: impl Into<String>, data: Vec<u8>) {
        self.0
            .push((name.into(), Dtype::U8, vec![data.len()], data));
    }

    /// Write the tensors and the string metadata `meta` to `path` ([`write_safetensors`]).
    pub fn write(&self, path: &Path, meta: HashMap<String, String>) -> Result<()> {
        let views: Vec<(&str, TensorView)> = self
            .0
            .iter()
            .map(|(n, dtype, s, b)| {
                TensorView::new(*dtype, s.clone(), b)
                    .map(|v| (n.as_str(), v))
                    .map_err(|e| Error::field(path, n.clone(), e.to_string()))
            })
            .collect::<Result<_>>()?;
        write_safetensors(path, views, meta)
    }
}

/// Write a safetensors file whose bytes depend only on its content. safetensors writes the
/// metadata in hash-map order, which changes from run to run; the header is rewritten with its
/// keys sorted (serde_json's objects are ordered maps) and padded to 8 bytes as before.
pub(crate) fn write_safetensors(
    path: &Path,
    views: Vec<(&str, TensorView)>,
    meta: HashMap<String, String>,
) -> Result<()> {
    let fail = |e: String| Error::field(path, ".", format!("writing safetensors failed: {e}"));
    let bytes = safetensors::serialize(views, Some(meta)).map_err(|e| fail(e.to_string()))?;
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("an 8-byte header length")) as usize;
    let header: serde_json::Value =
        serde_json::from_slice(&bytes[8..8 + n]).map_err(|e| fail(e.to_string()))?;
    let mut text = header.to_string();
    while !text.len().is_multiple_of(8) {
        text.push(' ');
    }
    let mut out = Vec::with_capacity(8 + text.len() + bytes.len() - 8 - n);
    out.extend_from_slice(&(text.len() as u64).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out.extend_from_slice(&bytes[8 + n..]);
    fs::write(path, out).map_err(|e| Error::io(path, e))
}

/// A safetensors file of a Prism `format`, read whole: its string metadata and float32 row
/// tensors, with errors that name the file and the key.
pub(crate) struct TensorFile<'p> {
    path: &'p Path,
    buf: Vec<u8>,
    meta: HashMap<String, String>,
}

impl<'p> TensorFile<'p> {
    /// Read `path` and check that its `metadata.format` is `format`.
    pub fn open(path: &'p Path, format: &str) -> Result<Self> {
        let buf = fs::read(path).map_err(|e| Error::io(path, e))?;
        SafeTensors::deserialize(&buf)
            .map_err(|e| Error::field(path, ".", format!("not a safetensors file: {e}")))?;
        let (_, header) = SafeTensors::read_metadata(&buf)
            .map_err(|e| Error::field(path, ".", format!("unreadable header: {e}")))?;
        let meta = header.metadata().clone().unwrap_or_default();
        let f = TensorFile { path, buf, meta };
        let got = f.meta("format")?;
        if got != format {
            return Err(Error::field(
                path,
                "metadata.format",
                format!("expected `{format}`, got `{got}`"),
            ));
        }
        Ok(f)
    }

    /// The metadata string under `key`.
    pub fn meta(&self, key: &str) -> Result<&str> {
        self.meta
            .get(key)
            .map(String::as_str)
            .ok_or_else(|| Error::field(self.path, format!("metadata.{key}"), "missing"))
    }

    /// The metadata under `key`, parsed as JSON (a bare number is JSON too).
    pub fn json<T: for<'de> Deserialize<'de>>(&self, key: &str) -> Result<T> {
        serde_json::from_str(self.meta(key)?)
            .map_err(|e| Error::field(self.path, format!("metadata.{key}"), e.to_string()))
    }

    /// The f32 tensor `name` of shape `[rows, cols]` (any `rows`), row-major.
    pub fn rows(&self, name: &str, cols: usize) -> Result<Vec<f32>> {
        let st = SafeTensors::deserialize(&self.buf).expect("checked when opened");
        let t = st
            .tensor(name)
            .map_err(|e| Error::field(self.path, name, e.to_string()))?;
        if t.dtype() != Dtype::F32 || t.shape().len() != 2 || t.shape()[1] != cols {
            return Err(Error::field(
                self.path,
                name,
                format!(
                    "expected f32 [K, {cols}], got {:?} {:?}",
                    t.dtype(),
                    t.shape()
                ),
            ));
        }
        Ok(t.data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// The byte tensor `name` (`[n]`, any `n`).
    pub fn bytes(&self, name: &str) -> Result<Vec<u8>> {
        let st = SafeTensors::deserialize(&self.buf).expect("checked when opened");
        let t = st
            .tensor(name)
            .map_err(|e| Error::field(self.path, name, e.to_string()))?;
        if t.dtype() != Dtype::U8 || t.shape().len() != 1 {
            return Err(Error::field(
                self.path,
                name,
                format!("expected u8 [n], got {:?} {:?}", t.dtype(), t.shape()),
            ));
        }
        Ok(t.data().to_vec())
    }

    /// The file being read.
    pub fn path(&self) -> &Path {
        self.path
    }
}

pub(crate) fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
