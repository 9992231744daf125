//! `assist dataset info PATH [--json]`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_data::{Dataset, Format, LoadOptions, Split};
use clap::{Args, Subcommand};
use serde_json::{Value, json};

#[derive(Subcommand, Debug)]
pub enum DatasetCommand {
    /// Format, frames per split, resolution, cameras, instances and bounds; validates that
    /// every referenced file exists and decodes at the declared size.
    Info(InfoArgs),
    /// The object boxes `assist train` would use (the dataset's plus a margin, or carved from
    /// the instance masks plus a margin, or the ones --boxes gives). With --json, a file that
    /// `assist train --boxes` reads back: edit it and pass it to override any box.
    Boxes(BoxesArgs),
    /// Instance masks for every image from boxes around the objects, on a scene trained
    /// on the dataset without masks (`assist train --no-objects`): a folder any tool reads
    /// and `assist train --masks` trains the objects from.
    Masks(crate::cmd_dataset_masks::MasksArgs),
}

#[derive(Args, Debug)]
pub struct BoxesArgs {
    /// A dataset folder or file.
    pub path: PathBuf,
    /// Print the boxes file (JSON) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Boxes overriding the estimated ones (as for `assist train --boxes`).
    #[arg(long)]
    pub boxes: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// A dataset folder or file (transforms.json, transforms_train.json, a COLMAP model, poses_bounds.npy).
    pub path: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Read as this format instead of detecting it (nerfstudio, blender, colmap, colmap-text, llff).
    #[arg(long)]
    pub format: Option<String>,
    /// LLFF downscale factor (images_N); default: the smallest available.
    #[arg(long)]
    pub llff_factor: Option<u32>,
    /// Make every image N times smaller (from images_N/ folders where they exist).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Skip decoding every file (only parse the dataset description).
    #[arg(long)]
    pub no_validate: bool,
    /// Also report a folder of background priors made elsewhere (as `train --prior-dir`).
    #[arg(long)]
    pub prior_dir: Option<PathBuf>,
}

pub fn run(cmd: DatasetCommand) -> anyhow::Result<()> {
    match cmd {
        DatasetCommand::Info(a) => info(a),
        DatasetCommand::Boxes(a) => boxes(a),
        DatasetCommand::Masks(a) => crate::cmd_dataset_masks::run(a),
    }
}

fn boxes(a: BoxesArgs) -> anyhow::Result<()> {
    let user = match &a.boxes {
        Some(p) => assist_data::boxes::read_boxes(p).context("--boxes")?,
        None => Vec::new(),
    };
    let list = assist_session::dataset_boxes(&a.path, user)
        .with_context(|| format!("dataset {}", a.path.display()))?;
    if a.json {
        let triples: Vec<_> = list
            .iter()
            .map(|n| (n.id, n.label.clone(), n.obb))
            .collect();
        let mut v = assist_data::boxes::boxes_json(&triples);
        for (e, n) in v["instances"]
            .as_array_mut()
            .into_iter()
            .flatten()
            .zip(&list)
        {
            e["source"] = serde_json::to_value(n.source)?;
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{:>5}  {:<8} {:>26}  {:>20}  label",
            "id", "source", "centre", "size"
        );
        for n in &list {
            let (c, sz) = (n.obb.center, n.obb.size());
            println!(
                "{:>5}  {:<8} {:>8.3} {:>8.3} {:>8.3}  {:>6.3} {:>6.3} {:>6.3}  {}",
                n.id,
                format!("{:?}", n.source).to_lowercase(),
                c.x,
                c.y,
                c.z,
                sz.x,
                sz.y,
                sz.z,
                n.label,
            );
        }
        if list.is_empty() {
            println!("(no object instances: the scene is background only)");
        }
    }
    Ok(())
}

pub fn load_options(
    format: Option<&str>,
    llff_factor: Option<u32>,
    downscale: u32,
    prior_dir: Option<PathBuf>,
) -> anyhow::Result<LoadOptions> {
    let format = match format {
        Some(f) => Some(Format::parse(f).with_context(|| {
            format!("--format {f}: expected nerfstudio, blender, colmap, colmap-text or llff")
        })?),
        None => None,
    };
    Ok(LoadOptions {
        format,
        llff_factor,
        downscale,
        prior_dir,
        masks: None,
    })
}

