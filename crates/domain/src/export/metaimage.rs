//! MetaImage (`.mha`): a text header, then the raw voxels in the same file.

use super::first_centre;
use crate::geometry::VolumeGrid;
use std::fmt::Write as _;

/// The header of a little-endian float volume on `grid`, up to and including the line that
/// announces the data (`ElementDataFile = LOCAL`).
pub(super) fn header(grid: &VolumeGrid, out: &mut Vec<u8>) {
    let o = first_centre(grid);
    let mut h = String::new();
    let _ = writeln!(h, "ObjectType = Image");
    let _ = writeln!(h, "NDims = 3");
    let _ = writeln!(h, "BinaryData = True");
    let _ = writeln!(h, "BinaryDataByteOrderMSB = False");
    let _ = writeln!(h, "CompressedData = False");
    let _ = writeln!(h, "TransformMatrix = 1 0 0 0 1 0 0 0 1");
    let _ = writeln!(h, "Offset = {} {} {}", o[0], o[1], o[2]);
    let _ = writeln!(h, "CenterOfRotation = 0 0 0");
    let _ = writeln!(h, "ElementSpacing = {} {} {}", grid.dx, grid.dy, grid.dz);
    let _ = writeln!(h, "DimSize = {} {} {}", grid.nx, grid.ny, grid.nz);
    let _ = writeln!(h, "ElementType = MET_FLOAT");
    let _ = writeln!(h, "ElementDataFile = LOCAL");
    out.extend_from_slice(h.as_bytes());
}
