//! The values the CubeCL kernels work with, as typed structs: small vectors and matrices, a
//! Gaussian's parameters, a view's camera, and the per-(view, Gaussian) records the kernels pass
//! between launches. Every record type owns its layout in a flat `f32` tensor: its `WIDTH` and
//! its `load` / `store` are the only code that knows where a field sits.
//!
//! The structs are values (`Copy`): operations return new values rather than mutating fields,
//! as the math reads. Arithmetic is inherent methods (`add`, `mul`, …), not `std::ops` impls:
//! `#[cube]` traces method calls into the kernel, operator overloading would bypass it.

#![allow(clippy::should_implement_trait)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

/// Finite (false for ±∞ and NaN).
#[cube]
pub fn finite(x: f32) -> bool {
    f32::abs(x) <= 3.0e38f32
}

/// A 3-vector (or the three components of a per-axis quantity).
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Vec3 {
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

#[cube]
impl Vec3 {
    pub fn new(x: f32, y: f32, z: f32) -> Vec3 {
        Vec3 { x, y, z }
    }

    pub fn zero() -> Vec3 {
        Vec3::new(0.0f32, 0.0f32, 0.0f32)
    }

    /// `t[o..o + 3]`.
    pub fn load(t: &Tensor<f32>, o: usize) -> Vec3 {
        Vec3::new(t[o], t[o + 1], t[o + 2])
    }

    /// Write to `t[o..o + 3]`.
    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        t[o] = self.x;
        t[o + 1] = self.y;
        t[o + 2] = self.z;
    }

    pub fn add(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }

    pub fn sub(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }

    pub fn scale(self, s: f32) -> Vec3 {
        Vec3::new(self.x * s, self.y * s, self.z * s)
    }

    /// Component-wise product.
    pub fn mul(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x * o.x, self.y * o.y, self.z * o.z)
    }

    pub fn dot(self, o: Vec3) -> f32 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    pub fn length(self) -> f32 {
        f32::sqrt(self.dot(self))
    }

    pub fn is_finite(self) -> bool {
        finite(self.x) && finite(self.y) && finite(self.z)
    }
}

/// A 3×3 matrix by rows.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Mat3 {
    pub r0: Vec3,
    pub r1: Vec3,
    pub r2: Vec3,
}

#[cube]
impl Mat3 {
    pub fn zero() -> Mat3 {
        Mat3 {
            r0: Vec3::zero(),
            r1: Vec3::zero(),
            r2: Vec3::zero(),
        }
    }

    /// Row-major `t[o..o + 9]`.
    pub fn load(t: &Tensor<f32>, o: usize) -> Mat3 {
        Mat3 {
            r0: Vec3::load(t, o),
            r1: Vec3::load(t, o + 3),
            r2: Vec3::load(t, o + 6),
        }
    }

    /// Write row-major to `t[o..o + 9]`.
    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        self.r0.store(t, o);
        self.r1.store(t, o + 3);
        self.r2.store(t, o + 6);
    }

    pub fn c0(self) -> Vec3 {
        Vec3::new(self.r0.x, self.r1.x, self.r2.x)
    }

    pub fn c1(self) -> Vec3 {
        Vec3::new(self.r0.y, self.r1.y, self.r2.y)
    }

    pub fn c2(self) -> Vec3 {
        Vec3::new(self.r0.z, self.r1.z, self.r2.z)
    }

    pub fn transpose(self) -> Mat3 {
        Mat3 {
            r0: self.c0(),
            r1: self.c1(),
            r2: self.c2(),
        }
    }

    /// `M v`.
    pub fn mul_vec(self, v: Vec3) -> Vec3 {
        Vec3::new(self.r0.dot(v), self.r1.dot(v), self.r2.dot(v))
    }

    /// `Mᵀ v`.
    pub fn t_mul_vec(self, v: Vec3) -> Vec3 {
        Vec3::new(self.c0().dot(v), self.c1().dot(v), self.c2().dot(v))
    }

    /// `M B`.
    pub fn mul(self, b: Mat3) -> Mat3 {
        Mat3 {
            r0: b.t_mul_vec(self.r0),
            r1: b.t_mul_vec(self.r1),
            r2: b.t_mul_vec(self.r2),
        }
    }

    pub fn add(self, b: Mat3) -> Mat3 {
        Mat3 {
            r0: self.r0.add(b.r0),
            r1: self.r1.add(b.r1),
            r2: self.r2.add(b.r2),
        }
    }

    /// `u vᵀ`.
    pub fn outer(u: Vec3, v: Vec3) -> Mat3 {
        Mat3 {
            r0: v.scale(u.x),
            r1: v.scale(u.y),
            r2: v.scale(u.z),
        }
    }

    pub fn is_finite(self) -> bool {
        self.r0.is_finite() && self.r1.is_finite() && self.r2.is_finite()
    }
}

