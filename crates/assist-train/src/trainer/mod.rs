//! The training loop (paper §III-C): random rays over the training images, compositional
//! rendering, the loss as the weighted sum of the terms in [`TERMS`] (the paper's five,
//! and ours, each with its weight), backward into every node's field, Adam with a learning
//! rate decaying exponentially over the run, occupancy-grid updates, periodic atomic
//! checkpoints, and divergence detection (a NaN loss stops training; the last good
//! checkpoint is kept).
//!
//! Each term is defined once, with its gradient, in [`crate::losses`]. Two depart from
//! the paper's text: a node's colour terms (`L_bg_rgb`, `L_obj_rgb`) compare its
//! composited colour with the target scaled by its own opacity
//! ([`losses::premultiplied_rgb`]), and a depth prior of known scale (the dataset's own
//! depth) is met by the whole weight distribution, not only its mean
//! ([`losses::depth_moment`]); a prior of unknown scale (a monocular model's, supplied by
//! the user) keeps the paper's squared error of the mean depth under a learnable affine
//! map. Both are measured in BENCHMARKS.md.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use crate::optimizer::{CpuOptimizer, NodeOptimizer};
use assist_core::Rng;
use assist_field::{Adam, Tape};
use assist_render::{BatchOutput, RayBatch, Traced};
use assist_scene::NeuralScene;
use rayon::prelude::*;

use crate::error::{Result, TrainError};
use crate::views::View;

mod error_map;
mod normals;
mod objective;
mod options;
mod poses;
mod proposal;
mod rays;
mod step;
mod terms;

pub use options::{
    EMPTY_MARGIN, KeptHistory, ObjectRays, PhaseTimes, ResumeState, StepStats, StopReason,
    TrainOptions, TrainReport, default_error_rays, default_lr_end, default_proposal,
    default_prune_eps, object_ray_draw,
};
pub use poses::{POSE_EVERY, POSE_LR, PoseRefiner, scene_extent};
use rays::Target;
pub use terms::{Lambdas, TERMS, TermInfo, Terms, term};

/// Smallest scale the depth prior's affine map may take.
pub const MIN_DEPTH_SCALE: f32 = 1e-3;

/// One Adam step on the depth prior's scale and shift, then the scale is kept positive.
/// A prior depth is ordered like the true one (far stays far), so only a positive scale
/// means anything; a negative one turns the loss into a push *away* from the prior (far
/// pixels rendered with little weight have a small rendered depth, which a flipped scale
/// rewards, and the background loses its far walls).
pub fn update_depth_affine(adam: &mut Adam, wq: &mut [f32; 2], grad: &mut [f32; 2]) {
    adam.update(1e-3, wq, grad);
    wq[0] = wq[0].max(MIN_DEPTH_SCALE);
}

