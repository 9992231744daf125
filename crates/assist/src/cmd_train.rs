//! `assist train DATA --out NAME.assist`: trains a compositional scene and saves it.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_session::{Appearance, LambdaOverrides, TrainConfig, TrainEvent, TrainJob};
use assist_train::BackgroundSpace;
use assist_train::PriorKind;
use assist_train::StopReason;
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A feature switched on or off.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    On,
    Off,
}

/// `--shadows`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Shadows {
    /// Estimated from the photographs, then trained with the scene.
    On,
    /// None: shadows stay on the background.
    Off,
    /// Estimated from the photographs and kept where they show it.
    Fixed,
}

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Dataset (any supported format: desk, nerfstudio, Blender, COLMAP, LLFF); also
    /// given as --data.
    #[arg(required_unless_present = "data_flag")]
    pub data: Option<PathBuf>,
    /// The dataset, as every other command takes it.
    #[arg(
        long = "data",
        id = "data_flag",
        value_name = "DATA",
        conflicts_with = "data"
    )]
    pub data_flag: Option<PathBuf>,
    /// Output scene directory (NAME.assist). Refused if it exists, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Iterations to train in all (a resumed run continues up to this count); --max-time
    /// may end the run first.
    #[arg(long, default_value_t = TrainConfig::default().iters)]
    pub iters: usize,
    /// Stop after this many seconds (the learning-rate schedule then runs on time). With
    /// --resume, this many seconds more than the scene was trained already.
    #[arg(long)]
    pub max_time: Option<f64>,
    /// Train on images N times smaller (from images_N/ folders beside the images where
    /// they exist, else reduced on loading); `eval` then defaults to the same.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Samples per training step (the ray count adapts).
    #[arg(long, default_value_t = TrainConfig::default().batch_samples)]
    pub batch_samples: usize,
    /// Share of each batch's rays drawn from pixels on or next to objects (the rest are
    /// drawn uniformly over all pixels), so that small objects get enough rays.
    #[arg(long, default_value_t = TrainConfig::default().object_rays)]
    pub object_rays: f64,
    /// Background prior under the objects: multi-view (from the other views that see it,
    /// where the dataset has depth; push-pull elsewhere), push-pull, exemplar, or none
    /// (none also sets λ1 = λ2 = 0).
    #[arg(long, default_value = "multi-view")]
    pub prior: String,
    /// Background priors made elsewhere (the paper's inpainting path): a folder with, per
    /// training image, that view with its objects inpainted (NAME.png or .jpg, the image's
    /// size), and optionally depth/NAME.npy (float32, any scale) or depth/NAME.png. They
    /// replace the built-in fill; images without one keep it.
    #[arg(long)]
    pub prior_dir: Option<PathBuf>,
    /// CLIP weights: after training, give each node a CLIP embedding (as `assist embed`)
    /// [default: $ASSIST_CLIP when set; without either, no embeddings].
    #[arg(long)]
    pub clip: Option<PathBuf>,
    /// λ1 of the paper: weight of the background's colour against its prior under the
    /// objects (0 with --prior none) [default: 0.5].
    #[arg(long, value_name = "W")]
    pub lambda_bg_rgb: Option<f32>,
    /// Weight of an opaque background behind its prior's depth (ours): where the prior has
    /// a depth, the background alone must be opaque past 95% of it, so that what objects
    /// hide is learnt as a surface at the prior's depth and not left transparent. It
    /// improves the background under the objects (what a moved object uncovers) but costs
    /// the unedited views ~1 dB, so it is off [default: 0].
    #[arg(long, value_name = "W")]
    pub lambda_bg_opacity: Option<f32>,
    /// λ2 of the paper: weight of the background's depth against the prior's depth (0
    /// with --prior none) [default: 0.1].
    #[arg(long, value_name = "W")]
    pub lambda_bg_depth: Option<f32>,
    /// λ3 of the paper: weight of each object's opacity against its instance mask
    /// [default: 0.1].
    #[arg(long, value_name = "W")]
    pub lambda_obj_acc: Option<f32>,
    /// λ4 of the paper: weight of each object's own colour inside its mask [default: 0.5].
    #[arg(long, value_name = "W")]
    pub lambda_obj_rgb: Option<f32>,
    /// Weight of the object-share term (ours, not the paper's; 0 gives the paper's loss)
    /// [default: 0.1].
    #[arg(long, value_name = "W")]
    pub lambda_obj_share: Option<f32>,
    /// Weight of the distortion loss (Nerfacto's; 0 turns it off) [default: 0].
    #[arg(long, value_name = "W")]
    pub lambda_distortion: Option<f32>,
    /// Weight of the empty-space term (ours, after Urban Radiance Fields' line-of-sight
    /// prior): where the dataset has depth, every node must be empty in front of the
    /// surface the depth map sees (no haze over a surface, which would cover the base of an
    /// object moved onto it) [default: 0].
    #[arg(long, value_name = "W")]
    pub lambda_empty: Option<f32>,
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
    /// Refine the training views' camera poses with the scene: each view learns a small
    /// translation and rotation (held-out views keep their poses) [default: off]
    #[arg(long)]
    pub refine_poses: bool,
    /// Learn each object's shadow on the background (fixed, on, off): the background then
    /// learns the surface without the objects, and a moved or deleted object takes its
    /// shadow along; `fixed` (the default) keeps each shadow where the photographs show it
    /// as estimated from them and trains only the rest (under the object) with the scene,
    /// `on` trains all of it. Only scenes with objects are affected.
    #[arg(long, value_enum, default_value_t = Shadows::Fixed)]
    pub shadows: Shadows,
    /// Start each object's shadow from the photographs (on, off): the darkening around it,
    /// photograph over the shadow-free prior, instead of no shadow.
    #[arg(long, value_enum, default_value_t = OnOff::On)]
    pub shadow_estimate: OnOff,
    /// What objects hide of the background learns only from the background's prior: its
    /// samples whose transmittance through the objects in front of them is below this get
    /// no gradient from the photographs (0 = off; a transmittance in [0, 1]).
    #[arg(long, value_name = "T", default_value_t = TrainConfig::default().hidden_stop)]
    pub hidden_stop: f32,
    /// Seed of every random draw (ray batches, initial weights): the same seed, data and
    /// flags give the same scene, bit for bit, on a machine with as many cores.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seconds between checkpoints (written atomically to --out).
    #[arg(long, default_value_t = TrainConfig::default().checkpoint_every)]
    pub checkpoint_every: f64,
    /// Continue training the scene in --out (from its last checkpoint). Refused when the
    /// dataset differs from the one it was trained on, unless --force.
    #[arg(long)]
    pub resume: bool,
    /// Replace --out if assist wrote it (a folder assist did not write is never replaced);
    /// with --resume, continue on a different dataset.
    #[arg(long)]
    pub force: bool,
    /// Measure held-out views (the dataset's test split, else val) every N iterations:
    /// their PSNR and SSIM go to the log, and the first view beside its render to
    /// NAME.preview.png beside --out. The time counts in the run's.
    #[arg(long, value_name = "N")]
    pub eval_every: Option<usize>,
    /// Held-out views measured, evenly spread over the split, during the run and at its
    /// end (0 = none).
    #[arg(long, value_name = "N", default_value_t = assist_session::DEFAULT_EVAL_VIEWS)]
    pub eval_views: usize,
    /// Write the training log to FILE as JSON Lines (one object per line: "kind" is
    /// "step" every --log-every iterations, "held_out" per evaluation, "end" once), to
    /// plot with pandas.read_json(FILE, lines=True). Refused if it exists, unless --force
    /// (or --resume, which appends).
    #[arg(long, value_name = "FILE")]
    pub log: Option<PathBuf>,
    /// Iterations between the log's "step" lines.
    #[arg(long, value_name = "N", default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..))]
    pub log_every: u64,
    /// Read flags from a TOML file (keys are the long flag names; flags on the command
    /// line win).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Print the whole configuration (every flag, defaults included) as TOML for
    /// --config, and exit.
    #[arg(long)]
    pub print_config: bool,
    /// Print one JSON object (the report) on stdout instead of text on stderr.
    #[arg(long)]
    pub json: bool,
    /// Testing aid: poison a parameter with NaN at this iteration.
    #[arg(long, hide = true)]
    pub poison_at: Option<usize>,
}