/// A quaternion `(w, x, y, z)`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Quat {
    pub w: f32,
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

#[cube]
impl Quat {
    pub fn new(w: f32, x: f32, y: f32, z: f32) -> Quat {
        Quat { w, x, y, z }
    }

    /// `t[o..o + 4]`.
    pub fn load(t: &Tensor<f32>, o: usize) -> Quat {
        Quat::new(t[o], t[o + 1], t[o + 2], t[o + 3])
    }

    /// Write to `t[o..o + 4]`.
    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        t[o] = self.w;
        t[o + 1] = self.x;
        t[o + 2] = self.y;
        t[o + 3] = self.z;
    }

    pub fn scale(self, s: f32) -> Quat {
        Quat::new(self.w * s, self.x * s, self.y * s, self.z * s)
    }

    pub fn add(self, o: Quat) -> Quat {
        Quat::new(self.w + o.w, self.x + o.x, self.y + o.y, self.z + o.z)
    }

    pub fn norm(self) -> f32 {
        f32::sqrt(self.w * self.w + self.x * self.x + self.y * self.y + self.z * self.z)
    }

    /// The rotation matrix of the unit quaternion `self`.
    pub fn rotation(self) -> Mat3 {
        let (w, x, y, z) = (self.w, self.x, self.y, self.z);
        Mat3 {
            r0: Vec3::new(
                1.0f32 - 2.0f32 * (y * y + z * z),
                2.0f32 * (x * y - w * z),
                2.0f32 * (x * z + w * y),
            ),
            r1: Vec3::new(
                2.0f32 * (x * y + w * z),
                1.0f32 - 2.0f32 * (x * x + z * z),
                2.0f32 * (y * z - w * x),
            ),
            r2: Vec3::new(
                2.0f32 * (x * z - w * y),
                2.0f32 * (y * z + w * x),
                1.0f32 - 2.0f32 * (x * x + y * y),
            ),
        }
    }

    pub fn is_finite(self) -> bool {
        finite(self.w) && finite(self.x) && finite(self.y) && finite(self.z)
    }
}

/// A pixel or voxel index box `[x0, x1) × [y0, y1)`, as f32 (exact below 2²⁴).
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Rect {
    pub x0: f32,
    pub x1: f32,
    pub y0: f32,
    pub y1: f32,
}

#[cube]
impl Rect {
    pub fn empty() -> Rect {
        Rect {
            x0: 0.0f32,
            x1: 0.0f32,
            y0: 0.0f32,
            y1: 0.0f32,
        }
    }

    /// `[x0, x1, y0, y1]` at `t[o..o + 4]`.
    pub fn load(t: &Tensor<f32>, o: usize) -> Rect {
        Rect {
            x0: t[o],
            x1: t[o + 1],
            y0: t[o + 2],
            y1: t[o + 3],
        }
    }

    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        t[o] = self.x0;
        t[o + 1] = self.x1;
        t[o + 2] = self.y0;
        t[o + 3] = self.y1;
    }

    pub fn is_empty(self) -> bool {
        !(self.x0 < self.x1 && self.y0 < self.y1)
    }

    /// The box clipped on its high ends to a `cols × rows` detector.
    pub fn clip(self, cols: f32, rows: f32) -> Rect {
        Rect {
            x0: self.x0,
            x1: f32::min(self.x1, cols),
            y0: self.y0,
            y1: f32::min(self.y1, rows),
        }
    }

    /// Whether the box overlaps `other`.
    pub fn overlaps(self, other: Rect) -> bool {
        self.x0 < other.x1 && self.x1 > other.x0 && self.y0 < other.y1 && self.y1 > other.y0
    }

    pub fn contains(self, x: f32, y: f32) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }
}

/// The cell range `[lo, hi)` of the inclusive index interval `[first, last]` on a grid of `n`
/// cells, as [`crate::cpu::tile_span`]; `(0, 0)` if it misses the grid or is NaN.
#[cube]
pub fn cell_span(first: f32, last: f32, n: u32) -> (f32, f32) {
    let lo = f32::max(f32::ceil(first), 0.0f32);
    let hi = f32::min(f32::floor(last), f32::cast_from(n) - 1.0f32);
    let mut a = 0.0f32;
    let mut b = 0.0f32;
    if first <= last && lo <= hi {
        a = lo;
        b = hi + 1.0f32;
    }
    (a, b)
}

/// One view's camera (see [`crate::camera::Camera`]): world → camera rotation `rot` and
/// translation `t`, focal lengths and principal point in pixels, source–detector distance, and
/// the beam.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct View {
    pub rot: Mat3,
    pub t: Vec3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub sdd: f32,
    pub cone: bool,
}

/// Floats per camera in the cameras tensor ([`super::pack_cameras`] writes them in the order
/// [`View::load`] reads).
pub const VIEW_WIDTH: usize = 18;

