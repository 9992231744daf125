//! The scene's key light, found from the objects' learned shadows, so that a moved object's
//! shadow is re-cast under it ([`assist_render::light`]).
//!
//! Every object's shadow grid says, at the lattice points training saw, how much darker
//! the background is there because of the object. Under a lamp, part of that darkening is
//! the lamp hidden by the object: `1 − s ≈ k · (1 − V_L)`, with `V_L` the lamp's
//! visibility past the object (a shadow ray through the object's density) and `k` the
//! share of the light there that is the lamp's. The light is the lamp position (and disc
//! radius) for which that explains the grids best, `k` fitted per object and colour
//! channel in closed form: a coarse search over directions above the objects and
//! distances from them, then a pattern search, then the disc's radius. When no lamp
//! explains at least [`MIN_EXPLAINED`] of the darkening (diffuse light, no shadows), the
//! scene is given none and moved objects keep their shadows as learned.

use assist_core::{DVec3, KeyLight, SceneNode, ShadowCast, Similarity3};
use assist_render::light::{Occluder, light_points};
use assist_scene::{NeuralScene, NodeField};
use rayon::prelude::*;

/// Share of the grids' darkening (sum of squares of `1 − s` about each object's mean, over
/// the fitted points) a lamp must explain to be adopted: it must do better than a uniform
/// darkening of each object's surroundings. Desk's lamp explains 11%, the built-in
/// scene's 17%, a made-up lamp's exact shadows over 80%; speckle no lamp cast, −146%.
pub const MIN_EXPLAINED: f64 = 0.05;

/// Lowest a lamp may be seen from the objects' centre, above the horizon (radians): a
/// lamp at the horizon shadows everything and fits any uniform darkening.
const MIN_ELEVATION: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// Lattice points fitted per object at most (evenly strided over those training set).
const FIT_POINTS: usize = 1500;

/// What [`estimate_light`] found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LightEstimate {
    /// The light adopted, if one explains the shadows.
    pub light: Option<KeyLight>,
    /// The best lamp's share of the darkening explained beyond a uniform one per object
    /// (0 = none; adopted from [`MIN_EXPLAINED`]).
    pub explained: f64,
    /// Per object (node id) its strength per channel under the adopted light.
    pub strength: Vec<(u16, [f32; 3])>,
    /// Lattice points fitted over all objects.
    pub points: usize,
}

/// One object's fit data: its occluder and its learned points.
struct Fit<'a> {
    node: usize,
    occupancy: &'a assist_field::OccupancyGrid,
    half_size: DVec3,
    /// Where the grid was learned.
    pose: Similarity3,
    /// World positions of the fitted lattice points.
    points: Vec<DVec3>,
    /// `1 − s` per point: mean over channels and per channel.
    dark: Vec<f64>,
    dark_rgb: Vec<[f64; 3]>,
}

impl Fit<'_> {
    /// `1 − V` per point under `lights`.
    fn hidden(&self, lights: &[DVec3]) -> Vec<f64> {
        let occ = Occluder {
            occupancy: self.occupancy,
            half_size: self.half_size,
            pose: &self.pose,
        };
        self.points
            .iter()
            .map(|&p| 1.0 - occ.visibility(p, lights) as f64)
            .collect()
    }
}

