//! Voxelization kernels, organised like the projection ones ([`super::project`]):
//! per-Gaussian preparation ([`prepare_kernel`], one [`VoxelRecord`] each), a brick forward that
//! culls and compacts Gaussians per 8×8×4 brick ([`forward_kernel`]) and a per-Gaussian gather
//! backward ([`backward_kernel`]).

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::math::{factors, quat_backward, variances};
use super::types::{
    GaussianBuffers, GeomGrad, Mat3, Params, Vec3, cell_span, densities_finite, finite,
};
use super::{CHUNK, PER_UNIT, STEP, stage_chunk};

/// Brick edge (units per cube: `BX · BY · BZ` = [`CHUNK`]).
pub const BX: u32 = 8;
pub const BY: u32 = 8;
pub const BZ: u32 = 4;

/// Floats per grid description (`[nx, ny, nz, dx, dy, dz, ox, oy, oz]`; [`super::grid_record`]
/// writes them in the order [`Grid::load`] reads).
pub const GRID_WIDTH: usize = 9;

/// A voxel grid ([`crate::VoxelGrid`]): voxel `(ix, iy, iz)` has its centre at
/// `o + (i + ½ − n/2)·d` per axis.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct Grid {
    pub n: Vec3,
    pub d: Vec3,
    pub o: Vec3,
}

#[cube]
impl Grid {
    pub fn load(t: &Tensor<f32>) -> Grid {
        Grid {
            n: Vec3::load(t, 0),
            d: Vec3::load(t, 3),
            o: Vec3::load(t, 6),
        }
    }

    /// The centre of voxel `(x, y, z)`.
    pub fn centre(self, x: u32, y: u32, z: u32) -> Vec3 {
        let i = Vec3::new(f32::cast_from(x), f32::cast_from(y), f32::cast_from(z));
        self.o.add(
            i.add(Vec3::new(0.5f32, 0.5f32, 0.5f32))
                .sub(self.n.scale(0.5f32))
                .mul(self.d),
        )
    }

    /// The (fractional) voxel index of a point: `(x − o)/d + n/2 − ½`.
    pub fn index(self, p: Vec3) -> Vec3 {
        let r = p.sub(self.o);
        Vec3::new(r.x / self.d.x, r.y / self.d.y, r.z / self.d.z)
            .add(self.n.scale(0.5f32))
            .sub(Vec3::new(0.5f32, 0.5f32, 0.5f32))
    }
}

/// The launch uniforms of the voxelization kernels (preparation, forward, backward): one call's
/// size and cut-off. Launched as a [`VoxelizeUniformsLaunch`].
#[derive(CubeType, CubeLaunch)]
pub struct VoxelizeUniforms {
    /// Number of Gaussians K.
    pub k: u32,
    /// Cut-off radius in Mahalanobis units (standard deviations): the preparation's voxel box.
    pub cutoff: f32,
    /// `cutoff²`, squared in f64 and rounded once: the per-voxel test.
    pub cut2: f32,
}

/// Floats per [`VoxelRecord`] (two of padding).
pub const VOXEL_WIDTH: usize = 20;
/// Where a [`VoxelRecord`] keeps the low and high ends of its voxel box.
pub const VOXEL_LO: usize = 12;
pub const VOXEL_HI: usize = 15;

/// A Gaussian prepared for voxelization: its mean, the scaled axes `w_j = r_j / s_j` (rows; the
/// value at `x` is `ρ · exp(−½ Σ_j (w_j · (x − mean))²)`), and its voxel box `[lo, hi)`.
#[derive(CubeType, CubeTypeMut, Clone, Copy)]
#[expand(derive(Clone, Copy))]
pub struct VoxelRecord {
    pub mean: Vec3,
    pub w: Mat3,
    pub lo: Vec3,
    pub hi: Vec3,
}

#[cube]
impl VoxelRecord {
    pub fn culled() -> VoxelRecord {
        VoxelRecord {
            mean: Vec3::zero(),
            w: Mat3::zero(),
            lo: Vec3::zero(),
            hi: Vec3::zero(),
        }
    }

