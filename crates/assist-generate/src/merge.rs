//! Joining the samples' annotations into dataset-wide files (COCO, BOP, the index).

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::{Value, json};

use crate::coco::CocoMasks;
use crate::integrity;
use crate::sample::io;
use crate::shards::{self, ShardState};
use crate::{GenError, Result};

/// A sample's folder in a run's output.
pub(crate) fn sample_dir(out: &Path, index: u64) -> PathBuf {
    out.join("samples").join(format!("{index:06}"))
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