fn info(a: InfoArgs) -> anyhow::Result<()> {
    let opts = load_options(
        a.format.as_deref(),
        a.llff_factor,
        a.downscale,
        a.prior_dir.clone(),
    )?;
    let ds = assist_data::load(&a.path, &opts)?;
    let report = if a.no_validate {
        None
    } else {
        Some(assist_data::validate::validate(&ds))
    };
    let mut v = describe(&ds);
    if let Some(r) = &report {
        v["validation"] = json!({
            "files_checked": r.files_checked,
            "errors": r.errors.iter().map(|e| e.to_string()).collect::<Vec<_>>(),
            "undeclared_instance_ids": r.undeclared_ids,
        });
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print_text(&ds, &v);
    }
    if let Some(r) = report
        && !r.errors.is_empty()
    {
        if !a.json {
            for e in r.errors.iter().take(20) {
                eprintln!("invalid: {e}");
            }
            if r.errors.len() > 20 {
                eprintln!("… and {} more", r.errors.len() - 20);
            }
        }
        bail!(
            "{}: {} of {} files failed validation; first: {}",
            a.path.display(),
            r.errors.len(),
            r.files_checked,
            r.errors[0]
        );
    }
    Ok(())
}

/// The dataset summary as JSON (the `--json` output, minus validation).
pub fn describe(ds: &Dataset) -> Value {
    let mut splits = BTreeMap::new();
    for s in [Split::Train, Split::Val, Split::Test] {
        let n = ds.count(s);
        if n > 0 {
            splits.insert(s.name(), n);
        }
    }
    let f0 = &ds.frames[0];
    let same_size = ds
        .frames
        .iter()
        .all(|f| (f.camera.width(), f.camera.height()) == (f0.camera.width(), f0.camera.height()));
    let mut models: Vec<&str> = ds.frames.iter().map(|f| f.camera_model.as_str()).collect();
    models.sort();
    models.dedup();
    let same_intr = ds
        .frames
        .iter()
        .all(|f| f.camera.intrinsics == f0.camera.intrinsics);
    let i = &f0.camera.intrinsics;
    json!({
        "format": ds.format.name(),
        "path": ds.root.display().to_string(),
        "frames": ds.frames.len(),
        "splits": splits,
        "split_source": ds.split_source,
        "split_declared": ds.split_declared,
        "rendered": ds.rendered,
        "width": f0.camera.width(),
        "height": f0.camera.height(),
        "uniform_resolution": same_size,
        "camera_model": if models.len() == 1 { models[0].to_string() } else { format!("mixed: {}", models.join(", ")) },
        "intrinsics": {
            "fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy,
            "distortion": i.distortion,
            "shared_by_all_frames": same_intr,
        },
        "has_masks": ds.frames.iter().any(|f| f.mask_path.is_some() || f.alpha_is_mask),
        "has_instance_masks": ds.frames.iter().any(|f| f.instance_mask_path.is_some()),
        "has_depth": ds.frames.iter().any(|f| f.depth_path.is_some()),
        "mask_folder": ds.mask_folder,
        "prior_folder": ds.prior_folder,
        "instances": ds.instances.iter().map(|inst| json!({
            "id": inst.id,
            "label": inst.label,
            "bbox": inst.bbox.as_ref().map(assist_data::boxes::bbox_json),
        })).collect::<Vec<_>>(),
        "sparse_points": ds.points.len(),
        "depth_range": ds.depth_range.map(|(n, f)| [n, f]),
        "world_up": ds.world_up.map(|u| u.to_array()),
        "meters_per_unit": ds.meters_per_unit,
        "bounds": { "min": ds.bounds.min.to_array(), "max": ds.bounds.max.to_array(), "source": ds.bounds.source },
        "normalization": { "center": ds.normalization.center.to_array(), "scale": ds.normalization.scale,
                           "meaning": "p_normalized = (p - center) * scale" },
    })
}

