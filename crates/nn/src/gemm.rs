//! Matrix multiply through `matrixmultiply::sgemm`, behind a safe, checked interface.
//!
//! This is the only `unsafe` code in fishprobe's libraries: `sgemm` takes raw pointers and
//! strides. Every call goes through [`gemm`], which checks that each operand's slice covers
//! every element its dimensions and strides address before handing the pointers over.

#![allow(unsafe_code)]

/// A row-major matrix view (`rows x cols`), optionally read transposed.
#[derive(Debug, Clone, Copy)]
pub struct Mat<'a> {
    /// The elements, row-major.
    pub data: &'a [f32],
    /// Rows as stored.
    pub rows: usize,
    /// Columns as stored.
    pub cols: usize,
    /// Read as its transpose.
    pub t: bool,
}

impl<'a> Mat<'a> {
    /// A matrix as stored.
    pub fn new(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            t: false,
        }
    }
    /// Its transpose (no copy).
    pub fn t(self) -> Self {
        Self { t: !self.t, ..self }
    }
    fn shape(&self) -> (usize, usize) {
        if self.t {
            (self.cols, self.rows)
        } else {
            (self.rows, self.cols)
        }
    }
    /// (row stride, column stride) of the logical matrix.
    fn strides(&self) -> (isize, isize) {
        if self.t {
            (1, self.cols as isize)
        } else {
            (self.cols as isize, 1)
        }
    }
}

/// Up to this many rows of C, [`gemm`] uses plain loops: `sgemm` allocates packing buffers
/// on every call, which a per-frame inference of one or two fish (the ConvNet fish, a policy
/// acting alone) must not do, and its packing does not pay off for a matrix-vector product.
const SMALL_ROWS: usize = 4;

/// C = alpha · A · B + beta · C by rows, for few rows; `beta == 0` ignores C's contents, as
/// `sgemm` does.
fn small_gemm(
    alpha: f32,
    a: Mat<'_>,
    b: Mat<'_>,
    beta: f32,
    c: &mut [f32],
    (m, k, n): (usize, usize, usize),
) {
    let (rsa, csa) = a.strides();
    let (rsb, csb) = b.strides();
    let (rsa, csa, rsb, csb) = (rsa as usize, csa as usize, rsb as usize, csb as usize);
    for i in 0..m {
        let ci = &mut c[i * n..(i + 1) * n];
        if beta == 0.0 {
            ci.fill(0.0);
        } else if beta != 1.0 {
            ci.iter_mut().for_each(|x| *x *= beta);
        }
        for kk in 0..k {
            let av = alpha * a.data[i * rsa + kk * csa];
            if csb == 1 {
                let row = &b.data[kk * rsb..kk * rsb + n];
                ci.iter_mut().zip(row).for_each(|(x, y)| *x += av * y);
            } else {
                for (j, x) in ci.iter_mut().enumerate() {
                    *x += av * b.data[kk * rsb + j * csb];
                }
            }
        }
    }
}

