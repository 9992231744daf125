//! The fixed-point kernels at the AVX-512 level: the activations' scaling and packing (16
//! columns a vector, the AVX2 path's bits) and the product with VNNI (see [`super::vnni`];
//! the same panels as the AVX2 kernel).

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

/// `super::quant_b` 16 columns at a time: the AVX2 path's steps on twice the lanes (each
/// lane's largest magnitude from its values' bits without their signs, `1 / s` or 0, the
/// values rounded to nearest even and packed in pairs of rows), so the same bits.
///
/// # Safety
/// AVX-512F; `n` a multiple of 16; bounds as `super::quant_b` asserts.
#[target_feature(enable = "avx512f")]
pub unsafe fn quant_b(
    b: &[f32],
    k: usize,
    n: usize,
    ldb: usize,
    out: &mut [u32],
    scale: &mut [f32],
) {
    let (bp, op) = (b.as_ptr(), out.as_mut_ptr());
    let k2 = k.div_ceil(2);
    // SAFETY (whole function): rows < k at columns < n, output words < k2·n and scales < n,
    // which the caller's contract puts inside the slices.
    unsafe {
        let abs = _mm512_set1_epi32(0x7fff_ffff);
        let low = _mm512_set1_epi32(0xffff);
        let xm = _mm512_set1_ps(super::x_max(k2));
        let tiny = _mm512_set1_ps(f32::MIN_POSITIVE);
        let one = _mm512_set1_ps(1.0);
        for j in (0..n).step_by(16) {
            let mut big = _mm512_setzero_si512();
            for r in 0..k {
                let v = _mm512_loadu_si512(bp.add(r * ldb + j).cast());
                big = _mm512_max_epi32(big, _mm512_and_si512(v, abs));
            }
            // Infinity and NaN have every exponent bit set.
            let bad = _mm512_cmpgt_epi32_mask(big, _mm512_set1_epi32(0x7f7f_ffff));
            let s = _mm512_div_ps(_mm512_castsi512_ps(big), xm);
            let usable = !bad & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(s, tiny);
            let inv = _mm512_maskz_div_ps(usable, one, s);
            _mm512_storeu_ps(
                scale.as_mut_ptr().add(j),
                _mm512_mask_blend_ps(bad, s, _mm512_set1_ps(f32::NAN)),
            );
            for p in 0..k2 {
                // The default rounding mode: to nearest even, as `round_ties_even`.
                let q0 = _mm512_cvtps_epi32(_mm512_mul_ps(
                    _mm512_loadu_ps(bp.add(2 * p * ldb + j)),
                    inv,
                ));
                let q1 = if 2 * p + 1 < k {
                    _mm512_cvtps_epi32(_mm512_mul_ps(
                        _mm512_loadu_ps(bp.add((2 * p + 1) * ldb + j)),
                        inv,
                    ))
                } else {
                    _mm512_setzero_si512()
                };
                let w = _mm512_or_si512(_mm512_and_si512(q0, low), _mm512_slli_epi32::<16>(q1));
                _mm512_storeu_si512(op.add(p * n + j).cast(), w);
            }
        }
    }
}
