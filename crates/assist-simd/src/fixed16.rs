//! 16-bit fixed-point matrix products for inference at the AVX2 level (`vpmaddwd`: two
//! 16-bit products summed into 32 bits, 16 multiply-adds per instruction against the f32
//! kernel's 8). Each weight row is scaled to integers of at
//! most [`W_MAX`] and each column of activations (one sample's) to at most [`x_max`]; the
//! products are summed exactly in i32 (the bounds keep every sum below 2³¹) and the sum is
//! scaled back to f32. About 4 significant digits per operand relative to its row's or
//! sample's largest — finer than bf16's 3 — for rendering, never for training (gradients
//! stay f32). A sample's outputs depend on its own inputs alone, whatever else shares its
//! block, so a render is the same bits however its samples are batched.
//!
//! Operands are packed in pairs along K, as `bf16` packs them: a 32-bit word holds element
//! `2p` in its low half and `2p + 1` in its high half. The scalar path is the reference and
//! the vector path gives the same bits (integer sums, then the same two f32 roundings).

use crate::Level;

/// The largest weight magnitude after scaling (12 bits and a sign).
pub const W_MAX: f32 = 4095.0;

/// The largest activation magnitude after scaling for products over `k2` pairs: every sum
/// of `2·k2` products stays below 2³¹ (8,194 for 32 pairs, a 64-wide layer).
pub fn x_max(k2: usize) -> f32 {
    let bound = (i32::MAX as f64 / (2.0 * k2.max(1) as f64 * W_MAX as f64)).floor();
    bound.min(32767.0) as f32
}

/// Whether rendering's products run in fixed point here (see [`crate::products`]).
pub fn available() -> bool {
    crate::products() == crate::Products::Fixed16
}

/// `1 / s`, or 0 where `s` is too small for a normal scale (the block is taken as zeros).
#[inline(always)]
fn inverse(s: f32) -> f32 {
    if s >= f32::MIN_POSITIVE { 1.0 / s } else { 0.0 }
}

#[inline(always)]
fn pair(lo: i32, hi: i32) -> u32 {
    (lo as u32 & 0xffff) | (hi as u32) << 16
}

/// Rows of a panel: the product kernel's block height. Six rows × 16 columns keep 12
/// accumulators, two activation vectors and a weight in AVX2's 16 registers.
const MR: usize = 6;

/// A weight matrix `A` (`m × k`) scaled per row and packed as i16 pairs in panels of
/// six rows (the kernel's block height; fewer in the last): word `p` of row `i` holds
/// `A[i][2p]`, `A[i][2p + 1]` (zero past `k`) over `scale[i]`, and a panel holds its rows'
/// words `p` side by side, so the kernel reads each step's weights from one place.
#[derive(Debug, Clone, PartialEq)]
pub struct QuantA {
    pub m: usize,
    pub k: usize,
    k2: usize,
    data: Vec<u32>,
    scale: Vec<f32>,
}

impl QuantA {
    /// Scales and packs the first `k` columns of `a` (row-major, stride `lda`). A row that
    /// is not finite is kept as NaN through its scale (so its outputs are NaN, as the f32
    /// product's would be).
    pub fn new(a: &[f32], m: usize, k: usize, lda: usize) -> Self {
        assert!(lda >= k && (m == 0 || a.len() >= (m - 1) * lda + k));
        let k2 = k.div_ceil(2);
        let mut rows = Vec::with_capacity(m);
        let mut scale = Vec::with_capacity(m);
        for i in 0..m {
            let row = &a[i * lda..i * lda + k];
            let big = row.iter().fold(0.0f32, |b, v| b.max(v.abs()));
            let finite = row.iter().all(|v| v.is_finite());
            let s = if finite { big / W_MAX } else { f32::NAN };
            // Rows too small for a normal scale are taken as zeros.
            let inv = inverse(s);
            let q = |c: usize| {
                if c < k && finite {
                    (row[c] * inv).round_ties_even() as i32
                } else {
                    0
                }
            };
            rows.push(
                (0..k2)
                    .map(|p| pair(q(2 * p), q(2 * p + 1)))
                    .collect::<Vec<_>>(),
            );
            scale.push(s);
        }
        let mut data = Vec::with_capacity(m * k2);
        for panel in rows.chunks(MR) {
            for p in 0..k2 {
                data.extend(panel.iter().map(|r| r[p]));
            }
        }
        QuantA {
            m,
            k,
            k2,
            data,
            scale,
        }
    }
    /// Words per row (`⌈k / 2⌉`), which is also the packed activations' row count.
    pub fn pairs(&self) -> usize {
        self.k2
    }
    /// Word `p` of row `i`.
    fn word(&self, i: usize, p: usize) -> u32 {
        let (start, rows) = (i / MR * MR, MR.min(self.m - i / MR * MR));
        self.data[start * self.k2 + p * rows + (i - start)]
    }
}

