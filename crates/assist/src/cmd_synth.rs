//! `assist synth`: the built-in scene generator.

use std::path::PathBuf;

use anyhow::Context;
use assist_data::synth::{CameraPath, SynthConfig, generate};
use clap::Args;

/// `--path`: where the cameras stand.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PathArg {
    Spiral,
    Walk,
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output folder (desk format). Refused if it exists and is not empty, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the scene's layout, textures and cameras.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Number of camera views (one in six is a test view).
    #[arg(long, visible_alias = "frames", default_value_t = 60)]
    pub views: usize,
    /// Image width, pixels.
    #[arg(long, default_value_t = 128)]
    pub width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 96)]
    pub height: u32,
    /// Image size WxH in pixels (instead of --width and --height).
    #[arg(long, value_name = "WxH", conflicts_with_all = ["width", "height"])]
    pub size: Option<String>,
    /// Number of objects on the table (3 to 6).
    #[arg(long, default_value_t = 5)]
    pub objects: usize,
    /// Colour samples per pixel (anti-aliasing).
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// Light samples per colour sample (soft shadows).
    #[arg(long, default_value_t = 4)]
    pub shadow_samples: u32,
    /// Where the cameras stand: spiral (spread over the room, every view different) or
    /// walk (one walk around the table in order, as a phone video is filmed).
    #[arg(long, value_enum, default_value_t = PathArg::Spiral)]
    pub path: PathArg,
    /// Replace an existing output folder.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

impl SynthArgs {
    pub fn config(&self) -> anyhow::Result<SynthConfig> {
        let (width, height) = match &self.size {
            Some(s) => crate::cmd_render::parse_size(s)?,
            None => (self.width, self.height),
        };
        Ok(SynthConfig {
            seed: self.seed,
            views: self.views,
            width,
            height,
            objects: self.objects,
            spp: self.spp,
            shadow_samples: self.shadow_samples,
            path: match self.path {
                PathArg::Spiral => CameraPath::Spiral,
                PathArg::Walk => CameraPath::Walk,
            },
        })
    }
}

pub fn run(a: SynthArgs) -> anyhow::Result<()> {
    let summary = synth(&a.config()?, &a.out, a.force, !a.json)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}

/// Generates with a progress bar (when `show` and stderr is a terminal) and a text summary.
pub fn synth(
    cfg: &SynthConfig,
    out: &std::path::Path,
    force: bool,
    show: bool,
) -> anyhow::Result<assist_data::synth::SynthSummary> {
    let start = std::time::Instant::now();
    let bar = crate::progress::bar(show, "rendering views");
    let summary = generate(cfg, out, force, &|done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("assist synth --out {}", out.display()))?;
    bar.finish_and_clear();
    if show {
        eprintln!(
            "synth: {} views ({} train, {} test) at {}x{}, {} objects, edits {}; {} images in {:.1} s -> {}",
            summary.views,
            summary.train,
            summary.test,
            cfg.width,
            cfg.height,
            summary.objects.len(),
            summary.edits.join(", "),
            summary.images_written,
            start.elapsed().as_secs_f64(),
            out.display()
        );
        for (id, label) in &summary.objects {
            eprintln!("  {id}: {label}");
        }
    }
    Ok(summary)
}