impl TrainArgs {
    /// The dataset, positional or --data.
    pub fn dataset(&self) -> &std::path::Path {
        self.data
            .as_deref()
            .or(self.data_flag.as_deref())
            .unwrap_or(std::path::Path::new(""))
    }

    /// The command line as a job configuration.
    pub fn config(&self) -> anyhow::Result<TrainConfig> {
        let background = BackgroundSpace::parse(&self.background).with_context(|| {
            format!(
                "--background: expected auto, box or contracted, got {:?}",
                self.background
            )
        })?;
        let prior = PriorKind::parse(&self.prior).with_context(|| {
            format!(
                "--prior: expected {}, got {:?}",
                PriorKind::NAMES,
                self.prior
            )
        })?;
        let appearance = Appearance::parse(&self.appearance).with_context(|| {
            format!(
                "--appearance: expected on, off or auto, got {:?}",
                self.appearance
            )
        })?;
        Ok(TrainConfig {
            data: self.dataset().to_path_buf(),
            out: self.out.clone(),
            iters: self.iters,
            max_time: self.max_time,
            downscale: self.downscale,
            batch_samples: self.batch_samples,
            object_rays: self.object_rays,
            prior,
            prior_dir: self.prior_dir.clone(),
            lambdas: LambdaOverrides {
                bg_rgb: self.lambda_bg_rgb,
                bg_opacity: self.lambda_bg_opacity,
                bg_depth: self.lambda_bg_depth,
                obj_acc: self.lambda_obj_acc,
                obj_rgb: self.lambda_obj_rgb,
                obj_share: self.lambda_obj_share,
                distortion: self.lambda_distortion,
                empty: self.lambda_empty,
            },
            boxes: self.boxes.clone(),
            appearance,
            background,
            refine_poses: self.refine_poses,
            shadows: self.shadows != Shadows::Off,
            shadows_fixed: self.shadows == Shadows::Fixed,
            shadow_estimate: self.shadow_estimate == OnOff::On,
            hidden_stop: self.hidden_stop,
            seed: self.seed,
            checkpoint_every: self.checkpoint_every,
            resume: self.resume,
            force: self.force,
            eval_every: self.eval_every,
            eval_views: self.eval_views,
            poison_at: self.poison_at,
        })
    }
}

