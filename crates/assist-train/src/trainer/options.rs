//! What a training run is given and what it reports: loss weights, options, per-step
//! figures with phase times, the final report, and the state a run resumes from.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use serde::{Deserialize, Serialize};

use super::terms::{Lambdas, Terms};

/// The part of the depth map's distance in front of which [`Lambdas::empty`] asks every
/// node to be empty: the rest absorbs depth quantisation and mixed edge pixels.
pub const EMPTY_MARGIN: f32 = 0.005;

#[derive(Debug, Clone, Serialize)]
pub struct TrainOptions {
    pub iters: usize,
    /// Stop after this many seconds (the schedule then runs on time).
    pub max_time: Option<f64>,
    /// Target number of samples per step; the ray count adapts to it.
    pub batch_samples: usize,
    pub lr_start: f32,
    /// The learning rate at the end of the run (it decays exponentially from `lr_start`
    /// over the iterations or the time budget); measured against 1e-4 in BENCHMARKS.md.
    /// See [`default_lr_end`] for a scene with an unbounded background.
    pub lr_end: f32,
    pub lambdas: Lambdas,
    pub occupancy_every: usize,
    pub seed: u64,
    /// Checkpoint directory and interval in seconds.
    pub checkpoint: Option<PathBuf>,
    pub checkpoint_every: f64,
    /// The least share of each batch's rays on or near objects (when masks exist), so that
    /// small objects get enough rays: rays are drawn from the objects' pixels only as far
    /// as a uniform draw over all pixels falls short of it (see [`object_ray_draw`]; the
    /// default is measured in BENCHMARKS.md).
    pub object_ray_fraction: f64,
    /// Samples behind the point where their node's transmittance falls below this are
    /// dropped after a density-only pass, before the forward and backward passes (0 =
    /// keep all; nerfacc's early stop, see `assist_render::prune`). The pass runs only
    /// while it drops enough to pay for itself (`PRUNE_PAYS`). 0 here; runs choose by
    /// their scene ([`default_prune_eps`]).
    pub prune_eps: f32,
    /// The background's samples whose transmittance through the objects in front of them
    /// is below this learn only from the background's own terms (its prior), not from the
    /// photographs through the objects' imperfect opacity ([`assist_render::HiddenStop`];
    /// 0 = off). What an object hides is not in the photographs: through a dark mug
    /// interior they favoured no table at all. Off by default: it costs the unedited views
    /// more than it gives a moved object (BENCHMARKS.md).
    pub hidden_stop: f32,
    /// Every node's marching steps times this while training (`SampleOptions::step_scale`;
    /// 1 = as rendered).
    pub step_scale: f32,
    /// Draw an unbounded background's samples from a proposal field trained with it, this
    /// many per ray (0: a background without one is marched at every step; one that has
    /// a proposal keeps it, and it goes on training).
    pub proposal_samples: usize,
    /// The dataset's `--downscale` (recorded in the scene for evaluation; 1 = none).
    pub downscale: u32,
    /// Learn a scale and shift of the background depth prior (`depth_wq`). For priors
    /// of unknown scale (a monocular model's depth supplied by the user); a prior made
    /// from the dataset's own depth is metric, and a free scale only lets the rendered
    /// depth drift from it (the demo's wall rendered at half its distance, scale 0.42).
    pub depth_affine: bool,
    /// L2 decay of the hash tables' entries each step touches ([`assist_field::Adam::
    /// table_decay`]; 0 = none, the default: measured in BENCHMARKS.md).
    pub grid_decay: f32,
    /// Share of the rays not drawn for objects that is drawn where the colour error is
    /// high (a running map per tile of each view, `trainer::error_map`), each weighted so
    /// the objective stays the uniform mean; 0 = every such ray uniform.
    pub error_rays: f64,
    /// Learn a correction of every training view's pose with the scene (see
    /// [`super::PoseRefiner`]); held-out views keep their given poses.
    pub refine_poses: bool,
    /// Testing aid: poison one parameter with NaN at this iteration (exercises divergence
    /// detection).
    #[serde(skip)]
    pub poison_at: Option<usize>,
    /// Set from another thread to stop the run after the current step (the report then
    /// says `cancelled`; the scene is as trained so far).
    #[serde(skip)]
    pub cancel: Option<Arc<AtomicBool>>,
    /// Further keys written into the scene file's `info` with every save (where the scene
    /// came from: the dataset and its fingerprint).
    #[serde(skip)]
    pub provenance: serde_json::Map<String, serde_json::Value>,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            iters: 5000,
            max_time: None,
            batch_samples: 1 << 16,
            lr_start: 1e-2,
            lr_end: 1e-3,
            lambdas: Lambdas::default(),
            occupancy_every: 16,
            seed: 0,
            checkpoint: None,
            checkpoint_every: 60.0,
            object_ray_fraction: 0.33,
            downscale: 1,
            depth_affine: false,
            refine_poses: false,
            grid_decay: 0.0,
            error_rays: 0.0,
            prune_eps: 0.0,
            hidden_stop: 0.0,
            step_scale: 1.0,
            proposal_samples: 0,
            poison_at: None,
            cancel: None,
            provenance: serde_json::Map::new(),
        }
    }
}

