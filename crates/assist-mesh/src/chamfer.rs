//! Distances between point sets (nearest neighbours through a uniform hash grid), and the
//! Chamfer distance of a mesh to reference points: both directions reported apart, since
//! a reference from depth maps holds only the surfaces the cameras saw.

use std::collections::HashMap;

use assist_core::DVec3;
use rayon::prelude::*;
use serde::Serialize;

/// Points bucketed by a cubic cell for nearest-neighbour queries.
pub struct PointIndex {
    cell: f64,
    cells: HashMap<[i64; 3], Vec<DVec3>>,
}

impl PointIndex {
    /// An index of `points` with cells of `cell` (about the expected query distance).
    pub fn new(points: &[DVec3], cell: f64) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<DVec3>> = HashMap::new();
        for p in points {
            cells.entry(Self::key(cell, *p)).or_default().push(*p);
        }
        PointIndex { cell, cells }
    }

    fn key(cell: f64, p: DVec3) -> [i64; 3] {
        (p / cell).floor().to_array().map(|v| v as i64)
    }

    /// Distance from `q` to the nearest indexed point, searching at most `max_rings` cells
    /// out (beyond that: the distance found so far, or infinity).
    pub fn nearest(&self, q: DVec3, max_rings: i64) -> f64 {
        let c = Self::key(self.cell, q);
        let mut best = f64::INFINITY;
        for r in 0..=max_rings {
            // Every point outside the cube of rings 0..=r is more than r cells away.
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        if let Some(v) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            for p in v {
                                best = best.min(p.distance(q));
                            }
                        }
                    }
                }
            }
            if best <= r as f64 * self.cell {
                break;
            }
        }
        best
    }
}

/// Summary of distances from one point set to another.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Distances {
    pub mean: f64,
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
    /// Share of points within `within` of the other set.
    pub within_share: f64,
    pub within: f64,
    pub points: usize,
}

/// Distances from each of `from` to the nearest of `to` (`within`: the threshold for
/// the share reported).
pub fn distances(from: &[DVec3], to: &[DVec3], within: f64) -> Distances {
    let cell = within.max(1e-9);
    let index = PointIndex::new(to, cell);
    let mut d: Vec<f64> = from.par_iter().map(|p| index.nearest(*p, 256)).collect();
    d.sort_by(f64::total_cmp);
    let n = d.len().max(1) as f64;
    let pick = |q: f64| {
        d.get(((d.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    Distances {
        mean: d.iter().sum::<f64>() / n,
        median: pick(0.5),
        p90: pick(0.9),
        within_share: d.iter().filter(|&&x| x <= within).count() as f64 / n,
        within,
        points: d.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::Rng;

    #[test]
    fn the_grid_finds_the_same_neighbour_as_brute_force() {
        let mut rng = Rng::new(5);
        let mut pt = || {
            DVec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            )
        };
        let to: Vec<DVec3> = (0..500).map(|_| pt()).collect();
        let from: Vec<DVec3> = (0..200).map(|_| pt() * 1.5).collect();
        for cell in [0.05, 0.1, 0.7] {
            let idx = PointIndex::new(&to, cell);
            for q in &from {
                let brute = to
                    .iter()
                    .map(|p| p.distance(*q))
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(idx.nearest(*q, 10_000), brute, "cell {cell}");
            }
        }
        let d = distances(&from, &to, 0.05);
        assert_eq!(d.points, 200);
        assert!(d.median <= d.p90 && d.within_share <= 1.0);
    }
}
