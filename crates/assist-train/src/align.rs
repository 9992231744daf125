//! Fitting a held-out view's camera to its photograph with the scene frozen: the
//! evaluation protocol for scenes whose poses are uncertain (COLMAP's draw, or a scene
//! trained with refined poses, whose frame drifts from the given one). The held-out
//! camera gets the same correction the training views get in [`crate::PoseRefiner`] — a
//! translation of its centre and a rotation of its rays — fitted by Adam on the
//! photometric loss of random pixels of its photograph; nothing of the scene changes.
//! Six numbers per view cannot learn what the view shows, only where it stands.

use assist_core::{Camera, DAffine3, Rng};
use assist_render::{
    BatchOutput, Behind, CompositeGrad, PRUNE_EPS, PruneBy, PruneScratch, Query, RayBatch,
    RayOutputs, SampleOptions, Traced, composite_batch, prune_occluded, query_fields, sample_rays,
    shade_background,
};
use assist_scene::NeuralScene;
use serde::Serialize;

use crate::trainer::{PoseRefiner, scene_extent};

/// How a camera is fitted.
#[derive(Debug, Clone, Copy)]
pub struct AlignOptions {
    /// Adam steps.
    pub steps: usize,
    /// Pixels drawn per step.
    pub rays: usize,
    /// Learning rate at the first step (radians, and tenths of the scene's extent, as
    /// [`crate::POSE_LR`]); it decays tenfold over the steps.
    pub lr: f32,
    pub seed: u64,
}

impl Default for AlignOptions {
    fn default() -> Self {
        AlignOptions {
            steps: 400,
            rays: 1024,
            lr: 2e-3,
            seed: 0,
        }
    }
}

/// Pixels of the fixed set the loss is measured on before and after fitting.
const CHECK_PIXELS: usize = 8192;

/// A fitted camera and what the fit did.
#[derive(Debug, Clone)]
pub struct Alignment {
    /// The camera with its correction (the given one when the fit did not lower the loss).
    pub camera: Camera,
    pub report: AlignReport,
}

#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct AlignReport {
    /// How far the centre moved (world units) and the rays turned (degrees).
    pub translation: f64,
    pub rotation_deg: f64,
    /// Mean squared error on a fixed set of the photograph's pixels, before and after.
    pub mse_before: f64,
    pub mse_after: f64,
    /// Whether the correction is used: false when the fit did not lower the loss on that
    /// set, and the given camera is kept.
    pub applied: bool,
}

/// Reused buffers of one fit.
#[derive(Default)]
struct Batch {
    rays: RayBatch,
    targets: Vec<[f32; 3]>,
    traced: Traced,
    tapes: Vec<assist_field::Tape>,
    out: BatchOutput,
    prune: PruneScratch,
}

impl Batch {
    /// Draws the rays of `pixels` (indices into the photograph) through the corrected
    /// camera.
    fn draw(
        &mut self,
        scene: &NeuralScene,
        camera: &Camera,
        rgb: &[f32],
        pixels: impl Iterator<Item = usize>,
        poses: &PoseRefiner,
    ) {
        self.rays.clear();
        self.rays.near = scene.scene.near as f32;
        self.targets.clear();
        let w = camera.width() as usize;
        for p in pixels {
            if let Some(mut ray) = camera.pixel_ray((p % w) as u32, (p / w) as u32) {
                poses.apply(0, &mut ray);
                self.rays.push(&ray, u32::MAX);
                self.targets
                    .push([rgb[3 * p], rgb[3 * p + 1], rgb[3 * p + 2]]);
            }
        }
    }

