//! Scene nodes and scenes: the data of the paper's *scene node* (id, label, embedding,
//! forward model, box) without the forward model's weights, which live in assist-field.
//!
//! A node names its field by a key (`field`), and a scene file stores one weights file per
//! key; replicas are nodes with the same key, so duplicating a node copies no weights.
//! A node's canonical space is its box, centred at the origin and axis-aligned, with
//! half extents `half_size`; `world_from_local` places it in the world (rotation,
//! translation and per-axis scale).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::InstanceId;
use crate::geometry::{Aabb, Obb};
use crate::similarity::Similarity3;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneNode {
    /// Instance id, 0 = background; stable across edits.
    pub id: InstanceId,
    pub label: String,
    /// Semantic class (what kind of thing it is), when it differs from the label: a
    /// replica "mug 2" is of class "mug". See [`Scene::classes`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub class: Option<String>,
    /// Vision-language feature for language queries, when computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub embedding: Option<Vec<f32>>,
    /// Key of the node's field (weights file `fields/<key>.safetensors`); shared by replicas.
    pub field: String,
    /// Half extents of the canonical box.
    pub half_size: DVec3,
    pub world_from_local: Similarity3,
    /// How the field's space relates to the box: the box itself (objects, bounded
    /// rooms), or the box kept linearly and everything beyond it contracted towards a
    /// finite shell (unbounded backgrounds of real captures).
    #[serde(default, skip_serializing_if = "NodeSpace::is_box")]
    pub space: NodeSpace,
    /// How the object's shadow was photographed, when the scene's [`KeyLight`] is known:
    /// moved, its shadow is re-cast under that light (see [`ShadowCast`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cast: Option<ShadowCast>,
}

/// Where an object stood when its shadow grid was learned, and how much of the light
/// falling around it comes from the scene's [`KeyLight`] (per colour channel, `[0, 1]`).
/// Placed elsewhere, its shadow is the learned one plus `strength` times the change in
/// the key light's visibility between the two poses: the part of the shadow the key
/// light casts turns and stretches with the light's direction, and the rest (contact
/// shadow, colour bleeding) stays as learned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShadowCast {
    pub pose: Similarity3,
    pub strength: [f32; 3],
}

/// The light that casts the objects' shadows, as estimated from them: a disc of `radius`
/// facing the scene's up, centred at `position` (world units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KeyLight {
    pub position: DVec3,
    pub radius: f64,
}

/// The space a node's field covers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NodeSpace {
    /// The canonical box; nothing outside it.
    #[default]
    Box,
    /// The box mapped linearly, all space beyond it contracted into a shell around it
    /// (mip-NeRF 360's contraction with the L∞ norm): walls and far scenery have a place.
    Contracted,
}

impl NodeSpace {
    pub fn is_box(&self) -> bool {
        *self == NodeSpace::Box
    }
}

impl SceneNode {
    pub fn is_background(&self) -> bool {
        self.id == 0
    }
    /// The node's semantic class: its `class`, else its label.
    pub fn class_name(&self) -> &str {
        self.class.as_deref().unwrap_or(&self.label)
    }
    /// The canonical box as an axis-aligned box in local space.
    pub fn local_aabb(&self) -> Aabb {
        Aabb::from_half_size(self.half_size)
    }
    /// A node whose canonical box is the world box `obb`.
    pub fn from_obb(id: InstanceId, label: &str, field: &str, obb: &Obb) -> Self {
        SceneNode {
            id,
            label: label.to_string(),
            embedding: None,
            class: None,
            field: field.to_string(),
            half_size: obb.half_size,
            world_from_local: obb.world_from_box(),
            space: NodeSpace::Box,
            cast: None,
        }
    }
    /// Where the box's corners are in the world (after scale, rotation, translation).
    pub fn world_corners(&self) -> [DVec3; 8] {
        self.local_aabb()
            .corners()
            .map(|c| self.world_from_local.transform_point(c))
    }
}

/// Largest coordinate a node may be placed at (world units): far beyond any capture, and
/// far below where f64 arithmetic on poses breaks down.
pub const MAX_COORDINATE: f64 = 1e9;

/// The most nodes a scene may hold (the background included): replicating or adding
/// past it is refused, and a scene file with more does not load.
pub const MAX_NODES: usize = 1000;

/// Longest node label, in characters.
pub const MAX_LABEL_CHARS: usize = 200;
/// Scale factors a node may have (relative to its trained size).
pub const SCALE_RANGE: (f64, f64) = (1e-6, 1e6);

