use super::*;
use crate::geometry::{Beam, Detector, VolumeGrid};
use crate::testing::write_r2_case;
use ndarray::{Array, Array2, Array3, Array4};
use ndarray_npy::write_npy;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_yaml_ng::Value;
use std::fs;
use std::path::Path;

/// 3 channels (80/100/120 kVp), 5 views, 6 rows × 8 cols, 4³ volume; channel 2 is missing at
/// view 1; view 4 is the test view.
fn small_scene() -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let geometry = Geometry {
        beam: Beam::Cone,
        dso: 100.0,
        dsd: 150.0,
        detector: Detector {
            rows: 6,
            cols: 8,
            pitch_u: 1.0,
            pitch_v: 0.5,
            offset_u: 0.25,
            offset_v: 0.0,
        },
        volume: VolumeGrid::cube(4, 1.0),
        angles_rad: Geometry::full_turn(5),
        vectors: None,
    };
    let mut channels = vec![
        Channel::new("80kVp", SpectralCoordinate::TubeVoltage { kvp: 80.0 }),
        Channel::new("100kVp", SpectralCoordinate::TubeVoltage { kvp: 100.0 }),
        Channel::new("120kVp", SpectralCoordinate::TubeVoltage { kvp: 120.0 }),
    ];
    normalise_tau(&mut channels).unwrap();
    // Random bits patterns, plus values whose bits a lossy path would change.
    let mut projections = Array4::from_shape_fn((3, 5, 6, 8), |_| rng.random::<f32>() * 3.0);
    projections[[0, 0, 0, 0]] = -0.0;
    projections[[0, 0, 0, 1]] = f32::MIN_POSITIVE / 8.0; // subnormal
    projections[[0, 0, 0, 2]] = 1.0 + f32::EPSILON;
    let mut availability = Array2::from_elem((5, 3), true);
    availability[[1, 2]] = false;
    projections.slice_mut(ndarray::s![2, 1, .., ..]).fill(0.0);
    let references = Array4::from_shape_fn((3, 4, 4, 4), |_| rng.random::<f32>() * 0.05);
    let structural = Array3::from_shape_fn((5, 6, 8), |_| rng.random::<f32>());
    Scene {
        name: "small".into(),
        geometry,
        channels,
        projections,
        availability,
        references: Some(references),
        split: Split {
            train: vec![0, 1, 2, 3],
            test: vec![4],
        },
        provenance: Provenance {
            generator: "scene tests".into(),
            config: "seed: 7\nviews: 5\n".into(),
            source_data: vec!["random".into()],
            licence: vec!["CC0".into()],
            created_by: "tests".into(),
            axis: None,
            overrides: vec!["geometry.views=13".into()],
        },
        structural: Some(structural),
        materials: Some(MaterialMaps {
            materials: vec![
                crate::physics::Material::Water,
                crate::physics::Material::Iodine,
            ],
            fractions: Array4::from_shape_fn((2, 4, 4, 4), |_| rng.random::<f32>()),
        }),
    }
}

