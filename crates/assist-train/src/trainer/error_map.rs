//! Training rays drawn where the scene is wrong: a coarse map of each training view's
//! photometric error (one running figure per tile of `TILE`² pixels) from which a share
//! of every batch is drawn, so that fine texture and what few views see get the rays
//! that pixels already learnt would have taken. Each ray carries the weight that keeps
//! the objective the uniform mean over pixels (importance sampling): the map lowers the
//! gradient's variance, it does not change what is fitted.

use assist_core::Rng;

use crate::views::View;

/// Tile side in pixels.
pub(super) const TILE: usize = 16;

/// The error a tile starts with: above any colour error a pixel can have, so the map's
/// draws visit every tile once before they follow what they measured.
const UNSEEN: f32 = 1.0;

/// How far one ray's error moves its tile's figure.
const RATE: f32 = 0.25;

/// Per training view and tile, the running colour error, and the cumulative weights the
/// draws search.
#[derive(Debug, Default)]
pub(super) struct ErrorMap {
    /// Share of the non-object rays drawn from the map (0: the map is off).
    pub(super) share: f64,
    /// Per view: tiles across, and the index of its first tile.
    views: Vec<(usize, usize)>,
    /// Per tile: its pixel count and running error.
    pixels: Vec<u32>,
    error: Vec<f32>,
    /// Cumulative `error × pixels` over all tiles (rebuilt by [`ErrorMap::rebuild`]).
    cdf: Vec<f64>,
    /// The training pixels in all.
    total: f64,
}

impl ErrorMap {
    pub(super) fn new(views: &[View], share: f64) -> Self {
        if share <= 0.0 {
            return ErrorMap::default();
        }
        let mut map = ErrorMap {
            share: share.min(0.9),
            ..Default::default()
        };
        for v in views {
            let (tw, th) = (v.width.div_ceil(TILE), v.height.div_ceil(TILE));
            map.views.push((tw, map.pixels.len()));
            for ty in 0..th {
                for tx in 0..tw {
                    let w = (v.width - tx * TILE).min(TILE);
                    let h = (v.height - ty * TILE).min(TILE);
                    map.pixels.push((w * h) as u32);
                }
            }
            map.total += (v.width * v.height) as f64;
        }
        map.error = vec![UNSEEN; map.pixels.len()];
        map.rebuild();
        map
    }

    pub(super) fn is_on(&self) -> bool {
        self.share > 0.0
    }

    fn tile_of(&self, views: &[View], vi: usize, p: usize) -> usize {
        let w = views[vi].width;
        let (tw, first) = self.views[vi];
        first + (p / w / TILE) * tw + (p % w) / TILE
    }

    /// The cumulative weights from the tiles' current errors.
    pub(super) fn rebuild(&mut self) {
        let mut acc = 0.0f64;
        self.cdf.clear();
        for (e, n) in self.error.iter().zip(&self.pixels) {
            acc += f64::from(*e) * f64::from(*n);
            self.cdf.push(acc);
        }
    }

    /// A pixel `(view, index)` drawn from the map (a tile by its error times its pixels,
    /// then a pixel of it uniformly); one a `mask_path` excludes is drawn again, 16 times
    /// at most.
    pub(super) fn draw(&self, views: &[View], rng: &mut Rng) -> Option<(usize, usize)> {
        let sum = *self.cdf.last()?;
        for _ in 0..16 {
            let x = rng.f64() * sum;
            let tile = self
                .cdf
                .partition_point(|&c| c <= x)
                .min(self.cdf.len() - 1);
            let vi = self.views.partition_point(|&(_, first)| first <= tile) - 1;
            let (tw, first) = self.views[vi];
            let v = &views[vi];
            let (tx, ty) = ((tile - first) % tw, (tile - first) / tw);
            let w = (v.width - tx * TILE).min(TILE);
            let h = (v.height - ty * TILE).min(TILE);
            let k = rng.below((w * h) as u64) as usize;
            let p = (ty * TILE + k / w) * v.width + tx * TILE + k % w;
            if v.valid.as_ref().is_none_or(|ok| ok[p]) {
                return Some((vi, p));
            }
        }
        None
    }

