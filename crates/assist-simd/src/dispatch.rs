//! Runtime multiversioning of ordinary Rust code: a [`WithSimd`] body (its `run` marked
//! `#[inline(always)]`) is instantiated inside functions compiled for AVX-512 and for
//! AVX2+FMA, and the one matching the CPU is called. The compiler then auto-vectorises the
//! body (and everything inlined into it) for that level; the baseline copy is always there
//! as the fallback. Callers stay free of `unsafe`.

use crate::Level;

/// A piece of work to run at the best SIMD level. Implement `run` with
/// `#[inline(always)]` so that it is compiled into each variant.
pub trait WithSimd {
    type Output;
    fn run(self) -> Self::Output;
}

/// Runs `w` compiled for the dispatched level.
#[inline]
pub fn dispatch<W: WithSimd>(w: W) -> W::Output {
    match crate::level() {
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => {
            // SAFETY: `level()` returns Avx512 only when the CPU reports every feature
            // enabled on `run_avx512` (see `Level::supported`).
            unsafe { run_avx512(w) }
        }
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => {
            // SAFETY: `level()` returns Avx2 only when the CPU reports AVX2 and FMA (and
            // the other features enabled on `run_avx2`).
            unsafe { run_avx2(w) }
        }
        _ => w.run(),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c,bmi1,bmi2,popcnt")]
unsafe fn run_avx512<W: WithSimd>(w: W) -> W::Output {
    w.run()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c,bmi1,bmi2,popcnt")]
unsafe fn run_avx2<W: WithSimd>(w: W) -> W::Output {
    w.run()
}

/// A closure as a [`WithSimd`] body. Mark the closure `#[inline(always)]`: otherwise the
/// optimiser inlines it into the variants only when it is small, and a larger one is
/// compiled once, at the baseline level (SSE2), whatever the CPU.
pub struct Closure<F>(pub F);

impl<R, F: FnOnce() -> R> WithSimd for Closure<F> {
    type Output = R;
    #[inline(always)]
    fn run(self) -> R {
        (self.0)()
    }
}

/// Runs the closure compiled for the dispatched SIMD level (write it
/// `simd(#[inline(always)] || …)`, see [`Closure`]).
#[inline]
pub fn simd<R>(f: impl FnOnce() -> R) -> R {
    dispatch(Closure(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Dot<'a>(&'a [f32], &'a [f32]);
    impl WithSimd for Dot<'_> {
        type Output = f32;
        #[inline(always)]
        fn run(self) -> f32 {
            self.0.iter().zip(self.1).map(|(a, b)| a * b).sum()
        }
    }

    #[test]
    fn dispatched_equals_baseline() {
        let a: Vec<f32> = (0..1000).map(|i| (i % 7) as f32).collect();
        let b: Vec<f32> = (0..1000).map(|i| (i % 5) as f32).collect();
        assert_eq!(dispatch(Dot(&a, &b)), Dot(&a, &b).run());
    }
}