fn bits<D: ndarray::Dimension>(a: &Array<f32, D>) -> Vec<u32> {
    a.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn normalise_tau_maps_the_coordinate_onto_unit_interval() {
    let mut ch = vec![
        Channel::new(
            "a",
            SpectralCoordinate::Window {
                lo_kev: 20.0,
                hi_kev: 35.0,
            },
        ),
        Channel::new(
            "b",
            SpectralCoordinate::Window {
                lo_kev: 35.0,
                hi_kev: 50.0,
            },
        ),
        Channel::new(
            "c",
            SpectralCoordinate::Window {
                lo_kev: 60.0,
                hi_kev: 90.0,
            },
        ),
    ];
    normalise_tau(&mut ch).unwrap();
    let tau: Vec<f64> = ch.iter().map(|c| c.tau).collect();
    assert_eq!(tau, vec![0.0, 15.0 / 40.0, 1.0]);

    let mut one = vec![Channel::new("x", SpectralCoordinate::Energy { kev: 70.0 })];
    normalise_tau(&mut one).unwrap();
    assert_eq!(one[0].tau, 0.0);

    let mut unordered = vec![
        Channel::new("a", SpectralCoordinate::Energy { kev: 70.0 }),
        Channel::new("b", SpectralCoordinate::Energy { kev: 70.0 }),
    ];
    let err = normalise_tau(&mut unordered).unwrap_err().to_string();
    assert!(err.contains("`channels[1].coordinate`"), "{err}");

    let mut mixed = vec![
        Channel::new("a", SpectralCoordinate::Energy { kev: 70.0 }),
        Channel::new("b", SpectralCoordinate::TubeVoltage { kvp: 80.0 }),
    ];
    let err = normalise_tau(&mut mixed).unwrap_err().to_string();
    assert!(err.contains("`channels[1].coordinate`"), "{err}");
}

#[test]
fn coordinate_values_and_units() {
    let m = SpectralCoordinate::Mixing {
        lambda: 0.3,
        low_kvp: 80.0,
        high_kvp: 140.0,
    };
    assert_eq!((m.value(), m.unit()), (0.3, "λ"));
    let w = SpectralCoordinate::Window {
        lo_kev: 33.0,
        hi_kev: 40.0,
    };
    assert_eq!((w.value(), w.unit()), (33.0, "keV"));
    let yaml = serde_yaml_ng::to_string(&m).unwrap();
    assert!(yaml.contains("kind: mixing"), "{yaml}");
    assert_eq!(
        serde_yaml_ng::from_str::<SpectralCoordinate>(&yaml).unwrap(),
        m
    );
    let typo = serde_yaml_ng::from_str::<SpectralCoordinate>("{kind: energy, kev: 70, kvp: 80}");
    assert!(
        typo.unwrap_err()
            .to_string()
            .contains("unknown field `kvp`")
    );
    let err = SpectralCoordinate::Window {
        lo_kev: 40.0,
        hi_kev: 33.0,
    }
    .validate()
    .unwrap_err()
    .to_string();
    assert!(err.contains("`hi_kev`"), "{err}");
}

#[test]
fn accessors_follow_availability_and_split() {
    let s = small_scene();
    s.validate().unwrap();
    assert_eq!(s.available_channels(1), vec![0, 1]);
    assert_eq!(s.available_channels(0), vec![0, 1, 2]);
    assert_eq!(s.views_with_channel(2), vec![0, 2, 3, 4]);
    assert_eq!(s.train_views(), &[0, 1, 2, 3]);
    assert_eq!(s.test_views(), &[4]);
    assert_eq!(
        s.channel_projections(1),
        s.projections.index_axis(ndarray::Axis(0), 1)
    );
}

#[test]
fn validation_names_the_field() {
    type Mutation = Box<dyn Fn(&mut Scene)>;
    let cases: Vec<(Mutation, &str)> = vec![
        (Box::new(|s| s.geometry.dso = 0.0), "geometry.dso"),
        (Box::new(|s| s.split.test = vec![3]), "split.test[0]"),
        (Box::new(|s| s.split.train.push(9)), "split.train[4]"),
        (Box::new(|s| s.split.train.push(0)), "split.train[4]"),
        (Box::new(|s| s.channels[1].tau = 0.9), "channels[1].tau"),
        (
            Box::new(|s| s.channels[1].label = "80kVp".into()),
            "channels[1].label",
        ),
        (
            Box::new(|s| s.availability.column_mut(0).fill(false)),
            "availability",
        ),
        (
            Box::new(|s| s.projections[[1, 2, 3, 4]] = f32::INFINITY),
            "projections[1][2][3][4]",
        ),
        (
            Box::new(|s| s.references.as_mut().unwrap()[[2, 0, 1, 3]] = f32::NAN),
            "references[2][0][1][3]",
        ),
        (
            Box::new(|s| s.structural = Some(Array3::zeros((5, 6, 7)))),
            "structural",
        ),
        (
            Box::new(|s| s.references = Some(Array4::zeros((3, 4, 4, 5)))),
            "references",
        ),
    ];
    for (mutate, field) in cases {
        let mut s = small_scene();
        mutate(&mut s);
        let err = s.validate().unwrap_err().to_string();
        assert!(
            err.contains(&format!("`{field}`")),
            "{err} should name {field}"
        );
    }
}

#[test]
fn save_then_load_is_bit_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scene");
    let s = small_scene();
    s.save(&dir).unwrap();
    let back = Scene::load(&dir).unwrap();
    assert_eq!(bits(&back.projections), bits(&s.projections));
    assert_eq!(
        bits(back.references.as_ref().unwrap()),
        bits(s.references.as_ref().unwrap())
    );
    assert_eq!(
        bits(back.structural.as_ref().unwrap()),
        bits(s.structural.as_ref().unwrap())
    );
    assert_eq!(back.availability, s.availability);
    assert_eq!(back.geometry, s.geometry);
    assert_eq!(back.channels, s.channels);
    assert_eq!(back.split, s.split);
    assert_eq!(back.provenance, s.provenance);
    assert_eq!(back, s);
    // Optional arrays stay absent.
    let mut bare = small_scene();
    bare.references = None;
    bare.structural = None;
    let dir2 = tmp.path().join("bare");
    bare.save(&dir2).unwrap();
    assert!(!dir2.join("references.npy").exists());
    assert_eq!(Scene::load(&dir2).unwrap(), bare);
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn saving_over_a_scene_replaces_it_and_failures_keep_the_old_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scene");
    let old = small_scene();
    old.save(&dir).unwrap();

    let mut new = small_scene();
    new.name = "replacement".into();
    new.references = None;
    new.projections.mapv_inplace(|x| x + 1.0);
    // A failure once the new scene is written, and one after the old scene was moved aside.
    for stage in ["written", "swapped"] {
        let err = new
            .save_with(&dir, |s| {
                if s == stage {
                    Err(Error::invalid("test", format!("injected failure at {s}")))
                } else {
                    Ok(())
                }
            })
            .unwrap_err();
        assert!(err.to_string().contains(stage));
        assert_eq!(
            Scene::load(&dir).unwrap(),
            old,
            "old scene intact after {stage}"
        );
        assert_eq!(
            entries(tmp.path()),
            vec!["scene"],
            "no leftovers after {stage}"
        );
    }
    // An invalid scene is refused before anything is written.
    let mut bad = new.clone();
    bad.split.test = vec![0];
    assert!(bad.save(&dir).is_err());
    assert_eq!(Scene::load(&dir).unwrap(), old);

    new.save(&dir).unwrap();
    assert_eq!(Scene::load(&dir).unwrap(), new);
    assert!(!dir.join("references.npy").exists());
    assert_eq!(entries(tmp.path()), vec!["scene"]);

    // A target whose parent cannot be created (it is a file) fails cleanly.
    let blocker = tmp.path().join("file.txt");
    fs::write(&blocker, b"x").unwrap();
    assert!(new.save(blocker.join("scene")).is_err());
    assert_eq!(fs::read(&blocker).unwrap(), b"x");
    fs::remove_file(&blocker).unwrap();

    // A directory that is not a scene is never replaced.
    let other = tmp.path().join("photos");
    fs::create_dir(&other).unwrap();
    fs::write(other.join("cat.jpg"), b"meow").unwrap();
    let err = new.save(&other).unwrap_err().to_string();
    assert!(err.contains("not a Prism scene"), "{err}");
    assert!(other.join("cat.jpg").exists());
}

