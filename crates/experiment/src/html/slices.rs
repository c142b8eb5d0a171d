//! The slice viewer's data. A set is one scene: its reference volumes and the volumes every
//! method reconstructed of it, per channel. Each volume is written as an 8-bit atlas of its axial
//! slices (slice `k` in tile `k`, tiles left to right, then top to bottom; `y` down, `x` right,
//! as the montages), PNG-encoded, in a script beside the page that hands the set to the viewer
//! when it is first shown.
//!
//! Quantisation, per channel, from the reference's 99.9th percentile `hi` (the montages' white):
//! images over `[−hi/8, 1.25·hi]` (one level is 0.54 % of `hi`, so a window can show negative
//! values and overshoot); residuals `method − reference` as `128 + round(127·e/r)` clamped to
//! `[1, 255]`, where `r` is the 99th percentile of `|e|` over every method of that channel (one
//! scale for all, so they compare). A volume larger than [`VOXELS`] keeps every `k`-th slice.

use crate::html::markdown::data_url;
use crate::{Error, Result};
use ndarray::{Array3, ArrayView2, ArrayView3, Axis};
use prism_domain::metrics::quantile;
use prism_domain::scene::Scene;
use prism_recon::report::RunScores;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The most voxels of one volume the viewer keeps (about 128³); a larger volume keeps every
/// `k`-th axial slice.
pub const VOXELS: usize = 1 << 21;

/// One scene's volumes to browse.
#[derive(Clone, Debug)]
pub struct SliceSet {
    pub title: String,
    /// The scene directory whose reference volumes are shown and subtracted; without one the
    /// viewer shows the methods' volumes only.
    pub scene: Option<PathBuf>,
    pub methods: Vec<Shown>,
}

/// One method's volumes in a [`SliceSet`].
#[derive(Clone, Debug)]
pub struct Shown {
    pub label: String,
    pub channels: Vec<ShownChannel>,
}

/// One channel's volume of a [`Shown`] method, with its 3-D scores as the tables give them.
#[derive(Clone, Debug)]
pub struct ShownChannel {
    pub label: String,
    /// `[z][y][x]` float32 `.npy` in mm⁻¹.
    pub volume: PathBuf,
    pub score: Option<Score>,
}

