//! Cameras: intrinsics with distortion, camera-to-world poses in the OpenGL convention
//! (+x right, +y up, looking along −z), ray generation and projection.
//!
//! Pixel `(i, j)` (column, row, origin top-left) has its centre at `(i + 0.5, j + 0.5)`.
//! Intrinsics follow OpenCV (`u = fx x + cx` with `x = X/Z` in the OpenCV camera frame,
//! x right, y down, z forward); the OpenGL camera frame is the OpenCV frame with y and z
//! negated.

use glam::{DAffine3, DMat3, DMat4, DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::distortion::Distortion;
use crate::error::{CoreError, check_finite};
use crate::geometry::Ray;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: Distortion,
}

/// Largest image side a camera may declare (pixels).
pub const MAX_IMAGE_SIDE: u32 = 32_768;
/// Largest image a camera may declare (pixels): 256 M, far above any camera's, so that a
/// declared size can never overflow a buffer size or exhaust memory before a file is read.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 28;

impl Intrinsics {
    /// Validates sizes and focal lengths; `field` prefixes error messages.
    pub fn validate(&self, field: &str) -> Result<(), CoreError> {
        if self.width == 0 || self.height == 0 {
            return Err(CoreError::invalid(
                format!("{field}.w/h"),
                format!(
                    "expected a positive image size, got {}x{}",
                    self.width, self.height
                ),
            ));
        }
        if self.width > MAX_IMAGE_SIDE
            || self.height > MAX_IMAGE_SIDE
            || self.width as u64 * self.height as u64 > MAX_IMAGE_PIXELS
        {
            return Err(CoreError::invalid(
                format!("{field}.w/h"),
                format!(
                    "{}x{} is larger than supported (at most {MAX_IMAGE_SIDE} pixels a side and {MAX_IMAGE_PIXELS} in all)",
                    self.width, self.height
                ),
            ));
        }
        check_finite(&format!("{field}.fx"), &[self.fx])?;
        check_finite(&format!("{field}.fy"), &[self.fy])?;
        check_finite(&format!("{field}.cx"), &[self.cx])?;
        check_finite(&format!("{field}.cy"), &[self.cy])?;
        check_finite(
            &format!("{field}.distortion"),
            &self.distortion.coefficients(),
        )?;
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(CoreError::invalid(
                format!("{field}.fx/fy"),
                format!(
                    "expected positive focal lengths, got {} and {}",
                    self.fx, self.fy
                ),
            ));
        }
        Ok(())
    }

    /// A pinhole camera with the given horizontal field of view (radians), centred.
    pub fn from_fov_x(width: u32, height: u32, fov_x: f64) -> Self {
        let f = 0.5 * width as f64 / (0.5 * fov_x).tan();
        Intrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: width as f64 * 0.5,
            cy: height as f64 * 0.5,
            distortion: Distortion::None,
        }
    }

    /// The same lens at an image `factor` times smaller (e.g. LLFF's `images_8`).
    pub fn downscaled(&self, factor: f64, width: u32, height: u32) -> Self {
        Intrinsics {
            width,
            height,
            fx: self.fx / factor,
            fy: self.fy / factor,
            cx: self.cx / factor,
            cy: self.cy / factor,
            distortion: self.distortion,
        }
    }

    /// Direction in the OpenGL camera frame (not normalised, z < 0 in front) of the ray
    /// through continuous pixel coordinates `(u, v)`.
    pub fn direction_gl(&self, u: f64, v: f64) -> Option<DVec3> {
        let pd = DVec2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let d_cv = self.distortion.undistort_direction(pd)?;
        Some(DVec3::new(d_cv.x, -d_cv.y, -d_cv.z))
    }

    /// Pixel coordinates of a point in the OpenGL camera frame, and its z-depth (distance
    /// along the viewing axis). `None` behind the camera.
    pub fn project_gl(&self, p_cam: DVec3) -> Option<(DVec2, f64)> {
        let z = -p_cam.z;
        if z <= 1e-12 {
            return None;
        }
        let pn = DVec2::new(p_cam.x / z, -p_cam.y / z);
        let pd = self.distortion.distort(pn);
        Some((
            DVec2::new(self.fx * pd.x + self.cx, self.fy * pd.y + self.cy),
            z,
        ))
    }

    /// Distorted pixel of undistorted pixel coordinates (pixel units round trip helpers).
    pub fn distort_pixel(&self, undistorted: DVec2) -> DVec2 {
        let pn = DVec2::new(
            (undistorted.x - self.cx) / self.fx,
            (undistorted.y - self.cy) / self.fy,
        );
        let pd = self.distortion.distort(pn);
        DVec2::new(self.fx * pd.x + self.cx, self.fy * pd.y + self.cy)
    }

    pub fn undistort_pixel(&self, distorted: DVec2) -> Option<DVec2> {
        let pd = DVec2::new(
            (distorted.x - self.cx) / self.fx,
            (distorted.y - self.cy) / self.fy,
        );
        let p = self.distortion.undistort(pd)?;
        Some(DVec2::new(self.fx * p.x + self.cx, self.fy * p.y + self.cy))
    }
}

