//! Matrix multiply through `matrixmultiply::sgemm`, behind a safe, checked interface, and the
//! two products of a network's first layer with a sparse input ([`SparseRows`]).
//!
//! This is nearly all the `unsafe` code in fishprobe's libraries (the rest: `Mlp::forward` and
//! `Mlp::backward` calling their AVX2-compiled copies after the same CPU check): `sgemm` takes raw pointers and
//! strides. Every call goes through [`gemm`], which checks that each operand's slice covers
//! every element its dimensions and strides address before handing the pointers over. The
//! sparse products use AVX2/FMA intrinsics: they run only after a run-time check that the CPU
//! has those features, and their vector loads and stores only on slices checked to be 8 long.

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

/// The sparse products are used when at most this fraction of A's entries is nonzero: they do
/// one load per FMA where sgemm does about a quarter, so below about half the entries they are
/// faster. The policy's observations are 22 % nonzero (the 36 wall rays and one entry in each
/// of the four 36-bin blocks of fish and goal).
const SPARSE_MAX_DENSITY: f32 = 0.5;

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

/// Inner-dimension block of [`fma_chain_gemm`]: a 16-column panel of B this deep is 8 KB, so
/// it stays in the L1 cache while every row block of A passes over it.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const CHAIN_KC: usize = 128;

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
    dense: usize,
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

impl SparseRows {
    /// Lists A's nonzeros when the sparse products pay and run here: A has more than
    /// `SMALL_ROWS` rows (fewer take [`gemm`]'s plain loops), at most SPARSE_MAX_DENSITY of
    /// its entries are nonzero, and the CPU has AVX2 and FMA. Returns whether it did; when
    /// not, multiply densely.
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

#[cfg(target_arch = "x86_64")]
mod fma {
    //! The sparse kernels' vector arithmetic: CHUNK / 8 AVX vectors of accumulators, or PW / 8
    //! for the dense-prefix kernels.
    use super::{CHUNK, PW};
    use std::arch::x86_64::{
        __m256, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_set1_ps, _mm256_setzero_ps,
        _mm256_storeu_ps,
    };

    /// CHUNK accumulators in registers.
    pub type Acc = [__m256; CHUNK / 8];

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn zero() -> Acc {
        [_mm256_setzero_ps(); CHUNK / 8]
    }

    /// acc = v · x + acc, elementwise with FMA.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn fma(acc: &mut Acc, v: f32, x: &[f32; CHUNK]) {
        let vv = _mm256_set1_ps(v);
        for (q, a) in acc.iter_mut().enumerate() {
            // SAFETY: x holds CHUNK floats, 8q + 8 <= CHUNK; this reads 8 of them from 8q.
            let xv = unsafe { _mm256_loadu_ps(x[8 * q..].as_ptr()) };
            *a = _mm256_fmadd_ps(vv, xv, *a);
        }
    }

    /// PW accumulators, or PW floats of the other operand, in registers.
    pub type Pair = [__m256; PW / 8];

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn zero_pair() -> Pair {
        [_mm256_setzero_ps(); PW / 8]
    }

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn load_pair(x: &[f32; PW]) -> Pair {
        // SAFETY: x holds PW = 16 floats; these read 8 from 0 and 8 from 8.
        unsafe {
            [
                _mm256_loadu_ps(x.as_ptr()),
                _mm256_loadu_ps(x[8..].as_ptr()),
            ]
        }
    }

    /// acc = v · x + acc, elementwise with FMA.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn fma_pair(acc: &mut Pair, v: f32, x: &Pair) {
        let vv = _mm256_set1_ps(v);
        acc[0] = _mm256_fmadd_ps(vv, x[0], acc[0]);
        acc[1] = _mm256_fmadd_ps(vv, x[1], acc[1]);
    }

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn store_pair(acc: &Pair) -> [f32; PW] {
        let mut out = [0.0f32; PW];
        // SAFETY: out holds PW = 16 floats; these write 8 from 0 and 8 from 8.
        unsafe {
            _mm256_storeu_ps(out.as_mut_ptr(), acc[0]);
            _mm256_storeu_ps(out[8..].as_mut_ptr(), acc[1]);
        }
        out
    }

    /// The accumulators as floats.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    pub fn store(acc: &Acc) -> [f32; CHUNK] {
        let mut out = [0.0f32; CHUNK];
        for (q, a) in acc.iter().enumerate() {
            // SAFETY: out holds CHUNK floats, 8q + 8 <= CHUNK; this writes 8 of them from 8q.
            unsafe { _mm256_storeu_ps(out[8 * q..].as_mut_ptr(), *a) };
        }
        out
    }
}

/// A full chunk of a row as an array reference.
#[cfg(target_arch = "x86_64")]
#[inline]
fn chunk_at(v: &[f32], at: usize) -> &[f32; CHUNK] {
    v[at..at + CHUNK].try_into().expect("CHUNK floats")
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

/// PW floats of a row as an array reference.
#[cfg(target_arch = "x86_64")]
#[inline]
fn panel_at(v: &[f32], at: usize) -> &[f32; PW] {
    v[at..at + PW].try_into().expect("PW floats")
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
