//! assist-simd: CPU feature detection, runtime-dispatched SIMD kernels, and the only
//! `unsafe` code of assist.
//!
//! Each kernel has a scalar variant (always compiled, the reference) and variants for
//! AVX2+FMA and AVX-512F, chosen once at start-up from what the CPU reports
//! (`is_x86_feature_detected!`). `ASSIST_SIMD=scalar|avx2|avx512` forces a level (lower
//! than the CPU's only: a level the CPU lacks falls back, loudly). Every variant is tested
//! against the scalar one on random inputs.

pub mod bf16;
pub mod denormals;
pub mod dispatch;
pub mod fixed16;
pub mod gemm;
pub mod grid;
pub mod math;
pub mod peak;
pub mod transpose;

use std::sync::OnceLock;

/// The SIMD level kernels run at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Scalar,
    Avx2,
    Avx512,
}

impl Level {
    pub fn name(&self) -> &'static str {
        match self {
            Level::Scalar => "scalar",
            Level::Avx2 => "avx2+fma",
            Level::Avx512 => "avx512f",
        }
    }
    /// Whether this CPU can run kernels of this level.
    pub fn supported(&self) -> bool {
        match self {
            Level::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => {
                is_x86_feature_detected!("avx2")
                    && is_x86_feature_detected!("fma")
                    && is_x86_feature_detected!("f16c")
                    && is_x86_feature_detected!("bmi1")
                    && is_x86_feature_detected!("bmi2")
                    && is_x86_feature_detected!("popcnt")
            }
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => {
                Level::Avx2.supported()
                    && is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512bw")
                    && is_x86_feature_detected!("avx512dq")
                    && is_x86_feature_detected!("avx512vl")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
    /// Peak single-precision FLOP per cycle per core assumed for this level (two FMA
    /// pipes of 256 bits; AVX-512 on Zen 4 is double-pumped, so the same).
    pub fn flops_per_cycle(&self) -> f64 {
        match self {
            Level::Scalar => 4.0,
            Level::Avx2 | Level::Avx512 => 32.0,
        }
    }
}

/// The best level this CPU supports, or the one forced by `ASSIST_SIMD`. Every kernel
/// asks before it runs, so this is also where a thread starts flushing subnormal floats
/// to zero ([`denormals`]).
pub fn level() -> Level {
    denormals::on_this_thread();
    static L: OnceLock<Level> = OnceLock::new();
    *L.get_or_init(|| {
        let best = [Level::Avx512, Level::Avx2, Level::Scalar].into_iter().find(|l| l.supported()).unwrap_or(Level::Scalar);
        match std::env::var("ASSIST_SIMD").ok().as_deref() {
            None | Some("") | Some("auto") => best,
            Some(s) => {
                let want = match s {
                    "scalar" => Level::Scalar,
                    "avx2" => Level::Avx2,
                    "avx512" => Level::Avx512,
                    other => {
                        eprintln!("assist: ASSIST_SIMD={other} is not scalar, avx2, avx512 or auto; using {}", best.name());
                        return best;
                    }
                };
                if want.supported() {
                    want
                } else {
                    eprintln!("assist: ASSIST_SIMD={s} but this CPU lacks it; using {}", best.name());
                    best
                }
            }
        }
    })
}

/// Whether this CPU's AVX2 gathers are slower than as many scalar loads, so the grids'
/// lookups load each corner's entries one by one: AMD's Zen, Zen+ and Zen 2 (family 17h),
/// whose gathers are microcoded. `ASSIST_GATHER=hw|loads|auto` forces either (for benchmarks).
pub fn slow_gathers() -> bool {
    static S: OnceLock<bool> = OnceLock::new();
    *S.get_or_init(|| match std::env::var("ASSIST_GATHER").ok().as_deref() {
        Some("hw") => false,
        Some("loads") => true,
        None | Some("") | Some("auto") => amd_family() == Some(0x17),
        Some(other) => {
            eprintln!("assist: ASSIST_GATHER={other} is not hw, loads or auto; using auto");
            amd_family() == Some(0x17)
        }
    })
}

/// The CPU's family when it is AMD's (CPUID leaf 1, base plus extended family).
fn amd_family() -> Option<u32> {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::__cpuid;
        let v = __cpuid(0);
        let vendor = [v.ebx, v.edx, v.ecx].map(u32::to_le_bytes).concat();
        if vendor != *b"AuthenticAMD" {
            return None;
        }
        let f = __cpuid(1).eax;
        let base = (f >> 8) & 0xf;
        Some(if base == 0xf {
            base + ((f >> 20) & 0xff)
        } else {
            base
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

/// Whether `level` can be exercised on this machine (for tests that skip loudly).
pub fn available(level: Level) -> bool {
    level.supported()
}

/// Whether rendering's MLP products run below f32 here: bf16 or 16-bit fixed point (see
/// [`products`]).
pub fn reduced_products() -> bool {
    products() != Products::F32
}

/// The arithmetic of rendering's MLP products (training's are always f32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Products {
    /// bf16 pairs with f32 sums ([`bf16`]; AVX-512 BF16).
    Bf16,
    /// 16-bit fixed point with exact integer sums ([`fixed16`]; AVX2).
    Fixed16,
    F32,
}

impl Products {
    pub fn name(&self) -> &'static str {
        match self {
            Products::Bf16 => "bf16",
            Products::Fixed16 => "fixed16",
            Products::F32 => "f32",
        }
    }
}

/// The products rendering takes on this CPU: the fastest measured for its kind
/// (docs/history.md, *Rendering speed*, session 69). bf16 where AVX-512 BF16 is there and
/// the CPU is AMD's (Zen 4 issues `vdpbf16ps` at twice its f32 FMA rate); on other AVX-512
/// CPUs 16-bit fixed point where they have VNNI (an Intel Xeon issues `vpdpwssd` twice a
/// cycle, 64 multiply-adds against its FMA's 32 and its `vdpbf16ps`'s 16), else f32; 16-bit
/// fixed point at the AVX2 level; f32 below it. `ASSIST_PRECISION=f32` gives f32;
/// `ASSIST_PRODUCTS=bf16|fixed16|f32|auto` forces one the dispatched level can run (for
/// benchmarks).
pub fn products() -> Products {
    if let Some(p) = FORCED_PRODUCTS.get() {
        return p;
    }
    static P: OnceLock<Products> = OnceLock::new();
    *P.get_or_init(|| {
        let bf16 = bf16::cpu_has_bf16() && level() == Level::Avx512;
        let fixed = level() >= Level::Avx2;
        let auto = if bf16 && amd_family().is_some() {
            Products::Bf16
        } else if level() == Level::Avx512 {
            if fixed16::vnni() {
                Products::Fixed16
            } else {
                Products::F32
            }
        } else if fixed {
            Products::Fixed16
        } else {
            Products::F32
        };
        if std::env::var("ASSIST_PRECISION").is_ok_and(|v| v == "f32") {
            return Products::F32;
        }
        match std::env::var("ASSIST_PRODUCTS").ok().as_deref() {
            None | Some("") | Some("auto") => auto,
            Some("bf16") if bf16 => Products::Bf16,
            Some("fixed16") if fixed => Products::Fixed16,
            Some("f32") => Products::F32,
            Some(other) => {
                eprintln!(
                    "assist: ASSIST_PRODUCTS={other} is not one of auto, f32{}{} here; using {}",
                    if bf16 { ", bf16" } else { "" },
                    if fixed { ", fixed16" } else { "" },
                    auto.name()
                );
                auto
            }
        }
    })
}

thread_local! {
    static FORCED_PRODUCTS: std::cell::Cell<Option<Products>> = const { std::cell::Cell::new(None) };
}

/// Runs `f` with [`products`] answering `p` on this thread (tests and benchmarks compare
/// the kinds in one process; a kind the CPU lacks runs its scalar reference).
pub fn with_products<R>(p: Products, f: impl FnOnce() -> R) -> R {
    struct Restore(Option<Products>);
    impl Drop for Restore {
        fn drop(&mut self) {
            FORCED_PRODUCTS.set(self.0);
        }
    }
    let _restore = Restore(FORCED_PRODUCTS.replace(Some(p)));
    f()
}

/// The reduced-precision products this CPU runs with its vector kernels at the dispatched
/// level (what [`with_products`] can exercise beside the default).
pub fn reduced_kinds() -> Vec<Products> {
    let mut v = Vec::new();
    if bf16::cpu_has_bf16() && level() == Level::Avx512 {
        v.push(Products::Bf16);
    }
    if level() >= Level::Avx2 {
        v.push(Products::Fixed16);
    }
    v
}

pub use dispatch::{WithSimd, dispatch, simd};

/// Shared helpers of this crate's tests.
#[cfg(test)]
mod test_util {
    /// `(m, n, k)` of the product kernels' tests: full blocks, row remainders, odd and
    /// short k, columns beyond one block, k longer than a block.
    pub const PRODUCT_SHAPES: [(usize, usize, usize); 8] = [
        (64, 64, 64),
        (16, 64, 64),
        (3, 64, 64),
        (64, 64, 31),
        (7, 48, 5),
        (1, 16, 1),
        (64, 128, 32),
        (13, 64, 127),
    ];

    /// `n` values uniform in [−1, 1) from a linear congruential sequence.
    pub fn rand_vec(n: usize, seed: &mut u64) -> Vec<f32> {
        (0..n)
            .map(|_| {
                *seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((*seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }
}
