//! Objects' shadows on the background: each background sample's colour, in the composited
//! image, is multiplied channel by channel by the shadow grids
//! ([`assist_field::ShadeGrid`]) of the objects whose region it lies in, evaluated in each
//! object's own frame. Moving, turning, scaling
//! or deleting an object moves, turns, scales or removes its shadow; the background alone
//! (a node layer, or the scene without its objects) has none.

use assist_core::{DVec3, SceneNode};
use assist_field::ShadeGrid;
use assist_field::shade::Corners;
use std::sync::Arc;

use rayon::prelude::*;

use crate::sample::{RayBatch, Traced};
use assist_scene::NeuralScene;

/// An object that casts a shadow: its node index, its node and its grid.
pub struct Caster<'a> {
    pub node: usize,
    pub scene_node: &'a SceneNode,
    pub grid: CasterGrid<'a>,
    /// A world box holding the whole region (slightly grown): most samples lie outside
    /// it, and are known to be without a transform into the node's frame.
    bounds: (DVec3, DVec3),
}

/// The world box around `node`'s box grown `extent` times, grown by a relative margin so
/// that rounding never puts a point inside the region outside it.
fn region_bounds(node: &SceneNode, extent: f32) -> (DVec3, DVec3) {
    let h = node.half_size * extent as f64;
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for i in 0..8 {
        let c = DVec3::new(
            if i & 1 == 0 { -h.x } else { h.x },
            if i & 2 == 0 { -h.y } else { h.y },
            if i & 4 == 0 { -h.z } else { h.z },
        );
        let w = node.world_from_local.transform_point(c);
        lo = lo.min(w);
        hi = hi.max(w);
    }
    let pad = (hi - lo).max_element() * 1e-6 + 1e-9;
    (lo - pad, hi + pad)
}

/// A caster's shadow grid: the learned one, or the one re-cast for where the object
/// stands now ([`crate::light`]).
pub enum CasterGrid<'a> {
    Learned(&'a ShadeGrid),
    Recast(Arc<ShadeGrid>),
}

impl std::ops::Deref for CasterGrid<'_> {
    type Target = ShadeGrid;
    fn deref(&self) -> &ShadeGrid {
        match self {
            CasterGrid::Learned(g) => g,
            CasterGrid::Recast(g) => g,
        }
    }
}

impl Caster<'_> {
    /// Where world point `p` lies in the grid, if inside its region.
    #[inline]
    fn corners(&self, p: DVec3) -> Option<Corners> {
        let (lo, hi) = self.bounds;
        if p.cmplt(lo).any() || p.cmpgt(hi).any() {
            return None;
        }
        let l = self.scene_node.world_from_local.local_from_world_point(p);
        let c = (l / self.scene_node.half_size).as_vec3().to_array();
        self.grid.corners(c)
    }
}

/// The objects of `scene` that cast a shadow (those whose field has a shadow grid), each
/// with its grid re-cast under the scene's key light when it stands elsewhere than where
/// its shadow was learned ([`crate::light`]).
pub fn casters(scene: &NeuralScene) -> Vec<Caster<'_>> {
    let lights = scene
        .scene
        .light
        .map(|l| crate::light::light_points(&l, scene.scene.up));
    scene
        .scene
        .nodes
        .iter()
        .enumerate()
        .filter(|(_, n)| !n.is_background())
        .filter_map(|(k, n)| {
            let nf = scene.field_of(k);
            let learned = nf.shade.as_ref()?;
            let grid = match (&n.cast, &lights) {
                (Some(cast), Some(lights)) if cast.pose != n.world_from_local => {
                    CasterGrid::Recast(crate::light::recast_cached(
                        &n.field,
                        learned,
                        &nf.occupancy,
                        n.half_size,
                        &n.world_from_local,
                        cast,
                        lights,
                    ))
                }
                _ => CasterGrid::Learned(learned),
            };
            let bounds = region_bounds(n, grid.extent);
            Some(Caster {
                node: k,
                scene_node: n,
                grid,
                bounds,
            })
        })
        .collect()
}

/// The index of the background node, if the scene has one.
fn background(scene: &NeuralScene) -> Option<usize> {
    scene.scene.nodes.iter().position(|n| n.is_background())
}

/// Whether any object of `scene` casts a shadow.
pub fn casts_shadows(scene: &NeuralScene) -> bool {
    !casters(scene).is_empty()
}

/// World position of sample `j` of ray `r` (sample distances are world distances along
/// the ray's unit direction).
#[inline]
fn position(rays: &RayBatch, r: usize, t: f32) -> DVec3 {
    let o = DVec3::from(rays.origin[r].map(f64::from));
    let d = DVec3::from(rays.dir[r].map(f64::from));
    o + d * t as f64
}

/// `f(casters, world position)` of every sample of the background node, in order; `None`
/// when the scene has no background or no object casts a shadow.
fn per_background_sample<T: Send>(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &Traced,
    f: impl Fn(&[Caster], DVec3) -> T + Sync,
) -> Option<Vec<T>> {
    let ns = background(scene).and_then(|b| traced.nodes.get(b))?;
    let cs = casters(scene);
    if cs.is_empty() {
        return None;
    }
    let (cs, f) = (&cs, &f);
    Some(
        (0..traced.rays)
            .into_par_iter()
            .flat_map_iter(|r| ns.range(r).map(move |j| f(cs, position(rays, r, ns.t[j]))))
            .collect(),
    )
}

/// The background's shading at world point `p`: per channel, the product of the factors
/// of the casters whose region holds it, in their order.
fn shade_at(cs: &[Caster], p: DVec3) -> [f32; 3] {
    let mut f = [1.0f32; 3];
    for c in cs {
        if let Some(k) = c.corners(p) {
            let v = c.grid.at(&k);
            for ch in 0..3 {
                f[ch] *= v[ch];
            }
        }
    }
    f
}