/// C (m x n, row-major) = alpha · A · B + beta · C.
///
/// # Panics
/// When the shapes do not match or a slice is shorter than its matrix: a programming error,
/// never a data error.
pub fn gemm(alpha: f32, a: Mat<'_>, b: Mat<'_>, beta: f32, c: &mut [f32], m: usize, n: usize) {
    let (am, ak) = a.shape();
    let (bk, bn) = b.shape();
    assert!(
        am == m && bn == n && ak == bk,
        "gemm shapes: ({am}x{ak}) · ({bk}x{bn}) -> ({m}x{n})"
    );
    assert!(
        a.data.len() >= a.rows * a.cols && b.data.len() >= b.rows * b.cols,
        "gemm operand too short"
    );
    assert!(c.len() >= m * n, "gemm output too short");
    if m == 0 || n == 0 {
        return;
    }
    if m <= SMALL_ROWS {
        small_gemm(alpha, a, b, beta, c, (m, ak, n));
        return;
    }
    let (rsa, csa) = a.strides();
    let (rsb, csb) = b.strides();
    // SAFETY: the assertions above guarantee that every element addressed by the dimensions
    // (m, k, n) and the strides lies inside the slices; C is a unique borrow not aliasing A or B.
    unsafe {
        matrixmultiply::sgemm(
            m,
            ak,
            n,
            alpha,
            a.data.as_ptr(),
            rsa,
            csa,
            b.data.as_ptr(),
            rsb,
            csb,
            beta,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_few_rows_path_agrees_with_sgemm() {
        let (k, n) = (7, 5);
        let a: Vec<f32> = (0..8 * k)
            .map(|i| ((i * 13 % 17) as f32 - 8.0) / 7.0)
            .collect();
        let b: Vec<f32> = (0..k * n)
            .map(|i| ((i * 7 % 11) as f32 - 5.0) / 3.0)
            .collect();
        for (m, bt) in [(1, false), (3, false), (2, true), (4, true)] {
            let bm = if bt {
                Mat::new(&b, n, k).t()
            } else {
                Mat::new(&b, k, n)
            };
            let mut small = vec![1.0f32; m * n];
            gemm(0.5, Mat::new(&a[..m * k], m, k), bm, 2.0, &mut small, m, n);
            // The same rows inside a taller product take the sgemm path.
            let mut big = vec![1.0f32; 8 * n];
            gemm(0.5, Mat::new(&a, 8, k), bm, 2.0, &mut big, 8, n);
            for (x, y) in small.iter().zip(&big[..m * n]) {
                assert!((x - y).abs() < 1e-5, "m {m}, transposed {bt}: {x} vs {y}");
            }
        }
        let mut c = vec![f32::NAN; 2];
        gemm(
            1.0,
            Mat::new(&[1.0, 2.0], 1, 2),
            Mat::new(&[1.0, 0.0, 0.0, 1.0], 2, 2),
            0.0,
            &mut c,
            1,
            2,
        );
        assert_eq!(c, [1.0, 2.0], "beta = 0 ignores C");
    }

    #[test]
    fn matches_naive_products_with_transposes() {
        let a: Vec<f32> = (0..6).map(|v| v as f32).collect(); // 2 x 3
        let b: Vec<f32> = (0..12).map(|v| (v as f32) * 0.5).collect(); // 3 x 4
        let mut c = vec![1.0; 8];
        gemm(
            1.0,
            Mat::new(&a, 2, 3),
            Mat::new(&b, 3, 4),
            0.0,
            &mut c,
            2,
            4,
        );
        // Row 0: [0,1,2] · columns of b.
        assert_eq!(c[0], 0.0 * 0.0 + 1.0 * 2.0 + 2.0 * 4.0);
        assert_eq!(c[7], 3.0 * 1.5 + 4.0 * 3.5 + 5.0 * 5.5);
        // Aᵀ (3 x 2) · A (2 x 3) = 3 x 3 Gram matrix.
        let mut g = vec![0.0; 9];
        gemm(
            1.0,
            Mat::new(&a, 2, 3).t(),
            Mat::new(&a, 2, 3),
            0.0,
            &mut g,
            3,
            3,
        );
        assert_eq!(g[0], 0.0 * 0.0 + 3.0 * 3.0);
        assert_eq!(g[5], 1.0 * 2.0 + 4.0 * 5.0);
        // beta accumulates.
        gemm(
            1.0,
            Mat::new(&a, 2, 3).t(),
            Mat::new(&a, 2, 3),
            1.0,
            &mut g,
            3,
            3,
        );
        assert_eq!(g[0], 18.0);
    }

    #[test]
    #[should_panic(expected = "gemm shapes")]
    fn mismatched_shapes_panic_before_touching_memory() {
        let a = [0.0; 6];
        let mut c = [0.0; 4];
        gemm(
            1.0,
            Mat::new(&a, 2, 3),
            Mat::new(&a, 2, 3),
            0.0,
            &mut c,
            2,
            2,
        );
    }
}
