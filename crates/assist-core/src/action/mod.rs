//! The paper's interaction structure `{instance_id, operation, config}` (raw, as written by
//! people, scripts, the language parser or an LLM) and its validated form [`Edit`].
//!
//! Two stages, as everywhere in assist: an [`Action`] is what was asked for and is only
//! checked for shape by serde (unknown fields are errors); [`Action::validate`] checks it
//! against a scene — the id exists, the values are finite and possible, units and frames
//! are known — and turns it into an [`Edit`] in the scene's own world units, which
//! [`crate::edit`] applies. Nothing is guessed: a missing or contradictory field is an error
//! that names the field and what was expected.
//!
//! Config fields by operation (all optional unless said):
//! - `select`: `{}`.
//! - `translate`: `axis` (`"x"`, `"-y"`, … or `[x, y, z]`) with `distance`, or `vector` /
//!   `offset` (`[dx, dy, dz]`); `unit` `m` (default), `cm`, `mm` or `units` (world units);
//!   `frame` `world` (default) or `object`.
//! - `rotate`: `axis` (default: the scene's up), `angle` with `unit` `deg` (default) or `rad`,
//!   or `degrees` / `radians`; `frame`; `center` (pivot in world units, default the box
//!   centre).
//! - `scale`: `factor` (uniform, or along `axis` only), or `factors` `[sx, sy, sz]` along the
//!   object's own axes; `center` as for rotate.
//! - `replicate`: optional `vector`/`offset` + `unit` (default: beside the original, not
//!   overlapping any object); optional `new_id`.
//! - `delete`: `{}`.
//! - `add`: `scene` (path of another `.assist` scene), `node` (id or label there), optional
//!   `position` (box centre) + `unit` (default: the node's pose in its scene, re-expressed in
//!   this scene's units). `instance_id` is the new node's id, 0 for a fresh one.
//! - `swap`: `with` (id, or id/label in `scene` when `scene` is given), optional `scene`
//!   (the other scene's node then takes this node's place and this node leaves), `new_id`.

use std::fmt;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::InstanceId;
use crate::scene::{Scene, SceneNode};

/// What an action does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Operation {
    Select,
    Translate,
    Rotate,
    Scale,
    Replicate,
    Delete,
    Add,
    Swap,
}

impl Operation {
    pub const ALL: [Operation; 8] = [
        Operation::Select,
        Operation::Translate,
        Operation::Rotate,
        Operation::Scale,
        Operation::Replicate,
        Operation::Delete,
        Operation::Add,
        Operation::Swap,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Operation::Select => "select",
            Operation::Translate => "translate",
            Operation::Rotate => "rotate",
            Operation::Scale => "scale",
            Operation::Replicate => "replicate",
            Operation::Delete => "delete",
            Operation::Add => "add",
            Operation::Swap => "swap",
        }
    }
}

impl fmt::Display for Operation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An axis: a name (`x`, `-z`, `up`, `down`) or a vector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum AxisSpec {
    Name(String),
    Vector([f64; 3]),
}

/// A node of another scene: by id or by label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum NodeRef {
    Id(InstanceId),
    Label(String),
}

impl fmt::Display for NodeRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeRef::Id(i) => write!(f, "id {i}"),
            NodeRef::Label(l) => write!(f, "{l:?}"),
        }
    }
}

/// The config of an action; which fields apply depends on the operation (module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionConfig {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<AxisSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vector: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub degrees: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radians: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub factors: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub node: Option<NodeRef>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub with: Option<NodeRef>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub new_id: Option<InstanceId>,
    /// Pivot of a rotation or scale in world units (default: the box centre).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
}

/// `{instance_id, operation, config}` — the paper's action, in exactly that JSON shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Action {
    pub instance_id: InstanceId,
    pub operation: Operation,
    #[serde(default)]
    pub config: ActionConfig,
}

/// Why an action cannot be applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ActionError {
    #[error("instance_id {id}: no such node (the scene has {available})")]
    NoSuchNode { id: InstanceId, available: String },
    #[error("{operation} config.{field}: {message}")]
    Config {
        operation: Operation,
        field: &'static str,
        message: String,
    },
    #[error("{operation} of instance {id}: {message}")]
    NotAllowed {
        operation: Operation,
        id: InstanceId,
        message: String,
    },
    #[error("add/swap config.scene {path}: {message}")]
    Source { path: String, message: String },
}

/// Where `add` and cross-scene `swap` find other scenes (the scene file reader lives in
/// assist-render; core only needs the scene's nodes and units).
pub trait SceneSource {
    /// The scene stored at `path`, or a message saying why it cannot be read.
    fn load_scene(&mut self, path: &str) -> Result<Scene, String>;
}

/// A source that has no other scenes (edits within one scene).
pub struct NoSources;

impl SceneSource for NoSources {
    fn load_scene(&mut self, path: &str) -> Result<Scene, String> {
        Err(format!(
            "cannot read other scenes here (asked for {path:?})"
        ))
    }
}

/// A node brought in from another scene: its placement in this scene and where its weights
/// come from.
#[derive(Debug, Clone, PartialEq)]
pub struct Imported {
    /// The node as it will stand in this scene (fresh id, unique field key).
    pub node: SceneNode,
    /// The other scene's path, as given.
    pub source: String,
    /// The node's field key in the other scene.
    pub source_field: String,
    /// The node's id in the other scene.
    pub source_id: InstanceId,
}