/// Fills the background node's [`NodeSamples::shade`](crate::NodeSamples::shade) (three
/// factors per sample) from the objects' shadow grids (left empty — no shadow — when no
/// object has one). Call after sampling, before compositing.
pub fn shade_background(scene: &NeuralScene, rays: &RayBatch, traced: &mut Traced) {
    let shade = per_background_sample(scene, rays, traced, shade_at);
    if let Some(ns) = background(scene).and_then(|b| traced.nodes.get_mut(b)) {
        // Three factors per sample, replacing the previous ones.
        ns.shade.clear();
        if let Some(s) = shade {
            ns.shade.reserve(3 * s.len());
            for f in s {
                ns.shade.extend_from_slice(&f);
            }
        }
    }
}

/// After node `k` alone moved (it stood as `before`), the background samples' shading
/// again where it can have changed: inside `k`'s shadow region where it stands now or
/// where it stood (every other caster's grid is as it was). Each sample there gets the
/// product over all casters, in [`shade_background`]'s order (the same bits); `changed[r]`
/// is set for every ray `r` with a factor that changed. Returns false, doing nothing,
/// when the background's shading is not laid out as [`shade_background`] leaves it or `k`
/// casts no shadow (then shade everything again).
pub(crate) fn reshade_moved(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &mut Traced,
    k: usize,
    before: &SceneNode,
    changed: &mut [bool],
) -> bool {
    let Some(bi) = background(scene) else {
        return false;
    };
    let cs = casters(scene);
    let Some(moved) = cs.iter().find(|c| c.node == k) else {
        return false;
    };
    let Some(ns) = traced.nodes.get(bi) else {
        return false;
    };
    if ns.shade.len() != 3 * ns.t.len() {
        return false;
    }
    let extent = moved.grid.extent as f64;
    let regions = [
        (moved.scene_node, moved.bounds),
        (before, region_bounds(before, moved.grid.extent)),
    ];
    let in_region = |p: DVec3| {
        regions.iter().any(|&(n, (lo, hi))| {
            !(p.cmplt(lo).any() || p.cmpgt(hi).any()) && {
                let c = n.world_from_local.local_from_world_point(p) / n.half_size;
                c.abs().max_element() <= extent
            }
        })
    };
    let (cs, ns_ref) = (&cs, ns);
    // Per ray with a change, its samples' new factors.
    type Changes = Vec<(usize, [f32; 3])>;
    let updates: Vec<(usize, Changes)> = (0..traced.rays)
        .into_par_iter()
        .filter_map(|r| {
            let mut u = Vec::new();
            for j in ns_ref.range(r) {
                let p = position(rays, r, ns_ref.t[j]);
                if !in_region(p) {
                    continue;
                }
                let f = shade_at(cs, p);
                if ns_ref.shade[3 * j..3 * j + 3] != f {
                    u.push((j, f));
                }
            }
            (!u.is_empty()).then_some((r, u))
        })
        .collect();
    let ns = &mut traced.nodes[bi];
    for (r, u) in updates {
        changed[r] = true;
        for (j, f) in u {
            ns.shade[3 * j..3 * j + 3].copy_from_slice(&f);
        }
    }
    true
}

/// Backward of [`shade_background`]: from the background samples' `d_shade` (written by
/// `composite_batch`), the gradient of the loss with respect to each casting object's grid
/// values, as `(node index, gradient sized like its grid's values)`.
pub fn shade_backward(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &Traced,
) -> Vec<(usize, Vec<f32>)> {
    let cs = casters(scene);
    let Some(ns) = background(scene).and_then(|b| traced.nodes.get(b)) else {
        return Vec::new();
    };
    if cs.is_empty() || ns.d_shade.len() != 3 * ns.len() {
        return Vec::new();
    }
    // Each sample's contributions, gathered in sample order and summed in that order: the
    // same seed trains the same bits however the threads split the rays.
    let contributions: Vec<(u32, u32, [f32; 3])> = (0..traced.rays)
        .into_par_iter()
        .flat_map_iter(|r| {
            let mut out: Vec<(u32, u32, [f32; 3])> = Vec::new();
            let mut hit: Vec<(usize, Corners, [f32; 3])> = Vec::with_capacity(cs.len());
            for j in ns.range(r) {
                let g: [f32; 3] = ns.d_shade[3 * j..3 * j + 3].try_into().expect("3");
                if g == [0.0; 3] {
                    continue;
                }
                let p = position(rays, r, ns.t[j]);
                hit.clear();
                for (i, c) in cs.iter().enumerate() {
                    if let Some(k) = c.corners(p) {
                        hit.push((i, k, c.grid.at(&k)));
                    }
                }
                // d(Π s_i)/d s_i = Π_{other} s_j, channel by channel.
                for (a, &(i, ref k, _)) in hit.iter().enumerate() {
                    let mut gi = g;
                    for (b, h) in hit.iter().enumerate() {
                        if b != a {
                            for ch in 0..3 {
                                gi[ch] *= h.2[ch];
                            }
                        }
                    }
                    for q in 0..8 {
                        let w = k.weight[q];
                        out.push((i as u32, k.index[q], gi.map(|v| v * w)));
                    }
                }
            }
            out
        })
        .collect();
    let mut grads: Vec<Vec<f32>> = cs
        .iter()
        .map(|c| vec![0.0f32; c.grid.values.len()])
        .collect();
    for (i, idx, v) in contributions {
        let at = 3 * idx as usize;
        for ch in 0..3 {
            grads[i as usize][at + ch] += v[ch];
        }
    }
    cs.iter().map(|c| c.node).zip(grads).collect()
}
