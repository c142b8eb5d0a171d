//! Byte layout of the written files. That other tools read them as meant is checked against
//! nibabel and ITK in `tests/cli_export.rs`.

use super::*;
use ndarray::Array3;
use std::io::Read;

fn grid() -> VolumeGrid {
    VolumeGrid {
        nx: 4,
        ny: 3,
        nz: 2,
        dx: 0.5,
        dy: 0.75,
        dz: 1.25,
        offset: [1.0, -2.0, 3.0],
    }
}

/// Voxel value encodes its indices, so any axis mix-up shows.
fn volume() -> Array3<f32> {
    Array3::from_shape_fn((2, 3, 4), |(z, y, x)| (100 * z + 10 * y + x) as f32)
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn i16_at(b: &[u8], at: usize) -> i16 {
    i16::from_le_bytes(b[at..at + 2].try_into().unwrap())
}

#[test]
fn nifti_header_fields_sit_at_the_standards_offsets_and_data_is_x_fastest() {
    let dir = tempfile::tempdir().unwrap();
    let g = grid();
    let p = VolumeFormat::Nifti.path(dir.path(), "mu");
    write_volume(&p, volume().view(), &g, VolumeFormat::Nifti, "prism test").unwrap();
    let b = std::fs::read(&p).unwrap();
    assert_eq!(b.len(), 352 + 4 * 24);
    assert_eq!(i32::from_le_bytes(b[0..4].try_into().unwrap()), 348);
    assert_eq!(&b[344..348], b"n+1\0");
    let dims: Vec<i16> = (0..8).map(|i| i16_at(&b, 40 + 2 * i)).collect();
    assert_eq!(dims, [3, 4, 3, 2, 1, 1, 1, 1]);
    assert_eq!((i16_at(&b, 70), i16_at(&b, 72)), (16, 32));
    assert_eq!(
        [f32_at(&b, 80), f32_at(&b, 84), f32_at(&b, 88)],
        [0.5, 0.75, 1.25]
    );
    assert_eq!(f32_at(&b, 108), 352.0);
    // First voxel centre: offset + (½ − n/2)·d per axis.
    let o = [
        1.0 + (0.5 - 2.0) * 0.5,
        -2.0 + (0.5 - 1.5) * 0.75,
        3.0 + (0.5 - 1.0) * 1.25,
    ];
    assert_eq!(
        [f32_at(&b, 268), f32_at(&b, 272), f32_at(&b, 276)],
        o.map(|v| v as f32)
    );
    assert_eq!(f32_at(&b, 280), 0.5);
    assert_eq!(f32_at(&b, 292), o[0] as f32);
    assert_eq!(f32_at(&b, 300), 0.75);
    assert_eq!(f32_at(&b, 320), 1.25);
    assert_eq!(f32_at(&b, 324), o[2] as f32);
    assert!(b[148..].starts_with(b"prism test\0"));
    // Voxel (x=1, y=2, z=1) is element 1 + 4·2 + 12·1 of the data.
    assert_eq!(f32_at(&b, 352 + 4 * (1 + 8 + 12)), 121.0);
}

#[test]
fn gzip_holds_the_same_bytes_and_metaimage_the_same_voxels() {
    let dir = tempfile::tempdir().unwrap();
    let (g, v) = (grid(), volume());
    let write = |f: VolumeFormat| {
        let p = f.path(dir.path(), "mu");
        write_volume(&p, v.view(), &g, f, "").unwrap();
        std::fs::read(p).unwrap()
    };
    let raw = write(VolumeFormat::Nifti);
    let mut unzipped = Vec::new();
    flate2::read::GzDecoder::new(&write(VolumeFormat::NiftiGz)[..])
        .read_to_end(&mut unzipped)
        .unwrap();
    assert_eq!(unzipped, raw);
    let mha = write(VolumeFormat::MetaImage);
    let text = String::from_utf8_lossy(&mha);
    let end = text.find("ElementDataFile = LOCAL\n").unwrap() + 24;
    assert!(
        text.contains("DimSize = 4 3 2\n") && text.contains("ElementSpacing = 0.5 0.75 1.25\n")
    );
    assert!(text.contains("Offset = 0.25 -2.75 2.375\n"), "{text}");
    assert_eq!(&mha[end..], &raw[352..]);
}

#[test]
fn wrong_shapes_and_formats_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.nii");
    let e = write_volume(
        &p,
        Array3::zeros((3, 3, 3)).view(),
        &grid(),
        VolumeFormat::Nifti,
        "",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("volume") && e.contains("[2, 3, 4]"), "{e}");
    assert!(!p.exists());
    let e = VolumeFormat::parse("nrrd").unwrap_err().to_string();
    assert!(e.contains("nrrd") && e.contains("nii.gz, mha"), "{e}");
    assert_eq!(
        VolumeFormat::parse(".nii.gz").unwrap(),
        VolumeFormat::NiftiGz
    );
    let mut big = grid();
    big.nx = 40_000;
    let e = write_volume(
        &p,
        Array3::zeros((2, 3, 40_000)).view(),
        &big,
        VolumeFormat::Nifti,
        "",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("32767") && e.contains("mha"), "{e}");
}

