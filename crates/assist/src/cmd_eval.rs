//! `assist eval NAME.assist --data DATA`: image quality and panoptic accuracy on a split.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_data::Split;
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
    let job = assist_session::EvalJob {
        scene: a.scene.clone(),
        data: a.data.clone(),
        split,
        stride: a.stride,
        downscale: a.downscale,
    };
    let bar = crate::progress::bar(!a.json && std::io::stderr().is_terminal(), "eval");
    let r = job
        .run(crate::progress::steps(&bar))
        .with_context(|| format!("evaluating {} on {}", a.scene.display(), a.data.display()))?;
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
