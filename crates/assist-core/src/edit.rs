//! Applying validated edits to a scene, and the edit log that gives undo/redo.
//!
//! Every edit changes only node data (pose, list of nodes, selection); weights are never
//! copied — a replica names the same field key as its original. Edits compose in order:
//! each one acts on the node's current pose, so "scale, then move, then rotate" is exactly
//! the product of the three.

use glam::{DQuat, DVec3};

use crate::InstanceId;
use crate::action::{ActionError, Edit, Operation};
use crate::geometry::Aabb;
use crate::scene::{Scene, SceneNode};

/// The node's box in world space, as an axis-aligned box around its corners.
pub fn world_aabb(node: &SceneNode) -> Aabb {
    let c = node.world_corners();
    let mut lo = c[0];
    let mut hi = c[0];
    for p in &c[1..] {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    Aabb::new(lo, hi)
}

fn overlaps(a: &Aabb, b: &Aabb) -> bool {
    (a.min.cmplt(b.max) & b.min.cmplt(a.max)).all()
}

/// Where a copy of `node` can stand beside it without overlapping any object: the first
/// of ±x, ±y (perpendicular to up, in that order) at one box width plus a 10% gap that
/// is free, else the first one.
pub fn free_offset(scene: &Scene, node: &SceneNode) -> DVec3 {
    let up = scene.up.normalize();
    let a = world_aabb(node);
    let size = a.max - a.min;
    let mut dirs = Vec::new();
    for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
        if axis.dot(up).abs() < 0.5 {
            dirs.push(axis);
            dirs.push(-axis);
        }
    }
    // x before y, + before −.
    dirs.sort_by_key(|d| (d.x == 0.0, d.x < 0.0 || d.y < 0.0 || d.z < 0.0));
    let offsets: Vec<DVec3> = dirs
        .iter()
        .map(|d| *d * (d.abs().dot(size) * 1.1))
        .collect();
    let others: Vec<Aabb> = scene
        .nodes
        .iter()
        .filter(|n| !n.is_background())
        .map(world_aabb)
        .collect();
    for &o in &offsets {
        let moved = Aabb::new(a.min + o, a.max + o);
        if !others.iter().any(|b| overlaps(&moved, b)) {
            return o;
        }
    }
    offsets[0]
}

/// Height of the lowest box corner along `up`.
fn bottom(node: &SceneNode, up: DVec3) -> f64 {
    node.world_corners()
        .iter()
        .map(|c| c.dot(up))
        .fold(f64::INFINITY, f64::min)
}

/// Moves `node` so that it rests where `place` stands: the same position across the
/// floor and the same bottom height along `up` (so a tall object does not sink into the
/// table nor a short one float).
pub fn rest_in_place_of(node: &mut SceneNode, place: &SceneNode, up: DVec3) {
    let up = up.normalize();
    let t = node.world_from_local.translation;
    let above_bottom = t.dot(up) - bottom(node, up);
    let p = place.world_from_local.translation;
    let target = p - up * p.dot(up) + up * (bottom(place, up) + above_bottom);
    node.world_from_local.translation = target;
}

fn missing(op: Operation, id: InstanceId, scene: &Scene) -> ActionError {
    let _ = op;
    ActionError::NoSuchNode {
        id,
        available: crate::action::describe_nodes(scene),
    }
}

/// Applies one validated edit.
pub fn apply(scene: &mut Scene, edit: &Edit) -> Result<(), ActionError> {
    let before = scene.clone();
    // Class ids stay what they were before the edit (a deleted node's class keeps its id).
    scene.register_classes();
    apply_unchecked(scene, edit)?;
    scene.register_classes();
    // An edit may not leave a node the scene file cannot hold (a 1e308 m move twice is
    // infinite): the scene is restored and the edit refused.
    // Nodes keep their order, so the node at the same index is looked at first (a scan
    // per node would make a thousand copies quadratic).
    let was = |i: usize, n: &SceneNode| {
        before
            .nodes
            .get(i)
            .filter(|b| b.id == n.id)
            .or_else(|| before.node(n.id))
    };
    let bad = scene
        .nodes
        .iter()
        .enumerate()
        .filter(|(i, n)| was(*i, n) != Some(*n))
        .find_map(|(_, n)| n.check().err().map(|e| (n.id, e)));
    if let Some((id, (field, message))) = bad {
        *scene = before;
        return Err(ActionError::NotAllowed {
            operation: edit_operation(edit).0,
            id,
            message: format!("refused: it would leave node {id} with {field}: {message}"),
        });
    }
    Ok(())
}

