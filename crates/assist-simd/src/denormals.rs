//! Subnormal floats flushed to zero on the threads that run assist's kernels.
//!
//! Late in a fit the gradients through the nets shrink until products of them fall below
//! f32's normal range (1.2e-38); x86 then takes a microcode assist on every such
//! operation, tens of times slower than the plain one: a split's distillation spent most
//! of its time there (docs/history.md, "subnormal floats"). Nothing assist
//! computes needs values below 1e-38 (Adam already drops moments under 1e-30), so each
//! thread sets the CPU's flush-to-zero and denormals-are-zero modes before its first
//! kernel ([`level`](crate::level) calls [`on_this_thread`]); the `assist` binary also
//! sets them on every thread of its pool as the thread starts.
//!
//! x86-64 only (MXCSR); elsewhere a no-op (arithmetic stays IEEE, only slower there).

use std::cell::Cell;

thread_local! {
    static FLUSHING: Cell<bool> = const { Cell::new(false) };
}

/// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6) modes.
#[cfg(target_arch = "x86_64")]
const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);

/// Sets flush-to-zero and denormals-are-zero on the calling thread, once per thread (a
/// thread-local flag read after that).
#[inline]
pub fn on_this_thread() {
    if !FLUSHING.with(Cell::get) {
        set();
        FLUSHING.with(|f| f.set(true));
    }
}

/// Whether the calling thread flushes subnormals to zero (the CPU's mode, read back).
pub fn flushing() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        read_csr() & FTZ_DAZ == FTZ_DAZ
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
fn read_csr() -> u32 {
    let mut csr = 0u32;
    // SAFETY: STMXCSR stores the 32-bit control register to the given address, a local
    // of that size; SSE is part of x86-64's baseline.
    unsafe {
        std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack, preserves_flags));
    }
    csr
}

fn set() {
    #[cfg(target_arch = "x86_64")]
    {
        let csr = read_csr() | FTZ_DAZ;
        // SAFETY: LDMXCSR loads the control register from a local; only the two mode bits
        // change (exception masks and rounding stay as they were).
        unsafe {
            std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, preserves_flags));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Before: a product below f32's normal range stays a subnormal. After: it is 0, a
    /// subnormal input counts as 0, and normal arithmetic is untouched. Run on a thread of
    /// its own, so the test harness's thread keeps its mode.
    #[test]
    fn subnormals_flush_to_zero_after_and_not_before() {
        std::thread::spawn(|| {
            let tiny = std::hint::black_box(1e-20f32);
            let sub = std::hint::black_box(f32::from_bits(1));
            let before = std::hint::black_box(tiny * tiny);
            #[cfg(target_arch = "x86_64")]
            {
                assert!(!flushing());
                assert!(before > 0.0 && before.is_subnormal(), "{before:e}");
            }
            on_this_thread();
            let after = std::hint::black_box(tiny) * std::hint::black_box(tiny);
            let read = std::hint::black_box(sub) * std::hint::black_box(2.0f32);
            let normal = std::hint::black_box(1.5f32) * std::hint::black_box(1e-30f32);
            #[cfg(target_arch = "x86_64")]
            {
                assert!(flushing());
                assert_eq!(after, 0.0);
                assert_eq!(read, 0.0);
            }
            assert_eq!(normal, 1.5e-30);
            on_this_thread();
        })
        .join()
        .unwrap();
    }

    /// The kernels' level check sets the mode on a thread that had not.
    #[test]
    fn asking_the_level_sets_the_mode() {
        std::thread::spawn(|| {
            crate::level();
            #[cfg(target_arch = "x86_64")]
            assert!(flushing());
        })
        .join()
        .unwrap();
    }
}
