//! `assist eval NAME.assist --data DATA`: image quality and panoptic accuracy on a split.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_data::Split;
use assist_data::image_io::ImageF32;
use assist_data::visual::{captioned, depth_image};
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
    /// Also write a contact sheet PNG here: a row per measured view, the photograph, the
    /// render (captioned with its PSNR) and its depth. An existing file needs `--force`.
    #[arg(long, value_name = "PNG")]
    pub sheet: Option<PathBuf>,
    /// Replace an existing `--sheet` file.
    #[arg(long)]
    pub force: bool,
    /// Fit each measured view's camera to its photograph first, with the scene frozen (a
    /// centre shift and a turn, by gradient descent on its pixels), and measure from the
    /// fitted camera: the protocol for poses from COLMAP or scenes trained with
    /// `--refine-poses`. Each view's fit is in the report.
    #[arg(long)]
    pub align_poses: bool,
    /// Gradient steps of each view's fit (`--align-poses`).
    #[arg(long, default_value_t = assist_train::AlignOptions::default().steps, requires = "align_poses")]
    pub align_steps: usize,
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
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
    let device = a.device.open()?;
    let job = assist_session::EvalJob {
        scene: a.scene.clone(),
        data: a.data.clone(),
        split,
        stride: a.stride,
        downscale: a.downscale,
        backend: device.field_backend(),
        align: a.align_poses.then(|| assist_train::AlignOptions {
            steps: a.align_steps,
            ..Default::default()
        }),
    };
    let bar = crate::progress::bar(!a.json && std::io::stderr().is_terminal(), "eval");
    if let Some(p) = &a.sheet
        && p.exists()
        && !a.force
    {
        bail!(
            "--sheet {}: the file exists (add --force to replace it)",
            p.display()
        );
    }
    let mut tiles = Vec::new();
    let r = job
        .run_each(crate::progress::steps(&bar), |v| {
            if a.sheet.is_some() {
                tiles.extend(sheet_row(&v));
            }
        })
        .with_context(|| format!("evaluating {} on {}", a.scene.display(), a.data.display()))?;
    bar.finish_and_clear();
    device.report();
    if let Some(p) = &a.sheet {
        let sheet = assist_data::visual::contact_sheet(&tiles, 3);
        assist_data::image_io::write_rgb_png(p, &sheet)
            .with_context(|| format!("writing --sheet {}", p.display()))?;
        if !a.json {
            eprintln!("contact sheet: {}", p.display());
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        eprintln!(
            "{} images of split {} in {:.1} s",
            r.images, r.split, r.seconds
        );
        eprintln!("PSNR {:.2} dB  SSIM {:.4}", r.psnr, r.ssim);
        let fits: Vec<_> = r.per_image.iter().filter_map(|s| s.alignment).collect();
        if !fits.is_empty() {
            let used: Vec<_> = fits.iter().filter(|f| f.applied).collect();
            let mut line = format!(
                "cameras fitted to their photographs: {} of {} moved",
                used.len(),
                fits.len()
            );
            if !used.is_empty() {
                let n = used.len() as f64;
                line += &format!(
                    " (mean {:.4} units, {:.3} deg)",
                    used.iter().map(|f| f.translation).sum::<f64>() / n,
                    used.iter().map(|f| f.rotation_deg).sum::<f64>() / n
                );
            }
            eprintln!("{line}");
        }
        eprintln!(
            "PSNR {:.2} dB after each view's best colour gain and offset (what exposure costs)",
            r.color_corrected_psnr
        );
        if let Some(m) = r.panoptic_miou {
            let per: Vec<String> = r
                .panoptic_iou
                .iter()
                .flatten()
                .map(|(id, v)| format!("{id}: {v:.3}"))
                .collect();
            eprintln!("panoptic mIoU {m:.4} (per instance {})", per.join(", "));
        }
        if let (Some(o), Some(b)) = (r.object_pixels_psnr, r.other_pixels_psnr) {
            eprintln!("PSNR {o:.2} dB on the masks' object pixels, {b:.2} dB on the others");
        }
        if let Some(d) = r.detail {
            let mut line = format!(
                "fine detail {d:.2} of the photographs' (1: as sharp; structure 1-3 pixels across)"
            );
            if let (Some(o), Some(b)) = (r.object_pixels_detail, r.other_pixels_detail) {
                line += &format!("; {o:.2} on the object pixels, {b:.2} on the others");
            }
            eprintln!("{line}");
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

/// One row of the contact sheet: photograph, render with its PSNR, depth.
fn sheet_row(v: &assist_session::EvaluatedView<'_>) -> [ImageF32; 3] {
    let (w, h) = (v.render.width, v.render.height);
    let rgb = |data: &[f32]| ImageF32 {
        width: w,
        height: h,
        channels: 3,
        data: data.iter().map(|x| x.clamp(0.0, 1.0)).collect(),
    };
    [
        captioned(&rgb(v.truth), &format!("truth {}", v.score.name), 1),
        captioned(
            &rgb(&v.render.rgb),
            &format!("render {:.2} dB", v.score.psnr),
            1,
        ),
        captioned(&depth_image(w, h, &v.render.depth), "depth", 1),
    ]
}
