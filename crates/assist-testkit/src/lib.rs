//! assist-testkit: helpers for tests only (never a runtime dependency).
//!
//! Finding the shared datasets (`ASSIST_DATA` or `../shared/data` beside the project),
//! skipping loudly when they are absent, temporary directories that clean up, and
//! tolerance statistics; with the `scenes` feature, hand-built scenes of constant fields.

#![forbid(unsafe_code)]

#[cfg(feature = "scenes")]
pub mod scenes;

use std::path::{Path, PathBuf};

/// The shared data folder, if present: `$ASSIST_DATA`, else `../shared/data` beside the
/// workspace root. When absent, prints a loud SKIP line and returns `None`; under CI
/// (`ASSIST_REQUIRE_DATA=1`) absence is a test failure instead.
pub fn shared_data(test: &str) -> Option<PathBuf> {
    let candidates: Vec<PathBuf> = match std::env::var_os("ASSIST_DATA") {
        Some(p) => vec![PathBuf::from(p)],
        None => vec![workspace_root().join("../shared/data")],
    };
    for c in &candidates {
        if c.join("README.md").is_file() || c.is_dir() {
            return Some(c.clone());
        }
    }
    if std::env::var_os("ASSIST_REQUIRE_DATA").is_some_and(|v| v == "1") {
        panic!("{test}: shared data not found at {candidates:?} and ASSIST_REQUIRE_DATA=1");
    }
    eprintln!(
        "\n!!! SKIP {test}: shared data not found (looked at {candidates:?}); set ASSIST_DATA to run it\n"
    );
    None
}

/// A named dataset inside the shared data folder, or `None` (loudly) when absent.
pub fn shared_dataset(test: &str, name: &str) -> Option<PathBuf> {
    let d = shared_data(test)?.join(name);
    if d.exists() {
        Some(d)
    } else if std::env::var_os("ASSIST_REQUIRE_DATA").is_some_and(|v| v == "1") {
        panic!(
            "{test}: shared dataset {} missing and ASSIST_REQUIRE_DATA=1",
            d.display()
        );
    } else {
        eprintln!("\n!!! SKIP {test}: {} not found\n", d.display());
        None
    }
}

/// The workspace root (two levels above a crate's manifest).
pub fn workspace_root() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent()
        .and_then(Path::parent)
        .unwrap_or(here)
        .to_path_buf()
}

/// A folder made once and shared by the test processes that ask for it by `key` (nextest
/// runs every test as its own process, and several train the same scene): the first to
/// ask makes it with `make` while the others wait on a lock, and later ones reuse it. It
/// lives beside `made_by` (the binary that makes it) and is made anew when that binary
/// or `recipe` (what `make` does, in words or its command lines) changes. Treat it as
/// read-only: copy what a test changes ([`copy_dir`]).
pub fn shared_fixture(
    key: &str,
    made_by: &Path,
    recipe: &str,
    make: impl FnOnce(&Path),
) -> PathBuf {
    use std::hash::{Hash, Hasher};
    let meta = std::fs::metadata(made_by)
        .unwrap_or_else(|e| panic!("fixture {key}: {}: {e}", made_by.display()));
    let mut stamp = std::collections::hash_map::DefaultHasher::new();
    meta.modified().ok().hash(&mut stamp);
    meta.len().hash(&mut stamp);
    recipe.hash(&mut stamp);
    let stamp = stamp.finish();
    let root = made_by
        .parent()
        .unwrap_or(Path::new("."))
        .join("test-fixtures");
    std::fs::create_dir_all(&root).expect("create the fixtures folder");
    let lock = std::fs::File::create(root.join(format!("{key}.lock"))).expect("fixture lock");
    lock.lock().expect("lock the fixture");
    let dir = root.join(format!("{key}-{stamp:016x}"));
    if dir.join(".made").is_file() {
        return dir;
    }
    // Made by another build of the binary, or left half made by a test that failed.
    if let Ok(entries) = std::fs::read_dir(&root) {
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            let stamped = name.strip_prefix(key).and_then(|r| r.strip_prefix('-'));
            let ours = stamped.is_some_and(|r| r.len() == 16 && u64::from_str_radix(r, 16).is_ok());
            if ours && e.path().is_dir() {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
    std::fs::create_dir_all(&dir).expect("create the fixture");
    make(&dir);
    std::fs::write(dir.join(".made"), b"").expect("mark the fixture made");
    dir
}

/// Copies the folder `from` (files and folders, recursively) to `to`, which must not exist.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir(to).unwrap_or_else(|e| panic!("create {}: {e}", to.display()));
    for e in std::fs::read_dir(from).unwrap_or_else(|e| panic!("{}: {e}", from.display())) {
        let e = e.expect("read a folder entry");
        let target = to.join(e.file_name());
        if e.file_type().expect("file type").is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target)
                .unwrap_or_else(|err| panic!("copy {}: {err}", e.path().display()));
        }
    }
}

