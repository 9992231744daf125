//! Camera-pose refinement (as nerfacto's camera optimizer does it, in our own terms): every
//! training view's pose gets a small learned correction — a translation of its centre and
//! a rotation of its rays about the centre, both in world axes — trained with the scene by
//! the same loss. A ray `(o, d)` of view `v` becomes `(o + τ_v, exp(ω_v) d)`.
//!
//! The gradient comes through the samples' positions: `x = o + t·d` for a sample at world
//! distance `t` (the sampling itself is held fixed, as in every NeRF), so `∂L/∂o = Σ ∂L/∂x`
//! and `∂L/∂d = Σ t ∂L/∂x` over the ray's samples in every node, and for a rotation
//! `∂L/∂ω = d × ∂L/∂d`. `∂L/∂x` is the field's position gradient (through its hash grid)
//! carried back through the node's map into its box — affine for objects, then the
//! contraction for a background. What the view direction does to the colour (through the
//! spherical harmonics) is left out: a rotation of a few tenths of a degree moves the
//! samples by far more than it changes a colour's view dependence.
//!
//! Held-out views keep the poses they were given (nothing is learned for them); the
//! corrections are reported in the scene's training info.

use assist_core::{DMat3, DVec3, NodeSpace};
use assist_field::Adam;
use assist_render::{RayBatch, Traced};
use assist_scene::NeuralScene;
use rayon::prelude::*;

/// Learning rate of the corrections at the start of the run (radians, and tenths of the
/// scene's extent for translations); it decays with the fields' schedule. Chosen on the
/// built-in scene with every training pose disturbed by 1° and 1 cm (BENCHMARKS.md).
pub const POSE_LR: f32 = 1e-3;

/// The corrections' gradient is taken, and they are stepped, every this many training
/// steps. Every step: every fourth (at twice the rate) recovered disturbed poses worse on
/// the built-in scene (rotations 0.57 against 0.92 cosine to the truth), although the
/// position gradient costs about as much as the hash-grid encoding.
pub const POSE_EVERY: usize = 1;

/// Translation parameters are in this many scene extents (the rotation's in radians), so
/// that one learning rate moves translations this much slower than rotations.
pub const TRANSLATION_SCALE: f64 = 0.1;

/// The learned corrections of every training view.
#[derive(Debug, Clone)]
pub struct PoseRefiner {
    /// Per view: translation in units of the scene extent (3), rotation vector (3).
    pub params: Vec<f32>,
    grad: Vec<f32>,
    adam: Adam,
    /// `exp(ω)` of each view, from `params`.
    rotations: Vec<DMat3>,
    extent: f64,
    /// Scratch: the position gradient of one node's samples.
    g: [Vec<f32>; 3],
}

/// The scene's extent: the diagonal of the box around every node's box (a contracted
/// background's inner box). The unit of the corrections' translations and of the
/// training's distance terms.
pub fn scene_extent(scene: &NeuralScene) -> f32 {
    let mut ext = assist_core::Aabb::empty();
    for n in &scene.scene.nodes {
        for c in n.world_corners() {
            ext.extend(c);
        }
    }
    ext.size().length().max(1e-6) as f32
}

/// `exp(ω)`: the rotation by `|ω|` radians about `ω`.
fn rotation(w: DVec3) -> DMat3 {
    let angle = w.length();
    if angle < 1e-12 {
        return DMat3::IDENTITY;
    }
    DMat3::from_axis_angle(w / angle, angle)
}

/// The contraction's vector–Jacobian product: given `g = ∂L/∂p` at `p =
/// contract_to_unit(u)`, returns `∂L/∂u` (`u` in box units, the box being [−1, 1]³).
pub fn contraction_vjp(u: DVec3, g: DVec3) -> DVec3 {
    let a = u.abs();
    let r = a.max_element();
    if r <= 1.0 {
        return 0.25 * g;
    }
    // c = s(r)·u, s = (2 − 1/r)/r; r = |u_m| for the largest axis m.
    let s = (2.0 - 1.0 / r) / r;
    let ds = -2.0 / (r * r) + 2.0 / (r * r * r);
    let m = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let mut out = s * g;
    out[m] += u[m].signum() * ds * u.dot(g);
    0.25 * out
}

impl PoseRefiner {
    pub fn new(views: usize, extent: f32) -> Self {
        let mut adam = Adam::new(6 * views);
        adam.eps = 1e-8;
        PoseRefiner {
            params: vec![0.0; 6 * views],
            grad: vec![0.0; 6 * views],
            adam,
            rotations: vec![DMat3::IDENTITY; views],
            extent: extent as f64 * TRANSLATION_SCALE,
            g: Default::default(),
        }
    }

    /// Takes saved corrections back (a resumed run); ignored when the view count differs.
    pub fn restore(&mut self, saved: &[f32]) {
        if saved.len() == self.params.len() {
            self.params.copy_from_slice(saved);
            self.step_rotations();
        }
    }