pub struct Trainer {
    pub scene: NeuralScene,
    pub views: Vec<View>,
    pub opts: TrainOptions,
    pub iteration: usize,
    /// Learnable scale and shift of the background depth prior.
    pub depth_wq: [f32; 2],
    /// One optimiser per field: the trainer never writes parameters itself.
    optimizers: BTreeMap<String, Box<dyn NodeOptimizer>>,
    tapes: Vec<Tape>,
    wq_adam: Adam,
    rays_per_batch: usize,
    extent: f32,
    node_of_id: BTreeMap<u16, u32>,
    background: Option<usize>,
    rays: RayBatch,
    traced: Traced,
    prune: assist_render::PruneScratch,
    /// Whether the last density pass dropped enough to pay for itself (see
    /// `step::PRUNE_PAYS`); while it did not, only every `PRUNE_PROBE_EVERY`-th step runs one.
    prune_pays: bool,
    out: BatchOutput,
    targets: Vec<Target>,
    pixel_count: usize,
    /// Pixels on or near objects (view, pixel), drawn from with probability
    /// `object_rays.extra` so that small objects get enough rays.
    object_pixels: Vec<(u32, u32)>,
    object_rays: ObjectRays,
    elapsed_before: f64,
    /// Where the optimisers' moments started afresh on fields trained before this run (a
    /// resume, a split's fine-tune): the learning rate ramps up from there (see
    /// [`warmed_lr`]). `None` for a scene trained from its first step.
    pub warm_from: Option<usize>,
    /// The training views' pose corrections (with `refine_poses`).
    pub poses: Option<PoseRefiner>,
    /// The view each ray of the batch came from.
    ray_views: Vec<u32>,
    /// Adam over each casting object's shadow grid, by field key.
    shade_adam: BTreeMap<String, Adam>,
    /// The step's gradient of each casting object's shadow grid, by node index (kept
    /// between steps: Adam leaves it zeroed).
    shade_grads: Vec<(usize, Vec<f32>)>,
    /// Lattice points of shadow grids that keep their values (by field key; see
    /// [`crate::ShadowEstimate::held`]): every other point trains with the scene.
    pub shade_held: BTreeMap<String, Vec<bool>>,
    /// The history saved with every checkpoint.
    pub kept: KeptHistory,
    /// The background's proposal field's training, when it has one.
    proposal: proposal::ProposalTraining,
    /// Where a share of the rays is drawn (`TrainOptions::error_rays`).
    error_map: error_map::ErrorMap,
    /// Per field, the largest density training's samples met in each occupancy cell
    /// since the grid's last round (see [`assist_field::OccupancyGrid::fold_seen`]).
    seen: BTreeMap<String, Vec<f32>>,
}

impl Trainer {
    /// The fields' optimizers from now on made by `factory` (a GPU's), their state fresh:
    /// call before the first step (a resumed run starts its moments afresh either way).
    pub fn use_optimizers(&mut self, factory: &dyn crate::OptimizerFactory) -> Result<()> {
        self.pull()?;
        for (k, f) in &self.scene.fields {
            let o = factory
                .make(f, self.opts.grid_decay)
                .map_err(|e| TrainError::Other(format!("{} for field {k}: {e}", factory.name())))?;
            self.optimizers.insert(k.clone(), o);
        }
        Ok(())
    }

    pub fn new(mut scene: NeuralScene, views: Vec<View>, opts: TrainOptions) -> Result<Self> {
        if views.is_empty() {
            return Err(TrainError::Other("no training images".into()));
        }
        // Scenes saved before fields recorded their views, and nodes made since (a split).
        crate::setup::set_anchors(&mut scene, &views);
        let keys: std::collections::BTreeSet<&String> =
            scene.scene.nodes.iter().map(|n| &n.field).collect();
        if keys.len() != scene.scene.nodes.len() {
            return Err(TrainError::Other(
                "every node must have its own field to be trained (replicas share one)".into(),
            ));
        }
        let optimizers = scene
            .fields
            .iter()
            .map(|(k, f)| {
                let o: Box<dyn NodeOptimizer> = Box::new(CpuOptimizer::new(f, opts.grid_decay));
                (k.clone(), o)
            })
            .collect();
        let extent = scene_extent(&scene);
        let node_of_id = scene
            .scene
            .nodes
            .iter()
            .enumerate()
            .filter(|(_, n)| !n.is_background())
            .map(|(k, n)| (n.id, k as u32))
            .collect();
        let background = scene.scene.nodes.iter().position(|n| n.is_background());
        let pixel_count = views.iter().map(|v| v.width * v.height).sum();
        let object_pixels: Vec<(u32, u32)> = views
            .par_iter()
            .enumerate()
            .flat_map_iter(|(vi, v)| {
                let near: Vec<bool> = match &v.ids {
                    Some(ids) => {
                        let m: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
                        crate::prior::dilate(&m, v.width, v.height, 2)
                    }
                    None => Vec::new(),
                };
                let valid = v.valid.as_deref();
                near.into_iter()
                    .enumerate()
                    .filter(move |(p, m)| *m && valid.is_none_or(|ok| ok[*p]))
                    .map(move |(p, _)| (vi as u32, p as u32))
            })
            .collect();
        let valid_pixels: usize = views
            .iter()
            .map(|v| {
                v.valid
                    .as_ref()
                    .map_or(v.width * v.height, |ok| ok.iter().filter(|&&b| b).count())
            })
            .sum();
        let object_rays = object_ray_draw(
            opts.object_ray_fraction,
            object_pixels.len() as f64 / valid_pixels.max(1) as f64,
        );
        let poses = opts
            .refine_poses
            .then(|| PoseRefiner::new(views.len(), extent));
        let proposal_samples = opts.proposal_samples;
        let error_map = error_map::ErrorMap::new(&views, opts.error_rays);
        let mut t = Trainer {
            scene,
            views,
            opts,
            iteration: 0,
            depth_wq: [1.0, 0.0],
            optimizers,
            tapes: Vec::new(),
            wq_adam: Adam::new(2),
            rays_per_batch: 512,
            extent,
            node_of_id,
            background,
            rays: RayBatch::default(),
            traced: Traced::default(),
            prune: assist_render::PruneScratch::default(),
            prune_pays: false,
            out: BatchOutput::default(),
            targets: Vec::new(),
            pixel_count,
            object_pixels,
            object_rays,
            elapsed_before: 0.0,
            warm_from: None,
            poses,
            ray_views: Vec::new(),
            shade_adam: BTreeMap::new(),
            shade_grads: Vec::new(),
            shade_held: BTreeMap::new(),
            kept: KeptHistory::default(),
            proposal: Default::default(),
            error_map,
            seen: BTreeMap::new(),
        };
        t.attach_proposal(proposal_samples);
        Ok(t)
    }