/// Save the small scene, let `edit` break it, and return the load error's message.
fn load_error(edit: impl FnOnce(&Path)) -> String {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    small_scene().save(&dir).unwrap();
    edit(&dir);
    Scene::load(&dir).unwrap_err().to_string()
}

/// Edit `scene.yaml` as a YAML value.
fn edit_yaml(dir: &Path, f: impl FnOnce(&mut Value)) {
    let path = dir.join(SCENE_FILE);
    let mut v: Value = serde_yaml_ng::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
    f(&mut v);
    fs::write(&path, serde_yaml_ng::to_string(&v).unwrap()).unwrap();
}

fn assert_names(err: &str, file: &str, field: &str) {
    assert!(err.contains(file), "`{err}` should name the file {file}");
    assert!(err.contains(field), "`{err}` should name the field {field}");
}

#[test]
fn missing_files_are_named() {
    let err = load_error(|d| fs::remove_file(d.join("scene.yaml")).unwrap());
    assert!(err.contains("scene.yaml"), "{err}");
    let err = load_error(|d| fs::remove_file(d.join("projections.npy")).unwrap());
    assert_names(&err, "projections.npy", "`arrays.projections.file`");
    let err = load_error(|d| fs::remove_file(d.join("references.npy")).unwrap());
    assert_names(&err, "references.npy", "`arrays.references.file`");
    let err = load_error(|d| {
        edit_yaml(d, |v| {
            v["arrays"]["availability"]["file"] = "../x.npy".into()
        })
    });
    assert_names(&err, "scene.yaml", "`arrays.availability.file`");
}

