//! `assist train DATA --out NAME.assist`: trains a compositional scene and saves it.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_data::{LoadOptions, Split};
use assist_train::setup::{BackgroundSpace, SetupOptions, background_color, build_scene};
use assist_train::trainer::Lambdas;
use assist_train::views::{fill_priors, load_views};
use assist_train::{PriorKind, TrainOptions, Trainer};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Dataset (any supported format).
    pub data: PathBuf,
    /// Output scene directory (NAME.assist). Refused if it exists, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 5000)]
    pub iters: usize,
    /// Stop after this many seconds (the learning-rate schedule then runs on time).
    #[arg(long)]
    pub max_time: Option<f64>,
    /// Train on images N times smaller (from images_N/ folders beside the images where
    /// they exist, else reduced on loading); `eval` then defaults to the same.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Samples per training step (the ray count adapts).
    #[arg(long, default_value_t = 1 << 16)]
    pub batch_samples: usize,
    /// Share of each batch's rays drawn from pixels on or next to objects (the rest are
    /// drawn uniformly over all pixels), so that small objects get enough rays.
    #[arg(long, default_value_t = TrainOptions::default().object_ray_fraction)]
    pub object_rays: f64,
    /// Background prior under the objects: multi-view (from the other views that see it,
    /// where the dataset has depth; push-pull elsewhere), push-pull, exemplar, or none
    /// (none also sets λ1 = λ2 = 0).
    #[arg(long, default_value = "multi-view")]
    pub prior: String,
    #[arg(long)]
    pub lambda_bg_rgb: Option<f32>,
    #[arg(long)]
    pub lambda_bg_depth: Option<f32>,
    #[arg(long)]
    pub lambda_obj_acc: Option<f32>,
    #[arg(long)]
    pub lambda_obj_rgb: Option<f32>,
    /// Weight of the object-share term (ours, not the paper's; 0 gives the paper's loss).
    #[arg(long)]
    pub lambda_obj_share: Option<f32>,
    /// Weight of the distortion loss (Nerfacto's; 0 turns it off).
    #[arg(long)]
    pub lambda_distortion: Option<f32>,
    /// Object boxes overriding the dataset's and the carved ones, used as given (a JSON file
    /// as `assist dataset boxes DATA --json` writes: {"instances": [{"id" or "label", "bbox":
    /// {"center", "size", "rotation"}}]}).
    #[arg(long)]
    pub boxes: Option<PathBuf>,
    /// Per-image appearance embeddings: on, off or auto (on for real captures: COLMAP, LLFF).
    #[arg(long, default_value = "auto")]
    pub appearance: String,
    /// The background node's space: contracted (a box kept linearly, all space beyond it
    /// contracted into a shell, for unbounded real captures), box, or auto (contracted
    /// unless the training views have depth maps, which bound the scene).
    #[arg(long, default_value = "auto")]
    pub background: String,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seconds between checkpoints (written atomically to --out).
    #[arg(long, default_value_t = 120.0)]
    pub checkpoint_every: f64,
    /// Continue training the scene in --out.
    #[arg(long)]
    pub resume: bool,
    #[arg(long)]
    pub force: bool,
    /// Print one JSON object (the report) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Testing aid: poison a parameter with NaN at this iteration.
    #[arg(long, hide = true)]
    pub poison_at: Option<usize>,
}

