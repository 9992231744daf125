//! The background's shading again after one object alone moved (a viewer's drag). Only
//! the samples its shadow grid shades, where it stands now or where it stood, can change;
//! every other caster is where it was. What a drag keeps between updates ([`Kept`]): which
//! samples the moved grid shaded last time, and what the other casters give each sample
//! once looked up. A sample that at most one other caster shades gets the product of that
//! factor and the moved grid's, which is [`crate::shade`]'s product over all casters to
//! the bit (the factors of exactly 1 drop out, and two factors multiply in either order to
//! the same bits); one that two or more others shade gets the whole product again.

use assist_core::SceneNode;
use assist_field::{LitCells, ShadeGrid};
use rayon::prelude::*;

use crate::sample::{RayBatch, Traced};
use crate::shade::{
    BoxRay, Caster, RAYS_PER_TASK, RayCaster, background, box_bounds, ray_casters, ray_span,
};
use assist_scene::NeuralScene;

/// What the other casters give a sample: not looked up yet, or two or more of them shade
/// it (the first channel holds the mark; a factor lies in `[MIN_SHADE, 1]`).
const UNKNOWN: f32 = f32::NAN;
const MANY: f32 = -1.0;

/// What a drag keeps about one batch's background samples between updates.
#[derive(Default)]
pub(crate) struct Kept {
    /// The samples the moved node's grid shaded at the last update, ascending (`None`:
    /// not known, found from the node as it stood).
    shaded: Option<Vec<u32>>,
    /// Per sample, the factors of the casters other than the moved one where at most one
    /// of them shades it ([`UNKNOWN`], [`MANY`]).
    others: Vec<[f32; 3]>,
}

impl Kept {
    /// Forgets which samples the moved grid shaded (after the background was shaded
    /// whole again); what the other casters give is kept.
    pub(crate) fn forget_shaded(&mut self) {
        self.shaded = None;
    }
}

/// [`crate::shade::shade_at`] with each caster's cells that shade nothing (`lits`, one per
/// caster of `cs`) skipped: the same bits, since such a cell's factor is exactly 1.
#[inline]
fn shade_at_lit(cs: &[Caster], lits: &[&LitCells], hit: &[RayCaster], t: f32) -> [f32; 3] {
    let mut f = [1.0f32; 3];
    let tt = t as f64;
    for &(i, (a, b), br) in hit {
        if tt < a || tt > b {
            continue;
        }
        if let Some(v) = cs[i].grid.shading_at(lits[i], br.at(t)) {
            for ch in 0..3 {
                f[ch] *= v[ch];
            }
        }
    }
    f
}

/// What the casters but `m` give the sample at `t`: the one factor that differs from 1,
/// `[1; 3]` when none does, [`MANY`] when two or more do.
#[inline]
fn others_at(cs: &[Caster], lits: &[&LitCells], hit: &[RayCaster], m: usize, t: f32) -> [f32; 3] {
    let (mut f, mut n) = ([1.0f32; 3], 0);
    let tt = t as f64;
    for &(i, (a, b), br) in hit {
        if i == m || tt < a || tt > b {
            continue;
        }
        if let Some(v) = cs[i].grid.shading_at(lits[i], br.at(t)) {
            n += 1;
            if n > 1 {
                return [MANY; 3];
            }
            f = v;
        }
    }
    f
}

/// The world box around the cells of `grid`, posed as `node`, that shade (`None`: none).
fn active_bounds(
    grid: &ShadeGrid,
    node: &SceneNode,
    lit: &LitCells,
) -> Option<(assist_core::DVec3, assist_core::DVec3)> {
    lit.active_box(grid.extent).map(|b| box_bounds(node, b))
}

/// Rays per task, each task's share of a per-sample slice.
fn task_rays(rays: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    (0..rays.div_ceil(RAYS_PER_TASK))
        .map(move |task| task * RAYS_PER_TASK..((task + 1) * RAYS_PER_TASK).min(rays))
}

/// The background samples (`t`, `start` as in [`crate::sample::NodeSamples`]) that
/// `grid`, posed as `node` with `lit` its cells that shade nothing, shades: ascending.
fn shaded_by(
    rays: &RayBatch,
    (t, start): (&[f32], &[u32]),
    grid: &ShadeGrid,
    node: &SceneNode,
    lit: &LitCells,
) -> Vec<u32> {
    let Some(bounds) = active_bounds(grid, node, lit) else {
        return Vec::new();
    };
    let n = start.len() - 1;
    let parts: Vec<Vec<u32>> = task_rays(n)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|rs| {
            let mut out = Vec::new();
            for r in rs {
                let Some((a, b)) = ray_span(rays, r, bounds) else {
                    continue;
                };
                let br = BoxRay::new(node, rays, r);
                for j in start[r] as usize..start[r + 1] as usize {
                    let tj = t[j];
                    if (a..=b).contains(&(tj as f64)) && !grid.shades_nothing_at(lit, br.at(tj)) {
                        out.push(j as u32);
                    }
                }
            }
            out
        })
        .collect();
    parts.concat()
}

