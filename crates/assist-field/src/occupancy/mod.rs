//! Occupancy grid (instant-NGP style) over a node's canonical box [0, 1]³: an EMA of
//! density per cell, updated periodically from the field with decay, and a bitfield of the
//! cells whose density is worth sampling. Ray marching steps through the box at a fixed
//! step, skipping empty cells by jumping to where the ray leaves them (staying on the same
//! step lattice, so samples in occupied cells are exactly those of dense marching).

use rayon::prelude::*;

use crate::field::Field;

mod march;
pub use march::{ConeRay, ContractedRay, Marching};

#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    pub res: u32,
    /// Density estimate per cell (x fastest).
    pub density: Vec<f32>,
    pub bits: Vec<u64>,
    /// A cell is occupied when its density exceeds `min(threshold, mean density)`.
    pub threshold: f32,
    pub decay: f32,
    /// Per cell, how many smallest steps one marching step through it spans (empty = 1
    /// everywhere): its density is weighted by this before the threshold, so a cell is
    /// occupied when one step through it is opaque enough, however long its steps are
    /// (the outer shell of a contracted node). Derived from the node, not saved.
    pub step_factor: Vec<f32>,
    /// Cells known to be empty (one bit per cell; empty vector = none), e.g. carved out
    /// of the free space depth maps see: their density estimate is held at 0 and they are
    /// never occupied. Not saved: the saved estimate holds the zeros.
    pub empty: Vec<u64>,
    /// Per cell, refresh samples still to take before its estimate may empty it (empty
    /// vector = none; see [`start_warmup`](Self::start_warmup)). Not saved.
    pub warmup: Vec<u8>,
    /// Cells known to hold a surface (one bit per cell; empty vector = none), e.g. where
    /// depth maps end rays: occupied whatever their estimate, since a random point in a
    /// cell rarely lands on a thin surface. Not saved: saved as never measured.
    pub kept: Vec<u64>,
    /// Per cell, its Chebyshev distance in cells to the nearest occupied cell, capped at
    /// [`REACH_CAP`] (0 = occupied): every cell within `reach − 1` cells of it on each
    /// axis is empty, so marching leaves that whole cube in one jump instead of crossing
    /// it cell by cell. Derived from `bits` wherever they change; empty = no skipping
    /// beyond the cell.
    reach: Vec<u8>,
}

/// The largest distance [`OccupancyGrid`]'s reach records (larger empty regions take a
/// few jumps).
pub const REACH_CAP: u8 = 32;

/// Whether bit `c` of a packed bit set (see [`pack_bits`]) is set.
#[inline]
fn bit_set(bits: &[u64], c: usize) -> bool {
    bits.get(c / 64).is_some_and(|&e| e >> (c % 64) & 1 == 1)
}

/// One bit per flag, 64 to a word (flag `c` is bit `c % 64` of word `c / 64`).
fn pack_bits(flags: &[bool]) -> Vec<u64> {
    flags
        .chunks(64)
        .map(|c| {
            c.iter()
                .enumerate()
                .fold(0u64, |w, (i, &e)| w | (u64::from(e) << i))
        })
        .collect()
}

/// One sample of a marched ray: distance along the (unit) direction and interval length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    pub t: f32,
    pub dt: f32,
}

impl OccupancyGrid {
    /// A grid with every cell occupied (nothing is skipped until the first update).
    pub fn new(res: u32) -> Self {
        let n = (res as usize).pow(3);
        OccupancyGrid {
            res,
            density: vec![f32::INFINITY; n],
            bits: vec![u64::MAX; n.div_ceil(64)],
            threshold: 0.01,
            decay: 0.95,
            step_factor: Vec::new(),
            empty: Vec::new(),
            warmup: Vec::new(),
            kept: Vec::new(),
            reach: Vec::new(),
        }
        .with_reach()
    }

    fn with_reach(mut self) -> Self {
        self.refresh_reach();
        self
    }

    /// Recomputes [`reach`](Self::reach) from `bits`: the L∞ distance transform is
    /// separable, so a 1-D transform along x (two linear passes) is followed by
    /// `g(y) = min_k max(|k|, f(y + k))` along y and then z, each over `|k| ≤ REACH_CAP`
    /// with whole rows (or planes) at a time.
    fn refresh_reach(&mut self) {
        let r = self.res as usize;
        let cap = REACH_CAP.min(u8::try_from(r).unwrap_or(u8::MAX));
        if r < 2 {
            self.reach.clear();
            return;
        }
        let n = r * r * r;
        let bits = &self.bits;
        let occupied = |c: usize| bits[c / 64] >> (c % 64) & 1 == 1;
        // Along x.
        let mut fx = vec![cap; n];
        fx.par_chunks_mut(r).enumerate().for_each(|(row, out)| {
            let base = row * r;
            let mut last = None;
            for x in 0..r {
                if occupied(base + x) {
                    last = Some(x);
                }
                if let Some(l) = last {
                    out[x] = out[x].min((x - l).min(cap as usize) as u8);
                }
            }
            last = None;
            for x in (0..r).rev() {
                if occupied(base + x) {
                    last = Some(x);
                }
                if let Some(l) = last {
                    out[x] = out[x].min((l - x).min(cap as usize) as u8);
                }
            }
        });
        // Along y, within each z slab (rows of r cells).
        let mut fy = vec![cap; n];
        fy.par_chunks_mut(r * r)
            .zip(fx.par_chunks(r * r))
            .for_each(|(out, inp)| min_max_lines(out, inp, r, r, cap));
        // Along z (planes of r² cells).
        let mut fz = fx;
        min_max_lines(&mut fz, &fy, r * r, r, cap);
        self.reach = fz;
    }

