//! TIFF stack (`.tif`): one 32-bit float page per z slice (z index 0 first), rows y (row 0 is
//! y index 0), columns x, uncompressed; ImageJ's metadata on the first page (`unit=mm`, the
//! x/y resolution in pixels per mm, `spacing` the z voxel size) so Fiji and tifffile read the
//! voxel size. TIFF has no origin: the grid position is not recorded (use NIfTI or MetaImage).

use crate::geometry::VolumeGrid;
use ndarray::{ArrayView3, Axis};
use std::io::Cursor;
use tiff::encoder::colortype::Gray32Float;
use tiff::encoder::{Rational, TiffEncoder};
use tiff::tags::{ResolutionUnit, Tag};

/// Pixels per mm as a TIFF rational (micro-pixel precision, clamped to what 32 bits hold).
fn per_mm(voxel_mm: f64) -> Rational {
    Rational {
        n: (1e6 / voxel_mm).round().clamp(1.0, u32::MAX as f64) as u32,
        d: 1_000_000,
    }
}

/// Append the whole file for `volume` on `grid` to `out`.
pub(super) fn write(
    volume: ArrayView3<f32>,
    grid: &VolumeGrid,
    out: &mut Vec<u8>,
) -> Result<(), tiff::TiffError> {
    let too_wide = || {
        tiff::TiffError::IoError(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "TIFF pages hold at most 2³² − 1 pixels per row and column",
        ))
    };
    let width = u32::try_from(grid.nx).map_err(|_| too_wide())?;
    let height = u32::try_from(grid.ny).map_err(|_| too_wide())?;
    let mut encoder = TiffEncoder::new(Cursor::new(out))?;
    let description = format!(
        "ImageJ=1.11a\nimages={n}\nslices={n}\nunit=mm\nspacing={dz}\nloop=false\n",
        n = grid.nz,
        dz = grid.dz
    );
    let mut page = Vec::with_capacity(grid.nx * grid.ny);
    for (z, slice) in volume.axis_iter(Axis(0)).enumerate() {
        page.clear();
        page.extend(slice.iter().copied());
        let mut image = encoder.new_image::<Gray32Float>(width, height)?;
        let tags = image.encoder();
        tags.write_tag(Tag::ResolutionUnit, ResolutionUnit::None)?;
        tags.write_tag(Tag::XResolution, per_mm(grid.dx))?;
        tags.write_tag(Tag::YResolution, per_mm(grid.dy))?;
        if z == 0 {
            tags.write_tag(Tag::ImageDescription, description.as_str())?;
        }
        image.write_data(&page)?;
    }
    Ok(())
}
