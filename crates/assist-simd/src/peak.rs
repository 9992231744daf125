//! Measures the machine's peak single-precision FMA throughput on one core (independent
//! accumulator chains, no memory traffic), for "how far from the limit" figures.

use crate::Level;

/// GFLOP/s of one core at `level` over roughly `seconds`.
pub fn fma_gflops(level: Level, seconds: f64) -> f64 {
    let start = std::time::Instant::now();
    let mut flops = 0f64;
    let mut sink = 0f32;
    while start.elapsed().as_secs_f64() < seconds {
        let iters = 1_000_000u64;
        let (f, s) = match level {
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 if level.supported() => {
                // SAFETY: AVX-512F and FMA are supported (checked just above).
                (unsafe { x86::fma512(iters) }, 0.0)
            }
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 if level.supported() => {
                // SAFETY: AVX2 and FMA are supported (checked just above).
                (unsafe { x86::fma256(iters) }, 0.0)
            }
            _ => scalar(iters),
        };
        flops += f;
        sink += s;
    }
    std::hint::black_box(sink);
    flops / start.elapsed().as_secs_f64() / 1e9
}

fn scalar(iters: u64) -> (f64, f32) {
    let mut acc = [1.0f32; 8];
    for _ in 0..iters {
        for a in &mut acc {
            *a = *a * 0.999_999 + 1e-7;
        }
    }
    (iters as f64 * 16.0, acc.iter().sum())
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// # Safety
    /// Needs AVX-512F and FMA.
    #[target_feature(enable = "avx512f,fma")]
    pub unsafe fn fma512(iters: u64) -> f64 {
        let m = _mm512_set1_ps(0.999_999);
        let c = _mm512_set1_ps(1e-7);
        let mut a = [_mm512_set1_ps(1.0); 12];
        for _ in 0..iters {
            for v in &mut a {
                *v = _mm512_fmadd_ps(*v, m, c);
            }
        }
        let mut s = _mm512_setzero_ps();
        for v in a {
            s = _mm512_add_ps(s, v);
        }
        std::hint::black_box(s);
        iters as f64 * 12.0 * 32.0
    }

    /// # Safety
    /// Needs AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn fma256(iters: u64) -> f64 {
        let m = _mm256_set1_ps(0.999_999);
        let c = _mm256_set1_ps(1e-7);
        let mut a = [_mm256_set1_ps(1.0); 12];
        for _ in 0..iters {
            for v in &mut a {
                *v = _mm256_fmadd_ps(*v, m, c);
            }
        }
        let mut s = _mm256_setzero_ps();
        for v in a {
            s = _mm256_add_ps(s, v);
        }
        std::hint::black_box(s);
        iters as f64 * 12.0 * 16.0
    }
}
