//! Products with few rows against a weight matrix packed once ([`PackedMatrix`]): the
//! ConvNet fish's layers for one frame's fish.

// The kernel is an AVX2/FMA function, called only after the CPU check in `fma_chain_gemm`.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use super::fma::{self, panel_at};
use super::{avx2_fma_supported, PW};

/// Inner-dimension block of [`fma_chain_gemm`]: a 16-column panel of B this deep is 8 KB, so
/// it stays in the L1 cache while every row block of A passes over it.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const CHAIN_KC: usize = 128;

/// A weight matrix B (k x n, row-major) laid out once for [`fma_chain_gemm`]: panels of 16
/// columns, each k x 16 contiguous, the last panel padded with zero columns. Products with
/// few rows (the ConvNet fish's layers for one frame's fish) read it in order, where sgemm
/// would repack B at every call and B's own rows (1,025 floats for the ConvNet's output
/// layer, about 4 KB apart) fall into the same cache sets.
#[derive(Debug, Clone, PartialEq)]
pub struct PackedMatrix {
    k: usize,
    n: usize,
    panels: Vec<f32>,
}

impl PackedMatrix {
    /// Packs B (k x n, row-major).
    ///
    /// # Panics
    /// When `b` is shorter than k x n (a programming error).
    pub fn new(b: &[f32], k: usize, n: usize) -> Self {
        assert!(b.len() >= k * n, "matrix too short");
        let count = n.div_ceil(PW);
        let mut panels = vec![0.0; count * k * PW];
        // `max(1)`: with k = 0 there are no panel rows to fill (and chunks may not be empty).
        for (p, panel) in panels.chunks_exact_mut((k * PW).max(1)).enumerate() {
            let (j0, w) = (p * PW, PW.min(n - p * PW));
            for (t, row) in panel.chunks_exact_mut(PW).enumerate() {
                row[..w].copy_from_slice(&b[t * n + j0..t * n + j0 + w]);
            }
        }
        Self { k, n, panels }
    }

    /// (rows, columns) of B.
    pub fn shape(&self) -> (usize, usize) {
        (self.k, self.n)
    }
}

/// C (m x n) = A (m x k, row-major) · B, where every element of C is one FMA chain over the
/// inner dimension from zero, in index order. So a row's result does not depend on how many
/// rows come with it or where it sits (sgemm's does: it adds in blocks of 256 and takes plain
/// loops for at most four rows). Register blocks of 4 rows x 16 columns; the last rows (m not
/// a multiple of 4) take the same chains one row at a time. Returns `false`, computing
/// nothing, on CPUs without AVX2 and FMA.
///
/// # Panics
/// When a slice is shorter than its matrix (a programming error).
#[allow(unsafe_code)]
pub fn fma_chain_gemm(a: &[f32], b: &PackedMatrix, c: &mut [f32], m: usize) -> bool {
    let (k, n) = b.shape();
    assert!(a.len() >= m * k && c.len() >= m * n);
    #[cfg(target_arch = "x86_64")]
    if avx2_fma_supported() {
        if k == 0 {
            // An empty sum.
            c[..m * n].fill(0.0);
        } else {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            unsafe { fma_chain_gemm_avx2(&a[..m * k], b, &mut c[..m * n]) };
        }
        return true;
    }
    false
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fma_chain_gemm_avx2(a: &[f32], b: &PackedMatrix, c: &mut [f32]) {
    let (k, n) = b.shape();
    let m = c.len() / n.max(1);
    for (p, panel) in b.panels.chunks_exact(k * PW).enumerate() {
        let cols = p * PW..(p * PW + PW).min(n);
        // The inner dimension in blocks, so that the part of the panel they read (CHAIN_KC x
        // 16 floats) stays in the L1 cache across all the rows; the accumulators go through C
        // between blocks, which continues each FMA chain unchanged.
        for k0 in (0..k).step_by(CHAIN_KC) {
            let inner = k0..(k0 + CHAIN_KC).min(k);
            let part = &panel[inner.start * PW..inner.end * PW];
            // Four rows per register block (eight accumulators: six rows measured slower),
            // then what is left.
            let mut i = 0;
            while i < m {
                let left = m - i;
                let rows = if left >= 4 {
                    chain_block::<4>(a, part, c, i, k, n, &inner, &cols)
                } else if left >= 2 {
                    chain_block::<2>(a, part, c, i, k, n, &inner, &cols)
                } else {
                    chain_block::<1>(a, part, c, i, k, n, &inner, &cols)
                };
                i += rows;
            }
        }
    }
}

/// Rows i..i+R of C, columns `cols` (one panel), continue their FMA chains over the inner
/// indices `inner` (`part`: those rows of the panel); returns R.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn chain_block<const R: usize>(
    a: &[f32],
    part: &[f32],
    c: &mut [f32],
    i: usize,
    k: usize,
    n: usize,
    inner: &std::ops::Range<usize>,
    cols: &std::ops::Range<usize>,
) -> usize {
    let (j0, w) = (cols.start, cols.len());
    let mut rows: [&[f32]; R] = [&[]; R];
    for (r, row) in rows.iter_mut().enumerate() {
        *row = &a[(i + r) * k + inner.start..(i + r) * k + inner.end];
    }
    let mut acc = [fma::zero_pair(); R];
    let mut out = [0.0f32; PW];
    if inner.start > 0 {
        for (r, acc) in acc.iter_mut().enumerate() {
            let at = (i + r) * n + j0;
            *acc = if w == PW {
                fma::load_pair(panel_at(c, at))
            } else {
                out[..w].copy_from_slice(&c[at..at + w]);
                fma::load_pair(&out)
            };
        }
    }
    for (t, x) in part.chunks_exact(PW).enumerate() {
        let x = fma::load_pair(panel_at(x, 0));
        for (acc, row) in acc.iter_mut().zip(&rows) {
            fma::fma_pair(acc, row[t], &x);
        }
    }
    for (r, acc) in acc.iter().enumerate() {
        let at = (i + r) * n + j0;
        out = fma::store_pair(acc);
        if w == PW {
            let full: &mut [f32; PW] = (&mut c[at..at + PW]).try_into().expect("PW floats");
            *full = out;
        } else {
            c[at..at + w].copy_from_slice(&out[..w]);
        }
    }
    R
}
