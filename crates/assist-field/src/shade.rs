//! An object's shadow on the background: a coarse grid of light-attenuation factors in
//! `[0, 1]`, one per colour channel, over a region around the object's box, in the
//! object's own frame. The background's colour at a point is multiplied channel by channel
//! by the factors there (1 outside the region), so the darkening an object casts on the
//! table — and the tint of the light it reflects there (a red mug leaves the table beside
//! it less dark in red than in green and blue) — moves, turns and disappears with the
//! object, and the background itself learns the surface without it.
//!
//! Coordinates are box units: the object's box is `[−1, 1]³` (its local position divided by
//! its half size) and the grid spans `[−extent, extent]³`. Factors sit on the `res³`
//! lattice points spanning that cube and are interpolated trilinearly.

/// Smallest factor a grid may hold (the optimiser clamps to it): an object never hides the
/// light entirely, and a factor of zero would stop the background's colour learning there.
pub const MIN_SHADE: f32 = 0.05;

#[derive(Debug, Clone, PartialEq)]
pub struct ShadeGrid {
    /// Lattice points per axis (at least 2).
    pub res: usize,
    /// Half-width of the region in box units (1 = the box itself).
    pub extent: f32,
    /// `res³` lattice points, x fastest, each `[r, g, b]`: `3 · res³` factors.
    pub values: Vec<f32>,
}

/// One bit per cell of a [`ShadeGrid`]: set where the grid shades nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct LitCells {
    res: usize,
    bits: Vec<u64>,
    /// The lowest and highest cell index per axis of the cells that shade (`None`: none).
    active: Option<([usize; 3], [usize; 3])>,
}

impl LitCells {
    /// No cell known to shade nothing (every point must be looked up).
    pub fn none(grid: &ShadeGrid) -> LitCells {
        let m = grid.res - 1;
        LitCells {
            res: grid.res,
            bits: vec![0; (m * m * m).div_ceil(64)],
            active: Some(([0; 3], [m - 1; 3])),
        }
    }

    /// The box (box units, lowest and highest corner) holding every cell that shades, for
    /// a grid of half-width `extent`; `None` when no cell does.
    pub fn active_box(&self, extent: f32) -> Option<([f64; 3], [f64; 3])> {
        let (lo, hi) = self.active?;
        let n = (self.res - 1) as f64;
        let c = |u: usize| (u as f64 / n * 2.0 - 1.0) * extent as f64;
        Some((lo.map(c), hi.map(|h| c(h + 1))))
    }
}

/// The lattice points around one position and their trilinear weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corners {
    pub index: [u32; 8],
    pub weight: [f32; 8],
}

impl ShadeGrid {
    /// A grid casting no shadow (every factor 1).
    pub fn new(res: usize, extent: f32) -> Self {
        let res = res.max(2);
        ShadeGrid {
            res,
            extent,
            values: vec![1.0; 3 * res * res * res],
        }
    }

    /// A grid whose every lattice point has the same factor in all three channels
    /// (`grey`, `res³` values: the layout of files written before the factors had colour).
    pub fn from_grey(res: usize, extent: f32, grey: &[f32]) -> Self {
        ShadeGrid {
            res,
            extent,
            values: grey.iter().flat_map(|&v| [v; 3]).collect(),
        }
    }

    /// Lattice points (`res³`).
    pub fn points(&self) -> usize {
        self.res.pow(3)
    }

    /// The cell holding `c` (box units): its lowest lattice index per axis and where `c`
    /// lies in it (0..1 per axis); `None` outside the region.
    #[inline]
    fn cell(&self, c: [f32; 3]) -> Option<([usize; 3], [f32; 3])> {
        let n = (self.res - 1) as f32;
        let mut i0 = [0usize; 3];
        let mut f = [0f32; 3];
        for a in 0..3 {
            let u = (c[a] / self.extent + 1.0) * 0.5 * n;
            if !(0.0..=n).contains(&u) {
                return None;
            }
            // `u` is at least 0 here, so truncation is the floor.
            let i = (u as usize).min(self.res - 2);
            i0[a] = i;
            f[a] = u - i as f32;
        }
        Some((i0, f))
    }

    /// The lattice points around `c` (box units) and their weights; `None` outside the
    /// region.
    #[inline]
    pub fn corners(&self, c: [f32; 3]) -> Option<Corners> {
        let (i0, f) = self.cell(c)?;
        Some(self.corners_of(i0, f))
    }

