//! `TrainJob`: a dataset → a trained scene on disk. One typed configuration (defaults
//! declared here, once), the rules that turn it into training options (loss weights,
//! background prior, appearance, resume), progress as typed events, cancellation.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use assist_core::NodeSpace;
use assist_data::{Dataset, LoadOptions, Split};
use assist_scene::NeuralScene;
use assist_train::{
    CaptureLayout, WalkAroundDefaults, default_error_rays, default_prune_eps, load_views,
    scene_takes_walk_around_defaults,
};
use assist_train::{
    KeptHistory, ResumeState, SetupOptions, StepStats, TrainOptions, TrainReport, Trainer,
};
use assist_train::{background_color, build_scene, default_lr_end, default_proposal};
use serde::Serialize;

use crate::held_out::HeldOutSet;
pub use crate::held_out::{HeldOut, preview_path};
use crate::train_config::{Appearance, Shadows, TrainConfig, lambdas};
use crate::{Result, SessionError, request};

/// What a training job tells while it runs.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum TrainEvent {
    /// The dataset is read; its training images are being loaded.
    Loading { images: usize, data: PathBuf },
    /// A stage of the setup begins (seconds each on a large capture); its result follows.
    Stage { name: &'static str },
    /// The background prior: the share of object-covered pixels other views see.
    Prior { seen_share: f64 },
    /// Background priors read from a folder (`TrainConfig::prior_dir`).
    UserPrior {
        folder: assist_data::priors::PriorFolder,
    },
    /// Free space carved from the depth maps, per node (share of its grid cells).
    Carved { nodes: Vec<(String, f64)> },
    /// Objects learn their shadows: `objects` grids added; the background prior near them
    /// made shadow-free on `covered` pixels under objects and `seen` around them; the new
    /// grids' first estimate from `estimated` pixels ([`assist_train::estimate_shadows`]).
    Shadows {
        objects: usize,
        covered: usize,
        seen: usize,
        estimated: usize,
    },
    /// The views have no instance masks; `unused` are mask folders for other sizes.
    NoMasks { unused: Vec<PathBuf> },
    /// How the training cameras stand (`gap_degrees`: the largest azimuth gap around the
    /// point they look at) and whether the run takes the walk-around's defaults.
    Layout {
        layout: CaptureLayout,
        /// The layout was given (`--layout`), not read from the poses.
        given: bool,
        gap_degrees: Option<f64>,
        walk_around_defaults: bool,
    },
    /// The scene's nodes (id, label).
    Nodes { nodes: Vec<(u16, String)> },
    /// How the batches reach the objects (`--object-rays`; where there are object pixels).
    ObjectRays(assist_train::ObjectRays),
    /// One training step, with the share of the run done and the seconds left.
    Step {
        stats: Box<StepStats>,
        eta_seconds: Option<f64>,
        /// Share of each node's occupancy grid that is occupied (sent every few seconds).
        occupancy: Option<Vec<(String, f64)>>,
    },
    /// Held-out views measured (on the `eval_every` schedule, and at the end).
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
    pub(crate) cancel: Arc<AtomicBool>,
    /// A scene to train on instead of a new one, with the history it keeps (a split).
    start: Option<(NeuralScene, KeptHistory)>,
    /// Whether the scene records `config.masks` (false for a folder deleted after the
    /// run: a split's temporary masks).
    pub(crate) masks_recorded: bool,
    /// Makes the fields' optimizers elsewhere than on this CPU (a GPU: `--device`).
    optimizers: Option<Arc<dyn assist_train::OptimizerFactory>>,
}

impl TrainJob {
    pub fn new(config: TrainConfig) -> Self {
        TrainJob {
            config,
            cancel: Arc::new(AtomicBool::new(false)),
            start: None,
            masks_recorded: true,
            optimizers: None,
        }
    }

    /// Steps the fields with `factory`'s optimizers (a GPU's) instead of the CPU's.
    pub fn with_optimizers(mut self, factory: Arc<dyn assist_train::OptimizerFactory>) -> Self {
        self.optimizers = Some(factory);
        self
    }

    /// Trains `scene` (its nodes and fields as they are) instead of a new scene, saving
    /// it with `kept`'s history.
    pub fn starting_from(mut self, scene: NeuralScene, kept: KeptHistory) -> Self {
        self.start = Some((scene, kept));
        self
    }

    /// A handle that stops the run after the current step when set (the scene trained so
    /// far is saved).
    pub fn cancel_handle(&self) -> Arc<AtomicBool> {
        self.cancel.clone()
    }

    /// Checks the configuration before any work (see [`TrainConfig::validate`]).
    pub fn validate(&self) -> Result<()> {
        self.config.validate()
    }

