//! The training loop (paper §III-C): random rays over the training images, compositional
//! rendering, the paper's five losses plus one of ours and Nerfacto's distortion loss,
//! `L = L_comp_rgb + λ1 L_bg_rgb + λ2 L_bg_depth + λ3 L_obj_acc + λ4 L_obj_rgb +
//! λ5 L_obj_share + λ6 L_dist`, backward into every node's field, Adam with a learning rate decaying exponentially from
//! 1e-2 to 1e-4 over the run, occupancy-grid updates, periodic atomic checkpoints, and
//! divergence detection (a NaN loss stops training; the last good checkpoint is kept).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use assist_core::Rng;
use assist_field::{Adam, Tape};
use assist_render::{
    BatchOutput, CompositeGrad, NeuralScene, RayBatch, RayOutputs, SampleOptions, Traced,
    composite_batch, sample_rays,
};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Result, TrainError};
use crate::losses;
use crate::views::View;

/// Loss weights. Defaults: λ1 = 0.5 (bg colour), λ2 = 0.1 (bg depth, in units of the
/// scene's extent), λ3 = 0.1 (object opacity), λ4 = 0.5 (object colour). The paper calls
/// them "normalising constants" and gives no values; these were chosen on the synth scene.
///
/// λ5 = 0.1 weighs a sixth term that is not in the paper, `L_obj_share = Σ_k M^k (1 − W^k)²`,
/// where `W^k` is node k's share of the weight composited along the ray (the quantity the
/// panoptic id is taken from). The paper's `M^k` means "the ray *first* hits object k", but
/// its `L_obj_acc` looks at each node alone, so it cannot tell whether another node — in
/// practice the background — has density in front of the object: both colour losses are
/// satisfied when the background grows a copy of the object's surface in front of it, and
/// the object then loses its pixels in the panoptic output. `L_obj_share` says what the mask
/// says, on the composite. `λ5 = 0` gives the paper's loss exactly.
///
/// λ6 weighs the distortion loss of mip-NeRF 360 (inter-interval term), which the paper's
/// per-node model, nerfstudio's Nerfacto, trains with: `Σ_{i,j} w_i w_j |t_i − t_j|` over
/// the composited weights of a ray, with `t` in units of the scene's extent. It removes the
/// semi-transparent haze that otherwise spreads a surface over centimetres of depth (on
/// desk without it: transmittance falls from 0.9 to 0.1 over 8 cm of depth at the median
/// ray, over 82 cm at the 90th percentile), which blurs novel views and costs samples.
/// λ6 defaults to 0 (off), by measurement on desk (150 s runs, λ6 = 0 / 0.01 / 0.1 / 1: background samples per
/// ray 138 / 147 / 114 / 40, rays per second 3.4 k / 3.8 k / 4.4 k / 7.2 k, test PSNR
/// 24.8 / 24.6 / 24.9 / 25.5 dB) — but λ6 = 1 over 900 s ended 0.7 dB *below* the run
/// without it (28.9 dB, 20 background samples per ray: the occupancy grid, fed by the
/// over-sharpened density, pruned cells surfaces still needed), and λ6 = 0.1 over 900 s
/// 0.15 dB below (29.42 dB, SSIM 0.864 against 0.882). It stays available for speed (λ6 =
/// 0.1 trains 2× the rays per second). See BENCHMARKS.md.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Lambdas {
    pub bg_rgb: f32,
    pub bg_depth: f32,
    pub obj_acc: f32,
    pub obj_rgb: f32,
    pub obj_share: f32,
    pub distortion: f32,
}

