//! Matrix multiply through `matrixmultiply::sgemm`, behind a safe, checked interface; the
//! two products of a network's first layer with a sparse input ([`SparseRows`], in
//! `sparse.rs`); and products with few rows against a packed weight matrix
//! ([`fma_chain_gemm`], in `chain.rs`).
//!
//! This module and its children are nearly all the `unsafe` code in fishprobe's libraries
//! (the rest: `Mlp::forward` and `Mlp::backward` calling their AVX2-compiled copies after the
//! same CPU check): `sgemm` takes raw pointers and strides. Every call goes through [`gemm`],
//! which checks that each operand's slice covers every element its dimensions and strides
//! address before handing the pointers over. The sparse and chain products use AVX2/FMA
//! intrinsics (`fma.rs`): they run only after a run-time check that the CPU has those
//! features, and their vector loads and stores only on slices checked to be 8 long.

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

/// sgemm (matrixmultiply 0.3, its `S_KC`) sums the inner dimension in blocks of this many
/// terms: each block's sum is accumulated from zero with FMA in index order, then added to C.
/// The sparse products sum in the same blocks and order, so that where sgemm runs its FMA
/// kernels (every x86-64 CPU with FMA) they give its results bit for bit.
const SGEMM_KC: usize = 256;

/// Output columns the sparse kernels keep in registers at a time: eight AVX vectors, so eight
/// independent FMA chains hide the FMA latency.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const CHUNK: usize = 64;

/// Rows (or, for Aᵀ·D, columns of A) per register block and output columns per panel of the
/// dense-prefix kernels: 4 x 16 floats are eight AVX accumulators, and each loaded vector of
/// the other operand serves four of them.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const RB: usize = 4;
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const PW: usize = 16;

/// Whether this CPU is x86-64 with AVX2 and FMA (checked once, then cached by the standard
/// library).
pub fn avx2_fma_supported() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The sparse kernels' and the chain kernel's vector arithmetic.
#[cfg(target_arch = "x86_64")]
mod fma;

mod chain;
mod sparse;

pub use chain::{fma_chain_gemm, PackedMatrix};
pub use sparse::{sparse_supported, SparseRows};

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix with about one entry in four nonzero, in a fixed pattern.
    fn sparse_matrix(rows: usize, cols: usize, salt: usize) -> Vec<f32> {
        (0..rows * cols)
            .map(|i| {
                let h = (i * 2654435761 + salt * 97) % 1009;
                if h.is_multiple_of(4) {
                    (h as f32 - 504.0) / 313.0
                } else {
                    0.0
                }
            })
            .collect()
    }

    fn same_bits(x: &[f32], y: &[f32]) -> bool {
        x.len() == y.len() && x.iter().zip(y).all(|(a, b)| a.to_bits() == b.to_bits())
    }

    #[test]
    fn fma_chain_gemm_is_the_product_and_independent_of_the_batch() {
        if !avx2_fma_supported() {
            return;
        }
        // The ConvNet fish's layer shapes, and rows and columns off the register block.
        for (m, k, n) in [
            (32, 576, 128),
            (13, 128, 1025),
            (5, 3, 17),
            (1, 40, 16),
            (6, 300, 9),
        ] {
            let a: Vec<f32> = (0..m * k)
                .map(|i| ((i * 37) % 101) as f32 / 50.0 - 1.0)
                .collect();
            let b: Vec<f32> = (0..k * n)
                .map(|i| ((i * 53) % 97) as f32 / 48.0 - 1.0)
                .collect();
            let mut c = vec![f32::NAN; m * n];
            let packed = PackedMatrix::new(&b, k, n);
            assert!(fma_chain_gemm(&a, &packed, &mut c, m));
            for i in 0..m {
                for j in 0..n {
                    let exact: f64 = (0..k)
                        .map(|t| f64::from(a[i * k + t]) * f64::from(b[t * n + j]))
                        .sum();
                    // one FMA chain, element by element
                    let chain = (0..k).fold(0.0f32, |s, t| a[i * k + t].mul_add(b[t * n + j], s));
                    assert_eq!(
                        c[i * n + j].to_bits(),
                        chain.to_bits(),
                        "({m},{k},{n}) [{i},{j}]"
                    );
                    assert!((f64::from(c[i * n + j]) - exact).abs() < 1e-4 * (1.0 + exact.abs()));
                }
                // each row alone gives the same bits as in the batch
                let mut row = vec![0.0; n];
                fma_chain_gemm(&a[i * k..(i + 1) * k], &packed, &mut row, 1);
                assert!(
                    same_bits(&row, &c[i * n..(i + 1) * n]),
                    "({m},{k},{n}) row {i}"
                );
            }
        }
    }

    #[test]
    fn sparse_products_give_sgemm_bit_for_bit() {
        // Shapes: the policy's first layer, an inner dimension past sgemm's 256-block, and
        // output widths that are not a multiple of the register chunk.
        // With `dense` leading columns nonzero in every row (an observation's wall rays), the
        // dense-prefix kernels run where the shapes allow.
        for (m, k, n, dense) in [
            (512, 180, 256, 0),
            (512, 180, 256, 36),
            (37, 300, 45, 0),
            (37, 300, 48, 10),
            (600, 13, 70, 3),
            (9, 50, 32, 7),
        ] {
            let mut a = sparse_matrix(m, k, 1);
            for (i, row) in a.chunks_exact_mut(k).enumerate() {
                for (j, v) in row[..dense].iter_mut().enumerate() {
                    *v = 0.25 + ((i * 7 + j * 3) % 11) as f32 / 13.0;
                }
            }
            let b: Vec<f32> = (0..k * n)
                .map(|i| ((i * 31 % 97) as f32 - 48.0) / 17.0)
                .collect();
            let d: Vec<f32> = (0..m * n)
                .map(|i| ((i * 17 % 89) as f32 - 44.0) / 23.0)
                .collect();
            let mut s = SparseRows::default();
            let ran = s.build(&a, m, k);
            assert_eq!(ran, sparse_supported());
            if !ran {
                continue;
            }
            assert!(
                s.dense >= dense,
                "{} dense columns found of {dense}",
                s.dense
            );
            let mut dense = vec![0.0f32; m * n];
            let (am, bm) = (Mat::new(&a, m, k), Mat::new(&b, k, n));
            gemm(1.0, am, bm, 0.0, &mut dense, m, n);
            let mut sparse = vec![f32::NAN; m * n];
            s.mul(&b, n, &mut sparse);
            assert!(
                same_bits(&dense, &sparse),
                "A·B ({m}x{k}x{n}, {} dense columns) differs from sgemm",
                s.dense
            );

            let start: Vec<f32> = (0..k * n).map(|i| (i % 7) as f32 * 0.1).collect();
            let mut dense = start.clone();
            gemm(1.0, am.t(), Mat::new(&d, m, n), 1.0, &mut dense, k, n);
            let mut sparse = start;
            s.t_mul_acc(&d, n, &mut sparse);
            assert!(
                same_bits(&dense, &sparse),
                "C + Aᵀ·D ({m}x{k}x{n}, {} dense columns) differs from sgemm",
                s.dense
            );
        }
        // Too dense, or too few rows: declined.
        let mut s = SparseRows::default();
        assert!(!s.build(&[1.0; 8 * 10], 8, 10));
        assert!(!s.build(&sparse_matrix(4, 10, 2), 4, 10));
    }

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
