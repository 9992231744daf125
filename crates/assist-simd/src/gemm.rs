//! Small single-precision GEMM for MLP layers: `C (=|+=) A · B`, all row-major with
//! leading dimensions. Shapes are those of tiny MLPs over chunks of samples (M, K ≤ 256;
//! N a chunk of samples, or K in weight-gradient products).
//!
//! Register-blocked micro-kernels: AVX-512 computes 8 rows × 32 columns (16 zmm
//! accumulators), AVX2 6 rows × 16 columns (12 ymm accumulators), both with A broadcast
//! and B loaded along rows; the rows left over below a multiple of the block height go
//! through the same kernel at their own height. Columns left over go one vector per row,
//! then scalar.

use crate::Level;

/// Operands of one product. `c` is M×N with stride `ldc`; `a` is M×K (stride `lda`); `b` is
/// K×N (stride `ldb`).
pub struct Gemm<'a> {
    pub m: usize,
    pub n: usize,
    pub k: usize,
    pub a: &'a [f32],
    pub lda: usize,
    pub b: &'a [f32],
    pub ldb: usize,
    pub ldc: usize,
    /// Add into `c` instead of overwriting it.
    pub accumulate: bool,
}

impl Gemm<'_> {
    fn check(&self, c: &[f32]) {
        assert!(
            self.lda >= self.k && self.ldb >= self.n && self.ldc >= self.n,
            "gemm strides"
        );
        if self.m > 0 && self.k > 0 {
            assert!(
                self.a.len() >= (self.m - 1) * self.lda + self.k,
                "gemm: a too short"
            );
        }
        if self.k > 0 && self.n > 0 {
            assert!(
                self.b.len() >= (self.k - 1) * self.ldb + self.n,
                "gemm: b too short"
            );
        }
        if self.m > 0 && self.n > 0 {
            assert!(
                c.len() >= (self.m - 1) * self.ldc + self.n,
                "gemm: c too short"
            );
        }
    }
}

/// Runs the product at the dispatched level.
pub fn gemm(g: &Gemm, c: &mut [f32]) {
    gemm_at(crate::level(), g, c)
}

/// Runs the product at a given level (falls back to scalar if the CPU lacks it).
pub fn gemm_at(level: Level, g: &Gemm, c: &mut [f32]) {
    g.check(c);
    match level {
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 if level.supported() => {
            // SAFETY: the CPU supports AVX-512F and FMA (checked just above); bounds were
            // checked by `g.check`, and the kernel stays within them.
            unsafe { x86::gemm_avx512(g, c) }
        }
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 if level.supported() => {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above); bounds as above.
            unsafe { x86::gemm_avx2(g, c) }
        }
        _ => gemm_scalar_region(g, c, 0, g.m, 0, g.n),
    }
}