impl Shown {
    /// The volumes and scores of a finished run directory, named `label`.
    pub fn run(label: impl Into<String>, run: &RunScores) -> Self {
        Shown {
            label: label.into(),
            channels: run
                .channels
                .iter()
                .map(|c| ShownChannel {
                    label: c.label.clone(),
                    volume: c.volume.clone(),
                    score: c.psnr.map(|psnr| Score { psnr, ssim: c.ssim }),
                })
                .collect(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Score {
    pub psnr: f64,
    pub ssim: Option<f64>,
}

/// What the viewer receives for one set (serialised as JSON into its script).
#[derive(Debug, Serialize)]
pub(crate) struct SetData {
    pub title: String,
    /// `[nz, ny, nx]` of the volumes.
    pub shape: [usize; 3],
    /// The `z` index of every kept slice, in atlas order.
    pub slices: Vec<usize>,
    /// Tiles per atlas row.
    pub cols: usize,
    pub channels: Vec<ChannelData>,
    pub methods: Vec<MethodData>,
    /// What could not be shown, and why.
    pub notes: Vec<String>,
}

#[derive(Debug, Serialize)]
pub(crate) struct ChannelData {
    pub label: String,
    /// Level 0 and 255 of the image atlases (mm⁻¹).
    pub lo: f32,
    pub top: f32,
    /// The default window's top: the reference's 99.9th percentile (mm⁻¹).
    pub hi: f32,
    /// The residual atlases' ± range (mm⁻¹).
    pub rmax: f32,
    pub reference: Option<String>,
}

#[derive(Debug, Serialize)]
pub(crate) struct MethodData {
    pub label: String,
    pub scores: Vec<Option<Score>>,
    /// Per channel: the image and residual atlases (PNG data URLs).
    pub images: Vec<Option<String>>,
    pub residuals: Vec<Option<String>>,
}

/// The image level range of a channel whose reference's 99.9th percentile is `hi`.
pub(crate) fn image_range(hi: f32) -> (f32, f32) {
    (-hi / 8.0, 1.25 * hi)
}

/// The 8-bit level of `v` on `[lo, top]` (NaN → 0).
pub(crate) fn image_level(v: f32, lo: f32, top: f32) -> u8 {
    if v.is_nan() {
        return 0;
    }
    ((v - lo) / (top - lo) * 255.0).round().clamp(0.0, 255.0) as u8
}

/// The 8-bit level of residual `e` on `±rmax` (128 is 0; NaN → 128).
pub(crate) fn residual_level(e: f32, rmax: f32) -> u8 {
    if e.is_nan() {
        return 128;
    }
    (128.0 + (e / rmax * 127.0).round()).clamp(1.0, 255.0) as u8
}

/// The kept slices of an `[nz, ny, nx]` volume and the atlas columns.
pub(crate) fn layout(shape: [usize; 3]) -> (Vec<usize>, usize) {
    let [nz, ny, nx] = shape;
    let stride = (nz * ny * nx).div_ceil(VOXELS).max(1);
    let slices: Vec<usize> = (0..nz).step_by(stride).collect();
    let cols = (slices.len() as f64).sqrt().ceil().max(1.0) as usize;
    (slices, cols)
}

/// The atlas of `slices` of `volume` (levels from `level`) as PNG bytes.
pub(crate) fn atlas(
    volume: ArrayView3<f32>,
    slices: &[usize],
    cols: usize,
    level: impl Fn(f32) -> u8,
) -> Result<Vec<u8>> {
    let (ny, nx) = (volume.shape()[1], volume.shape()[2]);
    let rows = slices.len().div_ceil(cols);
    let (w, h) = (cols * nx, rows * ny);
    let mut pixels = vec![0u8; w * h];
    for (k, &z) in slices.iter().enumerate() {
        let (tx, ty) = (k % cols, k / cols);
        let slice: ArrayView2<f32> = volume.index_axis(Axis(0), z);
        for y in 0..ny {
            let row = &mut pixels[(ty * ny + y) * w + tx * nx..][..nx];
            for (p, &v) in row.iter_mut().zip(slice.row(y)) {
                *p = level(v);
            }
        }
    }
    crate::figures::plot::encode_png(&pixels, w as u32, h as u32, png::ColorType::Grayscale)
        .map_err(|m| Error::invalid("html", format!("slice atlas: {m}")))
}

impl Shown {
    fn channel(&self, label: &str) -> Option<&ShownChannel> {
        self.channels.iter().find(|c| c.label == label)
    }
}

impl SliceSet {
    /// The channels shown: the scene's, else every method's in first-seen order.
    fn channel_labels(&self, scene: Option<&Scene>) -> Vec<String> {
        if let Some(sc) = scene {
            return sc.channels.iter().map(|c| c.label.clone()).collect();
        }
        let mut labels: Vec<String> = Vec::new();
        for c in self.methods.iter().flat_map(|m| &m.channels) {
            if !labels.contains(&c.label) {
                labels.push(c.label.clone());
            }
        }
        labels
    }

    /// `[nz, ny, nx]` of the set: the references', else the first method volume's.
    fn shape(&self, scene: Option<&Scene>) -> Result<[usize; 3]> {
        if let Some(r) = scene.and_then(|sc| sc.references.as_ref()) {
            return Ok([r.shape()[1], r.shape()[2], r.shape()[3]]);
        }
        let first = self
            .methods
            .iter()
            .flat_map(|m| &m.channels)
            .find(|c| c.volume.exists())
            .ok_or_else(|| {
                Error::invalid(
                    "html",
                    format!("{}: no volume of any method to show", self.title),
                )
            })?;
        let v: Array3<f32> = prism_domain::scene::npy::read_array(&first.volume, "volume")?;
        Ok([v.shape()[0], v.shape()[1], v.shape()[2]])
    }

    /// Read the set's volumes and encode them (one channel's volumes in memory at a time).
    pub(crate) fn encode(&self) -> Result<SetData> {
        let scene = match &self.scene {
            Some(dir) => Some(Scene::load(dir)?),
            None => None,
        };
        let labels = self.channel_labels(scene.as_ref());
        let shape = self.shape(scene.as_ref())?;
        let (slices, cols) = layout(shape);
        let mut notes = Vec::new();
        let mut methods: Vec<MethodData> = self
            .methods
            .iter()
            .map(|m| MethodData {
                label: m.label.clone(),
                scores: labels
                    .iter()
                    .map(|l| m.channel(l).and_then(|c| c.score))
                    .collect(),
                images: Vec::new(),
                residuals: Vec::new(),
            })
            .collect();
        let mut channels = Vec::new();
        for label in &labels {
            let reference: Option<Array3<f32>> = scene.as_ref().and_then(|sc| {
                let i = sc.channels.iter().position(|ch| &ch.label == label)?;
                Some(sc.references.as_ref()?.index_axis(Axis(0), i).to_owned())
            });
            let mut volumes: Vec<Option<Array3<f32>>> = Vec::new();
            for m in &self.methods {
                let path = m.channel(label).map(|c| &c.volume).filter(|p| p.exists());
                let v = match path {
                    Some(path) => {
                        let v: Array3<f32> = prism_domain::scene::npy::read_array(path, "volume")?;
                        if v.shape() == shape {
                            Some(v)
                        } else {
                            notes.push(format!(
                                "{} {label}: {} is {:?}, the set {shape:?}: not shown",
                                m.label,
                                path.display(),
                                v.shape()
                            ));
                            None
                        }
                    }
                    None => None,
                };
                volumes.push(v);
            }
            let errors: Vec<Option<Array3<f32>>> = volumes
                .iter()
                .map(|v| Some(v.as_ref()? - reference.as_ref()?))
                .collect();
            let kept = |v: &Array3<f32>| -> Vec<f32> {
                slices
                    .iter()
                    .flat_map(|&z| v.index_axis(Axis(0), z).into_iter().copied())
                    .collect()
            };
            let hi = reference
                .as_ref()
                .or_else(|| volumes.iter().flatten().next())
                .map_or(0.0, |b| quantile(kept(b).into_iter(), 0.999))
                .max(1e-6);
            let (lo, top) = image_range(hi);
            let rmax =
                quantile(errors.iter().flatten().flat_map(kept).map(f32::abs), 0.99).max(hi * 1e-4);
            let png = |v: &Array3<f32>, f: &dyn Fn(f32) -> u8| -> Result<String> {
                Ok(data_url("image/png", &atlas(v.view(), &slices, cols, f)?))
            };
            let image = |v: &Array3<f32>| png(v, &|x| image_level(x, lo, top));
            for ((m, v), e) in methods.iter_mut().zip(&volumes).zip(&errors) {
                m.images.push(v.as_ref().map(image).transpose()?);
                m.residuals.push(
                    e.as_ref()
                        .map(|e| png(e, &|x| residual_level(x, rmax)))
                        .transpose()?,
                );
            }
            channels.push(ChannelData {
                label: label.clone(),
                lo,
                top,
                hi,
                rmax,
                reference: reference.as_ref().map(image).transpose()?,
            });
        }
        Ok(SetData {
            title: self.title.clone(),
            shape,
            slices,
            cols,
            channels,
            methods,
            notes,
        })
    }
}

/// The script that hands set `index` to the viewer.
pub(crate) fn script(index: usize, data: &SetData) -> Result<String> {
    let json = serde_json::to_string(data)
        .map_err(|e| Error::invalid("html", format!("slice set {index}: {e}")))?;
    Ok(format!("PrismViewer.add({index}, {json});\n"))
}

/// `<dir>/set-<index>.js`.
pub(crate) fn file_name(index: usize) -> String {
    format!("set-{index}.js")
}

/// Remove the set scripts an earlier page left in `dir` (only those: `set-<n>.js`).
pub(crate) fn clear(dir: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let ours = name
            .strip_prefix("set-")
            .and_then(|n| n.strip_suffix(".js"))
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
        if ours {
            std::fs::remove_file(e.path()).map_err(|err| Error::io(e.path(), err))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    fn decode(png_bytes: &[u8]) -> (Vec<u8>, usize, usize) {
        let mut r = png::Decoder::new(std::io::Cursor::new(png_bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Grayscale);
        buf.truncate(info.buffer_size());
        (buf, info.width as usize, info.height as usize)
    }

    #[test]
    fn every_voxel_lands_in_its_tile_at_its_level() {
        // 5 slices of 3 × 4: 3 columns of tiles, 2 rows; voxel value = its own index.
        let v = Array3::from_shape_fn((5, 3, 4), |(z, y, x)| (z * 12 + y * 4 + x) as f32);
        let (slices, cols) = layout([5, 3, 4]);
        assert_eq!((slices.len(), cols), (5, 3));
        let (px, w, h) = decode(&atlas(v.view(), &slices, cols, |x| x as u8).unwrap());
        assert_eq!((w, h), (12, 6));
        for z in 0..5 {
            for y in 0..3 {
                for x in 0..4 {
                    let (tx, ty) = (z % 3, z / 3);
                    assert_eq!(
                        px[(ty * 3 + y) * w + tx * 4 + x] as usize,
                        z * 12 + y * 4 + x
                    );
                }
            }
        }
        // The unused sixth tile stays 0.
        assert!(px[3 * w + 8..3 * w + 12].iter().all(|&p| p == 0));
    }

    #[test]
    fn levels_invert_to_within_half_a_step() {
        let hi = 0.04f32;
        let (lo, top) = image_range(hi);
        let step = (top - lo) / 255.0;
        for v in [-0.005f32, 0.0, 0.013, 0.04, 0.0499] {
            let back = lo + image_level(v, lo, top) as f32 * step;
            assert!((back - v).abs() <= step / 2.0 + 1e-7, "{v} → {back}");
        }
        assert_eq!(image_level(-1.0, lo, top), 0);
        assert_eq!(image_level(1.0, lo, top), 255);
        assert_eq!(image_level(f32::NAN, lo, top), 0);
        assert_eq!(residual_level(0.0, 0.01), 128);
        assert_eq!(residual_level(0.01, 0.01), 255);
        assert_eq!(residual_level(-0.01, 0.01), 1);
        assert_eq!(residual_level(-5.0, 0.01), 1);
        let back = (residual_level(0.0017, 0.01) as f32 - 128.0) / 127.0 * 0.01;
        assert!((back - 0.0017).abs() <= 0.01 / 127.0 / 2.0 + 1e-7, "{back}");
    }

    #[test]
    fn a_large_volume_keeps_every_kth_slice() {
        let (s, cols) = layout([256, 256, 256]);
        assert_eq!(s.len(), 32);
        assert_eq!(s[1], 8);
        assert_eq!(cols, 6);
        let (s, _) = layout([1, 512, 512]);
        assert_eq!(s, [0]);
    }

    #[test]
    fn only_the_pages_set_scripts_are_cleared() {
        let dir = tempfile::tempdir().unwrap();
        for n in [
            "set-0.js",
            "set-12.js",
            "set-.js",
            "notes.txt",
            "set-1.json",
        ] {
            std::fs::write(dir.path().join(n), "x").unwrap();
        }
        clear(dir.path()).unwrap();
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        left.sort();
        assert_eq!(left, ["notes.txt", "set-.js", "set-1.json"]);
    }
}