#[test]
fn yaml_errors_name_the_file_and_field() {
    let err = load_error(|d| {
        let p = d.join(SCENE_FILE);
        let text = fs::read_to_string(&p).unwrap();
        fs::write(&p, text.replacen("name:", "name: [", 1)).unwrap();
    });
    assert!(err.contains("scene.yaml") && err.contains("line"), "{err}");

    let err = load_error(|d| edit_yaml(d, |v| v["geometry"]["detector"]["pitch"] = 1.0.into()));
    assert_names(&err, "scene.yaml", "`geometry.detector`");
    assert!(err.contains("unknown field `pitch`"), "{err}");

    let err = load_error(|d| {
        edit_yaml(d, |v| {
            v["channels"][1]["coordinate"]["kind"] = "wavelength".into();
        })
    });
    assert_names(&err, "scene.yaml", "`channels[1].coordinate.kind`");
    assert!(err.contains("wavelength"), "{err}");

    let err = load_error(|d| edit_yaml(d, |v| v["units"]["length"] = "cm".into()));
    assert_names(&err, "scene.yaml", "`units.length`");
}

#[test]
fn geometry_errors_name_the_file_and_field() {
    let err = load_error(|d| edit_yaml(d, |v| v["geometry"]["dso"] = (-5.0).into()));
    assert_names(&err, "scene.yaml", "`geometry.dso`");
    let err = load_error(|d| edit_yaml(d, |v| v["geometry"]["detector"]["pitch_v"] = 0.0.into()));
    assert_names(&err, "scene.yaml", "`geometry.detector.pitch_v`");
    let err = load_error(|d| {
        edit_yaml(d, |v| {
            if let Value::Sequence(a) = &mut v["geometry"]["angles_rad"] {
                a.pop();
            }
        })
    });
    assert_names(&err, "scene.yaml", "`geometry.angles_rad`");
    assert!(err.contains("4 angles") && err.contains("5 views"), "{err}");
    let err = load_error(|d| {
        write_npy(
            d.join("projections.npy"),
            &Array4::<f32>::zeros((3, 4, 6, 8)),
        )
        .unwrap()
    });
    assert_names(&err, "scene.yaml", "`geometry.angles_rad`");
    assert!(err.contains("projections.npy has 4 views"), "{err}");
    let err = load_error(|d| {
        edit_yaml(d, |v| {
            v["channels"][2]["coordinate"]["kvp"] = 90.0.into();
        })
    });
    assert_names(&err, "scene.yaml", "`channels[2].coordinate`");
    let err = load_error(|d| edit_yaml(d, |v| v["split"]["test"][0] = 2.into()));
    assert_names(&err, "scene.yaml", "`split.test[0]`");
    // Per-view vectors: a scene saved with them loads back equal; a bad row is named.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut s = small_scene();
    s.geometry = crate::testing::wobbled(&s.geometry);
    s.save(&dir).unwrap();
    assert_eq!(Scene::load(&dir).unwrap().geometry, s.geometry);
    edit_yaml(&dir, |v| v["geometry"]["vectors"][3][6] = 0.0.into());
    edit_yaml(&dir, |v| v["geometry"]["vectors"][3][7] = 0.0.into());
    edit_yaml(&dir, |v| v["geometry"]["vectors"][3][8] = 0.0.into());
    let err = Scene::load(&dir).unwrap_err().to_string();
    assert_names(&err, "scene.yaml", "`geometry.vectors[3].u`");
}

