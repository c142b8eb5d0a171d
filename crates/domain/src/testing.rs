//! Test-only analytic truth: axis-aligned ellipsoids, their exact chord integrals and
//! supersampled voxelisation, and small test geometries.

use crate::geometry::{Beam, Detector, Geometry, VolumeGrid};
use ndarray::{Array2, Array3};
use ndarray_npy::write_npy;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// A scene config (YAML) of the built-in phantom (radius 110 mm, cone beam, DSO 1000 mm, DSD
/// 1500 mm, a 512 mm detector) with `views` training and 2 test views, an `n`³ grid of 256 mm and
/// a `det`² detector, one monoenergetic channel per entry of `kevs`.
pub fn phantom_config_yaml(name: &str, views: usize, n: usize, det: usize, kevs: &[u32]) -> String {
    let channels: String = kevs
        .iter()
        .map(|k| format!("  - {{ kind: mono, kev: {k} }}\n"))
        .collect();
    format!(
        "name: {name}\ngeometry:\n  beam: cone\n  dso: 1000.0\n  dsd: 1500.0\n  \
         detector: {{ rows: {det}, cols: {det}, size_mm: [512.0, 512.0] }}\n  \
         volume: {{ n: {n}, size_mm: 256.0 }}\n  views: {views}\n  test_views: 2\n\
         object:\n  phantom: {{ radius_mm: 110.0 }}\nchannels:\n{channels}"
    )
}

/// Axis-aligned ellipsoid of constant density `rho` (mm⁻¹).
#[derive(Clone, Copy, Debug)]
pub struct Ellipsoid {
    pub centre: [f64; 3],
    pub axes: [f64; 3],
    pub rho: f64,
}

impl Ellipsoid {
    /// ∫ ρ over the segment `o + t·d`, t ∈ [0, len] (|d| = 1): map to the unit sphere and solve
    /// the quadratic (Kak & Slaney; the reference's §3).
    pub fn chord(&self, o: [f64; 3], d: [f64; 3], len: f64) -> f64 {
        let s: Vec<f64> = (0..3)
            .map(|k| (o[k] - self.centre[k]) / self.axes[k])
            .collect();
        let e: Vec<f64> = (0..3).map(|k| d[k] / self.axes[k]).collect();
        let a: f64 = e.iter().map(|x| x * x).sum();
        let b: f64 = s.iter().zip(&e).map(|(x, y)| x * y).sum();
        let c: f64 = s.iter().map(|x| x * x).sum::<f64>() - 1.0;
        let disc = b * b - a * c;
        if disc <= 0.0 {
            return 0.0;
        }
        let r = disc.sqrt();
        let (t0, t1) = ((-b - r) / a, (-b + r) / a);
        self.rho * (t1.min(len) - t0.max(0.0)).max(0.0)
    }

    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3)
            .map(|k| ((p[k] - self.centre[k]) / self.axes[k]).powi(2))
            .sum::<f64>()
            <= 1.0
    }
}

/// A small phantom: a body ellipsoid with two inserts (densities add).
pub fn phantom(scale: f64) -> Vec<Ellipsoid> {
    vec![
        Ellipsoid {
            centre: [0.0, 0.0, 0.0],
            axes: [0.8 * scale, 0.65 * scale, 0.7 * scale],
            rho: 0.02,
        },
        Ellipsoid {
            centre: [0.3 * scale, 0.1 * scale, 0.1 * scale],
            axes: [0.2 * scale, 0.25 * scale, 0.3 * scale],
            rho: 0.01,
        },
        Ellipsoid {
            centre: [-0.3 * scale, -0.15 * scale, -0.2 * scale],
            axes: [0.15 * scale, 0.15 * scale, 0.2 * scale],
            rho: 0.03,
        },
    ]
}