    /// The reach of empty cell `c` (see [`reach`](Self::reach); 1 without a distance
    /// field): every cell within `reach − 1` cells of it on each axis is empty too.
    #[inline(always)]
    pub fn reach_of(&self, c: usize) -> u32 {
        self.reach.get(c).map_or(1, |&v| u32::from(v.max(1)))
    }

    /// Where the ray at point `p` (parameter `t`, inverse direction `inv`) in empty cell
    /// `idx` (flat index `c`) leaves the empty cube around it.
    #[inline(always)]
    fn empty_exit(&self, idx: [u32; 3], c: usize, p: [f32; 3], inv: [f32; 3], t: f32) -> f32 {
        let k = self.reach_of(c) - 1;
        let r = self.res as f32;
        let mut t_exit = f32::INFINITY;
        for a in 0..3 {
            let face = if inv[a] > 0.0 {
                (idx[a] + k + 1).min(self.res) as f32 / r
            } else if inv[a] < 0.0 {
                idx[a].saturating_sub(k) as f32 / r
            } else {
                continue;
            };
            t_exit = t_exit.min(t + (face - p[a]) * inv[a]);
        }
        t_exit
    }

    /// Marks the cells where `kept[c]` holds as holding a surface (see
    /// [`kept`](Self::kept)) and refreshes the bits. A cell both empty and kept is empty.
    pub fn set_kept(&mut self, kept: &[bool]) {
        assert_eq!(kept.len(), self.cells(), "one flag per cell");
        self.kept = pack_bits(kept);
        self.refresh_bits();
    }

    /// Keeps every cell occupied until it has been sampled `samples` times by the
    /// training refreshes, its estimate meanwhile the largest density seen (no decay).
    ///
    /// One random point per cell says little about a thin surface early in training: a
    /// point that misses the table top, or lego's thin parts, empties the cell, no ray
    /// samples it again, and nothing but hash collisions can bring it back: early
    /// refreshes can empty most of a table top before training recovers it.
    pub fn start_warmup(&mut self, samples: u8) {
        self.warmup = if samples == 0 {
            Vec::new()
        } else {
            vec![samples; self.cells()]
        };
        self.refresh_bits();
    }

    /// Marks the cells where `empty[c]` holds as known empty (see [`empty`](Self::empty))
    /// and refreshes the bits.
    pub fn set_empty(&mut self, empty: &[bool]) {
        assert_eq!(empty.len(), self.cells(), "one flag per cell");
        self.empty = pack_bits(empty);
        self.refresh_bits();
    }

    /// Sets [`step_factor`](Self::step_factor) from a function of the cell centre (in
    /// [0, 1]³) and refreshes the bits.
    pub fn set_step_factor(&mut self, f: impl Fn([f32; 3]) -> f32 + Sync) {
        let r = self.res as usize;
        self.step_factor = (0..self.cells())
            .into_par_iter()
            .map(|c| {
                let idx = [c % r, (c / r) % r, c / (r * r)];
                f(idx.map(|i| (i as f32 + 0.5) / r as f32))
            })
            .collect();
        self.refresh_bits();
    }

    /// Whether cell `c` is in warm-up (occupied whatever its estimate) and not known empty.
    pub fn warming(&self, c: usize) -> bool {
        (self.warmup.get(c).is_some_and(|&w| w > 0) || bit_set(&self.kept, c))
            && !bit_set(&self.empty, c)
    }

    pub fn cells(&self) -> usize {
        (self.res as usize).pow(3)
    }

    /// The flat index of the cell holding `p` (in [0, 1]³), `None` outside.
    #[inline]
    pub fn cell_of(&self, p: [f32; 3]) -> Option<usize> {
        self.locate(p).map(|(_, c)| c)
    }

