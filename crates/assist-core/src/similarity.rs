//! `Similarity3`: rotation, translation and per-axis scale — the pose of a scene node.
//!
//! It maps a point of the node's canonical (local) space into the world as
//! `p_world = R (s ⊙ p_local) + t`: scale along the node's own axes first, then rotate, then
//! translate. The inverse is exact (`local_from_world_point`), but the inverse of a per-axis
//! scaled transform is not itself of this form unless the scale is uniform, so composition
//! is offered only where the result is representable (`compose`).

use glam::{DAffine3, DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, check_finite};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Similarity3 {
    pub rotation: DQuat,
    pub translation: DVec3,
    /// Per-axis scale applied in local space, before the rotation. Always > 0.
    pub scale: DVec3,
}

impl Default for Similarity3 {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Similarity3 {
    pub const IDENTITY: Similarity3 = Similarity3 {
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
        scale: DVec3::ONE,
    };

    /// Builds a transform, checking that every value is finite and every scale positive.
    pub fn new(rotation: DQuat, translation: DVec3, scale: DVec3) -> Result<Self, CoreError> {
        check_finite("rotation", &rotation.to_array())?;
        check_finite("translation", &translation.to_array())?;
        check_finite("scale", &scale.to_array())?;
        if scale.min_element() <= 0.0 {
            return Err(CoreError::invalid(
                "scale",
                format!("expected every scale factor > 0, got {scale:?}"),
            ));
        }
        let n = rotation.length();
        if (n - 1.0).abs() > 1e-3 {
            return Err(CoreError::invalid(
                "rotation",
                format!("expected a unit quaternion, got length {n}"),
            ));
        }
        Ok(Similarity3 {
            rotation: rotation.normalize(),
            translation,
            scale,
        })
    }

    /// A rigid transform from a rotation matrix and translation (scale 1).
    pub fn from_rotation_translation(rotation: DMat3, translation: DVec3) -> Self {
        Similarity3 {
            rotation: DQuat::from_mat3(&rotation).normalize(),
            translation,
            scale: DVec3::ONE,
        }
    }

    pub fn from_translation(translation: DVec3) -> Self {
        Similarity3 {
            translation,
            ..Self::IDENTITY
        }
    }

    pub fn rotation_matrix(&self) -> DMat3 {
        DMat3::from_quat(self.rotation)
    }

    /// The linear part `R · diag(s)`.
    pub fn linear(&self) -> DMat3 {
        self.rotation_matrix() * DMat3::from_diagonal(self.scale)
    }

    pub fn to_affine(&self) -> DAffine3 {
        DAffine3::from_mat3_translation(self.linear(), self.translation)
    }

    /// `p_world` from `p_local`.
    pub fn transform_point(&self, p_local: DVec3) -> DVec3 {
        self.rotation * (self.scale * p_local) + self.translation
    }

    /// A direction or offset from local to world (no translation).
    pub fn transform_vector(&self, v_local: DVec3) -> DVec3 {
        self.rotation * (self.scale * v_local)
    }

    /// `p_local` from `p_world` (exact inverse of `transform_point`).
    pub fn local_from_world_point(&self, p_world: DVec3) -> DVec3 {
        (self.rotation.inverse() * (p_world - self.translation)) / self.scale
    }

    /// A world direction expressed in local space (exact inverse of `transform_vector`).
    pub fn local_from_world_vector(&self, v_world: DVec3) -> DVec3 {
        (self.rotation.inverse() * v_world) / self.scale
    }

    pub fn is_uniform_scale(&self, tol: f64) -> bool {
        let s = self.scale;
        (s.max_element() - s.min_element()).abs() <= tol * s.max_element()
    }

    /// `self ∘ inner`: apply `inner` first, then `self`. Exactly representable when `self`
    /// scales uniformly or `inner` does not rotate; otherwise a per-axis scale would shear
    /// and `None` is returned.
    pub fn compose(&self, inner: &Similarity3) -> Option<Similarity3> {
        let inner_rotates = inner.rotation.angle_between(DQuat::IDENTITY) > 1e-12;
        if self.is_uniform_scale(1e-12) {
            let s = self.scale.x;
            Some(Similarity3 {
                rotation: (self.rotation * inner.rotation).normalize(),
                translation: self.transform_point(inner.translation),
                scale: inner.scale * s,
            })
        } else if !inner_rotates {
            Some(Similarity3 {
                rotation: self.rotation,
                translation: self.transform_point(inner.translation),
                scale: self.scale * inner.scale,
            })
        } else {
            None
        }
    }