/// Camera-to-world rigid transform in the OpenGL convention.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub world_from_camera: DAffine3,
}

/// OpenCV camera frame ↔ OpenGL camera frame (its own inverse).
const GL_FROM_CV: DMat3 = DMat3::from_cols(DVec3::X, DVec3::NEG_Y, DVec3::NEG_Z);

impl Pose {
    /// Validates a 4×4 camera-to-world matrix (OpenGL convention): finite values, last row
    /// `0 0 0 1`, orthonormal right-handed rotation. Small scale or skew (≤ 1e-2) is
    /// removed by re-orthonormalisation; more is an error.
    pub fn from_matrix(m: DMat4, field: &str) -> Result<Self, CoreError> {
        check_finite(field, &m.to_cols_array())?;
        let row3 = m.row(3);
        if (row3 - glam::DVec4::new(0.0, 0.0, 0.0, 1.0))
            .abs()
            .max_element()
            > 1e-6
        {
            return Err(CoreError::invalid(
                field,
                format!("expected last row [0, 0, 0, 1], got {:?}", row3.to_array()),
            ));
        }
        let r = DMat3::from_mat4(m);
        let t = m.w_axis.truncate();
        Self::from_rotation_translation(r, t, field)
    }

    pub fn from_rotation_translation(r: DMat3, t: DVec3, field: &str) -> Result<Self, CoreError> {
        check_finite(field, &r.to_cols_array())?;
        check_finite(field, &t.to_array())?;
        let err = (r.transpose() * r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if err > 1e-2 {
            return Err(CoreError::invalid(
                field,
                format!(
                    "rotation part is not orthonormal (max |RᵀR − I| = {err:.3e}); expected a rigid camera-to-world transform"
                ),
            ));
        }
        if r.determinant() < 0.0 {
            return Err(CoreError::invalid(
                field,
                "rotation part is a reflection (determinant < 0)",
            ));
        }
        let q = DQuat::from_mat3(&r).normalize();
        Ok(Pose {
            world_from_camera: DAffine3::from_mat3_translation(DMat3::from_quat(q), t),
        })
    }

    /// From an OpenCV-convention camera-to-world rotation and centre.
    pub fn from_opencv_world_from_camera(
        r_cv: DMat3,
        t: DVec3,
        field: &str,
    ) -> Result<Self, CoreError> {
        Self::from_rotation_translation(r_cv * GL_FROM_CV, t, field)
    }

    /// From COLMAP's world-to-camera quaternion `(qw, qx, qy, qz)` and translation
    /// (OpenCV convention).
    pub fn from_colmap(qvec: [f64; 4], tvec: [f64; 3], field: &str) -> Result<Self, CoreError> {
        check_finite(&format!("{field}.qvec"), &qvec)?;
        check_finite(&format!("{field}.tvec"), &tvec)?;
        let q = DQuat::from_xyzw(qvec[1], qvec[2], qvec[3], qvec[0]);
        let n = q.length();
        if n.is_nan() || n <= 1e-6 {
            return Err(CoreError::invalid(
                format!("{field}.qvec"),
                "expected a non-zero quaternion",
            ));
        }
        let r_cam_from_world = DMat3::from_quat(q / n);
        let t = DVec3::from_array(tvec);
        let r_world_from_cam = r_cam_from_world.transpose();
        let centre = -(r_world_from_cam * t);
        Self::from_opencv_world_from_camera(r_world_from_cam, centre, field)
    }

    /// A camera at `eye` looking at `target`, with `up` projected to the image's up.
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> Result<Self, CoreError> {
        let back = (eye - target).normalize();
        let right = up.cross(back);
        if right.length().is_nan() || right.length() <= 1e-9 {
            return Err(CoreError::invalid(
                "look_at",
                "view direction is parallel to up",
            ));
        }
        let right = right.normalize();
        let cam_up = back.cross(right);
        Self::from_rotation_translation(DMat3::from_cols(right, cam_up, back), eye, "look_at")
    }

    pub fn rotation(&self) -> DMat3 {
        self.world_from_camera.matrix3
    }
    pub fn center(&self) -> DVec3 {
        self.world_from_camera.translation
    }
    /// Viewing direction in the world (the camera's −z axis).
    pub fn forward(&self) -> DVec3 {
        -self.rotation().z_axis
    }
    pub fn to_matrix(&self) -> DMat4 {
        DMat4::from(self.world_from_camera)
    }
    pub fn camera_from_world(&self) -> DAffine3 {
        self.world_from_camera.inverse()
    }
    /// The OpenCV-convention rotation (camera-to-world).
    pub fn rotation_opencv(&self) -> DMat3 {
        self.rotation() * GL_FROM_CV
    }
}

/// Intrinsics and pose together.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub pose: Pose,
}