    /// Traces, queries and composites the drawn rays; with `grad`, the gradient of the
    /// mean squared error is left in the nodes' samples. Returns the mean squared error.
    /// `eye` is the held-out camera's centre: its samples take the novel view's
    /// appearance code seen from there, as its render does.
    fn run(
        &mut self,
        scene: &NeuralScene,
        seed: u64,
        jitter: bool,
        grad: bool,
        eye: [f64; 3],
    ) -> f64 {
        let so = SampleOptions {
            jitter,
            seed,
            max_per_node: 1024,
            step_scale: 1.0,
            keep_proposal: false,
        };
        sample_rays(scene, &self.rays, &so, &mut self.traced);
        // Samples behind surfaces weigh nothing in the loss or its gradient; the density
        // pass that finds them leaves the kept samples' encoding for the query.
        prune_occluded(
            scene,
            &mut self.traced,
            PRUNE_EPS,
            PruneBy::Ray,
            &mut self.prune,
            &mut self.tapes,
        );
        shade_background(scene, &self.rays, &mut self.traced);
        query_fields(
            scene,
            &mut self.traced,
            &mut self.tapes,
            Query::Fit { eye: Some(eye) },
        );
        let n = self.targets.len().max(1) as f32;
        let targets = &self.targets;
        let grad_fn = |o: &RayOutputs, g: &mut CompositeGrad, _: &mut [CompositeGrad]| {
            let (c, t) = (o.composite.rgb, targets[o.ray]);
            for k in 0..3 {
                g.rgb[k] = 2.0 * (c[k] - t[k]) / (3.0 * n);
            }
        };
        composite_batch(
            &mut self.traced,
            Behind::of(&scene.scene),
            &mut self.out,
            grad.then_some(&grad_fn as &assist_render::GradFn),
        );
        let se: f64 = self
            .out
            .rays
            .iter()
            .zip(&self.targets)
            .map(|(c, t)| {
                (0..3)
                    .map(|k| ((c.rgb[k] - t[k]) as f64).powi(2))
                    .sum::<f64>()
            })
            .sum();
        se / (3.0 * n as f64)
    }
}

/// Fits `camera` to its photograph `rgb` (interleaved, at the camera's size; `valid`
/// marks the pixels to use, `None` = all) with `scene` frozen.
pub fn align_camera(
    scene: &NeuralScene,
    camera: &Camera,
    rgb: &[f32],
    valid: Option<&[bool]>,
    opts: &AlignOptions,
) -> Alignment {
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    assert_eq!(rgb.len(), 3 * w * h, "align_camera: photograph size");
    let usable: Vec<usize> = match valid {
        Some(ok) => (0..w * h).filter(|&p| ok[p]).collect(),
        None => (0..w * h).collect(),
    };
    let mut poses = PoseRefiner::new(1, scene_extent(scene));
    let mut b = Batch::default();
    let mut rng = Rng::stream(opts.seed, 0);
    let check: Vec<usize> = (0..CHECK_PIXELS.min(usable.len()))
        .map(|_| usable[rng.below(usable.len() as u64) as usize])
        .collect();
    let unchanged = Alignment {
        camera: *camera,
        report: AlignReport {
            translation: 0.0,
            rotation_deg: 0.0,
            mse_before: f64::NAN,
            mse_after: f64::NAN,
            applied: false,
        },
    };
    if usable.is_empty() {
        return unchanged;
    }
    // The code of the given camera's place throughout, so that the fit moves the camera,
    // not the code it sees.
    let eye = camera.pose.center().to_array();
    b.draw(scene, camera, rgb, check.iter().copied(), &poses);
    let before = b.run(scene, opts.seed, false, false, eye);
    let no_views = vec![0u32; opts.rays];
    for step in 0..opts.steps {
        let mut rng = Rng::stream(opts.seed, 1 + step as u64);
        let pixels = (0..opts.rays).map(|_| usable[rng.below(usable.len() as u64) as usize]);
        b.draw(scene, camera, rgb, pixels, &poses);
        b.run(scene, opts.seed.wrapping_add(step as u64), true, true, eye);
        for (ns, tape) in b.traced.nodes.iter().zip(b.tapes.iter_mut()) {
            if !ns.is_empty() {
                let f = &scene.field_of(ns.node).field;
                f.backward_to_encoding(&ns.samples(), tape, &ns.d_sigma, &ns.d_rgb);
            }
        }
        let views = &no_views[..b.rays.len()];
        poses.accumulate(scene, &b.traced, &b.tapes, &b.rays, views);
        let progress = step as f32 / opts.steps.max(1) as f32;
        poses.step(opts.lr * 0.1f32.powf(progress));
    }
    b.draw(scene, camera, rgb, check.iter().copied(), &poses);
    let after = b.run(scene, opts.seed, false, false, eye);
    let (t, r) = poses.correction(0);
    // A NaN loss counts as not lowered.
    if after.partial_cmp(&before) != Some(std::cmp::Ordering::Less) {
        let mut a = unchanged;
        a.report.mse_before = before;
        a.report.mse_after = after;
        return a;
    }
    let mut fitted = *camera;
    fitted.pose.world_from_camera =
        DAffine3::from_mat3_translation(r * camera.pose.rotation(), camera.pose.center() + t);
    let (translation, rotation_deg) = poses.summary()[0];
    Alignment {
        camera: fitted,
        report: AlignReport {
            translation,
            rotation_deg,
            mse_before: before,
            mse_after: after,
            applied: true,
        },
    }
}