impl Default for Lambdas {
    fn default() -> Self {
        Lambdas {
            bg_rgb: 0.5,
            bg_depth: 0.1,
            obj_acc: 0.1,
            obj_rgb: 0.5,
            obj_share: 0.1,
            distortion: 0.0,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainOptions {
    pub iters: usize,
    /// Stop after this many seconds (the schedule then runs on time).
    pub max_time: Option<f64>,
    /// Target number of samples per step; the ray count adapts to it.
    pub batch_samples: usize,
    pub lr_start: f32,
    pub lr_end: f32,
    pub lambdas: Lambdas,
    pub occupancy_every: usize,
    pub seed: u64,
    /// Checkpoint directory and interval in seconds.
    pub checkpoint: Option<PathBuf>,
    pub checkpoint_every: f64,
    /// Fraction of each batch drawn from pixels on or near objects (when masks exist); the
    /// rest are drawn uniformly over all pixels. 0.25 by measurement on desk (900 s: 32.42
    /// dB against 30.76 dB with 0.5, the same mIoU).
    pub object_ray_fraction: f64,
    /// Samples behind the point where their node's transmittance falls below this are
    /// dropped after a density-only pass, before the forward and backward passes (0 =
    /// keep all; nerfacc's early stop, see `assist_render::prune`). Off by default, by
    /// measurement: on beer's contracted background it drops 9% of the samples (the
    /// contracted occupancy grid already keeps ~45 per ray) for a density pass over all
    /// of them, and beer and fern ended lower with it (23.96 / 22.80 dB against 24.20 /
    /// 23.42 dB in 300 s); lego_400 ended higher (30.06 against 29.61 dB: its batches
    /// held twice the rays). See BENCHMARKS.md.
    pub prune_eps: f32,
    /// The dataset's `--downscale` (recorded in the scene for evaluation; 1 = none).
    pub downscale: u32,
    /// Learn a scale and shift of the background depth prior (`depth_wq`). For priors
    /// of unknown scale (a monocular model's depth supplied by the user); a prior made
    /// from the dataset's own depth is metric, and a free scale only lets the rendered
    /// depth drift from it (the demo's wall rendered at half its distance, scale 0.42).
    pub depth_affine: bool,
    /// Testing aid: poison one parameter with NaN at this iteration (exercises divergence
    /// detection).
    #[serde(skip)]
    pub poison_at: Option<usize>,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            iters: 5000,
            max_time: None,
            batch_samples: 1 << 16,
            lr_start: 1e-2,
            lr_end: 1e-4,
            lambdas: Lambdas::default(),
            occupancy_every: 16,
            seed: 0,
            checkpoint: None,
            checkpoint_every: 60.0,
            object_ray_fraction: 0.25,
            downscale: 1,
            depth_affine: false,
            prune_eps: 0.0,
            poison_at: None,
        }
    }
}

/// One step's figures (losses are batch means, before the λ weights).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct StepStats {
    pub iteration: usize,
    pub loss: f64,
    pub comp_rgb: f64,
    pub bg_rgb: f64,
    pub bg_depth: f64,
    pub obj_acc: f64,
    pub obj_rgb: f64,
    pub obj_share: f64,
    pub distortion: f64,
    /// PSNR of the composite colour on this batch.
    pub psnr: f64,
    pub rays: usize,
    pub samples: usize,
    pub lr: f32,
    pub elapsed: f64,
    /// Fraction of the run done (iterations or time).
    pub progress: f64,
    /// Seconds in each phase of this step: ray drawing + sampling, field forward,
    /// compositing and losses, field backward, Adam, occupancy-grid update.
    pub phase: [f64; 6],
    /// Mean samples per ray of the first nodes (background first when present), after
    /// pruning.
    pub samples_per_ray: [f32; 4],
    /// Samples marched before pruning.
    pub candidates: usize,
    /// Samples dropped by pruning (`candidates − samples`).
    pub pruned: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    pub iterations: usize,
    pub seconds: f64,
    pub final_stats: StepStats,
    pub rays_per_sec: f64,
    pub samples_per_sec: f64,
    /// Seconds spent over the run in each phase (as `StepStats::phase`), then everything
    /// else (checkpoints, progress display).
    pub phase_seconds: [f64; 7],
    pub depth_scale_shift: [f32; 2],
}

/// What each ray is supervised with.
#[derive(Debug, Clone, Copy)]
struct Target {
    rgb: [f32; 3],
    /// Node index of the object this ray first hits (`u32::MAX`: none).
    mask_node: u32,
    /// Whether the view has instance masks (object losses apply).
    masked: bool,
    inpaint: Option<[f32; 3]>,
    /// Prior depth as distance along the ray, in units of the scene extent.
    depth: Option<f32>,
    /// Weight of the prior terms (the prior's confidence at this pixel).
    prior_weight: f32,
}

