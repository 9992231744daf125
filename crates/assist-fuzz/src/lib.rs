//! In-process fuzzing of every parser of untrusted input, on the stable toolchain.
//!
//! Each [`Target`] is one parser fed through its public entry point (a dataset folder, a
//! scene file, a field's bytes, an instruction, a viewer message). Inputs are real files
//! (from `../shared/data` where present, else small built-in seeds) put through stacked
//! structure-aware mutations: byte flips, JSON/number-aware token insertions (`NaN`,
//! `1e308`, `18446744073709551616`, …), deletions, duplications, splices, truncations.
//!
//! Per input: a panic is caught and counted (with the input saved); a watchdog aborts the
//! process if one input takes longer than the time limit (the input is saved first); the
//! allocator records the largest single allocation and aborts on any above
//! [`ALLOCATION_LIMIT`], so no parser may size a buffer from a header before checking it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

pub mod targets;

/// Largest single allocation any parser may make for one input (1 GiB).
pub const ALLOCATION_LIMIT: usize = 1 << 30;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

/// The allocator of the fuzzing binaries: the system's, recording the largest request and
/// refusing (by aborting with a message) any above [`ALLOCATION_LIMIT`].
pub struct Guarded;

unsafe impl GlobalAlloc for Guarded {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn check(size: usize) {
    LARGEST.fetch_max(size, Ordering::Relaxed);
    if size > ALLOCATION_LIMIT {
        use std::io::Write;
        // No allocation here: a fixed message, then abort (the input is on disk).
        let _ = std::io::stderr()
            .write_all(b"assist-fuzz: an allocation above the limit (1 GiB); input saved\n");
        std::process::abort();
    }
}

#[global_allocator]
static ALLOC: Guarded = Guarded;

/// Where inputs are written (the dataset readers take folders): a memory file system
/// where there is one, else the temporary folder; one folder per process.
pub fn scratch_base() -> PathBuf {
    let shm = Path::new("/dev/shm");
    let base = if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    base.join(format!("assist-fuzz-{}", std::process::id()))
}

/// A small deterministic generator.
#[derive(Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        // xorshift64*
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }
}

const TOKENS: &[&[u8]] = &[
    b"NaN",
    b"Infinity",
    b"-Infinity",
    b"-1",
    b"0",
    b"1",
    b"1e308",
    b"-1e308",
    b"1e-320",
    b"4294967295",
    b"4294967296",
    b"18446744073709551615",
    b"18446744073709551616",
    b"65536",
    b"2147483648",
    b"null",
    b"true",
    b"[]",
    b"{}",
    b"\"\"",
    b"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[",
    b"\"\\u0000\"",
    b"\xff\xfe",
    b"../../",
    b"3.14159",
];

const BYTES: &[u8] = b"{}[]\":,-0123456789e.\\ \n\x00\xff";