#[test]
fn tiff_pages_are_z_slices_with_rows_y_and_the_voxel_size_per_mm() {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::tags::Tag;
    let dir = tempfile::tempdir().unwrap();
    let p = VolumeFormat::Tiff.path(dir.path(), "mu");
    write_volume(&p, volume().view(), &grid(), VolumeFormat::Tiff, "").unwrap();
    let mut d = Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap())).unwrap();
    assert_eq!(d.dimensions().unwrap(), (4, 3));
    let text = d.get_tag_ascii_string(Tag::ImageDescription).unwrap();
    assert!(
        text.contains("slices=2\n") && text.contains("spacing=1.25\n"),
        "{text}"
    );
    let DecodingResult::F32(first) = d.read_image().unwrap() else {
        panic!("not float pages")
    };
    assert_eq!(first[4 * 2 + 3], 23.0); // z 0, y 2, x 3
    d.next_image().unwrap();
    let DecodingResult::F32(second) = d.read_image().unwrap() else {
        panic!("not float pages")
    };
    assert_eq!(second[4 + 1], 111.0); // z 1, y 1, x 1
    assert!(!d.more_images());
}

#[test]
fn png_previews_put_the_three_central_slices_side_by_side() {
    // 4 × 3 × 2 (x, y, z): voxel value 100z + 10y + x, so each pixel names its voxel.
    let (w, h, img) = png_preview::image(volume().view());
    assert_eq!((w, h), (4 + 2 + 4 + 2 + 3, 3));
    let white = 123.0f32; // the 99.9th percentile of 24 values is the largest
    let grey = |v: f32| (v * 255.0 / white).round() as u8;
    // Axial z = 1: row y, column x.
    assert_eq!(img[2 * w + 3], 255);
    // Coronal y = 1: row 0 is the top (z = 1), column x.
    assert_eq!(img[6 + 2], grey(112.0));
    assert_eq!(img[w + 6 + 2], grey(12.0));
    // Sagittal x = 2: row 0 is z = 1, column y.
    assert_eq!(img[12 + 1], grey(112.0));
    assert_eq!(img[w + 12], grey(2.0));
    // The gaps are black, and so is the row below the shorter slices.
    assert_eq!((img[4], img[5], img[2 * w + 8]), (0, 0, 0));
    let dir = tempfile::tempdir().unwrap();
    let p = VolumeFormat::Png.path(dir.path(), "mu");
    write_volume(&p, volume().view(), &grid(), VolumeFormat::Png, "").unwrap();
    assert!(std::fs::read(&p).unwrap().starts_with(b"\x89PNG"));
}