    /// The cell holding `p` (in [0, 1]³): its index per axis and its flat index.
    #[inline(always)]
    fn locate(&self, p: [f32; 3]) -> Option<([u32; 3], usize)> {
        let r = self.res as f32;
        let mut idx = [0u32; 3];
        for a in 0..3 {
            if !(0.0..=1.0).contains(&p[a]) {
                return None;
            }
            idx[a] = ((p[a] * r) as u32).min(self.res - 1);
        }
        let r = self.res as usize;
        Some((
            idx,
            idx[0] as usize + r * (idx[1] as usize + r * idx[2] as usize),
        ))
    }

    #[inline]
    pub fn is_occupied_cell(&self, c: usize) -> bool {
        self.bits[c / 64] >> (c % 64) & 1 == 1
    }

    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell_of(p).is_some_and(|c| self.is_occupied_cell(c))
    }

    pub fn occupied_fraction(&self) -> f64 {
        let n = self.cells();
        (0..n).filter(|&c| self.is_occupied_cell(c)).count() as f64 / n as f64
    }

    /// Updates the density estimate of every cell from one random point in it
    /// (`ema = max(ema · decay, σ)`), then the bitfield.
    pub fn update(&mut self, field: &Field, rng: &mut assist_core::Rng) {
        self.update_part(field, rng, 0, 1);
    }

    /// Into how many parts an update is split ([`update_round`](Self::update_round)): one
    /// part holds at most 2¹⁹ cells, so a 128³ grid is refreshed a quarter at a time.
    pub fn parts(&self) -> usize {
        (self.cells() >> 19).max(1)
    }

    /// The update training runs every few steps: round `round` refreshes part
    /// `round % parts()` of the cells (each cell every `parts()` rounds; all decay).
    pub fn update_round(&mut self, field: &Field, rng: &mut assist_core::Rng, round: usize) {
        let mut scratch = Vec::new();
        self.update_round_with(rng, round, |pos, sigma| {
            field.density_with(pos, sigma, &mut scratch)
        });
    }

    /// [`update_round`](Self::update_round) with the density at points (in [0, 1]³, up
    /// to 2¹⁶ at a time) from `density` (a GPU's copy of the field, say).
    pub fn update_round_with(
        &mut self,
        rng: &mut assist_core::Rng,
        round: usize,
        density: impl FnMut([&[f32]; 3], &mut [f32]),
    ) {
        let parts = self.parts();
        self.update_part_with(rng, round % parts, parts, density);
    }

    /// Like [`update`](Self::update) for the cells `c` with `c % parts == part` only
    /// (the others keep their estimate): spreads the cost of large grids over several calls.
    pub fn update_part(
        &mut self,
        field: &Field,
        rng: &mut assist_core::Rng,
        part: usize,
        parts: usize,
    ) {
        let mut scratch = Vec::new();
        self.update_part_with(rng, part, parts, |pos, sigma| {
            field.density_with(pos, sigma, &mut scratch)
        });
    }

    /// [`update_part`](Self::update_part) with the density from `density`.
    pub fn update_part_with(
        &mut self,
        rng: &mut assist_core::Rng,
        part: usize,
        parts: usize,
        mut density: impl FnMut([&[f32]; 3], &mut [f32]),
    ) {
        let r = self.res as usize;
        let parts = parts.max(1);
        let part = part % parts;
        let decay = self.decay;
        // Every cell decays each call, so stale estimates fade at the same rate whatever
        // `parts` is; the sampled cells are then refreshed below. Cells are numbered from
        // 0, so within each run of `parts` cells the one at offset `part` is sampled.
        if parts > 1 {
            // (Cells in warm-up hold a running maximum and do not decay.)
            let warm = &self.warmup;
            self.density
                .par_chunks_mut(parts * 4096)
                .enumerate()
                .for_each(|(k, run)| {
                    for (j, cells) in run.chunks_mut(parts).enumerate() {
                        let first = k * parts * 4096 + j * parts;
                        for (i, d) in cells.iter_mut().enumerate() {
                            let warming = warm.get(first + i).is_some_and(|&w| w > 0);
                            if i != part && d.is_finite() && !warming {
                                *d *= decay;
                            }
                        }
                    }
                });
        }
        let selected = (self.cells() - part).div_ceil(parts);
        let cell = |k: usize| part + k * parts;
        let seed = rng.next_u64();
        const BLOCK: usize = 1 << 16;
        const SUB: usize = 4096;
        let mut pos = [vec![0f32; BLOCK], vec![0f32; BLOCK], vec![0f32; BLOCK]];
        let mut sigma = vec![0f32; BLOCK];
        let (mut packed, mut packed_sigma) = ([Vec::new(), Vec::new(), Vec::new()], Vec::new());
        for lo in (0..selected).step_by(BLOCK) {
            let m = BLOCK.min(selected - lo);
            let [px, py, pz] = &mut pos;
            px[..m]
                .par_chunks_mut(SUB)
                .zip(py[..m].par_chunks_mut(SUB))
                .zip(pz[..m].par_chunks_mut(SUB))
                .enumerate()
                .for_each(|(j, ((x, y), z))| {
                    let first = lo + j * SUB;
                    let mut rng = assist_core::Rng::stream(seed, (first / SUB) as u64);
                    for i in 0..x.len() {
                        let c = cell(first + i);
                        let (cx, cy, cz) = (c % r, (c / r) % r, c / (r * r));
                        x[i] = (cx as f32 + rng.f32()) / r as f32;
                        y[i] = (cy as f32 + rng.f32()) / r as f32;
                        z[i] = (cz as f32 + rng.f32()) / r as f32;
                    }
                });
            // Cells known empty are not queried: `refresh_bits` holds their estimate at 0
            // whatever they read (their random points are still drawn, so every other
            // cell's stays where it was). Carving empties most of a capture with depth.
            let live: Vec<u32> = match self.empty.is_empty() {
                true => Vec::new(),
                false => (0..m as u32)
                    .filter(|&i| !bit_set(&self.empty, cell(lo + i as usize)))
                    .collect(),
            };
            if self.empty.is_empty() || live.len() == m {
                density([&pos[0][..m], &pos[1][..m], &pos[2][..m]], &mut sigma[..m]);
            } else {
                let k = live.len();
                let q = &mut packed;
                for (a, p) in q.iter_mut().zip(&pos) {
                    a.clear();
                    a.extend(live.iter().map(|&i| p[i as usize]));
                }
                sigma[..m].fill(0.0);
                if k > 0 {
                    packed_sigma.resize(k, 0.0);
                    density([&q[0][..], &q[1][..], &q[2][..]], &mut packed_sigma[..k]);
                    for (&i, &v) in live.iter().zip(&packed_sigma) {
                        sigma[i as usize] = v;
                    }
                }
            }
            for (i, &s) in sigma[..m].iter().enumerate() {
                let c = cell(lo + i);
                let d = &mut self.density[c];
                let warming = self.warmup.get(c).is_some_and(|&w| w > 0);
                *d = if !d.is_finite() {
                    s
                } else if warming {
                    d.max(s)
                } else {
                    (*d * decay).max(s)
                };
                if warming {
                    self.warmup[c] -= 1;
                }
            }
        }
        self.refresh_bits();
    }

    /// Raises each cell's estimate to the density `seen` holds for it (one value per
    /// cell; 0 = nothing seen), e.g. the largest that training's samples met there since
    /// the last round: a round's one random point per cell rarely lands on a thin
    /// surface that crosses only a corner of the cell, so without this such a cell's
    /// estimate decays below the threshold, the cell empties, and the surface vanishes
    /// from every ray through it (which then learns nothing there to bring it back).
    /// The bits follow at the next [`refresh_bits`](Self::refresh_bits).
    pub fn fold_seen(&mut self, seen: &[f32]) {
        for (d, &s) in self.density.iter_mut().zip(seen) {
            if d.is_finite() && s > *d {
                *d = s;
            }
        }
    }

    /// Folds one density value per cell into the estimate and recomputes the bits.
    pub fn update_from(&mut self, sigma: &[f32]) {
        for (d, &s) in self.density.iter_mut().zip(sigma) {
            *d = if d.is_finite() {
                (*d * self.decay).max(s)
            } else {
                s
            };
        }
        self.refresh_bits();
    }

    /// Recomputes the bitfield from the density estimate.
    pub fn refresh_bits(&mut self) {
        if !self.empty.is_empty() {
            let empty = &self.empty;
            self.density
                .par_chunks_mut(64)
                .zip(empty.par_iter())
                .for_each(|(chunk, &e)| {
                    if e != 0 {
                        for (i, d) in chunk.iter_mut().enumerate() {
                            if e >> i & 1 == 1 {
                                *d = 0.0;
                            }
                        }
                    }
                });
        }
        let weighted = !self.step_factor.is_empty();
        let factor = |c: usize| {
            if weighted { self.step_factor[c] } else { 1.0 }
        };
        // Partial sums collected in order and added in order: rayon's own `sum` associates
        // by however the work was split and stolen, which moved the threshold's last bits
        // from run to run.
        let parts: Vec<f64> = self
            .density
            .par_chunks(1 << 16)
            .enumerate()
            .map(|(k, c)| {
                c.iter()
                    .enumerate()
                    .map(|(i, &d)| (d * factor(k * (1 << 16) + i)) as f64)
                    .sum::<f64>()
            })
            .collect();
        let sum: f64 = parts.iter().sum();
        let thr = self.threshold.min((sum / self.density.len() as f64) as f32);
        self.refresh_bits_above(thr);
    }

    /// The bitfield with every cell whose (step-weighted) density estimate is at most
    /// `thr` empty (cells in warm-up or known to hold a surface stay occupied).
    pub fn refresh_bits_above(&mut self, thr: f32) {
        let weighted = !self.step_factor.is_empty();
        let factor = |c: usize| {
            if weighted { self.step_factor[c] } else { 1.0 }
        };
        let (warm, empty, kept) = (&self.warmup, &self.empty, &self.kept);
        self.bits
            .par_iter_mut()
            .zip(self.density.par_chunks(64))
            .enumerate()
            .for_each(|(k, (w, chunk))| {
                let mut word = 0u64;
                for (i, &d) in chunk.iter().enumerate() {
                    let c = k * 64 + i;
                    let warming = (warm.get(c).is_some_and(|&w| w > 0)
                        || kept.get(k).is_some_and(|&e| e >> i & 1 == 1))
                        && empty.get(k).is_none_or(|&e| e >> i & 1 == 0);
                    if warming || d * factor(c) > thr {
                        word |= 1 << i;
                    }
                }
                *w = word;
            });
        self.refresh_reach();
    }
}

