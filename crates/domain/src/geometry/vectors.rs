//! Per-view geometry vectors: every view's source (or ray direction), detector centre and
//! pixel axes, as ASTRA's `cone_vec` / `parallel3d_vec` rows. They express what one circular
//! orbit cannot: wobble, a non-circular source path, a tilted or shifted detector per view.
//!
//! A row is 12 numbers, world millimetres (`docs/geometry.md`, "Per-view vectors"):
//! `(sx, sy, sz, dx, dy, dz, ux, uy, uz, vx, vy, vz)`:
//! * `s`: the source position (cone), or the direction the rays travel (parallel, any length);
//! * `d`: the detector centre (between its middle pixels);
//! * `u`: from one pixel centre to the next column's (its length is the column pitch);
//! * `v`: from one pixel centre to the next row's (row 0 first, so `v` points down the image).
//!
//! Pixel (row r, col c) sits at `d + (c + ½ − cols/2)·u + (r + ½ − rows/2)·v`. The circular scan
//! of [`Geometry`] converts exactly ([`Geometry::to_vectors`]). Two limits, both refused with
//! the view named: `u` and `v` must be perpendicular (no skewed pixels; for parallel beams after
//! removing their components along the rays, which changes no ray), and `u × v` must point from
//! the source towards the detector (a mirrored image: reverse its columns and negate `u`).

use super::{Beam, Camera, Geometry};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Largest |cos| of the angle between `u` and `v` that counts as perpendicular (0.00006°).
pub const PERPENDICULAR: f64 = 1e-6;

/// One view's pose, ASTRA's vector layout (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "[f64; 12]", into = "[f64; 12]")]
pub struct ViewVectors {
    /// Cone: the source position. Parallel: the rays' direction (any length).
    pub source: [f64; 3],
    /// The detector centre.
    pub detector: [f64; 3],
    /// One column step on the detector (direction and pitch), mm.
    pub u: [f64; 3],
    /// One row step on the detector (direction and pitch), mm.
    pub v: [f64; 3],
}

impl From<[f64; 12]> for ViewVectors {
    fn from(a: [f64; 12]) -> Self {
        let part = |k: usize| [a[k], a[k + 1], a[k + 2]];
        ViewVectors {
            source: part(0),
            detector: part(3),
            u: part(6),
            v: part(9),
        }
    }
}

impl From<ViewVectors> for [f64; 12] {
    fn from(w: ViewVectors) -> Self {
        let mut a = [0.0; 12];
        for (k, p) in [w.source, w.detector, w.u, w.v].iter().enumerate() {
            a[3 * k..3 * k + 3].copy_from_slice(p);
        }
        a
    }
}

impl ViewVectors {
    /// A 2-D fan-beam row of ASTRA's `fanflat_vec` (`sx, sy, dx, dy, ux, uy`) as the middle row
    /// of a cone beam in the plane z = 0, its row `pitch_v` high (rows run along −z).
    pub fn from_fan(row: [f64; 6], pitch_v: f64) -> Self {
        ViewVectors {
            source: [row[0], row[1], 0.0],
            detector: [row[2], row[3], 0.0],
            u: [row[4], row[5], 0.0],
            v: [0.0, 0.0, -pitch_v],
        }
    }

    /// The view's camera (`docs/geometry.md`): `x_c` along `u`, `y_c` along `v` (made exactly
    /// perpendicular to `u`), `z_c = x_c × y_c`. Cone: the source is the camera origin.
    /// Parallel: the rays start on the plane `start` mm before the world origin along the rays
    /// (the geometry's `dso`). Checks as [`ViewVectors::validate`].
    pub fn camera(&self, beam: Beam, rows: usize, cols: usize, start: f64) -> Result<Camera> {
        let (rotation, origin) = self.frame(beam, start)?;
        let [xc, yc, zc] = rotation;
        let sdd = dot(sub(self.detector, origin), zc);
        // Where the camera's z axis meets the detector plane, relative to the detector centre.
        let foot = sub(add(origin, scale(zc, sdd)), self.detector);
        // The pitches (for a parallel beam across the rays: the components along them change
        // no ray).
        let (pu, pv) = (dot(self.u, xc), dot(self.v, yc));
        let r = rotation;
        let translation = [0, 1, 2].map(|k| -dot(r[k], origin));
        Ok(Camera {
            projection: beam.projection(),
            rotation,
            translation,
            fx: beam.focal(sdd, pu),
            fy: beam.focal(sdd, pv),
            cx: (cols as f64 - 1.0) / 2.0 + dot(foot, xc) / pu,
            cy: (rows as f64 - 1.0) / 2.0 + dot(foot, yc) / pv,
            rows,
            cols,
            sdd,
        })
    }

