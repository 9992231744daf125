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

use std::collections::BTreeSet;
use std::fmt;

use glam::{DQuat, DVec3};
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
        let m = |v: DVec3| {
            (v * meters_per_unit + DVec3::ZERO)
                .to_array()
                .map(|x| x + 0.0)
        };
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

/// Metres → world units factor for a length unit name.
fn length_unit(
    op: Operation,
    unit: Option<&str>,
    meters_per_unit: f64,
) -> Result<f64, ActionError> {
    let m = match unit.unwrap_or("m") {
        "m" | "meter" | "meters" | "metre" | "metres" => 1.0,
        "cm" | "centimeter" | "centimeters" | "centimetre" | "centimetres" => 0.01,
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => 0.001,
        "units" | "unit" => return Ok(1.0),
        other => {
            return Err(ActionError::Config {
                operation: op,
                field: "unit",
                message: format!("expected m, cm, mm or units, got {other:?}"),
            });
        }
    };
    Ok(m / meters_per_unit)
}

fn cfg_err(op: Operation, field: &'static str, message: impl Into<String>) -> ActionError {
    ActionError::Config {
        operation: op,
        field,
        message: message.into(),
    }
}

fn finite(op: Operation, field: &'static str, v: f64) -> Result<f64, ActionError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(cfg_err(
            op,
            field,
            format!("expected a finite number, got {v}"),
        ))
    }
}

