//! Hash-grid kernels (instant-NGP encoding): the 8 corner indices and trilinear weights of
//! a batch of positions at one level, and the gather-and-interpolate of F = 2 features that
//! dominates the encoding's forward pass.
//!
//! The vector variants compute 16 (AVX-512) or 8 (AVX2) lanes at a time — cell, fractions,
//! weights, dense or hashed indices — and gather the table with hardware gathers (by
//! scalar loads where gathers are slow, [`crate::slow_gathers`]); the scalar variant is
//! the reference and handles the lanes left over.

use crate::Level;

/// One level of the grid, as the kernels need it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridLevel {
    /// Cells per axis (grid points per axis are `res + 1`).
    pub res: u32,
    /// Entries in the level's table; a power of two when hashed.
    pub size: u32,
    /// Indexed directly rather than hashed.
    pub dense: bool,
}

/// The spatial hash's primes for y and z (x uses 1).
pub const PRIME_Y: u32 = 2_654_435_761;
pub const PRIME_Z: u32 = 805_459_861;

/// Corner indices (within the level's table) and trilinear weights of one position in
/// [0, 1]³ (outside values and NaN are clamped into it): the scalar reference. Corner `k`
/// is offset by `(k & 1, k >> 1 & 1, k >> 2)` cells.
#[inline(always)]
pub fn corners_one(lv: &GridLevel, x: f32, y: f32, z: f32) -> ([u32; 8], [f32; 8]) {
    let r = lv.res as f32;
    let cell = |v: f32| {
        // `max` first: NaN.max(0) is 0, as in the vector variants (`clamp` keeps NaN).
        #[allow(clippy::manual_clamp)]
        let p = v.max(0.0).min(1.0) * r;
        let c = (p as u32).min(lv.res - 1); // p ≥ 0, so `as` is floor
        (c, p - c as f32)
    };
    let ((cx, fx), (cy, fy), (cz, fz)) = (cell(x), cell(y), cell(z));
    let wxy = [
        (1.0 - fx) * (1.0 - fy),
        fx * (1.0 - fy),
        (1.0 - fx) * fy,
        fx * fy,
    ];
    let mut w = [0f32; 8];
    for k in 0..4 {
        w[k] = wxy[k] * (1.0 - fz);
        w[k + 4] = wxy[k] * fz;
    }
    let mut idx = [0u32; 8];
    if lv.dense {
        let s = lv.res + 1;
        let base = cx + cy * s + cz * s * s;
        for (k, i) in idx.iter_mut().enumerate() {
            *i = base
                + (k & 1) as u32
                + if k & 2 != 0 { s } else { 0 }
                + if k & 4 != 0 { s * s } else { 0 };
        }
    } else {
        let mask = lv.size - 1;
        let hy0 = cy.wrapping_mul(PRIME_Y);
        let hz0 = cz.wrapping_mul(PRIME_Z);
        let hy = [hy0, hy0.wrapping_add(PRIME_Y)];
        let hz = [hz0, hz0.wrapping_add(PRIME_Z)];
        for (k, i) in idx.iter_mut().enumerate() {
            *i = ((cx + (k & 1) as u32) ^ hy[(k >> 1) & 1] ^ hz[k >> 2]) & mask;
        }
    }
    (idx, w)
}

fn check(lv: &GridLevel, pos: [&[f32]; 3]) -> usize {
    let n = pos[0].len();
    assert!(
        pos[1].len() == n && pos[2].len() == n,
        "grid: position lengths"
    );
    assert!(lv.res >= 1, "grid: resolution 0");
    if lv.dense {
        let s = lv.res as u64 + 1;
        assert!(
            s * s * s <= lv.size as u64,
            "grid: dense level larger than its table"
        );
    } else {
        assert!(
            lv.size.is_power_of_two(),
            "grid: hashed table size not a power of two"
        );
    }
    n
}

