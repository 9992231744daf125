//! Marching a ray through the grid: samples at a fixed step in occupied cells, cone
//! marching whose step grows with distance, and marching in the contracted space of an
//! unbounded background; empty regions are crossed in one jump each.

use super::*;

impl OccupancyGrid {
    /// Marches `o + t·d` (in [0, 1]³ coordinates, `d` unit) over `[t0, t1]` with step `dt`;
    /// the first sample is at `t0 + jitter·dt` (`jitter` in [0, 1) stratifies training
    /// samples). Samples in occupied cells are appended to `out`; at most `max` are taken.
    #[inline]
    pub fn march(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        t0: f32,
        t1: f32,
        dt: f32,
        jitter: f32,
        max: usize,
        out: &mut Vec<Step>,
    ) {
        let start = out.len();
        let mut k = 0u32;
        let base = t0 + jitter * dt;
        let inv = inverse(d);
        loop {
            let t = base + k as f32 * dt;
            if t >= t1 || out.len() - start >= max {
                break;
            }
            let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
            match self.locate(p) {
                Some((_, c)) if self.is_occupied_cell(c) => {
                    out.push(Step { t, dt });
                    k += 1;
                }
                Some((idx, c)) => {
                    let t_exit = self.empty_exit(idx, c, p, inv, t);
                    let steps = ((t_exit - base) / dt).ceil().max(k as f32 + 1.0);
                    k = steps as u32;
                }
                None => k += 1,
            }
        }
    }
}

impl OccupancyGrid {
    /// Cone marching: like [`march`](Self::march) but the step grows with distance,
    /// `dt(t) = max(min_dt, cone · t)` (`t` measured from the ray origin, in the same units
    /// as `min_dt`), so far regions get fewer samples (a pixel's footprint grows with
    /// distance). Empty cells are skipped by jumping to where the ray leaves them.
    #[inline(always)]
    pub fn march_cone(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        t0: f32,
        t1: f32,
        min_dt: f32,
        cone: f32,
        jitter: f32,
        max: usize,
        out: &mut Vec<Step>,
    ) {
        let mut ray = ConeRay::new(o, d, t0, t1, min_dt, cone, jitter, max);
        while ray.advance(self, out) {}
    }

    /// Marches several rays at once ([`ConeRay`]s or [`ContractedRay`]s), `rays[i]`'s
    /// samples appended to `out[i]`: the same samples as one at a time. A ray's march is a
    /// chain of dependent steps, each waiting on the last; interleaving independent rays
    /// lets the processor overlap their chains.
    #[inline(always)]
    pub fn march_each<R: Marching, const L: usize>(
        &self,
        rays: &mut [R; L],
        out: &mut [Vec<Step>; L],
    ) {
        let mut live = [true; L];
        while live.iter().any(|&l| l) {
            for i in 0..L {
                if live[i] {
                    live[i] = rays[i].advance(self, &mut out[i]);
                }
            }
        }
    }
}

/// A ray being marched through a grid, one step at a time.
pub trait Marching {
    /// One step of the march: a sample taken into `out`, or an empty stretch crossed.
    /// False once the march is over.
    fn advance(&mut self, grid: &OccupancyGrid, out: &mut Vec<Step>) -> bool;
}

/// A ray being cone-marched through a grid ([`OccupancyGrid::march_cone`]): where it is
/// and what it has taken.
#[derive(Debug, Clone, Copy)]
pub struct ConeRay {
    o: [f32; 3],
    d: [f32; 3],
    inv: [f32; 3],
    t: f32,
    t1: f32,
    min_dt: f32,
    cone: f32,
    /// Samples still to be taken before the march stops.
    left: usize,
}

impl ConeRay {
    /// The march of `o + t·d` over `[t0, t1]` (see [`OccupancyGrid::march_cone`]).
    #[inline(always)]
    pub fn new(
        o: [f32; 3],
        d: [f32; 3],
        t0: f32,
        t1: f32,
        min_dt: f32,
        cone: f32,
        jitter: f32,
        max: usize,
    ) -> ConeRay {
        ConeRay {
            o,
            d,
            inv: inverse(d),
            t: t0 + jitter * (cone * t0).max(min_dt),
            t1,
            min_dt,
            cone,
            left: max,
        }
    }

    /// A ray with nothing to march (its samples are none).
    pub fn none() -> ConeRay {
        ConeRay::new([0.0; 3], [0.0; 3], 0.0, 0.0, 1.0, 0.0, 0.0, 0)
    }
}

impl Marching for ConeRay {
    #[inline(always)]
    fn advance(&mut self, grid: &OccupancyGrid, out: &mut Vec<Step>) -> bool {
        let t = self.t;
        if !(t < self.t1 && self.left > 0) {
            return false;
        }
        let (o, d) = (self.o, self.d);
        let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
        let dt = (self.cone * t).max(self.min_dt);
        match grid.locate(p) {
            Some((idx, c)) if !grid.is_occupied_cell(c) => {
                let t_exit = grid.empty_exit(idx, c, p, self.inv, t);
                // Land just past the face, keeping the phase of the step lattice.
                let n = ((t_exit - t) / dt).ceil().max(1.0);
                self.t = t + n * dt;
            }
            Some(_) => {
                out.push(Step { t, dt });
                self.left -= 1;
                self.t = t + dt;
            }
            None => self.t = t + dt,
        }
        true
    }
}