/// Flag names for the fields a job's configuration errors name.
pub(crate) fn flag_error(e: assist_session::SessionError) -> anyhow::Error {
    match e {
        assist_session::SessionError::Request { what, message } => {
            let flag = match what.as_str() {
                "out" if message.contains("already exists") => {
                    return anyhow::anyhow!(
                        "{} (pass --force to replace it, or --resume to continue it)",
                        message.split(" (").next().unwrap_or(&message)
                    );
                }
                "data" => "DATA".to_string(),
                other => format!("--{}", other.replace('_', "-")),
            };
            anyhow::anyhow!("{flag}: {message}")
        }
        other => other.into(),
    }
}

/// The training log (`--log`): JSON Lines, flushed per line so a crashed run keeps what
/// it logged. The file is created at the first line, so a run refused before it starts
/// leaves none.
struct Log {
    file: Option<std::io::BufWriter<std::fs::File>>,
    path: PathBuf,
    append: bool,
    error: Option<std::io::Error>,
}

impl Log {
    fn new(path: &std::path::Path, append: bool, force: bool) -> anyhow::Result<Log> {
        if path.exists() && !append && !force {
            anyhow::bail!(
                "--log: {} already exists (pass --force to replace it; --resume appends to it)",
                path.display()
            );
        }
        Ok(Log {
            file: None,
            path: path.to_path_buf(),
            append,
            error: None,
        })
    }

