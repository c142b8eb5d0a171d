use super::*;
use ndarray::{Array2, Array3};
use ndarray_npy::WriteNpyExt;
use std::fs::File;

fn write_npy<T: WriteNpyExt>(dir: &Path, name: &str, a: &T) -> std::path::PathBuf {
    let path = dir.join(name);
    a.write_npy(File::create(&path).unwrap()).unwrap();
    path
}

fn get(c: &[(Material, f64)], m: Material) -> f64 {
    c.iter().find(|(n, _)| *n == m).map_or(0.0, |p| p.1)
}

/// HU of a composition at 70 keV from the table values (affine in the fractions).
fn hu_of(c: &[(Material, f64)]) -> f64 {
    let mu = get(c, Material::Water) * MU70_WATER
        + get(c, Material::Air) * MU70_AIR
        + get(c, Material::CorticalBone) * MU70_CORTICAL_BONE
        + get(c, Material::Iodine) * MU70_IODINE;
    1000.0 * (mu / MU70_WATER - 1.0)
}

#[test]
fn loads_int16_and_reproduces_a_linear_ramp_along_z() {
    let dir = tempfile::tempdir().unwrap();
    // 6 slices of 3 mm, 4 × 5 in-plane voxels of 1.5 mm; HU = 100·z − 500 plus an in-plane tag.
    let a = Array3::<i16>::from_shape_fn((6, 4, 5), |(z, y, x)| {
        100 * z as i16 - 500 + (y * 5 + x) as i16
    });
    let path = write_npy(dir.path(), "ramp.npy", &a);
    let v = HuVolume::load(&path, [3.0, 1.5, 1.5]).unwrap();
    assert_eq!(v.hu.dim(), (6, 4, 5));
    assert_eq!(v.hu[[5, 3, 4]], 19.0);
    let iso = v.isotropic_z();
    assert_eq!(iso.voxel_zyx, [1.5, 1.5, 1.5]);
    assert_eq!(iso.hu.dim(), (12, 4, 5));
    // New slice i sits at old continuous index k = i/2 − 1/4; linear interpolation reproduces
    // the ramp wherever k ∈ [0, 5]; the outer half slices repeat the edge slice.
    for i in 0..12 {
        let k = (i as f64 / 2.0 - 0.25).clamp(0.0, 5.0);
        for y in 0..4 {
            for x in 0..5 {
                let want = 100.0 * k - 500.0 + (y * 5 + x) as f64;
                assert!((iso.hu[[i, y, x]] as f64 - want).abs() < 1e-4, "slice {i}");
            }
        }
    }
    // Trilinear resampling onto the volume's own grid is the identity; onto a grid shifted by
    // half a voxel in x it averages neighbours; beyond the volume it is air.
    let own = iso.resample(&iso.grid()).unwrap();
    assert_eq!(own, iso.hu);
    let mut g = iso.grid();
    g.offset = [0.75, 0.0, 0.0];
    let half = iso.resample(&g).unwrap();
    assert!((half[[3, 2, 1]] - 0.5 * (iso.hu[[3, 2, 1]] + iso.hu[[3, 2, 2]])).abs() < 1e-4);
    g.offset = [100.0, 0.0, 0.0];
    assert!(iso.resample(&g).unwrap().iter().all(|&h| h == AIR_HU));
    // The covering cube: 12 × 1.5 = 18 mm is the largest extent.
    let cube = iso.cube_grid(9).unwrap();
    assert_eq!((cube.nx, cube.dx), (9, 2.0));
}

#[test]
fn maps_hu_to_the_documented_fractions() {
    let m = HuMapping::default();
    let air = m.composition(-1000.0);
    assert_eq!(
        air,
        vec![
            (Material::Water, 0.0),
            (Material::Air, 1.0),
            (Material::CorticalBone, 0.0)
        ]
    );
    let water = m.composition(0.0);
    assert_eq!(get(&water, Material::Water), 1.0);
    assert_eq!(
        get(&water, Material::Air) + get(&water, Material::CorticalBone),
        0.0
    );
    // Soft range: water 1 + HU/1000.
    for h in [-150.0, 40.0, 199.0] {
        let c = m.composition(h);
        assert!((get(&c, Material::Water) - (1.0 + h / 1000.0)).abs() < 1e-12);
    }
    // 1000 HU: s = (1000 − 200)/(1559.1 − 200) of bone, the rest water at density 1.2.
    let bone_hu = HuMapping::bone_hu();
    assert!((bone_hu - 1559.1).abs() < 0.05, "{bone_hu}");
    let s = 800.0 / (bone_hu - 200.0);
    let c = m.composition(1000.0);
    assert!((get(&c, Material::CorticalBone) - s).abs() < 1e-12);
    assert!((get(&c, Material::Water) - 1.2 * (1.0 - s)).abs() < 1e-12);
    // Every HU from air to dense bone is reproduced at the calibration energy.
    for h in (-998..=3000).step_by(7) {
        let h = h as f64;
        assert!((hu_of(&m.composition(h)) - h).abs() < 1e-9, "{h}");
    }
    // Lung at −800 HU: air–water mixture between −998.9 and −200.
    let lung = m.composition(-800.0);
    let t = (-800.0 - HuMapping::air_hu()) / (-200.0 - HuMapping::air_hu());
    assert!((get(&lung, Material::Air) - (1.0 - t)).abs() < 1e-12);
    assert!((get(&lung, Material::Water) - 0.8 * t).abs() < 1e-12);
}

