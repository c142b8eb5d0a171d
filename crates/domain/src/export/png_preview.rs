//! PNG preview (`.png`): the three central slices of a volume side by side, 8-bit grey from 0
//! (black) to the volume's 99.9th percentile (white; negative and non-finite values black):
//! axial (z = nz/2; y down, x right), coronal (y = ny/2; z up, x right) and sagittal
//! (x = nx/2; z up, y right), two black columns apart. A preview for the eye, not data: voxels
//! are drawn square whatever their size.

use crate::metrics::quantile;
use ndarray::ArrayView3;

/// Columns of black between the slices.
const GAP: usize = 2;

/// The preview's grey image: width, height and row-major pixels.
pub(super) fn image(volume: ArrayView3<f32>) -> (usize, usize, Vec<u8>) {
    let (nz, ny, nx) = volume.dim();
    let white = quantile(volume.iter().copied(), 0.999);
    let scale = if white > 0.0 { 255.0 / white } else { 0.0 };
    // NaN·scale clamps to NaN, which `as u8` maps to 0 (black), as it does negatives.
    let grey = |v: f32| (v * scale).clamp(0.0, 255.0).round() as u8;
    let width = nx + GAP + nx + GAP + ny;
    let height = ny.max(nz);
    let mut img = vec![0u8; width * height];
    for y in 0..ny {
        for x in 0..nx {
            img[y * width + x] = grey(volume[[nz / 2, y, x]]);
        }
    }
    let (coronal, sagittal) = (nx + GAP, 2 * (nx + GAP));
    for r in 0..nz {
        let z = nz - 1 - r;
        for x in 0..nx {
            img[r * width + coronal + x] = grey(volume[[z, ny / 2, x]]);
        }
        for y in 0..ny {
            img[r * width + sagittal + y] = grey(volume[[z, y, nx / 2]]);
        }
    }
    (width, height, img)
}

/// Append the PNG file of `volume`'s preview to `out`.
pub(super) fn write(volume: ArrayView3<f32>, out: &mut Vec<u8>) -> Result<(), png::EncodingError> {
    let (w, h, img) = image(volume);
    let mut enc = png::Encoder::new(out, w as u32, h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header()?;
    writer.write_image_data(&img)?;
    writer.finish()
}