/// Exact projections `[view][row][col]` of a set of ellipsoids.
pub fn analytic_projections(g: &Geometry, objs: &[Ellipsoid]) -> Array3<f32> {
    let d = &g.detector;
    let mut out = Array3::zeros((g.views(), d.rows, d.cols));
    for v in 0..g.views() {
        let cam = g.camera(v);
        for r in 0..d.rows {
            for c in 0..d.cols {
                let ray = cam.pixel_ray(c as f64, r as f64);
                out[[v, r, c]] = objs
                    .iter()
                    .map(|e| e.chord(ray.origin, ray.direction, ray.length))
                    .sum::<f64>() as f32;
            }
        }
    }
    out
}

/// Mean density over each voxel, by `ss³` point samples.
pub fn voxelise(grid: &VolumeGrid, objs: &[Ellipsoid], ss: usize) -> Array3<f32> {
    Array3::from_shape_fn(grid.shape_zyx(), |(iz, iy, ix)| {
        let c = grid.voxel_centre(ix, iy, iz);
        let mut acc = 0.0;
        for a in 0..ss {
            for b in 0..ss {
                for e in 0..ss {
                    let f = |i: usize| (i as f64 + 0.5) / ss as f64 - 0.5;
                    let p = [
                        c[0] + f(a) * grid.dx,
                        c[1] + f(b) * grid.dy,
                        c[2] + f(e) * grid.dz,
                    ];
                    acc += objs
                        .iter()
                        .filter(|o| o.contains(p))
                        .map(|o| o.rho)
                        .sum::<f64>();
                }
            }
        }
        (acc / (ss * ss * ss) as f64) as f32
    })
}

/// Test geometry: `n³` grid of 1 mm voxels, `det²` detector, `views` over a full turn, with
/// detector and volume offsets when `offsets`.
pub fn geometry(beam: Beam, n: usize, det: usize, views: usize, offsets: bool) -> Geometry {
    let o = if offsets { 1.0 } else { 0.0 };
    let pitch = match beam {
        Beam::Cone => 1.6 * n as f64 / det as f64 * 1.2,
        Beam::Parallel => 1.2 * n as f64 / det as f64 * 1.2,
    };
    Geometry {
        beam,
        dso: 8.0 * n as f64,
        dsd: 12.0 * n as f64,
        detector: Detector {
            rows: det,
            cols: det,
            pitch_u: pitch,
            pitch_v: pitch * 0.9,
            offset_u: 0.7 * o,
            offset_v: -0.4 * o,
        },
        volume: VolumeGrid {
            nx: n,
            ny: n,
            nz: n,
            dx: 1.0,
            dy: 1.0,
            dz: 1.0,
            offset: [0.3 * o, -0.25 * o, 0.2 * o],
        },
        angles_rad: Geometry::full_turn(views),
        vectors: None,
    }
}

/// `g` with every view's pose disturbed as real scanners are, as per-view vectors: the source
/// wobbling along z (cone; a parallel beam's rays tilting out of the plane, its detector kept
/// across them), the detector turned
/// within its plane (up to 2.3°) and tilted out of it (1.7° about its rows), and shifted along u and
/// v. Deterministic in the view index; the angles are derived from the vectors.
pub fn wobbled(g: &Geometry) -> Geometry {
    use crate::geometry::{cross, dot, rotate, unit};
    let unit = |a: [f64; 3]| unit(a).expect("non-zero");
    let vectors = g
        .to_vectors()
        .into_iter()
        .enumerate()
        .map(|(k, mut w)| {
            let k = k as f64;
            let less = |a: [f64; 3], e: [f64; 3]| {
                let t = dot(a, e);
                [0, 1, 2].map(|k| a[k] - t * e[k])
            };
            match g.beam {
                Beam::Cone => w.source[2] += 3.0 * k.sin(),
                Beam::Parallel => {
                    // Tilted rays meet a detector across them (one tilted against the rays
                    // would have skewed pixels across them, which vectors may not describe).
                    w.source[2] += 0.03 * k.sin();
                    let r = unit(w.source);
                    w.u = less(w.u, r);
                    w.v = less(less(w.v, r), unit(w.u));
                }
            }
            let (eu, ev) = (unit(w.u), unit(w.v));
            let normal = cross(eu, ev);
            let spin = 0.04 * (1.3 * k).cos();
            w.u = rotate(w.u, normal, spin);
            w.v = rotate(w.v, normal, spin);
            let tilt = 0.03;
            w.u = rotate(w.u, unit(w.v), tilt);
            let (eu, ev) = (unit(w.u), unit(w.v));
            w.detector = [0, 1, 2].map(|a| {
                w.detector[a] + 0.7 * (2.0 * k).sin() * eu[a] + 0.4 * (0.7 * k).cos() * ev[a]
            });
            w
        })
        .collect();
    let d = &g.detector;
    Geometry::from_vectors(g.beam, d.rows, d.cols, g.volume.clone(), vectors, None)
        .expect("a valid disturbed geometry")
}