#[test]
fn array_errors_name_the_file_and_field() {
    // Wrong dtype: say what was found.
    let err = load_error(|d| {
        write_npy(
            d.join("projections.npy"),
            &Array4::<f64>::zeros((3, 5, 6, 8)),
        )
        .unwrap()
    });
    assert_names(&err, "projections.npy", "`projections`");
    assert!(err.contains("<f8"), "{err}");
    // Wrong shape: expected vs found.
    let err = load_error(|d| {
        write_npy(
            d.join("references.npy"),
            &Array4::<f32>::zeros((3, 4, 5, 4)),
        )
        .unwrap()
    });
    assert_names(&err, "references.npy", "`references`");
    assert!(
        err.contains("[3, 4, 4, 4]") && err.contains("[3, 4, 5, 4]"),
        "{err}"
    );
    // NaN: file, channel and first bad index.
    let err = load_error(|d| {
        let mut s = small_scene();
        s.projections[[1, 3, 2, 5]] = f32::NAN;
        s.projections[[2, 0, 0, 0]] = f32::NAN;
        write_npy(d.join("projections.npy"), &s.projections).unwrap();
    });
    assert_names(&err, "projections.npy", "`projections[1][3][2][5]`");
    assert!(err.contains("100kVp"), "{err}");
    let err = load_error(|d| {
        let mut s = small_scene().structural.unwrap();
        s[[0, 1, 1]] = f32::NEG_INFINITY;
        write_npy(d.join("structural.npy"), &s).unwrap();
    });
    assert_names(&err, "structural.npy", "`structural[0][1][1]`");
    // Availability: u8 is accepted when 0/1; other values, and channels never available for
    // training, are errors.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("u8");
    let s = small_scene();
    s.save(&dir).unwrap();
    write_npy(dir.join("availability.npy"), &s.availability.mapv(u8::from)).unwrap();
    edit_yaml(&dir, |v| v["arrays"]["availability"]["dtype"] = "u8".into());
    assert_eq!(Scene::load(&dir).unwrap(), s);
    let err = load_error(|d| {
        let mut a = small_scene().availability.mapv(u8::from);
        a[[2, 1]] = 2;
        write_npy(d.join("availability.npy"), &a).unwrap();
    });
    assert_names(&err, "availability.npy", "`availability[2][1]`");
    let err = load_error(|d| {
        let mut a = small_scene().availability;
        a.column_mut(1).fill(false);
        write_npy(d.join("availability.npy"), &a).unwrap();
    });
    assert_names(&err, "availability.npy", "`availability`");
    let err = load_error(|d| {
        write_npy(d.join("availability.npy"), &Array2::<f32>::zeros((5, 3))).unwrap()
    });
    assert_names(&err, "availability.npy", "`availability`");
    assert!(err.contains("<f4"), "{err}");
}

#[test]
fn r2_case_loads_with_transposed_volume() {
    let tmp = tempfile::tempdir().unwrap();
    let (imgs, vol) = write_r2_case(tmp.path());
    let s = Scene::load_r2(tmp.path()).unwrap();
    assert_eq!(Scene::open(tmp.path()).unwrap(), s);
    assert_eq!(s.n_channels(), 1);
    assert_eq!(s.channels[0].label, "r2");
    assert_eq!(s.channels[0].coordinate, SpectralCoordinate::Unspecified);
    assert_eq!(s.geometry.angles_rad, vec![0.0, 1.0, 2.0, 0.5, 1.5]);
    assert_eq!(s.split.train, vec![0, 1, 2]);
    assert_eq!(s.split.test, vec![3, 4]);
    assert_eq!(
        (s.geometry.detector.pitch_u, s.geometry.detector.pitch_v),
        (0.5, 0.5)
    );
    for (k, img) in imgs.iter().enumerate() {
        assert_eq!(
            s.channel_projections(0).index_axis(ndarray::Axis(0), k),
            img
        );
    }
    let r = s.references.as_ref().unwrap();
    assert_eq!(r.shape(), &[1, 2, 3, 4]);
    for z in 0..2 {
        for y in 0..3 {
            for x in 0..4 {
                assert_eq!(r[[0, z, y, x]], vol[[x, y, z]]);
                assert_eq!(r[[0, z, y, x]], (100 * x + 10 * y + z) as f32);
            }
        }
    }
    // The imported scene saves and loads like any other.
    let out = tmp.path().join("prism");
    s.save(&out).unwrap();
    assert_eq!(Scene::load(&out).unwrap(), s);
    assert_eq!(Scene::open(&out).unwrap(), s);
}