    pub fn load(t: &Tensor<f32>, o: usize) -> VoxelRecord {
        VoxelRecord {
            mean: Vec3::load(t, o),
            w: Mat3::load(t, o + 3),
            lo: Vec3::load(t, o + VOXEL_LO),
            hi: Vec3::load(t, o + VOXEL_HI),
        }
    }

    pub fn store(self, t: &mut Tensor<f32>, o: usize) {
        self.mean.store(t, o);
        self.w.store(t, o + 3);
        self.lo.store(t, o + VOXEL_LO);
        self.hi.store(t, o + VOXEL_HI);
        t[o + 18] = 0.0f32;
        t[o + 19] = 0.0f32;
    }
}

/// Whether the box `[lo, hi)` is non-empty and overlaps `[blo, bhi)` on every axis.
#[cube]
fn boxes_meet(lo: Vec3, hi: Vec3, blo: Vec3, bhi: Vec3) -> bool {
    lo.x < hi.x
        && lo.y < hi.y
        && lo.z < hi.z
        && lo.x < bhi.x
        && hi.x > blo.x
        && lo.y < bhi.y
        && hi.y > blo.y
        && lo.z < bhi.z
        && hi.z > blo.z
}

/// One [`VoxelRecord`] per Gaussian into `out`.
#[cube(launch)]
pub fn prepare_kernel(
    gaussians: &GaussianBuffers,
    grid: &Tensor<f32>,
    out: &mut Tensor<f32>,
    uniforms: &VoxelizeUniforms,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    if i >= uniforms.k as usize {
        terminate!();
    }
    let mut rec = VoxelRecord::culled();
    let p = Params::load(gaussians, i);
    let f = factors(p);
    if densities_finite(&gaussians.densities, i, m) && f.ok {
        let grid = Grid::load(grid);
        let v = variances(f);
        let half = Vec3::new(f32::sqrt(v.x), f32::sqrt(v.y), f32::sqrt(v.z)).scale(uniforms.cutoff);
        let first = grid.index(p.mean.sub(half));
        let last = grid.index(p.mean.add(half));
        let (lx, hx) = cell_span(first.x, last.x, u32::cast_from(grid.n.x));
        let (ly, hy) = cell_span(first.y, last.y, u32::cast_from(grid.n.y));
        let (lz, hz) = cell_span(first.z, last.z, u32::cast_from(grid.n.z));
        let lo = Vec3::new(lx, ly, lz);
        let hi = Vec3::new(hx, hy, hz);
        // Scaled axes w_j = r_j / s_j (r_j the j-th column of R).
        let w = Mat3 {
            r0: f.rot.c0().scale(1.0f32 / f.scale.x),
            r1: f.rot.c1().scale(1.0f32 / f.scale.y),
            r2: f.rot.c2().scale(1.0f32 / f.scale.z),
        };
        if half.is_finite() && w.is_finite() && boxes_meet(lo, hi, lo, hi) {
            rec = VoxelRecord {
                mean: p.mean,
                w,
                lo,
                hi,
            };
        }
    }
    rec.store(out, i * VOXEL_WIDTH);
}

/// `−½ q` of the offset `d` from a record's scaled axes `w` (`q = Σ_j (w_j · d)²`, a sum of
/// squares: no cancellation however thin the Gaussian), or `+1` beyond the cut-off.
#[cube]
fn neg_half_q3(w: Mat3, d: Vec3, cut2: f32) -> f32 {
    let e = w.mul_vec(d);
    let qq = e.dot(e);
    let mut r = 1.0f32;
    if qq <= cut2 {
        r = -0.5f32 * qq;
    }
    r
}