impl SceneNode {
    /// Why this node's box and pose cannot be saved and loaded again, if they cannot:
    /// every value finite, the box positive, the rotation a unit quaternion, the scale in
    /// [`SCALE_RANGE`] and the position within [`MAX_COORDINATE`] — the same of its
    /// [`ShadowCast`]'s pose, whose strengths lie in `[0, 1]`. Returns the field and the
    /// message.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let n = self.label.chars().count();
        if self.label.trim().is_empty() || n > MAX_LABEL_CHARS {
            return Err((
                "label",
                format!("expected 1 to {MAX_LABEL_CHARS} characters, got {n}"),
            ));
        }
        if self.label.chars().any(char::is_control) {
            return Err(("label", "control characters are not allowed".into()));
        }
        let hs = self.half_size.to_array();
        if !hs
            .iter()
            .all(|v| v.is_finite() && *v > 0.0 && *v <= MAX_COORDINATE)
        {
            return Err((
                "half_size",
                format!("expected 3 positive numbers up to {MAX_COORDINATE:e}, got {hs:?}"),
            ));
        }
        check_pose(
            &self.world_from_local,
            [
                "world_from_local",
                "world_from_local.scale",
                "world_from_local.translation",
                "world_from_local.rotation",
            ],
        )?;
        if let Some(c) = &self.cast {
            check_pose(
                &c.pose,
                [
                    "cast.pose",
                    "cast.pose.scale",
                    "cast.pose.translation",
                    "cast.pose.rotation",
                ],
            )?;
            if !c.strength.iter().all(|k| (0.0..=1.0).contains(k)) {
                return Err((
                    "cast.strength",
                    format!("expected 3 numbers from 0 to 1, got {:?}", c.strength),
                ));
            }
        }
        Ok(())
    }
}

/// Why pose `p` cannot be saved and loaded again, if it cannot: the field at fault (of
/// `fields`: the whole pose, its scale, translation, rotation) and the message.
fn check_pose(p: &Similarity3, fields: [&'static str; 4]) -> Result<(), (&'static str, String)> {
    let vals: Vec<f64> = p
        .rotation
        .to_array()
        .into_iter()
        .chain(p.translation.to_array())
        .chain(p.scale.to_array())
        .collect();
    if !vals.iter().all(|v| v.is_finite()) {
        return Err((fields[0], "expected finite numbers".into()));
    }
    let (lo, hi) = SCALE_RANGE;
    if p.scale.min_element() < lo || p.scale.max_element() > hi {
        return Err((
            fields[1],
            format!(
                "expected every factor from {lo:e} to {hi:e}, got {}",
                crate::fmt_vec(&p.scale.to_array())
            ),
        ));
    }
    if p.translation.abs().max_element() > MAX_COORDINATE {
        return Err((
            fields[2],
            format!(
                "expected coordinates within ±{MAX_COORDINATE:e}, got {}",
                crate::fmt_vec(&p.translation.to_array())
            ),
        ));
    }
    if (p.rotation.length() - 1.0).abs() > 1e-3 {
        return Err((fields[3], "expected a unit quaternion".into()));
    }
    Ok(())
}

/// What a ray shows past its last sample, where the nodes leave it transparent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backdrop {
    /// The scene's `background_color` (an object on a known background; scenes saved
    /// before backdrops existed).
    #[default]
    Color,
    /// The colour of the ray's last sample (nerfacto's `last_sample`), for captures whose
    /// background is unknown: a ray the field has not yet made opaque is not darkened
    /// towards a made-up colour, which would only be answered by raising every colour
    /// until the colour net saturates.
    LastSample,
}

impl Backdrop {
    pub fn is_color(&self) -> bool {
        *self == Backdrop::Color
    }
}

