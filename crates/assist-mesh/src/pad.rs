//! A base pad: a thin box under a flat-bottomed object, inside the outline of its base,
//! for simulators. MuJoCo collides a mesh with a box at one point of its convex hull, so
//! a flat base balances on one corner and creeps; a box under the base meets the support
//! through the box–box collider, which gives up to eight contacts. The pad lies inside
//! the convex hull of the base's points (the object's own support polygon), so it never
//! holds up an object that would tip.

use assist_core::{DQuat, DVec2, DVec3};

/// A box in a body's frame: its bottom face centred at `base` (on the object's lowest
/// level), turned by `rotation` (its z along up), `half` its half sides across up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pad {
    pub base: DVec3,
    pub rotation: DQuat,
    pub half: [f64; 2],
}

/// How thick a simulator's pad is, in metres: it reaches this far up into the object.
pub const THICKNESS_M: f64 = 0.002;

/// The base of an exported mesh: its points within this many metres of its lowest.
pub const BASE_TOLERANCE_M: f64 = 0.001;
/// No pad under a base whose rectangle has a side shorter than this, metres.
pub const MIN_SIDE_M: f64 = 0.004;

/// How far the pad keeps inside the base's outline: its sides are this share of the
/// largest rectangle found inside it.
const INSET: f64 = 0.9;

/// The pad under `points` (a mesh's vertices in its body's frame) for a body whose up is
/// `up` in that frame: the points within `tolerance` of the lowest level are the base;
/// `None` when the rectangle inside their outline has a side under `min_side` (a round
/// or pointed bottom, which a pad would make flat).
pub fn base_pad(points: &[[f64; 3]], up: DVec3, tolerance: f64, min_side: f64) -> Option<Pad> {
    let up = up.try_normalize()?;
    let turn = DQuat::from_rotation_arc(DVec3::Z, up);
    let (e1, e2) = (turn * DVec3::X, turn * DVec3::Y);
    let lowest = points
        .iter()
        .map(|p| DVec3::from_array(*p).dot(up))
        .fold(f64::INFINITY, f64::min);
    if !lowest.is_finite() {
        return None;
    }
    let base: Vec<DVec2> = points
        .iter()
        .map(|p| DVec3::from_array(*p))
        .filter(|p| p.dot(up) <= lowest + tolerance)
        .map(|p| DVec2::new(p.dot(e1), p.dot(e2)))
        .collect();
    let outline = convex_hull(base);
    let (centre, angle, half) = inscribed_rectangle(&outline)?;
    let half = half.map(|h| h * INSET);
    if half[0].min(half[1]) * 2.0 < min_side {
        return None;
    }
    Some(Pad {
        base: e1 * centre.x + e2 * centre.y + up * lowest,
        rotation: turn * DQuat::from_rotation_z(angle),
        half,
    })
}

/// The pad under an exported mesh (`points` in its body's frame, world units, the body
/// turned by `rotation` in a world whose up is `up`), with the export's thresholds in
/// metres ([`BASE_TOLERANCE_M`], [`MIN_SIDE_M`]).
pub fn exported_pad(
    points: &[[f64; 3]],
    rotation: DQuat,
    up: DVec3,
    meters_per_unit: f64,
) -> Option<Pad> {
    base_pad(
        points,
        rotation.inverse() * up,
        BASE_TOLERANCE_M / meters_per_unit,
        MIN_SIDE_M / meters_per_unit,
    )
}

impl Pad {
    /// The pad for an export's index, in metres (`meters_per_unit` per world unit).
    pub fn json_m(&self, meters_per_unit: f64) -> serde_json::Value {
        serde_json::json!({
            "base_m": (self.base * meters_per_unit).to_array(),
            "rotation_xyzw": self.rotation.to_array(),
            "half_size_m": self.half.map(|h| h * meters_per_unit),
            "thickness_m": THICKNESS_M,
        })
    }
}