/// A temporary directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> Self {
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        let p = std::env::temp_dir().join(format!(
            "assist-test-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("create temp dir");
        static SWEPT: std::sync::Once = std::sync::Once::new();
        SWEPT.call_once(sweep_stale);
        TempDir(p)
    }
    pub fn path(&self) -> &Path {
        &self.0
    }
    pub fn join(&self, p: impl AsRef<Path>) -> PathBuf {
        self.0.join(p)
    }
}

/// Removes the temporary directories of test processes that have ended. A directory held
/// in a `static` is never dropped, and nextest runs every test as its own process, so each
/// run would otherwise leave one per process behind. Linux only (liveness from `/proc`).
fn sweep_stale() {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix("assist-test-")) else {
            continue;
        };
        // assist-test-{tag}-{pid}-{n}: the pid is the second field from the end.
        let mut fields = rest.rsplit('-');
        let (Some(_n), Some(pid)) = (fields.next(), fields.next()) else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else {
            continue;
        };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// PSNR between two 8-bit images of the same size and layout (∞ when equal).
pub fn psnr_u8(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "images of one size");
    let se: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| ((x as f64 - y as f64) / 255.0).powi(2))
        .sum();
    let mse = se / a.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// Median of a list (NaN-free); panics on an empty list.
pub fn median(v: &mut [f64]) -> f64 {
    assert!(!v.is_empty(), "median of nothing");
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Made once for a binary and recipe, reused after; a new recipe or a rebuilt binary
    /// makes it anew and removes the old one; a half-made one is made again.
    #[test]
    fn a_shared_fixture_is_made_once_per_binary_and_recipe() {
        let tmp = TempDir::new("fixture");
        let bin = tmp.join("bin");
        std::fs::write(&bin, b"one").unwrap();
        let made = std::cell::Cell::new(0);
        let make = |d: &Path| {
            made.set(made.get() + 1);
            std::fs::write(d.join("x"), b"made").unwrap();
        };
        let a = shared_fixture("k", &bin, "r1", make);
        assert_eq!(shared_fixture("k", &bin, "r1", make), a);
        assert_eq!(made.get(), 1);
        assert_eq!(std::fs::read(a.join("x")).unwrap(), b"made");
        let b = shared_fixture("k", &bin, "r2", make);
        assert_ne!(a, b);
        assert!(!a.exists(), "the other recipe's fixture is removed");
        std::fs::write(&bin, b"rebuilt").unwrap();
        let c = shared_fixture("k", &bin, "r2", make);
        assert_ne!(b, c);
        assert_eq!(made.get(), 3);
        // Another key is left alone; a fixture without its mark is made again.
        let other = shared_fixture("k-other", &bin, "r2", make);
        std::fs::remove_file(c.join(".made")).unwrap();
        assert_eq!(shared_fixture("k", &bin, "r2", make), c);
        assert_eq!(made.get(), 5);
        assert!(other.join(".made").is_file());
    }
}