    /// Continues a run from where it was saved: the iteration count and the time already
    /// spent (for the schedule), and the depth prior's affine map. The moments start
    /// afresh, so the learning rate ramps up again ([`Trainer::warm_from`]).
    pub fn resume_from(&mut self, state: &ResumeState) {
        self.iteration = state.iteration;
        self.warm_from = Some(state.iteration);
        self.elapsed_before = state.elapsed_seconds;
        self.depth_wq = state.depth_scale_shift;
        if let (Some(p), Some(saved)) = (&mut self.poses, &state.pose_corrections) {
            p.restore(saved);
        }
    }

    /// Where the run stands after `elapsed` seconds in all.
    pub fn resume_state(&self, elapsed: f64) -> ResumeState {
        ResumeState {
            iteration: self.iteration,
            elapsed_seconds: elapsed,
            depth_scale_shift: self.depth_wq,
            pose_corrections: self.poses.as_ref().map(|p| p.params.clone()),
        }
    }

    /// Notes the largest density the step's samples met in each cell of their field's
    /// occupancy grid, for its next round.
    fn note_densities(&mut self) {
        for ns in &self.traced.nodes {
            let key = &self.scene.scene.nodes[ns.node].field;
            let grid = &self.scene.fields[key].occupancy;
            let seen = self.seen.entry(key.clone()).or_default();
            seen.resize(grid.cells(), 0.0);
            for (i, &s) in ns.sigma.iter().enumerate() {
                if let Some(c) = grid.cell_of([ns.pos[0][i], ns.pos[1][i], ns.pos[2][i]]) {
                    seen[c] = seen[c].max(s);
                }
            }
        }
    }

    /// Refreshes every field's occupancy grid from its density (and what the samples
    /// met since the last refresh).
    pub fn update_occupancy(&mut self) {
        let seed = self.opts.seed ^ self.iteration as u64;
        let round = self.iteration / self.opts.occupancy_every.max(1);
        for (i, (key, nf)) in self.scene.fields.iter_mut().enumerate() {
            let mut rng = Rng::stream(seed, i as u64);
            if let Some(seen) = self.seen.get_mut(key) {
                Arc::make_mut(nf).occupancy.fold_seen(seen);
                seen.fill(0.0);
            }
            self.optimizers
                .get_mut(key)
                .expect("optimizer per field")
                .refresh_occupancy(Arc::make_mut(nf), &mut rng, round);
        }
    }

