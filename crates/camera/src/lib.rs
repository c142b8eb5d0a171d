//! The plain-number camera of one view: what the scene geometry (`prism_domain::geometry`) builds
//! per view and the render ops (`prism-render`) consume. No Burn dependency, so the domain builds
//! and tests without it; render never parses a scene. The convention is the
//! project's single geometry convention, written once in `docs/geometry.md`:
//!
//! * camera axes (rows of [`Camera::rotation`], in world coordinates): `x_c` along detector columns
//!   (u, increasing column index), `y_c` along detector rows (v, increasing row index, i.e. downward
//!   on the detector image), `z_c` the viewing direction from the source towards the rotation axis;
//!   the frame is right-handed (`z_c = x_c × y_c`);
//! * pixel centres sit at integer (column, row) coordinates; `(cx, cy)` is where the camera z axis
//!   meets the detector;
//! * cone beam: `col = fx·x/z + cx`, `row = fy·y/z + cy` with `(x, y, z)` camera coordinates and the
//!   source at the camera origin; `fx = DSD / pitch_u`, `fy = DSD / pitch_v` (pixels);
//! * parallel beam: `col = fx·x + cx`, `row = fy·y + cy` with `fx = 1 / pitch_u`, `fy = 1 / pitch_v`
//!   (pixels per length unit); rays start on the plane `z = 0` and run along `+z_c`.
//!
//! All lengths are in the scene's length unit (millimetres for Prism scenes).

use serde::{Deserialize, Serialize};

/// Beam shape of a view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// Point source at the camera origin, flat detector at depth `sdd`.
    Cone,
    /// Parallel rays along `z_c`, starting on the plane `z_c = 0`, ending on `z_c = sdd`.
    Parallel,
}

/// One view's camera: world→camera transform, intrinsics in pixels, detector size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub projection: Projection,
    /// World→camera rotation, row-major; its rows are `x_c`, `y_c`, `z_c` in world coordinates.
    pub rotation: [[f64; 3]; 3],
    /// World→camera translation: `p_c = rotation · p_w + translation`.
    pub translation: [f64; 3],
    /// Cone: focal lengths in pixels. Parallel: pixels per length unit.
    pub fx: f64,
    pub fy: f64,
    /// Principal point (column, row) in pixels, pixel centres at integers.
    pub cx: f64,
    pub cy: f64,
    /// Detector size in pixels.
    pub rows: usize,
    pub cols: usize,
    /// Distance from the camera origin (source, or the parallel rays' start plane) to the detector
    /// plane along `z_c`, in length units. Rays are integrated over `[0, sdd]` along this axis.
    pub sdd: f64,
}

/// A ray through one pixel centre: `origin + t·direction`, `t ∈ [0, length]`, `|direction| = 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: [f64; 3],
    pub direction: [f64; 3],
    pub length: f64,
}

impl Camera {
    /// World point → camera coordinates.
    pub fn to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2],
        ]
    }

    /// Camera coordinates → world point.
    pub fn to_world(&self, c: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let d = [
            c[0] - self.translation[0],
            c[1] - self.translation[1],
            c[2] - self.translation[2],
        ];
        [
            r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2],
            r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2],
            r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2],
        ]
    }

    /// World direction → camera direction (rotation only).
    pub fn dir_to_world(&self, c: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        [
            r[0][0] * c[0] + r[1][0] * c[1] + r[2][0] * c[2],
            r[0][1] * c[0] + r[1][1] * c[1] + r[2][1] * c[2],
            r[0][2] * c[0] + r[1][2] * c[1] + r[2][2] * c[2],
        ]
    }

    /// Detector position (column, row) of a world point, or `None` for a cone-beam point at or
    /// behind the source plane (`z_c ≤ 0`).
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let c = self.to_camera(p);
        match self.projection {
            Projection::Cone => {
                if c[2] <= 0.0 {
                    return None;
                }
                Some([
                    self.fx * c[0] / c[2] + self.cx,
                    self.fy * c[1] / c[2] + self.cy,
                ])
            }
            Projection::Parallel => Some([self.fx * c[0] + self.cx, self.fy * c[1] + self.cy]),
        }
    }

    /// Camera-frame position of the centre of pixel (column, row) on the detector plane.
    pub fn pixel_camera(&self, col: f64, row: f64) -> [f64; 3] {
        match self.projection {
            Projection::Cone => [
                (col - self.cx) / self.fx * self.sdd,
                (row - self.cy) / self.fy * self.sdd,
                self.sdd,
            ],
            Projection::Parallel => [
                (col - self.cx) / self.fx,
                (row - self.cy) / self.fy,
                self.sdd,
            ],
        }
    }

    /// The ray through the centre of pixel (column, row), from the source (cone) or the start plane
    /// (parallel) to the detector, in world coordinates.
    pub fn pixel_ray(&self, col: f64, row: f64) -> Ray {
        let end_c = self.pixel_camera(col, row);
        let start_c = match self.projection {
            Projection::Cone => [0.0, 0.0, 0.0],
            Projection::Parallel => [end_c[0], end_c[1], 0.0],
        };
        let d = [
            end_c[0] - start_c[0],
            end_c[1] - start_c[1],
            end_c[2] - start_c[2],
        ];
        let length = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let unit = [d[0] / length, d[1] / length, d[2] / length];
        Ray {
            origin: self.to_world(start_c),
            direction: self.dir_to_world(unit),
            length,
        }
    }

    /// Number of detector pixels.
    pub fn pixels(&self) -> usize {
        self.rows * self.cols
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cone() -> Camera {
        // θ = 0 in the Prism convention: source on +x at 500, detector 300 beyond the axis.
        Camera {
            projection: Projection::Cone,
            rotation: [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]],
            translation: [0.0, 0.0, 500.0],
            fx: 800.0 / 2.0,
            fy: 800.0 / 2.0,
            cx: 15.5,
            cy: 15.5,
            rows: 32,
            cols: 32,
            sdd: 800.0,
        }
    }

    #[test]
    fn world_camera_round_trip() {
        let cam = cone();
        let p = [1.5, -2.0, 3.25];
        let back = cam.to_world(cam.to_camera(p));
        for k in 0..3 {
            assert!((back[k] - p[k]).abs() < 1e-12);
        }
    }

    #[test]
    fn ray_hits_the_pixel_it_was_built_for() {
        let cam = cone();
        let ray = cam.pixel_ray(3.0, 20.0);
        for t in [0.3, 0.5, 0.9] {
            let s = t * ray.length;
            let p = [
                ray.origin[0] + s * ray.direction[0],
                ray.origin[1] + s * ray.direction[1],
                ray.origin[2] + s * ray.direction[2],
            ];
            let uv = cam.project(p).unwrap();
            assert!(
                (uv[0] - 3.0).abs() < 1e-9 && (uv[1] - 20.0).abs() < 1e-9,
                "{uv:?}"
            );
        }
        // Source on +x at DSO.
        assert!((ray.origin[0] - 500.0).abs() < 1e-9);
    }

    #[test]
    fn points_behind_the_source_do_not_project() {
        assert!(cone().project([600.0, 0.0, 0.0]).is_none());
    }
}
