//! The two products of a network's first layer with a sparse input (the policy's
//! observations, 22 % nonzero): A · B and Aᵀ · D from A's nonzeros, giving sgemm's results
//! bit for bit where sgemm runs its FMA kernels.

// The kernels are AVX2/FMA functions, called only after the CPU check in `SparseRows::build`.
#![allow(unsafe_code)]

use super::{avx2_fma_supported, SGEMM_KC, SMALL_ROWS};
#[cfg(target_arch = "x86_64")]
use super::{
    fma::{self, chunk_at, panel_at},
    CHUNK, PW, RB,
};

/// The sparse products are used when at most this fraction of A's entries is nonzero: they do
/// one load per FMA where sgemm does about a quarter, so below about half the entries they are
/// faster. The policy's observations are 22 % nonzero (the 36 wall rays and one entry in each
/// of the four 36-bin blocks of fish and goal).
const SPARSE_MAX_DENSITY: f32 = 0.5;

/// The nonzero entries of a row-major matrix A (m x k), listed by row, and the scratch of the
/// by-column lists [`SparseRows::t_mul_acc`] makes from them; reused across calls.
#[derive(Debug, Clone, Default)]
pub struct SparseRows {
    m: usize,
    k: usize,
    /// Column index and value of each nonzero, row by row.
    idx: Vec<u32>,
    val: Vec<f32>,
    /// Where each row's entries start (m + 1 values).
    start: Vec<usize>,
    /// How many leading columns are nonzero in every row (the observation's 36 wall rays):
    /// there A is dense, and the products share each load of the other operand between four
    /// rows or columns of A.
    pub(super) dense: usize,
    /// The entries of one block of rows by column: row index, value, column starts.
    col_idx: Vec<u32>,
    col_val: Vec<f32>,
    col_start: Vec<usize>,
    fill: Vec<usize>,
}

/// Whether the sparse products run on this CPU (x86-64 with AVX2 and FMA).
pub fn sparse_supported() -> bool {
    avx2_fma_supported()
}

impl SparseRows {
    /// Lists A's nonzeros when the sparse products pay and run here: A has more than
    /// `SMALL_ROWS` rows (fewer take [`gemm`](super::gemm)'s plain loops), at most
    /// SPARSE_MAX_DENSITY of its entries are nonzero, and the CPU has AVX2 and FMA. Returns
    /// whether it did; when not, multiply densely.
    ///
    /// # Panics
    /// When `a` is shorter than m x k (a programming error).
    pub fn build(&mut self, a: &[f32], m: usize, k: usize) -> bool {
        assert!(a.len() >= m * k, "sparse operand too short");
        let a = &a[..m * k];
        if m <= SMALL_ROWS || k == 0 || !sparse_supported() {
            return false;
        }
        let nonzero: usize = a.iter().map(|v| usize::from(*v != 0.0)).sum();
        if nonzero as f32 > SPARSE_MAX_DENSITY * a.len() as f32 {
            return false;
        }
        (self.m, self.k) = (m, k);
        self.idx.resize(nonzero + 1, 0);
        self.val.resize(nonzero + 1, 0.0);
        self.start.resize(m + 1, 0);
        let mut len = 0;
        for (i, row) in a.chunks_exact(k).enumerate() {
            self.start[i] = len;
            // Branch-free: every entry is written, only a nonzero advances.
            for (j, &v) in row.iter().enumerate() {
                self.idx[len] = j as u32;
                self.val[len] = v;
                len += usize::from(v != 0.0);
            }
        }
        self.start[m] = len;
        self.dense = (0..m)
            .map(|i| {
                let row = &self.idx[self.start[i]..self.start[i + 1]];
                row.iter()
                    .enumerate()
                    .take_while(|(t, j)| **j as usize == *t)
                    .count()
            })
            .min()
            .unwrap_or(0);
        true
    }

    /// C (m x n) = A · B with B (k x n) row-major: `gemm(1.0, A, B, 0.0, C)` bit for bit.
    ///
    /// # Panics
    /// When a slice is shorter than its matrix (a programming error).
    pub fn mul(&self, b: &[f32], n: usize, c: &mut [f32]) {
        assert!(b.len() >= self.k * n && c.len() >= self.m * n);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `build` succeeded, so the CPU has AVX2 and FMA.
        unsafe {
            rows_fma(self, b, n, &mut c[..self.m * n]);
        }
    }