/// One step's figures (losses are batch means, before the λ weights).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct StepStats {
    pub iteration: usize,
    pub loss: f64,
    /// Each term of the loss (batch means, before the weights).
    #[serde(flatten)]
    pub terms: Terms<f64>,
    /// PSNR of the composite colour on this batch.
    pub psnr: f64,
    pub rays: usize,
    pub samples: usize,
    pub lr: f32,
    pub elapsed: f64,
    /// Fraction of the run done (iterations or time).
    pub progress: f64,
    /// Seconds in each phase of this step (`other` stays 0).
    pub phase: PhaseTimes,
    /// Mean samples per ray of the first nodes (background first when present), after
    /// pruning.
    pub samples_per_ray: [f32; 4],
    /// Samples marched before pruning.
    pub candidates: usize,
    /// Samples dropped by pruning (`candidates − samples`).
    pub pruned: usize,
    /// The proposal's interlevel loss (mean per ray; 0 without a proposal).
    pub interlevel: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    pub iterations: usize,
    /// Steps taken by this run: fewer than `iterations` when it resumed a scene. The
    /// phase times and rates are over these.
    pub steps: usize,
    pub seconds: f64,
    pub final_stats: StepStats,
    pub rays_per_sec: f64,
    pub samples_per_sec: f64,
    /// Seconds spent over the run in each phase; `other` is everything else
    /// (checkpoints, progress display).
    pub phases: PhaseTimes,
    pub depth_scale_shift: [f32; 2],
    /// Whether the run was stopped by [`TrainOptions::cancel`].
    pub cancelled: bool,
    /// What ended the run.
    pub stopped_by: StopReason,
}

/// What ended a training run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The iteration budget (`iters`) was reached.
    #[default]
    Iterations,
    /// The time budget (`max_time`) was spent.
    Time,
    /// [`TrainOptions::cancel`] was set (an interrupt).
    Cancelled,
}

/// Seconds in each phase of a training step or run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseTimes {
    /// Ray drawing and sampling.
    pub sampling: f64,
    /// Field forward passes.
    pub forward: f64,
    /// Compositing and losses.
    pub compositing: f64,
    /// Field backward passes.
    pub backward: f64,
    pub adam: f64,
    /// Occupancy-grid updates.
    pub occupancy: f64,
    pub other: f64,
}

impl PhaseTimes {
    /// From the times at which each of the six step phases ended, measured from the
    /// step's start.
    pub fn from_marks(ends: [f64; 6]) -> Self {
        let d = |i: usize| ends[i] - if i == 0 { 0.0 } else { ends[i - 1] };
        PhaseTimes {
            sampling: d(0),
            forward: d(1),
            compositing: d(2),
            backward: d(3),
            adam: d(4),
            occupancy: d(5),
            other: 0.0,
        }
    }

    pub fn add(&mut self, o: &PhaseTimes) {
        for (a, b) in self.as_mut_array().into_iter().zip(o.named()) {
            *a += b.1;
        }
    }

    fn as_mut_array(&mut self) -> [&mut f64; 7] {
        [
            &mut self.sampling,
            &mut self.forward,
            &mut self.compositing,
            &mut self.backward,
            &mut self.adam,
            &mut self.occupancy,
            &mut self.other,
        ]
    }

    /// Each phase with its name, in order.
    pub fn named(&self) -> [(&'static str, f64); 7] {
        [
            ("sampling", self.sampling),
            ("forward", self.forward),
            ("compositing", self.compositing),
            ("backward", self.backward),
            ("adam", self.adam),
            ("occupancy", self.occupancy),
            ("other", self.other),
        ]
    }

    pub fn total(&self) -> f64 {
        self.named().iter().map(|p| p.1).sum()
    }
}

/// Where a saved run stands, written into the scene file's `info` and read back to
/// resume it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResumeState {
    pub iteration: usize,
    pub elapsed_seconds: f64,
    /// Learnt scale and shift of the background depth prior.
    #[serde(default = "identity_affine")]
    pub depth_scale_shift: [f32; 2],
    /// The training views' pose corrections when poses are refined: per view (in the
    /// dataset's training order) a translation in scene extents and a rotation vector in
    /// radians, both in world axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_corrections: Option<Vec<f32>>,
}

fn identity_affine() -> [f32; 2] {
    [1.0, 0.0]
}

