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
