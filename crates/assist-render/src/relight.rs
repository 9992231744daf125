//! Objects shaded by the room's light where they stand now. A node's colours were learned
//! under the light that fell on it where it was photographed (its [`ShadowCast`] pose);
//! turned, its lit side would turn with it. With the scene's key light known, a sample's
//! colour is taken as albedo times irradiance, and the irradiance at the learned pose is
//! exchanged for the one at the present pose (in linear light, the field's colours being
//! sRGB like the photographs):
//!
//! `E(n, p) = (1 − s)·A(n)/A(up) + s·K(n, p)/K(up, p₀)`
//!
//! with `s` the key light's share of the light on an upward surface (per channel: fitted
//! to how the object's learned colours vary with `A` and `K` over its surface, see
//! [`fit_strength`]; else its shadow's [`ShadowCast::strength`]), `A(n) = 1 + n·up / 2` a
//! sky-like ambient term
//! brighter from above, and `K(n, p)` the key light's cosine-weighted, distance-attenuated
//! visibility from the surface point `p` with normal `n` through the object's own density
//! (self-shadowing), normalised by that on an unoccluded upward surface at the object's
//! learned place `p₀`. Normals are the object's density gradient (its occupancy grid's
//! estimate, smoothed). The factors `E(now)/E(then)` are taken on a lattice over the box
//! and interpolated per sample; where the density has no gradient (empty space, deep
//! inside) the factor is 1.

use std::sync::Arc;

use assist_core::{DVec3, ShadowCast, Similarity3};
use assist_field::OccupancyGrid;
use rayon::prelude::*;

use crate::light::Occluder;

mod node;
pub(crate) use node::relight_node;

/// Lattice points per axis at most (an object's shading varies smoothly).
const MAX_RES: usize = 32;

/// The weakest opacity gradient (per lattice cell) that gives a normal.
const MIN_GRADIENT: f32 = 0.02;

/// The factors' range: a surface the key light never reached at its learned pose has only
/// the ambient term there, so the factor stays finite.
const FACTOR_RANGE: (f32, f32) = (0.05, 8.0);

/// Relighting factors on an `res³` lattice spanning the node's box (x fastest), three per
/// point (linear light).
#[derive(Debug, Clone, PartialEq)]
pub struct RelightGrid {
    pub res: usize,
    pub factors: Vec<f32>,
}

impl RelightGrid {
    /// The factors at `u` (the box scaled to `[0, 1]³`, as samples' positions are),
    /// trilinear between lattice points.
    pub fn at(&self, u: [f32; 3]) -> [f32; 3] {
        let n = self.res;
        let f = |a: usize| {
            let x = (u[a].clamp(0.0, 1.0) * (n - 1) as f32).min((n - 1) as f32);
            let i = (x.floor() as usize).min(n - 2);
            (i, x - i as f32)
        };
        let ((x0, fx), (y0, fy), (z0, fz)) = (f(0), f(1), f(2));
        let mut out = [0.0f32; 3];
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, corner >> 1 & 1, corner >> 2 & 1);
            let w = if dx == 1 { fx } else { 1.0 - fx }
                * if dy == 1 { fy } else { 1.0 - fy }
                * if dz == 1 { fz } else { 1.0 - fz };
            let k = 3 * ((x0 + dx) + n * ((y0 + dy) + n * (z0 + dz)));
            for c in 0..3 {
                out[c] += w * self.factors[k + c];
            }
        }
        out
    }

    /// `rgb` (sRGB, three per sample) relit: each sample's colour in linear light times
    /// its factors at `pos` (box `[0, 1]³` coordinates, one array per axis).
    pub fn apply(&self, pos: &[Vec<f32>; 3], rgb: &mut [f32]) {
        rgb.par_chunks_mut(3 * 1024)
            .enumerate()
            .for_each(|(b, chunk)| {
                for (i, px) in chunk.chunks_exact_mut(3).enumerate() {
                    let j = b * 1024 + i;
                    let f = self.at([pos[0][j], pos[1][j], pos[2][j]]);
                    for c in 0..3 {
                        px[c] = to_srgb(to_linear(px[c]) * f[c]);
                    }
                }
            });
    }
}