impl ResumeState {
    /// Reads the state from a scene file's `info`; `Err` names the field that is missing
    /// or malformed.
    pub fn from_info(info: &serde_json::Value) -> Result<Self, String> {
        serde_json::from_value(info.clone()).map_err(|e| {
            format!("info: expected iteration, elapsed_seconds and depth_scale_shift: {e}")
        })
    }
}

/// The edit history a trained scene keeps with it (a split's scene before the split, so
/// that undo merges it back), and the fields only its steps refer to: saved with every
/// checkpoint, never trained.
#[derive(Debug, Clone, Default)]
pub struct KeptHistory {
    pub history: assist_core::History,
    pub fields: std::collections::BTreeMap<String, std::sync::Arc<assist_scene::NodeField>>,
}

impl KeptHistory {
    /// Takes out of `scene` the fields no node of it draws with (those `history` alone
    /// refers to), keeping them with `history`.
    pub fn split_off(scene: &mut assist_scene::NeuralScene, history: assist_core::History) -> Self {
        let used: std::collections::BTreeSet<&String> =
            scene.scene.nodes.iter().map(|n| &n.field).collect();
        let unused: Vec<String> = scene
            .fields
            .keys()
            .filter(|k| !used.contains(k))
            .cloned()
            .collect();
        let fields = unused
            .into_iter()
            .filter_map(|k| scene.fields.remove(&k).map(|f| (k, f)))
            .collect();
        KeptHistory { history, fields }
    }

    /// Saves `scene` at `dir` with this history and its fields (replacing `dir`).
    pub fn save(
        &self,
        dir: &std::path::Path,
        scene: &assist_scene::NeuralScene,
        info: serde_json::Value,
    ) -> Result<(), assist_scene::SceneFileError> {
        if self.history.is_empty() {
            return assist_scene::scene_file::save(dir, scene, info, true);
        }
        let mut all = scene.clone();
        for (k, f) in &self.fields {
            all.fields.entry(k.clone()).or_insert_with(|| f.clone());
        }
        assist_scene::scene_file::save_with_history(dir, &all, &self.history, info, true)
    }
}

/// The learning rate a run ends at unless told: 3e-3 where a node is unbounded (a
/// contracted background: real captures without depth, far from converged at their
/// budgets, where the later floor measured better), else [`TrainOptions::default`]'s
/// 1e-3 (the comparison is in BENCHMARKS.md).
pub fn default_lr_end(unbounded: bool) -> f32 {
    if unbounded {
        3e-3
    } else {
        TrainOptions::default().lr_end
    }
}

/// Samples per ray a run draws from a proposal unless told (`train --proposal`): 24
/// (Nerfacto's final count) where a node is unbounded, else none (a bounded background
/// marches few samples, and has no proposal). Against marching every step of the
/// contracted shell, the same time's training renders frames several times faster and
/// measured better on fern and beer; on gold_cape its cape gained and its room lost
/// (BENCHMARKS.md).
pub fn default_proposal(unbounded: bool) -> usize {
    if unbounded {
        24
    } else {
        TrainOptions::default().proposal_samples
    }
}

/// The share of rays a run draws from its error map unless told (`train --error-rays`):
/// half where a node is unbounded (real captures without depth, whose error gathers in
/// fine texture and in what few views see: fern, beer and gold_cape gained over two or
/// three seeds), else none (desk and lego came out level, within their seeds' spread).
/// BENCHMARKS.md has the figures.
pub fn default_error_rays(unbounded: bool) -> f64 {
    if unbounded {
        0.5
    } else {
        TrainOptions::default().error_rays
    }
}

/// The pruning threshold a run uses unless told: `PRUNE_EPS` where a node is unbounded (a
/// contracted background marches on through the room behind the first surface it meets,
/// and those samples carry no weight), else off (bounded nodes march few samples, and
/// nodes under `PRUNE_MIN_PER_RAY` samples per ray are never pruned). Measured in
/// BENCHMARKS.md.
pub fn default_prune_eps(unbounded: bool) -> f32 {
    if unbounded {
        assist_render::PRUNE_EPS
    } else {
        TrainOptions::default().prune_eps
    }
}

/// How a batch's rays reach the objects: `share` of the pixels to train on lie on or
/// next to objects, and `extra` of each batch's rays are drawn from those pixels before
/// the rest are drawn uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObjectRays {
    pub share: f64,
    pub extra: f64,
}

/// The extra draw that brings the rays on or next to objects up to `least` of each batch:
/// a uniform draw already puts `share` of them there, so `extra + (1 - extra) * share =
/// least`, and none where `share` reaches `least` (an object that fills the views, as
/// in a walk-around, needs no rays taken from the room around it).
pub fn object_ray_draw(least: f64, share: f64) -> ObjectRays {
    let extra = if share >= least || share >= 1.0 {
        0.0
    } else {
        ((least - share) / (1.0 - share)).clamp(0.0, 1.0)
    };
    ObjectRays { share, extra }
}