    /// C (k x n) += Aᵀ · D with D (m x n) row-major: `gemm(1.0, Aᵀ, D, 1.0, C)` bit for bit.
    ///
    /// # Panics
    /// When a slice is shorter than its matrix (a programming error).
    pub fn t_mul_acc(&mut self, d: &[f32], n: usize, c: &mut [f32]) {
        let (m, k) = (self.m, self.k);
        assert!(d.len() >= m * n && c.len() >= k * n);
        // Leading dense columns of A, in whole blocks of RB, go through the dense-prefix kernel;
        // the rest through by-column lists of their nonzeros.
        let handled = if n.is_multiple_of(PW) {
            self.dense / RB * RB
        } else {
            0
        };
        // sgemm's inner dimension is m here: one pass per block of SGEMM_KC rows of A.
        for r0 in (0..m).step_by(SGEMM_KC) {
            let r1 = (r0 + SGEMM_KC).min(m);
            if handled > 0 {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `build` succeeded, so the CPU has AVX2 and FMA.
                unsafe {
                    cols_dense_prefix(self, d, n, &mut c[..k * n], r0..r1, handled);
                }
            }
            let entries = self.start[r0]..self.start[r1];
            self.col_start.clear();
            self.col_start.resize(k + 1, 0);
            for &j in &self.idx[entries.clone()] {
                self.col_start[j as usize + 1] += usize::from(j as usize >= handled);
            }
            for j in 0..k {
                self.col_start[j + 1] += self.col_start[j];
            }
            self.col_idx.resize(entries.len(), 0);
            self.col_val.resize(entries.len(), 0.0);
            self.fill.clear();
            self.fill.extend_from_slice(&self.col_start[..k]);
            for i in r0..r1 {
                for e in self.start[i] + handled..self.start[i + 1] {
                    let j = self.idx[e] as usize;
                    self.col_idx[self.fill[j]] = i as u32;
                    self.col_val[self.fill[j]] = self.val[e];
                    self.fill[j] += 1;
                }
            }
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `build` succeeded, so the CPU has AVX2 and FMA.
            unsafe {
                cols_fma(self, d, n, &mut c[..k * n], handled);
            }
        }
    }
}

/// Row i of C = Σ over row i's entries (index order) of value · row `idx` of B, in SGEMM_KC
/// blocks of the index, FMA-accumulated; column panels outer so that a panel of B stays in the
/// L1 cache.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn rows_fma(s: &SparseRows, b: &[f32], n: usize, c: &mut [f32]) {
    // Whole blocks of RB rows whose dense prefix can share loads of B, when the inner dimension
    // is one sgemm block; the other rows one at a time.
    let blocked = if s.dense > 0 && s.k <= SGEMM_KC && n.is_multiple_of(PW) {
        s.m / RB * RB
    } else {
        0
    };
    rows_dense_prefix(s, b, n, &mut c[..blocked * n]);
    for j0 in (0..n).step_by(CHUNK) {
        let w = CHUNK.min(n - j0);
        for (i, crow) in c.chunks_exact_mut(n).enumerate().skip(blocked) {
            let entries = s.start[i]..s.start[i + 1];
            let (idx, val) = (&s.idx[entries.clone()], &s.val[entries]);
            let out = &mut crow[j0..j0 + w];
            let mut t = 0;
            for k0 in (0..s.k).step_by(SGEMM_KC) {
                let t0 = t;
                while t < idx.len() && (idx[t] as usize) < k0 + SGEMM_KC {
                    t += 1;
                }
                let sum = block_sum(&idx[t0..t], &val[t0..t], b, n, j0, w);
                if k0 == 0 {
                    out.copy_from_slice(&sum[..w]);
                } else {
                    out.iter_mut().zip(&sum).for_each(|(o, x)| *o += x);
                }
            }
        }
    }
}

