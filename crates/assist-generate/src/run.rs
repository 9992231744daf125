//! Running a generator into a folder: any shard of it, resumable, each sample staged and
//! committed whole; an unsharded run then merges the samples' annotations.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use serde_json::Value;

use crate::coco::CocoMasks;
use crate::integrity;
use crate::merge::{GENERATED, merge};
use crate::sample::{SampleReport, io, pretty};
use crate::shards;
use crate::{GenError, Generator, MergeSummary, Result, Shard};

/// Where and how a run writes.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    pub shard: Shard,
    /// Plan placements and write the actions and poses without rendering (into
    /// `OUT/plans/`).
    pub dry_run: bool,
    /// Replace an `OUT` that assist wrote for another spec.
    pub force: bool,
    /// Masks of the merged COCO instances (a whole run merges at its end).
    pub coco_masks: CocoMasks,
}

/// What a run reports as it goes.
pub enum RunEvent<'a> {
    /// The samples this process owns and how many of them are already done.
    Start { owned: u64, done: u64 },
    Sample {
        report: &'a SampleReport,
        /// Samples finished by this process so far (this one included).
        finished: u64,
        /// Samples left to make in this process.
        left: u64,
        elapsed: f64,
    },
}

/// What a run did.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    pub out: PathBuf,
    pub shard: String,
    pub made: u64,
    pub skipped: u64,
    pub seconds: f64,
    pub samples_per_second: f64,
    pub draws: u64,
    pub rejected: u64,
    pub gave_up: u64,
    /// The merged indices when this run covered every sample (unsharded).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merged: Option<MergeSummary>,
}