/// A scene: nodes plus what is needed to interpret edits and render.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    pub nodes: Vec<SceneNode>,
    /// World up direction.
    pub up: DVec3,
    /// Metres per world unit (for edits given in m/cm/mm).
    pub meters_per_unit: f64,
    /// Colour behind everything (what a ray that hits nothing shows, with
    /// [`Backdrop::Color`]).
    pub background_color: [f32; 3],
    /// What a ray shows past its last sample.
    #[serde(default, skip_serializing_if = "Backdrop::is_color")]
    pub backdrop: Backdrop,
    /// The selected (highlighted) node, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selected: Option<InstanceId>,
    /// Near plane: what lies closer to a camera than this (world units) is not rendered.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub near: f64,
    /// Semantic classes in the order they were first seen: class id `k + 1` is
    /// `classes[k]` (0 = background). A class stays when its last node is deleted, so ids
    /// are stable across edits and renders; see [`Scene::register_classes`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub classes: Vec<String>,
    /// The light that casts the objects' shadows, when estimated (see [`ShadowCast`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<KeyLight>,
    /// Whether an object moved or turned from where it was photographed is shaded by
    /// [`Scene::light`] where it stands now, rather than keeping the shading it was
    /// photographed with (assist-render's `relight`). Needs the light and the objects'
    /// [`ShadowCast`]s.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub relight: bool,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Scene {
    /// A scene of `nodes` with `up` as its up, one metre per unit and everything else at
    /// its default (black background colour, no selection, no near plane, no classes).
    pub fn with_nodes(nodes: Vec<SceneNode>, up: DVec3) -> Scene {
        Scene {
            nodes,
            up,
            meters_per_unit: 1.0,
            background_color: [0.0; 3],
            backdrop: Backdrop::default(),
            selected: None,
            near: 0.0,
            classes: Vec::new(),
            light: None,
            relight: false,
        }
    }
    /// The classes of objects not yet in `classes`, in id order of first appearance.
    fn unlisted_classes(&self) -> Vec<String> {
        let mut objects: Vec<&SceneNode> =
            self.nodes.iter().filter(|n| !n.is_background()).collect();
        objects.sort_by_key(|n| n.id);
        let mut out: Vec<String> = Vec::new();
        for n in objects {
            let c = n.class_name();
            if !self.classes.iter().any(|k| k == c) && !out.iter().any(|k| k == c) {
                out.push(c.to_string());
            }
        }
        out
    }
    /// Appends the classes of the objects not yet listed (in id order).
    pub fn register_classes(&mut self) {
        let new = self.unlisted_classes();
        self.classes.extend(new);
    }
    /// Every class name with the background first: index = class id (the listed classes,
    /// then any not yet registered).
    pub fn class_names(&self) -> Vec<String> {
        let mut names = vec!["background".to_string()];
        names.extend(self.classes.iter().cloned());
        names.extend(self.unlisted_classes());
        names
    }
    /// A label for a new copy of a node of class `class`: "mug 2", "mug 3", … (the first
    /// number no node's label uses).
    pub fn replica_label(&self, class: &str) -> String {
        // One pass over the labels (numbers already taken), not one per number tried:
        // a thousand copies stay cheap.
        let prefix = format!("{class} ");
        let taken: std::collections::BTreeSet<usize> = self
            .nodes
            .iter()
            .filter_map(|n| n.label.strip_prefix(&prefix)?.parse().ok())
            .collect();
        let k = (2..).find(|k| !taken.contains(k)).expect("a free number");
        format!("{class} {k}")
    }
    pub fn node(&self, id: InstanceId) -> Option<&SceneNode> {
        self.nodes.iter().find(|n| n.id == id)
    }
    /// The object nodes (every node but the background), in order.
    pub fn objects(&self) -> impl Iterator<Item = &SceneNode> {
        self.nodes.iter().filter(|n| !n.is_background())
    }
    pub fn node_mut(&mut self, id: InstanceId) -> Option<&mut SceneNode> {
        self.nodes.iter_mut().find(|n| n.id == id)
    }
    /// The smallest id not used by any node (never 0).
    pub fn fresh_id(&self) -> InstanceId {
        self.nodes
            .iter()
            .map(|n| n.id)
            .max()
            .unwrap_or(0)
            .saturating_add(1)
            .max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;

    #[test]
    fn node_from_obb_round_trips_corners() {
        let obb = Obb::new(
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::new(0.2, 0.4, 0.6),
            DMat3::from_rotation_z(0.7),
        );
        let n = SceneNode::from_obb(3, "mug", "mug", &obb);
        let a = n.world_corners();
        let b = obb.corners();
        for (p, q) in a.iter().zip(&b) {
            assert!((*p - *q).length() < 1e-12);
        }
    }

    #[test]
    fn fresh_ids_are_new_and_nonzero() {
        let s = Scene {
            nodes: vec![],
            up: DVec3::Z,
            meters_per_unit: 1.0,
            background_color: [0.0; 3],
            backdrop: Backdrop::Color,
            selected: None,
            near: 0.0,
            classes: Vec::new(),
            light: None,
            relight: false,
        };
        assert_eq!(s.fresh_id(), 1);
    }
}
