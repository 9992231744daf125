//! `TrainJob`: a dataset → a trained scene on disk. One typed configuration (defaults
//! declared here, once), the rules that turn it into training options (loss weights,
//! background prior, appearance, resume), progress as typed events, cancellation.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use assist_data::{Dataset, LoadOptions, Split};
use assist_scene::NeuralScene;
use assist_train::{BackgroundSpace, SetupOptions, background_color, build_scene};
use assist_train::{Lambdas, ResumeState, StepStats};
use assist_train::{PriorKind, TrainOptions, TrainReport, Trainer};
use assist_train::{fill_priors, load_views};
use serde::{Deserialize, Serialize};

use crate::{Result, SessionError, request};

/// Per-image appearance embeddings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Appearance {
    /// On for real captures (COLMAP, LLFF), off for rendered ones.
    #[default]
    Auto,
    On,
    Off,
}

impl Appearance {
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "auto" => Appearance::Auto,
            "on" => Appearance::On,
            "off" => Appearance::Off,
            _ => return None,
        })
    }
}

/// Fewest samples a training step may take.
pub const MIN_BATCH_SAMPLES: usize = 1 << 10;
/// Most samples a training step may take (2²⁴: about 2 GB of activations).
pub const MAX_BATCH_SAMPLES: usize = 1 << 24;

/// Loss weights the user sets; `None` keeps the rule's value (see [`Lambdas`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct LambdaOverrides {
    pub bg_rgb: Option<f32>,
    pub bg_opacity: Option<f32>,
    pub bg_depth: Option<f32>,
    pub obj_acc: Option<f32>,
    pub obj_rgb: Option<f32>,
    pub obj_share: Option<f32>,
    pub distortion: Option<f32>,
    pub empty: Option<f32>,
}

/// Everything a training run is configured with. `data` and `out` have no default; every
/// other field's default is the one `assist train` uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainConfig {
    /// The dataset (any supported format).
    pub data: PathBuf,
    /// The scene directory written (`NAME.assist`).
    pub out: PathBuf,
    pub iters: usize,
    /// Stop after this many seconds (the learning-rate schedule then runs on time).
    pub max_time: Option<f64>,
    /// Train on images this many times smaller.
    pub downscale: u32,
    /// Samples per training step (the ray count adapts).
    pub batch_samples: usize,
    /// Share of each batch's rays drawn from pixels on or next to objects.
    pub object_rays: f64,
    /// Background prior under the objects (`None` also sets λ1 = λ2 = 0 when the dataset
    /// supplies no inpainted images).
    pub prior: PriorKind,
    /// Background priors made elsewhere: per training image, the view inpainted without
    /// its objects, and optionally its depth (see [`assist_data::priors`]). They replace
    /// the built-in fill where present.
    pub prior_dir: Option<PathBuf>,
    pub lambdas: LambdaOverrides,
    /// Object boxes overriding the dataset's and the carved ones.
    pub boxes: Option<PathBuf>,
    pub appearance: Appearance,
    pub background: BackgroundSpace,
    /// Learn a pose correction for every training view with the scene (see
    /// [`assist_train::PoseRefiner`]).
    pub refine_poses: bool,
    /// Learn each object's shadow on the background (see [`assist_train::shadow`]), so
    /// the background learns the surface without the objects and an edited object takes
    /// its shadow along. Only scenes with objects are affected.
    pub shadows: bool,
    /// Start each new shadow grid from the photographs' darkening around its object
    /// ([`assist_train::estimate_shadows`]) instead of from no shadow.
    pub shadow_estimate: bool,
    /// The shadow grids keep the values they start from (the estimate) instead of training
    /// with the scene.
    pub shadows_fixed: bool,
    /// What objects hide of the background learns only from its prior (see
    /// [`TrainOptions::hidden_stop`]; 0 = off).
    pub hidden_stop: f32,
    pub seed: u64,
    /// Seconds between checkpoints written to `out`.
    pub checkpoint_every: f64,
    /// Continue training the scene in `out`.
    pub resume: bool,
    /// Replace `out` if it exists.
    pub force: bool,
    /// Measure held-out views (the test split, else val) every this many iterations,
    /// writing a preview image beside `out` (see [`preview_path`]).
    pub eval_every: Option<usize>,
    /// Held-out views measured, evenly spread over the split (0 = none, not even at the
    /// end of the run).
    pub eval_views: usize,
    /// Testing aid: poison a parameter with NaN at this iteration.
    #[serde(skip)]
    pub poison_at: Option<usize>,
}