    /// The lattice points of the cell `i0` and their weights at `f` within it.
    #[inline]
    fn corners_of(&self, i0: [usize; 3], f: [f32; 3]) -> Corners {
        let r = self.res;
        let mut out = Corners {
            index: [0; 8],
            weight: [0.0; 8],
        };
        for k in 0..8 {
            let (dx, dy, dz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
            out.index[k] = ((i0[2] + dz) * r * r + (i0[1] + dy) * r + i0[0] + dx) as u32;
            let wx = if dx == 1 { f[0] } else { 1.0 - f[0] };
            let wy = if dy == 1 { f[1] } else { 1.0 - f[1] };
            let wz = if dz == 1 { f[2] } else { 1.0 - f[2] };
            out.weight[k] = wx * wy * wz;
        }
        out
    }

    /// Which cells shade nothing: those whose eight corners are all exactly 1, where
    /// [`ShadeGrid::at`] gives exactly 1. Most of a region is such cells.
    pub fn lit_cells(&self) -> LitCells {
        use rayon::prelude::*;
        let (r, m) = (self.res, self.res - 1);
        let one: Vec<bool> = self
            .values
            .par_chunks_exact(3)
            .map(|v| v == [1.0; 3])
            .collect();
        // A cell is lit where its eight corners are; one slab of cells per task.
        let mut one_cells = vec![false; m * m * m];
        one_cells
            .par_chunks_mut(m * m)
            .enumerate()
            .for_each(|(z, slab)| {
                for y in 0..m {
                    for x in 0..m {
                        let at = |dx: usize, dy: usize, dz: usize| {
                            one[((z + dz) * r + y + dy) * r + x + dx]
                        };
                        slab[y * m + x] = (0..8).all(|c| at(c & 1, c >> 1 & 1, c >> 2 & 1));
                    }
                }
            });
        let mut bits = vec![0u64; (m * m * m).div_ceil(64)];
        let (mut lo, mut hi) = ([m; 3], [0; 3]);
        let mut i = 0;
        for z in 0..m {
            for y in 0..m {
                for x in 0..m {
                    if one_cells[i] {
                        bits[i / 64] |= 1 << (i % 64);
                    } else {
                        for (a, c) in [x, y, z].into_iter().enumerate() {
                            lo[a] = lo[a].min(c);
                            hi[a] = hi[a].max(c);
                        }
                    }
                    i += 1;
                }
            }
        }
        let active = (lo[0] <= hi[0]).then_some((lo, hi));
        LitCells {
            res: r,
            bits,
            active,
        }
    }

    /// Whether `c` (box units) gets exactly 1 from this grid: outside the region, or in
    /// a cell `lit` (this grid's [`ShadeGrid::lit_cells`]) marks.
    #[inline]
    pub fn shades_nothing_at(&self, lit: &LitCells, c: [f32; 3]) -> bool {
        debug_assert_eq!(lit.res, self.res, "lit cells of another grid");
        match self.cell(c) {
            None => true,
            Some((i0, _)) => {
                let m = self.res - 1;
                let i = (i0[2] * m + i0[1]) * m + i0[0];
                lit.bits[i / 64] >> (i % 64) & 1 == 1
            }
        }
    }

    /// The factors at `c` (box units) where they differ from 1: `None` where
    /// [`ShadeGrid::shades_nothing_at`] holds, else [`ShadeGrid::value`] (the same bits),
    /// with one look-up of the cell.
    #[inline]
    pub fn shading_at(&self, lit: &LitCells, c: [f32; 3]) -> Option<[f32; 3]> {
        debug_assert_eq!(lit.res, self.res, "lit cells of another grid");
        let (i0, f) = self.cell(c)?;
        let m = self.res - 1;
        let i = (i0[2] * m + i0[1]) * m + i0[0];
        if lit.bits[i / 64] >> (i % 64) & 1 == 1 {
            return None;
        }
        Some(self.at(&self.corners_of(i0, f)))
    }

    /// The factors at `c` (box units): 1 outside the region.
    #[inline]
    pub fn value(&self, c: [f32; 3]) -> [f32; 3] {
        match self.corners(c) {
            Some(k) => self.at(&k),
            None => [1.0; 3],
        }
    }

    /// The interpolated factors at `k`: exactly 1 (no shadow) where all eight corners are
    /// 1, as most of a region is. The weights' sum may miss 1 by a rounding; the exact 1
    /// lets a moved grid leave unshadowed samples' factors unchanged to the bit.
    #[inline]
    pub fn at(&self, k: &Corners) -> [f32; 3] {
        let mut out = [0.0f32; 3];
        let mut lit = true;
        for i in 0..8 {
            let v = &self.values[3 * k.index[i] as usize..3 * k.index[i] as usize + 3];
            for ch in 0..3 {
                out[ch] += k.weight[i] * v[ch];
                lit &= v[ch] == 1.0;
            }
        }
        if lit { [1.0; 3] } else { out }
    }

    /// Adds `Σ_ch g[ch] · ∂value[ch]/∂values` at `k` into `grad` (sized like `values`).
    #[inline]
    pub fn splat(k: &Corners, g: [f32; 3], grad: &mut [f32]) {
        for i in 0..8 {
            let at = 3 * k.index[i] as usize;
            for ch in 0..3 {
                grad[at + ch] += g[ch] * k.weight[i];
            }
        }
    }

    /// Keeps every factor in `[MIN_SHADE, 1]` (after an optimiser step).
    pub fn clamp(&mut self) {
        for v in &mut self.values {
            *v = v.clamp(MIN_SHADE, 1.0);
        }
    }

    /// Checks a grid read from a file: the shape and every value in `[0, 1]`.
    pub fn validate(&self) -> Result<(), String> {
        if self.res < 2 || self.values.len() != 3 * self.res.pow(3) {
            return Err(format!(
                "expected 3·res³ values with res ≥ 2, got {} values for res {}",
                self.values.len(),
                self.res
            ));
        }
        if !(self.extent.is_finite() && self.extent >= 1.0) {
            return Err(format!(
                "extent must be a finite number ≥ 1 (box units), got {}",
                self.extent
            ));
        }
        if let Some(i) = self
            .values
            .iter()
            .position(|v| !(v.is_finite() && (0.0..=1.0).contains(v)))
        {
            return Err(format!(
                "value {i} is {}, expected a factor in [0, 1]",
                self.values[i]
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_the_lattice_and_is_one_outside() {
        let mut g = ShadeGrid::new(3, 2.0);
        // Lattice points at −2, 0, 2 per axis; the centre point is index 13: its green
        // factor is 0.2, its red and blue ones 1 and 0.6.
        g.values[3 * 13..3 * 13 + 3].copy_from_slice(&[1.0, 0.2, 0.6]);
        let near = |a: [f32; 3], b: [f32; 3]| (0..3).all(|c| (a[c] - b[c]).abs() < 1e-6);
        assert!(near(g.value([0.0, 0.0, 0.0]), [1.0, 0.2, 0.6]));
        // Halfway from the centre to a face: halfway between it and 1.
        assert!(near(g.value([1.0, 0.0, 0.0]), [1.0, 0.6, 0.8]));
        assert!(near(g.value([1.0, 1.0, 0.0]), [1.0, 0.8, 0.9]));
        assert_eq!(g.value([2.5, 0.0, 0.0]), [1.0; 3]);
        assert_eq!(g.value([0.0, -2.01, 0.0]), [1.0; 3]);
        // The region's faces are inside it.
        assert!(near(g.value([2.0, 2.0, 2.0]), [1.0; 3]));
        // A grey grid (an older file's) has one factor in every channel.
        let grey = ShadeGrid::from_grey(2, 2.0, &[0.5; 8]);
        assert_eq!(grey.values.len(), 24);
        assert!(near(grey.value([0.3, -1.0, 1.5]), [0.5; 3]));
    }

    #[test]
    fn cells_marked_lit_give_exactly_one() {
        let mut rng = assist_core::Rng::new(9);
        let mut g = ShadeGrid::new(6, 2.0);
        // Lattice points with x ≤ 2 are 1 in every channel; one point among them is 1 in
        // red and green only, so the cells around it shade.
        for (i, v) in g.values.iter_mut().enumerate() {
            if (i / 3) % 6 > 2 {
                *v = 0.2 + 0.8 * rng.f32();
            }
        }
        let odd = 3 * (1 + 6 * (2 + 6 * 2)) + 2;
        g.values[odd] = 0.9;
        let lit = g.lit_cells();
        let none = LitCells::none(&g);
        let (mut marked, mut trials) = (0, 0);
        for _ in 0..20_000 {
            let c = [0.0; 3].map(|_| (rng.f32() * 2.0 - 1.0) * 2.3);
            trials += 1;
            assert!(!g.shades_nothing_at(&none, c) || g.corners(c).is_none());
            // One look-up gives what the two give, to the bit.
            match g.shading_at(&lit, c) {
                None => assert!(g.shades_nothing_at(&lit, c)),
                Some(v) => {
                    assert!(!g.shades_nothing_at(&lit, c));
                    assert_eq!(v.map(f32::to_bits), g.value(c).map(f32::to_bits));
                }
            }
            assert_eq!(g.shading_at(&none, c).is_none(), g.corners(c).is_none());
            if g.shades_nothing_at(&lit, c) {
                marked += 1;
                assert_eq!(g.value(c), [1.0; 3], "at {c:?}");
            } else if let Some((i0, _)) = g.cell(c) {
                // Unmarked inside: some corner differs from 1, in the active box.
                let (lo, hi) = lit.active_box(g.extent).unwrap();
                assert!((0..3).all(|a| (lo[a]..=hi[a]).contains(&(c[a] as f64))));
                let k = g.corners(c).unwrap();
                assert!(
                    k.index
                        .iter()
                        .any(|&p| g.values[3 * p as usize..3 * p as usize + 3] != [1.0; 3]),
                    "cell {i0:?}"
                );
            }
        }
        assert!(
            marked > trials / 10 && marked < trials,
            "{marked} of {trials}"
        );
        // The active box: where only lattice points with x ≥ 4 (of 0..5) shade, the cells
        // from x = 3 on (box units 0.4 to 2).
        let mut h = ShadeGrid::new(6, 2.0);
        for (i, v) in h.values.iter_mut().enumerate() {
            if (i / 3) % 6 >= 4 && (i / 18) % 6 == 1 {
                *v = 0.5;
            }
        }
        let (lo, hi) = h.lit_cells().active_box(h.extent).unwrap();
        assert!((lo[0] - 0.4).abs() < 1e-12 && hi[0] == 2.0, "{lo:?} {hi:?}");
        assert!(
            (lo[1] + 2.0).abs() < 1e-12 && (hi[1] + 0.4).abs() < 1e-12,
            "{lo:?} {hi:?}"
        );
        assert_eq!(ShadeGrid::new(4, 2.0).lit_cells().active_box(2.0), None);
        // A cell whose corners are all 1 gives exactly 1 whatever the weights' rounding.
        assert_eq!(g.value([-1.9, 0.37, 1.11]), [1.0; 3]);
    }

    #[test]
    fn splat_is_the_gradient_of_value() {
        let mut rng = assist_core::Rng::new(4);
        let mut g = ShadeGrid::new(5, 3.0);
        for v in &mut g.values {
            *v = 0.2 + 0.8 * rng.f32();
        }
        for _ in 0..50 {
            let c = [0, 1, 2].map(|_| (rng.f32() * 2.0 - 1.0) * 2.9);
            let k = g.corners(c).expect("inside");
            // The gradient of a weighted sum of the three channels.
            let wt = [0.3 + rng.f32(), -0.5 * rng.f32(), 2.0 * rng.f32()];
            let f = |g: &ShadeGrid| {
                let v = g.value(c);
                wt[0] * v[0] + wt[1] * v[1] + wt[2] * v[2]
            };
            let mut grad = vec![0.0; g.values.len()];
            ShadeGrid::splat(&k, wt, &mut grad);
            for (i, &an) in grad.iter().enumerate() {
                let eps = 1e-2;
                let (mut p, mut m) = (g.clone(), g.clone());
                p.values[i] += eps;
                m.values[i] -= eps;
                let num = (f(&p) - f(&m)) / (2.0 * eps);
                assert!((num - an).abs() < 1e-4, "value {i}: {an} vs {num}");
            }
        }
    }

    #[test]
    fn validate_names_what_is_wrong() {
        let mut g = ShadeGrid::new(2, 3.0);
        assert!(g.validate().is_ok());
        g.values[3] = 1.5;
        assert!(g.validate().unwrap_err().contains("value 3"));
        g.values[3] = 0.5;
        g.values.pop();
        assert!(g.validate().is_err());
    }
}
