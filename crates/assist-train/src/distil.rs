//! A new object's field started from what another node's field (the background's) holds
//! inside the object's box: points drawn in the box, seen from the training cameras, and
//! the new field fitted to the source's density (as optical depth per marching step, on a
//! log scale) and colour (weighted by that step's opacity). `assist scene split` starts a
//! node cut out of a background trained without masks this way, so that its fine-tune
//! begins from the object the background already shows rather than from fog.

use assist_core::{DVec3, Rng, SceneNode};
use assist_field::{Adam, Samples, Tape};
use assist_scene::{NeuralScene, NodeField, STEPS_PER_DIAGONAL};

/// How long and how hard the new field is fitted.
#[derive(Debug, Clone, Copy)]
pub struct DistilOptions {
    pub steps: usize,
    /// Points per step.
    pub batch: usize,
    pub lr: f32,
    pub seed: u64,
}

impl Default for DistilOptions {
    fn default() -> Self {
        DistilOptions {
            steps: 600,
            batch: 1 << 13,
            lr: 1e-2,
            seed: 0,
        }
    }
}

/// How close the new field came, on the last step's points: the mean absolute difference
/// of `ln(1 + τ)` (τ the optical depth of one marching step) and the opacity-weighted
/// root mean square colour difference (0–1).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct DistilReport {
    pub steps: usize,
    pub density_error: f32,
    pub color_error: f32,
    pub seconds: f64,
}