/// Held-out views measured during and after training.
pub const DEFAULT_EVAL_VIEWS: usize = 4;

/// Where periodic held-out evaluations leave their preview: beside the scene,
/// `NAME.preview.png` for `NAME.assist`.
pub fn preview_path(out: &std::path::Path) -> PathBuf {
    out.with_extension("preview.png")
}

/// How the scene does on views it did not train on.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOut {
    pub iteration: usize,
    /// Training seconds when measured.
    pub elapsed: f64,
    /// The split the views come from (test, else val).
    pub split: String,
    pub views: usize,
    /// Mean of per-view PSNR (dB) and SSIM.
    pub psnr: f64,
    pub ssim: f64,
    /// Seconds the measurement took (counted in the run's time).
    pub seconds: f64,
    /// The first view, ground truth left and render right (periodic evaluations).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preview: Option<PathBuf>,
}

/// The held-out views of a run, loaded once.
struct HeldOutSet {
    split: Split,
    views: Vec<(assist_core::Camera, assist_train::View)>,
}

impl HeldOutSet {
    /// Up to `n` views of the test split (else val), evenly spread; `None` without one.
    fn load(ds: &Dataset, n: usize) -> Result<Option<HeldOutSet>> {
        if n == 0 {
            return Ok(None);
        }
        let bg = background_color(ds);
        for split in [Split::Test, Split::Val] {
            let frames: Vec<_> = ds.frames_in(split).collect();
            if frames.is_empty() {
                continue;
            }
            let k = n.min(frames.len());
            let mut views = Vec::with_capacity(k);
            for i in 0..k {
                let f = frames[i * frames.len() / k];
                let v = assist_train::load_view(f, u32::MAX, bg)?;
                views.push((f.camera, v));
            }
            return Ok(Some(HeldOutSet { split, views }));
        }
        Ok(None)
    }

    /// Renders the views with `scene` (the average appearance) and scores them; with
    /// `preview`, writes the first view beside its render there.
    fn measure(
        &self,
        scene: &NeuralScene,
        iteration: usize,
        elapsed: f64,
        preview: Option<&std::path::Path>,
    ) -> Result<HeldOut> {
        use assist_train::metrics::{psnr, ssim};
        let t0 = std::time::Instant::now();
        let opts = assist_render::RenderOptions::default();
        let (mut p, mut q) = (0.0, 0.0);
        let mut first = None;
        for (cam, v) in &self.views {
            let img = assist_render::render_camera(scene, cam, u32::MAX, &opts);
            let rgb: Vec<f32> = img.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect();
            p += psnr(&rgb, &v.rgb, 3, None)
                .unwrap_or(f64::INFINITY)
                .min(100.0);
            q += ssim(&rgb, &v.rgb, v.width, v.height, 3);
            if first.is_none() {
                first = Some(rgb);
            }
        }
        let n = self.views.len().max(1) as f64;
        let mut written = None;
        if let (Some(path), Some(rgb), Some((_, v))) = (preview, &first, self.views.first()) {
            let (w, h) = (v.width, v.height);
            let mut side = vec![0u8; 2 * w * h * 3];
            let to8 = |x: f32| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        let i = 3 * (y * w + x) + c;
                        side[3 * (y * 2 * w + x) + c] = to8(v.rgb[i]);
                        side[3 * (y * 2 * w + w + x) + c] = to8(rgb[i]);
                    }
                }
            }
            assist_data::image_io::write_rgb8_png(path, 2 * w as u32, h as u32, &side)
                .map_err(SessionError::Data)?;
            written = Some(path.to_path_buf());
        }
        Ok(HeldOut {
            iteration,
            elapsed,
            split: self.split.name().to_string(),
            views: self.views.len(),
            psnr: p / n,
            ssim: q / n,
            seconds: t0.elapsed().as_secs_f64(),
            preview: written,
        })
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        let t = TrainOptions::default();
        TrainConfig {
            data: PathBuf::new(),
            out: PathBuf::new(),
            iters: t.iters,
            max_time: t.max_time,
            downscale: 1,
            batch_samples: t.batch_samples,
            object_rays: t.object_ray_fraction,
            prior: PriorKind::default(),
            prior_dir: None,
            lambdas: LambdaOverrides::default(),
            boxes: None,
            appearance: Appearance::Auto,
            background: BackgroundSpace::Auto,
            refine_poses: false,
            shadows: true,
            shadow_estimate: true,
            shadows_fixed: true,
            hidden_stop: t.hidden_stop,
            seed: 0,
            checkpoint_every: 120.0,
            resume: false,
            force: false,
            eval_every: None,
            eval_views: DEFAULT_EVAL_VIEWS,
            poison_at: None,
        }
    }
}