pub fn run(a: TrainArgs) -> anyhow::Result<()> {
    if a.out.exists() && !a.force && !a.resume {
        bail!(
            "{} already exists (pass --force to replace it, or --resume to continue it)",
            a.out.display()
        );
    }
    if !(0.0..=1.0).contains(&a.object_rays) {
        bail!(
            "--object-rays: expected a fraction between 0 and 1, got {}",
            a.object_rays
        );
    }
    let background_space = BackgroundSpace::parse(&a.background).with_context(|| {
        format!(
            "--background: expected auto, box or contracted, got {:?}",
            a.background
        )
    })?;
    let prior = PriorKind::parse(&a.prior).with_context(|| {
        format!(
            "--prior: expected multi-view, push-pull, exemplar or none, got {:?}",
            a.prior
        )
    })?;
    if a.resume && a.boxes.is_some() {
        bail!("--boxes cannot change the boxes of a scene being resumed (train anew with --force)");
    }
    let user_boxes = match &a.boxes {
        Some(p) => assist_data::boxes::read_boxes(p).context("--boxes")?,
        None => Vec::new(),
    };
    let load_opts = LoadOptions {
        downscale: a.downscale,
        ..Default::default()
    };
    let ds = assist_data::load(&a.data, &load_opts)
        .with_context(|| format!("loading dataset {}", a.data.display()))?;
    if ds.count(Split::Train) == 0 {
        bail!("{}: the dataset has no training frames", a.data.display());
    }
    let bgc = background_color(&ds);
    let show = !a.json && std::io::stderr().is_terminal();
    if !a.json {
        eprintln!(
            "loading {} training images from {} …",
            ds.count(Split::Train),
            a.data.display()
        );
    }
    let mut views = load_views(&ds, Split::Train, bgc)?;
    // A depth prior the user supplies (a monocular model's) has an unknown scale; one the
    // built-in fill makes from the dataset's depth is metric.
    let depth_affine = views.iter().any(|v| v.inpaint_depth.is_some());
    let mv = fill_priors(&mut views, prior);
    if let Some(mv) = mv
        && !a.json
        && mv.hole_pixels > 0
    {
        eprintln!(
            "background prior: {:.0}% of the pixels objects cover are seen by other views, the rest filled by push-pull",
            100.0 * mv.filled_pixels as f64 / mv.hole_pixels as f64
        );
    }
    let appearance = match a.appearance.as_str() {
        "on" => true,
        "off" => false,
        "auto" => matches!(
            ds.format,
            assist_data::Format::ColmapBinary
                | assist_data::Format::ColmapText
                | assist_data::Format::Llff
        ),
        o => bail!("--appearance: expected on, off or auto, got {o:?}"),
    };
    let (scene, resume_state) = if a.resume {
        let (scene, info) = assist_render::scene_file::load(&a.out)
            .with_context(|| format!("--resume: loading {}", a.out.display()))?;
        let it = info.get("iteration").and_then(|v| v.as_u64()).unwrap_or(0) as usize;
        let el = info
            .get("elapsed_seconds")
            .and_then(|v| v.as_f64())
            .unwrap_or(0.0);
        let wq = info
            .get("depth_scale_shift")
            .and_then(|v| serde_json::from_value::<[f32; 2]>(v.clone()).ok())
            .unwrap_or([1.0, 0.0]);
        (scene, Some((it, el, wq)))
    } else {
        let so = SetupOptions {
            appearance,
            seed: a.seed,
            boxes: user_boxes,
            background_space,
            ..Default::default()
        };
        (build_scene(&ds, &views, &so)?, None)
    };
    let mut scene = scene;
    let carved = assist_train::freespace::carve_scene(&mut scene, &views);
    if !a.json && !carved.is_empty() {
        let parts: Vec<String> = carved
            .iter()
            .map(|(k, f)| format!("{k} {:.0}%", 100.0 * f))
            .collect();
        eprintln!(
            "free space carved from the depth maps: {}",
            parts.join(", ")
        );
    }
    let mut lambdas = Lambdas::default();
    if prior == PriorKind::None && views.iter().all(|v| v.inpaint.is_none()) {
        lambdas.bg_rgb = 0.0;
        lambdas.bg_depth = 0.0;
    }
    if let Some(v) = a.lambda_bg_rgb {
        lambdas.bg_rgb = v;
    }
    if let Some(v) = a.lambda_bg_depth {
        lambdas.bg_depth = v;
    }
    if let Some(v) = a.lambda_obj_acc {
        lambdas.obj_acc = v;
    }
    if let Some(v) = a.lambda_obj_rgb {
        lambdas.obj_rgb = v;
    }
    if let Some(v) = a.lambda_obj_share {
        lambdas.obj_share = v;
    }
    if let Some(v) = a.lambda_distortion {
        lambdas.distortion = v;
    }
    let opts = TrainOptions {
        iters: a.iters,
        max_time: a.max_time,
        batch_samples: a.batch_samples,
        object_ray_fraction: a.object_rays,
        downscale: a.downscale,
        depth_affine,
        lambdas,
        seed: a.seed,
        checkpoint: Some(a.out.clone()),
        checkpoint_every: a.checkpoint_every,
        poison_at: a.poison_at,
        ..Default::default()
    };
    if !a.json && !a.resume && views.iter().all(|v| v.ids.is_none()) {
        let unused: Vec<String> = assist_data::masks::unused_mask_folders(&ds)
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        eprintln!(
            "no instance masks in {} (an instance_mask_path per frame, or a masks/ folder beside the images): training the background only{}",
            a.data.display(),
            if unused.is_empty() {
                String::new()
            } else {
                format!(
                    "; {} hold masks for other image sizes (masks_N/ is used with --downscale N)",
                    unused.join(", ")
                )
            }
        );
    }
    if !a.json {
        let nodes: Vec<String> = scene
            .scene
            .nodes
            .iter()
            .map(|n| format!("{} {:?}", n.id, n.label))
            .collect();
        eprintln!("nodes: {}", nodes.join(", "));
    }
    let mut trainer = Trainer::new(scene, views, opts)?;
    if let Some((it, el, wq)) = resume_state {
        trainer.resume_from(it, el, wq);
    }
    let bar = ProgressBar::new(1000);
    if !show {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template(
            "train [{bar:30}] {percent}% {elapsed_precise} ETA {eta} {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let mut last_log = std::time::Instant::now();
    let verbose = !a.json && !show;
    let report = trainer.run(|s, t| {
        bar.set_position((s.progress * 1000.0) as u64);
        bar.set_message(format!(
            "it {} loss {:.5} psnr {:.2} rays {}",
            s.iteration, s.loss, s.psnr, s.rays
        ));
        if verbose && last_log.elapsed().as_secs_f64() > 10.0 {
            eprintln!(
                "it {:>6}  {:>5.1}s  loss {:.5}  psnr {:.2}  rays {}  samples {}  lr {:.2e}  ms {:.0?}",
                s.iteration,
                s.elapsed,
                s.loss,
                s.psnr,
                s.rays,
                s.samples,
                s.lr,
                s.phase.map(|v| (v * 1e4).round() / 10.0)
            );
            let occ: Vec<String> = t
                .occupancy()
                .iter()
                .map(|(k, f)| format!("{k} {:.1}%", f * 100.0))
                .collect();
            eprintln!(
                "         pruned {} of {} samples; samples/ray {:.1?} terms: comp {:.5} bg_rgb {:.5} bg_depth {:.5} obj_acc {:.5} obj_rgb {:.5} obj_share {:.5} dist {:.5}; occupied: {}",
                s.pruned,
                s.candidates,
                s.samples_per_ray,
                s.comp_rgb,
                s.bg_rgb,
                s.bg_depth,
                s.obj_acc,
                s.obj_rgb,
                s.obj_share,
                s.distortion,
                occ.join(", ")
            );
            last_log = std::time::Instant::now();
        }
    });
    bar.finish_and_clear();
    let report = report?;
    assist_render::scene_file::save(&a.out, &trainer.scene, trainer.info(report.seconds), true)
        .with_context(|| format!("saving {}", a.out.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!(
            "trained {} iterations in {:.1} s ({:.0} rays/s, {:.2} M samples/s); last batch PSNR {:.2} dB\nsaved {}",
            report.iterations,
            report.seconds,
            report.rays_per_sec,
            report.samples_per_sec / 1e6,
            report.final_stats.psnr,
            a.out.display()
        );
        let names = [
            "sampling",
            "forward",
            "compositing",
            "backward",
            "adam",
            "occupancy",
            "other",
        ];
        let per_step = 1e3 / report.iterations.max(1) as f64;
        let parts: Vec<String> = names
            .iter()
            .zip(report.phase_seconds)
            .map(|(n, t)| format!("{n} {:.1}", t * per_step))
            .collect();
        eprintln!("ms per step: {}", parts.join(", "));
    }
    Ok(())
}
