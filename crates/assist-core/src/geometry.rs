//! Rays, axis-aligned and oriented boxes, and a robust ray–box intersection.
//!
//! Every box is an axis-aligned box in some local space plus a `Similarity3` into the world.
//! An intersection reports `[t_in, t_out]` along the world ray (unit direction) and along the
//! same ray re-expressed in the box's local space (also with a unit direction): for a node
//! scaled by `s`, local distances are world distances divided by the scale along the ray,
//! which is what lets density be integrated over canonical distance.

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::similarity::Similarity3;

/// A ray `o + t d`; `dir` is kept at unit length by the constructors that build rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
}

impl Ray {
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray {
            origin,
            dir: dir.normalize(),
        }
    }
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }
}

/// An axis-aligned box `[min, max]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Aabb { min, max }
    }
    pub fn from_half_size(half: DVec3) -> Self {
        Aabb {
            min: -half,
            max: half,
        }
    }
    pub fn empty() -> Self {
        Aabb {
            min: DVec3::splat(f64::INFINITY),
            max: DVec3::splat(f64::NEG_INFINITY),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }
    pub fn extend(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    pub fn center(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }
    pub fn size(&self) -> DVec3 {
        self.max - self.min
    }
    pub fn contains(&self, p: DVec3, eps: f64) -> bool {
        p.cmpge(self.min - eps).all() && p.cmple(self.max + eps).all()
    }
    pub fn corners(&self) -> [DVec3; 8] {
        let (a, b) = (self.min, self.max);
        std::array::from_fn(|i| {
            DVec3::new(
                if i & 1 == 0 { a.x } else { b.x },
                if i & 2 == 0 { a.y } else { b.y },
                if i & 4 == 0 { a.z } else { b.z },
            )
        })
    }

    /// Slab intersection of `o + t d` (any non-zero `d`) with the box, clipped to
    /// `[t_min, t_max]`. Components of `d` that are zero are handled exactly: the ray then
    /// hits only if its origin lies within that slab (boundary included).
    pub fn intersect(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<(f64, f64)> {
        let mut t0 = t_min;
        let mut t1 = t_max;
        for a in 0..3 {
            let (oa, da, lo, hi) = (o[a], d[a], self.min[a], self.max[a]);
            if da == 0.0 {
                if oa < lo || oa > hi {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / da;
            let (mut ta, mut tb) = ((lo - oa) * inv, (hi - oa) * inv);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            // max/min written so that a NaN (impossible here, kept for safety) never widens.
            t0 = if ta > t0 { ta } else { t0 };
            t1 = if tb < t1 { tb } else { t1 };
            if t0 > t1 {
                return None;
            }
        }
        Some((t0, t1))
    }
}

/// Where a world ray crosses a box that lives in a local space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxHit {
    /// Entry and exit along the world ray (unit direction).
    pub t_in: f64,
    pub t_out: f64,
    /// The ray in local space, with a unit direction.
    pub local_ray: Ray,
    /// Entry and exit along `local_ray`.
    pub local_t_in: f64,
    pub local_t_out: f64,
    /// Local distance per unit of world distance along this ray.
    pub local_per_world: f64,
}

/// Intersects a world ray with the local box `aabb` placed by `world_from_local`.
pub fn intersect_local_box(
    ray: &Ray,
    world_from_local: &Similarity3,
    aabb: &Aabb,
    t_min: f64,
    t_max: f64,
) -> Option<BoxHit> {
    let o_local = world_from_local.local_from_world_point(ray.origin);
    let d_local = world_from_local.local_from_world_vector(ray.dir);
    let (t_in, t_out) = aabb.intersect(o_local, d_local, t_min, t_max)?;
    let k = d_local.length();
    Some(BoxHit {
        t_in,
        t_out,
        local_ray: Ray {
            origin: o_local,
            dir: d_local / k,
        },
        local_t_in: t_in * k,
        local_t_out: t_out * k,
        local_per_world: k,
    })
}

/// An oriented box in the world: centre, half extents along its own axes, and the rotation
/// `world_from_box` (columns are the box axes in world coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Obb {
    pub center: DVec3,
    pub half_size: DVec3,
    pub rotation: DMat3,
}

impl Obb {
    pub fn new(center: DVec3, size: DVec3, rotation: DMat3) -> Self {
        Obb {
            center,
            half_size: size * 0.5,
            rotation,
        }
    }
    pub fn size(&self) -> DVec3 {
        self.half_size * 2.0
    }
    /// The rigid transform from box space (centred, axis-aligned) to the world.
    pub fn world_from_box(&self) -> Similarity3 {
        Similarity3 {
            rotation: DQuat::from_mat3(&self.rotation).normalize(),
            translation: self.center,
            scale: DVec3::ONE,
        }
    }
    pub fn local_aabb(&self) -> Aabb {
        Aabb::from_half_size(self.half_size)
    }
    pub fn contains(&self, p_world: DVec3, eps: f64) -> bool {
        let p = self.rotation.transpose() * (p_world - self.center);
        self.local_aabb().contains(p, eps)
    }
    pub fn corners(&self) -> [DVec3; 8] {
        self.local_aabb()
            .corners()
            .map(|c| self.rotation * c + self.center)
    }
    pub fn world_aabb(&self) -> Aabb {
        let mut a = Aabb::empty();
        for c in self.corners() {
            a.extend(c);
        }
        a
    }
    pub fn intersect(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<BoxHit> {
        intersect_local_box(
            ray,
            &self.world_from_box(),
            &self.local_aabb(),
            t_min,
            t_max,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn rv(r: &mut Rng, s: f64) -> DVec3 {
        DVec3::new(r.range(-s, s), r.range(-s, s), r.range(-s, s))
    }

    /// Brute force: march the ray finely and record where it is inside.
    fn brute(ray: &Ray, wfl: &Similarity3, aabb: &Aabb, t_max: f64) -> Option<(f64, f64)> {
        let n = 20_000;
        let mut first = None;
        let mut last = None;
        for i in 0..=n {
            let t = t_max * i as f64 / n as f64;
            if aabb.contains(wfl.local_from_world_point(ray.at(t)), 0.0) {
                first.get_or_insert(t);
                last = Some(t);
            }
        }
        Some((first?, last?))
    }

    #[test]
    fn intersection_matches_brute_force() {
        let mut r = Rng::new(5);
        let step = 20.0 / 20_000.0;
        let mut hits = 0;
        for _ in 0..1000 {
            let wfl = Similarity3::new(
                glam::DQuat::from_xyzw(r.normal(), r.normal(), r.normal(), r.normal()).normalize(),
                rv(&mut r, 1.0),
                DVec3::new(r.range(0.3, 2.0), r.range(0.3, 2.0), r.range(0.3, 2.0)),
            )
            .unwrap();
            let aabb = Aabb::new(rv(&mut r, 1.0) - 1.0, rv(&mut r, 1.0) + 1.0);
            let aabb = Aabb::new(aabb.min.min(aabb.max), aabb.min.max(aabb.max));
            // Aim at a point near the box so that about half the rays hit.
            let origin = rv(&mut r, 5.0);
            let target = wfl.transform_point(aabb.center() + rv(&mut r, 1.5) * aabb.size());
            let ray = Ray::new(origin, target - origin);
            let fast = intersect_local_box(&ray, &wfl, &aabb, 0.0, 20.0);
            let slow = brute(&ray, &wfl, &aabb, 20.0);
            match (fast, slow) {
                (Some(h), Some((a, b))) => {
                    hits += 1;
                    // local box volume is tiny when within one step; tolerance one step.
                    assert!((h.t_in - a).abs() <= step * 1.01, "t_in {} vs {a}", h.t_in);
                    assert!(
                        (h.t_out - b).abs() <= step * 1.01,
                        "t_out {} vs {b}",
                        h.t_out
                    );
                    // The local parametrisation lands on the same points.
                    let pw = ray.at(h.t_in);
                    let pl = h.local_ray.at(h.local_t_in);
                    assert!((wfl.transform_point(pl) - pw).length() < 1e-9);
                    let pl = h.local_ray.at(h.local_t_out);
                    assert!((wfl.transform_point(pl) - ray.at(h.t_out)).length() < 1e-9);
                }
                (None, None) => {}
                (Some(h), None) => assert!(h.t_out - h.t_in < step * 1.01, "missed by brute {h:?}"),
                (None, Some((a, b))) => panic!("fast missed [{a}, {b}]"),
            }
        }
        assert!(hits > 150, "too few hits to test anything: {hits}");
    }

    #[test]
    fn axis_parallel_and_boundary_rays() {
        let b = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        // Along x, inside the y/z slabs.
        assert_eq!(
            b.intersect(DVec3::new(-5.0, 0.0, 0.0), DVec3::X, 0.0, 100.0),
            Some((4.0, 6.0))
        );
        // Along x, on the y boundary plane: grazes the face (counts as a hit).
        assert_eq!(
            b.intersect(DVec3::new(-5.0, 1.0, 0.0), DVec3::X, 0.0, 100.0),
            Some((4.0, 6.0))
        );
        // Along x, outside the y slab.
        assert_eq!(
            b.intersect(DVec3::new(-5.0, 1.5, 0.0), DVec3::X, 0.0, 100.0),
            None
        );
        // Origin inside: entry clipped to t_min.
        assert_eq!(
            b.intersect(DVec3::ZERO, DVec3::Z, 0.0, 100.0),
            Some((0.0, 1.0))
        );
        // Box behind the ray.
        assert_eq!(
            b.intersect(DVec3::new(0.0, 0.0, 5.0), DVec3::Z, 0.0, 100.0),
            None
        );
        // Negative zero direction component behaves like zero.
        assert!(
            b.intersect(
                DVec3::new(-5.0, 0.0, 0.0),
                DVec3::new(1.0, -0.0, 0.0),
                0.0,
                100.0
            )
            .is_some()
        );
    }

    #[test]
    fn scaled_node_local_distance() {
        let wfl = Similarity3::new(glam::DQuat::IDENTITY, DVec3::ZERO, DVec3::splat(2.0)).unwrap();
        let aabb = Aabb::from_half_size(DVec3::ONE);
        let ray = Ray::new(DVec3::new(-10.0, 0.0, 0.0), DVec3::X);
        let h = intersect_local_box(&ray, &wfl, &aabb, 0.0, 100.0).unwrap();
        assert!((h.t_in - 8.0).abs() < 1e-12 && (h.t_out - 12.0).abs() < 1e-12);
        // Local box is 2 wide: the local segment length is 2, half the world length.
        assert!((h.local_t_out - h.local_t_in - 2.0).abs() < 1e-12);
        assert!((h.local_per_world - 0.5).abs() < 1e-12);
    }

    #[test]
    fn obb_contains_and_corners() {
        let rot = DMat3::from_rotation_z(0.7);
        let obb = Obb::new(DVec3::new(1.0, 2.0, 3.0), DVec3::new(2.0, 1.0, 0.5), rot);
        for c in obb.corners() {
            assert!(obb.contains(c, 1e-9));
        }
        assert!(obb.contains(obb.center, 0.0));
        assert!(!obb.contains(obb.center + DVec3::Z, 0.0));
    }
}