/// What a training job tells while it runs.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TrainEvent {
    /// The dataset is read; its training images are being loaded.
    Loading { images: usize, data: PathBuf },
    /// The background prior: the share of object-covered pixels other views see.
    Prior { seen_share: f64 },
    /// Background priors read from a folder (`TrainConfig::prior_dir`).
    UserPrior {
        folder: assist_data::priors::PriorFolder,
    },
    /// Free space carved from the depth maps, per node (share of its grid cells).
    Carved { nodes: Vec<(String, f64)> },
    /// Objects learn their shadows: `objects` shadow grids were added; the background
    /// prior near them was made shadow-free on `covered` pixels under objects and `seen`
    /// pixels around them; `estimated` photograph pixels gave the new grids their first
    /// estimate ([`assist_train::estimate_shadows`]).
    Shadows {
        objects: usize,
        covered: usize,
        seen: usize,
        estimated: usize,
    },
    /// The views have no instance masks; `unused` are mask folders for other sizes.
    NoMasks { unused: Vec<PathBuf> },
    /// The scene's nodes (id, label).
    Nodes { nodes: Vec<(u16, String)> },
    /// One training step, with the share of the run done and the seconds left.
    Step {
        stats: Box<StepStats>,
        eta_seconds: Option<f64>,
        /// Share of each node's occupancy grid that is occupied (sent every few seconds).
        occupancy: Option<Vec<(String, f64)>>,
    },
    /// Held-out views measured (every `eval_every` iterations).
    HeldOut(HeldOut),
    /// The key light was looked for in the learned shadows
    /// ([`assist_train::estimate_light`]); moved objects' shadows are re-cast under it when
    /// one was found.
    Light(assist_train::LightEstimate),
    /// The scene is saved.
    Saved { path: PathBuf },
}

/// A finished training job.
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub report: TrainReport,
    pub out: PathBuf,
    /// The held-out views measured at the end (none without a test or val split, with
    /// `eval_views` 0, or when the run was interrupted).
    pub held_out: Option<HeldOut>,
}

/// A training run to do.
pub struct TrainJob {
    pub config: TrainConfig,
    cancel: Arc<AtomicBool>,
}

impl TrainJob {
    pub fn new(config: TrainConfig) -> Self {
        TrainJob {
            config,
            cancel: Arc::new(AtomicBool::new(false)),
        }
    }

    /// A handle that stops the run after the current step when set (the scene trained so
    /// far is saved).
    pub fn cancel_handle(&self) -> Arc<AtomicBool> {
        self.cancel.clone()
    }

