//! Which way is up in a capture that does not say, from how its cameras were held.
//!
//! People hold phones and cameras level: a photograph's horizontal (the camera's right
//! axis) is horizontal in the world however far the camera looks up or down. Up is then
//! the direction perpendicular to every camera's right axis, found once the cameras
//! turned about the vertical enough for their right axes to span a plane. The mean of
//! the cameras' own up axes is not it for a capture that looks down at a floor or table
//! from one side: each image's up leans forward by the camera's pitch, and nothing
//! cancels the lean (around an object the leans cancel). When the right axes are all
//! about parallel (a capture facing one way), the mean up made perpendicular to them is
//! all the cameras tell.

use glam::{DMat3, DVec3};

/// The least spread of the cameras' right axes (the second eigenvalue of their mean
/// outer product, whose eigenvalues sum to 1) at which they fix up: their directions
/// spread over about ±10° of yaw.
pub const RIGHT_AXES_SPREAD: f64 = 0.03;

/// Up (against gravity) from each camera's right and up axes in the world (`(right,
/// up)`, unit vectors): perpendicular to the right axes, on the side of the mean up (see
/// the module's comment). `None` when the cameras' up axes disagree so much that their
/// mean is shorter than half (views turned every which way): no side to take.
pub fn cameras_up(axes: impl IntoIterator<Item = (DVec3, DVec3)>) -> Option<DVec3> {
    let (mut outer, mut sum, mut n) = (DMat3::ZERO, DVec3::ZERO, 0usize);
    for (r, u) in axes {
        outer += DMat3::from_cols(r * r.x, r * r.y, r * r.z);
        sum += u;
        n += 1;
    }
    let mean = sum / n.max(1) as f64;
    if mean.length() < 0.5 {
        return None;
    }
    let mean = mean.normalize();
    let (values, vectors) = symmetric_eigen(outer * (1.0 / n as f64));
    let up = if values[1] >= RIGHT_AXES_SPREAD {
        vectors[2] * vectors[2].dot(mean).signum()
    } else {
        (mean - vectors[0] * vectors[0].dot(mean)).normalize_or(mean)
    };
    Some(up)
}

/// Eigenvalues (largest first) and unit eigenvectors of a symmetric 3×3 matrix.
pub fn symmetric_eigen(m: DMat3) -> ([f64; 3], [DVec3; 3]) {
    let (values, vectors) = crate::eigen::symmetric_eigen(m.to_cols_array_2d());
    (values, vectors.map(DVec3::from_array))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at `eye` looking at `target`, level (its right axis horizontal for `up`):
    /// its right and up axes.
    fn level(eye: DVec3, target: DVec3, up: DVec3) -> (DVec3, DVec3) {
        let back = (eye - target).normalize();
        let right = up.cross(back).normalize();
        (right, back.cross(right))
    }

    #[test]
    fn eigen_decomposes_a_symmetric_matrix() {
        let r = DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 0.7);
        let m = r * DMat3::from_diagonal(DVec3::new(0.2, 3.0, -1.0)) * r.transpose();
        let (values, vectors) = symmetric_eigen(m);
        for (want, got) in [3.0, 0.2, -1.0].iter().zip(values) {
            assert!((want - got).abs() < 1e-12, "{values:?}");
        }
        for (l, v) in values.iter().zip(vectors) {
            assert!((m * v - v * *l).length() < 1e-12);
        }
    }

    /// Cameras on an arc in front of an object, looking down at it (a phone filming a can
    /// on the floor): their mean up leans forward by the pitch; the right axes give up.
    #[test]
    fn a_capture_looking_down_from_one_side_is_upright() {
        let turn = DMat3::from_euler(glam::EulerRot::XYZ, 1.1, -0.4, 2.3);
        let up = turn * DVec3::Z;
        let axes: Vec<(DVec3, DVec3)> = (0..15)
            .map(|k| {
                let a = (k as f64 / 14.0 - 0.5) * 1.2 - std::f64::consts::FRAC_PI_2;
                let eye = DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 2.5);
                level(turn * eye, DVec3::ZERO, up)
            })
            .collect();
        let mean = axes.iter().map(|a| a.1).sum::<DVec3>().normalize();
        let lean = mean.angle_between(up).to_degrees();
        assert!(lean > 30.0, "the mean up leans {lean}°");
        let got = cameras_up(axes.iter().copied()).unwrap();
        assert!(got.angle_between(up).to_degrees() < 1e-6, "{got} vs {up}");
        // Around an object too (where the mean was right already).
        let around: Vec<(DVec3, DVec3)> = (0..12)
            .map(|k| {
                let a = k as f64 / 12.0 * std::f64::consts::TAU;
                level(
                    turn * DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 1.5),
                    DVec3::ZERO,
                    up,
                )
            })
            .collect();
        let got = cameras_up(around).unwrap();
        assert!(got.angle_between(up).to_degrees() < 1e-6);
    }

    /// Cameras that all face one way (right axes parallel) tell only their mean up, made
    /// perpendicular to the right axis; cameras turned every which way tell nothing.
    #[test]
    fn parallel_right_axes_keep_the_mean_up() {
        let axes: Vec<(DVec3, DVec3)> = (0..8)
            .map(|k| {
                let eye = DVec3::new(0.1 * k as f64, -3.0, 1.0 + 0.05 * k as f64);
                level(eye, DVec3::new(0.1 * k as f64, 0.0, 0.0), DVec3::Z)
            })
            .collect();
        let mean = axes.iter().map(|a| a.1).sum::<DVec3>().normalize();
        let got = cameras_up(axes).unwrap();
        assert!((got - mean).length() < 1e-9, "{got} vs {mean}");
        let rolled = [DVec3::Z, DVec3::X, -DVec3::Z, -DVec3::X].map(|u| (u.cross(DVec3::Y), u));
        assert_eq!(cameras_up(rolled), None);
    }
}
