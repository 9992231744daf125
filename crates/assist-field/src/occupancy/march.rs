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
        let start = out.len();
        let step = |t: f32| (cone * t).max(min_dt);
        let mut t = t0 + jitter * step(t0);
        let inv = inverse(d);
        while t < t1 && out.len() - start < max {
            let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
            let dt = step(t);
            match self.locate(p) {
                Some((idx, c)) if !self.is_occupied_cell(c) => {
                    let t_exit = self.empty_exit(idx, c, p, inv, t);
                    // Land just past the face, keeping the phase of the step lattice.
                    let n = ((t_exit - t) / dt).ceil().max(1.0);
                    t += n * dt;
                }
                Some(_) => {
                    out.push(Step { t, dt });
                    t += dt;
                }
                None => t += dt,
            }
        }
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
        use crate::contraction::{contract_to_unit, outer_step};
        let start = out.len();
        let speed = d[0].abs().max(d[1].abs()).max(d[2].abs()).max(1e-12);
        let step = |t: f32, r: f32| (cone * t).max(min_dt).max(outer_step(r, dc) / speed);
        let at = |t: f32| [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
        let radius = |u: [f32; 3]| u[0].abs().max(u[1].abs()).max(u[2].abs());
        let mut t = t0 + jitter * step(t0, radius(at(t0))).min(t1 - t0);
        // Contracted-space direction inside the box (the map is u ↦ (u + 2) / 4 there).
        let dp = d.map(|v| v * 0.25);
        let inv = inverse(dp);
        while t < t1 && out.len() - start < max {
            let u = at(t);
            let r = radius(u);
            // The last step of the shell reaches the end of the march.
            let dt = step(t, r).min(t1 - t);
            let p = contract_to_unit(u);
            match self.locate(p) {
                Some((idx, c)) if !self.is_occupied_cell(c) => {
                    if r < 1.0 {
                        // Leave the empty cube (or the box, where the map stops being
                        // linear).
                        let t_cell = self.empty_exit(idx, c, p, inv, t);
                        let t_box = box_exit(u, d, t);
                        let n = ((t_cell.min(t_box) - t) / dt).ceil().max(1.0);
                        t += n * dt;
                    } else {
                        t += dt;
                    }
                }
                Some(_) => {
                    out.push(Step { t, dt });
                    t += dt;
                }
                None => t += dt,
            }
        }
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