#[test]
fn r2_errors_name_the_file_and_field() {
    let case = |edit: &dyn Fn(&Path)| {
        let tmp = tempfile::tempdir().unwrap();
        write_r2_case(tmp.path());
        edit(tmp.path());
        Scene::load_r2(tmp.path()).unwrap_err().to_string()
    };
    let err = case(&|d| fs::remove_file(d.join("proj_test/proj_test_0003.npy")).unwrap());
    assert_names(&err, "proj_test_0003.npy", "`proj_test[0].file_path`");
    let err = case(&|d| {
        write_npy(
            d.join("proj_train/proj_train_0001.npy"),
            &Array2::<f64>::zeros((6, 8)),
        )
        .unwrap()
    });
    assert_names(&err, "proj_train_0001.npy", "`proj_train[1]`");
    assert!(err.contains("<f8"), "{err}");
    let err = case(&|d| {
        write_npy(
            d.join("proj_train/proj_train_0002.npy"),
            &Array2::<f32>::zeros((8, 6)),
        )
        .unwrap()
    });
    assert_names(&err, "proj_train_0002.npy", "`proj_train[2]`");
    let err = case(&|d| write_npy(d.join("vol_gt.npy"), &Array3::<f32>::zeros((2, 3, 4))).unwrap());
    assert_names(&err, "vol_gt.npy", "`vol`");
    let err = case(&|d| {
        let p = d.join(R2_META_FILE);
        let text = fs::read_to_string(&p).unwrap();
        fs::write(&p, text.replace("\"DSO\":5.0", "\"DSO\":-5.0")).unwrap();
    });
    assert_names(&err, "meta_data.json", "`scanner.dso`");
    let err = case(&|d| fs::remove_file(d.join(R2_META_FILE)).unwrap());
    assert!(err.contains("meta_data.json"), "{err}");
}

#[test]
fn summary_reports_geometry_channels_and_ranges() {
    let s = small_scene();
    let text = s.summary();
    for needle in [
        "cone",
        "100 / 150 mm",
        "6 rows × 8 cols",
        "4 × 4 × 4 voxels",
        "5 from 0.00° to 288.00°",
        "4 train, 1 test",
        "80 kVp",
        "120kVp",
        "CC0",
    ] {
        assert!(text.contains(needle), "summary lacks `{needle}`:\n{text}");
    }
    // Channel 2: 4 available views (3 train, 1 test); projection range over those views only.
    let p2: Vec<f32> = [0, 2, 3, 4]
        .iter()
        .flat_map(|&v| s.projections.slice(ndarray::s![2, v, .., ..]).to_owned())
        .collect();
    let mean = p2.iter().map(|&x| f64::from(x)).sum::<f64>() / p2.len() as f64;
    let line = text
        .lines()
        .find(|l| l.contains("120kVp"))
        .unwrap_or_else(|| panic!("no channel line:\n{text}"));
    let cells: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(
        &cells[..7],
        &["2", "120kVp", "120", "kVp", "1.0000", "4", "3"],
        "{line}"
    );
    assert!(cells.contains(&format!("{mean:.4}").as_str()), "{line}");
    // Columns are aligned: the header's `label` starts where every label starts.
    let header = text.lines().find(|l| l.contains("label")).unwrap();
    let col = header.find("label").unwrap();
    for l in text.lines().filter(|l| l.contains("kVp  ")) {
        assert_eq!(l.find("kVp").map(|i| i >= col), Some(true));
        assert!(l[col..].starts_with(char::is_alphanumeric), "{l}");
    }
}

/// A `.npy` whose header claims far more data than the file holds is refused by name before
/// anything is allocated for it (it used to abort the process); an honest one still reads.
#[test]
fn npy_headers_claiming_more_than_the_file_holds_are_refused_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let honest = dir.path().join("honest.npy");
    write_npy(&honest, &Array3::<f32>::from_elem((2, 3, 4), 1.5)).unwrap();
    let a = npy::read_npy_f32(&honest, "volume").unwrap();
    assert_eq!(a.shape(), [2, 3, 4]);
    // A version-1 header declaring a 4 PB array, followed by 96 bytes of data.
    let mut dict =
        "{'descr': '<f4', 'fortran_order': False, 'shape': (99999, 99999, 99999), }".to_string();
    while !(10 + dict.len() + 1).is_multiple_of(64) {
        dict.push(' ');
    }
    dict.push('\n');
    let mut forged = b"\x93NUMPY\x01\x00".to_vec();
    forged.extend((dict.len() as u16).to_le_bytes());
    forged.extend(dict.as_bytes());
    forged.extend([0u8; 96]);
    let path = dir.path().join("forged.npy");
    fs::write(&path, &forged).unwrap();
    let e = npy::read_npy_f32(&path, "volume").unwrap_err().to_string();
    assert!(
        e.contains("forged.npy") && e.contains("[99999, 99999, 99999]") && e.contains("96"),
        "{e}"
    );
}