#[cube]
impl View {
    /// Camera `v` of the packed cameras.
    pub fn load(cams: &Tensor<f32>, v: usize) -> View {
        let o = v * VIEW_WIDTH;
        View {
            rot: Mat3::load(cams, o),
            t: Vec3::load(cams, o + 9),
            fx: cams[o + 12],
            fy: cams[o + 13],
            cx: cams[o + 14],
            cy: cams[o + 15],
            sdd: cams[o + 16],
            cone: cams[o + 17] > 0.5f32,
        }
    }

    /// A world point in the camera frame.
    pub fn to_camera(self, p: Vec3) -> Vec3 {
        self.rot.mul_vec(p).add(self.t)
    }
}

/// The Gaussian parameter tensors as the kernels read them, contiguous in the layouts of
/// [`crate::ops`]: means `[K, 3]`, scales `[K, 3]`, rotations `[K, 4]` (raw quaternions
/// `w, x, y, z`), densities `[K, M]`. The backward kernels write the parameters' gradients into a
/// second one (same shapes). Launched as a [`GaussianBuffersLaunch`].
#[derive(CubeType, CubeLaunch)]
pub struct GaussianBuffers {
    pub means: OwnedTensor<f32>,
    pub scales: OwnedTensor<f32>,
    pub rotations: OwnedTensor<f32>,
    pub densities: OwnedTensor<f32>,
}

/// Gaussian `i`'s parameters as the ops receive them: mean, scales (standard deviations), the raw
/// quaternion.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Params {
    pub mean: Vec3,
    pub scale: Vec3,
    pub quat: Quat,
}

#[cube]
impl Params {
    /// Gaussian `i` of `g`.
    pub fn load(g: &GaussianBuffers, i: usize) -> Params {
        Params {
            mean: Vec3::load(&g.means, 3 * i),
            scale: Vec3::load(&g.scales, 3 * i),
            quat: Quat::load(&g.rotations, 4 * i),
        }
    }
}

/// Whether every density of Gaussian `i` (`m` channels) is finite: the kernels cull it otherwise.
#[cube]
pub fn densities_finite(densities: &Tensor<f32>, i: usize, #[comptime] m: usize) -> bool {
    let mut ok = true;
    for c in 0..m {
        if !finite(densities[i * m + c]) {
            ok = false;
        }
    }
    ok
}

/// The gradient of one Gaussian's geometry: mean, scales, raw quaternion.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct GeomGrad {
    pub mean: Vec3,
    pub scale: Vec3,
    pub quat: Quat,
}

#[cube]
impl GeomGrad {
    pub fn zero() -> GeomGrad {
        GeomGrad {
            mean: Vec3::zero(),
            scale: Vec3::zero(),
            quat: Quat::new(0.0f32, 0.0f32, 0.0f32, 0.0f32),
        }
    }

    pub fn add(self, o: GeomGrad) -> GeomGrad {
        GeomGrad {
            mean: self.mean.add(o.mean),
            scale: self.scale.add(o.scale),
            quat: self.quat.add(o.quat),
        }
    }

    pub fn is_finite(self) -> bool {
        self.mean.is_finite() && self.scale.is_finite() && self.quat.is_finite()
    }

    /// Write Gaussian `i`'s gradients into the means, scales and rotations of `grads`.
    pub fn store(self, grads: &mut GaussianBuffers, i: usize) {
        self.mean.store(&mut grads.means, 3 * i);
        self.scale.store(&mut grads.scales, 3 * i);
        self.quat.store(&mut grads.rotations, 4 * i);
    }
}

/// Screen offset of view `v`, Gaussian `i` (`[V, K, 2]`).
#[cube]
pub(super) fn offset(screen: &Tensor<f32>, v: usize, k: usize, i: usize) -> (f32, f32) {
    let o = 2 * (v * k + i);
    (screen[o], screen[o + 1])
}

/// The launch uniforms of the projection kernels (preparation, forward and backward, affine and
/// exact mode): one call's sizes and options, the same for every kernel of the call (each reads
/// the ones it needs). Launched as a [`ProjectUniformsLaunch`].
#[derive(CubeType, CubeLaunch)]
pub struct ProjectUniforms {
    /// Number of Gaussians K.
    pub k: u32,
    /// Number of views V.
    pub n_views: u32,
    /// Detector rows (pixels), the same in every view.
    pub rows: u32,
    /// Detector columns (pixels), the same in every view.
    pub cols: u32,
    /// Cut-off radius in Mahalanobis units (standard deviations).
    pub cutoff: f32,
    /// `cutoff²`, squared in f64 and rounded once: the forward's per-pixel test. (The backward
    /// kernels square `cutoff` in f32.)
    pub cut2: f32,
    /// Near plane as a fraction of the source–detector distance (affine mode's culling).
    pub near_fraction: f32,
}