fn to_linear(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

fn to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Lattice points per axis for an occupancy grid of `res` cells per axis.
fn lattice_res(res: usize) -> usize {
    res.clamp(2, MAX_RES)
}

/// Opacity per lattice point: the occupancy grid's density over one lattice cell, box
/// filtered over the point's neighbours (densities are noisy; normals want a smooth
/// field). A cell never measured counts as opaque.
fn opacity(occ: &OccupancyGrid, half_size: DVec3, n: usize) -> Vec<f32> {
    let res = occ.res as usize;
    let cell = (2.0 * half_size.max_element() / n as f64) as f32;
    let raw: Vec<f32> = (0..n * n * n)
        .map(|k| {
            let idx = |i: usize| ((i as f64 + 0.5) / n as f64 * res as f64) as usize;
            let c = idx(k % n).min(res - 1)
                + res * (idx(k / n % n).min(res - 1) + res * idx(k / (n * n)).min(res - 1));
            let s = occ.density[c];
            if s.is_finite() {
                1.0 - (-s.max(0.0) * cell).exp()
            } else {
                1.0
            }
        })
        .collect();
    let at = |x: isize, y: isize, z: isize| {
        let cl = |v: isize| v.clamp(0, n as isize - 1) as usize;
        raw[cl(x) + n * (cl(y) + n * cl(z))]
    };
    (0..n * n * n)
        .map(|k| {
            let (x, y, z) = (
                (k % n) as isize,
                (k / n % n) as isize,
                (k / (n * n)) as isize,
            );
            let mut s = 0.0;
            for d in 0..27isize {
                s += at(x + d % 3 - 1, y + d / 3 % 3 - 1, z + d / 9 - 1);
            }
            s / 27.0
        })
        .collect()
}

/// The relighting factors of an object posed at `now` whose colours were learned at
/// `cast.pose`, under the key light sampled at `lights` (world points; see
/// [`crate::light::light_points`]); `up` is the scene's up.
pub fn relight_grid(
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    now: &Similarity3,
    cast: &ShadowCast,
    lights: &[DVec3],
    up: DVec3,
) -> RelightGrid {
    let learned = learned_light(occupancy, half_size, &cast.pose, lights, up);
    combine(
        learned.as_ref(),
        occupancy,
        half_size,
        now,
        cast,
        lights,
        up,
    )
}

/// An object's surface on the lattice (index, box-frame position and outward normal of
/// each point the opacity has a gradient at) and the light on it where it was learned:
/// the ambient and the key terms, the key normalised by the unoccluded upward surface at
/// the learned place.
pub(crate) struct Learned {
    n: usize,
    points: Vec<(usize, DVec3, DVec3)>,
    reference: f64,
    terms: Vec<(f32, f32)>,
}

/// [`Learned`] for an object learned at `pose`; `None` without a density grid or a lamp
/// above the object.
fn learned_light(
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    pose: &Similarity3,
    lights: &[DVec3],
    up: DVec3,
) -> Option<Learned> {
    if occupancy.res == 0 || occupancy.density.len() != (occupancy.res as usize).pow(3) {
        return None;
    }
    let up = up.normalize();
    let reference = key(pose.translation, up, lights, None);
    if reference <= 0.0 || lights.is_empty() {
        return None;
    }
    let n = lattice_res(occupancy.res as usize);
    let alpha = opacity(occupancy, half_size, n);
    let points: Vec<(usize, DVec3, DVec3)> = (0..n * n * n)
        .into_par_iter()
        .filter_map(|k| surface_at(&alpha, n, half_size, k).map(|(c, nl)| (k, c, nl)))
        .collect();
    let mut l = Learned {
        n,
        points,
        reference,
        terms: Vec::new(),
    };
    l.terms = terms(&l, occupancy, half_size, pose, lights, up);
    Some(l)
}

/// The ambient and normalised key terms at every surface point of `l`, the object posed
/// at `pose`.
fn terms(
    l: &Learned,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    pose: &Similarity3,
    lights: &[DVec3],
    up: DVec3,
) -> Vec<(f32, f32)> {
    let o = Occluder {
        occupancy,
        half_size,
        pose,
    };
    let out = (2.0 * half_size / l.n as f64).max_element() * 1.5;
    let up = up.normalize();
    l.points
        .par_iter()
        .map(|&(_, c, nl)| {
            // Shadow rays leave the surface a cell and a half out, past its own density.
            let (amb, key) = light_at(pose, &o, c + nl * out, nl, lights, up);
            (amb as f32, (key / l.reference) as f32)
        })
        .collect()
}

/// The factors `E(now) / E(then)` at `learned`'s surface points (1 elsewhere).
fn combine(
    learned: Option<&Learned>,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    now: &Similarity3,
    cast: &ShadowCast,
    lights: &[DVec3],
    up: DVec3,
) -> RelightGrid {
    let n = learned.map_or(lattice_res(occupancy.res as usize), |l| l.n);
    let mut grid = RelightGrid {
        res: n,
        factors: vec![1.0; 3 * n * n * n],
    };
    let Some(l) = learned else {
        return grid;
    };
    let here = terms(l, occupancy, half_size, now, lights, up);
    for ((&(k, _, _), &(amb0, key0)), &(amb1, key1)) in l.points.iter().zip(&l.terms).zip(&here) {
        for ch in 0..3 {
            let s = cast.strength[ch].clamp(0.0, 1.0);
            let e0 = (1.0 - s) * amb0 + s * key0;
            let e1 = (1.0 - s) * amb1 + s * key1;
            grid.factors[3 * k + ch] = (e1 / e0.max(1e-6)).clamp(FACTOR_RANGE.0, FACTOR_RANGE.1);
        }
    }
    grid
}

/// Lattice point `k`'s position in the box's frame and the outward normal there (the
/// opacity's falling gradient, per local unit: the lattice's cells may differ per axis),
/// when the opacity has a gradient there.
fn surface_at(alpha: &[f32], n: usize, half_size: DVec3, k: usize) -> Option<(DVec3, DVec3)> {
    let (x, y, z) = (k % n, k / n % n, k / (n * n));
    let a = |x: usize, y: usize, z: usize| alpha[x + n * (y + n * z)];
    let d = |lo: f32, hi: f32, span: usize| (hi - lo) / span.max(1) as f32;
    let (xm, xp) = (x.saturating_sub(1), (x + 1).min(n - 1));
    let (ym, yp) = (y.saturating_sub(1), (y + 1).min(n - 1));
    let (zm, zp) = (z.saturating_sub(1), (z + 1).min(n - 1));
    let g = [
        d(a(xm, y, z), a(xp, y, z), xp - xm),
        d(a(x, ym, z), a(x, yp, z), yp - ym),
        d(a(x, y, zm), a(x, y, zp), zp - zm),
    ];
    if g.iter().map(|v| v * v).sum::<f32>().sqrt() < MIN_GRADIENT {
        return None;
    }
    let step = 2.0 * half_size / n as f64;
    let normal = -DVec3::new(
        g[0] as f64 / step.x,
        g[1] as f64 / step.y,
        g[2] as f64 / step.z,
    )
    .normalize();
    let coord = |i: usize, a: usize| ((i as f64 + 0.5) / n as f64 * 2.0 - 1.0) * half_size[a];
    Some((DVec3::new(coord(x, 0), coord(y, 1), coord(z, 2)), normal))
}

/// The ambient term `A(n)/A(up)` and the key light's term `K` (unnormalised) at the
/// box-frame point `c` with box-frame normal `normal`, the object posed at `pose`, its
/// own density (`o`, at that pose) shadowing the key light.
fn light_at(
    pose: &Similarity3,
    o: &Occluder,
    c: DVec3,
    normal: DVec3,
    lights: &[DVec3],
    up: DVec3,
) -> (f64, f64) {
    let nw = (pose.linear().inverse().transpose() * normal).normalize();
    let pw = pose.transform_point(c);
    let amb = (1.0 + 0.5 * nw.dot(up)) / 1.5;
    (amb, key(pw, nw, lights, Some(o)))
}

/// The key light's share of the light on an upward surface (per channel), fitted to how
/// the object's learned colours vary over its surface: each channel's linear colour at
/// surface points is `α·A + β·K` (its mean albedo times the ambient and the key light's
/// terms, [`light_at`] at the learned pose, `K` normalised to the upward surface), fitted
/// by least squares with `α, β ≥ 0`; the share is `β / (α + β)`. `colour` gives the
/// field's sRGB colour at box `[0, 1]³` points seen from the given box-frame directions.
/// `None` with too few surface points or a key term that does not vary over them.
pub fn fit_strength(
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    learned: &Similarity3,
    lights: &[DVec3],
    up: DVec3,
    colour: impl FnOnce(&[[f32; 3]], &[[f32; 3]]) -> Vec<[f32; 3]>,
) -> Option<[f32; 3]> {
    let n = lattice_res(occupancy.res as usize);
    if occupancy.res == 0 || occupancy.density.len() != (occupancy.res as usize).pow(3) {
        return None;
    }
    let up = up.normalize();
    let reference = key(learned.translation, up, lights, None);
    if reference <= 0.0 || lights.is_empty() {
        return None;
    }
    let alpha = opacity(occupancy, half_size, n);
    let o = Occluder {
        occupancy,
        half_size,
        pose: learned,
    };
    let cell = (2.0 * half_size / n as f64).max_element();
    // Points on the surface's band: its colour is read half a cell inside, looking in.
    let points: Vec<(DVec3, DVec3)> = (0..n * n * n)
        .filter(|&k| (0.25..=0.75).contains(&alpha[k]))
        .filter_map(|k| surface_at(&alpha, n, half_size, k))
        .collect();
    if points.len() < MIN_FIT_POINTS {
        return None;
    }
    let terms: Vec<(f64, f64)> = points
        .par_iter()
        .map(|&(c, nl)| {
            let (a, k) = light_at(learned, &o, c + nl * 1.5 * cell, nl, lights, up);
            (a, k / reference)
        })
        .collect();
    let pos: Vec<[f32; 3]> = points
        .iter()
        .map(|&(c, nl)| {
            let u = ((c - nl * 0.5 * cell) / half_size + 1.0) * 0.5;
            u.as_vec3().to_array().map(|v| v.clamp(0.0, 1.0))
        })
        .collect();
    let dirs: Vec<[f32; 3]> = points
        .iter()
        .map(|&(_, nl)| (-nl).as_vec3().to_array())
        .collect();
    let rgb = colour(&pos, &dirs);
    let rows: Vec<(f32, f32, [f32; 3])> = terms
        .iter()
        .zip(&rgb)
        .map(|(&(a, k), c)| (a as f32, k as f32, c.map(to_linear)))
        .collect();
    fit_share(&rows)
}

/// Surface points a fit needs at least.
const MIN_FIT_POINTS: usize = 64;

/// Per channel, `β / (α + β)` of the least-squares fit of `colour ≈ α·ambient + β·key`
/// over `rows` (`(ambient, key, linear colour)`) with `α, β ≥ 0`; `None` when the key
/// term hardly varies (nothing separates the two) or nothing is lit.
pub fn fit_share(rows: &[(f32, f32, [f32; 3])]) -> Option<[f32; 3]> {
    let m = rows.len() as f64;
    if m < 2.0 {
        return None;
    }
    let (mut saa, mut sak, mut skk) = (0.0f64, 0.0f64, 0.0f64);
    for &(a, k, _) in rows {
        let (a, k) = (a as f64, k as f64);
        saa += a * a;
        sak += a * k;
        skk += k * k;
    }
    let det = saa * skk - sak * sak;
    if det <= 1e-9 * saa * skk || skk <= 0.0 {
        return None;
    }
    let mut out = [0.0f32; 3];
    for (ch, o) in out.iter_mut().enumerate() {
        let (mut sac, mut skc) = (0.0f64, 0.0f64);
        for &(a, k, c) in rows {
            sac += a as f64 * c[ch] as f64;
            skc += k as f64 * c[ch] as f64;
        }
        let (mut al, mut be) = ((skk * sac - sak * skc) / det, (saa * skc - sak * sac) / det);
        if al < 0.0 {
            (al, be) = (0.0, (skc / skk).max(0.0));
        } else if be < 0.0 {
            (al, be) = ((sac / saa).max(0.0), 0.0);
        }
        if al + be <= 0.0 {
            return None;
        }
        *o = (be / (al + be)) as f32;
    }
    Some(out)
}

/// The key light's cosine-weighted, inverse-square irradiance at world point `p` with
/// normal `normal`, averaged over `lights`, each seen through `occluder` when given.
fn key(p: DVec3, normal: DVec3, lights: &[DVec3], occluder: Option<&Occluder>) -> f64 {
    lights
        .iter()
        .map(|&l| {
            let to = l - p;
            let d2 = to.length_squared().max(1e-12);
            let cos = normal.dot(to / d2.sqrt()).max(0.0);
            if cos <= 0.0 {
                return 0.0;
            }
            let vis = occluder.map_or(1.0, |o| o.transmittance(p, l) as f64);
            cos * vis / d2
        })
        .sum::<f64>()
        / lights.len().max(1) as f64
}

/// [`relight_grid`], remembered by its inputs (the density by a sample of its values): a
/// batch of renders of one edit, or a viewer redrawing a moved object, computes it once.
pub fn relight_cached(
    key: &str,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    now: &Similarity3,
    cast: &ShadowCast,
    lights: &[DVec3],
    up: DVec3,
) -> Arc<RelightGrid> {
    use std::hash::{Hash, Hasher};
    let mut h = learned_hash(key, occupancy, half_size, &cast.pose, lights, up);
    let learned_id = h.finish();
    for s in cast.strength {
        s.to_bits().hash(&mut h);
    }
    for x in now
        .rotation
        .to_array()
        .iter()
        .chain(&now.translation.to_array())
        .chain(&now.scale.to_array())
    {
        x.to_bits().hash(&mut h);
    }
    crate::light::cached(&CACHE, h.finish(), || {
        let learned = crate::light::cached(&LEARNED, learned_id, || {
            learned_light(occupancy, half_size, &cast.pose, lights, up)
        });
        combine(
            learned.as_ref().as_ref(),
            occupancy,
            half_size,
            now,
            cast,
            lights,
            up,
        )
    })
}

/// A hash of what an object's learned light depends on: its field (by its key and a
/// sample of its density), its box, where it was learned, the lamp and the up.
fn learned_hash(
    key: &str,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    learned: &Similarity3,
    lights: &[DVec3],
    up: DVec3,
) -> std::collections::hash_map::DefaultHasher {
    use std::hash::Hash;
    let mut h = std::collections::hash_map::DefaultHasher::new();
    key.hash(&mut h);
    let vectors = [learned.translation, learned.scale, half_size, up];
    let values = learned
        .rotation
        .to_array()
        .into_iter()
        .chain(vectors.iter().chain(lights).flat_map(|v| v.to_array()));
    for x in values {
        x.to_bits().hash(&mut h);
    }
    (occupancy.res, occupancy.density.len()).hash(&mut h);
    for v in occupancy.density.iter().step_by(59) {
        v.to_bits().hash(&mut h);
    }
    h
}

/// The surfaces and their learned light, which a drag does not change.
static LEARNED: crate::light::Cache<Option<Learned>> = std::sync::Mutex::new(Vec::new());

/// [`fit_strength`], remembered by its inputs as [`relight_cached`] is (the field by its
/// key and its density).
pub fn strength_cached(
    key: &str,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    learned: &Similarity3,
    lights: &[DVec3],
    up: DVec3,
    colour: impl FnOnce(&[[f32; 3]], &[[f32; 3]]) -> Vec<[f32; 3]>,
) -> Option<[f32; 3]> {
    use std::hash::Hasher;
    let h = learned_hash(key, occupancy, half_size, learned, lights, up);
    *crate::light::cached(&STRENGTHS, h.finish(), || {
        fit_strength(occupancy, half_size, learned, lights, up, colour)
    })
}

static STRENGTHS: crate::light::Cache<Option<[f32; 3]>> = std::sync::Mutex::new(Vec::new());

static CACHE: crate::light::Cache<RelightGrid> = std::sync::Mutex::new(Vec::new());