/// Least-squares `k ∈ [0, 1]` of `b ≈ k·a` and its residual.
fn fit_k(a: &[f64], b: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let aa: f64 = a.iter().map(|x| x * x).sum();
    let ab: f64 = a.iter().zip(b.clone()).map(|(x, y)| x * y).sum();
    let k = if aa > 1e-12 {
        (ab / aa).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let res = a.iter().zip(b).map(|(x, y)| (y - k * x).powi(2)).sum();
    (k, res)
}

/// Sum over objects of the residual of the best `k` under `lights`.
fn residual(fits: &[Fit], lights: &[DVec3]) -> f64 {
    // Summed in order (rayon's `sum` associates by how the work was split: the same
    // lights could score differently from run to run).
    let each: Vec<f64> = fits
        .par_iter()
        .map(|f| fit_k(&f.hidden(lights), f.dark.iter().copied()).1)
        .collect();
    each.iter().sum()
}

/// `n` directions spread over the cap of the hemisphere about `up` from `min_elev`
/// radians above the horizon (a Fibonacci spiral).
fn cap_directions(up: DVec3, n: usize, min_elev: f64) -> Vec<DVec3> {
    let (e1, e2) = up.any_orthonormal_pair();
    let golden = std::f64::consts::PI * (3.0 - 5.0f64.sqrt());
    let zmin = min_elev.sin();
    (0..n)
        .map(|i| {
            let z = zmin + (1.0 - zmin) * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            e1 * (r * a.cos()) + e2 * (r * a.sin()) + up * z
        })
        .collect()
}

/// Finds the key light of `scene` from its objects' learned shadow grids and, when one
/// explains them, stores it in the scene with every caster's [`ShadowCast`] (the pose its
/// shadow was learned at — its [`ShadowCast`]'s if it has one, else its present pose —
/// and its strength). Objects without a shadow grid are left alone.
pub fn estimate_light(scene: &mut NeuralScene) -> LightEstimate {
    estimate_light_from(scene, |n| {
        Some(n.cast.as_ref().map_or(n.world_from_local, |c| c.pose))
    })
}

/// [`estimate_light`] with each object's pose where its shadow was learned given by
/// `learned_pose` (`None`: the object's grid was not learned in this scene — imported
/// from another — and is neither fitted nor given a cast).
pub fn estimate_light_from(
    scene: &mut NeuralScene,
    learned_pose: impl Fn(&SceneNode) -> Option<Similarity3>,
) -> LightEstimate {
    let up = scene.scene.up.normalize();
    // Each object's learned grid where it was learned (an edited scene's objects may
    // stand elsewhere now).
    let fits: Vec<Fit> = scene
        .scene
        .nodes
        .iter()
        .enumerate()
        .filter(|(_, n)| !n.is_background())
        .filter_map(|(node, n)| learned_shadow(scene.field_of(node), node, n, learned_pose(n)?))
        .collect();
    let points: usize = fits.iter().map(|f| f.points.len()).sum();
    // What a uniform darkening per object leaves unexplained: a lamp must do better than
    // that (one low enough to shadow every point fits any uniform darkening).
    let total: f64 = fits
        .iter()
        .map(|f| {
            let m = f.dark.iter().sum::<f64>() / f.dark.len() as f64;
            f.dark.iter().map(|b| (b - m).powi(2)).sum::<f64>()
        })
        .sum();
    let mut out = LightEstimate {
        light: None,
        explained: 0.0,
        strength: Vec::new(),
        points,
    };
    if fits.is_empty() || total <= 0.0 {
        return out;
    }
    // Where the objects are and how big: the search's origin and length scale.
    let centre = fits.iter().map(|f| f.pose.translation).sum::<DVec3>() / fits.len() as f64;
    let size = fits
        .iter()
        .map(|f| (f.half_size * f.pose.scale).length())
        .sum::<f64>()
        / fits.len() as f64;
    let (score, light) = search_light(&fits, centre, size, up);
    out.explained = 1.0 - score / total;
    if out.explained < MIN_EXPLAINED {
        return out;
    }
    // Strength per object and channel under the adopted light.
    let lights = light_points(&light, up);
    let strengths: Vec<(usize, ShadowCast)> = fits
        .par_iter()
        .map(|f| {
            let a = f.hidden(&lights);
            let strength =
                [0, 1, 2].map(|c| fit_k(&a, f.dark_rgb.iter().map(move |d| d[c])).0 as f32);
            (
                f.node,
                ShadowCast {
                    pose: f.pose,
                    strength,
                },
            )
        })
        .collect();
    drop(fits);
    scene.scene.light = Some(light);
    out.light = Some(light);
    for (k, cast) in strengths {
        let node = &mut scene.scene.nodes[k];
        out.strength.push((node.id, cast.strength));
        node.cast = Some(cast);
    }
    out
}

/// Where object `node`'s learned shadow grid (its shade values outside the box, away
/// from 1) lies in the world under `pose`, at most [`FIT_POINTS`] points, with how dark
/// each is; `None` when it has no shadow grid or nothing was learned.
fn learned_shadow<'a>(
    nf: &'a NodeField,
    node: usize,
    n: &SceneNode,
    pose: Similarity3,
) -> Option<Fit<'a>> {
    let g = nf.shade.as_ref()?;
    let r = g.res;
    let coord = |i: usize| (i as f64 / (r - 1) as f64 * 2.0 - 1.0) * g.extent as f64;
    let learned: Vec<usize> = (0..r * r * r)
        .filter(|&k| {
            let v = &g.values[3 * k..3 * k + 3];
            let b = [k % r, k / r % r, k / (r * r)].map(coord);
            b.iter().any(|x| x.abs() > 1.05) && v.iter().any(|&x| (x - 1.0).abs() > 1e-3)
        })
        .collect();
    if learned.is_empty() {
        return None;
    }
    let stride = learned.len().div_ceil(FIT_POINTS);
    let mut fit = Fit {
        node,
        occupancy: &nf.occupancy,
        half_size: n.half_size,
        pose,
        points: Vec::new(),
        dark: Vec::new(),
        dark_rgb: Vec::new(),
    };
    for &k in learned.iter().step_by(stride) {
        let b = DVec3::new(coord(k % r), coord(k / r % r), coord(k / (r * r)));
        fit.points.push(pose.transform_point(b * n.half_size));
        let v = &g.values[3 * k..3 * k + 3];
        let rgb = [0, 1, 2].map(|c| 1.0 - v[c] as f64);
        fit.dark.push(rgb.iter().sum::<f64>() / 3.0);
        fit.dark_rgb.push(rgb);
    }
    Some(fit)
}

