use super::*;

fn cone() -> Geometry {
    Geometry {
        beam: Beam::Cone,
        dso: 1000.0,
        dsd: 1500.0,
        detector: Detector {
            rows: 96,
            cols: 128,
            pitch_u: 1.5,
            pitch_v: 1.25,
            offset_u: 3.0,
            offset_v: -2.0,
        },
        volume: VolumeGrid::cube(64, 2.0),
        angles_rad: Geometry::full_turn(8),
        vectors: None,
    }
}

fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
    a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= tol)
}

#[test]
fn camera_matches_the_documented_convention() {
    let g = cone();
    for view in 0..g.views() {
        let th = g.angles_rad[view];
        let cam = g.camera(view);
        // The source is the camera origin.
        assert!(close(cam.to_world([0.0; 3]), g.source(view), 1e-9));
        // The isocentre lies on z_c at depth DSO.
        assert!(close(cam.to_camera([0.0; 3]), [0.0, 0.0, 1000.0], 1e-9));
        // Columns run along (−sin θ, cos θ, 0); rows run along −z.
        let u = cam.dir_to_world([1.0, 0.0, 0.0]);
        let v = cam.dir_to_world([0.0, 1.0, 0.0]);
        assert!(close(u, [-th.sin(), th.cos(), 0.0], 1e-12));
        assert!(close(v, [0.0, 0.0, -1.0], 1e-12));
    }
}

#[test]
fn pixel_centres_follow_the_offsets() {
    let g = cone();
    let cam = g.camera(0);
    // Pixel (row r, col c) sits at u = (c + ½ − cols/2)·pu + off_u, v = (r + ½ − rows/2)·pv + off_v.
    let (r, c) = (10.0, 100.0);
    let p = cam.pixel_camera(c, r);
    let u = (c + 0.5 - 64.0) * 1.5 + 3.0;
    let v = (r + 0.5 - 48.0) * 1.25 - 2.0;
    assert!(close(p, [u, v, 1500.0], 1e-9), "{p:?} vs {u} {v}");
    // At θ = 0 the detector plane is x = −(DSD − DSO), u along +y, v along −z.
    let w = cam.to_world(p);
    assert!(close(w, [-500.0, u, -v], 1e-9), "{w:?}");
}

#[test]
fn isocentre_projects_to_the_detector_centre_less_the_offset() {
    let g = cone();
    let cam = g.camera(3);
    let [col, row] = cam.project([0.0; 3]).unwrap();
    assert!((col - (63.5 - 2.0)).abs() < 1e-9);
    assert!((row - (47.5 + 1.6)).abs() < 1e-9);
}

#[test]
fn top_of_the_volume_lands_on_low_rows() {
    let g = cone();
    let cam = g.camera(0);
    let top = cam.project([0.0, 0.0, 50.0]).unwrap();
    let bottom = cam.project([0.0, 0.0, -50.0]).unwrap();
    assert!(top[1] < bottom[1]);
}

#[test]
fn parallel_rays_are_parallel_and_span_the_physical_detector() {
    let mut g = cone();
    g.beam = Beam::Parallel;
    g.detector.offset_u = 0.0;
    g.detector.offset_v = 0.0;
    let cam = g.camera(0);
    let a = cam.pixel_ray(0.0, 0.0);
    let b = cam.pixel_ray(127.0, 95.0);
    assert!(close(a.direction, b.direction, 1e-12));
    // Column 0 at u = −(cols/2 − ½)·pitch.
    assert!((a.origin[1] - (-63.5 * 1.5)).abs() < 1e-9, "{a:?}");
    assert!((a.length - 1500.0).abs() < 1e-9);
}

#[test]
fn voxel_centres_and_indices_are_inverse() {
    let mut grid = VolumeGrid::cube(5, 2.0);
    grid.offset = [1.0, -2.0, 0.5];
    let c = grid.voxel_centre(0, 2, 4);
    assert!(close(c, [1.0 - 4.0, -2.0, 0.5 + 4.0], 1e-12));
    assert!(close(grid.world_to_index(c), [0.0, 2.0, 4.0], 1e-12));
}

#[test]
fn uniform_angles_exclude_the_endpoint() {
    let a = Geometry::full_turn(4);
    assert_eq!(a.len(), 4);
    assert!((a[3] - 1.5 * PI).abs() < 1e-15);
}

