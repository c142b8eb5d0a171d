//! NIfTI-1 single-file header (`n+1`): 348 bytes, then 4 bytes of (absent) extension flags, then
//! the voxels at `vox_offset` 352. Field offsets are those of the standard's `nifti1.h`.

use super::first_centre;
use crate::geometry::VolumeGrid;

/// Header length (`sizeof_hdr`) and the offset of the data.
pub(super) const HEADER: usize = 348;
pub(super) const VOX_OFFSET: usize = 352;
/// `datatype` of 32-bit float voxels, and its `bitpix`.
const FLOAT32: i16 = 16;
/// `xyzt_units`: millimetres (time unknown).
const UNITS_MM: u8 = 2;
/// `qform_code` / `sform_code`: scanner-based coordinates.
const SCANNER_ANAT: i16 = 1;

/// Append the header and the extension flags of a float volume on `grid` (every axis at most
/// [`MAX_DIM`] voxels).
pub(super) fn header(grid: &VolumeGrid, description: &str, out: &mut Vec<u8>) {
    let mut h = [0u8; VOX_OFFSET];
    let put =
        |h: &mut [u8], at: usize, bytes: &[u8]| h[at..at + bytes.len()].copy_from_slice(bytes);
    put(&mut h, 0, &(HEADER as i32).to_le_bytes());
    h[38] = b'r'; // `regular`, as the standard asks
    let dims = [3, grid.nx, grid.ny, grid.nz, 1, 1, 1, 1];
    for (i, d) in dims.iter().enumerate() {
        // `write_volume` refuses grids beyond MAX_DIM; saturate rather than wrap regardless.
        let d = i16::try_from(*d).unwrap_or(i16::MAX);
        put(&mut h, 40 + 2 * i, &d.to_le_bytes());
    }
    put(&mut h, 70, &FLOAT32.to_le_bytes());
    put(&mut h, 72, &32i16.to_le_bytes());
    // pixdim[0] is qfac (+1: right-handed), then the voxel sizes.
    let pixdim = [1.0, grid.dx, grid.dy, grid.dz, 0.0, 0.0, 0.0, 0.0];
    for (i, p) in pixdim.iter().enumerate() {
        put(&mut h, 76 + 4 * i, &(*p as f32).to_le_bytes());
    }
    put(&mut h, 108, &(VOX_OFFSET as f32).to_le_bytes());
    put(&mut h, 112, &1f32.to_le_bytes()); // scl_slope: values as stored
    h[123] = UNITS_MM;
    let text = description.as_bytes();
    put(&mut h, 148, &text[..text.len().min(79)]);
    put(&mut h, 252, &SCANNER_ANAT.to_le_bytes());
    put(&mut h, 254, &SCANNER_ANAT.to_le_bytes());
    // qform: identity rotation (quatern b = c = d = 0) and the first voxel's centre.
    let o = first_centre(grid);
    for (a, v) in o.iter().enumerate() {
        put(&mut h, 268 + 4 * a, &(*v as f32).to_le_bytes());
    }
    // sform rows: world = diag(dx, dy, dz)·index + o.
    let d = grid.voxel_size();
    for (a, row_at) in [280, 296, 312].into_iter().enumerate() {
        let mut row = [0.0f64; 4];
        row[a] = d[a];
        row[3] = o[a];
        for (c, v) in row.iter().enumerate() {
            put(&mut h, row_at + 4 * c, &(*v as f32).to_le_bytes());
        }
    }
    put(&mut h, 344, b"n+1\0");
    out.extend_from_slice(&h);
}

/// The largest dimension a NIfTI-1 header holds.
pub(super) const MAX_DIM: usize = i16::MAX as usize;