/// A pixel `(view, index)` drawn uniformly over the pixels to train on: one a `mask_path`
/// excludes is drawn again, 16 times at most (`None` then: the ray is left out).
fn draw_pixel(views: &[View], total: u64, rng: &mut Rng) -> Option<(usize, usize)> {
    for _ in 0..16 {
        let mut p = rng.below(total) as usize;
        let mut vi = 0;
        while p >= views[vi].width * views[vi].height {
            p -= views[vi].width * views[vi].height;
            vi += 1;
        }
        if views[vi].valid.as_ref().is_none_or(|ok| ok[p]) {
            return Some((vi, p));
        }
    }
    None
}

/// Smallest scale the depth prior's affine map may take.
pub const MIN_DEPTH_SCALE: f32 = 1e-3;

/// One Adam step on the depth prior's scale and shift, then the scale is kept positive.
/// A prior depth is ordered like the true one (far stays far), so only a positive scale
/// means anything; a negative one turns the loss into a push *away* from the prior. On
/// desk without the object losses the scale did go negative (-3.3) and the background
/// lost its back wall (21.5 dB): far pixels rendered with little weight have a small
/// rendered depth, which the flipped scale then rewarded.
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
    adams: BTreeMap<String, Adam>,
    grads: BTreeMap<String, Vec<f32>>,
    tapes: Vec<Tape>,
    wq_adam: Adam,
    rays_per_batch: usize,
    extent: f32,
    node_of_id: BTreeMap<u16, u32>,
    background: Option<usize>,
    rays: RayBatch,
    traced: Traced,
    prune: assist_render::PruneScratch,
    out: BatchOutput,
    targets: Vec<Target>,
    pixel_count: usize,
    /// Pixels on or near objects (view, pixel), drawn with probability
    /// `object_ray_fraction` so that small objects get enough rays.
    object_pixels: Vec<(u32, u32)>,
    elapsed_before: f64,
}

impl Trainer {
    pub fn new(scene: NeuralScene, views: Vec<View>, opts: TrainOptions) -> Result<Self> {
        if views.is_empty() {
            return Err(TrainError::Other("no training images".into()));
        }
        let keys: std::collections::BTreeSet<&String> =
            scene.scene.nodes.iter().map(|n| &n.field).collect();
        if keys.len() != scene.scene.nodes.len() {
            return Err(TrainError::Other(
                "every node must have its own field to be trained (replicas share one)".into(),
            ));
        }
        let adams = scene
            .fields
            .iter()
            .map(|(k, f)| (k.clone(), Adam::for_field(&f.field)))
            .collect();
        let grads = scene
            .fields
            .iter()
            .map(|(k, f)| (k.clone(), vec![0.0; f.field.layout.total]))
            .collect();
        let mut ext = assist_core::Aabb::empty();
        for n in &scene.scene.nodes {
            for c in n.world_corners() {
                ext.extend(c);
            }
        }
        let extent = ext.size().length().max(1e-6) as f32;
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
        Ok(Trainer {
            scene,
            views,
            opts,
            iteration: 0,
            depth_wq: [1.0, 0.0],
            adams,
            grads,
            tapes: Vec::new(),
            wq_adam: Adam::new(2),
            rays_per_batch: 512,
            extent,
            node_of_id,
            background,
            rays: RayBatch::default(),
            traced: Traced::default(),
            prune: assist_render::PruneScratch::default(),
            out: BatchOutput::default(),
            targets: Vec::new(),
            pixel_count,
            object_pixels,
            elapsed_before: 0.0,
        })
    }

    /// Continue a run: the iteration count and the time already spent (for the schedule).
    pub fn resume_from(&mut self, iteration: usize, elapsed: f64, depth_wq: [f32; 2]) {
        self.iteration = iteration;
        self.elapsed_before = elapsed;
        self.depth_wq = depth_wq;
    }

    fn progress(&self, elapsed: f64) -> f64 {
        let by_iter = self.iteration as f64 / self.opts.iters.max(1) as f64;
        let by_time = self
            .opts
            .max_time
            .map(|t| elapsed / t.max(1e-9))
            .unwrap_or(0.0);
        by_iter.max(by_time).min(1.0)
    }

