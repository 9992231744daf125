//! `assist dataset masks DATA --scene SCENE --box … --label … --out DIR`: instance masks for
//! every image of a dataset nobody labelled, from boxes around its objects on a scene
//! trained on it without masks (`assist train --no-objects`). The folder holds one PNG
//! per image (named like it; 0 = background, the objects 1, 2, … in the order given),
//! `instances.json` (ids, labels, boxes) and `masks.json` (how they were made); any tool
//! reads it, and `assist train DATA --masks DIR` trains the objects from it.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_core::DVec3;
use assist_data::LoadOptions;
use assist_session::Session;
use assist_session::split::MaskProgress;
use assist_session::split::targets::Objects;
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct MasksArgs {
    /// The dataset (any supported format).
    pub data: PathBuf,
    /// A scene trained on DATA (without masks: `assist train DATA --no-objects`).
    #[arg(long)]
    pub scene: PathBuf,
    #[command(flatten)]
    pub objects: Objects,
    /// The masks folder written.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if assist wrote it.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

/// A point or size to a tenth of a millimetre in metres (for messages).
pub fn vec3(v: DVec3) -> String {
    format!("[{:.4}, {:.4}, {:.4}]", v.x, v.y, v.z)
}

pub fn run(a: MasksArgs) -> anyhow::Result<()> {
    assist_fs::check_replaceable(&a.out, a.force)?;
    assist_fs::check_not_input(&a.out, &[&a.data, &a.scene])?;
    let session = Session::open(&a.scene)?;
    let sam = a
        .objects
        .sam
        .as_deref()
        .map(assist_session::split::sam::SamRefine::load)
        .transpose()?;
    let ds = assist_data::load(&a.data, &LoadOptions::default())
        .with_context(|| format!("reading {}", a.data.display()))?;
    let targets = a.objects.targets(session.description().up)?;
    let boxes = targets.resolve(&session, &ds, 1, a.objects.render_downscale, |c, obb| {
        eprintln!(
            "--click {c}: box centre {} size {}",
            vec3(obb.center),
            vec3(obb.size())
        )
    })?;
    let staging = assist_fs::Staging::begin(&a.out, "dataset masks")?;
    let show = !a.json && std::io::stderr().is_terminal();
    let bar = crate::progress::bar(show, "rendering views");
    let made = session.write_masks(
        &ds,
        &boxes,
        staging.dir(),
        a.objects.render_downscale,
        false,
        sam.as_ref(),
        |p| {
            let (message, done, total) = match p {
                MaskProgress::Rendering { done, total } => ("rendering views", done, total),
                MaskProgress::Refining { done, total } => ("refining masks", done, total),
            };
            bar.set_message(message);
            crate::progress::steps(&bar)(done, total)
        },
    )?;
    bar.finish_and_clear();
    staging.commit()?;
    if let Some(o) = made.objects.iter().find(|o| o.pixels == 0) {
        eprintln!(
            "warning: {} ({}) owns no pixel in any view: is its box around a surface the scene shows?",
            o.label, o.id
        );
    }
    let n = made.images;
    if a.json {
        let mut v = serde_json::to_value(&made)?;
        v["data"] = json!(a.data);
        v["scene"] = json!(a.scene);
        v["out"] = json!(a.out);
        v["render_downscale"] = json!(a.objects.render_downscale);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        for o in &made.objects {
            println!(
                "{:>3}  {:<24} {} pixels over {n} images",
                o.id, o.label, o.pixels
            );
        }
        if let Some(c) = made.sam {
            println!(
                "SAM replaced {} of the {} object masks it was asked for (the rest disagreed with the geometry and were kept)",
                c.replaced, c.prompted
            );
        }
        println!(
            "masks of {n} images in {:.1} s -> {} (train with: assist train {} --masks {})",
            made.seconds,
            a.out.display(),
            a.data.display(),
            a.out.display()
        );
    }
    Ok(())
}