    /// Checks the configuration without reading the dataset.
    pub fn validate(&self) -> Result<()> {
        let c = &self.config;
        if c.data.as_os_str().is_empty() {
            return Err(request("data", "expected a dataset path".into()));
        }
        if c.out.as_os_str().is_empty() {
            return Err(request("out", "expected a scene path to write".into()));
        }
        if c.out.exists() && !c.force && !c.resume {
            return Err(request(
                "out",
                format!(
                    "{} already exists (replace it with force, or continue it with resume)",
                    c.out.display()
                ),
            ));
        }
        if !(MIN_BATCH_SAMPLES..=MAX_BATCH_SAMPLES).contains(&c.batch_samples) {
            return Err(request(
                "batch_samples",
                format!(
                    "expected {MIN_BATCH_SAMPLES} to {MAX_BATCH_SAMPLES}, got {}",
                    c.batch_samples
                ),
            ));
        }
        if let Some(t) = c.max_time
            && !(t.is_finite() && t > 0.0)
        {
            return Err(request(
                "max_time",
                format!("expected a positive number of seconds, got {t}"),
            ));
        }
        if c.eval_every == Some(0) {
            return Err(request(
                "eval_every",
                "expected at least 1 iteration between evaluations".into(),
            ));
        }
        if c.eval_every.is_some() && c.eval_views == 0 {
            return Err(request(
                "eval_views",
                "expected at least 1 view to evaluate every eval_every iterations".into(),
            ));
        }
        if !(0.0..=1.0).contains(&c.object_rays) {
            return Err(request(
                "object_rays",
                format!("expected a fraction between 0 and 1, got {}", c.object_rays),
            ));
        }
        if !(0.0..=1.0).contains(&c.hidden_stop) {
            return Err(request(
                "hidden_stop",
                format!(
                    "expected a transmittance between 0 and 1 (0 = off), got {}",
                    c.hidden_stop
                ),
            ));
        }
        let o = &c.lambdas;
        for (name, v) in [
            ("lambda_bg_rgb", o.bg_rgb),
            ("lambda_bg_opacity", o.bg_opacity),
            ("lambda_bg_depth", o.bg_depth),
            ("lambda_obj_acc", o.obj_acc),
            ("lambda_obj_rgb", o.obj_rgb),
            ("lambda_obj_share", o.obj_share),
            ("lambda_distortion", o.distortion),
            ("lambda_empty", o.empty),
        ] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(request(
                    name,
                    format!("expected a finite weight of 0 or more (0 = off), got {v}"),
                ));
            }
        }
        if c.resume && c.boxes.is_some() {
            return Err(request(
                "boxes",
                "cannot change the boxes of a scene being resumed (train anew instead)".into(),
            ));
        }
        if !(1..=64).contains(&c.downscale) {
            return Err(request(
                "downscale",
                format!("expected 1 to 64, got {}", c.downscale),
            ));
        }
        Ok(())
    }

    /// Loads, trains and saves, telling `on_event` as it goes.
    pub fn run(&self, mut on_event: impl FnMut(&TrainEvent)) -> Result<TrainOutcome> {
        self.validate()?;
        let c = &self.config;
        // Before any work: replace only what assist wrote, claim the output against a
        // second process (this also proves its folder writable) for the whole run.
        if !c.resume {
            assist_fs::check_replaceable(&c.out, c.force).map_err(SessionError::Output)?;
        }
        let _lock = assist_fs::lock(&c.out, &format!("assist train {}", c.data.display()))
            .map_err(SessionError::Output)?;
        let user_boxes = match &c.boxes {
            Some(p) => assist_data::boxes::read_boxes(p).map_err(SessionError::Data)?,
            None => Vec::new(),
        };
        let load_opts = LoadOptions {
            downscale: c.downscale,
            prior_dir: c.prior_dir.clone(),
            ..Default::default()
        };
        let ds = assist_data::load(&c.data, &load_opts).map_err(SessionError::Data)?;
        let n_train = ds.count(Split::Train);
        if n_train == 0 {
            return Err(request(
                "data",
                format!("{}: the dataset has no training frames", c.data.display()),
            ));
        }
        // A resumed run: the same dataset, iterations left, and more time (checked before
        // the images are read).
        let fingerprint = ds.fingerprint();
        let mut max_time = c.max_time;
        let mut resume = None;
        if c.resume {
            let (_, info) = assist_scene::scene_file::load_scene_json(&c.out)?;
            let state = resume_state(&c.out, &info)?;
            resume = Some(state.clone());
            let before = info.get("dataset_fingerprint").and_then(|v| v.as_str());
            if let Some(before) = before.filter(|b| *b != fingerprint)
                && !c.force
            {
                return Err(request(
                    "resume",
                    format!(
                        "{} was trained on another dataset ({}, fingerprint {before}); {} has fingerprint {fingerprint} (other frames or poses). Pass --force to continue on it anyway",
                        c.out.display(),
                        info.get("dataset")
                            .and_then(|v| v.as_str())
                            .unwrap_or("path not recorded"),
                        c.data.display()
                    ),
                ));
            }
            if state.iteration >= c.iters {
                return Err(request(
                    "iters",
                    format!(
                        "{} has already trained {} iterations; a resumed run continues up to --iters (raise it to train more)",
                        c.out.display(),
                        state.iteration
                    ),
                ));
            }
            // A resumed run's time budget is additional: it counts from where it stopped.
            max_time = max_time.map(|t| state.elapsed_seconds + t);
        }
        on_event(&TrainEvent::Loading {
            images: n_train,
            data: c.data.clone(),
        });
        if let Some(folder) = &ds.prior_folder {
            on_event(&TrainEvent::UserPrior {
                folder: folder.clone(),
            });
        }
        let mut views = load_views(&ds, Split::Train, background_color(&ds))?;
        // A depth prior the user supplies (a monocular model's) has an unknown scale; one
        // the built-in fill makes from the dataset's depth is metric.
        let depth_affine = views.iter().any(|v| v.inpaint_depth.is_some());
        if let Some(mv) = fill_priors(&mut views, c.prior)
            && mv.hole_pixels > 0
        {
            on_event(&TrainEvent::Prior {
                seen_share: mv.filled_pixels as f64 / mv.hole_pixels as f64,
            });
        }
        let mut scene = self.scene(&ds, &views, user_boxes)?;
        // Room for a checkpoint beside the previous one (the swap holds both for a moment).
        let bytes: usize = scene
            .fields
            .values()
            .map(|f| 4 * f.field.param_count())
            .sum();
        assist_fs::check_space(&c.out, 2 * bytes as u64 + (64 << 20))
            .map_err(SessionError::Output)?;
        let carved = assist_train::carve_scene(&mut scene, &views);
        if !carved.is_empty() {
            on_event(&TrainEvent::Carved { nodes: carved });
        }
        // Objects learn their shadows (a resumed scene's grids train on whatever the flag).
        let objects = if c.shadows {
            assist_train::add_shadow_grids(&mut scene)
        } else {
            0
        };
        let st = assist_train::shadow_free_priors(&scene, &mut views);
        // New grids start from the photographs' darkening (trained ones are left as they are).
        let est = if c.shadows && (c.shadow_estimate || c.shadows_fixed) {
            assist_train::estimate_shadows(&mut scene, &views)
        } else {
            assist_train::ShadowEstimate::default()
        };
        if objects > 0 || st.views > 0 {
            on_event(&TrainEvent::Shadows {
                objects,
                covered: st.covered,
                seen: st.seen,
                estimated: est.pixels,
            });
        }
        let held_shadows = est.held;
        let lambdas = lambdas(c, views.iter().any(|v| v.inpaint.is_some()));
        if !c.resume && views.iter().all(|v| v.ids.is_none()) {
            on_event(&TrainEvent::NoMasks {
                unused: assist_data::masks::unused_mask_folders(&ds),
            });
        }
        on_event(&TrainEvent::Nodes {
            nodes: scene
                .scene
                .nodes
                .iter()
                .map(|n| (n.id, n.label.clone()))
                .collect(),
        });
        let opts = TrainOptions {
            iters: c.iters,
            max_time,
            batch_samples: c.batch_samples,
            object_ray_fraction: c.object_rays,
            downscale: c.downscale,
            depth_affine,
            refine_poses: c.refine_poses,
            hidden_stop: c.hidden_stop,
            lambdas,
            seed: c.seed,
            checkpoint: Some(c.out.clone()),
            checkpoint_every: c.checkpoint_every,
            poison_at: c.poison_at,
            cancel: Some(self.cancel.clone()),
            provenance: serde_json::Map::from_iter([
                ("dataset".to_string(), c.data.display().to_string().into()),
                ("dataset_fingerprint".to_string(), fingerprint.into()),
            ]),
            ..Default::default()
        };
        let held = HeldOutSet::load(&ds, c.eval_views)?;
        if c.eval_every.is_some() && held.is_none() {
            return Err(request(
                "eval_every",
                format!(
                    "{} has no held-out views (no test or val split) to evaluate",
                    c.data.display()
                ),
            ));
        }
        let preview = preview_path(&c.out);
        let mut eval_error = None;
        let mut trainer = Trainer::new(scene, views, opts)?;
        if c.shadows_fixed {
            // What the photographs show of each shadow stays as estimated, and what lies
            // nearer another object stays shadow-free; the rest (under the object) trains
            // with the scene.
            trainer.shade_held = held_shadows;
        }
        if let Some(r) = &resume {
            trainer.resume_from(r);
        }
        let mut last_occupancy = std::time::Instant::now();
        let report = trainer.run(|s, t| {
            if let (Some(every), Some(h)) = (c.eval_every, &held)
                && s.iteration % every == 0
                && eval_error.is_none()
            {
                match h.measure(&t.scene, s.iteration, s.elapsed, Some(&preview)) {
                    Ok(m) => on_event(&TrainEvent::HeldOut(m)),
                    Err(e) => eval_error = Some(e),
                }
            }
            let occupancy = (last_occupancy.elapsed().as_secs_f64() > 10.0).then(|| {
                last_occupancy = std::time::Instant::now();
                t.occupancy()
            });
            let eta_seconds =
                (s.progress > 1e-6).then(|| (s.elapsed * (1.0 - s.progress) / s.progress).max(0.0));
            on_event(&TrainEvent::Step {
                stats: Box::new(*s),
                eta_seconds,
                occupancy,
            });
        })?;
        if assist_render::casts_shadows(&trainer.scene) {
            on_event(&TrainEvent::Light(assist_train::estimate_light(
                &mut trainer.scene,
            )));
        }
        assist_scene::scene_file::save(&c.out, &trainer.scene, trainer.info(report.seconds), true)?;
        on_event(&TrainEvent::Saved {
            path: c.out.clone(),
        });
        if let Some(e) = eval_error {
            return Err(e);
        }
        let held_out = match &held {
            Some(h) if !report.cancelled => {
                Some(h.measure(&trainer.scene, report.iterations, report.seconds, None)?)
            }
            _ => None,
        };
        Ok(TrainOutcome {
            report,
            out: c.out.clone(),
            held_out,
        })
    }

    /// A new scene for the dataset, or the one being resumed.
    fn scene(
        &self,
        ds: &Dataset,
        views: &[assist_train::View],
        boxes: Vec<assist_data::boxes::BoxOverride>,
    ) -> Result<NeuralScene> {
        let c = &self.config;
        if c.resume {
            return Ok(assist_scene::scene_file::load(&c.out)?.0);
        }
        let appearance = match c.appearance {
            Appearance::On => true,
            Appearance::Off => false,
            Appearance::Auto => matches!(
                ds.format,
                assist_data::Format::ColmapBinary
                    | assist_data::Format::ColmapText
                    | assist_data::Format::Llff
            ),
        };
        let so = SetupOptions {
            appearance,
            seed: c.seed,
            boxes,
            background_space: c.background,
            ..Default::default()
        };
        Ok(build_scene(ds, views, &so)?)
    }
}

