//! Each shard's completion record (`shards/I-of-N.json`, written last, once every sample
//! the shard owns holds): the run that made it (the spec's hash, the format, assist's
//! version) and each of its samples' manifests by size and hash — the manifests list every
//! file with its size and hash. [`status`] reads the records and the samples to say which
//! shards are complete, partial, missing or another run's; a rerun of a complete shard
//! does nothing; `merge` refuses a run whose shards do not all hold, naming them.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::{Value, json};

use crate::integrity::{self, MANIFEST};
use crate::merge::sample_dir;
use crate::sample::io;
use crate::{GenError, Result, Shard, Spec};

/// The records' folder inside a run's output.
pub const SHARDS: &str = "shards";

/// Where shard `s`'s completion record goes: `shards/3-of-8.json` (the index padded to
/// the count's width, so the records sort in order).
pub fn record_path(out: &Path, s: Shard) -> PathBuf {
    let w = s.count.to_string().len();
    out.join(SHARDS)
        .join(format!("{:0w$}-of-{}.json", s.index, s.count))
}

/// The shard a record's file name names.
fn parse_record_name(name: &str) -> Option<Shard> {
    let stem = name.strip_suffix(".json")?;
    let (i, n) = stem.split_once("-of-")?;
    Shard::parse(&format!(
        "{}/{}",
        i.parse::<u64>().ok()?,
        n.parse::<u64>().ok()?
    ))
    .ok()
}

/// Writes shard `s`'s completion record; every sample it owns must hold already.
pub fn write_record(out: &Path, s: Shard, count: u64, run: &Value) -> Result<()> {
    let mut samples = Vec::new();
    for i in (0..count).filter(|&i| s.owns(i)) {
        let mp = sample_dir(out, i).join(MANIFEST);
        let bytes = std::fs::read(&mp).map_err(|e| io(&mp, e))?;
        let files = serde_json::from_slice::<Value>(&bytes)
            .ok()
            .and_then(|m| m["files"].as_array().map(|f| f.len()))
            .unwrap_or(0);
        samples.push(json!({
            "index": i,
            "manifest": {"size": bytes.len(), "hash": integrity::hash_hex(&bytes)},
            "files": files,
        }));
    }
    let dir = out.join(SHARDS);
    std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
    let record = json!({
        "run": run,
        "shard": format!("{}/{}", s.index, s.count),
        "samples": samples,
    });
    assist_data::image_io::write_atomic(&record_path(out, s), &crate::sample::pretty(&record))?;
    Ok(())
}

/// Why shard `s`'s record does not hold for `run`, if it does not: absent, another run's,
/// or a sample's manifest gone or changed.
fn check_record(
    out: &Path,
    s: Shard,
    run: &Value,
    hashes: bool,
) -> std::result::Result<(), Problem> {
    let p = record_path(out, s);
    let Ok(text) = std::fs::read_to_string(&p) else {
        return Err(Problem::NoRecord);
    };
    let r: Value = serde_json::from_str(&text)
        .map_err(|e| Problem::Damaged(format!("{} is not valid JSON: {e}", rel(out, &p))))?;
    if r["run"] != *run {
        return Err(Problem::Foreign(format!(
            "{} records another run ({}; this run is {run}): another spec, seed or assist version",
            rel(out, &p),
            r["run"]
        )));
    }
    for e in r["samples"].as_array().into_iter().flatten() {
        let i = e["index"].as_u64().unwrap_or(u64::MAX);
        let mp = sample_dir(out, i).join(MANIFEST);
        let Ok(meta) = std::fs::metadata(&mp) else {
            return Err(Problem::Damaged(format!("sample {i:06} is gone")));
        };
        let changed = Some(meta.len()) != e["manifest"]["size"].as_u64()
            || (hashes
                && std::fs::read(&mp)
                    .map(|b| {
                        Some(integrity::hash_hex(&b).as_str()) != e["manifest"]["hash"].as_str()
                    })
                    .unwrap_or(true));
        if changed {
            return Err(Problem::Damaged(format!(
                "sample {i:06}'s {MANIFEST} changed since the shard finished"
            )));
        }
    }
    Ok(())
}

enum Problem {
    NoRecord,
    Foreign(String),
    Damaged(String),
}

fn rel(out: &Path, p: &Path) -> String {
    p.strip_prefix(out).unwrap_or(p).display().to_string()
}

/// One shard's state.
#[derive(Debug, Clone, Serialize)]
pub struct ShardState {
    /// `i/n`.
    pub shard: String,
    pub index: u64,
    /// complete, partial, missing or foreign (another run's).
    pub state: &'static str,
    /// Its samples that hold, of those it owns.
    pub done: u64,
    pub owned: u64,
    /// Its samples that are there but do not hold (a file missing, truncated or changed).
    pub damaged: u64,
    /// Why it is not complete (first few reasons).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub problems: Vec<String>,
}

