//! Shadows under the scene's key light: an object's shadow grid is learned where the
//! object was photographed, and a lamp above a table casts a shadow that turns and
//! stretches as the object moves under it. When the scene knows its key light
//! ([`assist_core::KeyLight`], estimated from the shadows themselves after training) and
//! the object how much of the light around it is that lamp's
//! ([`assist_core::ShadowCast`]), the grid of a moved object is the learned one plus
//! `strength` times the change of the lamp's visibility at each lattice point between the
//! learned pose and the present one. The visibility is a shadow ray from the point to
//! points on the lamp through the object's own density (its occupancy grid's estimate), so
//! the re-cast shadow has the object's shape; the rest of the learned grid (the contact
//! shadow, light the object reflects) moves with the object as before.

use std::sync::{Arc, Mutex};

use assist_core::{DVec3, KeyLight, ShadowCast, Similarity3};
use assist_field::shade::MIN_SHADE;
use assist_field::{OccupancyGrid, ShadeGrid};
use rayon::prelude::*;

/// Points taken on the lamp's disc for soft shadows (its centre and a ring).
pub const LIGHT_SAMPLES: usize = 7;

/// Optical depth beyond which a shadow ray is taken as blocked.
const OPAQUE_DEPTH: f32 = 12.0;

/// Points on `light`'s disc (facing `up`): its centre and [`LIGHT_SAMPLES`]` − 1` points on
/// the circle that splits the disc's area in two, so their mean visibility approximates
/// the disc's. A disc of radius 0 is one point.
pub fn light_points(light: &KeyLight, up: DVec3) -> Vec<DVec3> {
    if light.radius <= 0.0 {
        return vec![light.position];
    }
    let (e1, e2) = up.normalize().any_orthonormal_pair();
    let r = light.radius * std::f64::consts::FRAC_1_SQRT_2;
    let ring = LIGHT_SAMPLES - 1;
    std::iter::once(light.position)
        .chain((0..ring).map(|i| {
            let a = std::f64::consts::TAU * i as f64 / ring as f64;
            light.position + (e1 * a.cos() + e2 * a.sin()) * r
        }))
        .collect()
}

/// An object as shadow rays see it: its density in its box and where the box is.
#[derive(Clone, Copy)]
pub struct Occluder<'a> {
    pub occupancy: &'a OccupancyGrid,
    pub half_size: DVec3,
    pub pose: &'a Similarity3,
}

impl Occluder<'_> {
    /// Transmittance of the segment from world point `p` to world point `l` through the
    /// object: `exp(−∫σ)` with the occupancy grid's density in the cells rendering marches
    /// (an empty cell holds nothing for a shadow ray either), half a cell per step
    /// (distances in the node's local units, as its density is); 0 through a cell never
    /// measured (infinite density) or occupied whatever its estimate
    /// ([`OccupancyGrid::warming`]).
    pub fn transmittance(&self, p: DVec3, l: DVec3) -> f32 {
        let lp = self.pose.local_from_world_point(p);
        let dl = self.pose.local_from_world_vector(l - p);
        self.transmittance_local(lp, dl)
    }

    /// [`Self::transmittance`] of the segment from `lp` to `lp + dl`, in the node's local
    /// frame.
    fn transmittance_local(&self, lp: DVec3, dl: DVec3) -> f32 {
        let occ = self.occupancy;
        let res = occ.res as usize;
        if res == 0 || occ.density.len() != res.pow(3) {
            return 1.0;
        }
        // The segment in the box's unit cube: u(s) = u0 + s·du, s ∈ [0, 1].
        let u0 = (lp / self.half_size + 1.0) * 0.5;
        let du = dl / self.half_size * 0.5;
        let (mut s0, mut s1) = (0.0f64, 1.0f64);
        for a in 0..3 {
            if du[a].abs() < 1e-15 {
                if !(0.0..=1.0).contains(&u0[a]) {
                    return 1.0;
                }
                continue;
            }
            let (ta, tb) = ((0.0 - u0[a]) / du[a], (1.0 - u0[a]) / du[a]);
            s0 = s0.max(ta.min(tb));
            s1 = s1.min(ta.max(tb));
        }
        if s0 >= s1 {
            return 1.0;
        }
        let len_u = du.length();
        let ds = 0.5 / res as f64 / len_u;
        let step_local = (dl.length() * ds) as f32;
        // The most cells one step moves along any axis: an empty cell of reach `d` lets
        // the steps that stay within `d − 1` cells of it be skipped.
        let step_cells = ds * du.abs().max_element() * res as f64;
        let mut tau = 0.0f32;
        let mut s = s0 + 0.5 * ds;
        while s < s1 {
            let u = u0 + du * s;
            let i = |a: usize| ((u[a] * res as f64) as usize).min(res - 1);
            let c = i(0) + res * (i(1) + res * i(2));
            if !occ.is_occupied_cell(c) {
                let d = occ.reach_of(c);
                let skip = ((d - 1) as f64 / step_cells).floor() as usize;
                s += (skip + 1) as f64 * ds;
                continue;
            }
            // A cell occupied whatever its estimate (known to hold a surface, or in
            // warm-up) blocks the light as its file says (saved as never measured:
            // infinite density), so a scene finds the same light before and after saving.
            let sigma = occ.density[c];
            if !sigma.is_finite() || occ.warming(c) {
                return 0.0;
            }
            tau += sigma.max(0.0) * step_local;
            if tau > OPAQUE_DEPTH {
                return 0.0;
            }
            s += ds;
        }
        (-tau).exp()
    }

    /// Mean transmittance from world point `p` to `lights`.
    pub fn visibility(&self, p: DVec3, lights: &[DVec3]) -> f32 {
        lights
            .iter()
            .map(|&l| self.transmittance(p, l))
            .sum::<f32>()
            / lights.len() as f32
    }
}

