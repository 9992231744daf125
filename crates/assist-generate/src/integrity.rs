//! Each sample's completion manifest (`manifest.json`, written last before the folder is
//! swapped in): which run made it (a hash of the spec, the format and assist's version)
//! and every file with its size and hash. A rerun remakes a sample whose manifest does not
//! hold; `merge` refuses one, naming the sample and the file, rather than indexing
//! images that are gone, empty or from another run.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::{GenError, Result};

/// The manifest's file name inside a sample's folder.
pub const MANIFEST: &str = "manifest.json";

/// FNV-1a, 64 bits: stable across builds and platforms.
fn fnv(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// A file's content hash as written in the manifests.
pub fn hash_hex(bytes: &[u8]) -> String {
    format!("{:016x}", fnv(bytes))
}

/// What identifies a run, from its `generate.json`: the spec (seed included) by hash, the
/// folder format and the assist version that made it.
pub fn run_identity(manifest: &Value) -> Value {
    json!({
        "spec": format!("{:016x}", fnv(manifest["spec"].to_string().as_bytes())),
        "format": manifest["version"],
        "assist": env!("CARGO_PKG_VERSION"),
    })
}

/// Every file under `dir` but the manifest and the marker, as paths relative to it, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(rel) = p.strip_prefix(dir)
                && rel != Path::new(MANIFEST)
                && rel != Path::new(assist_fs::MARKER)
            {
                out.push(rel.to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// Writes `dir/manifest.json` for the files now in `dir`.
pub fn write_manifest(dir: &Path, run: &Value) -> Result<()> {
    let mut list = Vec::new();
    for rel in files(dir) {
        let p = dir.join(&rel);
        let bytes = std::fs::read(&p).map_err(|e| crate::sample::io(&p, e))?;
        list.push(json!({
            "path": rel.to_string_lossy().replace('\\', "/"),
            "size": bytes.len(),
            "hash": hash_hex(&bytes),
        }));
    }
    let m = json!({"run": run, "files": list});
    crate::sample::write(&dir.join(MANIFEST), &crate::sample::pretty(&m))
}

/// Why the sample in `dir` does not hold as `run` made it, if it does not: another run's,
/// no manifest, or a file missing, of another size or (with `hashes`) other content.
pub fn check(dir: &Path, run: &Value, hashes: bool) -> std::result::Result<(), String> {
    let mp = dir.join(MANIFEST);
    let text = std::fs::read_to_string(&mp)
        .map_err(|_| format!("has no {MANIFEST} (made by an older assist, or not finished)"))?;
    let m: Value =
        serde_json::from_str(&text).map_err(|e| format!("{MANIFEST} is not valid JSON: {e}"))?;
    if m["run"] != *run {
        return Err(format!(
            "was made by another run (its {MANIFEST} records {}; this run is {run}): another spec, seed or assist version",
            m["run"]
        ));
    }
    for f in m["files"].as_array().into_iter().flatten() {
        let rel = f["path"].as_str().unwrap_or("");
        let p = dir.join(rel);
        let Ok(meta) = std::fs::metadata(&p) else {
            return Err(format!("{rel} is missing"));
        };
        if Some(meta.len()) != f["size"].as_u64() {
            return Err(format!(
                "{rel} has {} bytes, {} when it was made",
                meta.len(),
                f["size"]
            ));
        }
        if hashes {
            let bytes = std::fs::read(&p).map_err(|e| format!("{rel}: {e}"))?;
            if Some(hash_hex(&bytes).as_str()) != f["hash"].as_str() {
                return Err(format!("{rel} was changed since it was made"));
            }
        }
    }
    Ok(())
}

/// Removes the temporaries a killed writer left in `dir` (`.NAME.tmp-PID` of a process
/// that is gone).
pub fn clean_stale(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .starts_with('.')
            .then(|| name.rsplit_once(".tmp-"))
            .flatten()
            .and_then(|(_, pid)| pid.parse::<u32>().ok())
        else {
            continue;
        };
        let alive = pid == std::process::id()
            || (Path::new("/proc").is_dir() && Path::new(&format!("/proc/{pid}")).exists())
            || !Path::new("/proc").is_dir();
        if !alive {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// A sample that does not hold, as the merge's error.
pub fn damaged(out: &Path, index: u64, why: String) -> GenError {
    GenError::Folder {
        path: out.into(),
        message: format!(
            "sample {index:06} {why}; run `assist generate` again with the same spec to remake it"
        ),
    }
}