/// Which shards of a run hold.
#[derive(Debug, Clone, Serialize)]
pub struct Status {
    pub out: PathBuf,
    /// Samples in the run, and how many hold.
    pub count: u64,
    pub samples_done: u64,
    /// The `n` of `--shard i/n` the shards are listed for.
    pub shards: u64,
    /// Where `shards` came from: given, the records, or a whole run (no records).
    pub shards_from: &'static str,
    pub complete: Vec<u64>,
    pub partial: Vec<u64>,
    pub missing: Vec<u64>,
    pub foreign: Vec<u64>,
    /// Every shard that is not complete, with its reasons.
    pub incomplete: Vec<ShardState>,
    /// Whether every shard is complete (then `merge` has what it needs).
    pub all_complete: bool,
    #[serde(skip)]
    pub(crate) sample_ok: Vec<bool>,
}

impl Status {
    /// Shards to run again: those not complete, as `i,j,…` (Slurm's `--array=` form).
    pub fn to_rerun(&self) -> String {
        let mut v: Vec<u64> = self
            .partial
            .iter()
            .chain(&self.missing)
            .chain(&self.foreign)
            .copied()
            .collect();
        v.sort_unstable();
        v.iter()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// Reads `out/generate.json`: the run's manifest.
pub(crate) fn read_manifest(out: &Path) -> Result<Value> {
    let file = out.join("generate.json");
    if !file.is_file() {
        return Err(GenError::Folder {
            path: out.into(),
            message: "has no generate.json: not a folder `assist generate` wrote".into(),
        });
    }
    serde_json::from_str(&assist_fs::read_text(&file)?).map_err(|e| GenError::Folder {
        path: file,
        message: format!("not valid JSON: {e}"),
    })
}

/// The `n` the records in `out/shards` name, if they agree on one.
fn shards_of_records(out: &Path) -> Result<Option<u64>> {
    let mut ns: Vec<u64> = std::fs::read_dir(out.join(SHARDS))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| parse_record_name(&e.file_name().to_string_lossy()))
        .map(|s| s.count)
        .collect();
    ns.sort_unstable();
    ns.dedup();
    match ns.as_slice() {
        [] => Ok(None),
        [n] => Ok(Some(*n)),
        _ => Err(GenError::Folder {
            path: out.join(SHARDS),
            message: format!(
                "holds records of runs split {} ways; give --shards N to say which split to list",
                ns.iter()
                    .map(|n| n.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}

/// Which of the run's shards in `out` are complete, partial, missing or another run's,
/// for `--shard i/n` with `n` = `shards` (default: the records' `n`, else one shard);
/// `hashes` checks every file's content, not only its size.
pub fn status(out: &Path, shards: Option<u64>, hashes: bool) -> Result<Status> {
    let manifest = read_manifest(out)?;
    let count = manifest["spec"]["count"].as_u64().unwrap_or(0);
    let run = integrity::run_identity(&manifest);
    let (n, from) = match shards {
        Some(0) => {
            return Err(GenError::Folder {
                path: out.into(),
                message: "--shards: expected at least 1".into(),
            });
        }
        Some(n) => (n, "given"),
        None => match shards_of_records(out)? {
            Some(n) => (n, "records"),
            None => (1, "whole run"),
        },
    };
    // Each sample once: absent, holds, or why not.
    let mut sample_ok = vec![false; count as usize];
    let mut present = vec![false; count as usize];
    let mut why: Vec<(u64, String)> = Vec::new();
    let mut foreign_sample = vec![false; count as usize];
    for i in 0..count {
        let d = sample_dir(out, i);
        if !d.join(assist_fs::MARKER).is_file() {
            continue;
        }
        present[i as usize] = true;
        match integrity::check(&d, &run, hashes) {
            Ok(()) => sample_ok[i as usize] = true,
            Err(w) => {
                foreign_sample[i as usize] = w.contains("another run");
                why.push((i, w));
            }
        }
    }
    let mut st = Status {
        out: out.into(),
        count,
        samples_done: sample_ok.iter().filter(|&&b| b).count() as u64,
        shards: n,
        shards_from: from,
        complete: Vec::new(),
        partial: Vec::new(),
        missing: Vec::new(),
        foreign: Vec::new(),
        incomplete: Vec::new(),
        all_complete: false,
        sample_ok: Vec::new(),
    };
    for k in 0..n {
        let s = Shard { index: k, count: n };
        let owned: Vec<u64> = (k..count).step_by(n as usize).collect();
        let done = owned.iter().filter(|&&i| sample_ok[i as usize]).count() as u64;
        let made = owned.iter().filter(|&&i| present[i as usize]).count();
        let record = check_record(out, s, &run, hashes);
        let foreign = owned.iter().any(|&i| foreign_sample[i as usize])
            || matches!(record, Err(Problem::Foreign(_)));
        let state = if foreign {
            "foreign"
        } else if record.is_ok() && done == owned.len() as u64 {
            "complete"
        } else if made == 0 && matches!(record, Err(Problem::NoRecord)) {
            "missing"
        } else {
            "partial"
        };
        match state {
            "complete" => st.complete.push(k),
            "missing" => st.missing.push(k),
            "foreign" => st.foreign.push(k),
            _ => st.partial.push(k),
        }
        if state == "complete" {
            continue;
        }
        let mut problems = Vec::new();
        if state == "missing" {
            problems.push(format!("none of its {} samples made", owned.len()));
        } else {
            match &record {
                Ok(()) => {}
                Err(Problem::NoRecord) => problems.push(format!(
                    "no completion record {} (still running, or stopped before its end)",
                    rel(out, &record_path(out, s))
                )),
                Err(Problem::Foreign(m) | Problem::Damaged(m)) => problems.push(m.clone()),
            }
            if made < owned.len() {
                problems.push(format!(
                    "{} of its {} samples not made",
                    owned.len() - made,
                    owned.len()
                ));
            }
            for (i, w) in why.iter().filter(|(i, _)| s.owns(*i)).take(3) {
                problems.push(format!("sample {i:06} {w}"));
            }
        }
        st.incomplete.push(ShardState {
            shard: format!("{k}/{n}"),
            index: k,
            state,
            done,
            owned: owned.len() as u64,
            damaged: owned
                .iter()
                .filter(|&&i| present[i as usize] && !sample_ok[i as usize])
                .count() as u64,
            problems,
        });
    }
    st.all_complete = st.complete.len() as u64 == n;
    st.sample_ok = sample_ok;
    Ok(st)
}

/// Whether shard `s` of the run `spec` describes is complete in `out` (its record holds
/// and every sample it owns holds at its size): a rerun then has nothing to do, and need
/// not load a scene to find out.
pub fn is_complete(out: &Path, spec: &Spec, s: Shard) -> bool {
    let Ok(manifest) = read_manifest(out) else {
        return false;
    };
    let Ok(spec_value) = serde_json::to_value(spec) else {
        return false;
    };
    if manifest["spec"] != spec_value {
        return false;
    }
    let run = integrity::run_identity(&manifest);
    check_record(out, s, &run, false).is_ok()
        && (0..spec.count)
            .filter(|&i| s.owns(i))
            .all(|i| integrity::check(&sample_dir(out, i), &run, false).is_ok())
}

/// A rerun of shard `s` that finds it complete: nothing to make (a whole run's merge is
/// written if it is not there yet).
#[derive(Debug, Clone)]
pub struct CompleteRerun {
    /// The samples the shard owns.
    pub owned: u64,
    pub merged: Option<crate::MergeSummary>,
}

/// What a rerun of shard `s` does when it is complete ([`is_complete`]); `None` when it
/// has work to do. The CLI and Python share it.
pub fn rerun_if_complete(
    out: &Path,
    spec: &Spec,
    s: Shard,
    masks: crate::CocoMasks,
) -> Result<Option<CompleteRerun>> {
    if !is_complete(out, spec, s) {
        return Ok(None);
    }
    let merged = if s.count == 1 && !out.join("index.json").is_file() {
        Some(crate::merge(out, false, masks)?)
    } else {
        None
    };
    Ok(Some(CompleteRerun {
        owned: (0..spec.count).filter(|&i| s.owns(i)).count() as u64,
        merged,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_names_round_trip_and_sort_in_shard_order() {
        let out = Path::new("/run");
        let mut names = Vec::new();
        for i in [0, 7, 9, 10, 99, 100, 999] {
            let s = Shard {
                index: i,
                count: 1000,
            };
            let p = record_path(out, s);
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            assert_eq!(parse_record_name(&name), Some(s), "{name}");
            names.push(name);
        }
        let mut sorted = names.clone();
        sorted.sort();
        assert_eq!(sorted, names, "padded indices sort as numbers");
        assert_eq!(names[1], "0007-of-1000.json");
        for bad in [
            "3-of-2.json",
            "x-of-4.json",
            "3-of-4.txt",
            "3of4.json",
            "-1-of-4.json",
        ] {
            assert_eq!(parse_record_name(bad), None, "{bad}");
        }
    }
}
