//! Total nuclear variation's linear algebra on one voxel's 3 × C Jacobian `J` (the channels'
//! gradients as columns): its Gram matrix, the symmetric 3 × 3 eigen-decomposition, and the
//! clipping of `J`'s singular values that projects onto the nuclear norm's dual ball
//! ([`super::tv`]).

/// `J Jᵀ` (3 × 3) of the group's 3 × C matrix `J[d][c] = group[3c + d]`.
pub(super) fn gram(group: &[f32]) -> [[f64; 3]; 3] {
    let mut m = [[0.0f64; 3]; 3];
    for col in group.chunks(3) {
        for a in 0..3 {
            for b in 0..3 {
                m[a][b] += col[a] as f64 * col[b] as f64;
            }
        }
    }
    m
}

/// Clip the singular values of the group's 3 × C matrix `J` at λ: with `J Jᵀ = U diag(s²) Uᵀ`,
/// `J ← U diag(min(1, λ/s)) Uᵀ J`.
pub(super) fn clip_singular_values(group: &mut [f32], lambda: f64) {
    let (eig, u) = sym3_eigen(gram(group));
    let f: [f64; 3] = std::array::from_fn(|i| {
        let s = eig[i].max(0.0).sqrt();
        if s > lambda { lambda / s } else { 1.0 }
    });
    if f.iter().all(|&f| f == 1.0) {
        return;
    }
    // P = U diag(f) Uᵀ, applied to every column of J.
    let p: [[f64; 3]; 3] = std::array::from_fn(|a| {
        std::array::from_fn(|b| (0..3).map(|i| u[a][i] * f[i] * u[b][i]).sum())
    });
    for col in group.chunks_mut(3) {
        let v = [col[0] as f64, col[1] as f64, col[2] as f64];
        for a in 0..3 {
            col[a] = (p[a][0] * v[0] + p[a][1] * v[1] + p[a][2] * v[2]) as f32;
        }
    }
}

/// Eigenvalues and eigenvectors (the columns of the returned matrix) of a symmetric 3 × 3
/// matrix, by cyclic Jacobi rotations (converges quadratically; 3 × 3 needs a handful of sweeps).
pub(super) fn sym3_eigen(mut m: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let scale: f64 = m.iter().flatten().map(|a| a.abs()).sum();
    if scale == 0.0 {
        return ([0.0; 3], v);
    }
    for _sweep in 0..32 {
        let off = m[0][1].abs() + m[0][2].abs() + m[1][2].abs();
        if off <= 1e-15 * scale {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if m[p][q].abs() <= 1e-300 {
                continue;
            }
            // Rotation that zeroes m[p][q] (Golub & Van Loan, symmetric Schur decomposition).
            let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in m.iter_mut() {
                let (mkp, mkq) = (row[p], row[q]);
                row[p] = c * mkp - s * mkq;
                row[q] = s * mkp + c * mkq;
            }
            let (rp, rq) = (m[p], m[q]);
            m[p] = std::array::from_fn(|k| c * rp[k] - s * rq[k]);
            m[q] = std::array::from_fn(|k| s * rp[k] + c * rq[k]);
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    ([m[0][0], m[1][1], m[2][2]], v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_diagonalises_a_symmetric_matrix() {
        let m = [[4.0, 1.0, -2.0], [1.0, 2.0, 0.5], [-2.0, 0.5, 3.0]];
        let (e, v) = sym3_eigen(m);
        for i in 0..3 {
            // M vᵢ = eᵢ vᵢ, and the columns are orthonormal.
            for a in 0..3 {
                let mv: f64 = (0..3).map(|b| m[a][b] * v[b][i]).sum();
                assert!(
                    (mv - e[i] * v[a][i]).abs() < 1e-12,
                    "{mv} vs {}",
                    e[i] * v[a][i]
                );
            }
            for j in 0..3 {
                let d: f64 = (0..3).map(|a| v[a][i] * v[a][j]).sum();
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!((e.iter().sum::<f64>() - 9.0).abs() < 1e-12); // the trace
    }
}