/// The reference: plain loops over a sub-rectangle of C.
pub fn gemm_scalar_region(g: &Gemm, c: &mut [f32], i0: usize, i1: usize, j0: usize, j1: usize) {
    for i in i0..i1 {
        let crow = &mut c[i * g.ldc..i * g.ldc + j1];
        if !g.accumulate {
            crow[j0..j1].fill(0.0);
        }
        for p in 0..g.k {
            let a = g.a[i * g.lda + p];
            if a == 0.0 {
                continue;
            }
            let brow = &g.b[p * g.ldb..p * g.ldb + j1];
            for j in j0..j1 {
                crow[j] += a * brow[j];
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Gemm, gemm_scalar_region};
    use std::arch::x86_64::*;

    /// `R` rows × 32 columns of C from row `i`, column `j` (R ≤ 8 zmm pairs).
    ///
    /// # Safety
    /// Needs AVX-512F and FMA; rows `i..i + R` < m and columns `j..j + 32` ≤ n of a `g`
    /// that passed `Gemm::check` for `c`.
    #[inline(always)]
    unsafe fn block512<const R: usize>(g: &Gemm, cp: *mut f32, i: usize, j: usize) {
        let (a, b) = (g.a.as_ptr(), g.b.as_ptr());
        // SAFETY: every offset is within the rows and columns the caller guarantees.
        unsafe {
            let mut acc = [[_mm512_setzero_ps(); 2]; R];
            if g.accumulate {
                for (r, row) in acc.iter_mut().enumerate() {
                    row[0] = _mm512_loadu_ps(cp.add((i + r) * g.ldc + j));
                    row[1] = _mm512_loadu_ps(cp.add((i + r) * g.ldc + j + 16));
                }
            }
            for p in 0..g.k {
                let b0 = _mm512_loadu_ps(b.add(p * g.ldb + j));
                let b1 = _mm512_loadu_ps(b.add(p * g.ldb + j + 16));
                for (r, row) in acc.iter_mut().enumerate() {
                    let av = _mm512_set1_ps(*a.add((i + r) * g.lda + p));
                    row[0] = _mm512_fmadd_ps(av, b0, row[0]);
                    row[1] = _mm512_fmadd_ps(av, b1, row[1]);
                }
            }
            for (r, row) in acc.iter().enumerate() {
                _mm512_storeu_ps(cp.add((i + r) * g.ldc + j), row[0]);
                _mm512_storeu_ps(cp.add((i + r) * g.ldc + j + 16), row[1]);
            }
        }
    }

    /// # Safety
    /// Needs AVX-512F and FMA; `g` must pass `Gemm::check` for `c`.
    #[target_feature(enable = "avx512f,fma")]
    pub unsafe fn gemm_avx512(g: &Gemm, c: &mut [f32]) {
        const MR: usize = 8;
        const NR: usize = 32;
        let (m_main, n_main) = (g.m / MR * MR, g.n / NR * NR);
        let (a, b, cp) = (g.a.as_ptr(), g.b.as_ptr(), c.as_mut_ptr());
        let mut j = 0;
        while j < n_main {
            let mut i = 0;
            while i < m_main {
                // SAFETY: rows i..i+8 ≤ m, columns j..j+32 ≤ n.
                unsafe { block512::<MR>(g, cp, i, j) };
                i += MR;
            }
            // The last m mod 8 rows in one block of that height (an MLP's output layer
            // of 3), not row by row: each B vector loaded serves them all.
            // SAFETY: rows m_main..m, columns j..j+32 ≤ n.
            unsafe {
                match g.m - m_main {
                    0 => {}
                    1 => block512::<1>(g, cp, m_main, j),
                    2 => block512::<2>(g, cp, m_main, j),
                    3 => block512::<3>(g, cp, m_main, j),
                    4 => block512::<4>(g, cp, m_main, j),
                    5 => block512::<5>(g, cp, m_main, j),
                    6 => block512::<6>(g, cp, m_main, j),
                    _ => block512::<7>(g, cp, m_main, j),
                }
            }
            j += NR;
        }
        if n_main < g.n {
            // Columns n_main..n16 of every row (one 16-wide vector each), then scalar.
            let n16 = g.n / 16 * 16;
            for i in 0..g.m {
                let mut j = n_main;
                while j < n16 {
                    // SAFETY: row i < m, columns j..j+16 ≤ n.
                    unsafe {
                        let mut acc = if g.accumulate {
                            _mm512_loadu_ps(cp.add(i * g.ldc + j))
                        } else {
                            _mm512_setzero_ps()
                        };
                        for p in 0..g.k {
                            let av = _mm512_set1_ps(*a.add(i * g.lda + p));
                            acc = _mm512_fmadd_ps(av, _mm512_loadu_ps(b.add(p * g.ldb + j)), acc);
                        }
                        _mm512_storeu_ps(cp.add(i * g.ldc + j), acc);
                    }
                    j += 16;
                }
            }
            gemm_scalar_region(g, c, 0, g.m, n16, g.n);
        }
    }

    /// `R` rows × 16 columns of C from row `i`, column `j` (R ≤ 6 ymm pairs).
    ///
    /// # Safety
    /// Needs AVX2 and FMA; rows `i..i + R` < m and columns `j..j + 16` ≤ n of a `g` that
    /// passed `Gemm::check` for `c`.
    #[inline(always)]
    unsafe fn block256<const R: usize>(g: &Gemm, cp: *mut f32, i: usize, j: usize) {
        let (a, b) = (g.a.as_ptr(), g.b.as_ptr());
        // SAFETY: every offset is within the rows and columns the caller guarantees.
        unsafe {
            let mut acc = [[_mm256_setzero_ps(); 2]; R];
            if g.accumulate {
                for (r, row) in acc.iter_mut().enumerate() {
                    row[0] = _mm256_loadu_ps(cp.add((i + r) * g.ldc + j));
                    row[1] = _mm256_loadu_ps(cp.add((i + r) * g.ldc + j + 8));
                }
            }
            for p in 0..g.k {
                let b0 = _mm256_loadu_ps(b.add(p * g.ldb + j));
                let b1 = _mm256_loadu_ps(b.add(p * g.ldb + j + 8));
                for (r, row) in acc.iter_mut().enumerate() {
                    let av = _mm256_broadcast_ss(&*a.add((i + r) * g.lda + p));
                    row[0] = _mm256_fmadd_ps(av, b0, row[0]);
                    row[1] = _mm256_fmadd_ps(av, b1, row[1]);
                }
            }
            for (r, row) in acc.iter().enumerate() {
                _mm256_storeu_ps(cp.add((i + r) * g.ldc + j), row[0]);
                _mm256_storeu_ps(cp.add((i + r) * g.ldc + j + 8), row[1]);
            }
        }
    }

    /// # Safety
    /// Needs AVX2 and FMA; `g` must pass `Gemm::check` for `c`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn gemm_avx2(g: &Gemm, c: &mut [f32]) {
        const MR: usize = 6;
        const NR: usize = 16;
        let (m_main, n_main) = (g.m / MR * MR, g.n / NR * NR);
        let (a, b, cp) = (g.a.as_ptr(), g.b.as_ptr(), c.as_mut_ptr());
        let mut j = 0;
        while j < n_main {
            let mut i = 0;
            while i < m_main {
                // SAFETY: rows i..i+6 ≤ m, columns j..j+16 ≤ n.
                unsafe { block256::<MR>(g, cp, i, j) };
                i += MR;
            }
            // The last m mod 6 rows (4 of an MLP's 64 or 16, 2 of 32, 3 of an output
            // layer) in one block of that height, not row by row.
            // SAFETY: rows m_main..m, columns j..j+16 ≤ n.
            unsafe {
                match g.m - m_main {
                    0 => {}
                    1 => block256::<1>(g, cp, m_main, j),
                    2 => block256::<2>(g, cp, m_main, j),
                    3 => block256::<3>(g, cp, m_main, j),
                    4 => block256::<4>(g, cp, m_main, j),
                    _ => block256::<5>(g, cp, m_main, j),
                }
            }
            j += NR;
        }
        if n_main < g.n {
            // Columns n_main..n8 of every row (one 8-wide vector each), then scalar.
            let n8 = g.n / 8 * 8;
            for i in 0..g.m {
                let mut j = n_main;
                while j < n8 {
                    // SAFETY: row i < m, columns j..j+8 ≤ n.
                    unsafe {
                        let mut acc = if g.accumulate {
                            _mm256_loadu_ps(cp.add(i * g.ldc + j))
                        } else {
                            _mm256_setzero_ps()
                        };
                        for p in 0..g.k {
                            let av = _mm256_broadcast_ss(&*a.add(i * g.lda + p));
                            acc = _mm256_fmadd_ps(av, _mm256_loadu_ps(b.add(p * g.ldb + j)), acc);
                        }
                        _mm256_storeu_ps(cp.add(i * g.ldc + j), acc);
                    }
                    j += 8;
                }
            }
            gemm_scalar_region(g, c, 0, g.m, n8, g.n);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_util::rand_vec;

    fn naive(
        m: usize,
        n: usize,
        k: usize,
        a: &[f32],
        lda: usize,
        b: &[f32],
        ldb: usize,
        c: &mut [f32],
        ldc: usize,
        acc: bool,
    ) {
        for i in 0..m {
            for j in 0..n {
                let mut s = if acc { c[i * ldc + j] as f64 } else { 0.0 };
                for p in 0..k {
                    s += a[i * lda + p] as f64 * b[p * ldb + j] as f64;
                }
                c[i * ldc + j] = s as f32;
            }
        }
    }

    /// Every level against a naive f64-accumulating reference, over shapes that hit every
    /// edge path (rows and columns not multiples of the micro-tile), with strides.
    #[test]
    fn all_levels_match_reference() {
        let mut seed = 1u64;
        let mut failures = Vec::new();
        for level in [Level::Scalar, Level::Avx2, Level::Avx512] {
            if !level.supported() {
                eprintln!("!!! SKIP gemm level {}: this CPU lacks it", level.name());
                continue;
            }
            for &(m, n, k) in &[
                (64, 128, 64),
                (16, 64, 64),
                (3, 64, 64),
                (64, 64, 32),
                (7, 33, 5),
                (13, 47, 19),
                (1, 1, 1),
                (9, 100, 64),
                (64, 16, 128),
                // Every leftover height of both kernels (m mod 6, m mod 8).
                (11, 48, 7),
                (14, 40, 9),
                (12, 32, 5),
                (32, 64, 16),
                (0, 5, 3),
                (4, 0, 3),
                (5, 4, 0),
            ] {
                for acc in [false, true] {
                    let (lda, ldb, ldc) = (k + 3, n + 5, n + 1);
                    let a = rand_vec(m * lda + 1, &mut seed);
                    let b = rand_vec(k * ldb + 1, &mut seed);
                    let c0 = rand_vec(m * ldc + 1, &mut seed);
                    let mut want = c0.clone();
                    naive(m, n, k, &a, lda, &b, ldb, &mut want, ldc, acc);
                    let mut got = c0.clone();
                    gemm_at(
                        level,
                        &Gemm {
                            m,
                            n,
                            k,
                            a: &a,
                            lda,
                            b: &b,
                            ldb,
                            ldc,
                            accumulate: acc,
                        },
                        &mut got,
                    );
                    let worst = want
                        .iter()
                        .zip(&got)
                        .map(|(x, y)| (x - y).abs())
                        .fold(0.0f32, f32::max);
                    // Padding between rows (beyond n) must be untouched.
                    let pad_ok =
                        (0..m).all(|i| (n..ldc).all(|j| got[i * ldc + j] == c0[i * ldc + j]));
                    if worst > 1e-4 * (k as f32).sqrt().max(1.0) || !pad_ok {
                        failures.push(format!(
                            "{} m{m} n{n} k{k} acc{acc}: max err {worst}, padding kept {pad_ok}",
                            level.name()
                        ));
                    }
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
    }
}
