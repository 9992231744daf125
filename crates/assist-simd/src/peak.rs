//! Measures the machine's peak single-precision FMA throughput on one core (independent
//! accumulator chains, no memory traffic) and the memory bandwidth of all its threads, for
//! "how far from the limit" figures.

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

/// Bytes [`memory_gbytes`] streams through per pass, its two arrays of 128 MiB shared out
/// among the threads: beyond the L3 of any core complex (96 MiB on AMD's stacked-cache
/// parts), so every pass goes to memory.
const STREAM_BYTES: usize = 256 << 20;

/// GB/s of memory traffic `threads` threads sustain together over roughly `seconds`
/// (the best pass): each updates its own share of two large arrays in place, `a[i] =
/// a[i] · s + b[i]`, which reads `a` and `b` and writes `a` back, as Adam's sweep reads
/// and rewrites its moments (no line is written that was not read, so none is fetched
/// for the write alone). The traffic counted is the three streams, 12 bytes an element:
/// the figure Adam's own bytes per second are set against (`assist bench field`).
pub fn memory_gbytes(seconds: f64, threads: usize) -> f64 {
    let threads = threads.max(1);
    let per = STREAM_BYTES / 8 / threads;
    let mut data: Vec<(Vec<f32>, Vec<f32>)> = (0..threads)
        .map(|t| (vec![1.0f32; per], vec![t as f32 * 1e-3; per]))
        .collect();
    let start = std::time::Instant::now();
    let mut best = 0f64;
    while best == 0.0 || start.elapsed().as_secs_f64() < seconds {
        let t0 = std::time::Instant::now();
        std::thread::scope(|sc| {
            for (a, b) in data.iter_mut() {
                sc.spawn(move || {
                    for (x, y) in a.iter_mut().zip(b.iter()) {
                        *x = *x * 0.999 + *y;
                    }
                    std::hint::black_box(&a[0]);
                });
            }
        });
        let bytes = (threads * per * 12) as f64;
        best = best.max(bytes / t0.elapsed().as_secs_f64() / 1e9);
    }
    best
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The bandwidth is a finite, positive figure whatever the thread count, and the FMA
    /// peak one at every level this CPU runs.
    #[test]
    fn the_measured_limits_are_positive_figures() {
        for threads in [1, 2, 3] {
            let g = memory_gbytes(0.0, threads);
            assert!(g.is_finite() && g > 0.0, "{threads} threads: {g}");
        }
        let f = fma_gflops(crate::level(), 0.01);
        assert!(f.is_finite() && f > 0.0, "{f}");
    }
}