impl Camera {
    pub fn width(&self) -> u32 {
        self.intrinsics.width
    }
    pub fn height(&self) -> u32 {
        self.intrinsics.height
    }

    /// World ray through continuous pixel coordinates `(u, v)`, unit direction.
    pub fn ray(&self, u: f64, v: f64) -> Option<Ray> {
        let d_cam = self.intrinsics.direction_gl(u, v)?;
        let d = self.pose.rotation() * d_cam;
        Some(Ray::new(self.pose.center(), d))
    }

    /// Ray through the centre of pixel `(i, j)`.
    pub fn pixel_ray(&self, i: u32, j: u32) -> Option<Ray> {
        self.ray(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// Z-depth of the point at distance `t` along a unit world direction `dir`.
    pub fn z_depth(&self, dir: DVec3, t: f64) -> f64 {
        t * dir.dot(self.pose.forward())
    }

    /// Pixel coordinates and z-depth of a world point; `None` if behind the camera.
    pub fn project(&self, p_world: DVec3) -> Option<(DVec2, f64)> {
        let p_cam = self.pose.camera_from_world().transform_point3(p_world);
        self.intrinsics.project_gl(p_cam)
    }

    /// World point seen at continuous pixel `(u, v)` with z-depth `z`.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> Option<DVec3> {
        let d = self.intrinsics.direction_gl(u, v)?;
        if d.z >= 0.0 {
            return None;
        }
        let p_cam = d * (z / -d.z);
        Some(self.pose.world_from_camera.transform_point3(p_cam))
    }

    /// Per pixel of a `w` × `h` depth map this camera saw (z-depths; `valid` says which
    /// pixels hold a surface): its world point and unit surface normal, the normal from
    /// the cross product of its four neighbours' differences (`None` at the border, next
    /// to an invalid pixel, or where the neighbours are collinear).
    pub fn depth_normals(
        &self,
        depth: &[f32],
        w: usize,
        h: usize,
        valid: impl Fn(usize) -> bool,
    ) -> Vec<Option<(DVec3, DVec3)>> {
        let lift = |x: usize, y: usize| {
            let i = y * w + x;
            (depth[i] > 0.0 && valid(i))
                .then(|| self.unproject(x as f64 + 0.5, y as f64 + 0.5, depth[i] as f64))
                .flatten()
        };
        let mut out = vec![None; w * h];
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let (Some(p), Some(l), Some(r), Some(u), Some(d)) = (
                    lift(x, y),
                    lift(x - 1, y),
                    lift(x + 1, y),
                    lift(x, y - 1),
                    lift(x, y + 1),
                ) else {
                    continue;
                };
                let n = (r - l).cross(d - u);
                let len = n.length();
                if len > 0.0 {
                    out[y * w + x] = Some((p, n / len));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn test_camera(distortion: Distortion) -> Camera {
        let pose = Pose::look_at(DVec3::new(1.0, 2.0, 3.0), DVec3::ZERO, DVec3::Z).unwrap();
        assert!((pose.forward() - DVec3::new(-1.0, -2.0, -3.0).normalize()).length() < 1e-12);
        Camera {
            intrinsics: Intrinsics {
                width: 640,
                height: 480,
                fx: 500.0,
                fy: 510.0,
                cx: 321.0,
                cy: 238.5,
                distortion,
            },
            pose,
        }
    }

    #[test]
    fn pixel_ray_projects_back_to_its_pixel() {
        for d in [
            Distortion::None,
            Distortion::OpenCv {
                k1: -0.2,
                k2: 0.05,
                k3: 0.0,
                p1: 1e-3,
                p2: 2e-4,
            },
            Distortion::Fisheye {
                k1: 0.1,
                k2: -0.02,
                k3: 0.0,
                k4: 0.0,
            },
        ] {
            let cam = test_camera(d);
            let mut r = Rng::new(1);
            for _ in 0..500 {
                let (u, v) = (r.range(0.0, 640.0), r.range(0.0, 480.0));
                let ray = cam.ray(u, v).unwrap();
                let p = ray.at(r.range(0.5, 5.0));
                let (px, _) = cam.project(p).unwrap();
                assert!(
                    (px - DVec2::new(u, v)).length() < 1e-7,
                    "{d:?} {u},{v} -> {px}"
                );
            }
        }
    }

    #[test]
    fn pixel_distortion_round_trip_below_1e4_px() {
        let cam = test_camera(Distortion::OpenCv {
            k1: -0.3,
            k2: 0.09,
            k3: -0.01,
            p1: 8e-4,
            p2: -6e-4,
        });
        let fe = test_camera(Distortion::Fisheye {
            k1: -0.01,
            k2: 0.003,
            k3: -0.001,
            k4: 0.0001,
        });
        for c in [cam, fe] {
            let mut worst = 0.0f64;
            for j in (0..480).step_by(7) {
                for i in (0..640).step_by(7) {
                    let p = DVec2::new(i as f64 + 0.5, j as f64 + 0.5);
                    let u = c.intrinsics.undistort_pixel(p).unwrap();
                    worst = worst.max((c.intrinsics.distort_pixel(u) - p).length());
                }
            }
            assert!(worst < 1e-4, "worst round-trip {worst} px");
        }
    }

    #[test]
    fn looks_along_negative_z_and_pixel_centres() {
        let pose = Pose::from_matrix(DMat4::IDENTITY, "pose").unwrap();
        let cam = Camera {
            intrinsics: Intrinsics::from_fov_x(4, 2, std::f64::consts::FRAC_PI_2),
            pose,
        };
        // Pixel (1, 0)'s centre is at u = 1.5, left of the principal point 2.0, above cy = 1.
        let r = cam.pixel_ray(1, 0).unwrap();
        assert!(r.dir.x < 0.0 && r.dir.y > 0.0 && r.dir.z < 0.0);
        let c = cam.ray(2.0, 1.0).unwrap();
        assert!((c.dir - DVec3::NEG_Z).length() < 1e-12);
        // z-depth of a point 2 units along a slanted ray.
        let p = r.at(2.0);
        assert!((cam.z_depth(r.dir, 2.0) + p.z).abs() < 1e-12);
        let q = cam.unproject(1.5, 0.5, 3.0).unwrap();
        assert!((q.z + 3.0).abs() < 1e-12);
    }

    #[test]
    fn colmap_pose_conversion() {
        // Camera at (0,0,-5) in OpenCV convention looking along +z (identity rotation).
        let pose = Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 5.0], "img").unwrap();
        assert!((pose.center() - DVec3::new(0.0, 0.0, -5.0)).length() < 1e-12);
        assert!((pose.forward() - DVec3::Z).length() < 1e-12);
        // The OpenGL camera's up is the OpenCV camera's −y.
        assert!((pose.rotation().y_axis - DVec3::NEG_Y).length() < 1e-12);
    }

    #[test]
    fn rejects_bad_poses() {
        let mut m = DMat4::IDENTITY;
        m.x_axis.y = f64::NAN;
        assert!(
            Pose::from_matrix(m, "frames[0].transform_matrix")
                .unwrap_err()
                .to_string()
                .contains("frames[0].transform_matrix")
        );
        let s = DMat4::from_scale(DVec3::splat(2.0));
        assert!(Pose::from_matrix(s, "p").is_err());
        let refl = DMat4::from_scale(DVec3::new(1.0, 1.0, -1.0));
        assert!(Pose::from_matrix(refl, "p").is_err());
    }
}
