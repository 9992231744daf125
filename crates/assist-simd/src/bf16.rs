//! BF16 matrix products for inference (AVX-512 BF16, `vdpbf16ps`): weights and
//! activations rounded to bfloat16 (8-bit mantissa, round to nearest even), products summed
//! in f32. Twice the multiply-adds per instruction of the f32 kernel, at about 3 significant
//! digits per operand — for rendering, never for training (gradients stay f32).
//!
//! Operands are packed in pairs along K, the layout the instruction consumes: a 32-bit word
//! holds element `2p` in its low half and `2p + 1` in its high half.

use crate::Level;

/// f32 → bf16, round to nearest even (NaN stays NaN).
#[inline(always)]
pub fn to_bf16(x: f32) -> u16 {
    let b = x.to_bits();
    if x.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    ((b + 0x7fff + ((b >> 16) & 1)) >> 16) as u16
}

/// bf16 → f32 (exact).
#[inline(always)]
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits((h as u32) << 16)
}

#[inline(always)]
fn pair(lo: f32, hi: f32) -> u32 {
    to_bf16(lo) as u32 | (to_bf16(hi) as u32) << 16
}

/// Whether rendering's products run in bf16 here (see [`crate::products`]).
pub fn available() -> bool {
    crate::products() == crate::Products::Bf16
}

/// Whether the CPU itself has AVX-512 BF16 (for tests, which skip loudly without it).
pub fn cpu_has_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        Level::Avx512.supported() && is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A weight matrix `A` (`m × k`) packed as bf16 pairs: word `p` of row `i` holds
/// `A[i][2p]`, `A[i][2p + 1]` (zero past `k`).
#[derive(Debug, Clone, PartialEq)]
pub struct PackedA {
    pub m: usize,
    pub k: usize,
    k2: usize,
    data: Vec<u32>,
}

impl PackedA {
    /// Packs the first `k` columns of `a` (row-major, stride `lda`).
    pub fn new(a: &[f32], m: usize, k: usize, lda: usize) -> Self {
        assert!(lda >= k && (m == 0 || a.len() >= (m - 1) * lda + k));
        let k2 = k.div_ceil(2);
        let mut data = Vec::with_capacity(m * k2);
        for i in 0..m {
            let row = &a[i * lda..i * lda + k];
            for p in 0..k2 {
                let hi = if 2 * p + 1 < k { row[2 * p + 1] } else { 0.0 };
                data.push(pair(row[2 * p], hi));
            }
        }
        PackedA { m, k, k2, data }
    }
    /// Words per row (`⌈k / 2⌉`), which is also the packed activations' row count.
    pub fn pairs(&self) -> usize {
        self.k2
    }
}

/// Packs activations `B` (`k × n`, row-major stride `ldb`) as bf16 pairs of rows:
/// `out[p * n + j]` holds `B[2p][j]`, `B[2p + 1][j]` (zero past `k`).
pub fn pack_b(level: Level, b: &[f32], k: usize, n: usize, ldb: usize, out: &mut [u32]) {
    assert!(ldb >= n && (k == 0 || b.len() >= (k - 1) * ldb + n));
    let k2 = k.div_ceil(2);
    assert!(out.len() >= k2 * n);
    #[cfg(target_arch = "x86_64")]
    if level == Level::Avx512 && cpu_has_bf16() && n.is_multiple_of(16) {
        // SAFETY: AVX-512F/BW/BF16 present (checked); rows 2p and 2p+1 < k are read over
        // columns < n, and out[p*n .. p*n + n] for p < k2 is written: all within the
        // lengths asserted above.
        unsafe { x86::pack_b(b, k, n, ldb, out) };
        return;
    }
    let _ = level;
    for p in 0..k2 {
        for j in 0..n {
            let hi = if 2 * p + 1 < k {
                b[(2 * p + 1) * ldb + j]
            } else {
                0.0
            };
            out[p * n + j] = pair(b[2 * p * ldb + j], hi);
        }
    }
}

