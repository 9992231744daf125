//! `assist eval NAME.assist --data DATA`: image quality and panoptic accuracy on a split.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_data::{LoadOptions, Split};
use clap::Args;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    /// Dataset with the cameras and ground truth.
    #[arg(long)]
    pub data: PathBuf,
    /// The split to measure: test, val, train or all.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Evaluate every N-th frame of the split.
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
    /// Evaluate with the images N times smaller (default: as the scene was trained).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: Option<u32>,
    /// Print the report as JSON on stdout (with per-image and per-instance figures);
    /// without it the report goes to stderr as text.
    #[arg(long)]
    pub json: bool,
}

/// The `--downscale` a scene was trained with (1 when it does not say).
pub(crate) fn trained_downscale(info: &serde_json::Value) -> u32 {
    info.pointer("/options/downscale")
        .and_then(|v| v.as_u64())
        .map_or(1, |v| {
            v.clamp(1, assist_data::downscale::MAX_DOWNSCALE as u64) as u32
        })
}

/// `--split`: a split name, or `all` (`None`).
pub(crate) fn parse_split(s: &str) -> anyhow::Result<Option<Split>> {
    if s == "all" {
        return Ok(None);
    }
    Ok(Some(Split::parse(s).with_context(|| {
        format!("--split: expected train, val, test or all, got {s:?}")
    })?))
}

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    let split = parse_split(&a.split)?;
    let (scene, info) = assist_scene::scene_file::load(&a.scene)
        .with_context(|| format!("loading scene {}", a.scene.display()))?;
    let downscale = a.downscale.unwrap_or_else(|| trained_downscale(&info));
    let opts = LoadOptions {
        downscale,
        ..Default::default()
    };
    let ds = assist_data::load(&a.data, &opts)
        .with_context(|| format!("loading dataset {}", a.data.display()))?;
    let bar = crate::progress::bar(!a.json && std::io::stderr().is_terminal(), "eval");
    let r = assist_train::evaluate(&scene, &ds, split, a.stride, crate::progress::steps(&bar))?;
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        eprintln!(
            "{} images of split {} in {:.1} s",
            r.images, r.split, r.seconds
        );
        eprintln!("PSNR {:.2} dB  SSIM {:.4}", r.psnr, r.ssim);
        if let Some(m) = r.panoptic_miou {
            let per: Vec<String> = r
                .panoptic_iou
                .iter()
                .flatten()
                .map(|(id, v)| format!("{id}: {v:.3}"))
                .collect();
            eprintln!("panoptic mIoU {m:.4} (per instance {})", per.join(", "));
        }
        if let Some(b) = r.background_psnr {
            eprintln!("background PSNR {b:.2} dB (all pixels)");
        }
        if let Some(b) = r.background_occluded_psnr {
            eprintln!("background PSNR {b:.2} dB (pixels covered by objects)");
        }
        if let Some(e) = r.background_depth_error {
            eprintln!(
                "background depth error {:.1}% (median |rendered - true| / true)",
                100.0 * e
            );
        }
    }
    Ok(())
}
