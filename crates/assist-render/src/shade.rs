//! Objects' shadows on the background: each background sample's colour, in the composited
//! image, is multiplied channel by channel by the shadow grids
//! ([`assist_field::ShadeGrid`]) of the objects whose region it lies in, evaluated in each
//! object's own frame. Moving, turning, scaling
//! or deleting an object moves, turns, scales or removes its shadow; the background alone
//! (a node layer, or the scene without its objects) has none.

use assist_core::{DVec3, SceneNode};
use assist_field::shade::Corners;
use assist_field::{LitCells, ShadeGrid};
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
    let e = extent as f64;
    box_bounds(node, ([-e; 3], [e; 3]))
}

/// The world box around the part `(lo, hi)` (box units) of `node`'s box, grown by a
/// relative margin as [`region_bounds`]'s.
pub(crate) fn box_bounds(node: &SceneNode, (lo, hi): ([f64; 3], [f64; 3])) -> (DVec3, DVec3) {
    let (lo, hi) = (
        DVec3::from(lo) * node.half_size,
        DVec3::from(hi) * node.half_size,
    );
    let mut wlo = DVec3::splat(f64::INFINITY);
    let mut whi = DVec3::splat(f64::NEG_INFINITY);
    for i in 0..8 {
        let c = DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let w = node.world_from_local.transform_point(c);
        wlo = wlo.min(w);
        whi = whi.max(w);
    }
    let pad = (whi - wlo).max_element() * 1e-6 + 1e-9;
    (wlo - pad, whi + pad)
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

/// A ray in a box's own units (the box spans `[−1, 1]³`): `c(t) = o + t·d` for `t` the
/// world distance along the ray. Found once per ray and caster, so that each sample costs
/// three products instead of a transform into the box's frame; every path that shades a
/// sample (render, drag, training's backward) finds its place this way, to the same bits.
#[derive(Clone, Copy)]
pub(crate) struct BoxRay {
    o: DVec3,
    d: DVec3,
}

impl BoxRay {
    pub(crate) fn new(node: &SceneNode, rays: &RayBatch, r: usize) -> Self {
        let (o, d) = ray(rays, r);
        let pose = &node.world_from_local;
        BoxRay {
            o: pose.local_from_world_point(o) / node.half_size,
            d: pose.local_from_world_vector(d) / node.half_size,
        }
    }

    #[inline]
    pub(crate) fn at(&self, t: f32) -> [f32; 3] {
        (self.o + self.d * t as f64).as_vec3().to_array()
    }
}

/// Origin and unit direction of ray `r`, in f64.
fn ray(rays: &RayBatch, r: usize) -> (DVec3, DVec3) {
    (
        DVec3::from(rays.origin[r].map(f64::from)),
        DVec3::from(rays.dir[r].map(f64::from)),
    )
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
pub(crate) fn background(scene: &NeuralScene) -> Option<usize> {
    scene.scene.nodes.iter().position(|n| n.is_background())
}

/// Whether any object of `scene` casts a shadow.
pub fn casts_shadows(scene: &NeuralScene) -> bool {
    !casters(scene).is_empty()
}

/// The stretch of ray `r` (distances along its unit direction) inside the world box
/// `(lo, hi)`, widened a little so that rounding never leaves out a sample whose position
/// lies inside; `None` when the ray's line misses the box.
pub(crate) fn ray_span(rays: &RayBatch, r: usize, (lo, hi): (DVec3, DVec3)) -> Option<(f64, f64)> {
    let (o, d) = ray(rays, r);
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (u, v) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        t0 = t0.max(u.min(v));
        t1 = t1.min(u.max(v));
    }
    let pad = 1e-6 * (1.0 + t0.abs().max(t1.abs()));
    (t0 <= t1).then_some((t0 - pad, t1 + pad))
}

/// A caster ray `r` can meet: its index, the stretch of the ray through the world box
/// around its region, and the ray in its box's units.
pub(crate) type RayCaster = (usize, (f64, f64), BoxRay);

/// The casters ray `r` can meet, in their order, into `out`.
pub(crate) fn ray_casters(rays: &RayBatch, r: usize, cs: &[Caster], out: &mut Vec<RayCaster>) {
    ray_casters_over(rays, r, cs, (f64::NEG_INFINITY, f64::INFINITY), out);
}

/// [`ray_casters`] for samples at distances within `(t0, t1)` only: a caster whose
/// stretch of the ray misses that range shades none of them ([`shade_at`] passes it by),
/// so it is left out before its ray in box units is found.
fn ray_casters_over(
    rays: &RayBatch,
    r: usize,
    cs: &[Caster],
    (t0, t1): (f64, f64),
    out: &mut Vec<RayCaster>,
) {
    out.clear();
    for (i, c) in cs.iter().enumerate() {
        if let Some(span) = ray_span(rays, r, c.bounds)
            && span.0 <= t1
            && span.1 >= t0
        {
            out.push((i, span, BoxRay::new(c.scene_node, rays, r)));
        }
    }
}

/// The background's shading at distance `t` along a ray that meets `hit` (as
/// [`ray_casters`] finds them): per channel, the product of the factors of the casters
/// whose region holds the point, in their order.
#[inline]
pub(crate) fn shade_at(cs: &[Caster], hit: &[RayCaster], t: f32) -> [f32; 3] {
    let mut f = [1.0f32; 3];
    let tt = t as f64;
    for &(i, (a, b), br) in hit {
        if tt < a || tt > b {
            continue;
        }
        let g = &cs[i].grid;
        if let Some(k) = g.corners(br.at(t)) {
            let v = g.at(&k);
            for ch in 0..3 {
                f[ch] *= v[ch];
            }
        }
    }
    f
}

/// Rays per parallel task of the shading passes.
pub(crate) const RAYS_PER_TASK: usize = 256;

/// Fills the background node's [`NodeSamples::shade`](crate::NodeSamples::shade) (three
/// factors per sample) from the objects' shadow grids (left empty — no shadow — when no
/// object has one). Call after sampling, before compositing.
pub fn shade_background(scene: &NeuralScene, rays: &RayBatch, traced: &mut Traced) {
    let Some(bi) = background(scene).filter(|&b| b < traced.nodes.len()) else {
        return;
    };
    let cs = casters(scene);
    let mut shade = std::mem::take(&mut traced.nodes[bi].shade);
    // Three factors per sample, replacing the previous ones.
    shade.clear();
    if !cs.is_empty() {
        let (ns, cs) = (&traced.nodes[bi], &cs);
        let parts: Vec<Vec<f32>> = (0..traced.rays.div_ceil(RAYS_PER_TASK))
            .into_par_iter()
            .map(|task| {
                let rs = task * RAYS_PER_TASK..((task + 1) * RAYS_PER_TASK).min(traced.rays);
                let mut out =
                    Vec::with_capacity(3 * (ns.start[rs.end] - ns.start[rs.start]) as usize);
                let mut hit = Vec::new();
                for r in rs {
                    let js = ns.range(r);
                    if js.is_empty() {
                        continue;
                    }
                    // The casters whose stretch of the ray holds a sample of it.
                    let (near, far) = ns.t[js.clone()]
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &t| {
                            (a.min(t), b.max(t))
                        });
                    ray_casters_over(rays, r, cs, (near as f64, far as f64), &mut hit);
                    for j in js {
                        out.extend_from_slice(&shade_at(cs, &hit, ns.t[j]));
                    }
                }
                out
            })
            .collect();
        shade.reserve(3 * ns.t.len());
        for p in parts {
            shade.extend_from_slice(&p);
        }
    }
    traced.nodes[bi].shade = shade;
}

