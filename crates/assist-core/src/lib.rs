//! assist-core: the shared vocabulary of assist.
//!
//! Geometry (`Similarity3`, oriented boxes, rays and their intersection), cameras (pinhole
//! intrinsics, OpenCV radial-tangential and fisheye distortion, camera-to-world poses in the
//! OpenGL convention with conversion from OpenCV/COLMAP) and a small deterministic random
//! number generator that every crate can rely on for reproducible results.
//!
//! Conventions (see `ARCHITECTURE.md`): cameras are camera-to-world in the OpenGL convention
//! (+x right, +y up, looking along −z); pixel centres sit at +0.5; transforms are named
//! `x_from_y`. Geometry is computed in `f64`; the renderer converts to `f32` batches.

#![forbid(unsafe_code)]

pub mod action;
pub mod camera;
pub mod distortion;
pub mod edit;
pub mod eigen;
pub mod error;
pub mod geometry;
pub mod placement;
pub mod rng;
pub mod scene;
pub mod similarity;
pub mod up;

pub use action::{
    Action, ActionConfig, ActionError, AxisSpec, Edit, NodeRef, Operation, SceneSource,
};
pub use camera::{Camera, Intrinsics, Pose};
pub use distortion::Distortion;
pub use edit::{History, HistoryStep};
pub use error::CoreError;
pub use geometry::{Aabb, BoxHit, Obb, Ray};
pub use glam;
pub use glam::{DAffine3, DMat3, DMat4, DQuat, DVec2, DVec3, Vec3};
pub use rng::Rng;
pub use scene::{Backdrop, KeyLight, NodeSpace, Scene, SceneNode, ShadowCast};
pub use similarity::Similarity3;
pub use up::cameras_up;

/// Instance identifier of a scene node; 0 is the background.
pub type InstanceId = u16;

/// A number as messages print it: the shortest form that reads back, in exponent form
/// when very large or very small (`1e300`, not three hundred digits).
pub fn fmt_num(v: f64) -> String {
    let a = v.abs();
    if v.is_finite() && a != 0.0 && !(1e-4..1e9).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// A vector as messages print it, each component as [`fmt_num`] does.
pub fn fmt_vec(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|&x| fmt_num(x)).collect();
    format!("[{}]", parts.join(", "))
}