/// Corner indices and weights of `n = pos[0].len()` positions, corner-major:
/// `idx[k * stride + l]`, `w[k * stride + l]` for corner `k` of lane `l`.
pub fn corners(
    level: Level,
    lv: &GridLevel,
    pos: [&[f32]; 3],
    idx: &mut [u32],
    w: &mut [f32],
    stride: usize,
) {
    let n = check(lv, pos);
    if n == 0 {
        return;
    }
    assert!(stride >= n && idx.len() >= 7 * stride + n && w.len() >= 7 * stride + n);
    let done = match level {
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 if level.supported() => {
            // SAFETY: AVX-512F/AVX2 are present (checked above); lengths were checked, and
            // the kernel touches lanes below `n` only.
            unsafe { x86::corners_avx512(lv, pos, idx, w, stride) }
        }
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 if level.supported() => {
            // SAFETY: AVX2 is present; lengths as above.
            unsafe { x86::corners_avx2(lv, pos, idx, w, stride) }
        }
        _ => 0,
    };
    for l in done..n {
        let (i, wk) = corners_one(lv, pos[0][l], pos[1][l], pos[2][l]);
        for k in 0..8 {
            idx[k * stride + l] = i[k];
            w[k * stride + l] = wk[k];
        }
    }
}

/// Interpolates the two features of every position from `table` (the level's entries):
/// feature 0 into `out0[l]`, feature 1 into `out1[l]`.
pub fn interp2(
    level: Level,
    lv: &GridLevel,
    table: &[[f32; 2]],
    pos: [&[f32]; 3],
    out0: &mut [f32],
    out1: &mut [f32],
) {
    // 8-byte entries: the byte offsets of 32-bit gathers stay below 2^31.
    let n = check_interp(lv, pos, table.len(), i32::MAX as u32 / 2, out0, out1);
    let done = match level {
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 if level.supported() => whole_vectors(16, pos, out0, out1, |p, o0, o1| {
            // SAFETY: AVX-512F is present; every index is < `lv.size` ≤ table.len() (the
            // kernel clamps them), and lanes below the positions' length only are read or
            // written.
            unsafe { x86::interp2_avx512(lv, table, p, o0, o1) }
        }),
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 if level.supported() => whole_vectors(8, pos, out0, out1, |p, o0, o1| {
            // SAFETY: AVX2 is present; indices and lanes as above.
            unsafe {
                if crate::slow_gathers() {
                    x86::interp2_avx2::<true>(lv, table, p, o0, o1)
                } else {
                    x86::interp2_avx2::<false>(lv, table, p, o0, o1)
                }
            }
        }),
        _ => 0,
    };
    interp2_scalar(lv, table, pos, done..n, out0, out1, |e| *e);
}

/// Runs `kernel` (a vector kernel of `width` ≤ 16 lanes; it returns how many lanes it did)
/// over every position: the whole vectors in place, then the lanes left over on a copy
/// padded with the last position. Every position takes the vector path, so its value never
/// depends on where it falls in a batch (a render queried in rounds gives a whole query's
/// bits). Returns the lanes done: all of them.
pub(crate) fn whole_vectors(
    width: usize,
    pos: [&[f32]; 3],
    out0: &mut [f32],
    out1: &mut [f32],
    mut kernel: impl FnMut([&[f32]; 3], &mut [f32], &mut [f32]) -> usize,
) -> usize {
    let n = pos[0].len();
    let done = kernel(pos, out0, out1);
    if done >= n {
        return done;
    }
    let rem = n - done;
    assert!(rem < width && width <= 16);
    let mut p = [[0f32; 16]; 3];
    for (dst, src) in p.iter_mut().zip(pos) {
        for (l, d) in dst[..width].iter_mut().enumerate() {
            *d = src[done + l.min(rem - 1)];
        }
    }
    let (mut o0, mut o1) = ([0f32; 16], [0f32; 16]);
    let lanes = [&p[0][..width], &p[1][..width], &p[2][..width]];
    kernel(lanes, &mut o0[..width], &mut o1[..width]);
    out0[done..n].copy_from_slice(&o0[..rem]);
    out1[done..n].copy_from_slice(&o1[..rem]);
    n
}