    fn step_rotations(&mut self) {
        for (v, r) in self.rotations.iter_mut().enumerate() {
            let p = &self.params[6 * v + 3..6 * v + 6];
            *r = rotation(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        }
    }

    /// View `v`'s correction: world translation and rotation.
    pub fn correction(&self, v: usize) -> (DVec3, DMat3) {
        let p = &self.params[6 * v..6 * v + 3];
        let t = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * self.extent;
        (t, self.rotations[v])
    }

    /// Applies view `v`'s correction to a ray.
    pub fn apply(&self, v: usize, ray: &mut assist_core::Ray) {
        let (t, r) = self.correction(v);
        ray.origin += t;
        ray.dir = (r * ray.dir).normalize();
    }

    /// Per view: the translation (in world units) and the rotation (degrees).
    pub fn summary(&self) -> Vec<(f64, f64)> {
        (0..self.rotations.len())
            .map(|v| {
                let p = &self.params[6 * v..6 * v + 6];
                let t = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * self.extent;
                let w = DVec3::new(p[3] as f64, p[4] as f64, p[5] as f64);
                (t.length(), w.length().to_degrees())
            })
            .collect()
    }

    /// Accumulates the gradient of the step's loss (after the fields' backward, whose tapes
    /// hold dL/d(encoding)) into the corrections of the views the rays came from.
    pub fn accumulate(
        &mut self,
        scene: &NeuralScene,
        traced: &Traced,
        tapes: &[assist_field::Tape],
        rays: &RayBatch,
        view_of_ray: &[u32],
    ) {
        let nr = rays.len();
        let mut g_o = vec![DVec3::ZERO; nr];
        let mut g_d = vec![DVec3::ZERO; nr];
        for (ns, tape) in traced.nodes.iter().zip(tapes) {
            if ns.is_empty() {
                continue;
            }
            let n = ns.len();
            for a in 0..3 {
                self.g[a].clear();
                self.g[a].resize(n, 0.0);
            }
            let nf = scene.field_of(ns.node);
            {
                let [gx, gy, gz] = &mut self.g;
                nf.field.position_grad(&ns.samples(), tape, [gx, gy, gz]);
            }
            let node = &scene.scene.nodes[ns.node];
            let wl = &node.world_from_local;
            // The linear part of local-from-world, as columns.
            let m = DMat3::from_cols(
                wl.local_from_world_vector(DVec3::X),
                wl.local_from_world_vector(DVec3::Y),
                wl.local_from_world_vector(DVec3::Z),
            );
            let mt = m.transpose();
            let contracted = nf.space == NodeSpace::Contracted;
            let (half, size) = (node.half_size, node.half_size * 2.0);
            let g = &self.g;
            let per_ray: Vec<(DVec3, DVec3)> = (0..nr)
                .into_par_iter()
                .map(|r| {
                    let (s0, s1) = (ns.start[r] as usize, ns.start[r + 1] as usize);
                    let (mut go, mut gd) = (DVec3::ZERO, DVec3::ZERO);
                    let o = DVec3::from(rays.origin[r].map(f64::from));
                    let d = DVec3::from(rays.dir[r].map(f64::from));
                    for j in s0..s1 {
                        let gp = DVec3::new(g[0][j] as f64, g[1][j] as f64, g[2][j] as f64);
                        if gp == DVec3::ZERO {
                            continue;
                        }
                        let gl = if contracted {
                            let x = o + ns.t[j] as f64 * d;
                            let u = wl.local_from_world_point(x) / half;
                            contraction_vjp(u, gp) / half
                        } else {
                            gp / size
                        };
                        let gw = mt * gl;
                        go += gw;
                        gd += ns.t[j] as f64 * gw;
                    }
                    (go, gd)
                })
                .collect();
            for (r, (go, gd)) in per_ray.into_iter().enumerate() {
                g_o[r] += go;
                g_d[r] += gd;
            }
        }
        for r in 0..nr {
            let v = view_of_ray[r] as usize;
            let d = DVec3::from(rays.dir[r].map(f64::from));
            let gw = d.cross(g_d[r]);
            let gt = g_o[r] * self.extent;
            for a in 0..3 {
                self.grad[6 * v + a] += gt[a] as f32;
                self.grad[6 * v + 3 + a] += gw[a] as f32;
            }
        }
    }

    /// One Adam step of the corrections (clears the gradient).
    pub fn step(&mut self, lr: f32) {
        self.adam.update(lr, &mut self.params, &mut self.grad);
        self.step_rotations();
    }

    /// The gradient accumulated so far (for tests).
    pub fn gradient(&self) -> &[f32] {
        &self.grad
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_field::contraction::contract_to_unit;

    #[test]
    fn the_contraction_vjp_matches_central_differences() {
        let mut rng = assist_core::Rng::new(4);
        for _ in 0..300 {
            let s = [0.5, 2.0, 20.0][rng.below(3) as usize];
            let u = DVec3::new(rng.normal(), rng.normal(), rng.normal()) * s;
            let g = DVec3::new(rng.normal(), rng.normal(), rng.normal());
            // The contraction in f64, checked against `contract_to_unit` (f32).
            let c64 = |u: DVec3| {
                let r = u.abs().max_element();
                let s = if r <= 1.0 { 1.0 } else { (2.0 - 1.0 / r) / r };
                (u * s + 2.0) * 0.25
            };
            let p32 = DVec3::from(contract_to_unit(u.as_vec3().to_array()).map(f64::from));
            assert!((p32 - c64(u)).length() < 1e-5);
            let f = |u: DVec3| c64(u).dot(g);
            let want = contraction_vjp(u, g);
            let h = 1e-3 * u.abs().max_element().max(1.0);
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = h;
                // Skip points where the largest axis changes within the step.
                let sorted = {
                    let mut v = u.abs().to_array();
                    v.sort_by(|x, y| x.total_cmp(y));
                    v
                };
                if sorted[2] - sorted[1] < 4.0 * h || (sorted[2] - 1.0).abs() < 4.0 * h {
                    continue;
                }
                let num = (f(u + e) - f(u - e)) / (2.0 * h);
                assert!(
                    (num - want[a]).abs() < 1e-5 * (1.0 + num.abs()),
                    "u {u} axis {a}: {} against {num}",
                    want[a]
                );
            }
        }
    }

    #[test]
    fn a_rotation_vector_rotates_about_itself() {
        let r = rotation(DVec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        let x = r * DVec3::X;
        assert!((x - DVec3::Y).length() < 1e-12);
        assert_eq!(rotation(DVec3::ZERO), DMat3::IDENTITY);
    }
}
