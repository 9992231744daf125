//! What the instruction tests share: nodes as 10 cm cubes at a point.

use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode, SceneSource};

/// A node of a 10 cm cube at `at`, its field keyed `f{id}`.
pub fn node(id: u16, label: &str, at: [f64; 3]) -> SceneNode {
    SceneNode::from_obb(
        id,
        label,
        &format!("f{id}"),
        &Obb::new(DVec3::from_array(at), DVec3::splat(0.05), DMat3::IDENTITY),
    )
}

/// A source of other scenes that has none (not every test file uses it).
#[allow(dead_code)]
pub struct NoScenes;

impl SceneSource for NoScenes {
    fn load_scene(&mut self, path: &str) -> Result<Scene, String> {
        Err(format!("{path}: no such scene"))
    }
}
