//! The sparse kernels' vector arithmetic: CHUNK / 8 AVX vectors of accumulators, or PW / 8
//! for the dense-prefix kernels and the chain kernel; and the checked array views their
//! loads and stores take.

// The vector loads and stores are unsafe by their signature; each is on an array of the
// length it reads or writes.
#![allow(unsafe_code)]
use super::{CHUNK, PW};
use std::arch::x86_64::{
    __m256, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_set1_ps, _mm256_setzero_ps, _mm256_storeu_ps,
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

/// A full chunk of a row as an array reference.
#[inline]
pub fn chunk_at(v: &[f32], at: usize) -> &[f32; CHUNK] {
    v[at..at + CHUNK].try_into().expect("CHUNK floats")
}

/// PW floats of a row as an array reference.
#[inline]
pub fn panel_at(v: &[f32], at: usize) -> &[f32; PW] {
    v[at..at + PW].try_into().expect("PW floats")
}