#[test]
fn validation_names_the_field() {
    type Mutation = Box<dyn Fn(&mut Geometry)>;
    let cases: Vec<(Mutation, &str)> = vec![
        (Box::new(|g| g.dso = -1.0), "dso"),
        (Box::new(|g| g.dsd = 900.0), "dsd"),
        (Box::new(|g| g.detector.pitch_u = 0.0), "detector.pitch_u"),
        (Box::new(|g| g.detector.rows = 0), "detector.rows"),
        (Box::new(|g| g.volume.dz = f64::NAN), "volume.dz"),
        (Box::new(|g| g.angles_rad.clear()), "angles_rad"),
        (
            Box::new(|g| g.angles_rad[2] = f64::INFINITY),
            "angles_rad[2]",
        ),
        (
            Box::new(|g| g.volume = VolumeGrid::cube(64, 40.0)),
            "volume",
        ),
    ];
    for (mutate, field) in cases {
        let mut g = cone();
        mutate(&mut g);
        let err = g.validate().unwrap_err().to_string();
        assert!(
            err.contains(&format!("`{field}`")),
            "{err} should name {field}"
        );
    }
}

#[test]
fn r2_scanner_converts_and_keeps_the_camera() {
    let json = r#"{"mode":"cone","DSD":7.0,"DSO":5.0,"nDetector":[64,48],"sDetector":[4.0,3.0],
        "nVoxel":[32,32,16],"sVoxel":[2.0,2.0,1.0],"offOrigin":[0,0,0],"offDetector":[0,0],
        "accuracy":0.5,"totalAngle":360,"startAngle":0}"#;
    let s: R2Scanner = serde_json::from_str(json).unwrap();
    let g = s.to_geometry(vec![0.0, 1.0]).unwrap();
    assert_eq!((g.detector.rows, g.detector.cols), (64, 48));
    assert!((g.detector.pitch_u - 3.0 / 48.0).abs() < 1e-15);
    assert!((g.detector.pitch_v - 4.0 / 64.0).abs() < 1e-15);
    assert_eq!((g.volume.nx, g.volume.nz), (32, 16));
    assert!((g.volume.dz - 1.0 / 16.0).abs() < 1e-15);
    // R²-Gaussian: f_x = DSD / dDet_u, principal point at (W − 1)/2.
    let cam = g.camera(1);
    assert!((cam.fx - 7.0 / (3.0 / 48.0)).abs() < 1e-9);
    assert!((cam.cx - 23.5).abs() < 1e-12);
}

#[test]
fn tigre_fields_convert_with_flipped_v() {
    let t = TigreGeometry {
        mode: "cone".into(),
        DSD: 1536.0,
        DSO: 1000.0,
        nDetector: [100, 120],
        dDetector: [0.8, 0.9],
        offDetector: [4.0, -6.0],
        nVoxel: [30, 40, 50],
        dVoxel: [1.0, 2.0, 3.0],
        offOrigin: [7.0, 8.0, 9.0],
    };
    let g = t.to_geometry(vec![0.0]).unwrap();
    assert_eq!((g.detector.rows, g.detector.cols), (100, 120));
    assert_eq!((g.detector.pitch_v, g.detector.pitch_u), (0.8, 0.9));
    assert_eq!((g.detector.offset_u, g.detector.offset_v), (-6.0, -4.0));
    assert_eq!((g.volume.nx, g.volume.ny, g.volume.nz), (50, 40, 30));
    assert_eq!(g.volume.offset, [9.0, 8.0, 7.0]);
    assert_eq!((g.volume.dx, g.volume.dz), (3.0, 1.0));
}

#[test]
fn yaml_round_trip() {
    let g = cone();
    let text = serde_yaml_ng::to_string(&g).unwrap();
    let back: Geometry = serde_yaml_ng::from_str(&text).unwrap();
    assert_eq!(g, back);
}

// ---- per-view vectors ----

fn parallel() -> Geometry {
    Geometry {
        beam: Beam::Parallel,
        ..cone()
    }
}

/// A fan beam: the middle row of a cone beam over a one-voxel slice.
fn fan() -> Geometry {
    let mut g = cone();
    g.detector.rows = 1;
    g.detector.offset_v = 0.0;
    g.volume.nz = 1;
    g
}