/// Scales each column `j` of activations `B` (`k × n`, row-major stride `ldb`) to integers
/// of at most [`x_max`]`(⌈k/2⌉)`, its scale into `scale[j]`, and packs them as i16 pairs of
/// rows: `out[p * n + j]` holds `B[2p][j]`, `B[2p + 1][j]` (zero past `k`). A column with a
/// value that is not finite gets a NaN scale (its outputs are NaN).
pub fn quant_b(
    level: Level,
    b: &[f32],
    k: usize,
    n: usize,
    ldb: usize,
    out: &mut [u32],
    scale: &mut [f32],
) {
    assert!(ldb >= n && (k == 0 || b.len() >= (k - 1) * ldb + n));
    let k2 = k.div_ceil(2);
    assert!(out.len() >= k2 * n && scale.len() >= n);
    #[cfg(target_arch = "x86_64")]
    if level == Level::Avx512 && Level::Avx512.supported() && n.is_multiple_of(16) {
        // SAFETY: AVX-512F present (checked); the same reads and writes as below.
        unsafe { x86v::quant_b(b, k, n, ldb, out, scale) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if level >= Level::Avx2 && Level::Avx2.supported() && n.is_multiple_of(8) {
        // SAFETY: AVX2 present (checked); rows < k over columns < n are read, words p·n + j
        // for p < k2, j < n and scale[..n] written: within the lengths asserted above.
        unsafe { x86::quant_b(b, k, n, ldb, out, scale) };
        return;
    }
    let _ = level;
    let xm = x_max(k2);
    for j in 0..n {
        let mut big = 0.0f32;
        let mut finite = true;
        for r in 0..k {
            let v = b[r * ldb + j];
            finite &= v.is_finite();
            big = big.max(v.abs());
        }
        let s = big / xm;
        let inv = if finite { inverse(s) } else { 0.0 };
        scale[j] = if finite { s } else { f32::NAN };
        let q = |r: usize| {
            if r < k {
                (b[r * ldb + j] * inv).round_ties_even() as i32
            } else {
                0
            }
        };
        for p in 0..k2 {
            out[p * n + j] = pair(q(2 * p), q(2 * p + 1));
        }
    }
}

/// `C (m × n, stride ldc) = A · B` from scaled operands (`bp` and `sb` from [`quant_b`] with
/// the same `k` and `n`): each exact integer sum, as f32, times `scale[i] · sb[j]`. The
/// vector path needs `n` a multiple of 16 and gives the scalar path's bits.
pub fn gemm(level: Level, a: &QuantA, bp: &[u32], sb: &[f32], n: usize, c: &mut [f32], ldc: usize) {
    let (m, k2) = (a.m, a.k2);
    assert!(bp.len() >= k2 * n && sb.len() >= n && ldc >= n);
    assert!(m == 0 || c.len() >= (m - 1) * ldc + n);
    #[cfg(target_arch = "x86_64")]
    if level == Level::Avx512 && vnni() && n.is_multiple_of(32) {
        // SAFETY: AVX-512 VNNI present (checked); the lengths as below.
        unsafe { x86v::gemm_vnni(&a.data, &a.scale, m, k2, bp, sb, n, c, ldc) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if level >= Level::Avx2 && Level::Avx2.supported() && n.is_multiple_of(16) {
        // SAFETY: AVX2 present (checked); a.data holds m·k2 words, bp k2·n, sb n, and c
        // rows < m over columns < n are written: within the lengths asserted above.
        unsafe { x86::gemm(&a.data, &a.scale, m, k2, bp, sb, n, c, ldc) };
        return;
    }
    let _ = level;
    for i in 0..m {
        for j in 0..n {
            let mut acc = 0i32;
            for p in 0..k2 {
                let (w, x) = (a.word(i, p), bp[p * n + j]);
                acc += (w as i16 as i32) * (x as i16 as i32)
                    + ((w >> 16) as i16 as i32) * ((x >> 16) as i16 as i32);
            }
            c[i * ldc + j] = acc as f32 * (a.scale[i] * sb[j]);
        }
    }
}

/// Whether the CPU has AVX-512 VNNI (`vpdpwssd`: the pairs' products and their sum in one
/// instruction, which an Intel Xeon issues twice a cycle, 64 multiply-adds against its
/// f32 FMA's 32) beside the AVX-512 level.
pub fn vnni() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        Level::Avx512.supported() && is_x86_feature_detected!("avx512vnni")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A product kernel's driver: each panel of up to [`MR`] rows times each `$step` columns,
/// through `$block::<R>` at the panel's height (the AVX2 and VNNI kernels share it).
/// Unsafe to expand: every block must stay within rows < m, words < k2 and columns < n,
/// inside the slices, as the kernels' contracts require.
#[cfg(target_arch = "x86_64")]
macro_rules! panels {
    ($block:ident, $step:expr, $a:expr, $scale:expr, $m:expr, $k2:expr, $bp:expr, $sb:expr, $n:expr, $c:expr, $ldc:expr) => {{
        let (ap, bptr, sp, cp) = ($a.as_ptr(), $bp.as_ptr(), $sb.as_ptr(), $c.as_mut_ptr());
        let (scale, m, k2, n, ldc) = ($scale, $m, $k2, $n, $ldc);
        let mut i = 0;
        while i < m {
            let rows = (m - i).min(crate::fixed16::MR);
            let ap = ap.add(i * k2);
            for j in (0..n).step_by($step) {
                match rows {
                    6 => $block::<6>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                    5 => $block::<5>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                    4 => $block::<4>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                    3 => $block::<3>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                    2 => $block::<2>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                    _ => $block::<1>(ap, scale, k2, bptr, sp, n, cp, ldc, i, j),
                }
            }
            i += rows;
        }
    }};
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// # Safety
    /// AVX2; `n` a multiple of 8; bounds as `super::quant_b` asserts.
    #[target_feature(enable = "avx2,fma")]
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
        // SAFETY (whole function): rows < k at columns < n, output words < k2·n and scales
        // < n, which the caller's contract puts inside the slices.
        unsafe {
            let abs = _mm256_set1_epi32(0x7fff_ffff);
            let low = _mm256_set1_epi32(0xffff);
            let xm = _mm256_set1_ps(super::x_max(k2));
            let tiny = _mm256_set1_ps(f32::MIN_POSITIVE);
            let one = _mm256_set1_ps(1.0);
            for j in (0..n).step_by(8) {
                // Each lane's largest magnitude as the largest of its values' bits without
                // their signs (ordered as the magnitudes are); infinity and NaN have every
                // exponent bit set.
                let mut big = _mm256_setzero_si256();
                for r in 0..k {
                    let v = _mm256_loadu_si256(bp.add(r * ldb + j).cast());
                    big = _mm256_max_epi32(big, _mm256_and_si256(v, abs));
                }
                let bad =
                    _mm256_castsi256_ps(_mm256_cmpgt_epi32(big, _mm256_set1_epi32(0x7f7f_ffff)));
                let s = _mm256_div_ps(_mm256_castsi256_ps(big), xm);
                // 1 / s where s is normal and the column finite, else 0 (as `inverse`).
                let usable = _mm256_andnot_ps(bad, _mm256_cmp_ps::<_CMP_GE_OQ>(s, tiny));
                let inv = _mm256_and_ps(_mm256_div_ps(one, s), usable);
                _mm256_storeu_ps(
                    scale.as_mut_ptr().add(j),
                    _mm256_blendv_ps(s, _mm256_set1_ps(f32::NAN), bad),
                );
                for p in 0..k2 {
                    // Rounded to nearest even (the default rounding mode), as the scalar
                    // path's `round_ties_even`.
                    let q0 = _mm256_cvtps_epi32(_mm256_mul_ps(
                        _mm256_loadu_ps(bp.add(2 * p * ldb + j)),
                        inv,
                    ));
                    let q1 = if 2 * p + 1 < k {
                        _mm256_cvtps_epi32(_mm256_mul_ps(
                            _mm256_loadu_ps(bp.add((2 * p + 1) * ldb + j)),
                            inv,
                        ))
                    } else {
                        _mm256_setzero_si256()
                    };
                    let w = _mm256_or_si256(_mm256_and_si256(q0, low), _mm256_slli_epi32::<16>(q1));
                    _mm256_storeu_si256(op.add(p * n + j).cast(), w);
                }
            }
        }
    }

    /// Rows `i..i + R` (the panel at `a`) × columns `j..j + 16`: the integer sums, scaled
    /// into `c`.
    ///
    /// # Safety
    /// AVX2; the rows, words and columns exist (as `gemm`'s contract).
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
            let mut acc = [[_mm256_setzero_si256(); 2]; R];
            let (mut wp, mut xp) = (a, bp.add(j));
            for _ in 0..k2 {
                let b0 = _mm256_loadu_si256(xp.cast());
                let b1 = _mm256_loadu_si256(xp.add(8).cast());
                for (r, row) in acc.iter_mut().enumerate() {
                    let w = _mm256_set1_epi32(*wp.add(r) as i32);
                    row[0] = _mm256_add_epi32(row[0], _mm256_madd_epi16(b0, w));
                    row[1] = _mm256_add_epi32(row[1], _mm256_madd_epi16(b1, w));
                }
                (wp, xp) = (wp.add(R), xp.add(n));
            }
            let (s0, s1) = (_mm256_loadu_ps(sb.add(j)), _mm256_loadu_ps(sb.add(j + 8)));
            for (r, row) in acc.iter().enumerate() {
                let w = _mm256_set1_ps(scale[i + r]);
                let out = c.add((i + r) * ldc + j);
                let (t0, t1) = (_mm256_mul_ps(w, s0), _mm256_mul_ps(w, s1));
                _mm256_storeu_ps(out, _mm256_mul_ps(_mm256_cvtepi32_ps(row[0]), t0));
                _mm256_storeu_ps(out.add(8), _mm256_mul_ps(_mm256_cvtepi32_ps(row[1]), t1));
            }
        }
    }

    /// # Safety
    /// AVX2; `a` holds m·k2 words, `scale` m, `bp` k2·n, `sb` n, `c` m rows of stride ldc ≥ n;
    /// `n` a multiple of 16.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn gemm(
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
        unsafe { panels!(block, 16, a, scale, m, k2, bp, sb, n, c, ldc) }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86v;

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_util::{PRODUCT_SHAPES, rand_vec};

    /// The vector packing and product give the scalar reference's bits, and both are the
    /// f32 product within the scaling's rounding; over shapes with odd k, row remainders,
    /// rows of zeros, rows and samples of very different sizes, and a sample of zeros. A
    /// sample's outputs are the same bits whatever the other samples of its block hold.
    #[test]
    fn vector_matches_reference_and_f32() {
        if !Level::Avx2.supported() {
            eprintln!("!!! SKIP fixed16 vector kernels: this CPU lacks AVX2");
            return;
        }
        let mut seed = 11u64;
        let mut failures = Vec::new();
        for (m, n, k) in PRODUCT_SHAPES {
            let (lda, ldb, ldc) = (k + 3, n + 16, n + 5);
            let mut a = rand_vec(m * lda, &mut seed);
            // A row of zeros and a row a thousand times smaller than the others.
            a[..k].iter_mut().for_each(|v| *v = 0.0);
            if m > 1 {
                a[lda..lda + k].iter_mut().for_each(|v| *v *= 1e-3);
            }
            let mut b = rand_vec(k * ldb, &mut seed);
            b.iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v *= 1.0 + (i % 7) as f32 * (1 + i % ldb % 5) as f32);
            (0..k).for_each(|r| b[r * ldb + 1] = 0.0);
            let qa = QuantA::new(&a, m, k, lda);
            let k2 = qa.pairs();
            let (mut ps, mut pv) = (vec![0u32; k2 * n], vec![0u32; k2 * n]);
            let (mut ss, mut sv) = (vec![0.0; n], vec![0.0; n]);
            quant_b(Level::Scalar, &b, k, n, ldb, &mut ps, &mut ss);
            quant_b(Level::Avx2, &b, k, n, ldb, &mut pv, &mut sv);
            if ps != pv || ss != sv {
                failures.push(format!("pack m{m} n{n} k{k}: words or scales differ"));
            }
            if Level::Avx512.supported() {
                let (mut p5, mut s5) = (vec![0u32; k2 * n], vec![0.0f32; n]);
                quant_b(Level::Avx512, &b, k, n, ldb, &mut p5, &mut s5);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                if ps != p5 || bits(&ss) != bits(&s5) {
                    failures.push(format!(
                        "pack m{m} n{n} k{k}: AVX-512 words or scales differ"
                    ));
                }
            }
            let c0 = rand_vec(m * ldc, &mut seed);
            let (mut cs, mut cv) = (c0.clone(), c0.clone());
            gemm(Level::Scalar, &qa, &ps, &ss, n, &mut cs, ldc);
            gemm(Level::Avx2, &qa, &pv, &sv, n, &mut cv, ldc);
            // The AVX-512 level (VNNI where the CPU has it): the same bits.
            if Level::Avx512.supported() {
                let mut c5 = c0.clone();
                gemm(Level::Avx512, &qa, &pv, &sv, n, &mut c5, ldc);
                if c5.iter().zip(&cv).any(|(x, y)| x.to_bits() != y.to_bits()) {
                    failures.push(format!("m{m} n{n} k{k}: AVX-512 level differs"));
                }
            }
            // Sample 0 alone in its block (the others zeros): the same bits.
            let mut alone = vec![0.0f32; k * ldb];
            (0..k).for_each(|r| alone[r * ldb] = b[r * ldb]);
            let (mut pa, mut sa) = (vec![0u32; k2 * n], vec![0.0; n]);
            quant_b(Level::Avx2, &alone, k, n, ldb, &mut pa, &mut sa);
            let mut ca = c0.clone();
            gemm(Level::Avx2, &qa, &pa, &sa, n, &mut ca, ldc);
            if (0..m).any(|i| ca[i * ldc].to_bits() != cv[i * ldc].to_bits()) {
                failures.push(format!(
                    "m{m} n{n} k{k}: sample 0 changed with its neighbours"
                ));
            }
            for i in 0..m {
                for j in 0..ldc {
                    let (s, v) = (cs[i * ldc + j], cv[i * ldc + j]);
                    if j >= n {
                        if v != c0[i * ldc + j] || s != c0[i * ldc + j] {
                            failures.push(format!("m{m} n{n} k{k}: padding ({i},{j}) written"));
                        }
                        continue;
                    }
                    if s.to_bits() != v.to_bits() {
                        failures.push(format!("m{m} n{n} k{k} ({i},{j}): scalar {s} vector {v}"));
                    }
                    let exact: f64 = (0..k)
                        .map(|p| a[i * lda + p] as f64 * b[p * ldb + j] as f64)
                        .sum();
                    // The rounding of each operand: half a step of its row's or sample's scale.
                    let (wmax, xmax) = (
                        (0..k).map(|p| a[i * lda + p].abs()).fold(0.0, f32::max) as f64,
                        (0..k).map(|p| b[p * ldb + j].abs()).fold(0.0, f32::max) as f64,
                    );
                    let bound = k as f64
                        * wmax
                        * xmax
                        * (0.5 / W_MAX as f64 + 0.5 / x_max(k2) as f64)
                        * 1.01
                        + 1e-30;
                    if (v as f64 - exact).abs() > bound {
                        failures.push(format!(
                            "m{m} n{n} k{k} ({i},{j}): vector {v} exact {exact} bound {bound}"
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

    /// The bounds keep the integer sums exact: every operand at its largest magnitude and
    /// of one sign, over the widest product, sums without wrapping.
    #[test]
    fn largest_sums_do_not_wrap() {
        for k in [1usize, 2, 31, 64, 128, 1024] {
            let k2 = k.div_ceil(2);
            let (m, n) = (2, 32);
            let a = vec![-3.0f32; m * k];
            let b = vec![-5.0f32; k * n];
            let qa = QuantA::new(&a, m, k, k);
            for level in [Level::Scalar, Level::Avx2, Level::Avx512] {
                if !level.supported() {
                    continue;
                }
                let (mut bp, mut sb) = (vec![0u32; k2 * n], vec![0.0; n]);
                quant_b(level, &b, k, n, n, &mut bp, &mut sb);
                let mut c = vec![0.0f32; m * n];
                gemm(level, &qa, &bp, &sb, n, &mut c, n);
                for v in c {
                    assert!(
                        (v - 15.0 * k as f32).abs() <= 1e-3 * 15.0 * k as f32,
                        "k {k} {level:?}: {v}"
                    );
                }
            }
        }
    }

    /// A sample with a value that is not finite, or a row of weights that is not, gives
    /// NaN outputs; the other samples and rows are unchanged.
    #[test]
    fn non_finite_values_give_nan() {
        for level in [Level::Scalar, Level::Avx2, Level::Avx512] {
            if !level.supported() {
                continue;
            }
            let mut a = vec![1.0f32; 2 * 4];
            a[5] = f32::NAN;
            let qa = QuantA::new(&a, 2, 4, 4);
            for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
                let mut b = vec![0.5f32; 4 * 16];
                b[2 * 16 + 5] = bad;
                let (mut bp, mut sb) = (vec![0u32; 2 * 16], vec![0.0; 16]);
                quant_b(level, &b, 4, 16, 16, &mut bp, &mut sb);
                let mut c = vec![0.0f32; 2 * 16];
                gemm(level, &qa, &bp, &sb, 16, &mut c, 16);
                for (j, v) in c[..16].iter().enumerate() {
                    assert!(
                        if j == 5 {
                            v.is_nan()
                        } else {
                            (v - 2.0).abs() < 1e-3
                        },
                        "{level:?} {bad}: {c:?}"
                    );
                }
                assert!(c[16..].iter().all(|v| v.is_nan()), "{c:?}");
            }
        }
    }
}
