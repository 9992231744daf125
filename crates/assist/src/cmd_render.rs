//! `assist render SCENE --out DIR`: renders a trained (possibly edited) scene into a new
//! dataset others can train on: RGB PNG, z-depth (16-bit PNG in millimetres and float32
//! `.npy`), instance ids (16-bit PNG + JSON legend), semantic classes (16-bit PNG + legend),
//! per-node layers (RGBA, alpha = the node's opacity), the background alone, and a
//! nerfstudio `transforms.json` of the rendered cameras. Cameras come from a dataset split
//! (file names kept), a `transforms.json`, or an orbit around the objects.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_session::{
    CameraSource, DatasetOutput, Highlight, Orbit, Output, Quality, RenderJob, Session,
    SessionError, SplitChoice,
};
use clap::Args;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    /// The new dataset's folder (RGB, depth, labels, transforms.json). Refused if it
    /// exists, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Cameras: a dataset (directory; also given as --data), a transforms.json, or
    /// `orbit` (a ring of views around the objects, see --frames and --size).
    #[arg(long, visible_alias = "data", default_value = "orbit")]
    pub cameras: String,
    /// Dataset split to render (train, val, test, all, or auto: the test split when the
    /// dataset declares its split — split.json, *_filenames, Blender's files — else every
    /// frame, e.g. for a bare transforms.json of cameras).
    #[arg(long, default_value = "auto")]
    pub split: String,
    /// With a dataset as --cameras: render its cameras N times smaller.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Comma-separated: rgb, depth, panoptic, semantic, objects, background, unseen (255
    /// where no training view saw the surface and its colour was continued).
    #[arg(long, default_value = "rgb,depth,panoptic")]
    pub outputs: String,
    /// Highlight this object: an instance id or a name ("ball", "the red mug"), found as
    /// `edit` finds objects (default: the scene's selection, if any).
    #[arg(long, value_name = "ID|NAME")]
    pub select: Option<String>,
    /// Do not highlight the scene's selection.
    #[arg(long)]
    pub no_highlight: bool,
    /// Orbit: number of views.
    #[arg(long, visible_alias = "views", default_value_t = 24)]
    pub frames: usize,
    /// Orbit: image size WxH.
    #[arg(long, default_value = "480x360")]
    pub size: String,
    /// Orbit: horizontal field of view in degrees.
    #[arg(long, default_value_t = 50.0)]
    pub fov: f64,
    /// Orbit: camera elevation above the horizon in degrees.
    #[arg(long, default_value_t = 30.0)]
    pub elevation: f64,
    /// Orbit: distance from the centre in world units (default: frames the objects).
    #[arg(long)]
    pub radius: Option<f64>,
    /// Replace --out if assist wrote it (a folder assist did not write is never
    /// replaced).
    #[arg(long)]
    pub force: bool,
    /// Read flags from a TOML file (keys are the long flag names; flags on the command
    /// line win).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// How finely rays are sampled: `full` (as trained) or `draft` (half the samples per
    /// ray: steps twice as long, and half the samples a proposal draws; 0.5–0.8 of the
    /// time; measured PSNR cost 0.8–2.7 dB on real captures (gold_cape, fern, beer),
    /// 2.3–5.3 dB on object scenes (lego_400, desk)).
    #[arg(long, value_enum, default_value_t = Quality::Full)]
    pub quality: Quality,
    /// Print a JSON summary (views, folder, outputs) on stdout.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

pub(crate) fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--size: expected WxH such as 480x360, got {s:?}"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("--size: bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("--size: bad height in {s:?}"))?;
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        bail!("--size: expected 1..8192 per side, got {s:?}");
    }
    Ok((w, h))
}

/// The command line as a job.
fn job(a: &RenderArgs, select: Option<u16>) -> anyhow::Result<RenderJob> {
    let outputs = Output::parse_list(&a.outputs).map_err(|m| anyhow::anyhow!("--outputs: {m}"))?;
    let cameras = if a.cameras == "orbit" {
        let (width, height) = parse_size(&a.size)?;
        CameraSource::Orbit(Orbit {
            frames: a.frames,
            width,
            height,
            fov_deg: a.fov,
            elevation_deg: a.elevation,
            radius: a.radius,
        })
    } else {
        let split = SplitChoice::parse(&a.split).with_context(|| {
            format!(
                "--split: expected train, val, test, all or auto, got {:?}",
                a.split
            )
        })?;
        CameraSource::Dataset {
            path: PathBuf::from(&a.cameras),
            split,
            downscale: a.downscale,
        }
    };
    let highlight = match (a.no_highlight, select) {
        (true, _) => Highlight::None,
        (false, Some(id)) => Highlight::Node(id),
        (false, None) => Highlight::Selected,
    };
    Ok(RenderJob {
        cameras,
        output: DatasetOutput {
            out: a.out.clone(),
            outputs,
            highlight,
            force: a.force,
            quality: a.quality,
        },
    })
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    // Before anything is loaded: --force replaces only what assist wrote (the new dataset
    // is swapped in whole, never mixed with the old one's files).
    assist_fs::check_replaceable_as(&a.out, a.force, assist_fs::Kind::Dataset)?;
    let inputs: Vec<&std::path::Path> = std::iter::once(a.scene.as_path())
        .chain((a.cameras != "orbit").then(|| std::path::Path::new(a.cameras.as_str())))
        .collect();
    assist_fs::check_not_input(&a.out, &inputs)?;
    let mut session =
        Session::open(&a.scene).with_context(|| format!("loading scene {}", a.scene.display()))?;
    let device = a.device.open()?;
    session.set_backend(device.field_backend());
    let select = match &a.select {
        None => None,
        Some(t) => match t.trim().parse::<u16>() {
            Ok(id) => Some(id),
            // A name: found as an instruction finds it (candidates listed when unclear).
            Err(_) => {
                let mpu = session.description().meters_per_unit;
                let r = session
                    .resolve(&format!("select the {t}"), None)
                    .map_err(|e| anyhow::anyhow!("--select {t:?}: {e}"))?;
                r.edits.first().map(|e| e.to_action(mpu).instance_id)
            }
        },
    };
    let job = job(&a, select)?;
    let bar = crate::progress::bar(std::io::stderr().is_terminal(), "render");
    let done = session
        .run_render(&job, |v| {
            bar.set_length(v.total as u64);
            bar.set_position(v.index as u64 + 1);
        })
        .map_err(|e| match e {
            SessionError::Request { what, message } if what == "highlight" => {
                anyhow::anyhow!("--select: {message}")
            }
            other => other.into(),
        })?;
    bar.finish_and_clear();
    device.report();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "views": done.views,
                "out": done.out,
                "outputs": a.outputs.split(',').map(str::trim).collect::<Vec<_>>(),
                "highlight": select,
                "device": device.name(),
            }))?
        );
    } else {
        eprintln!("rendered {} views into {}", done.views, done.out.display());
    }
    Ok(())
}