/// Brick forward: one cube per brick of `BX × BY × BZ` voxels sums the records that reach it.
#[cube(launch)]
pub fn forward_kernel(
    prepared: &Tensor<f32>,
    bounds: &Tensor<f32>,
    densities: &Tensor<f32>,
    grid: &Tensor<f32>,
    out: &mut Tensor<f32>,
    uniforms: &VoxelizeUniforms,
    #[comptime] m: usize,
) {
    let cut2 = uniforms.cut2;
    let grid = Grid::load(grid);
    let t = ((UNIT_POS_Z * BY + UNIT_POS_Y) * BX + UNIT_POS_X) as usize;
    let nx = u32::cast_from(grid.n.x);
    let ny = u32::cast_from(grid.n.y);
    let nz = u32::cast_from(grid.n.z);
    let blo = Vec3::new(
        f32::cast_from(CUBE_POS_X * BX),
        f32::cast_from(CUBE_POS_Y * BY),
        f32::cast_from(CUBE_POS_Z * BZ),
    );
    let bhi = Vec3::new(
        f32::min(blo.x + f32::cast_from(BX), grid.n.x),
        f32::min(blo.y + f32::cast_from(BY), grid.n.y),
        f32::min(blo.z + f32::cast_from(BZ), grid.n.z),
    );
    let ix = CUBE_POS_X * BX + UNIT_POS_X;
    let iy = CUBE_POS_Y * BY + UNIT_POS_Y;
    let iz = CUBE_POS_Z * BZ + UNIT_POS_Z;
    let voxel = Vec3::new(f32::cast_from(ix), f32::cast_from(iy), f32::cast_from(iz));
    let centre = grid.centre(ix, iy, iz);
    let mut scan = Shared::<[u32]>::new_slice(2 * CHUNK);
    let mut ids = Shared::<[u32]>::new_slice(STEP);
    let mut acc = Array::<f32>::new(m);
    for c in 0..m {
        acc[c] = 0.0f32;
    }
    let kk = uniforms.k as usize;
    let mut start = 0usize;
    while start < kk {
        // The step's union box (super::step_bounds_kernel, `(lo, hi)` per axis): skip the step,
        // uniformly across the cube, if it misses the brick.
        let b = (start / STEP) * 6;
        let step_lo = Vec3::new(bounds[b], bounds[b + 2], bounds[b + 4]);
        let step_hi = Vec3::new(bounds[b + 1], bounds[b + 3], bounds[b + 5]);
        if boxes_meet(step_lo, step_hi, blo, bhi) {
            let first = start + t * PER_UNIT;
            let mut hits = 0u32;
            for i in 0..PER_UNIT {
                let j = first + i;
                if j < kk {
                    let o = j * VOXEL_WIDTH;
                    let lo = Vec3::load(prepared, o + VOXEL_LO);
                    let hi = Vec3::load(prepared, o + VOXEL_HI);
                    if boxes_meet(lo, hi, blo, bhi) {
                        hits |= 1u32 << i as u32;
                    }
                }
            }
            let n = stage_chunk(hits, first, t, &mut scan, &mut ids);
            for e in 0..n as usize {
                let gi = ids[e] as usize;
                let rec = VoxelRecord::load(prepared, gi * VOXEL_WIDTH);
                let inside = voxel.x >= rec.lo.x
                    && voxel.x < rec.hi.x
                    && voxel.y >= rec.lo.y
                    && voxel.y < rec.hi.y
                    && voxel.z >= rec.lo.z
                    && voxel.z < rec.hi.z;
                // Only voxels inside the box evaluate: a warp (a SIMD group on lavapipe) whose
                // voxels all miss skips the work.
                if inside {
                    let nhq = neg_half_q3(rec.w, centre.sub(rec.mean), cut2);
                    if nhq <= 0.0f32 {
                        let g = f32::exp(nhq);
                        for c in 0..m {
                            acc[c] += densities[gi * m + c] * g;
                        }
                    }
                }
            }
            sync_cube();
        }
        start += STEP;
    }
    if ix < nx && iy < ny && iz < nz {
        let vol = (nx * ny * nz) as usize;
        let p = ((iz * ny + iy) * nx + ix) as usize;
        for c in 0..m {
            out[c * vol + p] = acc[c];
        }
    }
}

