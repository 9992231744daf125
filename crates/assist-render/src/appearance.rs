//! Which appearance code a render's samples take: a training view's own, or for a view
//! from elsewhere the blend of the codes of the training views taken nearest to it
//! ([`assist_field::Field::novel_code`]).

use assist_core::Camera;
use assist_scene::NeuralScene;

use crate::RenderOptions;

/// The appearance code of node `node`'s samples seen from `eye` (world) without an
/// image's own: the blend of its field's nearest training views (`None`: the average).
pub(crate) fn novel_code(
    scene: &NeuralScene,
    node: usize,
    eye: Option<[f64; 3]>,
) -> Option<Vec<f32>> {
    let eye = assist_core::DVec3::from_array(eye?);
    let at = scene.scene.nodes[node]
        .world_from_local
        .local_from_world_point(eye);
    scene.field_of(node).field.novel_code(at.to_array())
}

/// `opts` for a render of `camera` with appearance code `image`: a novel view's
/// ([`u32::MAX`]) takes its codes from where the camera stands unless `opts` says where.
pub(crate) fn seen_from<'a>(
    opts: &'a RenderOptions,
    camera: &Camera,
    image: u32,
) -> std::borrow::Cow<'a, RenderOptions> {
    if image != u32::MAX || opts.eye.is_some() {
        return std::borrow::Cow::Borrowed(opts);
    }
    std::borrow::Cow::Owned(RenderOptions {
        eye: Some(camera.pose.center().to_array()),
        ..opts.clone()
    })
}
