//! A new object's field started from what another node's field (the background's) holds
//! inside the object's box: points drawn in the box, seen from the training cameras, and
//! the new field fitted to the source's density (as optical depth per marching step, on a
//! log scale) and colour (weighted by that step's opacity). `assist scene split` starts a
//! node cut out of a background trained without masks this way, so that its fine-tune
//! begins from the object the background already shows rather than from fog.

use assist_core::{DVec3, Obb, Rng, SceneNode};
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

impl DistilOptions {
    /// [`clear`]'s: gentler steps than a fresh field's, since every step moves the shared
    /// tables and nets of a trained field everywhere (at a fresh field's rate a desk's
    /// table top drifted far from every object).
    pub fn clearing() -> Self {
        DistilOptions {
            steps: 900,
            lr: 2e-3,
            ..Default::default()
        }
    }
}

impl Default for DistilOptions {
    fn default() -> Self {
        DistilOptions {
            steps: 1800,
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
/// `scene` inside `node`'s box where `owned` holds (world points; elsewhere in the box,
/// the support it stands on, to no density), viewed from the points `eyes` (the training
/// cameras' centres; the box centre's surroundings when empty).
pub fn distil(
    scene: &NeuralScene,
    source: usize,
    node: &SceneNode,
    target: &mut NodeField,
    owned: impl Fn(DVec3) -> bool,
    eyes: &[DVec3],
    opts: &DistilOptions,
) -> DistilReport {
    let started = std::time::Instant::now();
    let mut rng = Rng::new(opts.seed);
    let w = node.world_from_local;
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
    for step in 0..opts.steps {
        let mut world = Vec::with_capacity(n);
        let mut dirs = Vec::with_capacity(n);
        for a in 0..3 {
            pos[a].clear();
            dir[a].clear();
        }
        for _ in 0..n {
            let u = [rng.f32(), rng.f32(), rng.f32()];
            let p = assist_scene::world_position(node, assist_core::NodeSpace::Box, u);
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
        let (mut sigma_t, rgb_t) = scene.query_at_world(source, &world, Some(&dirs));
        for (s, p) in sigma_t.iter_mut().zip(&world) {
            if !owned(*p) {
                *s = 0.0;
            }
        }
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
        // The rate falls tenfold over the run, so that the fit settles into detail.
        let lr = opts.lr * 0.1f32.powf(step as f32 / opts.steps.max(1) as f32);
        adam.update(lr, &mut field.params, &mut grad);
    }
    report.seconds = started.elapsed().as_secs_f64();
    report
}

/// Regions grow by this factor around the cleared volume: the points drawn there that are
/// not cleared hold the field to what it was (the support under an object, the space and
/// surfaces around it).
const CLEAR_GROW: f64 = 1.5;

/// What [`clear`] achieved: the mean `ln(1 + τ)` (τ the optical depth of one marching
/// step) at the cleared points before and after, and the mean absolute change of it at
/// the points held around the regions.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct ClearReport {
    pub steps: usize,
    pub cleared_before: f32,
    pub cleared_after: f32,
    pub held_change: f32,
    /// The same at the points drawn in the field's occupied cells anywhere.
    pub held_elsewhere: f32,
    pub seconds: f64,
}

/// Empties node `index` of `scene` where `cleared` holds: points drawn in `regions`
/// (world boxes, grown by [`CLEAR_GROW`]) and in the field's occupied cells, seen from
/// `eyes`, its field fitted to no density where `cleared` holds and elsewhere to its own
/// density and colour as they were.
/// `assist scene split` clears the background inside each new object this way: the
/// object's field took over what the background held there, and a copy left in the
/// background shows as a ghost where the object stood once it moves.
pub fn clear(
    scene: &mut NeuralScene,
    index: usize,
    regions: &[Obb],
    cleared: impl Fn(DVec3) -> bool,
    eyes: &[DVec3],
    opts: &DistilOptions,
) -> ClearReport {
    let started = std::time::Instant::now();
    let mut report = ClearReport {
        steps: opts.steps,
        ..Default::default()
    };
    if regions.is_empty() {
        return report;
    }
    let node = scene.scene.nodes[index].clone();
    let key = node.field.clone();
    let Some(nf) = scene.fields.get_mut(&key) else {
        return report;
    };
    let nf = std::sync::Arc::make_mut(nf);
    // A proposal drawn for the field as it was would not find what the clearing fills:
    // the node is marched at every step again (a later `train --proposal` draws anew).
    nf.proposal = None;
    let space = nf.space;
    let teacher = nf.field.clone();
    let field = &mut nf.field;
    let mut rng = Rng::new(opts.seed);
    let mut adam = Adam::for_field(field);
    let mut grad = vec![0f32; field.layout.total];
    let mut tape = Tape::default();
    let n = opts.batch.max(1);
    // The field's occupied cells everywhere: half the points are drawn there, so that what
    // the clearing moves through the shared hash tables and nets is held across the whole
    // scene, not only around the regions (held there alone, a desk's table top drifted).
    let occupied: Vec<u32> = (0..nf.occupancy.cells())
        .filter(|&c| nf.occupancy.is_occupied_cell(c))
        .map(|c| c as u32)
        .collect();
    let res = nf.occupancy.res as usize;
    let near = if occupied.is_empty() {
        n
    } else {
        n.div_ceil(2)
    };
    for step in 0..opts.steps {
        let (mut pos, mut dir): ([Vec<f32>; 3], [Vec<f32>; 3]) = Default::default();
        let mut empty = Vec::with_capacity(n);
        while empty.len() < n {
            let (p, at) = if empty.len() < near {
                let b = &regions[rng.below(regions.len() as u64) as usize];
                let u = DVec3::new(rng.f32() as f64, rng.f32() as f64, rng.f32() as f64);
                let p = b.center + b.rotation * ((u * 2.0 - 1.0) * b.half_size * CLEAR_GROW);
                let Some(at) = assist_scene::field_position(&node, space, p) else {
                    continue;
                };
                (p, at)
            } else {
                let c = occupied[rng.below(occupied.len() as u64) as usize] as usize;
                let idx = [c % res, (c / res) % res, c / (res * res)];
                let at = [0, 1, 2].map(|a| (idx[a] as f32 + rng.f32()) / res as f32);
                (assist_scene::world_position(&node, space, at), at)
            };
            let eye = match eyes.len() {
                0 => p + DVec3::new(rng.normal(), rng.normal(), rng.normal()),
                k => eyes[rng.below(k as u64) as usize],
            };
            let d = node
                .world_from_local
                .local_from_world_vector((p - eye).normalize_or(DVec3::Z))
                .normalize_or(DVec3::Z);
            for a in 0..3 {
                pos[a].push(at[a]);
                dir[a].push(d[a] as f32);
            }
            empty.push(cleared(p));
        }
        let s = Samples {
            pos: [&pos[0], &pos[1], &pos[2]],
            dir: [&dir[0], &dir[1], &dir[2]],
            image: &[],
        };
        let (mut sigma_t, mut rgb_t) = (vec![0f32; n], vec![0f32; 3 * n]);
        teacher.forward(&s, &mut sigma_t, &mut rgb_t);
        let (mut sigma, mut rgb) = (vec![0f32; n], vec![0f32; 3 * n]);
        field.forward_train(&s, &mut tape, &mut sigma, &mut rgb);
        let (mut d_sigma, mut d_rgb) = (vec![0f32; n], vec![0f32; 3 * n]);
        let (mut gone, mut was, mut n_gone, mut moved, mut n_held) = (0f64, 0f64, 0, 0f64, 0);
        let (mut moved_far, mut n_far) = (0f64, 0);
        for i in 0..n {
            let tau = sigma[i] / STEPS_PER_DIAGONAL;
            let tau_was = sigma_t[i] / STEPS_PER_DIAGONAL;
            let tau_t = if empty[i] { 0.0 } else { tau_was };
            let diff = tau.ln_1p() - tau_t.ln_1p();
            d_sigma[i] = 2.0 * diff / (1.0 + tau) / STEPS_PER_DIAGONAL / n as f32;
            if empty[i] {
                gone += tau.ln_1p() as f64;
                was += tau_was.ln_1p() as f64;
                n_gone += 1;
                continue;
            }
            if i < near {
                moved += diff.abs() as f64;
                n_held += 1;
            } else {
                moved_far += diff.abs() as f64;
                n_far += 1;
            }
            let weight = 1.0 - (-tau_t).exp();
            for c in 0..3 {
                d_rgb[3 * i + c] = 2.0 * weight * (rgb[3 * i + c] - rgb_t[3 * i + c]) / n as f32;
            }
        }
        let mean = |x: f64, k: usize| (x / k.max(1) as f64) as f32;
        if step == 0 {
            report.cleared_before = mean(was, n_gone);
        }
        report.cleared_after = mean(gone, n_gone);
        report.held_change = mean(moved, n_held);
        report.held_elsewhere = mean(moved_far, n_far);
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

    /// The scene of two boxes, a new node over half of its red box (and the space beside
    /// it), a fresh field for the node, and two eyes.
    fn over_the_red_box() -> (NeuralScene, SceneNode, NodeField, [DVec3; 2]) {
        let scene = scenes::two_boxes(0.1);
        let node = scenes::node(7, "part", 0.12, DVec3::new(-0.1, 0.0, 0.05));
        let target = assist_scene::NodeField::new(
            assist_field::Field::new(assist_field::FieldConfig::object(1), 7).unwrap(),
            assist_field::OccupancyGrid::new(16),
            node.half_size,
        );
        let eyes = [DVec3::new(0.0, -2.0, 0.5), DVec3::new(2.0, 0.3, 0.4)];
        (scene, node, target, eyes)
    }

    /// A new node over half of a dense red box (and the empty space beside it) takes the
    /// box's density and colour where the box is and it owns (above z = 0), and stays
    /// empty elsewhere: beside the box, and in the box's part below z = 0 it leaves to the
    /// source (as an object leaves the table it stands on to the background).
    #[test]
    fn a_distilled_field_reproduces_the_source_where_it_owns_it() {
        let (scene, node, mut target, eyes) = over_the_red_box();
        let one = DistilOptions {
            steps: 1,
            ..Default::default()
        };
        let before = distil(&scene, 1, &node, &mut target.clone(), |_| true, &eyes, &one);
        let after = distil(
            &scene,
            1,
            &node,
            &mut target,
            |p| p.z > 0.0,
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
        let outside = [
            DVec3::new(0.0, 0.0, 0.05),
            DVec3::new(0.01, -0.08, 0.12),
            DVec3::new(-0.12, 0.0, -0.03),
            DVec3::new(-0.1, 0.05, -0.05),
        ];
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

    /// A field distilled from the red box, then cleared over the box's far half: empty
    /// there, and the near half as dense as before.
    #[test]
    fn a_cleared_field_is_empty_where_told_and_unchanged_beside_it() {
        let (scene, node, mut target, eyes) = over_the_red_box();
        let quick = DistilOptions {
            steps: 250,
            ..Default::default()
        };
        distil(&scene, 1, &node, &mut target, |_| true, &eyes, &quick);
        let mut part = scene.clone();
        part.scene.nodes.push(node.clone());
        part.fields.insert(node.field.clone(), Arc::new(target));
        let k = part.scene.nodes.len() - 1;
        let far = [DVec3::new(-0.2, 0.0, 0.05), DVec3::new(-0.19, 0.05, 0.1)];
        let near = [DVec3::new(-0.09, 0.0, 0.05), DVec3::new(-0.1, -0.05, 0.1)];
        let (far_before, near_before) = (
            part.density_at_world(k, &far),
            part.density_at_world(k, &near),
        );
        let red = assist_core::Obb::new(
            DVec3::new(-0.15, 0.0, 0.05),
            DVec3::splat(0.2),
            assist_core::glam::DMat3::IDENTITY,
        );
        let report = clear(&mut part, k, &[red], |p| p.x < -0.15, &eyes, &quick);
        assert!(
            report.cleared_after < 0.05 * report.cleared_before,
            "{report:?}"
        );
        for (a, b) in far_before.iter().zip(part.density_at_world(k, &far)) {
            assert!(b < 0.01 * a, "cleared: {a} → {b}");
        }
        for (a, b) in near_before.iter().zip(part.density_at_world(k, &near)) {
            assert!((b / a - 1.0).abs() < 0.3, "held: {a} → {b}");
        }
        // The other nodes' fields are untouched.
        for (key, f) in &scene.fields {
            assert!(Arc::ptr_eq(f, &part.fields[key]), "{key}");
        }
    }
}