/// The operation of an edit, and the node it acts on.
fn edit_operation(edit: &Edit) -> (Operation, InstanceId) {
    match edit {
        Edit::Select { id } => (Operation::Select, *id),
        Edit::Translate { id, .. } => (Operation::Translate, *id),
        Edit::Rotate { id, .. } => (Operation::Rotate, *id),
        Edit::Scale { id, .. } => (Operation::Scale, *id),
        Edit::Replicate { id, .. } => (Operation::Replicate, *id),
        Edit::Delete { id } => (Operation::Delete, *id),
        Edit::Add { imported } => (Operation::Add, imported.node.id),
        Edit::Swap { a, .. } => (Operation::Swap, *a),
        Edit::SwapIn { id, .. } => (Operation::Swap, *id),
    }
}

fn apply_unchecked(scene: &mut Scene, edit: &Edit) -> Result<(), ActionError> {
    let get = |scene: &mut Scene, op: Operation, id: InstanceId| -> Result<usize, ActionError> {
        scene
            .nodes
            .iter()
            .position(|n| n.id == id)
            .ok_or_else(|| missing(op, id, scene))
    };
    match edit {
        Edit::Select { id } => {
            get(scene, Operation::Select, *id)?;
            scene.selected = Some(*id);
        }
        Edit::Translate { id, offset } => {
            let i = get(scene, Operation::Translate, *id)?;
            scene.nodes[i].world_from_local.translation += *offset;
        }
        Edit::Rotate {
            id,
            axis,
            angle,
            pivot,
        } => {
            let i = get(scene, Operation::Rotate, *id)?;
            let q = DQuat::from_axis_angle(axis.normalize(), *angle);
            let p = &mut scene.nodes[i].world_from_local;
            // About the box centre (the translation) unless another pivot is given.
            p.rotation = (q * p.rotation).normalize();
            if let Some(c) = pivot {
                p.translation = *c + q * (p.translation - *c);
            }
        }
        Edit::Scale { id, factors, pivot } => {
            let i = get(scene, Operation::Scale, *id)?;
            let p = &mut scene.nodes[i].world_from_local;
            p.scale *= *factors;
            if let Some(c) = pivot {
                let local = p.rotation.inverse() * (p.translation - *c);
                p.translation = *c + p.rotation * (local * *factors);
            }
        }
        Edit::Replicate { id, new_id, offset } => {
            let i = get(scene, Operation::Replicate, *id)?;
            if scene.node(*new_id).is_some() {
                return Err(ActionError::NotAllowed {
                    operation: Operation::Replicate,
                    id: *id,
                    message: format!("new id {new_id} is already used"),
                });
            }
            let mut copy = scene.nodes[i].clone();
            copy.id = *new_id;
            copy.world_from_local.translation += *offset;
            // "mug 2", of class "mug": nameable on its own, the same kind of thing.
            let class = copy.class_name().to_string();
            copy.label = scene.replica_label(&class);
            copy.class = Some(class);
            scene.nodes.push(copy);
        }
        Edit::Delete { id } => {
            let i = get(scene, Operation::Delete, *id)?;
            scene.nodes.remove(i);
            if scene.selected == Some(*id) {
                scene.selected = None;
            }
        }
        Edit::Add { imported } => {
            if scene.node(imported.node.id).is_some() {
                return Err(ActionError::NotAllowed {
                    operation: Operation::Add,
                    id: imported.node.id,
                    message: "the id is already used".into(),
                });
            }
            let mut node = imported.node.clone();
            number_if_taken(scene, &mut node);
            scene.nodes.push(node);
        }
        Edit::Swap { a, b } => {
            let ia = get(scene, Operation::Swap, *a)?;
            let ib = get(scene, Operation::Swap, *b)?;
            let (na, nb) = (scene.nodes[ia].clone(), scene.nodes[ib].clone());
            let up = scene.up;
            rest_in_place_of(&mut scene.nodes[ia], &nb, up);
            rest_in_place_of(&mut scene.nodes[ib], &na, up);
        }
        Edit::SwapIn { id, imported } => {
            let i = get(scene, Operation::Swap, *id)?;
            let mut node = imported.node.clone();
            scene.nodes[i].label.clear();
            number_if_taken(scene, &mut node);
            scene.nodes[i] = node;
            if scene.selected == Some(*id) {
                scene.selected = None;
            }
        }
    }
    Ok(())
}