/// The convex hull of `points`, counter-clockwise, without collinear points (Andrew's
/// monotone chain).
fn convex_hull(mut points: Vec<DVec2>) -> Vec<DVec2> {
    points.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    points.dedup();
    if points.len() < 3 {
        return points;
    }
    // Adds `p` to the chain from `start` on, dropping the points it leaves inside.
    let add = |hull: &mut Vec<DVec2>, start: usize, p: DVec2| {
        while hull.len() >= start + 2 {
            let (o, a) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            if (a - o).perp_dot(p - o) > 0.0 {
                break;
            }
            hull.pop();
        }
        hull.push(p);
    };
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * points.len());
    for &p in &points {
        add(&mut hull, 0, p);
    }
    hull.pop();
    let start = hull.len();
    for &p in points.iter().rev() {
        add(&mut hull, start, p);
    }
    hull.pop();
    hull
}

/// Whether `p` lies inside the counter-clockwise convex polygon `poly`.
fn inside(poly: &[DVec2], p: DVec2) -> bool {
    (0..poly.len()).all(|i| {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        (b - a).perp_dot(p - a) >= -1e-12 * (b - a).length_squared().max(1e-300)
    })
}

/// A large rectangle inside a convex polygon: its centre, its turn (radians) and half
/// sides. Every turn in steps of 2° over a quarter turn is tried, the rectangle shaped
/// like the polygon's bounds in that turn, centred at the polygon's centroid and grown
/// by bisection while its corners stay inside; the largest wins.
fn inscribed_rectangle(poly: &[DVec2]) -> Option<(DVec2, f64, [f64; 2])> {
    if poly.len() < 3 {
        return None;
    }
    let centre = centroid(poly)?;
    let mut best: Option<(DVec2, f64, [f64; 2])> = None;
    for step in 0..45 {
        let angle = (step as f64 * 2.0).to_radians();
        let (u, v) = (DVec2::from_angle(angle), DVec2::from_angle(angle).perp());
        let mut reach = [0.0f64; 2];
        for p in poly {
            let d = *p - centre;
            reach[0] = reach[0].max(d.dot(u).abs());
            reach[1] = reach[1].max(d.dot(v).abs());
        }
        let fits = |s: f64| {
            [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
                .iter()
                .all(|(a, b)| {
                    inside(
                        poly,
                        centre + u * (a * s * reach[0]) + v * (b * s * reach[1]),
                    )
                })
        };
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if fits(mid) { lo = mid } else { hi = mid }
        }
        let half = [lo * reach[0], lo * reach[1]];
        if best.is_none_or(|b| half[0] * half[1] > b.2[0] * b.2[1]) {
            best = Some((centre, angle, half));
        }
    }
    best
}