/// Where a saved run stands, from its scene file's `info` (errors name the file).
fn resume_state(out: &std::path::Path, info: &serde_json::Value) -> Result<ResumeState> {
    ResumeState::from_info(info).map_err(|m| {
        request(
            "resume",
            format!("{}: {m}", out.join("scene.json").display()),
        )
    })
}

/// The loss weights of a run: the defaults, the background-prior terms off when there is
/// no prior at all, then the user's values.
pub fn lambdas(c: &TrainConfig, dataset_inpaint: bool) -> Lambdas {
    let mut l = Lambdas::default();
    if c.prior == PriorKind::None && !dataset_inpaint {
        l.bg_rgb = 0.0;
        l.bg_depth = 0.0;
    }
    let o = &c.lambdas;
    for (slot, v) in [
        (&mut l.bg_rgb, o.bg_rgb),
        (&mut l.bg_opacity, o.bg_opacity),
        (&mut l.bg_depth, o.bg_depth),
        (&mut l.obj_acc, o.obj_acc),
        (&mut l.obj_rgb, o.obj_rgb),
        (&mut l.obj_share, o.obj_share),
        (&mut l.distortion, o.distortion),
        (&mut l.empty, o.empty),
    ] {
        if let Some(v) = v {
            *slot = v;
        }
    }
    l
}