/// Box coordinates (`[−extent, extent]`) of lattice index `i` of `n` points per axis.
#[inline]
fn lattice_coord(i: usize, n: usize, extent: f32) -> f64 {
    (i as f64 / (n - 1) as f64 * 2.0 - 1.0) * extent as f64
}

/// Mean visibility of `lights` past the object posed at `pose`, at the `n³` lattice
/// points spanning `[−extent, extent]³` box units (x fastest).
fn lattice_visibility(
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    pose: &Similarity3,
    lights: &[DVec3],
    n: usize,
    extent: f32,
) -> Vec<f32> {
    let o = Occluder {
        occupancy,
        half_size,
        pose,
    };
    // The lattice and the lamp in the node's frame: each segment without a transform.
    let local: Vec<DVec3> = lights
        .iter()
        .map(|&l| pose.local_from_world_point(l))
        .collect();
    (0..n * n * n)
        .into_par_iter()
        .map(|k| {
            let c = DVec3::new(
                lattice_coord(k % n, n, extent),
                lattice_coord(k / n % n, n, extent),
                lattice_coord(k / (n * n), n, extent),
            ) * half_size;
            local
                .iter()
                .map(|&l| o.transmittance_local(c, l - c))
                .sum::<f32>()
                / local.len() as f32
        })
        .collect()
}

/// Points per axis of the lattice visibilities are taken on for a grid of `res`: half as
/// fine (a lamp's shadow is soft).
fn coarse_res(res: usize) -> usize {
    res.div_ceil(2).max(2)
}

/// The shadow grid of an object posed at `now` whose grid `grid` was learned at
/// `cast.pose`: each factor plus `cast.strength` times the change of `lights`' visibility
/// at the lattice point between the two poses, clamped to the grid's range. Visibilities
/// are taken on a lattice half as fine and interpolated.
pub fn recast(
    grid: &ShadeGrid,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    now: &Similarity3,
    cast: &ShadowCast,
    lights: &[DVec3],
) -> ShadeGrid {
    let n = coarse_res(grid.res);
    let then = lattice_visibility(occupancy, half_size, &cast.pose, lights, n, grid.extent);
    let here = lattice_visibility(occupancy, half_size, now, lights, n, grid.extent);
    recast_from(grid, &then, &here, cast.strength)
}