/// `rows_fma` for the rows of `c` (a multiple of RB; the inner dimension one sgemm block, n a
/// multiple of PW): RB rows at a time, their dense prefixes sharing each load of B, then each
/// row's remaining entries. Every element is still one FMA chain from zero over its row's
/// entries in index order, as in `block_sum`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn rows_dense_prefix(s: &SparseRows, b: &[f32], n: usize, c: &mut [f32]) {
    let p = s.dense;
    for j0 in (0..n).step_by(PW) {
        for (g, cblock) in c.chunks_exact_mut(RB * n).enumerate() {
            let first = &s.start[g * RB..g * RB + RB + 1];
            let mut acc = [fma::zero_pair(); RB];
            for kk in 0..p {
                let x = fma::load_pair(panel_at(b, kk * n + j0));
                for (a, &st) in acc.iter_mut().zip(first) {
                    fma::fma_pair(a, s.val[st + kk], &x);
                }
            }
            for (r, a) in acc.iter_mut().enumerate() {
                let tail = first[r] + p..first[r + 1];
                for (&j, &v) in s.idx[tail.clone()].iter().zip(&s.val[tail]) {
                    fma::fma_pair(a, v, &fma::load_pair(panel_at(b, j as usize * n + j0)));
                }
                cblock[r * n + j0..r * n + j0 + PW].copy_from_slice(&fma::store_pair(a));
            }
        }
    }
}

/// Rows 0..handled of C (A's dense leading columns, a multiple of RB) += Σ over the rows of
/// the block (in order) of A's value · that row of D, RB columns of A at a time sharing each
/// load of D; each element's block sum is one FMA chain from zero, then added, as in
/// `cols_fma`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn cols_dense_prefix(
    s: &SparseRows,
    d: &[f32],
    n: usize,
    c: &mut [f32],
    rows: std::ops::Range<usize>,
    handled: usize,
) {
    for j0 in (0..n).step_by(PW) {
        for f0 in (0..handled).step_by(RB) {
            let mut acc = [fma::zero_pair(); RB];
            for i in rows.clone() {
                let x = fma::load_pair(panel_at(d, i * n + j0));
                let v = &s.val[s.start[i] + f0..s.start[i] + f0 + RB];
                for (a, &v) in acc.iter_mut().zip(v) {
                    fma::fma_pair(a, v, &x);
                }
            }
            for (f, a) in acc.iter().enumerate() {
                let sum = fma::store_pair(a);
                c[(f0 + f) * n + j0..(f0 + f) * n + j0 + PW]
                    .iter_mut()
                    .zip(&sum)
                    .for_each(|(o, x)| *o += x);
            }
        }
    }
}

/// Row j of C += Σ over column j's entries (row order) of value · row `idx` of D,
/// FMA-accumulated, then added, for the columns j from `handled` on; column panels outer.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn cols_fma(s: &SparseRows, d: &[f32], n: usize, c: &mut [f32], handled: usize) {
    for j0 in (0..n).step_by(CHUNK) {
        let w = CHUNK.min(n - j0);
        for (j, crow) in c.chunks_exact_mut(n).enumerate().take(s.k).skip(handled) {
            let entries = s.col_start[j]..s.col_start[j + 1];
            let sum = block_sum(
                &s.col_idx[entries.clone()],
                &s.col_val[entries],
                d,
                n,
                j0,
                w,
            );
            crow[j0..j0 + w]
                .iter_mut()
                .zip(&sum)
                .for_each(|(o, x)| *o += x);
        }
    }
}

/// Σ over the entries (in order) of value · columns j0..j0+w of row `idx` of X (row-major,
/// n wide), each column's sum accumulated from zero with FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn block_sum(idx: &[u32], val: &[f32], x: &[f32], n: usize, j0: usize, w: usize) -> [f32; CHUNK] {
    if w == CHUNK {
        let mut acc = fma::zero();
        for (&r, &v) in idx.iter().zip(val) {
            fma::fma(&mut acc, v, chunk_at(x, r as usize * n + j0));
        }
        fma::store(&acc)
    } else {
        let mut acc = [0.0f32; CHUNK];
        for (&r, &v) in idx.iter().zip(val) {
            let row = &x[r as usize * n + j0..][..w];
            acc.iter_mut()
                .zip(row)
                .for_each(|(a, &x)| *a = v.mul_add(x, *a));
        }
        acc
    }
}
