//! Running a generator into a folder (any shard of it, resumable) and joining the samples'
//! annotations into dataset-wide files.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use serde_json::{Value, json};

use crate::coco::CocoMasks;
use crate::integrity;
use crate::sample::{SampleReport, io, pretty};
use crate::shards::{self, ShardState};
use crate::{GenError, Generator, Result, Shard};

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

pub(crate) fn sample_dir(out: &Path, index: u64) -> PathBuf {
    out.join("samples").join(format!("{index:06}"))
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

/// What `generate` writes at the top of its folder: anything else there is the user's,
/// and `--force` refuses to delete it.
pub const GENERATED: &[&str] = &[
    "samples",
    "annotations",
    "generate.json",
    "index.json",
    "plans",
    crate::bop::MODELS,
    shards::SHARDS,
];

/// What a merge wrote.
#[derive(Debug, Clone, Serialize)]
pub struct MergeSummary {
    pub samples: u64,
    pub images: u64,
    pub annotations: u64,
    pub missing: Vec<u64>,
}

/// Joins the samples in `out` into `annotations/instances.json` (COCO instances),
/// `annotations/panoptic.json` (COCO panoptic; its PNGs are the samples'
/// `views/panoptic_coco/`, paths relative to `out`) and `index.json`. Refuses a sample
/// that does not hold and another run's shards, naming them; missing samples are an error
/// unless `partial`. Streams: one sample's annotations in memory at a time, the arrays
/// gathered in temporary files beside the output, so a run of any size merges in bounded
/// memory. COCO ids follow the samples' order, so they are the same however the run was
/// sharded.
pub fn merge(out: &Path, partial: bool, masks: CocoMasks) -> Result<MergeSummary> {
    let manifest = shards::read_manifest(out)?;
    let count = manifest["spec"]["count"].as_u64().unwrap_or(0);
    // What a killed merge left behind.
    integrity::clean_stale(out);
    integrity::clean_stale(&out.join("annotations"));
    let st = shards::status(out, None, true)?;
    refuse_unless_whole(out, &st, count, partial)?;
    let classes: Vec<String> = manifest["classes"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|c| c.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    let ad = out.join("annotations");
    std::fs::create_dir_all(&ad).map_err(|e| io(&ad, e))?;
    let mut sinks = Sinks {
        images: Part::new(&ad, "images")?,
        anns: Part::new(&ad, "annotations")?,
        pan: Part::new(&ad, "panoptic")?,
    };
    let mut index = Part::new(out, "index-samples")?;
    let mut missing = Vec::new();
    let (mut draws, mut rejected) = (0u64, 0u64);
    let mut by_reason = serde_json::Map::new();
    for i in 0..count {
        if !st.sample_ok[i as usize] {
            missing.push(i);
            continue;
        }
        let sf = sample_dir(out, i).join("sample.json");
        let s: Value =
            serde_json::from_str(&assist_fs::read_text(&sf)?).map_err(|e| GenError::Folder {
                path: sf.clone(),
                message: format!("not valid JSON: {e}"),
            })?;
        add_views(&s, i, masks, &mut sinks)?;
        draws += s["draws"].as_u64().unwrap_or(0);
        rejected += s["rejected"].as_u64().unwrap_or(0);
        for (r, k) in s["rejections"].as_object().into_iter().flatten() {
            let sum =
                by_reason.get(r).and_then(|v| v.as_u64()).unwrap_or(0) + k.as_u64().unwrap_or(0);
            by_reason.insert(r.clone(), json!(sum));
        }
        index.push(&json!({
            "index": i,
            "dir": format!("samples/{i:06}"),
            "objects": s["objects"].as_array().map(|a| a.len()).unwrap_or(0),
            "views": s["views"].as_array().map(|a| a.len()).unwrap_or(0),
            "draws": s["draws"],
            "rejected": s["rejected"],
            "rejections": s["rejections"],
            "gave_up": s["gave_up"],
        }))?;
    }
    let things: Vec<Value> = classes
        .iter()
        .enumerate()
        .skip(1)
        .map(|(k, c)| json!({"id": k, "name": c, "supercategory": "object"}))
        .collect();
    let info = json!({"description": "assist generate", "version": "1", "masks": masks});
    let mut pan_cats =
        vec![json!({"id": 0, "name": "background", "supercategory": "background", "isthing": 0})];
    pan_cats.extend(
        classes
            .iter()
            .enumerate()
            .skip(1)
            .map(|(k, c)| json!({"id": k, "name": c, "supercategory": "object", "isthing": 1})),
    );
    for p in [
        &mut sinks.images,
        &mut sinks.anns,
        &mut sinks.pan,
        &mut index,
    ] {
        p.flush()?;
    }
    let head = |cats: &Vec<Value>| {
        format!(
            "{{\"info\": {info},\n\"categories\": {},\n\"images\": [\n",
            Value::from(cats.clone())
        )
    };
    assemble(
        &ad.join("instances.json"),
        &[
            Piece::Text(head(&things)),
            Piece::Part(&sinks.images),
            Piece::Text("\n],\n\"annotations\": [\n".into()),
            Piece::Part(&sinks.anns),
            Piece::Text("\n]}\n".into()),
        ],
    )?;
    assemble(
        &ad.join("panoptic.json"),
        &[
            Piece::Text(head(&pan_cats)),
            Piece::Part(&sinks.images),
            Piece::Text("\n],\n\"annotations\": [\n".into()),
            Piece::Part(&sinks.pan),
            Piece::Text("\n]}\n".into()),
        ],
    )?;
    let summary = json!({
        "count": count,
        "missing": missing,
        "draws": draws,
        "rejected": rejected,
        "rejections": by_reason,
        "classes": classes,
    });
    let summary = summary.to_string();
    assemble(
        &out.join("index.json"),
        &[
            Piece::Text(format!(
                "{},\n\"samples\": [\n",
                &summary[..summary.len() - 1]
            )),
            Piece::Part(&index),
            Piece::Text("\n]}\n".into()),
        ],
    )?;
    Ok(MergeSummary {
        samples: index.n,
        images: sinks.images.n,
        annotations: sinks.anns.n,
        missing,
    })
}

/// The merge's refusals: another run's shards, damaged ones, and (unless `partial`)
/// missing ones, each named.
fn refuse_unless_whole(out: &Path, st: &shards::Status, count: u64, partial: bool) -> Result<()> {
    let refuse = |what: &str, bad: Vec<&ShardState>, hint: &str| -> GenError {
        let named: Vec<String> = bad
            .iter()
            .take(10)
            .map(|s| format!("{} {} ({})", s.shard, s.state, s.problems.join("; ")))
            .collect();
        GenError::Folder {
            path: out.into(),
            message: format!(
                "{} shard{} {what}: {}{}; {hint} (`assist generate status {}` lists them)",
                bad.len(),
                if bad.len() == 1 { "" } else { "s" },
                named.join(", "),
                if bad.len() > 10 { ", …" } else { "" },
                out.display()
            ),
        }
    };
    let foreign: Vec<&ShardState> = st
        .incomplete
        .iter()
        .filter(|s| s.state == "foreign")
        .collect();
    if !foreign.is_empty() {
        return Err(refuse(
            "made by another run (another spec, seed or assist version)",
            foreign,
            "run them again with this run's spec and assist",
        ));
    }
    let damaged = st.incomplete.iter().any(|s| s.damaged > 0);
    if damaged || (st.samples_done < count && !partial) {
        // Without --partial every shard that is not complete is named; with it, the
        // damaged ones (a merge never indexes a file that does not hold).
        let bad: Vec<&ShardState> = st
            .incomplete
            .iter()
            .filter(|s| !partial || s.damaged > 0)
            .collect();
        return Err(refuse(
            &format!("not complete ({} of {count} samples hold)", st.samples_done),
            bad,
            "run them again with the same spec (a rerun remakes only what does not hold), or merge the others with --partial",
        ));
    }
    Ok(())
}

/// One JSON array's elements, written as they come to a temporary file (`.NAME.tmp-PID`,
/// which a later merge clears if this one is killed) and removed when dropped.
struct Part {
    path: PathBuf,
    w: std::io::BufWriter<std::fs::File>,
    n: u64,
}

impl Part {
    fn new(dir: &Path, name: &str) -> Result<Part> {
        let path = dir.join(format!(".{name}.tmp-{}", std::process::id()));
        let f = std::fs::File::create(&path).map_err(|e| io(&path, e))?;
        Ok(Part {
            w: std::io::BufWriter::new(f),
            path,
            n: 0,
        })
    }

    fn push(&mut self, v: &Value) -> Result<()> {
        use std::io::Write;
        let r = (|| {
            if self.n > 0 {
                self.w.write_all(b",\n")?;
            }
            serde_json::to_writer(&mut self.w, v).map_err(std::io::Error::other)
        })();
        self.n += 1;
        r.map_err(|e| io(&self.path, e))
    }

    fn flush(&mut self) -> Result<()> {
        use std::io::Write;
        self.w.flush().map_err(|e| io(&self.path, e))
    }
}

impl Drop for Part {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

enum Piece<'a> {
    Text(String),
    Part(&'a Part),
}

/// Writes `path` atomically from text and parts, in order.
fn assemble(path: &Path, pieces: &[Piece]) -> Result<()> {
    use std::io::Write;
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    let r = (|| -> std::io::Result<()> {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        for p in pieces {
            match p {
                Piece::Text(t) => w.write_all(t.as_bytes())?,
                Piece::Part(part) => {
                    std::io::copy(&mut std::fs::File::open(&part.path)?, &mut w)?;
                }
            }
        }
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = r {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(path, e));
    }
    Ok(())
}

/// Where a merge writes each sample's COCO images, instances and panoptic segments.
struct Sinks {
    images: Part,
    anns: Part,
    pan: Part,
}

/// Sample `i`'s views (its `sample.json` `s`) as COCO images, instance annotations and
/// panoptic segments, with ids following those already written.
fn add_views(s: &Value, i: u64, masks: CocoMasks, sinks: &mut Sinks) -> Result<()> {
    let rel = format!("samples/{i:06}");
    for v in s["views"].as_array().into_iter().flatten() {
        let name = v["name"].as_str().unwrap_or("");
        let image_id = sinks.images.n + 1;
        let (w, h) = (
            v["width"].as_u64().unwrap_or(0),
            v["height"].as_u64().unwrap_or(0),
        );
        sinks.images.push(&json!({
            "id": image_id,
            "file_name": format!("{rel}/views/images/{name}.png"),
            "width": w,
            "height": h,
            "sample": i,
            "view": name,
        }))?;
        let mut segments = Vec::new();
        for o in v["objects"].as_array().into_iter().flatten() {
            let Some(rle) = o["rle"].as_str() else {
                continue;
            };
            let segmentation = match masks {
                CocoMasks::Rle => json!({"size": [h, w], "counts": rle}),
                // A sample written before polygons were kept: its exact RLE.
                CocoMasks::Polygon if o["polygons"].is_null() => {
                    json!({"size": [h, w], "counts": rle})
                }
                CocoMasks::Polygon => o["polygons"].clone(),
            };
            sinks.anns.push(&json!({
                "id": sinks.anns.n + 1,
                "image_id": image_id,
                "category_id": o["class"],
                "segmentation": segmentation,
                "area": o["visible_pixels"],
                "bbox": o["bbox_visible"],
                "iscrowd": 0,
                "instance_id": o["id"],
                "bbox_amodal": o["bbox_amodal"],
                "visibility": o["visibility"],
            }))?;
            segments.push(json!({
                "id": o["id"],
                "category_id": o["class"],
                "area": o["visible_pixels"],
                "bbox": o["bbox_visible"],
                "iscrowd": 0,
            }));
        }
        if v["background_pixels"].as_u64().unwrap_or(0) > 0 {
            segments.push(json!({
                "id": 1 << 16,
                "category_id": 0,
                "area": v["background_pixels"],
                "bbox": v["background_bbox"],
                "iscrowd": 0,
            }));
        }
        sinks.pan.push(&json!({
            "image_id": image_id,
            "file_name": format!("{rel}/views/panoptic_coco/{name}.png"),
            "segments_info": segments,
        }))?;
    }
    Ok(())
}