/// [`recast`] from the coarse visibilities where the grid was learned (`then`) and where
/// the object stands (`here`).
fn recast_from(grid: &ShadeGrid, then: &[f32], here: &[f32], strength: [f32; 3]) -> ShadeGrid {
    let n = coarse_res(grid.res);
    let coarse: Vec<f32> = here.iter().zip(then).map(|(a, b)| a - b).collect();
    let r = grid.res;
    let mut out = ShadeGrid {
        res: r,
        extent: grid.extent,
        values: vec![0.0; grid.values.len()],
    };
    out.values
        .par_chunks_mut(3 * r)
        .enumerate()
        .for_each(|(row, vals)| {
            let (y, z) = (row % r, row / r);
            let f = |i: usize| {
                let u = i as f64 / (r - 1) as f64 * (n - 1) as f64;
                let i0 = (u.floor() as usize).min(n - 2);
                (i0, (u - i0 as f64) as f32)
            };
            let ((y0, fy), (z0, fz)) = (f(y), f(z));
            for x in 0..r {
                let (x0, fx) = f(x);
                let mut dv = 0.0f32;
                for corner in 0..8 {
                    let (dx, dy, dz) = (corner & 1, corner >> 1 & 1, corner >> 2 & 1);
                    let w = if dx == 1 { fx } else { 1.0 - fx }
                        * if dy == 1 { fy } else { 1.0 - fy }
                        * if dz == 1 { fz } else { 1.0 - fz };
                    dv += w * coarse[(x0 + dx) + n * ((y0 + dy) + n * (z0 + dz))];
                }
                let learned = &grid.values[3 * (row * r + x)..3 * (row * r + x) + 3];
                for c in 0..3 {
                    vals[3 * x + c] = (learned[c] + strength[c] * dv).clamp(MIN_SHADE, 1.0);
                }
            }
        });
    out
}

/// Re-cast grids lately made, by what they were made from: a viewer redrawing a moved
/// object, or a batch of renders of one edit, computes each only once.
static CACHE: Mutex<Vec<(u64, Arc<ShadeGrid>)>> = Mutex::new(Vec::new());
const CACHE_ENTRIES: usize = 8;
/// The visibilities where grids were learned, which a drag does not change.
static LEARNED: Mutex<Vec<(u64, Arc<Vec<f32>>)>> = Mutex::new(Vec::new());

/// A cache of values by the hash of what they were made from, the oldest dropped first.
pub(crate) type Cache<T> = Mutex<Vec<(u64, Arc<T>)>>;

/// The entry of `cache` for `id`, made by `make` (and kept, the oldest dropped) if none.
pub(crate) fn cached<T>(
    cache: &Mutex<Vec<(u64, Arc<T>)>>,
    id: u64,
    make: impl FnOnce() -> T,
) -> Arc<T> {
    if let Some((_, v)) = cache.lock().expect("cache").iter().find(|(k, _)| *k == id) {
        return v.clone();
    }
    let v = Arc::new(make());
    let mut c = cache.lock().expect("cache");
    if c.len() >= CACHE_ENTRIES {
        c.remove(0);
    }
    c.push((id, v.clone()));
    v
}

/// [`recast`], remembered by its inputs (the grid and density by a sample of their values).
pub fn recast_cached(
    key: &str,
    grid: &ShadeGrid,
    occupancy: &OccupancyGrid,
    half_size: DVec3,
    now: &Similarity3,
    cast: &ShadowCast,
    lights: &[DVec3],
) -> Arc<ShadeGrid> {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    key.hash(&mut h);
    let f64s = |h: &mut std::collections::hash_map::DefaultHasher, v: &[f64]| {
        for x in v {
            x.to_bits().hash(h);
        }
    };
    let pose = |h: &mut std::collections::hash_map::DefaultHasher, p: &Similarity3| {
        f64s(h, &p.rotation.to_array());
        f64s(h, &p.translation.to_array());
        f64s(h, &p.scale.to_array());
    };
    pose(&mut h, &cast.pose);
    f64s(&mut h, &half_size.to_array());
    for l in lights {
        f64s(&mut h, &l.to_array());
    }
    (grid.res, grid.extent.to_bits()).hash(&mut h);
    (occupancy.res, occupancy.density.len()).hash(&mut h);
    for v in occupancy.density.iter().step_by(59) {
        v.to_bits().hash(&mut h);
    }
    let learned_id = h.finish();
    pose(&mut h, now);
    for s in cast.strength {
        s.to_bits().hash(&mut h);
    }
    grid.values.len().hash(&mut h);
    for v in grid.values.iter().step_by(61) {
        v.to_bits().hash(&mut h);
    }
    let id = h.finish();
    cached(&CACHE, id, || {
        let n = coarse_res(grid.res);
        let then = cached(&LEARNED, learned_id, || {
            lattice_visibility(occupancy, half_size, &cast.pose, lights, n, grid.extent)
        });
        let here = lattice_visibility(occupancy, half_size, now, lights, n, grid.extent);
        recast_from(grid, &then, &here, cast.strength)
    })
}
