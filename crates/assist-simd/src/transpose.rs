//! Matrix transpose (`dst[j][i] = src[i][j]`) for f32, blocked 8 × 8 with AVX2 shuffles
//! where available, scalar otherwise; and a software prefetch hint.

use crate::Level;

/// Transposes the `rows × cols` matrix `src` (stride `lds`) into `dst` (`cols × rows`,
/// stride `ldd`).
pub fn transpose(src: &[f32], rows: usize, cols: usize, lds: usize, dst: &mut [f32], ldd: usize) {
    transpose_at(crate::level(), src, rows, cols, lds, dst, ldd)
}

pub fn transpose_at(
    level: Level,
    src: &[f32],
    rows: usize,
    cols: usize,
    lds: usize,
    dst: &mut [f32],
    ldd: usize,
) {
    if rows == 0 || cols == 0 {
        return;
    }
    assert!(lds >= cols && ldd >= rows, "transpose strides");
    assert!(
        src.len() >= (rows - 1) * lds + cols && dst.len() >= (cols - 1) * ldd + rows,
        "transpose: slice too short"
    );
    let (r8, c8) = (rows / 8 * 8, cols / 8 * 8);
    #[cfg(target_arch = "x86_64")]
    if level >= Level::Avx2 && level.supported() {
        for i in (0..r8).step_by(8) {
            for j in (0..c8).step_by(8) {
                // SAFETY: AVX2 is supported; the 8×8 block at (i, j) lies within `src`
                // (i + 8 ≤ rows, j + 8 ≤ cols) and its image within `dst` (checked above).
                unsafe {
                    x86::block8(
                        src.as_ptr().add(i * lds + j),
                        lds,
                        dst.as_mut_ptr().add(j * ldd + i),
                        ldd,
                    )
                };
            }
        }
        scalar_region(src, lds, dst, ldd, 0, rows, c8, cols);
        scalar_region(src, lds, dst, ldd, r8, rows, 0, c8);
        return;
    }
    let _ = (r8, c8);
    scalar_region(src, lds, dst, ldd, 0, rows, 0, cols);
}

fn scalar_region(
    src: &[f32],
    lds: usize,
    dst: &mut [f32],
    ldd: usize,
    i0: usize,
    i1: usize,
    j0: usize,
    j1: usize,
) {
    for i in i0..i1 {
        for j in j0..j1 {
            dst[j * ldd + i] = src[i * lds + j];
        }
    }
}

/// Hints the CPU to bring the cache line holding `p` into its L2 only: for a block larger
/// than the L1 asked for ahead, which would push out what is being computed.
#[inline(always)]
pub fn prefetch_l2<T>(p: &T) {
    #[cfg(target_arch = "x86_64")]
    hint::<{ std::arch::x86_64::_MM_HINT_T1 }, T>(p);
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Hints the CPU to bring the cache line holding `p` closer (no effect elsewhere).
#[inline(always)]
pub fn prefetch<T>(p: &T) {
    #[cfg(target_arch = "x86_64")]
    hint::<{ std::arch::x86_64::_MM_HINT_T0 }, T>(p);
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// A prefetch of `p`'s line with the cache-level hint `H`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn hint<const H: i32, T>(p: &T) {
    // SAFETY: a prefetch never faults and has no architectural effect; `p` is a valid reference.
    unsafe { std::arch::x86_64::_mm_prefetch::<H>(p as *const T as *const i8) };
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// # Safety
    /// Needs AVX2; 8 rows of 8 floats readable at `s` (stride `lds`), writable at `d`.
    #[target_feature(enable = "avx2")]
    pub unsafe fn block8(s: *const f32, lds: usize, d: *mut f32, ldd: usize) {
        // SAFETY: the caller guarantees the 8×8 block is in bounds on both sides.
        unsafe {
            let r: [__m256; 8] = std::array::from_fn(|k| _mm256_loadu_ps(s.add(k * lds)));
            let t0 = _mm256_unpacklo_ps(r[0], r[1]);
            let t1 = _mm256_unpackhi_ps(r[0], r[1]);
            let t2 = _mm256_unpacklo_ps(r[2], r[3]);
            let t3 = _mm256_unpackhi_ps(r[2], r[3]);
            let t4 = _mm256_unpacklo_ps(r[4], r[5]);
            let t5 = _mm256_unpackhi_ps(r[4], r[5]);
            let t6 = _mm256_unpacklo_ps(r[6], r[7]);
            let t7 = _mm256_unpackhi_ps(r[6], r[7]);
            let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
            let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
            let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
            let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
            let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
            let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
            let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
            let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
            let o = [
                _mm256_permute2f128_ps::<0x20>(u0, u4),
                _mm256_permute2f128_ps::<0x20>(u1, u5),
                _mm256_permute2f128_ps::<0x20>(u2, u6),
                _mm256_permute2f128_ps::<0x20>(u3, u7),
                _mm256_permute2f128_ps::<0x31>(u0, u4),
                _mm256_permute2f128_ps::<0x31>(u1, u5),
                _mm256_permute2f128_ps::<0x31>(u2, u6),
                _mm256_permute2f128_ps::<0x31>(u3, u7),
            ];
            for (k, v) in o.iter().enumerate() {
                _mm256_storeu_ps(d.add(k * ldd), *v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simd_transpose_matches_scalar() {
        for level in [Level::Scalar, Level::Avx2, Level::Avx512] {
            if !level.supported() {
                eprintln!(
                    "!!! SKIP transpose level {}: this CPU lacks it",
                    level.name()
                );
                continue;
            }
            for &(r, c) in &[
                (64, 64),
                (8, 8),
                (13, 21),
                (64, 16),
                (3, 64),
                (1, 1),
                (17, 9),
            ] {
                let (lds, ldd) = (c + 3, r + 2);
                let src: Vec<f32> = (0..r * lds).map(|v| v as f32).collect();
                let mut dst = vec![-1.0; c * ldd];
                transpose_at(level, &src, r, c, lds, &mut dst, ldd);
                for i in 0..r {
                    for j in 0..c {
                        assert_eq!(
                            dst[j * ldd + i],
                            src[i * lds + j],
                            "{} {r}x{c} at {i},{j}",
                            level.name()
                        );
                    }
                }
                // Padding untouched.
                for j in 0..c {
                    for i in r..ldd {
                        assert_eq!(dst[j * ldd + i], -1.0);
                    }
                }
            }
        }
    }
}
