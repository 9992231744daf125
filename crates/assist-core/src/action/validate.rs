//! Stage two of actions: checking an `Action` against a scene and expressing it as an
//! `Edit` in the scene's world units.

use std::collections::BTreeSet;

use glam::DVec3;

use super::import::import;

use super::{Action, ActionConfig, ActionError, AxisSpec, Edit, NodeRef, Operation, SceneSource};
use crate::InstanceId;
use crate::scene::{Scene, SceneNode};

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

pub(super) fn cfg_err(
    op: Operation,
    field: &'static str,
    message: impl Into<String>,
) -> ActionError {
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
            format!("expected a finite number, got {}", crate::fmt_num(v)),
        ))
    }
}

fn finite3(op: Operation, field: &'static str, v: [f64; 3]) -> Result<DVec3, ActionError> {
    for x in v {
        finite(op, field, x)?;
    }
    Ok(DVec3::from_array(v))
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
        if matches!(op, Operation::Add | Operation::Replicate)
            && scene.nodes.len() >= crate::scene::MAX_NODES
        {
            return Err(not_allowed(
                op,
                id,
                &format!(
                    "the scene has {} nodes, the most a scene may hold",
                    scene.nodes.len()
                ),
            ));
        }
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
        if node.is_background()
            && matches!(
                op,
                Operation::Delete | Operation::Replicate | Operation::Swap | Operation::Scale
            )
        {
            return Err(not_allowed(
                op,
                id,
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
        let on = OnNode {
            op,
            c,
            scene,
            node,
            frame_object,
        };
        Ok(match op {
            Operation::Select => Edit::Select { id },
            Operation::Delete => Edit::Delete { id },
            Operation::Translate => Edit::Translate {
                id,
                offset: on.translation()?,
            },
            Operation::Rotate => {
                let (axis, angle) = on.rotation()?;
                let pivot = c.center.map(|p| finite3(op, "center", p)).transpose()?;
                Edit::Rotate {
                    id,
                    axis,
                    angle,
                    pivot,
                }
            }
            Operation::Scale => {
                let factors = on.scale_factors()?;
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
            Operation::Swap => on.swap(sources, taken_fields)?,
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

fn not_allowed(operation: Operation, id: InstanceId, message: &str) -> ActionError {
    ActionError::NotAllowed {
        operation,
        id,
        message: message.to_string(),
    }
}

/// An operation on an existing node, with what its parts need to be checked.
struct OnNode<'a> {
    op: Operation,
    c: &'a ActionConfig,
    scene: &'a Scene,
    node: &'a SceneNode,
    /// Axes and vectors are in the object's frame (`frame: "object"`).
    frame_object: bool,
}

impl OnNode<'_> {
    fn axis(&self, axis: &AxisSpec) -> Result<DVec3, ActionError> {
        axis_direction(axis, self.scene.up).map_err(|m| cfg_err(self.op, "axis", m))
    }

    /// A direction in the action's frame, as a world direction.
    fn to_world_dir(&self, v: DVec3) -> DVec3 {
        if self.frame_object {
            (self.node.world_from_local.rotation * v).normalize()
        } else {
            v
        }
    }

    fn to_world(&self, v: DVec3) -> DVec3 {
        if self.frame_object {
            self.node.world_from_local.rotation * v
        } else {
            v
        }
    }

    /// Translation: axis + distance, or a vector, in world units.
    fn translation(&self) -> Result<DVec3, ActionError> {
        let (op, c) = (self.op, self.c);
        let unit = length_unit(op, c.unit.as_deref(), self.scene.meters_per_unit)?;
        let v = match (&c.axis, c.distance, c.vector.or(c.offset)) {
            (Some(axis), Some(d), None) => {
                self.to_world_dir(self.axis(axis)?) * finite(op, "distance", d)?
            }
            (None, None, Some(v)) => self.to_world(finite3(op, "vector", v)?),
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
        Ok(v * unit)
    }

    /// Rotation: the world axis (the scene's up by default) and the angle in radians.
    fn rotation(&self) -> Result<(DVec3, f64), ActionError> {
        let (op, c) = (self.op, self.c);
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
            Some(a) => self.to_world_dir(self.axis(a)?),
            None => self.scene.up.normalize(),
        };
        Ok((axis, angle))
    }

    /// Scale factors along the object's own axes: uniform, along one axis, or per axis.
    fn scale_factors(&self) -> Result<DVec3, ActionError> {
        let (op, c) = (self.op, self.c);
        match (c.factor, c.factors) {
            (Some(f), None) => {
                let f = finite(op, "factor", f)?;
                check_factor(op, "factor", f)?;
                let Some(axis) = &c.axis else {
                    return Ok(DVec3::splat(f));
                };
                let dir = self.axis(axis)?;
                let local = if self.frame_object {
                    dir
                } else {
                    self.node.world_from_local.rotation.inverse() * dir
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
                Ok(f3)
            }
            (None, Some(fs)) => {
                let v = finite3(op, "factors", fs)?;
                for f in fs {
                    check_factor(op, "factors", f)?;
                }
                Ok(v)
            }
            (None, None) => Err(cfg_err(op, "factor", "expected factor or factors")),
            _ => Err(cfg_err(op, "factor", "give factor or factors, not both")),
        }
    }

    /// Swap with another node of this scene, or with a node imported from another scene.
    fn swap(
        &self,
        sources: &mut dyn SceneSource,
        taken_fields: &BTreeSet<String>,
    ) -> Result<Edit, ActionError> {
        let (op, c, scene, id) = (self.op, self.c, self.scene, self.node.id);
        let with = c
            .with
            .as_ref()
            .ok_or_else(|| cfg_err(op, "with", "expected the node to swap with"))?;
        if c.scene.is_some() {
            let new_id = fresh_or_given(op, scene, c.new_id)?;
            let mut imported = import(op, scene, sources, taken_fields, c, new_id)?;
            crate::edit::rest_in_place_of(&mut imported.node, self.node, scene.up);
            return Ok(Edit::SwapIn { id, imported });
        }
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
            return Err(not_allowed(op, id, "swap needs two different object nodes"));
        }
        Ok(Edit::Swap { a: id, b })
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
            format!(
                "expected a scale factor between 0.001 and 1000, got {}",
                crate::fmt_num(f)
            ),
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
    // At most this many are named: an error about a huge scene stays a line.
    const LISTED: usize = 24;
    let v: Vec<String> = scene
        .nodes
        .iter()
        .take(LISTED)
        .map(|n| format!("{} {:?}", n.id, n.label))
        .collect();
    let more = scene.nodes.len().saturating_sub(LISTED);
    if v.is_empty() {
        "no nodes".into()
    } else if more > 0 {
        format!("{}, … and {more} more", v.join(", "))
    } else {
        v.join(", ")
    }
}