impl OccupancyGrid {
    /// Marching through a contracted node ([`crate::contraction`]): `o` and `d` are the
    /// ray's origin and direction in box units (the box is [−1, 1]³; `d` per unit of `t`).
    /// Steps are `max(min_dt, cone · t)` inside the box and grow with the square of the
    /// box radius outside it, advancing about `dc` in contracted space each; the grid is
    /// over the contracted space. Empty cells are skipped by jumping to where the ray
    /// leaves them inside the box (where the map is linear) and step by step beyond it.
    #[inline(always)]
    pub fn march_contracted(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        t0: f32,
        t1: f32,
        min_dt: f32,
        cone: f32,
        dc: f32,
        jitter: f32,
        max: usize,
        out: &mut Vec<Step>,
    ) {
        let mut ray = ContractedRay::new(o, d, t0, t1, min_dt, cone, dc, jitter, max);
        while ray.advance(self, out) {}
    }
}

/// A ray being marched through a contracted node's grid
/// ([`OccupancyGrid::march_contracted`]).
#[derive(Debug, Clone, Copy)]
pub struct ContractedRay {
    o: [f32; 3],
    d: [f32; 3],
    /// The contracted-space direction's inverse inside the box.
    inv: [f32; 3],
    /// The direction's largest component (the box radius's rate along the ray).
    speed: f32,
    t: f32,
    t1: f32,
    min_dt: f32,
    cone: f32,
    dc: f32,
    left: usize,
}

impl ContractedRay {
    /// The march of `o + t·d` over `[t0, t1]` (see [`OccupancyGrid::march_contracted`]).
    #[inline(always)]
    pub fn new(
        o: [f32; 3],
        d: [f32; 3],
        t0: f32,
        t1: f32,
        min_dt: f32,
        cone: f32,
        dc: f32,
        jitter: f32,
        max: usize,
    ) -> ContractedRay {
        let speed = d[0].abs().max(d[1].abs()).max(d[2].abs()).max(1e-12);
        let mut ray = ContractedRay {
            o,
            d,
            // Contracted-space direction inside the box (the map is u ↦ (u + 2) / 4 there).
            inv: inverse(d.map(|v| v * 0.25)),
            speed,
            t: t0,
            t1,
            min_dt,
            cone,
            dc,
            left: max,
        };
        ray.t = t0 + jitter * ray.step(t0, radius(ray.at(t0))).min(t1 - t0);
        ray
    }

    /// A ray with nothing to march (its samples are none).
    pub fn none() -> ContractedRay {
        ContractedRay::new([0.0; 3], [1.0; 3], 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0)
    }

    #[inline(always)]
    fn at(&self, t: f32) -> [f32; 3] {
        let (o, d) = (self.o, self.d);
        [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t]
    }

    #[inline(always)]
    fn step(&self, t: f32, r: f32) -> f32 {
        use crate::contraction::outer_step;
        (self.cone * t)
            .max(self.min_dt)
            .max(outer_step(r, self.dc) / self.speed)
    }
}

/// The box radius (L∞ norm) of a point in box units.
#[inline(always)]
fn radius(u: [f32; 3]) -> f32 {
    u[0].abs().max(u[1].abs()).max(u[2].abs())
}

impl Marching for ContractedRay {
    #[inline(always)]
    fn advance(&mut self, grid: &OccupancyGrid, out: &mut Vec<Step>) -> bool {
        let t = self.t;
        if !(t < self.t1 && self.left > 0) {
            return false;
        }
        let u = self.at(t);
        let r = radius(u);
        // The last step of the shell reaches the end of the march.
        let dt = self.step(t, r).min(self.t1 - t);
        let p = crate::contraction::contract_to_unit(u);
        match grid.locate(p) {
            Some((idx, c)) if !grid.is_occupied_cell(c) => {
                if r < 1.0 {
                    // Leave the empty cube (or the box, where the map stops being linear).
                    let t_cell = grid.empty_exit(idx, c, p, self.inv, t);
                    let t_box = box_exit(u, self.d, t);
                    let n = ((t_cell.min(t_box) - t) / dt).ceil().max(1.0);
                    self.t = t + n * dt;
                } else {
                    self.t = t + dt;
                }
            }
            Some(_) => {
                out.push(Step { t, dt });
                self.left -= 1;
                self.t = t + dt;
            }
            None => self.t = t + dt,
        }
        true
    }
}

/// The inverse of each direction component (0 where the component is 0: never crossed).
#[inline(always)]
fn inverse(d: [f32; 3]) -> [f32; 3] {
    d.map(|v| if v != 0.0 { 1.0 / v } else { 0.0 })
}

/// Where the ray `u + s·d` (at parameter `t`) leaves the box [−1, 1]³.
#[inline]
fn box_exit(u: [f32; 3], d: [f32; 3], t: f32) -> f32 {
    let mut t_exit = f32::INFINITY;
    for a in 0..3 {
        if d[a] > 0.0 {
            t_exit = t_exit.min(t + (1.0 - u[a]) / d[a]);
        } else if d[a] < 0.0 {
            t_exit = t_exit.min(t + (-1.0 - u[a]) / d[a]);
        }
    }
    t_exit
}