/// `C (m × n, stride ldc) = A · B` from packed operands (`bp` from [`pack_b`] with the same
/// `k` and `n`). The vector path needs `n` a multiple of 16; the scalar path is the
/// reference (f32 sums of the bf16 products, pair by pair).
pub fn gemm(level: Level, a: &PackedA, bp: &[u32], n: usize, c: &mut [f32], ldc: usize) {
    let (m, k2) = (a.m, a.k2);
    assert!(bp.len() >= k2 * n && ldc >= n && (m == 0 || c.len() >= (m - 1) * ldc + n));
    #[cfg(target_arch = "x86_64")]
    if level == Level::Avx512 && cpu_has_bf16() && n.is_multiple_of(16) {
        // SAFETY: AVX-512F/BF16 present (checked); a.data holds m·k2 words, bp k2·n, and
        // c rows < m over columns < n are written: within the lengths asserted above.
        unsafe { x86::gemm(&a.data, m, k2, bp, n, c, ldc) };
        return;
    }
    let _ = level;
    for i in 0..m {
        let row = &mut c[i * ldc..i * ldc + n];
        row.fill(0.0);
        for p in 0..k2 {
            let w = a.data[i * k2 + p];
            let (w0, w1) = (from_bf16(w as u16), from_bf16((w >> 16) as u16));
            for (j, v) in row.iter_mut().enumerate() {
                let x = bp[p * n + j];
                *v += w0 * from_bf16(x as u16) + w1 * from_bf16((x >> 16) as u16);
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// # Safety
    /// AVX-512F/BW/BF16; `n` a multiple of 16; bounds as `super::pack_b` asserts.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub unsafe fn pack_b(b: &[f32], k: usize, n: usize, ldb: usize, out: &mut [u32]) {
        // Interleaves the two halves: word j = (row0[j], row1[j]).
        let inter = _mm512_set_epi16(
            31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20,
            4, 19, 3, 18, 2, 17, 1, 16, 0,
        );
        let zero = _mm512_setzero_ps();
        for p in 0..k.div_ceil(2) {
            for j in (0..n).step_by(16) {
                // SAFETY: rows 2p (< k) and 2p+1 (only if < k) at columns j..j+16 ≤ n; out
                // words p·n + j .. +16.
                unsafe {
                    let r0 = _mm512_loadu_ps(b.as_ptr().add(2 * p * ldb + j));
                    let r1 = if 2 * p + 1 < k {
                        _mm512_loadu_ps(b.as_ptr().add((2 * p + 1) * ldb + j))
                    } else {
                        zero
                    };
                    let h: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(r1, r0));
                    let v = _mm512_permutexvar_epi16(inter, h);
                    _mm512_storeu_si512(out.as_mut_ptr().add(p * n + j).cast(), v);
                }
            }
        }
    }

    /// # Safety
    /// AVX-512F/BF16; `a` holds m·k2 words, `bp` k2·n, `c` m rows of stride ldc ≥ n;
    /// `n` a multiple of 16.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub unsafe fn gemm(
        a: &[u32],
        m: usize,
        k2: usize,
        bp: &[u32],
        n: usize,
        c: &mut [f32],
        ldc: usize,
    ) {
        const MR: usize = 4;
        const NB: usize = 4;
        let (ap, bptr, cp) = (a.as_ptr(), bp.as_ptr(), c.as_mut_ptr());
        let m_main = m / MR * MR;
        let n_main = n / (16 * NB) * (16 * NB);
        // SAFETY (whole function): every offset below stays within rows < m, words < k2
        // and columns < n, which the caller's contract puts inside the slices.
        unsafe {
            let mut i = 0;
            while i < m_main {
                let mut j = 0;
                while j < n_main {
                    let mut acc = [[_mm512_setzero_ps(); NB]; MR];
                    for p in 0..k2 {
                        let bv: [__m512bh; NB] = std::array::from_fn(|q| {
                            std::mem::transmute(_mm512_loadu_si512(
                                bptr.add(p * n + j + 16 * q).cast(),
                            ))
                        });
                        for (r, row) in acc.iter_mut().enumerate() {
                            let av: __m512bh = std::mem::transmute(_mm512_set1_epi32(
                                *ap.add((i + r) * k2 + p) as i32,
                            ));
                            for q in 0..NB {
                                row[q] = _mm512_dpbf16_ps(row[q], av, bv[q]);
                            }
                        }
                    }
                    for (r, row) in acc.iter().enumerate() {
                        for q in 0..NB {
                            _mm512_storeu_ps(cp.add((i + r) * ldc + j + 16 * q), row[q]);
                        }
                    }
                    j += 16 * NB;
                }
                i += MR;
            }
            // Everything else one row × 16 columns at a time.
            let one = |i: usize, j: usize| {
                let mut acc = _mm512_setzero_ps();
                for p in 0..k2 {
                    let bv: __m512bh =
                        std::mem::transmute(_mm512_loadu_si512(bptr.add(p * n + j).cast()));
                    let av: __m512bh =
                        std::mem::transmute(_mm512_set1_epi32(*ap.add(i * k2 + p) as i32));
                    acc = _mm512_dpbf16_ps(acc, av, bv);
                }
                _mm512_storeu_ps(cp.add(i * ldc + j), acc);
            };
            for i in 0..m {
                let j0 = if i < m_main { n_main } else { 0 };
                for j in (j0..n).step_by(16) {
                    one(i, j);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_util::{PRODUCT_SHAPES, rand_vec};

    #[test]
    fn rounding() {
        assert_eq!(from_bf16(to_bf16(1.0)), 1.0);
        assert_eq!(from_bf16(to_bf16(-2.5)), -2.5);
        // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties go to even (1).
        assert_eq!(from_bf16(to_bf16(1.0 + 1.0 / 256.0)), 1.0);
        assert_eq!(from_bf16(to_bf16(1.0 + 3.0 / 256.0)), 1.0 + 4.0 / 256.0);
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
        for x in rand_vec(1000, &mut 5) {
            let y = from_bf16(to_bf16(x));
            assert!((x - y).abs() <= x.abs() / 256.0, "{x} → {y}");
        }
    }

    /// The vector packing and product against the scalar reference (same bf16 inputs, so
    /// only the order of f32 additions differs), and against the f32 product within bf16's
    /// rounding; over shapes with odd k and row remainders.
    #[test]
    fn vector_matches_reference() {
        if !cpu_has_bf16() {
            eprintln!("!!! SKIP bf16 vector kernels: this CPU lacks AVX-512 BF16");
            return;
        }
        let mut seed = 9u64;
        let mut failures = Vec::new();
        for (m, n, k) in PRODUCT_SHAPES {
            let (lda, ldb, ldc) = (k + 3, n + 16, n + 5);
            let a = rand_vec(m * lda, &mut seed);
            let b = rand_vec(k * ldb, &mut seed);
            let pa = PackedA::new(&a, m, k, lda);
            let k2 = pa.pairs();
            let (mut ps, mut pv) = (vec![0u32; k2 * n], vec![0u32; k2 * n]);
            pack_b(Level::Scalar, &b, k, n, ldb, &mut ps);
            pack_b(Level::Avx512, &b, k, n, ldb, &mut pv);
            if ps != pv {
                failures.push(format!("pack m{m} n{n} k{k}: words differ"));
            }
            let c0 = rand_vec(m * ldc, &mut seed);
            let (mut cs, mut cv) = (c0.clone(), c0.clone());
            gemm(Level::Scalar, &pa, &ps, n, &mut cs, ldc);
            gemm(Level::Avx512, &pa, &pv, n, &mut cv, ldc);
            for i in 0..m {
                for j in 0..ldc {
                    let (s, v) = (cs[i * ldc + j], cv[i * ldc + j]);
                    if j >= n {
                        if v != c0[i * ldc + j] {
                            failures.push(format!("m{m} n{n} k{k}: padding ({i},{j}) written"));
                        }
                        continue;
                    }
                    let exact: f64 = (0..k)
                        .map(|p| a[i * lda + p] as f64 * b[p * ldb + j] as f64)
                        .sum();
                    let scale = (0..k)
                        .map(|p| (a[i * lda + p] * b[p * ldb + j]).abs() as f64)
                        .sum::<f64>()
                        .max(1e-3);
                    if (s - v).abs() as f64 > 1e-5 * scale {
                        failures.push(format!("m{m} n{n} k{k} ({i},{j}): scalar {s} vector {v}"));
                    }
                    if (v as f64 - exact).abs() > 1e-2 * scale {
                        failures.push(format!(
                            "m{m} n{n} k{k} ({i},{j}): vector {v} exact {exact}"
                        ));
                    }
                }
            }
        }
        assert!(
            failures.is_empty(),
            "{:#?}",
            &failures[..failures.len().min(20)]
        );
    }
}
