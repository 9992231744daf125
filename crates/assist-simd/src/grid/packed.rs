//! The F = 2 interpolation from a table of bf16 pairs, for rendering: one 32-bit entry
//! per grid point holds both features (feature 0 in the low half), so a corner costs one
//! 4-byte gather instead of one 8-byte one, and the table half the memory and cache. bf16
//! keeps f32's range and 8 significant bits; widening it to f32 is a shift, so no F16C or
//! AVX-512 BF16 is needed. The interpolation itself is f32, as in [`interp2`].
//!
//! [`interp2`]: super::interp2

use super::{GridLevel, check_interp, interp2_scalar, whole_vectors};
use crate::Level;

/// f32 → bf16, rounded to nearest even (NaN stays NaN).
#[inline]
pub fn to_bf16(v: f32) -> u16 {
    let b = v.to_bits();
    if v.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    let round = 0x7fff + ((b >> 16) & 1);
    (b.wrapping_add(round) >> 16) as u16
}

/// A level's (or a whole field's) table of feature pairs packed as bf16 pairs.
pub fn pack(table: &[[f32; 2]]) -> Vec<u32> {
    table
        .iter()
        .map(|e| to_bf16(e[0]) as u32 | (to_bf16(e[1]) as u32) << 16)
        .collect()
}

/// The two features of a packed entry, widened to f32.
#[inline(always)]
pub fn unpack(e: u32) -> [f32; 2] {
    [f32::from_bits(e << 16), f32::from_bits(e & 0xffff_0000)]
}

