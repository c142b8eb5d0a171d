use super::*;
use ndarray::{Array2, Array3, Axis, s};
use ndarray_npy::read_npy;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/ssim")
        .join(name)
}

fn reference() -> serde_json::Value {
    let text = std::fs::read_to_string(fixture("reference.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn crop() -> SsimParams {
    SsimParams {
        border: Border::Crop,
        ..SsimParams::default()
    }
}

#[test]
fn ssim_2d_matches_scikit_image_and_the_zero_padded_reference() {
    let r = reference();
    let a: Array2<f32> = read_npy(fixture("a2.npy")).unwrap();
    let b: Array2<f32> = read_npy(fixture("b2.npy")).unwrap();
    let crop_got = ssim_2d(b.view(), a.view(), &crop()).unwrap();
    let pad_got = ssim_2d(b.view(), a.view(), &SsimParams::default()).unwrap();
    assert!(
        (crop_got - r["ssim2d_crop"].as_f64().unwrap()).abs() <= 1e-4,
        "{crop_got}"
    );
    assert!(
        (pad_got - r["ssim2d_zero_pad"].as_f64().unwrap()).abs() <= 1e-4,
        "{pad_got}"
    );
}

#[test]
fn ssim_3d_matches_scikit_image_per_axis() {
    let r = reference();
    let gt: Array3<f32> = read_npy(fixture("gt3.npy")).unwrap();
    let pred: Array3<f32> = read_npy(fixture("pred3.npy")).unwrap();
    for (params, key) in [
        (crop(), "ssim3d_crop_axes"),
        (SsimParams::default(), "ssim3d_zero_pad_axes"),
    ] {
        let got = ssim_3d(pred.view(), gt.view(), &params).unwrap();
        let want: Vec<f64> = r[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for (k, (g, w)) in got.axes.iter().zip(&want).enumerate() {
            let g = g.expect("every axis of the fixture holds the window");
            assert!((g - w).abs() <= 1e-4, "{key}[{k}]: {g} vs {w}");
        }
        assert!((got.mean - want.iter().sum::<f64>() / 3.0).abs() <= 1e-4);
    }
    let p = psnr(pred.view(), gt.view(), 1.0).unwrap();
    assert!((p - r["psnr3d"].as_f64().unwrap()).abs() < 1e-6, "{p}");
}

#[test]
fn ssim_3d_of_one_slice_is_its_2d_ssim() {
    // A 2-D scene's volume: one z slice. Its y and x slices (1 × n) cannot hold the window and are
    // left out, under both border conventions.
    let gt: Array3<f32> = read_npy(fixture("gt3.npy")).unwrap();
    let pred: Array3<f32> = read_npy(fixture("pred3.npy")).unwrap();
    let (g, p) = (gt.slice(s![3..4, .., ..]), pred.slice(s![3..4, .., ..]));
    for params in [crop(), SsimParams::default()] {
        let got = ssim_3d(p, g, &params).unwrap();
        let want = ssim_2d(p.index_axis(Axis(0), 0), g.index_axis(Axis(0), 0), &params).unwrap();
        assert_eq!(got.axes[1..], [None, None]);
        assert_eq!(got.mean, want);
    }
    let tiny = Array3::<f32>::ones((2, 3, 4));
    assert!(ssim_3d(tiny.view(), tiny.view(), &crop()).is_err());
}

#[test]
fn psnr_of_a_constant_offset_is_closed_form() {
    let t = Array3::<f32>::from_shape_fn((4, 5, 6), |(i, j, k)| (i + j + k) as f32 / 15.0);
    let p = t.mapv(|x| x + 0.1);
    // MSE = 0.01 → 20 dB for peak 1, +20·log10(2) for peak 2.
    assert!((psnr(p.view(), t.view(), 1.0).unwrap() - 20.0).abs() < 1e-5);
    assert!((psnr(p.view(), t.view(), 2.0).unwrap() - 20.0 - 20.0 * 2f64.log10()).abs() < 1e-5);
    assert_eq!(psnr(t.view(), t.view(), 1.0).unwrap(), f64::INFINITY);
    assert!(
        psnr(p.view(), t.view(), 0.0)
            .unwrap_err()
            .to_string()
            .contains("peak")
    );
}

#[test]
fn ssim_of_identical_images_is_one_and_bad_inputs_are_errors() {
    let t = Array3::<f32>::from_shape_fn((12, 13, 14), |(i, j, k)| ((i * j + k) % 7) as f32 / 7.0);
    for params in [crop(), SsimParams::default()] {
        let s = ssim_3d(t.view(), t.view(), &params).unwrap();
        assert!((s.mean - 1.0).abs() < 1e-12, "{s:?}");
    }
    let small = Array2::<f32>::zeros((8, 20));
    assert!(
        ssim_2d(small.view(), small.view(), &crop())
            .unwrap_err()
            .to_string()
            .contains("window")
    );
    let zero = Array3::<f32>::zeros((12, 12, 12));
    assert!(
        ssim_3d(zero.view(), zero.view(), &crop())
            .unwrap_err()
            .to_string()
            .contains("all zero")
    );
    let other = Array3::<f32>::zeros((12, 12, 13));
    assert!(ssim_3d(other.view(), zero.view(), &crop()).is_err());
}

#[test]
fn projection_metrics_normalise_each_view_by_its_maximum() {
    let t = Array3::<f32>::from_shape_fn((3, 16, 16), |(v, i, j)| {
        if v == 1 {
            0.0
        } else {
            ((i * 3 + j * 5 + v) % 11) as f32
        }
    });
    // A prediction that differs from the reference by a per-view scale is perfect after the
    // per-view normalisation; the all-zero reference view is skipped.
    let p = Array3::from_shape_fn(t.dim(), |(v, i, j)| t[[v, i, j]] * (1.0 + v as f32));
    let (ps, ss) = projection_metrics(p.view(), t.view(), &SsimParams::default()).unwrap();
    assert!(ps.is_infinite() && (ss - 1.0).abs() < 1e-12, "{ps} {ss}");
    let z = Array3::<f32>::zeros((2, 16, 16));
    assert!(projection_metrics(z.view(), z.view(), &SsimParams::default()).is_err());
}