    /// Loads, trains and saves, telling `on_event` as it goes.
    pub fn run(&self, mut on_event: impl FnMut(&TrainEvent)) -> Result<TrainOutcome> {
        self.validate()?;
        let c = &self.config;
        // Before any work: replace only what assist wrote, claim the output against a
        // second process (this also proves its folder writable) for the whole run.
        self.check_output()?;
        let _lock = assist_fs::lock(&c.out, &format!("assist train {}", c.data.display()))
            .map_err(SessionError::Output)?;
        let user_boxes = match &c.boxes {
            Some(p) => assist_data::boxes::read_boxes(p).map_err(SessionError::Data)?,
            None => Vec::new(),
        };
        let ds = self.dataset()?;
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
        let (resume, max_time) = self.resume_point(&fingerprint)?;
        // Free space from the dataset's metadata, before any image is read; again below
        // with the scene's real size.
        self.check_space(assist_train::scene_param_estimate(
            &ds,
            n_train,
            self.appearance(&ds),
        ))?;
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
        let layout = c.layout.resolve(&views);
        self.priors(&mut views, layout, &mut on_event);
        on_event(&TrainEvent::Stage {
            name: "nodes, and the free space views see through",
        });
        let (mut scene, kept) = self.scene(&ds, &views, user_boxes, layout)?;
        let walk_around = scene_takes_walk_around_defaults(layout, &scene);
        on_event(&self.layout_event(layout, &views, walk_around));
        self.check_space(scene.fields.values().map(|f| f.field.param_count()).sum())?;
        let carved = assist_train::carve_scene(&mut scene, &views);
        if !carved.is_empty() {
            on_event(&TrainEvent::Carved { nodes: carved });
        }
        // `--shadows auto` learns them where every view has depth.
        let depth = views.iter().all(|v| v.depth.is_some());
        let held_shadows = self.shadows(&mut scene, &mut views, depth, &mut on_event);
        let lambdas = lambdas(c, views.iter().any(|v| v.inpaint.is_some()), walk_around);
        // (Not with `--no-objects`: the masks were set aside on purpose.)
        if !c.resume
            && self.start.is_none()
            && !c.no_objects
            && views.iter().all(|v| v.ids.is_none())
        {
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
        let opts = self.options(max_time, depth_affine, lambdas, fingerprint, &scene, layout);
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
        let mut trainer = self.trainer(scene, views, opts, resume.as_ref())?;
        trainer.kept = kept;
        if let Some(o) = trainer.object_rays() {
            on_event(&TrainEvent::ObjectRays(o));
        }
        if c.shadows.resolve(depth) == Shadows::Fixed {
            // What the photographs show of each shadow stays as estimated, and what lies
            // nearer another object stays shadow-free; the rest (under the object) trains
            // with the scene.
            trainer.shade_held = held_shadows;
        }
        let mut last_occupancy = std::time::Instant::now();
        let mut last_eval = None;
        let report = trainer
            .run(|s, t| {
                if let (Some(every), Some(h)) = (c.eval_every, &held)
                    && every.due(s.iteration, s.elapsed, &mut last_eval)
                    && eval_error.is_none()
                {
                    match h.measure_during(t, s, &preview) {
                        Ok(m) => on_event(&TrainEvent::HeldOut(m)),
                        Err(e) => eval_error = Some(e),
                    }
                }
                let occupancy = (last_occupancy.elapsed().as_secs_f64() > 10.0).then(|| {
                    last_occupancy = std::time::Instant::now();
                    t.occupancy()
                });
                let eta_seconds = (s.progress > 1e-6)
                    .then(|| (s.elapsed * (1.0 - s.progress) / s.progress).max(0.0));
                on_event(&TrainEvent::Step {
                    stats: Box::new(*s),
                    eta_seconds,
                    occupancy,
                });
            })
            .map_err(|e| self.save_failed(e.into()))?;
        self.save(&mut trainer, report.seconds, &mut on_event)
            .map_err(|e| self.save_failed(e))?;
        if let Some(e) = eval_error {
            return Err(e);
        }
        let held_out = match &held {
            // With periodic checks, the preview shows the final scene too.
            Some(h) if !report.cancelled => Some(h.measure(
                &trainer.scene,
                report.iterations,
                report.seconds,
                c.eval_every.map(|_| preview.as_path()),
            )?),
            _ => None,
        };
        Ok(TrainOutcome {
            report,
            out: c.out.clone(),
            held_out,
        })
    }

    /// What the run tells of its cameras' layout.
    fn layout_event(
        &self,
        layout: CaptureLayout,
        views: &[assist_train::View],
        walk_around_defaults: bool,
    ) -> TrainEvent {
        TrainEvent::Layout {
            layout,
            given: self.config.layout != assist_train::LayoutChoice::Auto,
            gap_degrees: assist_train::azimuth_gap(views),
            walk_around_defaults,
        }
    }

    /// Ends a run: the key light looked for in the learned shadows, then the scene saved.
    fn save(
        &self,
        trainer: &mut Trainer,
        seconds: f64,
        on_event: &mut impl FnMut(&TrainEvent),
    ) -> Result<()> {
        if assist_render::casts_shadows(&trainer.scene) {
            on_event(&TrainEvent::Light(assist_train::estimate_light(
                &mut trainer.scene,
            )));
        }
        let out = &self.config.out;
        trainer
            .kept
            .save(out, &trainer.scene, trainer.info(seconds))?;
        on_event(&TrainEvent::Saved { path: out.clone() });
        Ok(())
    }

    /// A failed save (a full disk) says what stands in `--out` and how to go on from it.
    fn save_failed(&self, e: SessionError) -> SessionError {
        use assist_scene::SceneFileError::Save;
        let is_save = matches!(
            &e,
            SessionError::File(Save { .. })
                | SessionError::Train(assist_train::TrainError::Scene(Save { .. }))
        );
        if !is_save {
            return e;
        }
        let c = &self.config;
        let kept = assist_scene::scene_file::load_scene_json(&c.out)
            .ok()
            .and_then(|(_, info)| info.get("iteration").and_then(|i| i.as_u64()));
        let hint = match kept {
            Some(i) => format!(
                "the checkpoint in {} (iteration {i}) is intact: free some space, then continue it with `assist train {} --out {} --resume`",
                c.out.display(),
                c.data.display(),
                c.out.display()
            ),
            None => "no checkpoint was saved: free some space and train again".into(),
        };
        SessionError::SaveFailed(format!("{e}; {hint}"))
    }

    /// The trainer's options for this job's configuration.
    fn options(
        &self,
        max_time: Option<f64>,
        depth_affine: bool,
        lambdas: assist_train::Lambdas,
        fingerprint: String,
        scene: &NeuralScene,
        layout: CaptureLayout,
    ) -> TrainOptions {
        let c = &self.config;
        let walk_around = scene_takes_walk_around_defaults(layout, scene);
        // Left to the scene: the floor where it is unbounded; so are the pruning and the
        // proposal, but on the CPU only (a GPU queries every sample, and the density pass
        // and the proposal's training would run on this CPU).
        let unbounded = unbounded(scene);
        let unbounded_on_cpu = unbounded && self.optimizers.is_none();
        let lr_end = c.lr_end.unwrap_or(default_lr_end(unbounded));
        let prune_eps = c.prune_eps.unwrap_or(default_prune_eps(unbounded_on_cpu));
        let proposal = c.proposal.unwrap_or(default_proposal(unbounded_on_cpu));
        let error_rays = c.error_rays.unwrap_or(default_error_rays(unbounded));
        let grid_decay = c.grid_decay.unwrap_or(if walk_around {
            WalkAroundDefaults::GRID_DECAY
        } else {
            TrainOptions::default().grid_decay
        });
        TrainOptions {
            iters: c.iters_limit(),
            max_time,
            lr_start: c.lr_start,
            lr_end,
            batch_samples: c.batch_samples,
            object_ray_fraction: c.object_rays,
            downscale: c.downscale,
            depth_affine,
            refine_poses: c.refine_poses,
            grid_decay,
            error_rays,
            hidden_stop: c.hidden_stop,
            step_scale: c.step_scale,
            proposal_samples: proposal,
            prune_eps,
            lambdas,
            seed: c.seed,
            checkpoint: Some(c.out.clone()),
            checkpoint_every: c.checkpoint_every,
            poison_at: c.poison_at,
            cancel: Some(self.cancel.clone()),
            provenance: serde_json::Map::from_iter([
                // Recorded whole: a relative path would be read against whatever
                // folder a later command runs in.
                (
                    "dataset".to_string(),
                    std::path::absolute(&c.data)
                        .unwrap_or_else(|_| c.data.clone())
                        .display()
                        .to_string()
                        .into(),
                ),
                ("dataset_fingerprint".to_string(), fingerprint.into()),
                ("train_config".to_string(), {
                    let mut r = c.record();
                    // The floor, the pruning, the proposal and the error map's share the run
                    // used, where left to the scene.
                    r["lr_end"] = lr_end.into();
                    r["prune_eps"] = prune_eps.into();
                    r["proposal"] = proposal.into();
                    r["error_rays"] = error_rays.into();
                    r["layout"] = layout.as_str().into();
                    r["grid_decay"] = grid_decay.into();
                    r["grid_resolution"] = assist_train::background_grid_resolution(scene).into();
                    if !self.masks_recorded {
                        r["masks"] = serde_json::Value::Null;
                    }
                    r
                }),
            ]),
            ..Default::default()
        }
    }

    /// The output may be written: a new run replaces only a scene assist wrote (with
    /// `force`), never the dataset it reads.
    fn check_output(&self) -> Result<()> {
        let c = &self.config;
        if !c.resume {
            assist_fs::check_replaceable_as(&c.out, c.force, assist_fs::Kind::Scene)
                .map_err(SessionError::Output)?;
            assist_fs::check_not_input(&c.out, &[c.data.as_path()])
                .map_err(SessionError::Output)?;
        }
        Ok(())
    }

    /// The trainer of `scene`, with this job's optimizers, continuing `resume`.
    fn trainer(
        &self,
        scene: NeuralScene,
        views: Vec<assist_train::View>,
        opts: assist_train::TrainOptions,
        resume: Option<&ResumeState>,
    ) -> Result<Trainer> {
        let mut trainer = Trainer::new(scene, views, opts)?;
        if let Some(f) = &self.optimizers {
            trainer.use_optimizers(f.as_ref())?;
        }
        if let Some(r) = resume {
            trainer.resume_from(r);
        } else if self.start.is_some() {
            // A scene given to start from (a split's fine-tune) holds trained fields.
            trainer.warm_from = Some(trainer.iteration);
        }
        Ok(trainer)
    }

    /// Where a resumed run starts, and the run's time budget (a resumed run's counts from
    /// where it stopped); refused when the scene was trained on another dataset (unless
    /// `force`) or has no iterations left.
    fn resume_point(&self, fingerprint: &str) -> Result<(Option<ResumeState>, Option<f64>)> {
        let c = &self.config;
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
            if state.iteration >= c.iters_limit() {
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
        Ok((resume, max_time))
    }

    /// The dataset as this run reads it: downscaled, with the user's priors and masks,
    /// unlabelled with `--no-objects`.
    fn dataset(&self) -> Result<Dataset> {
        let c = &self.config;
        let load_opts = LoadOptions {
            downscale: c.downscale,
            prior_dir: c.prior_dir.clone(),
            masks: c.masks.clone(),
            ..Default::default()
        };
        let mut ds = assist_data::load(&c.data, &load_opts).map_err(SessionError::Data)?;
        if c.no_objects {
            ds.unlabel();
        }
        Ok(ds)
    }

    /// Whether the fields get per-image appearance codes (`auto`: for photographs, not
    /// rendered images; see [`Dataset::rendered`]).
    fn appearance(&self, ds: &Dataset) -> bool {
        match self.config.appearance {
            Appearance::On => true,
            Appearance::Off => false,
            Appearance::Auto => !ds.rendered,
        }
    }

    /// Fails unless the checkpoints of `params` field parameters fit in `--out`: the swap
    /// holds a new checkpoint beside the previous one for a moment, so a new output needs
    /// room for two and one that exists (a resumed run, `--force`) for one more.
    fn check_space(&self, params: usize) -> Result<()> {
        let copies = if self.config.out.exists() { 1 } else { 2 };
        assist_fs::check_space(&self.config.out, copies * 4 * params as u64 + (64 << 20))
            .map_err(SessionError::Output)
    }

    /// A new scene for the dataset, the one given to start from, or the one being
    /// resumed, with the history it keeps.
    fn scene(
        &self,
        ds: &Dataset,
        views: &[assist_train::View],
        boxes: Vec<assist_data::boxes::BoxOverride>,
        layout: CaptureLayout,
    ) -> Result<(NeuralScene, KeptHistory)> {
        let c = &self.config;
        if let Some((scene, kept)) = &self.start {
            return Ok((scene.clone(), kept.clone()));
        }
        if c.resume {
            let (mut scene, history, _) = assist_scene::scene_file::load_with_history(&c.out)?;
            let kept = KeptHistory::split_off(&mut scene, history);
            return Ok((scene, kept));
        }
        let so = SetupOptions {
            appearance: self.appearance(ds),
            seed: c.seed,
            boxes,
            background_space: c.background,
            reflect: c.reflect == crate::train_config::OnOff::On,
            grid_resolution: c.grid_resolution.unwrap_or_else(|| {
                assist_train::default_grid_resolution(layout, views, c.background)
            }),
            ..Default::default()
        };
        Ok((build_scene(ds, views, &so)?, KeptHistory::default()))
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

/// Whether a node of `scene` is unbounded (a contracted background).
fn unbounded(scene: &NeuralScene) -> bool {
    scene
        .fields
        .values()
        .any(|f| f.space == NodeSpace::Contracted)
}