    /// Every number finite, `u` and `v` non-zero and perpendicular (across the rays for a
    /// parallel beam), and the detector in front of the source. Errors name the part (`u`,
    /// `source`…); the caller prefixes the view.
    pub fn validate(&self, beam: Beam) -> Result<()> {
        self.frame(beam, 1.0).map(|_| ())
    }

    /// The camera's rotation (rows `x_c`, `y_c`, `z_c` in world coordinates) and origin.
    fn frame(&self, beam: Beam, start: f64) -> Result<([[f64; 3]; 3], [f64; 3])> {
        for (name, p) in [
            ("source", self.source),
            ("detector", self.detector),
            ("u", self.u),
            ("v", self.v),
        ] {
            if let Some(k) = p.iter().position(|x| !x.is_finite()) {
                return Err(Error::invalid(
                    format!("{name}[{k}]"),
                    format!("is not finite ({})", p[k]),
                ));
            }
        }
        // Parallel: the axes across the rays (a detector tilted against the rays sees the same
        // rays as its projection onto the plane across them).
        let (u, v, ray) = match beam {
            Beam::Cone => (self.u, self.v, None),
            Beam::Parallel => {
                let r = unit(self.source)
                    .ok_or_else(|| Error::invalid("source", "the ray direction is zero"))?;
                let across = |a: [f64; 3]| sub(a, scale(r, dot(a, r)));
                (across(self.u), across(self.v), Some(r))
            }
        };
        let along = |name: &str, a: [f64; 3]| {
            unit(a).ok_or_else(|| {
                Error::invalid(
                    name,
                    match beam {
                        Beam::Cone => "is zero: a pixel needs a size",
                        Beam::Parallel => "runs along the rays: a pixel needs a size across them",
                    },
                )
            })
        };
        let xc = along("u", u)?;
        let vn = along("v", v)?;
        let cos = dot(xc, vn);
        if cos.abs() > PERPENDICULAR {
            return Err(Error::invalid(
                "v",
                format!(
                    "is not perpendicular to u ({:.4}° between them): skewed pixels are not \
                     supported",
                    cos.clamp(-1.0, 1.0).acos().to_degrees()
                ),
            ));
        }
        // Exactly perpendicular axes, right-handed.
        let zc = unit(cross(xc, vn)).expect("perpendicular unit vectors");
        let yc = cross(zc, xc);
        let origin = match ray {
            None => self.source,
            Some(r) => {
                if dot(r, zc) <= 0.0 {
                    return Err(mirrored());
                }
                scale(r, -start)
            }
        };
        if ray.is_none() && dot(sub(self.detector, origin), zc) <= 0.0 {
            return Err(mirrored());
        }
        Ok(([xc, yc, zc], origin))
    }
}

fn mirrored() -> Error {
    Error::invalid(
        "u",
        "u × v points back towards the source: the image is mirrored (reverse its columns and \
         negate u), or the detector lies behind the source",
    )
}

impl Geometry {
    /// Every view's vectors: the stored ones, or the circular scan's (exact, module docs).
    pub fn to_vectors(&self) -> Vec<ViewVectors> {
        if let Some(v) = &self.vectors {
            return v.clone();
        }
        let d = &self.detector;
        self.angles_rad
            .iter()
            .map(|&th| {
                let (s, c) = th.sin_cos();
                let eu = [-s, c, 0.0];
                let ev = [0.0, 0.0, -1.0];
                let src = [self.dso * c, self.dso * s, 0.0];
                let centre = add(
                    add([src[0] - self.dsd * c, src[1] - self.dsd * s, 0.0], {
                        scale(eu, d.offset_u)
                    }),
                    scale(ev, d.offset_v),
                );
                ViewVectors {
                    source: match self.beam {
                        Beam::Cone => src,
                        Beam::Parallel => [-c, -s, 0.0],
                    },
                    detector: centre,
                    u: scale(eu, d.pitch_u),
                    v: scale(ev, d.pitch_v),
                }
            })
            .collect()
    }

