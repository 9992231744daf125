//! The fixed-point product kernel with AVX-512 VNNI (see [`super::vnni`]); the same panels as the AVX2 kernel.

use std::arch::x86_64::*;

/// Rows `i..i + R` (the panel at `a`) × columns `j..j + 32`, as `x86::block` with
/// AVX-512 VNNI: the same exact integer sums and the same two f32 roundings, so the
/// same bits.
///
/// # Safety
/// AVX-512F and VNNI; the rows, words and columns exist (as `gemm_vnni`'s contract).
#[inline(always)]
unsafe fn block<const R: usize>(
    a: *const u32,
    scale: &[f32],
    k2: usize,
    bp: *const u32,
    sb: *const f32,
    n: usize,
    c: *mut f32,
    ldc: usize,
    i: usize,
    j: usize,
) {
    // SAFETY: within the bounds the caller guarantees.
    unsafe {
        let mut acc = [[_mm512_setzero_si512(); 2]; R];
        let (mut wp, mut xp) = (a, bp.add(j));
        for _ in 0..k2 {
            let b0 = _mm512_loadu_si512(xp.cast());
            let b1 = _mm512_loadu_si512(xp.add(16).cast());
            for (r, row) in acc.iter_mut().enumerate() {
                let w = _mm512_set1_epi32(*wp.add(r) as i32);
                row[0] = _mm512_dpwssd_epi32(row[0], b0, w);
                row[1] = _mm512_dpwssd_epi32(row[1], b1, w);
            }
            (wp, xp) = (wp.add(R), xp.add(n));
        }
        let (s0, s1) = (_mm512_loadu_ps(sb.add(j)), _mm512_loadu_ps(sb.add(j + 16)));
        for (r, row) in acc.iter().enumerate() {
            let w = _mm512_set1_ps(scale[i + r]);
            let out = c.add((i + r) * ldc + j);
            let (t0, t1) = (_mm512_mul_ps(w, s0), _mm512_mul_ps(w, s1));
            _mm512_storeu_ps(out, _mm512_mul_ps(_mm512_cvtepi32_ps(row[0]), t0));
            _mm512_storeu_ps(out.add(16), _mm512_mul_ps(_mm512_cvtepi32_ps(row[1]), t1));
        }
    }
}

/// # Safety
/// AVX-512F and VNNI; as `x86::gemm`, with `n` a multiple of 32.
#[target_feature(enable = "avx512f,avx512vnni")]
pub unsafe fn gemm_vnni(
    a: &[u32],
    scale: &[f32],
    m: usize,
    k2: usize,
    bp: &[u32],
    sb: &[f32],
    n: usize,
    c: &mut [f32],
    ldc: usize,
) {
    // SAFETY: the caller's contract (`panels!`'s).
    unsafe { panels!(block, 32, a, scale, m, k2, bp, sb, n, c, ldc) }
}