/// Per-Gaussian backward: one unit gathers its record's voxel box from `grad`
/// (`[M, nz, ny, nx]`) and writes the Gaussian's gradients into `grads`.
#[cube(launch)]
pub fn backward_kernel(
    gaussians: &GaussianBuffers,
    grid: &Tensor<f32>,
    prepared: &Tensor<f32>,
    grad: &Tensor<f32>,
    grads: &mut GaussianBuffers,
    uniforms: &VoxelizeUniforms,
    #[comptime] m: usize,
) {
    let i = ABSOLUTE_POS;
    if i >= uniforms.k as usize {
        terminate!();
    }
    let cut2 = uniforms.cut2;
    let grid = Grid::load(grid);
    let rec = VoxelRecord::load(prepared, i * VOXEL_WIDTH);
    let nx = u32::cast_from(grid.n.x);
    let ny = u32::cast_from(grid.n.y);
    let nz = u32::cast_from(grid.n.z);
    let vol = (nx * ny * nz) as usize;
    let mut sums = Array::<f32>::new(m);
    for c in 0..m {
        sums[c] = 0.0f32;
    }
    // Moments in the Gaussian's frame, e_j = w_j · d (weight w = uG, u = Σ_c ρ_c ∂L/∂value_c):
    // Σ w e_j, Σ w e_j², Σ w e_j d (row j). Sums of e_j² keep the thin axis of a needle or sheet
    // accurate, where world moments d dᵀ contracted with Σ⁻¹ cancel in f32.
    let mut m_e = Vec3::zero();
    let mut m_ee = Vec3::zero();
    let mut m_ed = Mat3::zero();
    let x0 = u32::cast_from(rec.lo.x);
    let y0 = u32::cast_from(rec.lo.y);
    let z0 = u32::cast_from(rec.lo.z);
    let x1 = u32::min(u32::cast_from(rec.hi.x), nx);
    let y1 = u32::min(u32::cast_from(rec.hi.y), ny);
    let z1 = u32::min(u32::cast_from(rec.hi.z), nz);
    let mut z = z0;
    while z < z1 {
        let mut y = y0;
        while y < y1 {
            let mut x = x0;
            while x < x1 {
                let d = grid.centre(x, y, z).sub(rec.mean);
                let e = rec.w.mul_vec(d);
                let qq = e.dot(e);
                if qq <= cut2 {
                    let g = f32::exp(-0.5f32 * qq);
                    let p = ((z * ny + y) * nx + x) as usize;
                    let mut u = 0.0f32;
                    for c in 0..m {
                        let gc = grad[c * vol + p];
                        sums[c] += gc * g;
                        u += gaussians.densities[i * m + c] * gc;
                    }
                    let we = e.scale(u * g);
                    m_e = m_e.add(we);
                    m_ee = m_ee.add(we.mul(e));
                    m_ed = m_ed.add(Mat3::outer(we, d));
                }
                x += 1;
            }
            y += 1;
        }
        z += 1;
    }
    let f = factors(Params::load(gaussians, i));
    let mut good = x0 < x1 && y0 < y1 && z0 < z1 && f.ok;
    let mut out = GeomGrad::zero();
    if good {
        // G = exp(−½ Σ_j e_j²), e_j = r_jᵀd / s_j:
        // ∂G/∂mean = G Σ_j e_j w_j, ∂G/∂s_j = G e_j² / s_j, ∂G/∂r_j = −G e_j d / s_j.
        let inv_s = Vec3::new(1.0f32 / f.scale.x, 1.0f32 / f.scale.y, 1.0f32 / f.scale.z);
        let g_axes = Mat3 {
            r0: m_ed.r0.scale(-inv_s.x),
            r1: m_ed.r1.scale(-inv_s.y),
            r2: m_ed.r2.scale(-inv_s.z),
        };
        out = GeomGrad {
            mean: rec.w.t_mul_vec(m_e),
            scale: m_ee.mul(inv_s),
            // Row j of `g_axes` is ∂L/∂r_j, the j-th column of R.
            quat: quat_backward(f, g_axes.transpose()),
        };
        good = out.is_finite();
        for c in 0..m {
            if !finite(sums[c]) {
                good = false;
            }
        }
    }
    if !good {
        out = GeomGrad::zero();
        for c in 0..m {
            sums[c] = 0.0f32;
        }
    }
    out.store(grads, i);
    for c in 0..m {
        grads.densities[i * m + c] = sums[c];
    }
}
