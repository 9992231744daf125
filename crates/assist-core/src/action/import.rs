//! Nodes from other scenes: finding the named node in the source scene and re-expressing
//! it in this scene's units, up direction, ids and field keys.

use std::collections::BTreeSet;

use glam::DQuat;

use super::validate::{cfg_err, describe_nodes};
use super::{ActionConfig, ActionError, Imported, NodeRef, Operation, SceneSource};
use crate::InstanceId;
use crate::scene::{Scene, SceneNode};

/// Reads the node named by `config.node` (add) or `config.with` (swap) from `config.scene`,
/// re-expressed in `scene`'s units and up direction, with a fresh id and a free field key.
pub(super) fn import(
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
    // Its shadow was learned under the other scene's light: it keeps it as learned.
    node.cast = None;
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