/// The cells of node `k`'s shadow grid, as [`casters`] finds it where `k` stands now,
/// that shade nothing (`None` when `k` casts no shadow).
pub(crate) fn lit_cells_of(cs: &[Caster], k: usize) -> Option<LitCells> {
    cs.iter().find(|c| c.node == k).map(|c| c.grid.lit_cells())
}

/// Backward of [`shade_background`]: from the background samples' `d_shade` (written by
/// `composite_batch`), the gradient of the loss with respect to each casting object's grid
/// values, as `(node index, gradient sized like its grid's values)`.
pub fn shade_backward(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &Traced,
) -> Vec<(usize, Vec<f32>)> {
    let mut grads = Vec::new();
    shade_backward_add(scene, rays, traced, &mut grads);
    grads
}

/// [`shade_backward`] into buffers kept between calls (a trainer's): `grads` is made to
/// hold one `(node index, gradient)` per caster, in [`casters`]' order, each gradient
/// sized like its grid's values (kept where node and size already match, else replaced by
/// zeros), and each sample's contributions are added to it. Each caster's gradient is
/// summed by one thread in ray, sample and corner order: the same bits however the
/// threads split the work, and without a list of every contribution in between.
pub fn shade_backward_add(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &Traced,
    grads: &mut Vec<(usize, Vec<f32>)>,
) {
    let cs = casters(scene);
    let bg = background(scene).and_then(|b| traced.nodes.get(b));
    let Some(ns) = bg.filter(|ns| !cs.is_empty() && ns.d_shade.len() == 3 * ns.len()) else {
        grads.clear();
        return;
    };
    let fits = grads.len() == cs.len()
        && grads
            .iter()
            .zip(&cs)
            .all(|((k, g), c)| *k == c.node && g.len() == c.grid.values.len());
    if !fits {
        *grads = cs
            .iter()
            .map(|c| (c.node, vec![0.0f32; c.grid.values.len()]))
            .collect();
    }
    cs.par_iter()
        .enumerate()
        .zip(grads.par_iter_mut())
        .for_each(|((me, c), (_, out))| {
            let mut hit: Vec<(usize, Corners, [f32; 3])> = Vec::with_capacity(cs.len());
            let mut meets = Vec::new();
            for r in 0..traced.rays {
                // Whether the ray meets this caster's region at all, before the others'.
                if ray_span(rays, r, c.bounds).is_none() {
                    continue;
                }
                ray_casters(rays, r, &cs, &mut meets);
                let Some(&(_, (a0, b0), _)) = meets.iter().find(|m| m.0 == me) else {
                    continue;
                };
                for j in ns.range(r) {
                    let t = ns.t[j];
                    if !(a0..=b0).contains(&(t as f64)) {
                        continue;
                    }
                    let g: [f32; 3] = ns.d_shade[3 * j..3 * j + 3].try_into().expect("3");
                    if g == [0.0; 3] {
                        continue;
                    }
                    hit.clear();
                    for &(i, (a, b), br) in &meets {
                        let ci = &cs[i].grid;
                        if (a..=b).contains(&(t as f64))
                            && let Some(k) = ci.corners(br.at(t))
                        {
                            hit.push((i, k, ci.at(&k)));
                        }
                    }
                    let Some(a) = hit.iter().position(|h| h.0 == me) else {
                        continue;
                    };
                    // d(Π s_i)/d s_i = Π_{other} s_j, channel by channel.
                    let mut gi = g;
                    for (b, h) in hit.iter().enumerate() {
                        if b != a {
                            for ch in 0..3 {
                                gi[ch] *= h.2[ch];
                            }
                        }
                    }
                    let k = &hit[a].1;
                    for q in 0..8 {
                        let w = k.weight[q];
                        let v = gi.map(|v| v * w);
                        let at = 3 * k.index[q] as usize;
                        for ch in 0..3 {
                            out[at + ch] += v[ch];
                        }
                    }
                }
            }
        });
}