/// After node `k` alone moved (it stood as `before`, its grid's cells that shade nothing
/// then `before_lit`), the background samples' shading again where it can have changed:
/// where `k`'s grid shades, where it stands now or where it stood. `cs` are the casters
/// ([`crate::shade::casters`]) and `lits` each one's cells that shade nothing where it
/// stands now; `kept` what the last update of this batch left. Each such sample gets the
/// bits [`crate::shade::shade_background`] would give it; `changed[r]` is set for every
/// ray `r` with a factor that changed. Returns false, doing nothing, when the background's
/// shading is not laid out as `shade_background` leaves it or `k` casts no shadow (then
/// shade everything again).
#[allow(clippy::too_many_arguments)]
pub(crate) fn reshade_moved(
    scene: &NeuralScene,
    rays: &RayBatch,
    traced: &mut Traced,
    (cs, lits): (&[Caster], &[&LitCells]),
    k: usize,
    (before, before_lit): (&SceneNode, &LitCells),
    kept: &mut Kept,
    changed: &mut [bool],
) -> bool {
    let Some(bi) = background(scene) else {
        return false;
    };
    let Some(m) = cs.iter().position(|c| c.node == k) else {
        return false;
    };
    let Some(ns) = traced.nodes.get_mut(bi) else {
        return false;
    };
    let n = ns.t.len();
    if ns.shade.len() != 3 * n || lits.len() != cs.len() || changed.len() != traced.rays {
        return false;
    }
    let (moved, now_lit) = (&cs[m], lits[m]);
    let grid = &moved.grid;
    let (t, start) = (&ns.t[..], &ns.start[..]);
    let prev = match kept.shaded.take() {
        Some(p) => p,
        None => shaded_by(rays, (t, start), grid, before, before_lit),
    };
    if kept.others.len() != n {
        kept.others = vec![[UNKNOWN; 3]; n];
    }
    let now_bounds = active_bounds(grid, moved.scene_node, now_lit);
    // Each task's rays with their flags, their samples' factors, what the other casters
    // give them and the samples shaded last time, split off in order: the tasks write in
    // place.
    let mut tasks = Vec::new();
    let (mut shade, mut flags) = (&mut ns.shade[..], changed);
    let (mut others, mut prev_rest) = (&mut kept.others[..], &prev[..]);
    for rs in task_rays(traced.rays) {
        let samples = (start[rs.end] - start[rs.start]) as usize;
        let (sh, rest) = std::mem::take(&mut shade).split_at_mut(3 * samples);
        shade = rest;
        let (fl, rest) = std::mem::take(&mut flags).split_at_mut(rs.len());
        flags = rest;
        let (oth, rest) = std::mem::take(&mut others).split_at_mut(samples);
        others = rest;
        let (pv, rest) = prev_rest.split_at(prev_rest.partition_point(|&j| j < start[rs.end]));
        prev_rest = rest;
        tasks.push((rs, sh, fl, oth, pv));
    }
    let parts: Vec<Vec<u32>> = tasks
        .into_par_iter()
        .map(|(rs, sh, fl, oth, pv)| {
            let base = start[rs.start] as usize;
            let (mut p, mut hit, mut now) = (0, Vec::new(), Vec::new());
            for r in rs.clone() {
                let (s0, s1) = (start[r] as usize, start[r + 1] as usize);
                let span = now_bounds.and_then(|b| ray_span(rays, r, b));
                if span.is_none() && pv.get(p).is_none_or(|&j| j as usize >= s1) {
                    continue;
                }
                let br = BoxRay::new(moved.scene_node, rays, r);
                let mut met = false;
                for j in s0..s1 {
                    let was = pv.get(p) == Some(&(j as u32));
                    p += was as usize;
                    let tj = t[j];
                    let vk = match span {
                        Some((a, b)) if (a..=b).contains(&(tj as f64)) => {
                            grid.shading_at(now_lit, br.at(tj))
                        }
                        _ => None,
                    };
                    if vk.is_none() && !was {
                        continue;
                    }
                    if vk.is_some() {
                        now.push(j as u32);
                    }
                    let o = &mut oth[j - base];
                    if o[0].is_nan() || o[0] == MANY {
                        if !met {
                            ray_casters(rays, r, cs, &mut hit);
                            met = true;
                        }
                        if o[0].is_nan() {
                            *o = others_at(cs, lits, &hit, m, tj);
                        }
                    }
                    let f = if o[0] == MANY {
                        shade_at_lit(cs, lits, &hit, tj)
                    } else {
                        let v = vk.unwrap_or([1.0; 3]);
                        [o[0] * v[0], o[1] * v[1], o[2] * v[2]]
                    };
                    let at = 3 * (j - base);
                    if sh[at..at + 3] != f {
                        sh[at..at + 3].copy_from_slice(&f);
                        fl[r - rs.start] = true;
                    }
                }
            }
            now
        })
        .collect();
    kept.shaded = Some(parts.concat());
    true
}
