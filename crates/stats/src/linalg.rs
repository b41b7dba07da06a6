//! Dense linear algebra for the few parameters of a GLM.

/// Inverse of a small square matrix (row-major, n x n) by Gauss-Jordan elimination with
/// partial pivoting; `None` when singular.
pub fn invert(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut m = a.to_vec();
    let mut inv = vec![0.0; n * n];
    for i in 0..n {
        inv[i * n + i] = 1.0;
    }
    for col in 0..n {
        let pivot =
            (col..n).max_by(|&r, &s| m[r * n + col].abs().total_cmp(&m[s * n + col].abs()))?;
        if m[pivot * n + col].abs() < 1e-300 {
            return None;
        }
        for k in 0..n {
            m.swap(col * n + k, pivot * n + k);
            inv.swap(col * n + k, pivot * n + k);
        }
        let d = m[col * n + col];
        for k in 0..n {
            m[col * n + k] /= d;
            inv[col * n + k] /= d;
        }
        for r in 0..n {
            if r != col {
                let f = m[r * n + col];
                if f != 0.0 {
                    for k in 0..n {
                        m[r * n + k] -= f * m[col * n + k];
                        inv[r * n + k] -= f * inv[col * n + k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// C = A · B for n x n matrices.
pub fn matmul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            for j in 0..n {
                c[i * n + j] += aik * b[k * n + j];
            }
        }
    }
    c
}

/// Eigen-decomposition of a small symmetric matrix (row-major, n x n) by cyclic Jacobi
/// rotations: the eigenvalues and the eigenvectors as the columns of a row-major matrix, so
/// that `a = V diag(w) Vᵀ`. Accurate to rounding for the few-by-few covariance matrices it
/// is meant for.
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut m = a.to_vec();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| m[i * n + j] * m[i * n + j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (m[q * n + q] - m[p * n + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (mkp, mkq) = (m[k * n + p], m[k * n + q]);
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let (mpk, mqk) = (m[p * n + k], m[q * n + k]);
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| m[i * n + i]).collect(), v)
}

/// The nearest symmetric positive semi-definite matrix (Frobenius norm) to a symmetric one:
/// its eigenvalues below `floor` raised to it.
pub fn clip_to_psd(a: &[f64], n: usize, floor: f64) -> Vec<f64> {
    let (w, v) = sym_eigen(a, n);
    let mut out = vec![0.0; n * n];
    for (k, &wk) in w.iter().enumerate() {
        let wk = wk.max(floor);
        for i in 0..n {
            for j in 0..n {
                out[i * n + j] += wk * v[i * n + k] * v[j * n + k];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_decomposition_rebuilds_the_matrix_and_psd_clipping_drops_negatives() {
        // numpy.linalg.eigh([[4, 1, 2], [1, 3, 0], [2, 0, 5]]) = [1.8549..., 3.4760..., 6.6691...]
        let a = [4.0, 1.0, 2.0, 1.0, 3.0, 0.0, 2.0, 0.0, 5.0];
        let (mut w, v) = sym_eigen(&a, 3);
        let back = clip_to_psd(&a, 3, f64::NEG_INFINITY);
        for (x, y) in back.iter().zip(&a) {
            assert!((x - y).abs() < 1e-10, "{back:?}");
        }
        // Orthonormal eigenvectors.
        for i in 0..3 {
            let norm: f64 = (0..3).map(|k| v[k * 3 + i] * v[k * 3 + i]).sum();
            assert!((norm - 1.0).abs() < 1e-12);
        }
        w.sort_by(f64::total_cmp);
        for (x, want) in w.iter().zip([
            1.854_897_308_799_576,
            3.476_023_602_918_133,
            6.669_079_088_282_287,
        ]) {
            assert!((x - want).abs() < 1e-9, "{w:?}");
        }
        // [[1, 2], [2, 1]] has eigenvalues 3 and -1: clipped at 0 it becomes [[1.5, 1.5], [1.5, 1.5]].
        let c = clip_to_psd(&[1.0, 2.0, 2.0, 1.0], 2, 0.0);
        for x in c {
            assert!((x - 1.5).abs() < 1e-12);
        }
    }

    #[test]
    fn inverse_times_matrix_is_identity() {
        let a = [4.0, 7.0, 2.0, 0.0, 6.0, 1.0, 3.0, 0.5, 5.0];
        let inv = invert(&a, 3).unwrap();
        let id = matmul(&a, &inv, 3);
        for i in 0..3 {
            for j in 0..3 {
                assert!((id[i * 3 + j] - f64::from(u8::from(i == j))).abs() < 1e-12);
            }
        }
        assert!(invert(&[1.0, 2.0, 2.0, 4.0], 2).is_none());
    }
}