fn cameras_close(a: &Camera, b: &Camera, tol: f64) -> Result<(), String> {
    let pairs = [
        (a.fx, b.fx),
        (a.fy, b.fy),
        (a.cx, b.cx),
        (a.cy, b.cy),
        (a.sdd, b.sdd),
    ];
    let mut worst: f64 = 0.0;
    for (x, y) in pairs {
        worst = worst.max((x - y).abs() / x.abs().max(1.0));
    }
    for k in 0..3 {
        worst = worst.max((a.translation[k] - b.translation[k]).abs() / 1000.0);
        for j in 0..3 {
            worst = worst.max((a.rotation[k][j] - b.rotation[k][j]).abs());
        }
    }
    if worst <= tol && a.projection == b.projection && (a.rows, a.cols) == (b.rows, b.cols) {
        Ok(())
    } else {
        Err(format!("{a:?}\nvs\n{b:?}\n(worst {worst:e})"))
    }
}

/// Pixel (r, c) at `d + (c + ½ − cols/2)·u + (r + ½ − rows/2)·v` (the module's convention).
fn pixel_centre(w: &ViewVectors, rows: usize, cols: usize, c: f64, r: f64) -> [f64; 3] {
    let (a, b) = (c + 0.5 - cols as f64 / 2.0, r + 0.5 - rows as f64 / 2.0);
    [0, 1, 2].map(|k| w.detector[k] + a * w.u[k] + b * w.v[k])
}

#[test]
fn circular_scans_convert_to_vectors_exactly() {
    // Rounding only: the cameras agree to 1e-12 (relative; rotations absolute).
    for g in [cone(), parallel(), fan()] {
        let w = g.to_vectors();
        let held = Geometry {
            vectors: Some(w.clone()),
            ..g.clone()
        };
        held.validate().unwrap();
        for v in 0..g.views() {
            cameras_close(&g.camera(v), &held.camera(v), 1e-12).unwrap();
        }
        // The nominal fields come back from the vectors alone.
        let d = &g.detector;
        let n = Geometry::from_vectors(g.beam, d.rows, d.cols, g.volume.clone(), w, None).unwrap();
        for (a, b) in n.angles_rad.iter().zip(&g.angles_rad) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        assert!((n.detector.pitch_u - d.pitch_u).abs() < 1e-12);
        assert!((n.detector.pitch_v - d.pitch_v).abs() < 1e-12);
        if g.beam == Beam::Cone {
            assert!((n.dso - g.dso).abs() < 1e-9 && (n.dsd - g.dsd).abs() < 1e-9);
            for v in 0..g.views() {
                cameras_close(&g.camera(v), &n.camera(v), 1e-12).unwrap();
            }
        }
        // Parallel: another start plane, the same rays.
        for v in 0..g.views() {
            let (a, b) = (g.camera(v), n.camera(v));
            for (c, r) in [(0.0, 0.0), (100.0, 0.0), (37.0, 0.0)] {
                let (ra, rb) = (a.pixel_ray(c, r), b.pixel_ray(c, r));
                let end = |x: &Ray| [0, 1, 2].map(|k| x.origin[k] + x.length * x.direction[k]);
                assert!(close(end(&ra), end(&rb), 1e-9), "{ra:?} vs {rb:?}");
                assert!(close(ra.direction, rb.direction, 1e-12));
            }
        }
    }
}

#[test]
fn cameras_follow_the_vectors_of_a_disturbed_scan() {
    // Independent of the camera's construction: each pixel's ray ends on the pixel centre the
    // vectors place, starts at the source (cone) or runs along the rays (parallel), and the
    // pixel centre projects back to its (column, row).
    for g in [cone(), parallel()] {
        let g = crate::testing::wobbled(&g);
        let (rows, cols) = (g.detector.rows, g.detector.cols);
        for (v, wv) in g.vectors.iter().flatten().enumerate() {
            let cam = g.camera(v);
            for (c, r) in [(0.0, 0.0), (127.0, 95.0), (40.0, 71.0)] {
                let p = pixel_centre(wv, rows, cols, c, r);
                let ray = cam.pixel_ray(c, r);
                let end = [0, 1, 2].map(|k| ray.origin[k] + ray.length * ray.direction[k]);
                let uv = cam.project(p).unwrap();
                assert!(
                    (uv[0] - c).abs() < 1e-9 && (uv[1] - r).abs() < 1e-9,
                    "{uv:?}"
                );
                match g.beam {
                    Beam::Cone => {
                        assert!(close(end, p, 1e-9), "{end:?} vs {p:?}");
                        assert!(close(ray.origin, wv.source, 1e-9));
                    }
                    Beam::Parallel => {
                        let n = wv.source.iter().map(|x| x * x).sum::<f64>().sqrt();
                        assert!(close(ray.direction, wv.source.map(|x| x / n), 1e-12));
                        // The pixel centre lies on the ray.
                        let off = [0, 1, 2].map(|k| p[k] - ray.origin[k]);
                        let t: f64 = (0..3).map(|k| off[k] * ray.direction[k]).sum();
                        let foot = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k]);
                        assert!(close(foot, p, 1e-9), "{foot:?} vs {p:?}");
                    }
                }
            }
        }
        // A disturbed scan keeps its derived angles continuous and near the circular ones.
        for (a, b) in g.angles_rad.iter().zip(&Geometry::full_turn(8)) {
            assert!((a - b).abs() < 0.1, "{a} vs {b}");
        }
    }
}