    fn draw_rays(&mut self) {
        let n = self.rays_per_batch;
        let seed = self.opts.seed ^ (self.iteration as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let views = &self.views;
        let total = self.pixel_count as u64;
        let node_of_id = &self.node_of_id;
        let extent = self.extent;
        let objects = &self.object_pixels;
        let object_fraction = self.opts.object_ray_fraction;
        let drawn: Vec<Option<(assist_core::Ray, u32, Target)>> = (0..n)
            .into_par_iter()
            .map(|r| {
                let mut rng = Rng::stream(seed, r as u64);
                let (vi, p) = if !objects.is_empty() && rng.f64() < object_fraction {
                    let (vi, p) = objects[rng.below(objects.len() as u64) as usize];
                    (vi as usize, p as usize)
                } else {
                    draw_pixel(views, total, &mut rng)?
                };
                let v = &views[vi];
                let (i, j) = ((p % v.width) as u32, (p / v.width) as u32);
                let ray = v.camera.pixel_ray(i, j)?;
                let rgb = [v.rgb[3 * p], v.rgb[3 * p + 1], v.rgb[3 * p + 2]];
                let (masked, mask_node) = match &v.ids {
                    Some(ids) => (true, node_of_id.get(&ids[p]).copied().unwrap_or(u32::MAX)),
                    None => (false, u32::MAX),
                };
                let inpaint = v
                    .inpaint
                    .as_ref()
                    .map(|im| [im[3 * p], im[3 * p + 1], im[3 * p + 2]]);
                let cos = ray.dir.dot(v.camera.pose.forward()) as f32;
                let depth = v
                    .inpaint_depth
                    .as_ref()
                    .map(|d| d[p])
                    .filter(|&z| z > 0.0 && cos > 1e-3)
                    .map(|z| z / cos / extent);
                let prior_weight = v.prior_confidence.as_ref().map_or(1.0, |c| c[p]);
                Some((
                    ray,
                    v.image_index,
                    Target {
                        rgb,
                        mask_node,
                        masked,
                        inpaint,
                        depth,
                        prior_weight,
                    },
                ))
            })
            .collect();
        self.rays.clear();
        self.rays.near = self.scene.scene.near as f32;
        self.targets.clear();
        for (ray, img, t) in drawn.into_iter().flatten() {
            self.rays.push(&ray, img);
            self.targets.push(t);
        }
    }

    /// One training step.
    pub fn step(&mut self, elapsed: f64) -> Result<StepStats> {
        let progress = self.progress(elapsed);
        let lr = self.opts.lr_start * (self.opts.lr_end / self.opts.lr_start).powf(progress as f32);
        let tp = Instant::now();
        let mut phase = [0.0f64; 6];
        self.draw_rays();
        let so = SampleOptions {
            jitter: true,
            seed: self.opts.seed.wrapping_add(self.iteration as u64 * 7919),
            max_per_node: 1024,
        };
        sample_rays(&self.scene, &self.rays, &so, &mut self.traced);
        let candidates = self.traced.total_samples();
        let pruned = if self.opts.prune_eps > 0.0 {
            assist_render::prune_occluded(
                &self.scene,
                &mut self.traced,
                self.opts.prune_eps,
                &mut self.prune,
            )
        } else {
            assist_render::PruneStats::default()
        };
        let nn = self.traced.nodes.len();
        phase[0] = tp.elapsed().as_secs_f64();
        self.tapes.resize_with(nn, Tape::default);
        for (ns, tape) in self.traced.nodes.iter_mut().zip(self.tapes.iter_mut()) {
            ns.prepare_outputs(true);
            if ns.is_empty() {
                continue;
            }
            let nf = &self.scene.fields[&self.scene.scene.nodes[ns.node].field];
            let mut sigma = std::mem::take(&mut ns.sigma);
            let mut rgb = std::mem::take(&mut ns.rgb);
            nf.field
                .forward_train(&ns.samples(), tape, &mut sigma, &mut rgb);
            ns.sigma = sigma;
            ns.rgb = rgb;
        }
        phase[1] = tp.elapsed().as_secs_f64();
        let lam = self.opts.lambdas;
        let n_rays = self.targets.len().max(1) as f32;
        let targets = &self.targets;
        let bg = self.background;
        let wq = self.depth_wq;
        let depth_affine = self.opts.depth_affine;
        let extent = self.extent;
        let is_object: Vec<bool> = self
            .scene
            .scene
            .nodes
            .iter()
            .map(|n| !n.is_background())
            .collect();
        let grad_fn = |o: &RayOutputs, g: &mut CompositeGrad, gn: &mut [CompositeGrad]| {
            let (c, per) = (o.composite, o.nodes);
            let t = &targets[o.ray];
            let (_, d) = losses::rgb(c.rgb, t.rgb);
            g.rgb = d.map(|v| v / n_rays);
            g.distortion = lam.distortion / extent / n_rays;
            if t.masked {
                for (k, pk) in per.iter().enumerate() {
                    if !is_object[k] {
                        continue;
                    }
                    let m = if t.mask_node == k as u32 { 1.0 } else { 0.0 };
                    let (_, d) = losses::opacity(pk.opacity, m);
                    gn[k].opacity += lam.obj_acc * d / n_rays;
                    if m > 0.0 {
                        let (_, dc, d_o) = losses::premultiplied_rgb(pk.rgb, pk.opacity, t.rgb);
                        for ch in 0..3 {
                            gn[k].rgb[ch] += lam.obj_rgb * dc[ch] / n_rays;
                        }
                        gn[k].opacity += lam.obj_rgb * d_o / n_rays;
                        let (_, d) = losses::share(o.share[k]);
                        gn[k].share += lam.obj_share * d / n_rays;
                    }
                }
            }
            if let Some(b) = bg {
                let pw = t.prior_weight;
                if let Some(inp) = t.inpaint {
                    let (_, dc, d_o) = losses::premultiplied_rgb(per[b].rgb, per[b].opacity, inp);
                    for ch in 0..3 {
                        gn[b].rgb[ch] += pw * lam.bg_rgb * dc[ch] / n_rays;
                    }
                    gn[b].opacity += pw * lam.bg_rgb * d_o / n_rays;
                }
                if let Some(d) = t.depth {
                    if depth_affine {
                        let (_, gd, _) = losses::affine_depth(per[b].depth, extent, wq, d);
                        gn[b].depth += pw * lam.bg_depth * gd / n_rays;
                    } else {
                        let (_, gd, gs) =
                            losses::depth_moment(per[b].depth, per[b].depth_sq, extent, d);
                        gn[b].depth += pw * lam.bg_depth * gd / n_rays;
                        gn[b].depth_sq += pw * lam.bg_depth * gs / n_rays;
                    }
                }
            }
        };
        composite_batch(
            &mut self.traced,
            assist_render::Behind::of(&self.scene.scene),
            &mut self.out,
            Some(&grad_fn),
        );
        // Loss values and the depth scale/shift gradient.
        let mut s = StepStats {
            iteration: self.iteration,
            rays: self.targets.len(),
            samples: self.traced.total_samples(),
            candidates,
            pruned: pruned.dropped,
            lr,
            elapsed,
            progress,
            ..Default::default()
        };
        let mut g_wq = [0.0f32; 2];
        for (r, t) in self.targets.iter().enumerate() {
            let c = &self.out.rays[r];
            let per = &self.out.nodes[r * nn..(r + 1) * nn];
            let share = &self.out.share[r * nn..(r + 1) * nn];
            s.distortion += (self.out.distortion[r] / self.extent) as f64;
            s.comp_rgb += losses::rgb(c.rgb, t.rgb).0 as f64;
            if t.masked {
                for (k, pk) in per.iter().enumerate() {
                    if is_object[k] {
                        let m = if t.mask_node == k as u32 { 1.0 } else { 0.0 };
                        s.obj_acc += losses::opacity(pk.opacity, m).0 as f64;
                        if m > 0.0 {
                            s.obj_rgb +=
                                losses::premultiplied_rgb(pk.rgb, pk.opacity, t.rgb).0 as f64;
                            s.obj_share += losses::share(share[k]).0 as f64;
                        }
                    }
                }
            }
            if let Some(b) = bg {
                let pw = t.prior_weight;
                if let Some(inp) = t.inpaint {
                    let (v, _, _) = losses::premultiplied_rgb(per[b].rgb, per[b].opacity, inp);
                    s.bg_rgb += (pw * v) as f64;
                }
                if let Some(d) = t.depth {
                    if self.opts.depth_affine {
                        let (v, _, gab) =
                            losses::affine_depth(per[b].depth, self.extent, self.depth_wq, d);
                        s.bg_depth += (pw * v) as f64;
                        g_wq[0] += pw * lam.bg_depth * gab[0] / n_rays;
                        g_wq[1] += pw * lam.bg_depth * gab[1] / n_rays;
                    } else {
                        let (v, _, _) =
                            losses::depth_moment(per[b].depth, per[b].depth_sq, self.extent, d);
                        s.bg_depth += (pw * v) as f64;
                    }
                }
            }
        }
        let nr = self.targets.len().max(1) as f64;
        s.comp_rgb /= nr;
        s.obj_acc /= nr;
        s.obj_rgb /= nr;
        s.obj_share /= nr;
        s.distortion /= nr;
        s.bg_rgb /= nr;
        s.bg_depth /= nr;
        s.loss = s.comp_rgb
            + lam.bg_rgb as f64 * s.bg_rgb
            + lam.bg_depth as f64 * s.bg_depth
            + lam.obj_acc as f64 * s.obj_acc
            + lam.obj_rgb as f64 * s.obj_rgb
            + lam.obj_share as f64 * s.obj_share
            + lam.distortion as f64 * s.distortion;
        s.psnr = crate::metrics::mse_to_psnr(s.comp_rgb);
        if !s.loss.is_finite() {
            return Err(TrainError::Diverged {
                iteration: self.iteration,
                message: format!("the loss became {}", s.loss),
                checkpoint: None,
            });
        }
        phase[2] = tp.elapsed().as_secs_f64();
        // Backward into each field, then Adam.
        for (ns, tape) in self.traced.nodes.iter().zip(self.tapes.iter_mut()) {
            if ns.is_empty() {
                continue;
            }
            let key = &self.scene.scene.nodes[ns.node].field;
            let nf = &self.scene.fields[key];
            let grad = self.grads.get_mut(key).expect("grad buffer per field");
            nf.field
                .backward(&ns.samples(), tape, &ns.d_sigma, &ns.d_rgb, grad);
        }
        phase[3] = tp.elapsed().as_secs_f64();
        for (key, nf) in self.scene.fields.iter_mut() {
            let nf = Arc::make_mut(nf);
            let grad = self.grads.get_mut(key).expect("grad buffer per field");
            self.adams
                .get_mut(key)
                .expect("adam per field")
                .update(lr, &mut nf.field.params, grad);
        }
        if bg.is_some() && lam.bg_depth > 0.0 && self.opts.depth_affine {
            update_depth_affine(&mut self.wq_adam, &mut self.depth_wq, &mut g_wq);
        }
        phase[4] = tp.elapsed().as_secs_f64();
        if self.opts.poison_at == Some(self.iteration) {
            for nf in self.scene.fields.values_mut() {
                let f = &mut Arc::make_mut(nf).field;
                let b = f.layout.color.last().expect("colour layers").b;
                f.params[b] = f32::NAN;
            }
        }
        self.iteration += 1;
        if self
            .iteration
            .is_multiple_of(self.opts.occupancy_every.max(1))
        {
            self.update_occupancy();
        }
        phase[5] = tp.elapsed().as_secs_f64();
        for i in (1..6).rev() {
            phase[i] -= phase[i - 1];
        }
        s.phase = phase;
        for (k, ns) in self.traced.nodes.iter().take(4).enumerate() {
            s.samples_per_ray[k] = ns.len() as f32 / s.rays.max(1) as f32;
        }
        // Adapt the ray count towards the target sample count.
        // A sample through the density pass costs about half a full one more (the
        // hash-grid encoding and the density net, no tape).
        let per_ray = (s.samples as f64 + 0.5 * pruned.queried as f64) / s.rays.max(1) as f64;
        let want = (self.opts.batch_samples as f64 / per_ray.max(1.0)) as usize;
        self.rays_per_batch = ((self.rays_per_batch + want) / 2).clamp(256, 1 << 16);
        Ok(s)
    }

    /// Refreshes every field's occupancy grid from its density.
    pub fn update_occupancy(&mut self) {
        let seed = self.opts.seed ^ self.iteration as u64;
        let round = self.iteration / self.opts.occupancy_every.max(1);
        for (i, nf) in self.scene.fields.values_mut().enumerate() {
            let nf = Arc::make_mut(nf);
            let mut rng = Rng::stream(seed, i as u64);
            nf.occupancy.update_round(&nf.field, &mut rng, round);
        }
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
            .values()
            .all(|f| f.field.params.par_iter().all(|v| v.is_finite()))
    }

    /// Training information written into the scene file (`info`).
    pub fn info(&self, elapsed: f64) -> serde_json::Value {
        serde_json::json!({
            "iteration": self.iteration,
            "elapsed_seconds": elapsed,
            "depth_scale_shift": self.depth_wq,
            "options": self.opts,
        })
    }

    /// Runs until the iteration or time budget is spent, calling `on_step` after each
    /// step; checkpoints atomically every `checkpoint_every` seconds when configured.
    pub fn run(&mut self, mut on_step: impl FnMut(&StepStats, &Trainer)) -> Result<TrainReport> {
        let start = Instant::now();
        let mut last_ckpt = Instant::now();
        let mut last = StepStats::default();
        let (mut rays, mut samples) = (0usize, 0usize);
        let mut phase_seconds = [0.0f64; 7];
        let mut saved: Option<PathBuf> = None;
        loop {
            let elapsed = self.elapsed_before + start.elapsed().as_secs_f64();
            if self.iteration >= self.opts.iters || self.opts.max_time.is_some_and(|t| elapsed >= t)
            {
                break;
            }
            match self.step(elapsed) {
                Ok(s) => {
                    rays += s.rays;
                    samples += s.samples;
                    for (t, p) in phase_seconds.iter_mut().zip(s.phase) {
                        *t += p;
                    }
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
            if let Some(dir) = &self.opts.checkpoint
                && last_ckpt.elapsed().as_secs_f64() >= self.opts.checkpoint_every
            {
                if self.is_finite() {
                    let el = self.elapsed_before + start.elapsed().as_secs_f64();
                    assist_render::scene_file::save(dir, &self.scene, self.info(el), true)?;
                    saved = Some(dir.clone());
                }
                last_ckpt = Instant::now();
            }
        }
        let secs = start.elapsed().as_secs_f64();
        phase_seconds[6] = secs - phase_seconds[..6].iter().sum::<f64>();
        Ok(TrainReport {
            iterations: self.iteration,
            seconds: self.elapsed_before + secs,
            final_stats: last,
            rays_per_sec: rays as f64 / secs.max(1e-9),
            samples_per_sec: samples as f64 / secs.max(1e-9),
            phase_seconds,
            depth_scale_shift: self.depth_wq,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_a_mask_excludes_are_never_drawn() {
        let camera = assist_core::Camera {
            intrinsics: assist_core::Intrinsics::from_fov_x(4, 2, 1.0),
            pose: assist_core::Pose::look_at(
                assist_core::DVec3::Z,
                assist_core::DVec3::ZERO,
                assist_core::DVec3::Y,
            )
            .unwrap(),
        };
        let view = |valid: Option<Vec<bool>>| View {
            name: "v".into(),
            camera,
            image_index: 0,
            width: 4,
            height: 2,
            rgb: vec![0.0; 24],
            ids: None,
            valid,
            depth: None,
            inpaint: None,
            inpaint_depth: None,
            prior_confidence: None,
        };
        // View 0: only pixel 5 is valid; view 1: all; view 2: none.
        let mut only5 = vec![false; 8];
        only5[5] = true;
        let views = [view(Some(only5)), view(None), view(Some(vec![false; 8]))];
        let mut rng = Rng::new(2);
        let mut seen = std::collections::BTreeSet::new();
        let mut left_out = 0;
        for _ in 0..4000 {
            match draw_pixel(&views, 24, &mut rng) {
                Some((vi, p)) => {
                    assert!(vi != 2 && (vi != 0 || p == 5), "drew ({vi}, {p})");
                    seen.insert((vi, p));
                }
                None => left_out += 1,
            }
        }
        // Every valid pixel is drawn; a ray is rarely left out (P = (15/24)^16).
        assert_eq!(seen.len(), 9);
        assert!(left_out < 10, "{left_out}");
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