/// The lengths an F = 2 interpolation needs (positions, table, outputs, entries within
/// `max_size` for the gathers); returns the number of positions.
pub(crate) fn check_interp(
    lv: &GridLevel,
    pos: [&[f32]; 3],
    table_len: usize,
    max_size: u32,
    out0: &[f32],
    out1: &[f32],
) -> usize {
    let n = check(lv, pos);
    assert!(
        table_len >= lv.size as usize,
        "grid: table shorter than the level"
    );
    assert!(out0.len() >= n && out1.len() >= n);
    assert!(
        lv.size <= max_size,
        "grid: table too large for 32-bit gathers"
    );
    n
}

/// The scalar reference of the F = 2 interpolation over positions `lanes`, from entries
/// widened to f32 pairs by `pair`.
pub(crate) fn interp2_scalar<T>(
    lv: &GridLevel,
    table: &[T],
    pos: [&[f32]; 3],
    lanes: std::ops::Range<usize>,
    out0: &mut [f32],
    out1: &mut [f32],
    pair: impl Fn(&T) -> [f32; 2],
) {
    for l in lanes {
        let (i, w) = corners_one(lv, pos[0][l], pos[1][l], pos[2][l]);
        let (mut a, mut b) = (0f32, 0f32);
        for k in 0..8 {
            let e = pair(&table[i[k] as usize]);
            a += w[k] * e[0];
            b += w[k] * e[1];
        }
        out0[l] = a;
        out1[l] = b;
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{GridLevel, PRIME_Y, PRIME_Z};
    use std::arch::x86_64::*;

    /// Cells, weights and indices of 16 lanes at `p + l` (l < 16).
    ///
    /// # Safety
    /// AVX-512F; 16 floats readable at each of `x`, `y`, `z`.
    #[inline]
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn corners16(
        lv: &GridLevel,
        x: *const f32,
        y: *const f32,
        z: *const f32,
    ) -> ([__m512i; 8], [__m512; 8]) {
        let r = _mm512_set1_ps(lv.res as f32);
        let rm1 = _mm512_set1_epi32((lv.res - 1) as i32);
        let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
        let cell = |p: *const f32| {
            // SAFETY: 16 floats are readable at p (the caller's contract).
            let v = unsafe { _mm512_loadu_ps(p) };
            // max(v, 0) returns 0 for NaN v (the second operand).
            let t = _mm512_mul_ps(_mm512_min_ps(_mm512_max_ps(v, zero), one), r);
            let c = _mm512_min_epu32(_mm512_cvttps_epu32(t), rm1);
            (c, _mm512_sub_ps(t, _mm512_cvtepu32_ps(c)))
        };
        let ((cx, fx), (cy, fy), (cz, fz)) = (cell(x), cell(y), cell(z));
        let (gx, gy, gz) = (
            _mm512_sub_ps(one, fx),
            _mm512_sub_ps(one, fy),
            _mm512_sub_ps(one, fz),
        );
        let wxy = [
            _mm512_mul_ps(gx, gy),
            _mm512_mul_ps(fx, gy),
            _mm512_mul_ps(gx, fy),
            _mm512_mul_ps(fx, fy),
        ];
        let w: [__m512; 8] =
            std::array::from_fn(|k| _mm512_mul_ps(wxy[k & 3], if k < 4 { gz } else { fz }));
        let idx: [__m512i; 8] = if lv.dense {
            let s = lv.res + 1;
            let (vs, vs2) = (
                _mm512_set1_epi32(s as i32),
                _mm512_set1_epi32((s * s) as i32),
            );
            let base = _mm512_add_epi32(
                cx,
                _mm512_add_epi32(_mm512_mullo_epi32(cy, vs), _mm512_mullo_epi32(cz, vs2)),
            );
            std::array::from_fn(|k| {
                let off = (k & 1) as u32
                    + if k & 2 != 0 { s } else { 0 }
                    + if k & 4 != 0 { s * s } else { 0 };
                _mm512_add_epi32(base, _mm512_set1_epi32(off as i32))
            })
        } else {
            let mask = _mm512_set1_epi32((lv.size - 1) as i32);
            let (py, pz) = (
                _mm512_set1_epi32(PRIME_Y as i32),
                _mm512_set1_epi32(PRIME_Z as i32),
            );
            let hy0 = _mm512_mullo_epi32(cy, py);
            let hz0 = _mm512_mullo_epi32(cz, pz);
            let hy = [hy0, _mm512_add_epi32(hy0, py)];
            let hz = [hz0, _mm512_add_epi32(hz0, pz)];
            let xs = [cx, _mm512_add_epi32(cx, _mm512_set1_epi32(1))];
            std::array::from_fn(|k| {
                let h = _mm512_xor_si512(xs[k & 1], _mm512_xor_si512(hy[(k >> 1) & 1], hz[k >> 2]));
                _mm512_and_si512(h, mask)
            })
        };
        // Never past the table, whatever the arithmetic above produced.
        let last = _mm512_set1_epi32((lv.size - 1) as i32);
        (idx.map(|i| _mm512_min_epu32(i, last)), w)
    }

    /// # Safety
    /// AVX-512F; `pos` lengths equal, `idx`/`w` hold `7 * stride + n` with `stride ≥ n`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn corners_avx512(
        lv: &GridLevel,
        pos: [&[f32]; 3],
        idx: &mut [u32],
        w: &mut [f32],
        stride: usize,
    ) -> usize {
        let n16 = pos[0].len() / 16 * 16;
        for l in (0..n16).step_by(16) {
            // SAFETY: lanes l..l+16 ≤ n of every input and of every corner row of the outputs.
            unsafe {
                let (i, wk) = corners16(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                for k in 0..8 {
                    _mm512_storeu_si512(idx.as_mut_ptr().add(k * stride + l).cast(), i[k]);
                    _mm512_storeu_ps(w.as_mut_ptr().add(k * stride + l), wk[k]);
                }
            }
        }
        n16
    }

    /// # Safety
    /// AVX-512F; `table` holds at least `lv.size` entries; outputs hold `n` lanes.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn interp2_avx512(
        lv: &GridLevel,
        table: &[[f32; 2]],
        pos: [&[f32]; 3],
        out0: &mut [f32],
        out1: &mut [f32],
    ) -> usize {
        let n16 = pos[0].len() / 16 * 16;
        let base = table.as_ptr().cast::<f32>();
        let dup_lo = _mm512_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7);
        let dup_hi = _mm512_add_epi32(dup_lo, _mm512_set1_epi32(8));
        let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
        for l in (0..n16).step_by(16) {
            // SAFETY: lanes l..l+16 ≤ n; every gathered index is < lv.size ≤ table.len(), so
            // entry `i` (floats 2i and 2i+1, scale 8 bytes) is inside the table.
            unsafe {
                let (i, w) = corners16(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                // Each entry is one 64-bit pair: 8 lanes per gather, features interleaved;
                // weights are duplicated to match, and the sums split apart at the end.
                let mut lo = _mm512_setzero_ps();
                let mut hi = _mm512_setzero_ps();
                for k in 0..8 {
                    let i_lo = _mm512_castsi512_si256(i[k]);
                    let i_hi = _mm512_extracti64x4_epi64::<1>(i[k]);
                    let e_lo = _mm512_castpd_ps(_mm512_i32gather_pd::<8>(i_lo, base.cast()));
                    let e_hi = _mm512_castpd_ps(_mm512_i32gather_pd::<8>(i_hi, base.cast()));
                    lo = _mm512_fmadd_ps(_mm512_permutexvar_ps(dup_lo, w[k]), e_lo, lo);
                    hi = _mm512_fmadd_ps(_mm512_permutexvar_ps(dup_hi, w[k]), e_hi, hi);
                }
                let a = _mm512_permutex2var_ps(lo, even, hi);
                let b = _mm512_permutex2var_ps(lo, odd, hi);
                _mm512_storeu_ps(out0.as_mut_ptr().add(l), a);
                _mm512_storeu_ps(out1.as_mut_ptr().add(l), b);
            }
        }
        n16
    }

    /// The AVX2 counterpart of `corners16` over 8 lanes.
    ///
    /// # Safety
    /// AVX2; 8 floats readable at each of `x`, `y`, `z`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn corners8(
        lv: &GridLevel,
        x: *const f32,
        y: *const f32,
        z: *const f32,
    ) -> ([__m256i; 8], [__m256; 8]) {
        let r = _mm256_set1_ps(lv.res as f32);
        let rm1 = _mm256_set1_epi32((lv.res - 1) as i32);
        let (zero, one) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0));
        let cell = |p: *const f32| {
            // SAFETY: 8 floats are readable at p (the caller's contract).
            let v = unsafe { _mm256_loadu_ps(p) };
            let t = _mm256_mul_ps(_mm256_min_ps(_mm256_max_ps(v, zero), one), r);
            // t ∈ [0, res] < 2^31, so the signed conversion is the floor.
            let c = _mm256_min_epu32(_mm256_cvttps_epi32(t), rm1);
            (c, _mm256_sub_ps(t, _mm256_cvtepi32_ps(c)))
        };
        let ((cx, fx), (cy, fy), (cz, fz)) = (cell(x), cell(y), cell(z));
        let (gx, gy, gz) = (
            _mm256_sub_ps(one, fx),
            _mm256_sub_ps(one, fy),
            _mm256_sub_ps(one, fz),
        );
        let wxy = [
            _mm256_mul_ps(gx, gy),
            _mm256_mul_ps(fx, gy),
            _mm256_mul_ps(gx, fy),
            _mm256_mul_ps(fx, fy),
        ];
        let w: [__m256; 8] =
            std::array::from_fn(|k| _mm256_mul_ps(wxy[k & 3], if k < 4 { gz } else { fz }));
        let idx: [__m256i; 8] = if lv.dense {
            let s = lv.res + 1;
            let (vs, vs2) = (
                _mm256_set1_epi32(s as i32),
                _mm256_set1_epi32((s * s) as i32),
            );
            let base = _mm256_add_epi32(
                cx,
                _mm256_add_epi32(_mm256_mullo_epi32(cy, vs), _mm256_mullo_epi32(cz, vs2)),
            );
            std::array::from_fn(|k| {
                let off = (k & 1) as u32
                    + if k & 2 != 0 { s } else { 0 }
                    + if k & 4 != 0 { s * s } else { 0 };
                _mm256_add_epi32(base, _mm256_set1_epi32(off as i32))
            })
        } else {
            let mask = _mm256_set1_epi32((lv.size - 1) as i32);
            let (py, pz) = (
                _mm256_set1_epi32(PRIME_Y as i32),
                _mm256_set1_epi32(PRIME_Z as i32),
            );
            let hy0 = _mm256_mullo_epi32(cy, py);
            let hz0 = _mm256_mullo_epi32(cz, pz);
            let hy = [hy0, _mm256_add_epi32(hy0, py)];
            let hz = [hz0, _mm256_add_epi32(hz0, pz)];
            let xs = [cx, _mm256_add_epi32(cx, _mm256_set1_epi32(1))];
            std::array::from_fn(|k| {
                let h = _mm256_xor_si256(xs[k & 1], _mm256_xor_si256(hy[(k >> 1) & 1], hz[k >> 2]));
                _mm256_and_si256(h, mask)
            })
        };
        let last = _mm256_set1_epi32((lv.size - 1) as i32);
        (idx.map(|i| _mm256_min_epu32(i, last)), w)
    }

    /// # Safety
    /// AVX2; as `corners_avx512`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn corners_avx2(
        lv: &GridLevel,
        pos: [&[f32]; 3],
        idx: &mut [u32],
        w: &mut [f32],
        stride: usize,
    ) -> usize {
        let n8 = pos[0].len() / 8 * 8;
        for l in (0..n8).step_by(8) {
            // SAFETY: lanes l..l+8 ≤ n of every input and of every corner row of the outputs.
            unsafe {
                let (i, wk) = corners8(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                for k in 0..8 {
                    _mm256_storeu_si256(idx.as_mut_ptr().add(k * stride + l).cast(), i[k]);
                    _mm256_storeu_ps(w.as_mut_ptr().add(k * stride + l), wk[k]);
                }
            }
        }
        n8
    }

    /// `LOADS`: each corner's entries fetched by scalar loads instead of gathers (where
    /// gathers are slow, [`crate::slow_gathers`]; the same bits).
    ///
    /// # Safety
    /// AVX2; as `interp2_avx512`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn interp2_avx2<const LOADS: bool>(
        lv: &GridLevel,
        table: &[[f32; 2]],
        pos: [&[f32]; 3],
        out0: &mut [f32],
        out1: &mut [f32],
    ) -> usize {
        let n8 = pos[0].len() / 8 * 8;
        let base = table.as_ptr().cast::<f32>();
        for l in (0..n8).step_by(8) {
            // SAFETY: as in `interp2_avx512`.
            unsafe {
                let (i, w) = corners8(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                // One 8-byte gather per corner and lane fetches both features (half the
                // gathered elements of two 4-byte gathers); lanes 0–3 and 4–7 accumulate
                // as interleaved pairs, split once at the end.
                let pairs = base.cast::<f64>();
                let dup_lo = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
                let dup_hi = _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7);
                let mut lo = _mm256_setzero_ps();
                let mut hi = _mm256_setzero_ps();
                let mut ix = [0u32; 8];
                for k in 0..8 {
                    let (g_lo, g_hi) = if LOADS {
                        _mm256_storeu_si256(ix.as_mut_ptr().cast(), i[k]);
                        let e = |j: usize| *pairs.cast::<i64>().add(ix[j] as usize);
                        (
                            _mm256_castsi256_ps(_mm256_setr_epi64x(e(0), e(1), e(2), e(3))),
                            _mm256_castsi256_ps(_mm256_setr_epi64x(e(4), e(5), e(6), e(7))),
                        )
                    } else {
                        (
                            _mm256_castpd_ps(_mm256_i32gather_pd::<8>(
                                pairs,
                                _mm256_castsi256_si128(i[k]),
                            )),
                            _mm256_castpd_ps(_mm256_i32gather_pd::<8>(
                                pairs,
                                _mm256_extracti128_si256::<1>(i[k]),
                            )),
                        )
                    };
                    lo = _mm256_fmadd_ps(_mm256_permutevar8x32_ps(w[k], dup_lo), g_lo, lo);
                    hi = _mm256_fmadd_ps(_mm256_permutevar8x32_ps(w[k], dup_hi), g_hi, hi);
                }
                // lo = a0 b0 a1 b1 | a2 b2 a3 b3, hi = a4 b4 a5 b5 | a6 b6 a7 b7.
                let even = _mm256_shuffle_ps::<0b10_00_10_00>(lo, hi); // a0 a1 a4 a5 | a2 a3 a6 a7
                let odd = _mm256_shuffle_ps::<0b11_01_11_01>(lo, hi);
                let order = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(
                    _mm256_castps_pd(even),
                ));
                let a = order;
                let b = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(
                    odd,
                )));
                _mm256_storeu_ps(out0.as_mut_ptr().add(l), a);
                _mm256_storeu_ps(out1.as_mut_ptr().add(l), b);
            }
        }
        n8
    }
}

pub mod packed;

#[cfg(test)]
mod tests;
