//! One training step: the batch's rays traced through every node, the fields queried,
//! the composite with the objective's gradient, backward into the fields, shadow grids
//! and poses, and the optimizers' steps.

use std::sync::Arc;
use std::time::Instant;

use assist_field::Adam;
use assist_render::{CompositeGrad, RayOutputs, SampleOptions, composite_batch, sample_rays};

use super::objective::Objective;
use super::{
    EMPTY_MARGIN, POSE_EVERY, POSE_LR, PhaseTimes, StepStats, Trainer, update_depth_affine,
    warmed_lr,
};
use crate::error::{Result, TrainError};

/// A field's forward pass failed (on a GPU).
fn field_error(key: &str, e: String) -> TrainError {
    TrainError::Other(format!("the forward pass of field {key}: {e}"))
}

/// The share of the density pass's samples that must be dropped for the pass to pay: a
/// sample's density pass costs a fraction of its forward and backward passes, and the
/// compaction adds to it (the captures measured either way are in BENCHMARKS.md).
pub(crate) const PRUNE_PAYS: f64 = 0.3;

/// While pruning does not pay, every this many steps one runs the density pass to look
/// again (what lies behind surfaces grows as the scene sharpens).
pub(crate) const PRUNE_PROBE_EVERY: usize = 100;

impl Trainer {
    fn progress(&self, elapsed: f64) -> f64 {
        let by_iter = self.iteration as f64 / self.opts.iters.max(1) as f64;
        let by_time = self
            .opts
            .max_time
            .map(|t| elapsed / t.max(1e-9))
            .unwrap_or(0.0);
        by_iter.max(by_time).min(1.0)
    }