#[test]
fn bad_vectors_are_refused_naming_the_view_and_part() {
    type Mutation = Box<dyn Fn(&mut Vec<ViewVectors>)>;
    let rot = |a: [f64; 3], b: [f64; 3], deg: f64| {
        // Turn `a` by `deg` towards `b` (both perpendicular, |a| kept).
        let (s, c) = deg.to_radians().sin_cos();
        let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
        let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        [0, 1, 2].map(|k| a[k] * c + b[k] / nb * na * s)
    };
    let cases: Vec<(Beam, Mutation, &str, &str)> = vec![
        (
            Beam::Cone,
            Box::new(move |w| w[2].v = rot(w[2].v, w[2].u, 1.0)),
            "vectors[2].v",
            "perpendicular",
        ),
        (
            Beam::Cone,
            Box::new(|w| w[0].u = [0.0; 3]),
            "vectors[0].u",
            "zero",
        ),
        (
            Beam::Cone,
            Box::new(|w| w[5].u = w[5].u.map(|x| -x)),
            "vectors[5].u",
            "mirrored",
        ),
        (
            Beam::Cone,
            Box::new(|w| w[1].detector[0] = f64::NAN),
            "vectors[1].detector[0]",
            "finite",
        ),
        (
            Beam::Cone,
            Box::new(|w| w[3].source = [0.0, 0.0, 10.0]),
            "vectors[3].source",
            "source",
        ),
        (
            Beam::Cone,
            Box::new(|w| w[4].detector = [0.0, 0.0, 0.0]),
            "vectors[4].detector",
            "cuts the volume",
        ),
        (
            Beam::Parallel,
            Box::new(|w| w[6].u = w[6].source),
            "vectors[6].u",
            "along the rays",
        ),
        (
            Beam::Parallel,
            Box::new(|w| w[7].source = [0.0; 3]),
            "vectors[7].source",
            "zero",
        ),
    ];
    for (beam, mutate, field, words) in cases {
        let g = Geometry { beam, ..cone() };
        let mut w = g.to_vectors();
        mutate(&mut w);
        let held = Geometry {
            vectors: Some(w.clone()),
            ..g.clone()
        };
        let d = &g.detector;
        for err in [
            held.validate().unwrap_err(),
            Geometry::from_vectors(beam, d.rows, d.cols, g.volume.clone(), w, None).unwrap_err(),
        ] {
            let err = err.to_string();
            assert!(
                err.contains(&format!("`{field}`")) && err.contains(words),
                "{err} should name {field} and say {words}"
            );
        }
    }
    // One row of vectors per angle.
    let mut g = cone();
    g.vectors = Some(g.to_vectors());
    g.angles_rad.pop();
    assert!(g.validate().unwrap_err().to_string().contains("`vectors`"));
}

#[test]
fn vectors_are_stored_as_astra_rows() {
    let g = crate::testing::wobbled(&cone());
    let text = serde_yaml_ng::to_string(&g).unwrap();
    let back: Geometry = serde_yaml_ng::from_str(&text).unwrap();
    assert_eq!(g, back);
    // A row is (source, detector centre, u, v).
    let w = g.vectors.as_ref().unwrap()[3];
    let row: [f64; 12] = w.into();
    assert_eq!(ViewVectors::from(row), w);
    assert_eq!(row[6..9], w.u);
    let value: serde_yaml_ng::Value = serde_yaml_ng::from_str(&text).unwrap();
    assert_eq!(value["vectors"][3].as_sequence().unwrap().len(), 12);
    // A circular geometry writes no `vectors` key (scenes from before read unchanged).
    assert!(
        !serde_yaml_ng::to_string(&cone())
            .unwrap()
            .contains("vectors")
    );
}