/// Uniform random array in [−1, 1), seeded.
pub fn random(shape: [usize; 3], seed: u64) -> Array3<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    Array3::from_shape_simple_fn(shape, || rng.random_range(-1.0f32..1.0))
}

/// Relative L2 error ‖a − b‖ / ‖b‖.
pub fn rel_l2(a: &Array3<f32>, b: &Array3<f32>) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

/// An R²-Gaussian case: 3 train + 2 test views of 6×8, a 4×3×2 `[x][y][z]` volume.
pub fn write_r2_case(dir: &Path) -> (Vec<Array2<f32>>, Array3<f32>) {
    std::fs::create_dir_all(dir.join("proj_train")).unwrap();
    std::fs::create_dir_all(dir.join("proj_test")).unwrap();
    let angles = [0.0, 1.0, 2.0, 0.5, 1.5];
    let mut imgs = Vec::new();
    let mut list = |name: &str, range: std::ops::Range<usize>| -> Vec<serde_json::Value> {
        range
            .map(|k| {
                let img = Array2::from_shape_fn((6, 8), |(r, c)| (k * 100 + r * 10 + c) as f32);
                let path = format!("{name}/{name}_{k:04}.npy");
                write_npy(dir.join(&path), &img).unwrap();
                imgs.push(img);
                serde_json::json!({"file_path": path, "angle": angles[k]})
            })
            .collect()
    };
    let train = list("proj_train", 0..3);
    let test = list("proj_test", 3..5);
    let vol = Array3::from_shape_fn((4, 3, 2), |(x, y, z)| (100 * x + 10 * y + z) as f32);
    write_npy(dir.join("vol_gt.npy"), &vol).unwrap();
    let meta = serde_json::json!({
        "scanner": {"mode": "cone", "DSD": 7.0, "DSO": 5.0, "nDetector": [6, 8],
                    "sDetector": [3.0, 4.0], "nVoxel": [4, 3, 2], "sVoxel": [2.0, 1.5, 1.0],
                    "offOrigin": [0, 0, 0], "offDetector": [0, 0], "accuracy": 0.5},
        "vol": "vol_gt.npy",
        "bbox": [[-1, -1, -1], [1, 1, 1]],
        "proj_train": train,
        "proj_test": test,
    });
    std::fs::write(dir.join(crate::scene::R2_META_FILE), meta.to_string()).unwrap();
    (imgs, vol)
}

/// A copy of safetensors file `from` at `to` with its JSON metadata entry `key` changed by `edit`.
pub fn edit_metadata(from: &Path, to: &Path, key: &str, edit: impl FnOnce(&mut serde_json::Value)) {
    let bytes = std::fs::read(from).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let entry = &mut header["__metadata__"][key];
    let mut value: serde_json::Value = serde_json::from_str(entry.as_str().unwrap()).unwrap();
    edit(&mut value);
    *entry = serde_json::Value::String(value.to_string());
    let mut text = header.to_string().into_bytes();
    text.resize(text.len().next_multiple_of(8), b' ');
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&text);
    out.extend_from_slice(&bytes[8 + n..]);
    std::fs::write(to, out).unwrap();
}