/// A validated action in this scene's world units, ready to apply.
#[derive(Debug, Clone, PartialEq)]
pub enum Edit {
    Select {
        id: InstanceId,
    },
    /// Move the node by `offset` (world units).
    Translate {
        id: InstanceId,
        offset: DVec3,
    },
    /// Rotate the node by `angle` radians around the world `axis` through `pivot` (world
    /// units; `None` = the box centre).
    Rotate {
        id: InstanceId,
        axis: DVec3,
        angle: f64,
        pivot: Option<DVec3>,
    },
    /// Multiply the node's scale along its own axes, about `pivot` (`None` = box centre).
    Scale {
        id: InstanceId,
        factors: DVec3,
        pivot: Option<DVec3>,
    },
    /// A new node `new_id` sharing `id`'s field, moved by `offset`.
    Replicate {
        id: InstanceId,
        new_id: InstanceId,
        offset: DVec3,
    },
    Delete {
        id: InstanceId,
    },
    Add {
        imported: Imported,
    },
    /// Two nodes of this scene exchange places, each resting where the other stood.
    Swap {
        a: InstanceId,
        b: InstanceId,
    },
    /// A node of another scene takes `id`'s place (resting where it stood); `id` leaves.
    SwapIn {
        id: InstanceId,
        imported: Imported,
    },
}

impl Edit {
    /// The node the edit acts on (for `add`, the new node).
    pub fn instance_id(&self) -> InstanceId {
        match self {
            Edit::Select { id }
            | Edit::Translate { id, .. }
            | Edit::Rotate { id, .. }
            | Edit::Scale { id, .. }
            | Edit::Replicate { id, .. }
            | Edit::Delete { id }
            | Edit::SwapIn { id, .. } => *id,
            Edit::Swap { a, .. } => *a,
            Edit::Add { imported } => imported.node.id,
        }
    }
    /// The edit written back as an explicit action (metres, degrees, ids resolved, new ids
    /// and default offsets filled in); validating it again gives the same edit.
    pub fn to_action(&self, meters_per_unit: f64) -> Action {
        // (`+ 0.0` turns −0 into 0 so printed configs read cleanly.)
        let m = |v: DVec3| (v * meters_per_unit).to_array().map(|x| x + 0.0);
        let metres = Some("m".to_string());
        let (id, op, config) = match self {
            Edit::Select { id } => (*id, Operation::Select, ActionConfig::default()),
            Edit::Delete { id } => (*id, Operation::Delete, ActionConfig::default()),
            Edit::Translate { id, offset } => (
                *id,
                Operation::Translate,
                ActionConfig {
                    vector: Some(m(*offset)),
                    unit: metres,
                    ..Default::default()
                },
            ),
            Edit::Rotate {
                id,
                axis,
                angle,
                pivot,
            } => (
                *id,
                Operation::Rotate,
                ActionConfig {
                    axis: Some(axis_spec(*axis)),
                    angle: Some(angle.to_degrees()),
                    unit: Some("deg".into()),
                    center: pivot.map(|p| p.to_array()),
                    ..Default::default()
                },
            ),
            Edit::Scale { id, factors, pivot } => {
                let mut config = if factors.x == factors.y && factors.y == factors.z {
                    ActionConfig {
                        factor: Some(factors.x),
                        ..Default::default()
                    }
                } else {
                    ActionConfig {
                        factors: Some(factors.to_array()),
                        ..Default::default()
                    }
                };
                config.center = pivot.map(|p| p.to_array());
                (*id, Operation::Scale, config)
            }
            Edit::Replicate { id, new_id, offset } => (
                *id,
                Operation::Replicate,
                ActionConfig {
                    vector: Some(m(*offset)),
                    unit: metres,
                    new_id: Some(*new_id),
                    ..Default::default()
                },
            ),
            Edit::Add { imported } => (
                imported.node.id,
                Operation::Add,
                ActionConfig {
                    scene: Some(imported.source.clone()),
                    node: Some(NodeRef::Id(imported.source_id)),
                    position: Some(m(imported.node.world_from_local.translation)),
                    unit: metres,
                    ..Default::default()
                },
            ),
            Edit::Swap { a, b } => (
                *a,
                Operation::Swap,
                ActionConfig {
                    with: Some(NodeRef::Id(*b)),
                    ..Default::default()
                },
            ),
            Edit::SwapIn { id, imported } => (
                *id,
                Operation::Swap,
                ActionConfig {
                    scene: Some(imported.source.clone()),
                    with: Some(NodeRef::Id(imported.source_id)),
                    new_id: Some(imported.node.id),
                    ..Default::default()
                },
            ),
        };
        Action::new(id, op, config)
    }

    /// A node this edit creates, if any.
    pub fn created(&self) -> Option<InstanceId> {
        match self {
            Edit::Replicate { new_id, .. } => Some(*new_id),
            Edit::Add { imported } | Edit::SwapIn { imported, .. } => Some(imported.node.id),
            _ => None,
        }
    }
}

/// `"x"`, `"-z"`, … for a signed coordinate axis, else the vector.
fn axis_spec(v: DVec3) -> AxisSpec {
    for (name, a) in [("x", DVec3::X), ("y", DVec3::Y), ("z", DVec3::Z)] {
        if v.dot(a) > 1.0 - 1e-12 {
            return AxisSpec::Name(name.into());
        }
        if v.dot(a) < -1.0 + 1e-12 {
            return AxisSpec::Name(format!("-{name}"));
        }
    }
    AxisSpec::Vector(v.to_array())
}

mod import;
mod validate;
pub use import::free_field_key;
pub use validate::{axis_direction, describe_nodes};