    /// One training step.
    pub fn step(&mut self, elapsed: f64) -> Result<StepStats> {
        let progress = self.progress(elapsed);
        let scheduled =
            self.opts.lr_start * (self.opts.lr_end / self.opts.lr_start).powf(progress as f32);
        let lr = warmed_lr(scheduled, self.iteration, self.warm_from, self.opts.iters);
        let tp = Instant::now();
        let mut phase = [0.0f64; 6];
        let (candidates, pruned) = self.trace()?;
        phase[0] = tp.elapsed().as_secs_f64();
        self.forward()?;
        self.note_densities();
        let interlevel = self.train_proposal(lr);
        phase[1] = tp.elapsed().as_secs_f64();
        // The step's figures; the losses come with the compositing.
        let mut s = StepStats {
            iteration: self.iteration,
            rays: self.targets.len(),
            samples: self.traced.total_samples(),
            candidates,
            pruned: pruned.dropped,
            interlevel: interlevel.unwrap_or(0.0),
            lr,
            elapsed,
            progress,
            ..Default::default()
        };
        let g_wq = self.composite_and_losses(&mut s)?;
        phase[2] = tp.elapsed().as_secs_f64();
        self.backward()?;
        phase[3] = tp.elapsed().as_secs_f64();
        self.update(lr, g_wq)?;
        phase[4] = tp.elapsed().as_secs_f64();
        if self.opts.poison_at == Some(self.iteration) {
            self.pull()?;
            for nf in self.scene.fields.values_mut() {
                Arc::make_mut(nf).field.poison();
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
        s.phase = PhaseTimes::from_marks(phase);
        for (k, ns) in self.traced.nodes.iter().take(4).enumerate() {
            s.samples_per_ray[k] = ns.len() as f32 / s.rays.max(1) as f32;
        }
        // Adapt the ray count towards the target sample count, for the next step's way of
        // tracing. A sample through the density pass costs about half a full one more (the
        // hash-grid encoding and the density net, no tape).
        let per_ray = if self.prune_pays {
            s.samples as f64 + 0.5 * pruned.queried as f64
        } else {
            (s.samples + pruned.dropped) as f64
        } / s.rays.max(1) as f64;
        let want = (self.opts.batch_samples as f64 / per_ray.max(1.0)) as usize;
        self.rays_per_batch = ((self.rays_per_batch + want) / 2).clamp(256, 1 << 16);
        Ok(s)
    }

    /// Draws the batch's rays and their samples in every node, drops those hidden behind
    /// opaque ones, and shades the background beyond: the candidates drawn and what the
    /// pruning did.
    fn trace(&mut self) -> Result<(usize, assist_render::PruneStats)> {
        self.draw_rays();
        let so = SampleOptions {
            jitter: true,
            seed: self.opts.seed.wrapping_add(self.iteration as u64 * 7919),
            max_per_node: 1024,
            step_scale: self.opts.step_scale,
            keep_proposal: true,
        };
        sample_rays(&self.scene, &self.rays, &so, &mut self.traced);
        let candidates = self.traced.total_samples();
        let probe = self.iteration.is_multiple_of(PRUNE_PROBE_EVERY);
        // A proposal's samples are kept whole: its loss pairs them with their spans.
        let drawn = self.traced.proposal.is_some();
        let pruned = if self.opts.prune_eps > 0.0 && !drawn && (self.prune_pays || probe) {
            // The density pass reads the fields on the CPU.
            self.pull()?;
            let p = assist_render::prune_occluded(
                &self.scene,
                &mut self.traced,
                self.opts.prune_eps,
                assist_render::PruneBy::Ray,
                &mut self.prune,
                &mut self.tapes,
            );
            self.prune_pays = p.dropped as f64 >= PRUNE_PAYS * p.queried.max(1) as f64;
            p
        } else {
            assist_render::PruneStats::default()
        };
        self.set_beyond();
        // Distortion in scene extents, bounded beyond one (a contracted background's far
        // samples lie up to a thousand extents away).
        self.traced.distortion_unit = self.extent;
        self.traced.hidden_stop = match self.background {
            Some(b) if self.opts.hidden_stop > 0.0 && self.traced.nodes.len() > 1 => {
                Some(assist_render::HiddenStop {
                    background: b,
                    below: self.opts.hidden_stop,
                })
            }
            _ => None,
        };
        assist_render::shade_background(&self.scene, &self.rays, &mut self.traced);
        Ok((candidates, pruned))
    }

    /// Composites the batch with the objective's gradient per sample, then sums the
    /// loss terms into `s` (per ray, averaged); returns the depth scale/shift gradient.
    fn composite_and_losses(&mut self, s: &mut StepStats) -> Result<[f32; 2]> {
        let nn = self.traced.nodes.len();
        let lam = self.opts.lambdas;
        let is_object: Vec<bool> = self
            .scene
            .scene
            .nodes
            .iter()
            .map(|n| !n.is_background())
            .collect();
        let objective = Objective {
            lam,
            n_rays: self.targets.len().max(1) as f32,
            extent: self.extent,
            background: self.background,
            depth_affine: self.opts.depth_affine,
            depth_wq: self.depth_wq,
            is_object: &is_object,
        };
        let targets = &self.targets;
        let grad_fn = |o: &RayOutputs, g: &mut CompositeGrad, gn: &mut [CompositeGrad]| {
            objective.ray(&targets[o.ray], o, Some((g, gn)));
        };
        composite_batch(
            &mut self.traced,
            assist_render::Behind::of(&self.scene.scene),
            &mut self.out,
            Some(&grad_fn),
        );
        let mut g_wq = [0.0f32; 2];
        let mut weights = 0.0f64;
        for (r, t) in self.targets.iter().enumerate() {
            let o = RayOutputs {
                ray: r,
                composite: &self.out.rays[r],
                nodes: &self.out.nodes[r * nn..(r + 1) * nn],
                share: &self.out.share[r * nn..(r + 1) * nn],
                distortion: self.out.distortion[r],
            };
            let v = objective.ray(t, &o, None);
            let w = f64::from(t.weight);
            weights += w;
            s.terms
                .zip_with(&v.map(|x| f64::from(x) * w), |a, b| *a += b);
            g_wq[0] += v.d_depth_wq[0];
            g_wq[1] += v.d_depth_wq[1];
        }
        s.terms = s.terms.map(|v| v / weights.max(1e-12));
        if self.error_map.is_on() {
            let rays = self.out.rays.iter().zip(&self.targets).zip(&self.ray_views);
            self.error_map.record(
                &self.views,
                rays.map(|((o, t), &vi)| {
                    (
                        vi as usize,
                        t.pixel as usize,
                        crate::losses::rgb(o.rgb, t.rgb).0,
                    )
                }),
            );
            if self.iteration.is_multiple_of(8) {
                self.error_map.rebuild();
            }
        }
        s.terms.normal = self.normal_loss();
        s.loss = s.terms.weighted(&lam);
        s.psnr = crate::metrics::mse_to_psnr(s.terms.comp_rgb);
        if !s.loss.is_finite() {
            return Err(TrainError::Diverged {
                iteration: self.iteration,
                message: format!("the loss became {}", s.loss),
                checkpoint: None,
            });
        }
        Ok(g_wq)
    }

    /// Backward from the samples into each field's optimizer, the shadow grids and
    /// (every POSE_EVERY steps) the camera poses; returns the shadow grids' gradients.
    /// The fields queried at the batch's samples: by the optimizers where they can (a
    /// GPU's, unless the poses are refined: that needs the CPU's tapes), else on the CPU.
    fn forward(&mut self) -> Result<()> {
        let q = assist_render::Query::Train;
        if self.poses.is_some() {
            self.pull()?;
            assist_render::query_fields(&self.scene, &mut self.traced, &mut self.tapes, q);
            return Ok(());
        }
        self.tapes
            .resize_with(self.traced.nodes.len(), Default::default);
        // Every node's pass started first (a GPU's run back to back; the CPU's nodes
        // meanwhile), then each collected.
        let mut started = vec![false; self.traced.nodes.len()];
        for (k, (ns, tape)) in self
            .traced
            .nodes
            .iter_mut()
            .zip(self.tapes.iter_mut())
            .enumerate()
        {
            let key = &self.scene.scene.nodes[ns.node].field;
            let opt = self.optimizers.get_mut(key).expect("optimizer per field");
            ns.prepare_outputs(true);
            if ns.is_empty() {
                continue;
            }
            match opt.forward_submit(&self.scene.fields[key], &ns.samples()) {
                Some(r) => {
                    r.map_err(|e| field_error(key, e))?;
                    started[k] = true;
                }
                None => assist_render::query_node(&self.scene, ns, tape, q),
            }
        }
        for (ns, _) in self
            .traced
            .nodes
            .iter_mut()
            .zip(started)
            .filter(|(_, s)| *s)
        {
            let key = &self.scene.scene.nodes[ns.node].field;
            let opt = self.optimizers.get_mut(key).expect("optimizer per field");
            opt.forward_finish(&mut ns.sigma, &mut ns.rgb)
                .map_err(|e| field_error(key, e))?;
        }
        Ok(())
    }

    fn backward(&mut self) -> Result<()> {
        for (ns, tape) in self.traced.nodes.iter().zip(self.tapes.iter_mut()) {
            if ns.is_empty() {
                continue;
            }
            let key = &self.scene.scene.nodes[ns.node].field;
            self.optimizers
                .get_mut(key)
                .expect("optimizer per field")
                .accumulate(
                    &self.scene.fields[key],
                    &ns.samples(),
                    tape,
                    &ns.d_sigma,
                    &ns.d_rgb,
                )
                .map_err(|e| TrainError::Other(format!("the gradient of field {key}: {e}")))?;
        }
        assist_render::shade_backward_add(
            &self.scene,
            &self.rays,
            &self.traced,
            &mut self.shade_grads,
        );
        let pose_step = self.iteration.is_multiple_of(POSE_EVERY);
        if let Some(p) = self.poses.as_mut().filter(|_| pose_step) {
            // The poses' gradient reads dL/d(encoding) from the CPU's tapes; where the
            // field's backward pass ran elsewhere (a GPU), the nets' runs here for it.
            for (ns, tape) in self.traced.nodes.iter().zip(self.tapes.iter_mut()) {
                let key = &self.scene.scene.nodes[ns.node].field;
                if !ns.is_empty() && !self.optimizers[key].fills_tape() {
                    let field = &self.scene.fields[key].field;
                    field.backward_to_encoding(&ns.samples(), tape, &ns.d_sigma, &ns.d_rgb);
                }
            }
            p.accumulate(
                &self.scene,
                &self.traced,
                &self.tapes,
                &self.rays,
                &self.ray_views,
            );
        }
        Ok(())
    }

    /// The optimizers' steps at learning rate `lr`: poses, fields, shadow grids (points
    /// held keep their factors) and the depth scale/shift.
    fn update(&mut self, lr: f32, mut g_wq: [f32; 2]) -> Result<()> {
        let pose_step = self.iteration.is_multiple_of(POSE_EVERY);
        if let Some(p) = self.poses.as_mut().filter(|_| pose_step) {
            p.step(POSE_LR * lr / self.opts.lr_start);
        }
        for (key, nf) in self.scene.fields.iter_mut() {
            self.optimizers
                .get_mut(key)
                .expect("optimizer per field")
                .step(Arc::make_mut(nf), lr)
                .map_err(|e| TrainError::Other(format!("the step of field {key}: {e}")))?;
        }
        for (k, g) in self.shade_grads.iter_mut() {
            let key = self.scene.scene.nodes[*k].field.clone();
            let nf = Arc::make_mut(self.scene.fields.get_mut(&key).expect("field of node"));
            if let Some(grid) = nf.shade.as_mut() {
                let held = self
                    .shade_held
                    .get(&key)
                    .filter(|h| 3 * h.len() == grid.values.len());
                let keep: Vec<f32> = held.map_or_else(Vec::new, |_| grid.values.clone());
                self.shade_adam
                    .entry(key)
                    .or_insert_with(|| Adam::new(grid.values.len()))
                    .update(lr, &mut grid.values, g);
                grid.clamp();
                if let Some(h) = held {
                    // Per lattice point: its three factors.
                    for ((v, k), &hold) in grid
                        .values
                        .chunks_exact_mut(3)
                        .zip(keep.chunks_exact(3))
                        .zip(h)
                    {
                        if hold {
                            v.copy_from_slice(k);
                        }
                    }
                }
            }
        }
        if self.background.is_some() && self.opts.lambdas.bg_depth > 0.0 && self.opts.depth_affine {
            update_depth_affine(&mut self.wq_adam, &mut self.depth_wq, &mut g_wq);
        }
        Ok(())
    }
}

/// Where the background must be opaque behind: this fraction of the prior's depth along
/// the ray (the margin absorbs the prior's depth error; what lies between is hidden by the
/// object that covers the pixel, or is the surface itself).
const BEYOND_FRACTION: f32 = 0.95;

impl Trainer {
    /// Sets `Traced::beyond` of every ray whose prior has a depth to
    /// [`BEYOND_FRACTION`] of it (in world distance along the ray, through the learnt
    /// scale and shift when the prior's depth has no scale); the background's opacity past
    /// it is what `Lambdas::bg_opacity` asks to be 1.
    fn set_beyond(&mut self) {
        self.traced.front.clear();
        if self.opts.lambdas.empty > 0.0 {
            let e = self.extent * (1.0 - EMPTY_MARGIN);
            self.traced.front.extend(
                self.targets
                    .iter()
                    .map(|t| t.surface.map_or(f32::NEG_INFINITY, |d| d * e)),
            );
        }
        self.traced.beyond.clear();
        let lam = &self.opts.lambdas;
        if self.background.is_none() || (lam.bg_opacity <= 0.0 && lam.bg_clear <= 0.0) {
            return;
        }
        let (e, wq) = (self.extent, self.depth_wq);
        let affine = self.opts.depth_affine;
        self.traced.beyond.extend(self.targets.iter().map(|t| {
            match (t.inpaint, t.depth.and_then(|d| prior_depth(d, affine, wq))) {
                (Some(_), Some(x)) => BEYOND_FRACTION * x * e,
                _ => f32::INFINITY,
            }
        }));
    }
}

/// The prior's depth `d` in units of the extent (`a·x + b = d` when its scale is learnt,
/// `wq = [a, b]`), or `None` where that gives no distance in front of the camera.
pub(super) fn prior_depth(d: f32, affine: bool, [a, b]: [f32; 2]) -> Option<f32> {
    let x = if affine { (d - b) / a } else { d };
    (x.is_finite() && x > 0.0).then_some(x)
}