/// A node brought in from elsewhere whose label another node already has is numbered as a
/// copy is ("mug 2", of class "mug"), so every object keeps a name of its own.
fn number_if_taken(scene: &Scene, node: &mut SceneNode) {
    if scene.nodes.iter().any(|n| n.label == node.label) {
        let class = node.class_name().to_string();
        node.label = scene.replica_label(&class);
        node.class = Some(class);
    }
}

/// Undo/redo over whole-scene snapshots (node data only; a scene of a hundred nodes is a few
/// kilobytes), so an undo restores the scene exactly, bit for bit. Each step remembers what
/// made it: the instruction's text (or the script's name) and the resolved actions.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct History {
    pub undo: Vec<HistoryStep>,
    pub redo: Vec<HistoryStep>,
}

/// One undo (or redo) step: the scene to go back (or forward) to, and the edit between.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HistoryStep {
    /// In `undo`: the scene before the step; in `redo`: the scene after it.
    pub scene: Scene,
    /// The instruction in words, or where the actions came from; `None` when not known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
    /// The step's actions as resolved and applied.
    #[serde(default)]
    pub actions: Vec<crate::Action>,
}

impl<'de> serde::Deserialize<'de> for HistoryStep {
    /// A step, or a bare scene snapshot (how histories were saved before steps carried
    /// their instruction).
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Step {
            scene: Scene,
            #[serde(default)]
            text: Option<String>,
            #[serde(default)]
            actions: Vec<crate::Action>,
        }
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Repr {
            Step(Step),
            Bare(Scene),
        }
        Ok(match Repr::deserialize(d)? {
            Repr::Step(s) => HistoryStep {
                scene: s.scene,
                text: s.text,
                actions: s.actions,
            },
            Repr::Bare(scene) => HistoryStep {
                scene,
                text: None,
                actions: Vec::new(),
            },
        })
    }
}

impl History {
    /// Applies `edit`, remembering the scene before it; clears the redo list.
    pub fn apply(&mut self, scene: &mut Scene, edit: &Edit) -> Result<(), ActionError> {
        let before = scene.clone();
        apply(scene, edit)?;
        let action = edit.to_action(scene.meters_per_unit);
        self.record(before, None, vec![action]);
        Ok(())
    }
    /// Remembers `before`, the scene an edit (or a group of edits) started from, once the
    /// scene holds the result, with what made the step; clears the redo list.
    pub fn record(&mut self, before: Scene, text: Option<String>, actions: Vec<crate::Action>) {
        self.undo.push(HistoryStep {
            scene: before,
            text,
            actions,
        });
        self.redo.clear();
    }
    /// Restores the scene before the last step; false when there is nothing to undo.
    pub fn undo(&mut self, scene: &mut Scene) -> bool {
        match self.undo.pop() {
            Some(step) => {
                let HistoryStep {
                    scene: prev,
                    text,
                    actions,
                } = step;
                self.redo.push(HistoryStep {
                    scene: std::mem::replace(scene, prev),
                    text,
                    actions,
                });
                true
            }
            None => false,
        }
    }
    /// Re-applies the last undone step; false when there is nothing to redo.
    pub fn redo(&mut self, scene: &mut Scene) -> bool {
        match self.redo.pop() {
            Some(step) => {
                let HistoryStep {
                    scene: next,
                    text,
                    actions,
                } = step;
                self.undo.push(HistoryStep {
                    scene: std::mem::replace(scene, next),
                    text,
                    actions,
                });
                true
            }
            None => false,
        }
    }
    /// Field keys referenced anywhere in the history (their weights must be kept).
    pub fn field_keys(&self) -> std::collections::BTreeSet<String> {
        self.undo
            .iter()
            .chain(&self.redo)
            .flat_map(|s| s.scene.nodes.iter().map(|n| n.field.clone()))
            .collect()
    }
    pub fn is_empty(&self) -> bool {
        self.undo.is_empty() && self.redo.is_empty()
    }
}

pub use crate::placement::sinking_depth;
