//! Plausible placement: an object stands with its lowest occupied point on a support
//! surface, its footprint on flat, seen ground, and its occupied box apart from every other
//! object's by the gap.
//!
//! An object's shape is taken from its own occupancy grid (what training found occupied),
//! not from its box: the occupied cells' extent is the *occupied box* (tight, in the node's
//! frame) used for collisions, and the lowest and highest occupied cell of each column
//! along the node's axis nearest to up give its bottom and footprint. Cells below the
//! surface the object stood on in its own capture are dropped: no view saw them (the table
//! hid them), so what training left there is not part of the object.

use assist_core::{DMat3, DQuat, DVec3, Obb, SceneNode, Similarity3};
use assist_session::NodeField;

use crate::surface::SupportMap;

/// An object's occupied shape in its field's unit cube `[0, 1]³`.
#[derive(Debug, Clone)]
pub struct Shape {
    /// Column extremes of the occupied cells (cell centres), unit coordinates.
    pub points: Vec<[f64; 3]>,
    /// The occupied cells' extent (cell corners), unit coordinates.
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl Shape {
    /// The shape of a field's occupancy; `up_axis` is the local axis along which columns
    /// are taken; only cells whose centre `keep` accepts count. `None` when nothing is
    /// occupied.
    pub fn of(nf: &NodeField, up_axis: usize, keep: impl Fn([f64; 3]) -> bool) -> Option<Shape> {
        let g = &nf.occupancy;
        let r = g.res as usize;
        let (a, b) = match up_axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let idx = |v: [usize; 3]| v[0] + r * (v[1] + r * v[2]);
        let mut points = Vec::new();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for i in 0..r {
            for j in 0..r {
                let mut first = None;
                let mut last = None;
                for k in 0..r {
                    let mut v = [0; 3];
                    v[a] = i;
                    v[b] = j;
                    v[up_axis] = k;
                    if g.is_occupied_cell(idx(v)) && keep(v.map(|c| (c as f64 + 0.5) / r as f64)) {
                        first.get_or_insert(v);
                        last = Some(v);
                    }
                }
                for v in [first, last].into_iter().flatten() {
                    let p = v.map(|c| (c as f64 + 0.5) / r as f64);
                    for ax in 0..3 {
                        lo[ax] = lo[ax].min(v[ax] as f64 / r as f64);
                        hi[ax] = hi[ax].max((v[ax] + 1) as f64 / r as f64);
                    }
                    if points.last() != Some(&p) {
                        points.push(p);
                    }
                }
            }
        }
        (!points.is_empty()).then_some(Shape { points, lo, hi })
    }
}

/// The local axis of `node` nearest to `up` in the world.
pub fn up_axis(pose: &Similarity3, up: DVec3) -> usize {
    let r = pose.rotation_matrix();
    (0..3)
        .max_by(|&x, &y| r.col(x).dot(up).abs().total_cmp(&r.col(y).dot(up).abs()))
        .unwrap_or(2)
}

/// An object in a candidate pose: its world transform and half size.
#[derive(Debug, Clone, Copy)]
pub struct Posed {
    pub pose: Similarity3,
    pub half_size: DVec3,
}

impl Posed {
    pub fn of(n: &SceneNode) -> Self {
        Posed {
            pose: n.world_from_local,
            half_size: n.half_size,
        }
    }
    /// A unit-cube point in the world.
    pub fn world(&self, u: [f64; 3]) -> DVec3 {
        let local = (DVec3::from_array(u) - 0.5) * (self.half_size * 2.0);
        self.pose.translation + self.pose.rotation * (local * self.pose.scale)
    }
    /// The occupied box in the world.
    pub fn occupied_box(&self, s: &Shape) -> Obb {
        let lo = self.world_local(s.lo);
        let hi = self.world_local(s.hi);
        let centre_local = (lo + hi) * 0.5;
        Obb {
            center: self.pose.translation + self.pose.rotation * centre_local,
            half_size: (hi - lo).abs() * 0.5,
            rotation: DMat3::from_quat(self.pose.rotation),
        }
    }
    fn world_local(&self, u: [f64; 3]) -> DVec3 {
        (DVec3::from_array(u) - 0.5) * (self.half_size * 2.0) * self.pose.scale
    }
    /// The lowest occupied point's height along `up`.
    pub fn bottom(&self, s: &Shape, up: DVec3) -> f64 {
        s.points
            .iter()
            .map(|&u| self.world(u).dot(up))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Whether two oriented boxes, each grown by `gap / 2`, overlap (separating axis test).
pub fn boxes_overlap(a: &Obb, b: &Obb, gap: f64) -> bool {
    let ha = a.half_size + gap * 0.5;
    let hb = b.half_size + gap * 0.5;
    let ra = [a.rotation.col(0), a.rotation.col(1), a.rotation.col(2)];
    let rb = [b.rotation.col(0), b.rotation.col(1), b.rotation.col(2)];
    let t = b.center - a.center;
    let mut axes: Vec<DVec3> = Vec::with_capacity(15);
    axes.extend(ra);
    axes.extend(rb);
    for x in ra {
        for y in rb {
            let c = x.cross(y);
            if c.length_squared() > 1e-12 {
                axes.push(c.normalize());
            }
        }
    }
    for l in axes {
        let pa: f64 = (0..3).map(|k| ha[k] * ra[k].dot(l).abs()).sum();
        let pb: f64 = (0..3).map(|k| hb[k] * rb[k].dot(l).abs()).sum();
        if t.dot(l).abs() > pa + pb {
            return false;
        }
    }
    true
}

/// Why a draw was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Reject {
    /// Part of the footprint is over no allowed surface (off the captured area or a
    /// table's edge).
    OffSurface,
    /// The support under the footprint is not flat.
    NotFlat,
    /// It would overlap another object.
    Overlap,
}

impl Reject {
    pub fn name(self) -> &'static str {
        match self {
            Reject::OffSurface => "off the supported area",
            Reject::NotFlat => "support not flat",
            Reject::Overlap => "overlaps another object",
        }
    }
}

/// Rests `obj` (its plane position and orientation given) on the support under it: returns
/// the pose with its lowest occupied point on the support under its footprint (which must
/// be allowed everywhere and flat within `flatness`), and that support height.
pub fn rest(
    obj: &Posed,
    shape: &Shape,
    support: &SupportMap,
    flatness: f64,
) -> Result<(Posed, f64), Reject> {
    let f = &support.frame;
    let mut hs = Vec::with_capacity(shape.points.len());
    for &u in &shape.points {
        let p = obj.world(u);
        let Some(h) = support.allowed_height(f.plane(p)) else {
            return Err(Reject::OffSurface);
        };
        hs.push(h);
    }
    hs.sort_by(f64::total_cmp);
    let (lo, hi) = (hs[0], hs[hs.len() - 1]);
    if hi - lo > flatness {
        return Err(Reject::NotFlat);
    }
    // The surface estimate is noisy by a few millimetres; its median under the footprint
    // is where the object stands.
    let level = hs[hs.len() / 2];
    let bottom = obj.bottom(shape, f.up);
    let mut out = *obj;
    out.pose.translation += f.up * (level - bottom);
    Ok((out, level))
}

/// A rotation by `deg` degrees about `up`, applied on the left of `q` (as the editor's
/// world-frame rotate does).
pub fn yawed(q: DQuat, up: DVec3, deg: f64) -> DQuat {
    DQuat::from_axis_angle(up.normalize(), deg.to_radians()) * q
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obb(c: [f64; 3], h: [f64; 3], yaw: f64) -> Obb {
        Obb {
            center: DVec3::from_array(c),
            half_size: DVec3::from_array(h),
            rotation: DMat3::from_rotation_z(yaw.to_radians()),
        }
    }

    #[test]
    fn separating_axes_decide_overlap() {
        let a = obb([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0);
        assert!(boxes_overlap(
            &a,
            &obb([1.9, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0),
            0.0
        ));
        assert!(!boxes_overlap(
            &a,
            &obb([2.1, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0),
            0.0
        ));
        // The gap counts.
        assert!(boxes_overlap(
            &a,
            &obb([2.1, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0),
            0.2
        ));
        // A box turned 45° reaches √2 along x: apart at 2.45, touching at 2.35.
        assert!(!boxes_overlap(
            &a,
            &obb([2.45, 0.0, 0.0], [1.0, 1.0, 1.0], 45.0),
            0.0
        ));
        assert!(boxes_overlap(
            &a,
            &obb([2.35, 0.0, 0.0], [1.0, 1.0, 1.0], 45.0),
            0.0
        ));
        // Diagonal neighbours whose projections overlap on x and y but not on the
        // cross axis.
        let b = obb([1.5, 1.5, 0.0], [0.2, 1.0, 0.5], 45.0);
        let c = obb([0.0, 0.0, 0.0], [0.2, 1.0, 0.5], 45.0);
        assert!(!boxes_overlap(&b, &c, 0.0));
    }

    #[test]
    fn posed_points_follow_rotation_scale_and_translation() {
        let p = Posed {
            pose: Similarity3 {
                rotation: DQuat::from_rotation_z(90f64.to_radians()),
                translation: DVec3::new(1.0, 2.0, 3.0),
                scale: DVec3::splat(2.0),
            },
            half_size: DVec3::new(0.5, 0.25, 0.5),
        };
        // Unit corner (1, 0.5, 0.5) is local (0.5, 0, 0) → scaled (1, 0, 0) → turned
        // (0, 1, 0) → (1, 3, 3).
        let w = p.world([1.0, 0.5, 0.5]);
        assert!((w - DVec3::new(1.0, 3.0, 3.0)).length() < 1e-12, "{w}");
        let s = Shape {
            points: vec![[0.5, 0.5, 0.0], [0.5, 0.5, 1.0]],
            lo: [0.25, 0.0, 0.0],
            hi: [0.75, 1.0, 1.0],
        };
        assert!((p.bottom(&s, DVec3::Z) - 2.0).abs() < 1e-12);
        let b = p.occupied_box(&s);
        assert!((b.half_size - DVec3::new(0.5, 0.5, 1.0)).length() < 1e-12);
        assert!((b.center - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    }
}