    /// Brings the parameters the optimizers hold into the scene's fields where they are
    /// newer (a GPU's, which stay on the device between steps): call before reading the
    /// fields on the CPU between steps. `run` pulls before its checkpoints and at its end.
    pub fn pull(&mut self) -> Result<()> {
        for (key, nf) in self.scene.fields.iter_mut() {
            self.optimizers
                .get_mut(key)
                .expect("optimizer per field")
                .pull(Arc::make_mut(nf))
                .map_err(|e| TrainError::Other(format!("reading field {key} back: {e}")))?;
        }
        Ok(())
    }

    /// How the batches reach the objects (`None`: no object pixels to draw from).
    pub fn object_rays(&self) -> Option<ObjectRays> {
        (!self.object_pixels.is_empty()).then_some(self.object_rays)
    }

    /// Occupied fraction of each field's grid (by field key).
    pub fn occupancy(&self) -> Vec<(String, f64)> {
        self.scene
            .fields
            .iter()
            .map(|(k, f)| (k.clone(), f.occupancy.occupied_fraction()))
            .collect()
    }

    /// Whether every parameter is finite (checked before checkpoints).
    pub fn is_finite(&self) -> bool {
        self.scene
            .fields
            .iter()
            .all(|(k, f)| self.optimizers[k].is_finite(f))
    }

    /// Training information written into the scene file (`info`).
    pub fn info(&self, elapsed: f64) -> serde_json::Value {
        let mut v = serde_json::to_value(self.resume_state(elapsed)).expect("plain numbers");
        v["options"] = serde_json::to_value(&self.opts).expect("plain values");
        for (k, x) in &self.opts.provenance {
            v[k] = x.clone();
        }
        if let Some(o) = self.object_rays() {
            v["object_rays"] = serde_json::to_value(o).expect("plain numbers");
        }
        if let Some(p) = &self.poses {
            // What the refinement did to each training view, for the user: the world
            // translation of its centre and the rotation vector (radians) of its rays.
            let list: Vec<serde_json::Value> = self
                .views
                .iter()
                .enumerate()
                .map(|(k, view)| {
                    let (t, _) = p.correction(k);
                    let w = &p.params[6 * k + 3..6 * k + 6];
                    serde_json::json!({
                        "view": view.name,
                        "translation": t.to_array(),
                        "rotation": w,
                    })
                })
                .collect();
            v["camera_corrections"] = list.into();
        }
        v
    }

    /// Runs until the iteration or time budget is spent, calling `on_step` after each
    /// step (which calls [`Trainer::pull`] before it reads the fields); checkpoints
    /// atomically every `checkpoint_every` seconds when configured. The fields are
    /// current when it returns.
    pub fn run(
        &mut self,
        mut on_step: impl FnMut(&StepStats, &mut Trainer),
    ) -> Result<TrainReport> {
        let start = Instant::now();
        let first = self.iteration;
        let mut last_ckpt = Instant::now();
        let mut last = StepStats::default();
        let (mut rays, mut samples) = (0usize, 0usize);
        let mut phases = PhaseTimes::default();
        let mut saved: Option<PathBuf> = None;
        let mut cancelled = false;
        let stopped_by = loop {
            let elapsed = self.elapsed_before + start.elapsed().as_secs_f64();
            if self.iteration >= self.opts.iters {
                break StopReason::Iterations;
            }
            if self.opts.max_time.is_some_and(|t| elapsed >= t) {
                break StopReason::Time;
            }
            if let Some(c) = &self.opts.cancel
                && c.load(std::sync::atomic::Ordering::Relaxed)
            {
                cancelled = true;
                break StopReason::Cancelled;
            }
            match self.step(elapsed) {
                Ok(s) => {
                    rays += s.rays;
                    samples += s.samples;
                    phases.add(&s.phase);
                    last = s;
                    on_step(&s, self);
                }
                Err(TrainError::Diverged {
                    iteration, message, ..
                }) => {
                    return Err(TrainError::Diverged {
                        iteration,
                        message,
                        checkpoint: saved,
                    });
                }
                Err(e) => return Err(e),
            }
            if let Some(dir) = self.opts.checkpoint.clone()
                && last_ckpt.elapsed().as_secs_f64() >= self.opts.checkpoint_every
            {
                self.pull()?;
                if self.is_finite() {
                    let el = self.elapsed_before + start.elapsed().as_secs_f64();
                    self.kept.save(&dir, &self.scene, self.info(el))?;
                    saved = Some(dir);
                }
                last_ckpt = Instant::now();
            }
        };
        self.pull()?;
        let secs = start.elapsed().as_secs_f64();
        phases.other = secs - phases.total();
        Ok(TrainReport {
            iterations: self.iteration,
            steps: self.iteration - first,
            seconds: self.elapsed_before + secs,
            final_stats: last,
            rays_per_sec: rays as f64 / secs.max(1e-9),
            samples_per_sec: samples as f64 / secs.max(1e-9),
            phases,
            depth_scale_shift: self.depth_wq,
            cancelled,
            stopped_by,
        })
    }
}