/// `out[y] = min_k max(|k|, inp[y + k])` over `|k| ≤ cap` (`y + k` inside), for `lines`
/// lines of `stride` values each, elementwise along the line.
fn min_max_lines(out: &mut [u8], inp: &[u8], stride: usize, lines: usize, cap: u8) {
    out.par_chunks_mut(stride)
        .enumerate()
        .take(lines)
        .for_each(|(y, o)| {
            o.copy_from_slice(&inp[y * stride..(y + 1) * stride]);
            for k in 1..=cap {
                // max(k, ·) ≥ k: no line further away can lower a value ≤ k.
                if o.iter().all(|&v| v <= k) {
                    break;
                }
                let k_us = usize::from(k);
                for yy in [y.checked_sub(k_us), Some(y + k_us).filter(|&v| v < lines)]
                    .into_iter()
                    .flatten()
                {
                    let line = &inp[yy * stride..(yy + 1) * stride];
                    for (v, &w) in o.iter_mut().zip(line) {
                        *v = (*v).min(w.max(k));
                    }
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 64³ grid with a few occupied clumps, and the same grid without its distance field.
    fn clumps() -> (OccupancyGrid, OccupancyGrid) {
        let mut g = OccupancyGrid::new(64);
        let r = 64usize;
        let centres = [[0.3f32, 0.4, 0.5], [0.7, 0.7, 0.2], [0.5, 0.15, 0.8]];
        let sigma: Vec<f32> = (0..g.cells())
            .map(|c| {
                let p = [c % r, c / r % r, c / (r * r)].map(|v| (v as f32 + 0.5) / r as f32);
                let near = centres
                    .iter()
                    .any(|q| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f32>().sqrt() < 0.08);
                if near { 10.0 } else { 0.0 }
            })
            .collect();
        g.density = vec![0.0; g.cells()];
        g.update_from(&sigma);
        let mut fine = g.clone();
        fine.reach.clear();
        (g, fine)
    }

    /// A thin surface across the corner of a cell: the rounds' random points miss it, so
    /// the cell empties; with the densities training's samples met there folded in, it
    /// stays occupied. Folding never lowers an estimate nor touches an unmeasured cell.
    #[test]
    fn samples_on_a_surface_keep_its_cell_occupied() {
        // Density 500 only where x + y + z < 0.01 (a corner of cell 0 of an 8³ grid, whose
        // cells are 0.125 wide), a little everywhere else.
        let corner = |x: f32, y: f32, z: f32| if x + y + z < 0.01 { 500.0 } else { 0.05 };
        let density = |p: [&[f32]; 3], out: &mut [f32]| {
            for (i, o) in out.iter_mut().enumerate() {
                *o = corner(p[0][i], p[1][i], p[2][i]);
            }
        };
        let run = |fold: bool| {
            let mut g = OccupancyGrid::new(8);
            g.threshold = 1.0;
            g.density = vec![0.05; g.cells()];
            g.density[0] = 500.0;
            let mut rng = assist_core::Rng::new(9);
            let mut seen = vec![0.0f32; g.cells()];
            for _ in 0..200 {
                if fold {
                    // A training sample on the surface.
                    let p = [0.002f32, 0.003, 0.001];
                    let c = g.cell_of(p).unwrap();
                    seen[c] = seen[c].max(corner(p[0], p[1], p[2]));
                    g.fold_seen(&seen);
                    seen.fill(0.0);
                }
                g.update_part_with(&mut rng, 0, 1, density);
            }
            g.is_occupied_cell(0)
        };
        assert!(
            !run(false),
            "the random points alone should have lost the corner"
        );
        assert!(run(true));

        let mut g = OccupancyGrid::new(2);
        g.density = vec![3.0, f32::INFINITY, 7.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        g.fold_seen(&[5.0, 9.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0]);
        assert_eq!(
            g.density,
            vec![5.0, f32::INFINITY, 7.0, 0.0, 0.0, 0.0, 0.0, 2.0]
        );
    }

    #[test]
    fn empty_regions_are_crossed_in_one_jump_without_losing_samples() {
        let (g, fine) = clumps();
        assert!(g.reach.iter().any(|&v| v > 4));
        let mut rng = assist_core::Rng::new(5);
        for _ in 0..500 {
            let o = [0.0; 3].map(|_| rng.f32());
            let mut d = [0.0; 3].map(|_| rng.f32() - 0.5);
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d = d.map(|v| v / n);
            let jitter = rng.f32();
            // Fixed steps: exactly the samples cell-by-cell skipping takes.
            let (mut a, mut b) = (Vec::new(), Vec::new());
            g.march(o, d, 0.0, 2.0, 0.004, jitter, 4096, &mut a);
            fine.march(o, d, 0.0, 2.0, 0.004, jitter, 4096, &mut b);
            assert_eq!(a, b);
            // Growing steps: every sample in an occupied cell, about as many as before.
            let (mut a, mut b) = (Vec::new(), Vec::new());
            g.march_cone(o, d, 0.0, 2.0, 0.002, 0.004, jitter, 4096, &mut a);
            fine.march_cone(o, d, 0.0, 2.0, 0.002, 0.004, jitter, 4096, &mut b);
            for s in &a {
                let p = [0, 1, 2].map(|k| o[k] + d[k] * s.t);
                assert!(g.is_occupied(p), "sample at {p:?} in an empty cell");
            }
            let (na, nb) = (a.len() as f32, b.len() as f32);
            assert!((na - nb).abs() <= 2.0 + 0.1 * nb, "{na} vs {nb} samples");
        }
    }

    #[test]
    fn rays_marched_together_take_the_samples_each_takes_alone() {
        let (g, _) = clumps();
        let mut rng = assist_core::Rng::new(11);
        // A random direction, or (even lanes) towards a point of the first clump.
        let mut ray = |i: usize, o: [f32; 3], clump: [f32; 3]| {
            let d = if i.is_multiple_of(2) {
                [0, 1, 2].map(|a| clump[a] + 0.05 * (rng.f32() - 0.5) - o[a])
            } else {
                [0.0; 3].map(|_| rng.f32() - 0.5)
            };
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (d.map(|v| v / n), rng.f32())
        };
        let mut taken = 0;
        for round in 0..100 {
            // Lanes of different lengths and caps, one of them with nothing to march.
            let mut cone = [ConeRay::none(); 4];
            let mut contracted = [ContractedRay::none(); 4];
            let (mut want_cone, mut want_contracted) = (Vec::new(), Vec::new());
            for i in 0..4 {
                let max = if i == 2 { 3 + round % 5 } else { 4096 };
                let t1 = if i == 3 { 0.0 } else { 2.0 };
                let o = [0.1 + round as f32 * 0.008, 0.9, 0.6];
                let (d, jitter) = ray(i, o, [0.3, 0.4, 0.5]);
                cone[i] = ConeRay::new(o, d, 0.0, t1, 0.002, 0.004, jitter, max);
                let mut v = Vec::new();
                g.march_cone(o, d, 0.0, t1, 0.002, 0.004, jitter, max, &mut v);
                want_cone.push(v);
                // In box units (the box is [−1, 1]³, the grid over its contraction).
                let o = [-1.5 + round as f32 * 0.03, 1.2, 0.4];
                let (d, jitter) = ray(i, o, [-0.8, -0.4, 0.0]);
                let (dt, cone_k, dc) = (0.01, 0.002, 1.0 / 64.0);
                let t1 = 8.0 * t1;
                contracted[i] = ContractedRay::new(o, d, 0.0, t1, dt, cone_k, dc, jitter, max);
                let mut v = Vec::new();
                g.march_contracted(o, d, 0.0, t1, dt, cone_k, dc, jitter, max, &mut v);
                want_contracted.push(v);
            }
            let mut got: [Vec<Step>; 4] = Default::default();
            g.march_each(&mut cone, &mut got);
            assert_eq!(got.to_vec(), want_cone, "round {round}: cone marching");
            assert!(want_cone[3].is_empty() && want_contracted[3].is_empty());
            taken += want_cone[0].len().min(want_contracted[0].len());
            let mut got: [Vec<Step>; 4] = Default::default();
            g.march_each(&mut contracted, &mut got);
            assert_eq!(got.to_vec(), want_contracted, "round {round}: contracted");
        }
        assert!(
            taken > 1000,
            "{taken}: the rays aimed at a clump should sample it"
        );
    }

    #[test]
    fn reach_is_the_capped_chebyshev_distance_to_the_nearest_occupied_cell() {
        let mut rng = assist_core::Rng::new(3);
        for (res, fill) in [(12u32, 0.002f32), (20, 0.0005), (40, 0.00002), (9, 0.0)] {
            let mut g = OccupancyGrid::new(res);
            let r = res as usize;
            let sigma: Vec<f32> = (0..g.cells())
                .map(|_| if rng.f32() < fill { 10.0 } else { 0.0 })
                .collect();
            g.density = vec![0.0; g.cells()];
            g.update_from(&sigma);
            let occ: Vec<[i64; 3]> = (0..g.cells())
                .filter(|&c| g.is_occupied_cell(c))
                .map(|c| [c % r, c / r % r, c / (r * r)].map(|v| v as i64))
                .collect();
            let cap = REACH_CAP.min(res as u8);
            for c in 0..g.cells() {
                let p = [c % r, c / r % r, c / (r * r)].map(|v| v as i64);
                let d = occ
                    .iter()
                    .map(|q| (0..3).map(|a| (p[a] - q[a]).abs()).max().unwrap())
                    .min()
                    .unwrap_or(i64::MAX)
                    .min(cap as i64);
                assert_eq!(g.reach[c] as i64, d, "res {res} cell {p:?}");
            }
        }
    }

    #[test]
    fn marching_skips_empty_cells_and_keeps_occupied_samples() {
        let mut g = OccupancyGrid::new(16);
        // Only a ball of radius 0.2 at the centre is occupied.
        let r = g.res as usize;
        let sigma: Vec<f32> = (0..g.cells())
            .map(|c| {
                let p = [
                    (c % r) as f32 + 0.5,
                    ((c / r) % r) as f32 + 0.5,
                    (c / (r * r)) as f32 + 0.5,
                ]
                .map(|v| v / r as f32 - 0.5);
                if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() < 0.2 {
                    10.0
                } else {
                    0.0
                }
            })
            .collect();
        g.update_from(&sigma);
        assert!(g.occupied_fraction() < 0.1);
        let full = OccupancyGrid::new(16);
        let mut rng = assist_core::Rng::new(1);
        for _ in 0..200 {
            let o = [rng.f32(), rng.f32(), -0.1];
            let d = {
                let v = [rng.f32() - 0.5, rng.f32() - 0.5, 1.0];
                let n = (v[0] * v[0] + v[1] * v[1] + 1.0f32).sqrt();
                v.map(|x| x / n)
            };
            let (mut a, mut b) = (Vec::new(), Vec::new());
            g.march(o, d, 0.0, 2.0, 0.01, 0.3, 10_000, &mut a);
            full.march(o, d, 0.0, 2.0, 0.01, 0.3, 10_000, &mut b);
            // The skipped march's samples are exactly the dense samples in occupied cells.
            let kept: Vec<Step> = b
                .into_iter()
                .filter(|s| {
                    g.is_occupied([o[0] + d[0] * s.t, o[1] + d[1] * s.t, o[2] + d[2] * s.t])
                })
                .collect();
            assert_eq!(a.len(), kept.len());
            for (x, y) in a.iter().zip(&kept) {
                assert!((x.t - y.t).abs() < 1e-5);
            }
        }
    }

    /// A field of one density everywhere (zero output weights, one bias).
    fn constant_field(sigma: f32) -> Field {
        use crate::FieldConfig;
        let cfg = FieldConfig {
            levels: 4,
            log2_table_size: 10,
            base_resolution: 4,
            max_resolution: 32,
            appearance_dim: 0,
            num_images: 0,
            ..FieldConfig::nerfacto(0)
        };
        let mut field = Field::new(cfg, 3).unwrap();
        let d2 = field.layout.density[1];
        field.params[d2.w..d2.w + d2.out * d2.inp_pad].fill(0.0);
        field.params[d2.b] = sigma.ln();
        field
    }

    #[test]
    fn cells_in_warm_up_stay_occupied_and_keep_their_largest_density() {
        let (high, low) = (constant_field(5.0), constant_field(1e-4));
        let mut rng = assist_core::Rng::new(9);
        let mut g = OccupancyGrid::new(8);
        g.start_warmup(3);
        // A carved cell is empty whatever its warm-up.
        let mut carved = vec![false; g.cells()];
        carved[5] = true;
        g.set_empty(&carved);
        assert!(!g.is_occupied_cell(5) && g.is_occupied_cell(6));
        // One dense sample, then two empty ones: no decay, the maximum is kept, and the
        // cells stay occupied until the third sample.
        g.update(&high, &mut rng);
        g.update(&low, &mut rng);
        assert_eq!(g.occupied_fraction(), 1.0 - 1.0 / 512.0);
        assert!(
            g.density
                .iter()
                .enumerate()
                .all(|(c, &d)| c == 5 || (d - 5.0).abs() < 1e-3)
        );
        g.update(&low, &mut rng);
        // Warm-up over: the estimate (5) is trusted, and now decays.
        assert!(g.warmup.iter().all(|&w| w == 0));
        assert_eq!(g.occupied_fraction(), 1.0 - 1.0 / 512.0);
        g.update(&low, &mut rng);
        let want = 5.0 * g.decay;
        assert!(
            g.density
                .iter()
                .enumerate()
                .all(|(c, &d)| c == 5 || (d - want).abs() < 1e-3)
        );
    }

    /// A refresh queries no cell known empty, and ends as it would have had it queried
    /// them (their estimate is held at 0 either way), bit for bit: the other cells' random
    /// points are where they were.
    #[test]
    fn a_refresh_skips_the_cells_known_empty() {
        let r = 32usize;
        let mut rng = assist_core::Rng::new(8);
        let empty: Vec<bool> = (0..r * r * r).map(|_| rng.f32() < 0.7).collect();
        let mut skipping = OccupancyGrid::new(r as u32);
        skipping.set_empty(&empty);
        let mut querying = OccupancyGrid::new(r as u32);
        // The cells a point may be in (a random point rounds onto its cell's far face).
        let cells = |p: [f32; 3]| {
            let i = |v: f32, e: f32| ((v * r as f32 - e).max(0.0) as usize).min(r - 1);
            (0..8).map(move |k| {
                let e = |a: usize| if k >> a & 1 == 1 { 1e-3 } else { 0.0 };
                i(p[0], e(0)) + r * (i(p[1], e(1)) + r * i(p[2], e(2)))
            })
        };
        let smooth = |x: f32, y: f32, z: f32| 20.0 * (x * 7.0).sin().abs() * y + z;
        let (mut asked, mut all) = (0usize, 0usize);
        for round in 0..5u64 {
            let (part, parts) = (round as usize % 3, 3);
            let (mut a, mut b) = (assist_core::Rng::new(round), assist_core::Rng::new(round));
            skipping.update_part_with(&mut a, part, parts, |[x, y, z], sigma| {
                for i in 0..sigma.len() {
                    let p = [x[i], y[i], z[i]];
                    assert!(
                        cells(p).any(|c| !empty[c]),
                        "a known-empty cell was queried"
                    );
                    sigma[i] = smooth(x[i], y[i], z[i]);
                }
                asked += sigma.len();
            });
            querying.update_part_with(&mut b, part, parts, |[x, y, z], sigma| {
                for i in 0..sigma.len() {
                    sigma[i] = smooth(x[i], y[i], z[i]);
                }
                all += sigma.len();
            });
        }
        let live = empty.iter().filter(|&&e| !e).count();
        assert!(asked < all / 2 && asked >= live, "{asked} of {all}");
        for c in 0..r * r * r {
            let (d, q) = (skipping.density[c], querying.density[c]);
            if empty[c] {
                assert_eq!(d, 0.0, "cell {c}");
                assert!(!skipping.is_occupied_cell(c));
            } else {
                assert_eq!(d.to_bits(), q.to_bits(), "cell {c}");
                assert_eq!(skipping.is_occupied_cell(c), querying.is_occupied_cell(c));
            }
        }
        assert!(skipping.occupied_fraction() > 0.05);
    }

    #[test]
    fn an_update_part_refreshes_its_cells_and_decays_the_others() {
        let field = constant_field(5.0);
        let mut sigma0 = [0.0f32];
        field.density([&[0.3], &[0.6], &[0.9]], &mut sigma0);
        let sigma0 = sigma0[0];
        assert!((sigma0 - 5.0).abs() < 1e-3, "{sigma0}");
        // 9³ = 729 cells in 4 parts (729 = 4 · 182 + 1: the last run is short).
        let mut g = OccupancyGrid::new(9);
        let start: Vec<f32> = (0..g.cells()).map(|c| [1.0, 20.0][c % 2]).collect();
        g.density = start.clone();
        let mut rng = assist_core::Rng::new(4);
        g.update_part(&field, &mut rng, 2, 4);
        for (c, (&d, &d0)) in g.density.iter().zip(&start).enumerate() {
            let want = if c % 4 == 2 {
                (d0 * g.decay).max(sigma0)
            } else {
                d0 * g.decay
            };
            assert_eq!(d, want, "cell {c}");
        }
        // The bits follow the estimate: threshold min(0.01, mean) = 0.01, all occupied.
        assert_eq!(g.occupied_fraction(), 1.0);
        g.density.fill(0.0);
        g.density[700] = 1.0;
        g.refresh_bits();
        assert!(g.is_occupied_cell(700) && !g.is_occupied_cell(699));
        // A round-robin of `parts()` rounds reaches every cell.
        let mut big = OccupancyGrid::new(96);
        assert_eq!(big.parts(), 1);
        big.density.fill(0.0);
        big.update_round(&field, &mut rng, 7);
        assert!(big.density.iter().all(|&d| d == sigma0));
        let mut huge = OccupancyGrid::new(128);
        assert_eq!(huge.parts(), 4);
        huge.density.fill(0.0);
        for round in 0..4 {
            huge.update_round(&field, &mut rng, round);
        }
        assert!(
            huge.density
                .iter()
                .all(|&d| d >= sigma0 * huge.decay.powi(3))
        );
    }
}
