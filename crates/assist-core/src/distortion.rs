//! Lens distortion: OpenCV radial-tangential (k1, k2, k3, p1, p2) and OpenCV fisheye
//! (equidistant, k1..k4), applied to normalised image coordinates of the OpenCV camera
//! frame (x right, y down, z forward). Undistortion is solved by Newton's method with the
//! analytic Jacobian, so `distort(undistort(p)) == p` to round-off.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    #[default]
    None,
    /// OpenCV's radial-tangential model (`cv::projectPoints` with 5 coefficients).
    OpenCv {
        k1: f64,
        k2: f64,
        k3: f64,
        p1: f64,
        p2: f64,
    },
    /// OpenCV's fisheye (equidistant) model (`cv::fisheye`).
    Fisheye { k1: f64, k2: f64, k3: f64, k4: f64 },
}

impl Distortion {
    pub fn is_none(&self) -> bool {
        match *self {
            Distortion::None => true,
            Distortion::OpenCv { k1, k2, k3, p1, p2 } => {
                [k1, k2, k3, p1, p2].iter().all(|&v| v == 0.0)
            }
            Distortion::Fisheye { .. } => false,
        }
    }

    pub fn coefficients(&self) -> Vec<f64> {
        match *self {
            Distortion::None => vec![],
            Distortion::OpenCv { k1, k2, k3, p1, p2 } => vec![k1, k2, k3, p1, p2],
            Distortion::Fisheye { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        }
    }

    /// Distorts the normalised coordinates of a point at `(x, y, 1)` (for fisheye: of any
    /// point in front of the camera, given as `x/z, y/z`).
    pub fn distort(&self, p: DVec2) -> DVec2 {
        match *self {
            Distortion::None => p,
            Distortion::OpenCv { k1, k2, k3, p1, p2 } => {
                let (x, y) = (p.x, p.y);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                DVec2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Distortion::Fisheye { .. } => {
                let r = p.length();
                if r < 1e-15 {
                    return p;
                }
                let theta = r.atan();
                p * (self.fisheye_theta_d(theta) / r)
            }
        }
    }

    fn fisheye_theta_d(&self, theta: f64) -> f64 {
        let Distortion::Fisheye { k1, k2, k3, k4 } = *self else {
            return theta;
        };
        let t2 = theta * theta;
        theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    }

    /// The camera-frame direction (OpenCV frame, not normalised) of the ray through the
    /// distorted normalised coordinates `pd`. `None` when no ray maps there (outside the
    /// lens model's valid range).
    pub fn undistort_direction(&self, pd: DVec2) -> Option<DVec3> {
        match *self {
            Distortion::None => Some(pd.extend(1.0)),
            Distortion::OpenCv { .. } => self.undistort_opencv(pd).map(|p| p.extend(1.0)),
            Distortion::Fisheye { k1, k2, k3, k4 } => {
                let rd = pd.length();
                if rd < 1e-15 {
                    return Some(DVec3::new(pd.x, pd.y, 1.0));
                }
                // Solve theta_d(theta) = rd by Newton from theta = rd.
                let mut theta = rd.min(std::f64::consts::PI * 0.999);
                for _ in 0..60 {
                    let t2 = theta * theta;
                    let f = self.fisheye_theta_d(theta) - rd;
                    let df =
                        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
                    if df.abs() < 1e-12 {
                        return None;
                    }
                    let step = f / df;
                    theta -= step;
                    if step.abs() < 1e-15 {
                        break;
                    }
                }
                if !(theta.is_finite() && (0.0..std::f64::consts::PI).contains(&theta)) {
                    return None;
                }
                if (self.fisheye_theta_d(theta) - rd).abs() > 1e-9 {
                    return None;
                }
                let s = theta.sin() / rd;
                Some(DVec3::new(pd.x * s, pd.y * s, theta.cos()))
            }
        }
    }

    /// Undistorted normalised coordinates `(x, y)` for the point at `(x, y, 1)`.
    pub fn undistort(&self, pd: DVec2) -> Option<DVec2> {
        let d = self.undistort_direction(pd)?;
        if d.z <= 0.0 {
            return None;
        }
        Some(DVec2::new(d.x / d.z, d.y / d.z))
    }

    fn undistort_opencv(&self, pd: DVec2) -> Option<DVec2> {
        let Distortion::OpenCv { k1, k2, k3, p1, p2 } = *self else {
            return Some(pd);
        };
        let mut p = pd;
        for _ in 0..60 {
            let (x, y) = (p.x, p.y);
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
            let f = self.distort(p) - pd;
            let jxx = radial + x * dradial_dr2 * 2.0 * x + 2.0 * p1 * y + 6.0 * p2 * x;
            let jxy = x * dradial_dr2 * 2.0 * y + 2.0 * p1 * x + 2.0 * p2 * y;
            let jyx = y * dradial_dr2 * 2.0 * x + 2.0 * p1 * x + 2.0 * p2 * y;
            let jyy = radial + y * dradial_dr2 * 2.0 * y + 6.0 * p1 * y + 2.0 * p2 * x;
            let det = jxx * jyy - jxy * jyx;
            if det.abs() < 1e-15 || !det.is_finite() {
                return None;
            }
            let step = DVec2::new((jyy * f.x - jxy * f.y) / det, (jxx * f.y - jyx * f.x) / det);
            p -= step;
            if step.length() < 1e-15 {
                break;
            }
        }
        let err = (self.distort(p) - pd).length();
        (p.is_finite() && err < 1e-9).then_some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn none_is_identity() {
        let p = DVec2::new(0.3, -0.2);
        assert_eq!(Distortion::None.distort(p), p);
        assert_eq!(Distortion::None.undistort(p), Some(p));
    }

    #[test]
    fn opencv_round_trip() {
        let d = Distortion::OpenCv {
            k1: -0.28,
            k2: 0.07,
            k3: 0.01,
            p1: 1e-3,
            p2: -5e-4,
        };
        for i in 0..21 {
            for j in 0..21 {
                let pd = DVec2::new(-0.6 + 0.06 * i as f64, -0.45 + 0.045 * j as f64);
                let p = d.undistort(pd).unwrap();
                assert!((d.distort(p) - pd).length() < 1e-12, "{pd}");
            }
        }
    }

    #[test]
    fn fisheye_round_trip_and_wide_angles() {
        let d = Distortion::Fisheye {
            k1: 0.05,
            k2: -0.01,
            k3: 0.002,
            k4: -0.0003,
        };
        for i in 0..41 {
            for j in 0..41 {
                let pd = DVec2::new(-1.4 + 0.07 * i as f64, -1.4 + 0.07 * j as f64);
                let dir = d.undistort_direction(pd).unwrap();
                if dir.z > 1e-6 {
                    let back = d.distort(DVec2::new(dir.x / dir.z, dir.y / dir.z));
                    assert!((back - pd).length() < 1e-12, "{pd} -> {back}");
                }
                // The angle from the axis follows the equidistant model.
                let theta = dir.truncate().length().atan2(dir.z);
                let t2 = theta * theta;
                let rd = theta * (1.0 + t2 * (0.05 + t2 * (-0.01 + t2 * (0.002 + t2 * -0.0003))));
                assert!((rd - pd.length()).abs() < 1e-12);
            }
        }
    }
}