/// One to four stacked mutations of `input`; `others` are splice partners.
pub fn mutate(rng: &mut Rng, input: &[u8], others: &[Vec<u8>]) -> Vec<u8> {
    let mut v = input.to_vec();
    let n = 1 + rng.below(4);
    for _ in 0..n {
        let len = v.len();
        match rng.below(9) {
            0 if len > 0 => {
                let i = rng.below(len);
                v[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                v[i] = BYTES[rng.below(BYTES.len())];
            }
            2 if len > 0 => {
                let i = rng.below(len);
                let k = (1 + rng.below(16)).min(len - i);
                v.drain(i..i + k);
            }
            3 if len > 0 => {
                let i = rng.below(len);
                let k = (1 + rng.below(64)).min(len - i);
                let chunk = v[i..i + k].to_vec();
                let at = rng.below(len + 1);
                v.splice(at..at, chunk);
            }
            4 => {
                let t = TOKENS[rng.below(TOKENS.len())];
                let at = rng.below(len + 1);
                v.splice(at..at, t.iter().copied());
            }
            5 if len > 0 => {
                // Replace a number (a run of digits, signs, dots, exponents) by a token.
                let i = rng.below(len);
                if let Some(s) = (i..len).find(|&j| v[j].is_ascii_digit()) {
                    let e = (s..len)
                        .find(|&j| !(v[j].is_ascii_digit() || b".eE+-".contains(&v[j])))
                        .unwrap_or(len);
                    let t = TOKENS[rng.below(15)];
                    v.splice(s..e, t.iter().copied());
                }
            }
            6 if !others.is_empty() && len > 0 => {
                let o = &others[rng.below(others.len())];
                let cut = rng.below(len);
                let from = rng.below(o.len() + 1);
                v.truncate(cut);
                v.extend_from_slice(&o[from..]);
            }
            7 if len > 0 => {
                v.truncate(rng.below(len));
            }
            8 if len >= 4 => {
                // A little-endian length field set to something huge (binary formats).
                let i = rng.below(len - 3);
                let big = [0xffu8, 0xff, 0xff, 0x7f];
                v[i..i + 4].copy_from_slice(&big[..]);
            }
            _ => {}
        }
    }
    v
}

/// Parses one input (given a scratch folder for parsers that read files).
pub type Parse = Box<dyn Fn(&[u8], &Path)>;

/// A parser under test.
pub struct Target {
    pub name: &'static str,
    pub seeds: Vec<Vec<u8>>,
    /// Parses one input; any `Ok`/`Err` is fine, a panic is not. Gets a scratch folder.
    pub run: Parse,
}

/// What a fuzzing run found.
#[derive(Debug, Clone, Default)]
pub struct Report {
    pub target: String,
    pub executions: u64,
    pub panics: u64,
    pub first_panic: Option<(PathBuf, String)>,
    pub slowest: Duration,
    pub largest_allocation: usize,
    pub seconds: f64,
}

/// Runs `target` on `runs` mutated inputs. Saved inputs go to `out`; an input running past
/// `limit` aborts the process (after saving it as `out/TARGET-hang.bin`).
pub fn fuzz(target: &Target, runs: u64, seed: u64, limit: Duration, out: &Path) -> Report {
    // One run at a time per process: the watchdog, the panic hook and the allocation
    // record are process-wide.
    static ONE: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one = ONE.lock().unwrap_or_else(|e| e.into_inner());
    std::fs::create_dir_all(out).expect("fuzz output folder");
    let scratch = out.join(format!("scratch-{}", target.name));
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir_all(&scratch).expect("scratch folder");
    let current = out.join(format!("{}-current.bin", target.name));
    // The watchdog: aborts when one input runs past the limit.
    static STARTED_NS: AtomicU64 = AtomicU64::new(0);
    static BUSY: AtomicBool = AtomicBool::new(false);
    static DONE: AtomicBool = AtomicBool::new(false);
    let epoch = Instant::now();
    DONE.store(false, Ordering::SeqCst);
    let hang_path = out.join(format!("{}-hang.bin", target.name));
    let cur = current.clone();
    let watchdog = std::thread::spawn(move || {
        while !DONE.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(50));
            if BUSY.load(Ordering::SeqCst) {
                let t = Duration::from_nanos(STARTED_NS.load(Ordering::SeqCst));
                if epoch.elapsed().saturating_sub(t) > limit {
                    let _ = std::fs::copy(&cur, &hang_path);
                    eprintln!(
                        "assist-fuzz: an input ran past {limit:?}; saved as {}",
                        hang_path.display()
                    );
                    std::process::abort();
                }
            }
        }
    });
    let prev_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = Rng::new(seed);
    let mut rep = Report {
        target: target.name.to_string(),
        ..Default::default()
    };
    let t0 = Instant::now();
    for i in 0..runs {
        let base = &target.seeds[rng.below(target.seeds.len())];
        // Every so often an unmutated seed, so the deep paths stay exercised.
        let input = if i % 64 == 0 {
            base.clone()
        } else {
            mutate(&mut rng, base, &target.seeds)
        };
        let _ = std::fs::write(&current, &input);
        LARGEST.store(0, Ordering::Relaxed);
        STARTED_NS.store(epoch.elapsed().as_nanos() as u64, Ordering::SeqCst);
        BUSY.store(true, Ordering::SeqCst);
        let t = Instant::now();
        let res = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            (target.run)(&input, &scratch)
        }));
        let dt = t.elapsed();
        BUSY.store(false, Ordering::SeqCst);
        rep.executions += 1;
        rep.slowest = rep.slowest.max(dt);
        rep.largest_allocation = rep.largest_allocation.max(LARGEST.load(Ordering::Relaxed));
        if let Err(p) = res {
            rep.panics += 1;
            if rep.first_panic.is_none() {
                let path = out.join(format!("{}-panic-{i}.bin", target.name));
                let _ = std::fs::write(&path, &input);
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                rep.first_panic = Some((path, msg));
            }
        }
    }
    rep.seconds = t0.elapsed().as_secs_f64();
    std::panic::set_hook(prev_hook);
    DONE.store(true, Ordering::SeqCst);
    let _ = watchdog.join();
    let _ = std::fs::remove_dir_all(&scratch);
    let _ = std::fs::remove_file(&current);
    rep
}