    /// Appends one line (the first write error is kept and reported at the end).
    fn line(&mut self, v: serde_json::Value) {
        use std::io::Write;
        if self.error.is_some() {
            return;
        }
        if self.file.is_none() {
            match std::fs::OpenOptions::new()
                .create(true)
                .write(true)
                .append(self.append)
                .truncate(!self.append)
                .open(&self.path)
            {
                Ok(f) => self.file = Some(std::io::BufWriter::new(f)),
                Err(e) => {
                    self.error = Some(e);
                    return;
                }
            }
        }
        let Some(f) = self.file.as_mut() else { return };
        if let Err(e) = writeln!(f, "{v}").and_then(|_| f.flush()) {
            self.error = Some(e);
        }
    }
}

/// A step as a log line: losses, PSNR, speed, learning rate and phase times.
fn step_line(s: &assist_train::StepStats) -> serde_json::Value {
    let step_s = s.phase.total();
    let phases: serde_json::Map<String, serde_json::Value> = s.phase.named()[..6]
        .iter()
        .map(|(n, t)| (format!("{n}_ms"), (t * 1e3).into()))
        .collect();
    serde_json::json!({
        "kind": "step",
        "iteration": s.iteration,
        "elapsed": s.elapsed,
        "loss": s.loss,
        "psnr": s.psnr,
        "lr": s.lr,
        "rays": s.rays,
        "samples": s.samples,
        "rays_per_sec": if step_s > 0.0 { s.rays as f64 / step_s } else { 0.0 },
        "comp_rgb": s.comp_rgb,
        "bg_rgb": s.bg_rgb,
        "bg_opacity": s.bg_opacity,
        "bg_depth": s.bg_depth,
        "obj_acc": s.obj_acc,
        "obj_rgb": s.obj_rgb,
        "obj_share": s.obj_share,
        "distortion": s.distortion,
        "empty": s.empty,
        "phases": phases,
    })
}

/// A held-out measurement in words.
fn held_out_text(h: &assist_session::HeldOut) -> String {
    format!(
        "held-out PSNR {:.2} dB, SSIM {:.3} ({} {} view(s), {:.1} s)",
        h.psnr, h.ssim, h.views, h.split, h.seconds
    )
}

/// With CLIP weights (`--clip` or `ASSIST_CLIP`), each node's embedding, saved into the
/// trained scene; `None` without weights.
fn embed_after_training(
    a: &TrainArgs,
    out: &std::path::Path,
) -> anyhow::Result<Option<assist_session::EmbedSummary>> {
    let configured = std::env::var_os(assist_session::clip::ENV).is_some_and(|v| !v.is_empty());
    if a.clip.is_none() && !configured {
        return Ok(None);
    }
    let clip = crate::cmd_embed::load_clip(a.clip.as_deref())?;
    let mut session = assist_session::Session::open(out)
        .with_context(|| format!("loading the trained scene {}", out.display()))?;
    let mut job = assist_session::EmbedJob::new(a.dataset().to_path_buf());
    job.replace = true;
    job.load.downscale = a.downscale;
    let s = crate::cmd_embed::embed_session(&mut session, &clip, &job, a.json)?;
    session
        .save(out, true)
        .with_context(|| format!("saving {}", out.display()))?;
    Ok(Some(s))
}

