//! An object's shadow on the background: a coarse grid of light-attenuation factors in
//! `[0, 1]` over a region around the object's box, in the object's own frame. The
//! background's colour at a point is multiplied by the factor there (1 outside the region),
//! so the darkening an object casts on the table moves, turns and disappears with the
//! object, and the background itself learns the surface without it.
//!
//! Coordinates are box units: the object's box is `[−1, 1]³` (its local position divided by
//! its half size) and the grid spans `[−extent, extent]³`. Values sit on the `res³` lattice
//! points spanning that cube and are interpolated trilinearly.

/// Smallest factor a grid may hold (the optimiser clamps to it): an object never hides the
/// light entirely, and a factor of zero would stop the background's colour learning there.
pub const MIN_SHADE: f32 = 0.05;

#[derive(Debug, Clone, PartialEq)]
pub struct ShadeGrid {
    /// Lattice points per axis (at least 2).
    pub res: usize,
    /// Half-width of the region in box units (1 = the box itself).
    pub extent: f32,
    /// `res³` factors, x fastest.
    pub values: Vec<f32>,
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
            values: vec![1.0; res * res * res],
        }
    }

    /// The lattice points around `c` (box units) and their weights; `None` outside the
    /// region.
    #[inline]
    pub fn corners(&self, c: [f32; 3]) -> Option<Corners> {
        let n = (self.res - 1) as f32;
        let mut i0 = [0usize; 3];
        let mut f = [0f32; 3];
        for a in 0..3 {
            let u = (c[a] / self.extent + 1.0) * 0.5 * n;
            if !(0.0..=n).contains(&u) {
                return None;
            }
            let i = (u.floor() as usize).min(self.res - 2);
            i0[a] = i;
            f[a] = u - i as f32;
        }
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
        Some(out)
    }

    /// The factor at `c` (box units): 1 outside the region.
    #[inline]
    pub fn value(&self, c: [f32; 3]) -> f32 {
        match self.corners(c) {
            Some(k) => self.at(&k),
            None => 1.0,
        }
    }

    /// The interpolated factor at `k`.
    #[inline]
    pub fn at(&self, k: &Corners) -> f32 {
        (0..8)
            .map(|i| k.weight[i] * self.values[k.index[i] as usize])
            .sum()
    }

    /// Adds `g · ∂value/∂values` at `k` into `grad` (sized like `values`).
    #[inline]
    pub fn splat(k: &Corners, g: f32, grad: &mut [f32]) {
        for i in 0..8 {
            grad[k.index[i] as usize] += g * k.weight[i];
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
        if self.res < 2 || self.values.len() != self.res.pow(3) {
            return Err(format!(
                "expected res³ values with res ≥ 2, got {} values for res {}",
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
        // Lattice points at −2, 0, 2 per axis; the centre point is index 13.
        g.values[13] = 0.2;
        assert!((g.value([0.0, 0.0, 0.0]) - 0.2).abs() < 1e-6);
        // Halfway from the centre to a face: halfway between 0.2 and 1.
        assert!((g.value([1.0, 0.0, 0.0]) - 0.6).abs() < 1e-6);
        assert!((g.value([1.0, 1.0, 0.0]) - 0.8).abs() < 1e-6);
        assert_eq!(g.value([2.5, 0.0, 0.0]), 1.0);
        assert_eq!(g.value([0.0, -2.01, 0.0]), 1.0);
        // The region's faces are inside it.
        assert!((g.value([2.0, 2.0, 2.0]) - 1.0).abs() < 1e-6);
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
            let mut grad = vec![0.0; g.values.len()];
            ShadeGrid::splat(&k, 1.0, &mut grad);
            for (i, &an) in grad.iter().enumerate() {
                let eps = 1e-2;
                let (mut p, mut m) = (g.clone(), g.clone());
                p.values[i] += eps;
                m.values[i] -= eps;
                let num = (p.value(c) - m.value(c)) / (2.0 * eps);
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