/// Steps over which the learning rate ramps up when the optimisers' moments start afresh
/// on trained fields (at most a tenth of the steps the run has left).
pub const WARMUP_STEPS: usize = 300;

/// The learning rate of `iteration` given the schedule's `lr`, in a run of `iters` steps:
/// with fresh moments Adam's first steps move every parameter with a gradient by about the
/// learning rate whatever the gradient's size, which shakes a trained field where few rays
/// reach (the split desk's fine-tune without the ramp: object colours strewn on the floor
/// beside the table, measured in BENCHMARKS.md). A linear ramp from `warm_from`.
pub fn warmed_lr(lr: f32, iteration: usize, warm_from: Option<usize>, iters: usize) -> f32 {
    match warm_from {
        Some(from) => {
            let ramp = WARMUP_STEPS.min(iters.saturating_sub(from) / 10).max(1);
            let done = iteration.saturating_sub(from) + 1;
            lr * (done as f32 / ramp as f32).min(1.0)
        }
        None => lr,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resumed_run_ramps_its_learning_rate_up() {
        // A scene trained from its first step: the schedule as it is.
        assert_eq!(warmed_lr(1e-2, 0, None, 5000), 1e-2);
        // Resumed at 2,630 of 7,890: the first step a 300th of the schedule, then linear.
        let at = |i| warmed_lr(1e-2, i, Some(2630), 7890);
        assert!((at(2630) - 1e-2 / WARMUP_STEPS as f32).abs() < 1e-9);
        assert!((at(2630 + 149) - 0.5e-2).abs() < 1e-9);
        assert_eq!(at(2630 + WARMUP_STEPS - 1), 1e-2);
        assert_eq!(at(2630 + 5000), 1e-2);
        assert!((1..WARMUP_STEPS).all(|k| at(2630 + k) > at(2630 + k - 1)));
        // A short run ramps over a tenth of its steps; a run without a step limit over 300.
        assert_eq!(warmed_lr(1e-2, 9, Some(0), 100), 1e-2);
        assert!(warmed_lr(1e-2, 8, Some(0), 100) < 1e-2);
        assert!(warmed_lr(1e-2, 298, Some(0), usize::MAX) < 1e-2);
        assert_eq!(warmed_lr(1e-2, 0, Some(0), 5), 1e-2);
    }

    #[test]
    fn the_depth_prior_scale_stays_positive() {
        let mut adam = Adam::new(2);
        let mut wq = [1.0f32, 0.0];
        // A gradient that keeps pushing the scale down (and the shift up) for many steps.
        for _ in 0..5000 {
            update_depth_affine(&mut adam, &mut wq, &mut [1.0, -1.0]);
            assert!(wq[0] >= MIN_DEPTH_SCALE, "{wq:?}");
        }
        assert_eq!(wq[0], MIN_DEPTH_SCALE);
        assert!(wq[1] > 4.0, "the shift is not constrained: {wq:?}");
        // Pushed back up, the scale moves off the floor again (Adam steps of ~1e-3).
        for _ in 0..100 {
            update_depth_affine(&mut adam, &mut wq, &mut [-1.0, 0.0]);
        }
        assert!(wq[0] > 0.05, "{wq:?}");
    }
}