/// The area centroid of a convex polygon (`None` when it has no area).
fn centroid(poly: &[DVec2]) -> Option<DVec2> {
    let (mut area, mut c) = (0.0, DVec2::ZERO);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let w = a.perp_dot(b);
        area += w;
        c += (a + b) * w;
    }
    (area.abs() > 1e-300).then(|| c / (3.0 * area))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pad's four bottom corners, in the body's frame.
    fn corners(p: &Pad) -> Vec<DVec3> {
        [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
            .iter()
            .map(|(a, b)| p.base + p.rotation * DVec3::new(a * p.half[0], b * p.half[1], 0.0))
            .collect()
    }

    /// A box's vertices: a grid over its faces, `half` its half sizes, turned by `q`.
    fn box_points(half: DVec3, q: DQuat, offset: DVec3) -> Vec<[f64; 3]> {
        let mut out = Vec::new();
        let n = 8;
        for i in 0..=n {
            for j in 0..=n {
                for k in 0..=n {
                    let t = DVec3::new(i as f64, j as f64, k as f64) / n as f64 * 2.0 - 1.0;
                    if t.abs().max_element() == 1.0 {
                        out.push((offset + q * (t * half)).to_array());
                    }
                }
            }
        }
        out
    }

    #[test]
    fn a_turned_brick_gets_a_pad_filling_its_base() {
        let q = DQuat::from_rotation_z(0.5);
        let pts = box_points(DVec3::new(0.03, 0.02, 0.01), q, DVec3::new(1.0, 2.0, 3.0));
        let pad = base_pad(&pts, DVec3::Z, 1e-3, 4e-3).expect("a flat base has a pad");
        assert!((pad.base.z - 2.99).abs() < 1e-12, "{pad:?}");
        assert!((pad.base.truncate() - DVec2::new(1.0, 2.0)).length() < 1e-9);
        // The base is 6 × 4 cm: the pad covers 0.9² of it (the turn is found to 2°).
        let area = 4.0 * pad.half[0] * pad.half[1];
        assert!(
            area > 0.8 * 0.81 * 24e-4 && area <= 0.81 * 24e-4 + 1e-12,
            "{area}"
        );
        // Every corner inside the base, on its level.
        for c in corners(&pad) {
            let local = q.inverse() * (c - DVec3::new(1.0, 2.0, 3.0));
            assert!(local.x.abs() <= 0.03 && local.y.abs() <= 0.02, "{local}");
            assert!((local.z + 0.01).abs() < 1e-12);
        }
    }

    #[test]
    fn a_round_base_gets_a_pad_inside_its_circle() {
        // A cylinder of radius 2 cm standing on z = 0, up along −y in its body (the body
        // frame turned a quarter turn about x).
        let turn = DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2);
        let mut pts = Vec::new();
        for k in 0..64 {
            let a = k as f64 / 64.0 * std::f64::consts::TAU;
            for z in [0.0, 0.05] {
                pts.push(
                    (turn.inverse() * DVec3::new(0.02 * a.cos(), 0.02 * a.sin(), z)).to_array(),
                );
            }
        }
        pts.push((turn.inverse() * DVec3::new(0.0, 0.0, 0.0)).to_array());
        let up = turn.inverse() * DVec3::Z;
        let pad = base_pad(&pts, up, 1e-3, 4e-3).unwrap();
        for c in corners(&pad) {
            let w = turn * c;
            assert!(w.z.abs() < 1e-12);
            assert!(w.truncate().length() < 0.02, "{w}");
        }
        // A square inside a circle of radius r has a half side up to r/√2.
        assert!(
            pad.half[0].min(pad.half[1]) > 0.85 * 0.9 * 0.02 / 2f64.sqrt(),
            "{pad:?}"
        );
    }

    #[test]
    fn a_pointed_or_narrow_base_gets_none() {
        // A cone standing on its tip, and a knife edge 1 mm wide.
        let mut cone = vec![[0.0, 0.0, 0.0]];
        for k in 0..16 {
            let a = k as f64 / 16.0 * std::f64::consts::TAU;
            cone.push([0.03 * a.cos(), 0.03 * a.sin(), 0.05]);
        }
        assert_eq!(base_pad(&cone, DVec3::Z, 1e-3, 4e-3), None);
        let edge = box_points(DVec3::new(0.05, 0.0005, 0.02), DQuat::IDENTITY, DVec3::ZERO);
        assert_eq!(base_pad(&edge, DVec3::Z, 1e-3, 4e-3), None);
        assert_eq!(base_pad(&[], DVec3::Z, 1e-3, 4e-3), None);
    }

    #[test]
    fn an_l_shaped_base_keeps_the_pad_inside_its_hull() {
        // The hull of an L is a pentagon; the pad must not reach the cut-away corner.
        let mut pts = box_points(
            DVec3::new(0.04, 0.01, 0.01),
            DQuat::IDENTITY,
            DVec3::new(0.0, -0.03, 0.0),
        );
        pts.extend(box_points(
            DVec3::new(0.01, 0.04, 0.01),
            DQuat::IDENTITY,
            DVec3::new(-0.03, 0.0, 0.0),
        ));
        let pad = base_pad(&pts, DVec3::Z, 1e-3, 4e-3).unwrap();
        let hull = convex_hull(
            pts.iter()
                .filter(|p| p[2] < -0.009)
                .map(|p| DVec2::new(p[0], p[1]))
                .collect(),
        );
        for c in corners(&pad) {
            assert!(inside(&hull, c.truncate()), "{c} outside {hull:?}");
        }
        assert!(!inside(&hull, DVec2::new(0.035, 0.035)));
    }

    #[test]
    fn the_hull_drops_inner_and_collinear_points() {
        let pts = vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.5, 0.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 1.0),
            DVec2::new(0.5, 0.5),
        ];
        let h = convex_hull(pts);
        assert_eq!(h.len(), 4, "{h:?}");
        assert!((centroid(&h).unwrap() - DVec2::splat(0.5)).length() < 1e-12);
    }
}