fn finite3(op: Operation, field: &'static str, v: [f64; 3]) -> Result<DVec3, ActionError> {
    for x in v {
        finite(op, field, x)?;
    }
    Ok(DVec3::from_array(v))
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

/// A unit direction from an axis spec (`up`/`down` use the scene's up).
pub fn axis_direction(spec: &AxisSpec, up: DVec3) -> Result<DVec3, String> {
    let v = match spec {
        AxisSpec::Vector(v) => DVec3::from_array(*v),
        AxisSpec::Name(n) => {
            let n = n.trim().to_ascii_lowercase();
            let (neg, name) = match n.strip_prefix('-') {
                Some(r) => (true, r.to_string()),
                None => (false, n.strip_prefix('+').unwrap_or(&n).to_string()),
            };
            let v = match name.as_str() {
                "x" => DVec3::X,
                "y" => DVec3::Y,
                "z" => DVec3::Z,
                "up" => up,
                "down" => -up,
                _ => {
                    return Err(format!(
                        "expected x, y, z (optionally signed), up, down or [x, y, z], got {n:?}"
                    ));
                }
            };
            if neg { -v } else { v }
        }
    };
    if !v.is_finite() || v.length() < 1e-12 {
        return Err(format!("expected a finite non-zero direction, got {v:?}"));
    }
    Ok(v.normalize())
}

impl Action {
    pub fn new(instance_id: InstanceId, operation: Operation, config: ActionConfig) -> Self {
        Action {
            instance_id,
            operation,
            config,
        }
    }

    /// Checks the action against `scene` and expresses it in the scene's world units.
    /// `taken_fields` lists field keys that must not be reused by imported nodes (e.g. keys
    /// still referenced by undo history), besides those of the scene's nodes.
    pub fn validate(
        &self,
        scene: &Scene,
        sources: &mut dyn SceneSource,
        taken_fields: &BTreeSet<String>,
    ) -> Result<Edit, ActionError> {
        let op = self.operation;
        let c = &self.config;
        let id = self.instance_id;
        self.check_fields()?;
        if op == Operation::Add {
            // The new node's id: `instance_id` when not 0, else a fresh one.
            let new_id = fresh_or_given(op, scene, (id != 0).then_some(id))?;
            let mut imported = import(op, scene, sources, taken_fields, c, new_id)?;
            if let Some(p) = c.position {
                let p = finite3(op, "position", p)?
                    * length_unit(op, c.unit.as_deref(), scene.meters_per_unit)?;
                imported.node.world_from_local.translation = p;
            }
            return Ok(Edit::Add { imported });
        }
        let node = scene.node(id).ok_or_else(|| ActionError::NoSuchNode {
            id,
            available: describe_nodes(scene),
        })?;
        let not_allowed = |message: &str| ActionError::NotAllowed {
            operation: op,
            id,
            message: message.to_string(),
        };
        if node.is_background()
            && matches!(
                op,
                Operation::Delete | Operation::Replicate | Operation::Swap | Operation::Scale
            )
        {
            return Err(not_allowed(
                "the background node cannot be deleted, replicated, swapped or scaled",
            ));
        }
        let frame_object = match c.frame.as_deref() {
            None | Some("world") => false,
            Some("object" | "local") => true,
            Some(f) => {
                return Err(cfg_err(
                    op,
                    "frame",
                    format!("expected world or object, got {f:?}"),
                ));
            }
        };
        let to_world_dir = |v: DVec3| {
            if frame_object {
                (node.world_from_local.rotation * v).normalize()
            } else {
                v
            }
        };
        Ok(match op {
            Operation::Select => Edit::Select { id },
            Operation::Delete => Edit::Delete { id },
            Operation::Translate => {
                let unit = length_unit(op, c.unit.as_deref(), scene.meters_per_unit)?;
                let v = match (&c.axis, c.distance, c.vector.or(c.offset)) {
                    (Some(axis), Some(d), None) => {
                        let dir =
                            axis_direction(axis, scene.up).map_err(|m| cfg_err(op, "axis", m))?;
                        to_world_dir(dir) * finite(op, "distance", d)?
                    }
                    (None, None, Some(v)) => {
                        let v = finite3(op, "vector", v)?;
                        if frame_object {
                            node.world_from_local.rotation * v
                        } else {
                            v
                        }
                    }
                    (Some(_), None, None) => {
                        return Err(cfg_err(
                            op,
                            "distance",
                            "expected a distance along the axis",
                        ));
                    }
                    (None, Some(_), None) => {
                        return Err(cfg_err(op, "axis", "expected an axis for the distance"));
                    }
                    (None, None, None) => {
                        return Err(cfg_err(
                            op,
                            "vector",
                            "expected axis + distance, or vector/offset",
                        ));
                    }
                    _ => {
                        return Err(cfg_err(
                            op,
                            "vector",
                            "give either axis + distance or vector/offset, not both",
                        ));
                    }
                };
                Edit::Translate {
                    id,
                    offset: v * unit,
                }
            }
            Operation::Rotate => {
                let angle = match (c.angle, c.degrees, c.radians) {
                    (Some(a), None, None) => {
                        let a = finite(op, "angle", a)?;
                        match c.unit.as_deref().unwrap_or("deg") {
                            "deg" | "degree" | "degrees" => a.to_radians(),
                            "rad" | "radian" | "radians" => a,
                            u => {
                                return Err(cfg_err(
                                    op,
                                    "unit",
                                    format!("expected deg or rad, got {u:?}"),
                                ));
                            }
                        }
                    }
                    (None, Some(d), None) => finite(op, "degrees", d)?.to_radians(),
                    (None, None, Some(r)) => finite(op, "radians", r)?,
                    (None, None, None) => {
                        return Err(cfg_err(
                            op,
                            "angle",
                            "expected angle (with unit), degrees or radians",
                        ));
                    }
                    _ => {
                        return Err(cfg_err(
                            op,
                            "angle",
                            "give only one of angle, degrees, radians",
                        ));
                    }
                };
                let axis = match &c.axis {
                    Some(a) => to_world_dir(
                        axis_direction(a, scene.up).map_err(|m| cfg_err(op, "axis", m))?,
                    ),
                    None => scene.up.normalize(),
                };
                let pivot = c.center.map(|p| finite3(op, "center", p)).transpose()?;
                Edit::Rotate {
                    id,
                    axis,
                    angle,
                    pivot,
                }
            }
            Operation::Scale => {
                let factors = match (c.factor, c.factors) {
                    (Some(f), None) => {
                        let f = finite(op, "factor", f)?;
                        check_factor(op, "factor", f)?;
                        match &c.axis {
                            None => DVec3::splat(f),
                            Some(axis) => {
                                let dir = axis_direction(axis, scene.up)
                                    .map_err(|m| cfg_err(op, "axis", m))?;
                                let local = if frame_object {
                                    dir
                                } else {
                                    node.world_from_local.rotation.inverse() * dir
                                };
                                let k = local.abs().max_position();
                                if local.abs()[k] < 0.9 {
                                    return Err(cfg_err(
                                        op,
                                        "axis",
                                        format!(
                                            "{axis:?} is not close to any of the object's own axes (a per-axis scale along it would shear); give frame \"object\" with x, y or z"
                                        ),
                                    ));
                                }
                                let mut f3 = DVec3::ONE;
                                f3[k] = f;
                                f3
                            }
                        }
                    }
                    (None, Some(fs)) => {
                        let v = finite3(op, "factors", fs)?;
                        for f in fs {
                            check_factor(op, "factors", f)?;
                        }
                        v
                    }
                    (None, None) => {
                        return Err(cfg_err(op, "factor", "expected factor or factors"));
                    }
                    _ => return Err(cfg_err(op, "factor", "give factor or factors, not both")),
                };
                let pivot = c.center.map(|p| finite3(op, "center", p)).transpose()?;
                Edit::Scale { id, factors, pivot }
            }
            Operation::Replicate => {
                let new_id = fresh_or_given(op, scene, c.new_id)?;
                let offset = match c.vector.or(c.offset) {
                    Some(v) => {
                        finite3(op, "vector", v)?
                            * length_unit(op, c.unit.as_deref(), scene.meters_per_unit)?
                    }
                    None => crate::edit::free_offset(scene, node),
                };
                Edit::Replicate { id, new_id, offset }
            }
            Operation::Add => unreachable!("handled above"),
            Operation::Swap => {
                let with = c
                    .with
                    .as_ref()
                    .ok_or_else(|| cfg_err(op, "with", "expected the node to swap with"))?;
                if c.scene.is_some() {
                    let new_id = fresh_or_given(op, scene, c.new_id)?;
                    let mut imported = import(op, scene, sources, taken_fields, c, new_id)?;
                    crate::edit::rest_in_place_of(&mut imported.node, node, scene.up);
                    Edit::SwapIn { id, imported }
                } else {
                    let b = match with {
                        NodeRef::Id(b) => *b,
                        NodeRef::Label(l) => {
                            return Err(cfg_err(
                                op,
                                "with",
                                format!(
                                    "expected an instance id of this scene (labels are resolved by the language parser), got {l:?}"
                                ),
                            ));
                        }
                    };
                    let other = scene.node(b).ok_or_else(|| ActionError::NoSuchNode {
                        id: b,
                        available: describe_nodes(scene),
                    })?;
                    if other.is_background() || b == id {
                        return Err(not_allowed("swap needs two different object nodes"));
                    }
                    Edit::Swap { a: id, b }
                }
            }
        })
    }

    /// Fields that do not belong to the operation are errors, not silently ignored.
    fn check_fields(&self) -> Result<(), ActionError> {
        let c = &self.config;
        let present = [
            ("center", c.center.is_some()),
            ("axis", c.axis.is_some()),
            ("frame", c.frame.is_some()),
            ("distance", c.distance.is_some()),
            ("vector", c.vector.is_some()),
            ("offset", c.offset.is_some()),
            ("unit", c.unit.is_some()),
            ("angle", c.angle.is_some()),
            ("degrees", c.degrees.is_some()),
            ("radians", c.radians.is_some()),
            ("factor", c.factor.is_some()),
            ("factors", c.factors.is_some()),
            ("scene", c.scene.is_some()),
            ("node", c.node.is_some()),
            ("position", c.position.is_some()),
            ("with", c.with.is_some()),
            ("new_id", c.new_id.is_some()),
        ];
        let allowed: &[&str] = match self.operation {
            Operation::Select | Operation::Delete => &[],
            Operation::Translate => &["axis", "frame", "distance", "vector", "offset", "unit"],
            Operation::Rotate => &[
                "axis", "frame", "angle", "degrees", "radians", "unit", "center",
            ],
            Operation::Scale => &["axis", "frame", "factor", "factors", "center"],
            Operation::Replicate => &["vector", "offset", "unit", "new_id"],
            Operation::Add => &["scene", "node", "position", "unit"],
            Operation::Swap => &["with", "scene", "new_id"],
        };
        for (name, is) in present {
            if is && !allowed.contains(&name) {
                return Err(cfg_err(
                    self.operation,
                    name,
                    format!(
                        "not a field of {} (expected {})",
                        self.operation,
                        if allowed.is_empty() {
                            "an empty config".to_string()
                        } else {
                            allowed.join(", ")
                        }
                    ),
                ));
            }
        }
        Ok(())
    }
}

fn check_factor(op: Operation, field: &'static str, f: f64) -> Result<(), ActionError> {
    if f <= 0.0 {
        return Err(cfg_err(
            op,
            field,
            format!("expected a scale factor > 0, got {f}"),
        ));
    }
    if !(1e-3..=1e3).contains(&f) {
        return Err(cfg_err(
            op,
            field,
            format!("expected a scale factor between 0.001 and 1000, got {f}"),
        ));
    }
    Ok(())
}

fn fresh_or_given(
    op: Operation,
    scene: &Scene,
    given: Option<InstanceId>,
) -> Result<InstanceId, ActionError> {
    match given {
        None => Ok(scene.fresh_id()),
        Some(0) => Err(cfg_err(op, "new_id", "0 is the background's id")),
        Some(n) if scene.node(n).is_some() => {
            Err(cfg_err(op, "new_id", format!("id {n} is already used")))
        }
        Some(n) => Ok(n),
    }
}

/// One line per node: `id "label"`.
pub fn describe_nodes(scene: &Scene) -> String {
    let v: Vec<String> = scene
        .nodes
        .iter()
        .map(|n| format!("{} {:?}", n.id, n.label))
        .collect();
    if v.is_empty() {
        "no nodes".into()
    } else {
        v.join(", ")
    }
}

/// Reads the node named by `config.node` (add) or `config.with` (swap) from `config.scene`,
/// re-expressed in `scene`'s units and up direction, with a fresh id and a free field key.
fn import(
    op: Operation,
    scene: &Scene,
    sources: &mut dyn SceneSource,
    taken_fields: &BTreeSet<String>,
    c: &ActionConfig,
    new_id: InstanceId,
) -> Result<Imported, ActionError> {
    let path = c
        .scene
        .as_deref()
        .ok_or_else(|| cfg_err(op, "scene", "expected the path of the other scene"))?;
    let (field, which) = if op == Operation::Add {
        ("node", c.node.as_ref())
    } else {
        ("with", c.with.as_ref())
    };
    let which = which
        .ok_or_else(|| cfg_err(op, field, "expected a node id or label of the other scene"))?;
    let src = sources
        .load_scene(path)
        .map_err(|message| ActionError::Source {
            path: path.to_string(),
            message,
        })?;
    let candidates: Vec<&SceneNode> = match which {
        NodeRef::Id(i) => src.nodes.iter().filter(|n| n.id == *i).collect(),
        NodeRef::Label(l) => {
            let l = l.trim().to_lowercase();
            let exact: Vec<_> = src
                .nodes
                .iter()
                .filter(|n| n.label.to_lowercase() == l)
                .collect();
            if exact.is_empty() {
                src.nodes
                    .iter()
                    .filter(|n| n.label.to_lowercase().contains(&l))
                    .collect()
            } else {
                exact
            }
        }
    };
    let n = match candidates.as_slice() {
        [n] => *n,
        [] => {
            return Err(ActionError::Source {
                path: path.into(),
                message: format!("no node {which} (it has {})", describe_nodes(&src)),
            });
        }
        many => {
            return Err(ActionError::Source {
                path: path.into(),
                message: format!(
                    "{which} is ambiguous: {}",
                    many.iter()
                        .map(|n| format!("{} {:?}", n.id, n.label))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
    };
    if n.is_background() {
        return Err(cfg_err(
            op,
            field,
            "the other scene's background cannot be imported",
        ));
    }
    let s = src.meters_per_unit / scene.meters_per_unit;
    if !(s.is_finite() && s > 0.0) {
        return Err(ActionError::Source {
            path: path.into(),
            message: format!(
                "meters_per_unit {} cannot be converted",
                src.meters_per_unit
            ),
        });
    }
    let q = DQuat::from_rotation_arc(src.up.normalize(), scene.up.normalize());
    let p = n.world_from_local;
    let mut node = n.clone();
    node.id = new_id;
    node.world_from_local = crate::Similarity3 {
        rotation: (q * p.rotation).normalize(),
        translation: q * (p.translation * s),
        scale: p.scale * s,
    };
    node.field = free_field_key(&n.field, scene, taken_fields);
    Ok(Imported {
        node,
        source: path.to_string(),
        source_field: n.field.clone(),
        source_id: n.id,
    })
}

/// `key`, or `key-2`, `key-3`, … — the first not used by `scene` nor in `taken`.
pub fn free_field_key(key: &str, scene: &Scene, taken: &BTreeSet<String>) -> String {
    let used = |k: &str| taken.contains(k) || scene.nodes.iter().any(|n| n.field == k);
    if !used(key) {
        return key.to_string();
    }
    (2..)
        .map(|i| format!("{key}-{i}"))
        .find(|k| !used(k))
        .expect("unbounded")
}