/// Fits `target` (the field of `node`, a box node not yet in `scene`) to node `source` of
/// `scene` inside `node`'s box, viewed from the points `eyes` (the training cameras'
/// centres; the box centre's surroundings when empty).
pub fn distil(
    scene: &NeuralScene,
    source: usize,
    node: &SceneNode,
    target: &mut NodeField,
    eyes: &[DVec3],
    opts: &DistilOptions,
) -> DistilReport {
    let started = std::time::Instant::now();
    let mut rng = Rng::new(opts.seed);
    let w = node.world_from_local;
    let half = node.half_size;
    // Target σ per canonical diagonal from σ per world unit (see `density_at_world`).
    let node_per_world = (3.0 / w.scale.element_sum()) as f32 / target.unit;
    let field = &mut target.field;
    let mut adam = Adam::for_field(field);
    let mut grad = vec![0f32; field.layout.total];
    let mut tape = Tape::default();
    let n = opts.batch.max(1);
    let (mut pos, mut dir): ([Vec<f32>; 3], [Vec<f32>; 3]) = Default::default();
    let mut report = DistilReport {
        steps: opts.steps,
        density_error: 0.0,
        color_error: 0.0,
        seconds: 0.0,
    };
    for _ in 0..opts.steps {
        let mut world = Vec::with_capacity(n);
        let mut dirs = Vec::with_capacity(n);
        for a in 0..3 {
            pos[a].clear();
            dir[a].clear();
        }
        for _ in 0..n {
            let u = [rng.f32(), rng.f32(), rng.f32()];
            let local = DVec3::new(
                (u[0] as f64 - 0.5) * 2.0 * half.x,
                (u[1] as f64 - 0.5) * 2.0 * half.y,
                (u[2] as f64 - 0.5) * 2.0 * half.z,
            );
            let p = w.transform_point(local);
            let eye = match eyes.len() {
                0 => p + DVec3::new(rng.normal(), rng.normal(), rng.normal()),
                k => eyes[rng.below(k as u64) as usize],
            };
            let d = (p - eye).normalize_or(DVec3::Z);
            let dl = w.local_from_world_vector(d).normalize_or(DVec3::Z);
            for a in 0..3 {
                pos[a].push(u[a]);
                dir[a].push(dl[a] as f32);
            }
            world.push(p);
            dirs.push(d);
        }
        let (sigma_t, rgb_t) = scene.query_at_world(source, &world, Some(&dirs));
        let s = Samples {
            pos: [&pos[0], &pos[1], &pos[2]],
            dir: [&dir[0], &dir[1], &dir[2]],
            image: &[],
        };
        let mut sigma = vec![0f32; n];
        let mut rgb = vec![0f32; 3 * n];
        field.forward_train(&s, &mut tape, &mut sigma, &mut rgb);
        let mut d_sigma = vec![0f32; n];
        let mut d_rgb = vec![0f32; 3 * n];
        let (mut dens_err, mut col_err, mut col_w) = (0f64, 0f64, 0f64);
        for i in 0..n {
            let tau_t = sigma_t[i] / node_per_world / STEPS_PER_DIAGONAL;
            let tau = sigma[i] / STEPS_PER_DIAGONAL;
            let diff = tau.ln_1p() - tau_t.ln_1p();
            dens_err += diff.abs() as f64;
            d_sigma[i] = 2.0 * diff / (1.0 + tau) / STEPS_PER_DIAGONAL / n as f32;
            let weight = 1.0 - (-tau_t).exp();
            for c in 0..3 {
                let e = rgb[3 * i + c] - rgb_t[i][c];
                col_err += (weight * e * e) as f64;
                d_rgb[3 * i + c] = 2.0 * weight * e / n as f32;
            }
            col_w += 3.0 * weight as f64;
        }
        report.density_error = (dens_err / n as f64) as f32;
        report.color_error = (col_err / col_w.max(1e-12)).sqrt() as f32;
        field.backward(&s, &mut tape, &d_sigma, &d_rgb, &mut grad);
        adam.update(opts.lr, &mut field.params, &mut grad);
    }
    report.seconds = started.elapsed().as_secs_f64();
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_testkit::scenes;
    use std::sync::Arc;

    /// A new node over half of a dense red box (and the empty space beside it) takes the
    /// box's density and colour where the box is and stays empty elsewhere.
    #[test]
    fn a_distilled_field_reproduces_the_source_in_its_box() {
        let scene = scenes::two_boxes(0.1);
        let node = scenes::node(7, "part", 0.12, DVec3::new(-0.1, 0.0, 0.05));
        let mut target = assist_scene::NodeField::new(
            assist_field::Field::new(assist_field::FieldConfig::object(1), 7).unwrap(),
            assist_field::OccupancyGrid::new(16),
            node.half_size,
        );
        let eyes = [DVec3::new(0.0, -2.0, 0.5), DVec3::new(2.0, 0.3, 0.4)];
        let one = DistilOptions {
            steps: 1,
            ..Default::default()
        };
        let before = distil(&scene, 1, &node, &mut target.clone(), &eyes, &one);
        let after = distil(
            &scene,
            1,
            &node,
            &mut target,
            &eyes,
            &DistilOptions::default(),
        );
        assert!(
            after.density_error < 0.2 * before.density_error && after.color_error < 0.1,
            "{before:?} → {after:?}"
        );
        let mut both = scene.clone();
        both.scene.nodes.push(node.clone());
        both.fields.insert(node.field.clone(), Arc::new(target));
        let k = both.scene.nodes.len() - 1;
        // In the red box (which ends at x = −0.05), then beside it.
        let inside = [DVec3::new(-0.15, 0.0, 0.05), DVec3::new(-0.1, 0.05, 0.1)];
        let outside = [DVec3::new(0.0, 0.0, 0.05), DVec3::new(0.01, -0.08, 0.12)];
        let src = both.density_at_world(1, &inside);
        let dirs = [DVec3::X; 2];
        let (got, rgb) = both.query_at_world(k, &inside, Some(&dirs));
        for (a, b) in src.iter().zip(&got) {
            assert!((b / a - 1.0).abs() < 0.3, "source {a}, distilled {b}");
        }
        for c in &rgb {
            assert!((c[0] - 0.9).abs() < 0.1 && c[1] < 0.2, "colour {c:?}");
        }
        for (p, s) in outside.iter().zip(both.density_at_world(k, &outside)) {
            // Less than 1% opacity per marching step of the source's.
            assert!(s < 0.01 * src[0], "at {p}: {s} (the box's {})", src[0]);
        }
    }
}