#[test]
fn iodine_window_gives_contrast_tissue_iodine() {
    let m = HuMapping {
        iodine_contrast: true,
        ..HuMapping::default()
    };
    m.validate().unwrap();
    assert_eq!(m.materials().last(), Some(&Material::Iodine));
    let c = m.composition(250.0);
    assert!((get(&c, Material::Water) - 1.1).abs() < 1e-12);
    let iodine = get(&c, Material::Iodine);
    assert!((iodine - 150.0 * 0.192853 / (1000.0 * 24.7269)).abs() < 1e-15);
    // ≈ 26 HU per mg/mL of iodine: 150 HU of excess is ≈ 5.8 mg/mL.
    let mg_ml = iodine * 4930.0;
    assert!((mg_ml - 5.77).abs() < 0.01, "{mg_ml}");
    for h in (-998..=3000).step_by(11) {
        let h = h as f64;
        assert!((hu_of(&m.composition(h)) - h).abs() < 1e-9, "{h}");
    }
    assert_eq!(get(&m.composition(90.0), Material::Iodine), 0.0);
    let bad = HuMapping {
        iodine_window_hu: [300.0, 200.0],
        ..m
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("iodine_window_hu[1]")
    );
    let bad = HuMapping {
        air_below_hu: -1200.0,
        ..HuMapping::default()
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("air_below_hu")
    );
}

#[test]
fn fraction_volumes_on_a_grid() {
    let hu = Array3::from_shape_fn((2, 3, 4), |(z, y, x)| {
        [-1000.0, 0.0, 1000.0][(z + y + x) % 3]
    });
    let m = HuMapping::default();
    let vols = m.fractions(&hu).unwrap();
    assert_eq!(vols.len(), 3);
    for ((z, y, x), &h) in hu.indexed_iter() {
        let c = m.composition(h as f64);
        for (k, (mat, vol)) in vols.iter().enumerate() {
            assert_eq!(c[k].0, *mat);
            assert_eq!(vol[[z, y, x]], c[k].1 as f32);
        }
    }
    // End to end from a file.
    let dir = tempfile::tempdir().unwrap();
    let a = Array3::<i16>::from_elem((4, 4, 4), 0);
    let path = write_npy(dir.path(), "water.npy", &a);
    let grid = VolumeGrid::cube(8, 1.0); // covers the 4 mm cube and 2 mm of air around it
    let vols = hu_material_volumes(&path, [1.0; 3], &grid, &m).unwrap();
    let water = &vols[0].1;
    assert_eq!(vols[0].0, Material::Water);
    assert_eq!(water[[4, 4, 4]], 1.0);
    assert_eq!(water[[0, 4, 4]], 0.0);
    assert_eq!(vols[1].1[[0, 4, 4]], 1.0);
}

#[test]
fn load_errors_name_the_file_dtype_and_shape() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.npy");
    let e = HuVolume::load(&missing, [1.0; 3]).unwrap_err().to_string();
    assert!(e.contains("nope.npy"), "{e}");
    let f64_path = write_npy(dir.path(), "float.npy", &Array3::<f64>::zeros((2, 2, 2)));
    let e = HuVolume::load(&f64_path, [1.0; 3]).unwrap_err().to_string();
    assert!(
        e.contains("float.npy") && e.contains("<f8") && e.contains("dtype"),
        "{e}"
    );
    let flat = write_npy(dir.path(), "flat.npy", &Array2::<i16>::zeros((3, 3)));
    let e = HuVolume::load(&flat, [1.0; 3]).unwrap_err().to_string();
    assert!(e.contains("flat.npy") && e.contains("2-D"), "{e}");
    let ok = write_npy(dir.path(), "ok.npy", &Array3::<i16>::zeros((2, 2, 2)));
    let e = HuVolume::load(&ok, [1.0, 0.0, 1.0])
        .unwrap_err()
        .to_string();
    assert!(e.contains("ok.npy") && e.contains("voxel_zyx[1]"), "{e}");
    let empty = write_npy(dir.path(), "empty.npy", &Array3::<i16>::zeros((0, 2, 2)));
    let e = HuVolume::load(&empty, [1.0; 3]).unwrap_err().to_string();
    assert!(e.contains("empty.npy") && e.contains("empty"), "{e}");
    assert!(
        HuVolume::new(Array3::zeros((1, 1, 1)), [1.0; 3])
            .unwrap()
            .cube_grid(0)
            .is_err()
    );
}