pub fn run(a: TrainArgs) -> anyhow::Result<()> {
    let job = TrainJob::new(a.config()?);
    job.validate().map_err(flag_error)?;
    let mut log = match &a.log {
        Some(p) => Some(Log::new(p, a.resume, a.force)?),
        None => None,
    };
    // Ctrl+C or SIGTERM: stop after the current step and save; a second one quits at once.
    let cancel = job.cancel_handle();
    let _ = ctrlc::set_handler(move || {
        if cancel.swap(true, std::sync::atomic::Ordering::SeqCst) {
            eprintln!("\ninterrupted again: quitting without saving");
            std::process::exit(130);
        }
        eprintln!(
            "\ninterrupted: saving the scene trained so far (interrupt again to quit without saving)"
        );
    });
    let show = !a.json && std::io::stderr().is_terminal();
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
    let verbose = !a.json && !show;
    let text = !a.json;
    let data = a.dataset().display().to_string();
    let outcome = job.run(|ev| match ev {
        TrainEvent::Loading { images, data } if text => {
            eprintln!("loading {images} training images from {} …", data.display());
        }
        TrainEvent::UserPrior { folder } if text => {
            eprintln!(
                "background prior from {}: {} of {} training images ({} with depth){}",
                folder.folder.display(),
                folder.images,
                folder.train_frames,
                folder.depths,
                match folder.missing.first() {
                    Some(m) => format!(
                        "; {} (e.g. {m}) keep the built-in fill",
                        folder.missing.len()
                    ),
                    None => String::new(),
                }
            );
        }
        TrainEvent::Prior { seen_share } if text => eprintln!(
            "background prior: {:.0}% of the pixels objects cover are seen by other views, the rest filled by push-pull",
            100.0 * seen_share
        ),
        TrainEvent::Carved { nodes } if text => {
            let parts: Vec<String> = nodes
                .iter()
                .map(|(k, f)| format!("{k} {:.0}%", 100.0 * f))
                .collect();
            eprintln!("free space carved from the depth maps: {}", parts.join(", "));
        }
        TrainEvent::Shadows {
            objects,
            covered,
            seen,
            estimated,
        } if text => eprintln!(
            "shadows: {objects} object(s) learn their shadow, first estimated from {estimated} pixels; shadow-free background prior on {covered} pixels under objects and {seen} around them"
        ),
        TrainEvent::NoMasks { unused } if text => eprintln!(
            "no instance masks in {data} (an instance_mask_path per frame, or a masks/ folder beside the images): training the background only{}",
            if unused.is_empty() {
                String::new()
            } else {
                let u: Vec<String> = unused.iter().map(|p| p.display().to_string()).collect();
                format!(
                    "; {} hold masks for other image sizes (masks_N/ is used with --downscale N)",
                    u.join(", ")
                )
            }
        ),
        TrainEvent::Light(e) if text => eprintln!("{}", crate::cmd_scene::describe_light(e)),
        TrainEvent::Nodes { nodes } if text => {
            let n: Vec<String> = nodes.iter().map(|(id, l)| format!("{id} {l:?}")).collect();
            eprintln!("nodes: {}", n.join(", "));
        }
        TrainEvent::HeldOut(h) => {
            if let Some(l) = log.as_mut() {
                let mut v = serde_json::to_value(h).unwrap_or_default();
                v["kind"] = "held_out".into();
                l.line(v);
            }
            if text {
                let msg = format!(
                    "it {:>6}  {}{}",
                    h.iteration,
                    held_out_text(h),
                    h.preview
                        .as_ref()
                        .map(|p| format!("; preview {}", p.display()))
                        .unwrap_or_default()
                );
                if show {
                    bar.println(msg);
                } else {
                    eprintln!("{msg}");
                }
            }
        }
        TrainEvent::Step {
            stats: s,
            occupancy,
            ..
        } => {
            if let Some(l) = log.as_mut()
                && (s.iteration as u64).is_multiple_of(a.log_every)
            {
                l.line(step_line(s));
            }
            bar.set_position((s.progress * 1000.0) as u64);
            bar.set_message(format!(
                "it {} loss {:.5} psnr {:.2} rays {}",
                s.iteration, s.loss, s.psnr, s.rays
            ));
            if let Some(occupancy) = occupancy.as_ref().filter(|_| verbose) {
                let ms: Vec<String> = s.phase.named()[..6]
                    .iter()
                    .map(|(n, t)| format!("{n} {:.0}", t * 1e3))
                    .collect();
                eprintln!(
                    "it {:>6}  {:>5.1}s  loss {:.5}  psnr {:.2}  rays {}  samples {}  lr {:.2e}  ms per phase: {}",
                    s.iteration,
                    s.elapsed,
                    s.loss,
                    s.psnr,
                    s.rays,
                    s.samples,
                    s.lr,
                    ms.join(", ")
                );
                let occ: Vec<String> = occupancy
                    .iter()
                    .map(|(k, f)| format!("{k} {:.1}%", f * 100.0))
                    .collect();
                eprintln!(
                    "         pruned {} of {} samples; samples/ray {:.1?} terms: comp {:.5} bg_rgb {:.5} bg_opacity {:.5} bg_depth {:.5} obj_acc {:.5} obj_rgb {:.5} obj_share {:.5} dist {:.5} empty {:.5}; occupied: {}",
                    s.pruned,
                    s.candidates,
                    s.samples_per_ray,
                    s.comp_rgb,
                    s.bg_rgb,
                    s.bg_opacity,
                    s.bg_depth,
                    s.obj_acc,
                    s.obj_rgb,
                    s.obj_share,
                    s.distortion,
                    s.empty,
                    occ.join(", ")
                );
            }
        }
        _ => {}
    });
    bar.finish_and_clear();
    let outcome = outcome.map_err(flag_error)?;
    let report = &outcome.report;
    if let Some(mut l) = log.take() {
        l.line(serde_json::json!({
            "kind": "end",
            "iteration": report.iterations,
            "elapsed": report.seconds,
            "stopped_by": report.stopped_by,
            "psnr": report.final_stats.psnr,
            "held_out_psnr": outcome.held_out.as_ref().map(|h| h.psnr),
            "held_out_ssim": outcome.held_out.as_ref().map(|h| h.ssim),
        }));
        if let Some(e) = l.error {
            anyhow::bail!("--log: writing {} failed: {e}", l.path.display());
        }
    }
    if a.json {
        let mut v = serde_json::to_value(report)?;
        v["held_out"] = serde_json::to_value(&outcome.held_out)?;
        if !report.cancelled {
            v["embedding"] = serde_json::to_value(embed_after_training(&a, &outcome.out)?)?;
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if report.cancelled {
        eprintln!(
            "interrupted at iteration {} ({:.1} s): saved {}\ncontinue with: assist train {} --out {} --resume",
            report.iterations,
            report.seconds,
            outcome.out.display(),
            a.dataset().display(),
            outcome.out.display()
        );
    } else {
        let why = match report.stopped_by {
            StopReason::Iterations => format!("reached --iters {}", a.iters),
            StopReason::Time => format!(
                "--max-time {} s was spent before --iters {}",
                a.max_time.unwrap_or_default(),
                a.iters
            ),
            StopReason::Cancelled => "interrupted".to_string(),
        };
        eprintln!(
            "trained {} iterations in {:.1} s ({why}; {:.0} rays/s, {:.2} M samples/s)\nlast training batch PSNR {:.2} dB; {}\nsaved {}",
            report.iterations,
            report.seconds,
            report.rays_per_sec,
            report.samples_per_sec / 1e6,
            report.final_stats.psnr,
            match &outcome.held_out {
                Some(h) => held_out_text(h),
                None if a.eval_views == 0 => "held-out views not measured (--eval-views 0)".into(),
                None => "no held-out views (the dataset has no test or val split)".into(),
            },
            outcome.out.display()
        );
        let per_step = 1e3 / report.iterations.max(1) as f64;
        let parts: Vec<String> = report
            .phases
            .named()
            .iter()
            .map(|(n, t)| format!("{n} {:.1}", t * per_step))
            .collect();
        eprintln!("ms per step: {}", parts.join(", "));
    }
    if report.cancelled {
        // Saved, but not finished: scripts must not mistake it for a complete run.
        std::process::exit(130);
    }
    if !a.json
        && let Some(s) = embed_after_training(&a, &outcome.out)?
    {
        eprintln!(
            "embedded {} node(s) from {} crops in {:.1} s (CLIP {})",
            s.nodes.iter().filter(|n| n.crops > 0).count(),
            s.crops,
            s.seconds,
            s.model
        );
    }
    Ok(())
}