/// As [`super::interp2`], from a packed table: feature 0 into `out0[l]`, 1 into `out1[l]`.
pub fn interp2_bf16(
    level: Level,
    lv: &GridLevel,
    table: &[u32],
    pos: [&[f32]; 3],
    out0: &mut [f32],
    out1: &mut [f32],
) {
    let n = check_interp(lv, pos, table.len(), i32::MAX as u32, out0, out1);
    let done = match level {
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 if level.supported() => whole_vectors(16, pos, out0, out1, |p, o0, o1| {
            // SAFETY: AVX-512F is present; every index is < `lv.size` ≤ table.len() (the
            // corner kernel clamps them), and lanes below the positions' length only are
            // read or written.
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
    interp2_scalar(lv, table, pos, done..n, out0, out1, |e| unpack(*e));
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::super::x86::{corners8, corners16};
    use super::GridLevel;
    use std::arch::x86_64::*;

    /// # Safety
    /// AVX-512F; every index the corner kernel makes (< `lv.size`) within `table`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn interp2_avx512(
        lv: &GridLevel,
        table: &[u32],
        pos: [&[f32]; 3],
        out0: &mut [f32],
        out1: &mut [f32],
    ) -> usize {
        let n16 = pos[0].len() / 16 * 16;
        let base = table.as_ptr().cast::<i32>();
        let high = _mm512_set1_epi32(0xffff_0000u32 as i32);
        for l in (0..n16).step_by(16) {
            // SAFETY: lanes l..l+16 of every input and output exist; indices as above.
            unsafe {
                let (i, w) = corners16(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                let (mut a, mut b) = (_mm512_setzero_ps(), _mm512_setzero_ps());
                for k in 0..8 {
                    let g = _mm512_i32gather_epi32::<4>(i[k], base);
                    let e0 = _mm512_castsi512_ps(_mm512_slli_epi32::<16>(g));
                    let e1 = _mm512_castsi512_ps(_mm512_and_si512(g, high));
                    a = _mm512_fmadd_ps(w[k], e0, a);
                    b = _mm512_fmadd_ps(w[k], e1, b);
                }
                _mm512_storeu_ps(out0.as_mut_ptr().add(l), a);
                _mm512_storeu_ps(out1.as_mut_ptr().add(l), b);
            }
        }
        n16
    }

    /// `LOADS`: each corner's entries fetched by eight scalar loads instead of one gather
    /// (where gathers are slow, [`crate::slow_gathers`]; the same bits).
    ///
    /// # Safety
    /// AVX2 and FMA; as `interp2_avx512`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn interp2_avx2<const LOADS: bool>(
        lv: &GridLevel,
        table: &[u32],
        pos: [&[f32]; 3],
        out0: &mut [f32],
        out1: &mut [f32],
    ) -> usize {
        let n8 = pos[0].len() / 8 * 8;
        let base = table.as_ptr().cast::<i32>();
        let high = _mm256_set1_epi32(0xffff_0000u32 as i32);
        for l in (0..n8).step_by(8) {
            // SAFETY: as in `interp2_avx512`.
            unsafe {
                let (i, w) = corners8(
                    lv,
                    pos[0].as_ptr().add(l),
                    pos[1].as_ptr().add(l),
                    pos[2].as_ptr().add(l),
                );
                let (mut a, mut b) = (_mm256_setzero_ps(), _mm256_setzero_ps());
                let mut ix = [0u32; 8];
                for k in 0..8 {
                    let g = if LOADS {
                        _mm256_storeu_si256(ix.as_mut_ptr().cast(), i[k]);
                        let e = |j: usize| *base.add(ix[j] as usize);
                        _mm256_setr_epi32(e(0), e(1), e(2), e(3), e(4), e(5), e(6), e(7))
                    } else {
                        _mm256_i32gather_epi32::<4>(base, i[k])
                    };
                    let e0 = _mm256_castsi256_ps(_mm256_slli_epi32::<16>(g));
                    let e1 = _mm256_castsi256_ps(_mm256_and_si256(g, high));
                    a = _mm256_fmadd_ps(w[k], e0, a);
                    b = _mm256_fmadd_ps(w[k], e1, b);
                }
                _mm256_storeu_ps(out0.as_mut_ptr().add(l), a);
                _mm256_storeu_ps(out1.as_mut_ptr().add(l), b);
            }
        }
        n8
    }
}

#[cfg(test)]
mod tests {
    use super::super::interp2;
    use super::super::tests::{levels, positions};
    use super::*;

    #[test]
    fn bf16_rounds_to_nearest_even() {
        assert_eq!(to_bf16(1.0), 0x3f80);
        // 1 + 2^-8 lies halfway between 1 and 1 + 2^-7: to the even one, 1.
        assert_eq!(to_bf16(1.0 + 1.0 / 256.0), 0x3f80);
        assert_eq!(to_bf16(1.0 + 3.0 / 256.0), 0x3f82);
        assert_eq!(unpack(pack(&[[-2.5, 0.15625]])[0]), [-2.5, 0.15625]);
        assert!(f32::from_bits((to_bf16(f32::NAN) as u32) << 16).is_nan());
    }

    /// Every level of SIMD against the scalar packed reference (within rounding), and the
    /// packed reference against the f32 kernel within bf16's precision.
    #[test]
    fn packed_matches_scalar_and_f32() {
        let mut failures = Vec::new();
        for (lv, n) in levels()
            .into_iter()
            .flat_map(|l| [1, 7, 16, 37, 64].map(|n| (l, n)))
        {
            let p = positions(n, n as u64 + lv.res as u64);
            let table: Vec<[f32; 2]> = (0..lv.size)
                .map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos()])
                .collect();
            let packed = pack(&table);
            let pos = [&p[0][..], &p[1][..], &p[2][..]];
            let (mut r0, mut r1) = (vec![0f32; n], vec![0f32; n]);
            interp2_bf16(Level::Scalar, &lv, &packed, pos, &mut r0, &mut r1);
            let (mut f0, mut f1) = (vec![0f32; n], vec![0f32; n]);
            interp2(Level::Scalar, &lv, &table, pos, &mut f0, &mut f1);
            let off = r0
                .iter()
                .zip(&f0)
                .chain(r1.iter().zip(&f1))
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            // Entries within 1, each rounded by at most 2^-9 relative; weights sum to 1.
            if off > 1.0 / 256.0 || r0.iter().chain(&r1).any(|v| !v.is_finite()) {
                failures.push(format!("packed vs f32 res {} n {n}: {off}", lv.res));
            }
            for level in [Level::Avx2, Level::Avx512] {
                if !level.supported() {
                    eprintln!(
                        "!!! SKIP packed grid level {}: this CPU lacks it",
                        level.name()
                    );
                    continue;
                }
                let (mut s0, mut s1) = (vec![0f32; n], vec![0f32; n]);
                interp2_bf16(level, &lv, &packed, pos, &mut s0, &mut s1);
                let worst = r0
                    .iter()
                    .zip(&s0)
                    .chain(r1.iter().zip(&s1))
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f32, f32::max);
                if worst > 1e-5 {
                    failures.push(format!("{} res {} n {n}: {worst}", level.name(), lv.res));
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
    }

    /// An AVX2 interpolation kernel of this module.
    #[cfg(target_arch = "x86_64")]
    type Kernel = unsafe fn(&GridLevel, &[u32], [&[f32]; 3], &mut [f32], &mut [f32]) -> usize;
    #[cfg(target_arch = "x86_64")]
    type KernelF32 =
        unsafe fn(&GridLevel, &[[f32; 2]], [&[f32]; 3], &mut [f32], &mut [f32]) -> usize;

    /// The AVX2 kernels that load each corner's entries one by one give the gathering
    /// ones' bits exactly (either may run, by the CPU), on packed and on f32 tables.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn loads_match_gathers() {
        if !Level::Avx2.supported() {
            eprintln!("!!! SKIP AVX2 loads against gathers: this CPU lacks AVX2");
            return;
        }
        for (lv, n) in levels()
            .into_iter()
            .flat_map(|l| [8, 64, 200].map(|n| (l, n)))
        {
            let p = positions(n, 3 * n as u64 + lv.res as u64);
            let table: Vec<[f32; 2]> = (0..lv.size)
                .map(|i| [(i as f32 * 0.29).sin(), (i as f32 * 0.13).cos()])
                .collect();
            let packed = pack(&table);
            let pos = [&p[0][..], &p[1][..], &p[2][..]];
            let run = |f: Kernel| {
                let (mut o0, mut o1) = (vec![0f32; n], vec![0f32; n]);
                // SAFETY: AVX2 is present (checked above); indices come from the corner
                // kernel, within the level's table.
                let done = unsafe { f(&lv, &packed, pos, &mut o0, &mut o1) };
                assert_eq!(done, n / 8 * 8);
                (o0, o1)
            };
            let hw = run(x86::interp2_avx2::<false>);
            let loads = run(x86::interp2_avx2::<true>);
            assert_eq!(hw, loads, "packed, res {} n {n}", lv.res);
            assert!(hw.0.iter().any(|&v| v != 0.0));
            // The f32 tables' kernel too.
            let run = |f: KernelF32| {
                let (mut o0, mut o1) = (vec![0f32; n], vec![0f32; n]);
                // SAFETY: as above.
                unsafe { f(&lv, &table, pos, &mut o0, &mut o1) };
                (o0, o1)
            };
            let hw = run(super::super::x86::interp2_avx2::<false>);
            let loads = run(super::super::x86::interp2_avx2::<true>);
            assert_eq!(hw, loads, "f32, res {} n {n}", lv.res);
        }
    }
}