/// The key light that best explains the fits' darkening, and its residual: directions
/// above the objects (at `centre`, of typical size `size`) × distances, a pattern search
/// about the best, then the disc's radius.
fn search_light(fits: &[Fit], centre: DVec3, size: f64, up: DVec3) -> (f64, KeyLight) {
    // Coarse: directions above the objects × distances from them.
    let mut best = (f64::INFINITY, centre + up * 8.0 * size);
    for d in cap_directions(up, 48, MIN_ELEVATION) {
        for dist in [4.0, 8.0, 16.0, 32.0, 64.0] {
            let l = centre + d * dist * size;
            let r = residual(fits, &[l]);
            if r < best.0 {
                best = (r, l);
            }
        }
    }
    // Pattern search about the best.
    let (mut score, mut pos) = best;
    let mut step = 0.25 * (pos - centre).length();
    for _ in 0..24 {
        let mut moved = false;
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            for sign in [-1.0, 1.0] {
                let l = pos + axis * sign * step;
                if (l - centre).normalize().dot(up) < MIN_ELEVATION.sin() {
                    continue;
                }
                let r = residual(fits, &[l]);
                if r < score {
                    (score, pos, moved) = (r, l, true);
                }
            }
        }
        if !moved {
            step *= 0.5;
            if step < 0.02 * (pos - centre).length() {
                break;
            }
        }
    }
    // The disc's radius.
    let dist = (pos - centre).length();
    let mut light = KeyLight {
        position: pos,
        radius: 0.0,
    };
    for f in [0.1, 0.2, 0.3] {
        let l = KeyLight {
            position: pos,
            radius: f * dist,
        };
        let r = residual(fits, &light_points(&l, up));
        if r < score {
            (score, light) = (r, l);
        }
    }
    (score, light)
}
