//! Volumes written for viewers and other tools: NIfTI-1 (`.nii`, `.nii.gz`) and MetaImage
//! (`.mha`), with the voxel spacing and the position of the grid from the geometry, and TIFF
//! stacks (`.tif`, voxel size only; see [`tiff_stack`]) and PNG previews of the central slices
//! (`.png`, see [`png_preview`]).
//!
//! Conventions (`docs/geometry.md`): Prism volumes are stored `[z][y][x]` (x fastest), which is
//! the storage order of both formats (first index fastest), so voxel (i, j, k) of the file is
//! voxel (ix, iy, iz) of the grid. The index-to-world map written is Prism's scanner frame in mm:
//! `world = offset + ((i + ½ − nx/2)·dx, (j + ½ − ny/2)·dy, (k + ½ − nz/2)·dz)` with an identity
//! direction. The scanner frame is not a patient frame: NIfTI readers take the written axes as
//! RAS (nibabel shows the affine as written), ITK's NIfTI reader flips x and y into its LPS
//! frame (its MetaImage reader does not). Values are μ in mm⁻¹, 32-bit float, little-endian.
//!
//! NIfTI-1 is written by hand (the 348-byte header of the standard, `vox_offset` 352): the `nifti`
//! crate builds on ndarray 0.15 (the workspace uses 0.17), and independent readers (nibabel and
//! ITK, `tests/cli_export.rs`) check every file written here.

mod metaimage;
mod nifti;
pub mod png_preview;
#[cfg(test)]
mod tests;
pub mod tiff_stack;

use crate::geometry::VolumeGrid;
use crate::{Error, Result};
use ndarray::ArrayView3;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A volume file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VolumeFormat {
    /// NIfTI-1, one file (`.nii`).
    Nifti,
    /// NIfTI-1, gzip-compressed (`.nii.gz`).
    NiftiGz,
    /// MetaImage with the data in the same file (`.mha`).
    MetaImage,
    /// A stack of float TIFF pages, one per z slice (`.tif`).
    Tiff,
    /// The three central slices side by side, 8-bit grey (`.png`; a preview, not data).
    Png,
}

impl VolumeFormat {
    pub const ALL: [VolumeFormat; 5] = [
        VolumeFormat::Nifti,
        VolumeFormat::NiftiGz,
        VolumeFormat::MetaImage,
        VolumeFormat::Tiff,
        VolumeFormat::Png,
    ];

    /// The file extension, also the format's name on the command line.
    pub fn extension(self) -> &'static str {
        match self {
            VolumeFormat::Nifti => "nii",
            VolumeFormat::NiftiGz => "nii.gz",
            VolumeFormat::MetaImage => "mha",
            VolumeFormat::Tiff => "tif",
            VolumeFormat::Png => "png",
        }
    }

    /// The format named `name` (an extension, with or without the leading dot).
    pub fn parse(name: &str) -> Result<Self> {
        let name = name.trim_start_matches('.');
        Self::ALL
            .into_iter()
            .find(|f| f.extension() == name)
            .ok_or_else(|| {
                let known: Vec<&str> = Self::ALL.iter().map(|f| f.extension()).collect();
                Error::invalid(
                    "format",
                    format!(
                        "unknown volume format `{name}` (known: {})",
                        known.join(", ")
                    ),
                )
            })
    }

    /// `dir/stem.<extension>`.
    pub fn path(self, dir: &Path, stem: &str) -> PathBuf {
        dir.join(format!("{stem}.{}", self.extension()))
    }
}

/// World position (mm) of the centre of voxel (0, 0, 0): the origin both formats record.
fn first_centre(grid: &VolumeGrid) -> [f64; 3] {
    grid.voxel_centre(0, 0, 0)
}

/// Write `volume` (`[z][y][x]` on `grid`) to `path` in `format`; `description` goes into the
/// header where the format has room for one (NIfTI: 79 bytes). The file appears whole or not
/// at all (written beside it, then renamed).
pub fn write_volume(
    path: &Path,
    volume: ArrayView3<f32>,
    grid: &VolumeGrid,
    format: VolumeFormat,
    description: &str,
) -> Result<()> {
    crate::error::ensure_shape(
        "volume",
        volume.shape(),
        &grid.shape_zyx(),
        "the grid's [nz, ny, nx]",
    )?;
    let is_nifti = matches!(format, VolumeFormat::Nifti | VolumeFormat::NiftiGz);
    if is_nifti
        && [grid.nx, grid.ny, grid.nz]
            .iter()
            .any(|&n| n > nifti::MAX_DIM)
    {
        return Err(Error::invalid(
            "volume",
            format!(
                "NIfTI-1 holds at most {} voxels per axis; the grid is {}×{}×{} (use mha)",
                nifti::MAX_DIM,
                grid.nx,
                grid.ny,
                grid.nz
            ),
        ));
    }
    let bytes = volume.len().checked_mul(4).ok_or_else(|| {
        Error::invalid(
            "volume",
            format!("{} voxels overflow a file size", volume.len()),
        )
    })?;
    let mut out = Vec::with_capacity(bytes + 1024);
    match format {
        VolumeFormat::Tiff => {
            tiff_stack::write(volume, grid, &mut out)
                .map_err(|e| Error::io(path, std::io::Error::other(e.to_string())))?;
            return write_atomically(path, &out);
        }
        VolumeFormat::Png => {
            png_preview::write(volume, &mut out)
                .map_err(|e| Error::io(path, std::io::Error::other(e.to_string())))?;
            return write_atomically(path, &out);
        }
        VolumeFormat::MetaImage => metaimage::header(grid, &mut out),
        VolumeFormat::Nifti | VolumeFormat::NiftiGz => nifti::header(grid, description, &mut out),
    }
    for v in volume.iter() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    if format == VolumeFormat::NiftiGz {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(&out).map_err(|e| Error::io(path, e))?;
        out = gz.finish().map_err(|e| Error::io(path, e))?;
    }
    write_atomically(path, &out)
}

/// Write `bytes` to a hidden sibling of `path`, flushed, then renamed over it (the file gets
/// the user's umask, like any file the user creates).
fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::staged::replace_file(path, bytes)
}

/// Read a `[z][y][x]` f32 volume from a `.npy` file (errors name the file).
pub fn read_volume_npy(path: &Path) -> Result<ndarray::Array3<f32>> {
    crate::scene::npy::read_npy_f32(path, "volume")?
        .into_dimensionality()
        .map_err(|_| Error::field(path, "volume", "expected a 3-D array [z][y][x]"))
}