impl Generator {
    /// Makes every sample of `opts.shard` that is not already in `opts.out`; an unsharded
    /// run then merges the indices.
    pub fn run(&self, opts: &RunOptions, mut on: impl FnMut(&RunEvent)) -> Result<RunSummary> {
        let out = &opts.out;
        self.claim(out, opts.force)?;
        let kind = if opts.dry_run { "plans" } else { "samples" };
        let owned: Vec<u64> = (0..self.spec.count)
            .filter(|&i| opts.shard.owns(i))
            .collect();
        let dir_of = |i: u64| out.join(kind).join(format!("{i:06}"));
        // A sample is done when its manifest holds (this run's, every file there at its
        // size); a damaged or foreign one is made again.
        let run = integrity::run_identity(&self.manifest());
        let todo: Vec<u64> = owned
            .iter()
            .copied()
            .filter(|&i| {
                let d = dir_of(i);
                !d.join(assist_fs::MARKER).is_file() || integrity::check(&d, &run, false).is_err()
            })
            .collect();
        let skipped = owned.len() as u64 - todo.len() as u64;
        on(&RunEvent::Start {
            owned: owned.len() as u64,
            done: skipped,
        });
        // The object models, once per run (by the first shard; a rerun keeps them).
        if opts.shard.index == 0 && !opts.dry_run {
            self.write_models(out)?;
        }
        let t0 = Instant::now();
        let (mut draws, mut rejected, mut gave_up) = (0u64, 0u64, 0u64);
        let mut finished = 0u64;
        let mut done = |report: SampleReport| {
            draws += report.draws as u64;
            rejected += report.rejected as u64;
            gave_up += report.gave_up.len() as u64;
            finished += 1;
            on(&RunEvent::Sample {
                report: &report,
                finished,
                left: todo.len() as u64 - finished,
                elapsed: t0.elapsed().as_secs_f64(),
            });
        };
        // A sample's files are written while the next one renders: writing is mostly one
        // thread encoding images, and rendering keeps every core busy otherwise.
        std::thread::scope(|scope| -> Result<()> {
            let mut writing = None;
            let joined = |h: std::thread::ScopedJoinHandle<'_, Result<SampleReport>>| {
                h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
            };
            for &i in &todo {
                let made = self.sample(i, !opts.dry_run);
                if let Some(h) = writing.take() {
                    done(joined(h)?);
                }
                let sample = made?;
                let target = dir_of(i);
                let run = &run;
                writing = Some(scope.spawn(move || -> Result<SampleReport> {
                    let staging =
                        assist_fs::Staging::begin(&target, &format!("generating sample {i}"))?;
                    self.write_sample(&sample, staging.dir(), opts.dry_run)?;
                    integrity::write_manifest(staging.dir(), run)?;
                    staging.commit()?;
                    Ok(sample.report)
                }));
            }
            if let Some(h) = writing.take() {
                done(joined(h)?);
            }
            Ok(())
        })?;
        // Last: the shard's completion record (every sample it owns holds now).
        if !opts.dry_run {
            shards::write_record(out, opts.shard, self.spec.count, &run)?;
        }
        let seconds = t0.elapsed().as_secs_f64();
        let merged = if opts.shard.count == 1 && !opts.dry_run {
            Some(merge(out, false, opts.coco_masks)?)
        } else {
            None
        };
        Ok(RunSummary {
            out: out.clone(),
            shard: format!("{}/{}", opts.shard.index, opts.shard.count),
            made: todo.len() as u64,
            skipped,
            seconds,
            samples_per_second: if seconds > 0.0 {
                todo.len() as f64 / seconds
            } else {
                0.0
            },
            draws,
            rejected,
            gave_up,
            merged,
        })
    }

    /// Makes `out` this run's folder: a new folder, or one this same spec started (a
    /// restart, another shard). A folder another spec made is replaced only with `force`
    /// (and only if assist wrote it); anything else is refused.
    fn claim(&self, out: &Path, force: bool) -> Result<()> {
        // The shards of a run start together: one claims the new folder while the others
        // wait, then find its generate.json and agree with it.
        let _claiming = claim_lock(out)?;
        let manifest = self.manifest();
        let file = out.join("generate.json");
        if file.is_file() {
            let text = assist_fs::read_text(&file)?;
            let old: Value = serde_json::from_str(&text).map_err(|e| GenError::Folder {
                path: file.clone(),
                message: format!("not valid JSON: {e}"),
            })?;
            if old == manifest {
                return Ok(());
            }
            if !force {
                let what = ["spec", "classes", "format", "version"]
                    .into_iter()
                    .find(|k| old.get(k) != manifest.get(k))
                    .unwrap_or("spec");
                let detail = match (old.get("spec"), manifest.get("spec")) {
                    (Some(Value::Object(a)), Some(Value::Object(b))) => a
                        .keys()
                        .chain(b.keys())
                        .find(|k| a.get(*k) != b.get(*k))
                        .map(|k| format!(" (spec field {k:?} differs)"))
                        .unwrap_or_default(),
                    _ => String::new(),
                };
                return Err(GenError::Folder {
                    path: out.into(),
                    message: format!(
                        "was generated from another {what}{detail}; give another --out, or --force to replace it"
                    ),
                });
            }
            assist_fs::check_replaceable_as(out, true, assist_fs::Kind::Generated)?;
            assist_fs::check_only_ours(out, GENERATED)?;
            std::fs::remove_dir_all(out).map_err(|e| io(out, e))?;
        } else {
            assist_fs::check_replaceable_as(out, force, assist_fs::Kind::Generated)?;
            assist_fs::check_only_ours(out, GENERATED)?;
            if out.is_dir() {
                std::fs::remove_dir_all(out).map_err(|e| io(out, e))?;
            }
        }
        std::fs::create_dir_all(out.join("samples")).map_err(|e| io(out, e))?;
        let marker = out.join(assist_fs::MARKER);
        if !marker.exists() {
            assist_data::image_io::write_atomic(&marker, b"written by assist generate\n")?;
        }
        assist_data::image_io::write_atomic(&file, &pretty(&manifest))?;
        Ok(())
    }
}

/// The output's lock, waited for (a minute at most) while another shard holds it.
fn claim_lock(out: &Path) -> Result<assist_fs::OutputLock> {
    let t0 = Instant::now();
    loop {
        match assist_fs::lock(out, "claiming the folder of a generate run") {
            Err(assist_fs::FsError::Busy { .. }) if t0.elapsed().as_secs() < 60 => {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            r => return Ok(r?),
        }
    }
}
