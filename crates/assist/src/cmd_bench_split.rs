//! `assist bench split SCENE --data DATA --boxes FILE`: masks derived from object boxes on
//! a scene trained without masks, against the dataset's own instance masks. For each view
//! of the chosen split, the boxes' masks are rendered at `--render-downscale` and refined
//! on the photograph (full size); intersection over union per object is summed over the
//! views, and mIoU is its mean over the objects. Each `--refine` radius is one row (0 =
//! the render's mask upsampled, unrefined).

use std::time::Instant;

use anyhow::{Context, bail};
use assist_data::{LoadOptions, Split, image_io};
use assist_session::Session;
use assist_session::split::{MaskOptions, MaskView, SplitBox, iou_per_id};
use clap::Args;
use serde_json::{Value, json};

#[derive(Args, Debug)]
pub struct SplitBenchArgs {
    /// Scene trained on DATA without its masks (`assist train --no-objects`).
    pub scene: std::path::PathBuf,
    /// The dataset, with instance masks to compare against.
    #[arg(long)]
    pub data: std::path::PathBuf,
    /// The objects' boxes (as `assist dataset boxes DATA --json` writes them; ids or
    /// labels name the dataset's instances).
    #[arg(long)]
    pub boxes: std::path::PathBuf,
    /// Which views: test (held-out) or train.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Render N times smaller than the photographs.
    #[arg(long, default_value_t = assist_session::split::click::RENDER_DOWNSCALE)]
    pub render_downscale: u32,
    /// Guided-filter radii as shares of the photograph's larger side (comma-separated;
    /// 0 = unrefined).
    #[arg(long, value_delimiter = ',', default_values_t = [MaskOptions::default().refine_radius])]
    pub refine: Vec<f64>,
    /// Support bands as shares of a box's height (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [MaskOptions::default().support_band])]
    pub band: Vec<f64>,
    /// A Segment Anything checkpoint: each mask then sharpened by SAM as `--sam` of
    /// `assist scene split` does (its time included).
    #[arg(long, value_name = "CHECKPOINT")]
    pub sam: Option<std::path::PathBuf>,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: SplitBenchArgs) -> anyhow::Result<()> {
    let session = Session::open(&a.scene)?;
    let sam = a
        .sam
        .as_deref()
        .map(assist_session::split::sam::SamRefine::load)
        .transpose()?;
    let ds = assist_data::load(&a.data, &LoadOptions::default())
        .with_context(|| format!("reading {}", a.data.display()))?;
    let split = match a.split.as_str() {
        "test" => Split::Test,
        "train" => Split::Train,
        other => bail!("--split: expected test or train, got {other:?}"),
    };
    let boxes = split_boxes(&a.boxes, &ds)?;
    let frames: Vec<_> = ds
        .frames
        .iter()
        .filter(|f| f.split == split && f.instance_mask_path.is_some())
        .collect();
    if frames.is_empty() {
        bail!(
            "{}: no {} views with instance masks to compare against",
            a.data.display(),
            a.split
        );
    }
    let mut photos = Vec::new();
    let mut truth = Vec::new();
    for f in &frames {
        photos.push(image_io::read_rgb(&f.image_path, [0.0; 3])?.0);
        let m =
            image_io::read_instance_mask(f.instance_mask_path.as_ref().unwrap(), f.mask_encoding)?;
        truth.push(m.data);
    }
    let ids: Vec<u16> = boxes.iter().map(|b| b.id).collect();
    let mut rows = Vec::new();
    for &band in &a.band {
        for &radius in &a.refine {
            let opts = MaskOptions {
                support_band: band,
                refine_radius: radius,
                ..MaskOptions::default()
            };
            let views: Vec<MaskView> = frames
                .iter()
                .zip(&photos)
                .map(|(f, p)| MaskView {
                    camera: f.camera,
                    photo: Some(p),
                })
                .collect();
            let size = |c: &assist_core::Camera| {
                assist_session::split::click::render_size(c, a.render_downscale as f64)
            };
            let t0 = Instant::now();
            let masks =
                session.box_masks(&views, &boxes, Some(size(&frames[0].camera)), &opts, |_| {})?;
            let mut masks = masks;
            let mut replaced = 0;
            if let Some(sam) = &sam {
                for (m, p) in masks.iter_mut().zip(&photos) {
                    replaced += sam.refine(p, m, &boxes)?.replaced;
                }
            }
            let seconds = t0.elapsed().as_secs_f64();
            let pairs: Vec<(Vec<u16>, Vec<u16>)> =
                masks.into_iter().zip(truth.iter().cloned()).collect();
            let ious = iou_per_id(&pairs, &ids);
            let miou = ious.iter().map(|(_, v)| v).sum::<f64>() / ious.len().max(1) as f64;
            rows.push(json!({
                "band": band,
                "refine_radius": radius,
                "miou": miou,
                "iou": ious.iter().map(|(id, v)| json!({"id": id, "iou": v})).collect::<Vec<_>>(),
                "seconds": seconds,
                "sam_replaced": sam.as_ref().map(|_| replaced),
            }));
        }
    }
    let out = json!({
        "scene": a.scene,
        "data": a.data,
        "split": a.split,
        "views": frames.len(),
        "render_downscale": a.render_downscale,
        "objects": boxes.iter().map(|b| json!({"id": b.id, "label": b.label})).collect::<Vec<_>>(),
        "rows": rows,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_rows(&out);
    }
    Ok(())
}

fn print_rows(out: &Value) {
    println!(
        "{} {} views, rendered 1/{}:",
        out["views"], out["split"], out["render_downscale"]
    );
    println!(
        "{:>6} {:>7} {:>6}  per object  (s)",
        "band", "refine", "mIoU"
    );
    for r in out["rows"].as_array().into_iter().flatten() {
        let per: Vec<String> = r["iou"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|o| format!("{:.3}", o["iou"].as_f64().unwrap_or(0.0)))
            .collect();
        println!(
            "{:>6} {:>7} {:>6.3}  {}  ({:.1})",
            r["band"],
            r["refine_radius"],
            r["miou"].as_f64().unwrap_or(0.0),
            per.join(" "),
            r["seconds"].as_f64().unwrap_or(0.0)
        );
    }
}

/// The boxes of a boxes file as new objects: ids from the file, or the dataset's
/// instance of the label it names.
fn split_boxes(path: &std::path::Path, ds: &assist_data::Dataset) -> anyhow::Result<Vec<SplitBox>> {
    let read = assist_data::boxes::read_boxes(path)?;
    read.into_iter()
        .map(|b| {
            let inst = ds.instances.iter().find(|i| {
                b.id.is_some_and(|id| id == i.id) || b.label.as_deref() == Some(i.label.as_str())
            });
            let id = b.id.or(inst.map(|i| i.id)).with_context(|| {
                format!(
                    "{} {}: names no instance of {}",
                    b.file.display(),
                    b.entry,
                    ds.root.display()
                )
            })?;
            Ok(SplitBox {
                id,
                label: b
                    .label
                    .clone()
                    .or(inst.map(|i| i.label.clone()))
                    .unwrap_or_else(|| format!("object-{id}")),
                obb: b.bbox,
            })
        })
        .collect()
}