fn print_text(ds: &Dataset, v: &Value) {
    println!(
        "dataset   {} ({})",
        ds.root.display(),
        v["format"].as_str().unwrap_or("")
    );
    let splits: Vec<String> = v["splits"]
        .as_object()
        .map(|o| o.iter().map(|(k, n)| format!("{k} {n}")).collect())
        .unwrap_or_default();
    println!(
        "frames    {} ({}; split: {})",
        ds.frames.len(),
        splits.join(", "),
        ds.split_source
    );
    println!(
        "images    {}x{}{}, {} (appearance codes by default: {})",
        v["width"],
        v["height"],
        if v["uniform_resolution"].as_bool() == Some(true) {
            ""
        } else {
            " (first frame; sizes vary)"
        },
        if ds.rendered {
            "rendered"
        } else {
            "photographs"
        },
        if ds.rendered { "off" } else { "on" }
    );
    let i = &ds.frames[0].camera.intrinsics;
    println!(
        "camera    {}  fx {:.3} fy {:.3} cx {:.3} cy {:.3}  distortion {:?}{}",
        v["camera_model"].as_str().unwrap_or(""),
        i.fx,
        i.fy,
        i.cx,
        i.cy,
        i.distortion,
        if v["intrinsics"]["shared_by_all_frames"].as_bool() == Some(true) {
            ""
        } else {
            " (first frame; per-frame intrinsics)"
        }
    );
    let extras: Vec<&str> = [
        ("masks", "has_masks"),
        ("instance masks", "has_instance_masks"),
        ("depth", "has_depth"),
    ]
    .iter()
    .filter(|(_, k)| v[*k].as_bool() == Some(true))
    .map(|(n, _)| *n)
    .collect();
    println!(
        "with      {}",
        if extras.is_empty() {
            "images only".to_string()
        } else {
            extras.join(", ")
        }
    );
    if let Some(p) = &ds.prior_folder {
        println!(
            "priors    {} of {} training images in {} ({} with depth)",
            p.images,
            p.train_frames,
            p.folder.display(),
            p.depths
        );
    }
    if let Some(m) = &ds.mask_folder {
        let kind = match m.encoding {
            assist_data::masks::MaskEncoding::Ids => "instance-valued".to_string(),
            assist_data::masks::MaskEncoding::Binary { threshold } => {
                format!("binary, one object where the value is at least {threshold}")
            }
        };
        println!(
            "masks     {} files in {} ({kind}); instance ids {:?}",
            m.files,
            m.folder.display(),
            m.ids
        );
    }
    println!("instances {}", ds.instances.len());
    for inst in &ds.instances {
        match inst.bbox {
            Some(b) => println!(
                "  {:>3}  {:<40} box centre {:.3?} size {:.3?}",
                inst.id,
                inst.label,
                b.center.to_array(),
                b.size().to_array()
            ),
            None => println!("  {:>3}  {}", inst.id, inst.label),
        }
    }
    if !ds.points.is_empty() {
        println!("points    {} sparse 3D points", ds.points.len());
    }
    println!(
        "bounds    min {:.3?} max {:.3?} ({})",
        ds.bounds.min.to_array(),
        ds.bounds.max.to_array(),
        ds.bounds.source
    );
    use assist_data::Format;
    match ds.world_up {
        Some(u) => println!(
            "up        [{:.3}, {:.3}, {:.3}]{}",
            u.x,
            u.y,
            u.z,
            if matches!(
                ds.format,
                Format::Llff | Format::ColmapBinary | Format::ColmapText
            ) {
                " (from how the cameras were held: the format states none)"
            } else {
                ""
            }
        ),
        None => println!("up        not stated (+Z taken)"),
    }
    match ds.meters_per_unit {
        Some(m) => println!("scale     {m} m per unit"),
        None => println!("scale     unknown (no metric scale in the dataset)"),
    }
    if let Some(val) = v.get("validation") {
        println!(
            "validated {} files, {} errors",
            val["files_checked"],
            val["errors"].as_array().map(|a| a.len()).unwrap_or(0)
        );
        if let Some(ids) = val["undeclared_instance_ids"].as_array()
            && !ids.is_empty()
        {
            println!("warning   instance ids in masks but not declared: {ids:?}");
        }
    }
}