    /// The inverse, when representable (uniform scale); see `compose`.
    pub fn inverse(&self) -> Option<Similarity3> {
        if !self.is_uniform_scale(1e-12) {
            return None;
        }
        let inv_rot = self.rotation.inverse();
        let inv_s = 1.0 / self.scale.x;
        Some(Similarity3 {
            rotation: inv_rot,
            translation: -(inv_rot * self.translation) * inv_s,
            scale: DVec3::splat(inv_s),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_quat(r: &mut Rng) -> DQuat {
        DQuat::from_xyzw(r.normal(), r.normal(), r.normal(), r.normal()).normalize()
    }
    fn random_vec(r: &mut Rng, s: f64) -> DVec3 {
        DVec3::new(r.range(-s, s), r.range(-s, s), r.range(-s, s))
    }
    fn random_sim(r: &mut Rng, uniform: bool) -> Similarity3 {
        let scale = if uniform {
            DVec3::splat(r.range(0.2, 3.0))
        } else {
            DVec3::new(r.range(0.2, 3.0), r.range(0.2, 3.0), r.range(0.2, 3.0))
        };
        Similarity3::new(random_quat(r), random_vec(r, 5.0), scale).unwrap()
    }

    #[test]
    fn inverse_point_round_trip_property() {
        let mut r = Rng::new(11);
        for _ in 0..2000 {
            let s = random_sim(&mut r, false);
            let p = random_vec(&mut r, 10.0);
            let q = s.local_from_world_point(s.transform_point(p));
            assert!((q - p).length() < 1e-9, "{p} -> {q}");
            let v = random_vec(&mut r, 1.0);
            let w = s.local_from_world_vector(s.transform_vector(v));
            assert!((w - v).length() < 1e-9);
            // The affine matrix agrees with the direct formula.
            assert!((s.to_affine().transform_point3(p) - s.transform_point(p)).length() < 1e-9);
        }
    }

    #[test]
    fn composition_property() {
        let mut r = Rng::new(12);
        for i in 0..2000 {
            let outer_uniform = i % 2 == 0;
            let outer = random_sim(&mut r, outer_uniform);
            let mut inner = random_sim(&mut r, false);
            if !outer_uniform {
                inner.rotation = DQuat::IDENTITY;
            }
            let c = outer.compose(&inner).expect("representable");
            let p = random_vec(&mut r, 3.0);
            let direct = outer.transform_point(inner.transform_point(p));
            assert!((c.transform_point(p) - direct).length() < 1e-9);
        }
        // Non-representable composition is refused, not approximated.
        let outer =
            Similarity3::new(DQuat::IDENTITY, DVec3::ZERO, DVec3::new(1.0, 2.0, 3.0)).unwrap();
        let inner = Similarity3::new(DQuat::from_rotation_z(0.3), DVec3::ZERO, DVec3::ONE).unwrap();
        assert!(outer.compose(&inner).is_none());
    }

    #[test]
    fn inverse_property() {
        let mut r = Rng::new(13);
        for _ in 0..1000 {
            let s = random_sim(&mut r, true);
            let inv = s.inverse().unwrap();
            let id = s.compose(&inv).unwrap();
            let p = random_vec(&mut r, 3.0);
            assert!((id.transform_point(p) - p).length() < 1e-9);
            assert!((inv.transform_point(s.transform_point(p)) - p).length() < 1e-9);
        }
        let s = Similarity3::new(DQuat::IDENTITY, DVec3::ZERO, DVec3::new(1.0, 2.0, 1.0)).unwrap();
        assert!(s.inverse().is_none());
    }

    #[test]
    fn rejects_bad_values() {
        assert!(
            Similarity3::new(DQuat::IDENTITY, DVec3::new(f64::NAN, 0.0, 0.0), DVec3::ONE).is_err()
        );
        assert!(Similarity3::new(DQuat::IDENTITY, DVec3::ZERO, DVec3::new(1.0, 0.0, 1.0)).is_err());
        assert!(
            Similarity3::new(
                DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0),
                DVec3::ZERO,
                DVec3::ONE
            )
            .is_err()
        );
    }
}