    /// A geometry given by per-view `vectors` on a `rows × cols` detector. The circular fields
    /// become the nominal scan the vectors describe, used only where a method assumes a
    /// circular orbit (FDK's angular weights, axis search) and in summaries: `angles_rad` the
    /// azimuth about +z of each view's axis turned back towards the source (`angles` instead,
    /// if given), `dso` and `dsd` the mean depths of the isocentre and the detector plane along
    /// the view axes (parallel: the rays start twice the volume's reach before the isocentre),
    /// the pitches the mean lengths of `u` and `v`, no offsets. Checked as
    /// [`Geometry::validate`].
    pub fn from_vectors(
        beam: Beam,
        rows: usize,
        cols: usize,
        volume: super::VolumeGrid,
        vectors: Vec<ViewVectors>,
        angles: Option<Vec<f64>>,
    ) -> Result<Geometry> {
        if vectors.is_empty() {
            return Err(Error::invalid("vectors", "the view list is empty"));
        }
        for (k, w) in vectors.iter().enumerate() {
            w.validate(beam)
                .map_err(|e| e.under(&format!("vectors[{k}]")))?;
        }
        let n = vectors.len() as f64;
        let mean = |f: &dyn Fn(&ViewVectors) -> f64| vectors.iter().map(f).sum::<f64>() / n;
        // The view axis: from the source through the isocentre's foot on the detector plane.
        let axis = |w: &ViewVectors| {
            let (r, _) = w.frame(beam, 1.0).expect("validated");
            r[2]
        };
        let (dso, dsd) = match beam {
            Beam::Cone => (
                mean(&|w| -dot(w.source, axis(w))),
                mean(&|w| dot(sub(w.detector, w.source), axis(w))),
            ),
            // Parallel: the rays start twice the volume's reach before the isocentre.
            Beam::Parallel => {
                let (lo, hi) = volume.bounds();
                let reach = norm([0, 1, 2].map(|a| lo[a].abs().max(hi[a].abs())));
                let start = 2.0 * reach;
                (start, start + mean(&|w| dot(w.detector, axis(w))))
            }
        };
        let azimuth = |w: &ViewVectors| {
            let a = axis(w);
            (-a[1]).atan2(-a[0])
        };
        let angles_rad = match angles {
            Some(a) => {
                if a.len() != vectors.len() {
                    return Err(Error::invalid(
                        "angles",
                        format!("{} angles for {} views of vectors", a.len(), vectors.len()),
                    ));
                }
                a
            }
            None => unwrap_turns(vectors.iter().map(azimuth).collect()),
        };
        let pitch = |f: fn(&ViewVectors) -> [f64; 3]| mean(&|w| norm(f(w)));
        let g = Geometry {
            beam,
            dso,
            dsd,
            detector: super::Detector {
                rows,
                cols,
                pitch_u: pitch(|w| w.u),
                pitch_v: pitch(|w| w.v),
                offset_u: 0.0,
                offset_v: 0.0,
            },
            volume,
            angles_rad,
            vectors: Some(vectors),
        };
        g.validate()?;
        Ok(g)
    }

    /// The per-view checks of [`Geometry::validate`] for a geometry with vectors: one row per
    /// angle, each row valid, and every corner of the volume in front of each view's source
    /// (cone) and on the source side of its detector plane.
    pub(super) fn validate_vectors(&self, vectors: &[ViewVectors]) -> Result<()> {
        if vectors.len() != self.angles_rad.len() {
            return Err(Error::invalid(
                "vectors",
                format!(
                    "{} views of vectors but angles_rad lists {}",
                    vectors.len(),
                    self.angles_rad.len()
                ),
            ));
        }
        let (lo, hi) = self.volume.bounds();
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|i| [0, 1, 2].map(|a| if i >> a & 1 == 0 { lo[a] } else { hi[a] }))
            .collect();
        let d = &self.detector;
        for (k, w) in vectors.iter().enumerate() {
            let at = |e: Error| e.under(&format!("vectors[{k}]"));
            let cam = w.camera(self.beam, d.rows, d.cols, self.dso).map_err(at)?;
            let depths = corners.iter().map(|&p| cam.to_camera(p)[2]);
            let (near, far) = depths.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), z| {
                (a.min(z), b.max(z))
            });
            if near <= 0.0 {
                return Err(at(Error::invalid(
                    "source",
                    match self.beam {
                        Beam::Cone => "the volume reaches the source's plane or behind it",
                        Beam::Parallel => "the rays start inside the volume: raise dso",
                    },
                )));
            }
            if far >= cam.sdd {
                return Err(at(Error::invalid(
                    "detector",
                    "the detector plane cuts the volume",
                )));
            }
        }
        Ok(())
    }
}

/// Angles made continuous: each differs from the previous by less than half a turn.
fn unwrap_turns(mut a: Vec<f64>) -> Vec<f64> {
    use std::f64::consts::{PI, TAU};
    for i in 1..a.len() {
        let step = (a[i] - a[i - 1] + PI).rem_euclid(TAU) - PI;
        a[i] = a[i - 1] + step;
    }
    a
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// `a` turned by `phi` radians about the unit axis `e` (Rodrigues).
pub(crate) fn rotate(a: [f64; 3], e: [f64; 3], phi: f64) -> [f64; 3] {
    let (s, c) = phi.sin_cos();
    let ea = dot(e, a);
    let x = cross(e, a);
    [0, 1, 2].map(|k| a[k] * c + x[k] * s + e[k] * ea * (1.0 - c))
}

/// `a / |a|`, or `None` for a zero (or non-finite) length.
pub(crate) fn unit(a: [f64; 3]) -> Option<[f64; 3]> {
    let n = norm(a);
    (n > 0.0 && n.is_finite()).then(|| scale(a, 1.0 / n))
}