    /// The weight of a ray at pixel `p` of view `vi` drawn by the mixture (the map with
    /// probability `share`, else uniformly): the uniform draw's probability over the
    /// mixture's, so that weighted means estimate the uniform mean.
    pub(super) fn weight(&self, views: &[View], vi: usize, p: usize) -> f32 {
        let tile = self.tile_of(views, vi, p);
        let sum = self.cdf.last().copied().unwrap_or(0.0);
        let uniform = 1.0 / self.total;
        let mapped = if sum > 0.0 {
            f64::from(self.error[tile]) / sum
        } else {
            uniform
        };
        (uniform / ((1.0 - self.share) * uniform + self.share * mapped)) as f32
    }

    /// Moves each ray's tile towards its colour error, in the batch's order.
    pub(super) fn record(
        &mut self,
        views: &[View],
        rays: impl Iterator<Item = (usize, usize, f32)>,
    ) {
        for (vi, p, e) in rays {
            let t = self.tile_of(views, vi, p);
            let cur = &mut self.error[t];
            *cur = if *cur >= UNSEEN {
                e
            } else {
                *cur + RATE * (e - *cur)
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Draws follow the tiles' errors times their pixels, and the weights undo it: the
    /// weighted count of draws per pixel is the uniform one.
    #[test]
    fn draws_follow_the_error_and_weights_undo_it() {
        let views = [View::blank(40, 20), View::blank(16, 16)];
        let mut map = ErrorMap::new(&views, 0.5);
        // View 0 has 3 × 2 tiles (the last column 8 wide, the last row 4 high).
        assert_eq!(map.views, vec![(3, 0), (1, 6)]);
        assert_eq!(map.pixels, vec![256, 256, 128, 64, 64, 32, 256]);
        // Tile 1 of view 0 is wrong, the others right; view 1 is not seen yet.
        let mut seen = Vec::new();
        for t in 0..6 {
            let (tx, ty) = (t % 3, t / 3);
            let p = (ty * TILE) * 40 + tx * TILE;
            seen.push((0, p, if t == 1 { 0.08 } else { 0.01 }));
        }
        map.record(&views, seen.into_iter());
        map.rebuild();
        assert_eq!(map.error[1], 0.08);
        assert_eq!(map.error[6], UNSEEN);
        let mut rng = Rng::new(3);
        let n = 200_000;
        let mut count = [0usize; 7];
        let mut weighted = [0.0f64; 7];
        for _ in 0..n {
            // The mixture as the trainer draws it.
            let (vi, p) = if rng.f64() < map.share {
                map.draw(&views, &mut rng).unwrap()
            } else {
                let k = rng.below(40 * 20 + 256) as usize;
                if k < 800 { (0, k) } else { (1, k - 800) }
            };
            let t = map.tile_of(&views, vi, p);
            count[t] += 1;
            weighted[t] += f64::from(map.weight(&views, vi, p));
        }
        // Each tile draws its pixels times the mixture's probability: the uniform draw's
        // half, and the map's half by its error (the unseen view most, the wrong tile
        // eight times a right one per pixel).
        let sum = 0.01 * (256.0 + 128.0 + 64.0 + 64.0 + 32.0) + 0.08 * 256.0 + 256.0;
        for t in 0..7 {
            let e = [0.01, 0.08, 0.01, 0.01, 0.01, 0.01, 1.0][t];
            let want = f64::from(map.pixels[t]) * (0.5 / 1056.0 + 0.5 * e / sum);
            let got = count[t] as f64 / n as f64;
            assert!(
                (got - want).abs() < 0.03 * want + 1e-3,
                "tile {t}: {got} vs {want}"
            );
        }
        // Weighted, every tile draws its share of pixels.
        for t in 0..7 {
            let want = f64::from(map.pixels[t]) / 1056.0;
            let got = weighted[t] / n as f64;
            assert!(
                (got - want).abs() < 0.06 * want + 1e-3,
                "tile {t}: {got} vs {want}"
            );
        }
    }

    /// A tile's first error replaces the unseen mark; later ones move it by `RATE`.
    #[test]
    fn a_tile_follows_its_rays() {
        let views = [View::blank(32, 16)];
        let mut map = ErrorMap::new(&views, 0.3);
        map.record(&views, [(0, 17, 0.2)].into_iter());
        assert_eq!(map.error, vec![UNSEEN, 0.2]);
        map.record(&views, [(0, 16 + 32 * 15, 0.1), (0, 3, 0.4)].into_iter());
        assert!((map.error[1] - 0.175).abs() < 1e-7);
        assert_eq!(map.error[0], 0.4);
        assert!(!ErrorMap::new(&views, 0.0).is_on());
    }
}
