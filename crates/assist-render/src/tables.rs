//! Packed (bf16) hash tables of a scene's fields, kept beside the scene for rendering it
//! (`RenderOptions::tables`): the encoding reads half the bytes and gathers once per
//! corner (`assist_field::PackedTables`). Each entry holds the `Arc` of the node field it
//! was packed from and is found by that `Arc`'s identity, so whoever changes the field's
//! parameters (`Arc::make_mut`) works on a copy: a stale snapshot is never used, it is
//! just not found, and that node is encoded from its f32 parameters until the next
//! [`SceneTables::refresh`].

use std::collections::HashMap;
use std::sync::Arc;

use assist_field::{PackedTables, Precision};
use assist_scene::{NeuralScene, NodeField};

use crate::render::Query;

/// Packed tables of scene fields, by the identity of the field's `Arc` (so forks of a
/// scene, and scenes that share fields, share them).
#[derive(Debug, Default, Clone)]
pub struct SceneTables {
    by_field: HashMap<usize, (Arc<NodeField>, Arc<PackedTables>)>,
}

fn id(nf: &Arc<NodeField>) -> usize {
    Arc::as_ptr(nf) as usize
}

impl SceneTables {
    /// Packed tables of every field of `scene` (those with two features per level).
    pub fn of(scene: &NeuralScene) -> Self {
        let mut t = SceneTables::default();
        t.refresh(scene);
        t
    }

    /// Packs the fields of `scene` not packed yet (new, or changed since: another `Arc`),
    /// and forgets those no scene holds any more. Returns how many were packed.
    pub fn refresh(&mut self, scene: &NeuralScene) -> usize {
        self.by_field.retain(|_, (nf, _)| Arc::strong_count(nf) > 1);
        let mut packed = 0;
        for nf in scene.fields.values() {
            if self.by_field.contains_key(&id(nf)) {
                continue;
            }
            if let Some(t) = nf.field.pack_tables() {
                self.by_field.insert(id(nf), (nf.clone(), Arc::new(t)));
                packed += 1;
            }
        }
        packed
    }

    /// Whether every field of `scene` that packs has its tables here.
    pub fn covers(&self, scene: &NeuralScene) -> bool {
        scene
            .fields
            .values()
            .all(|nf| self.by_field.contains_key(&id(nf)) || nf.field.layout.grid.features != 2)
    }

    /// Node `node`'s packed tables, if they were packed from the field it has now.
    pub fn get(&self, scene: &NeuralScene, node: usize) -> Option<&PackedTables> {
        let nf = scene.fields.get(&scene.scene.nodes[node].field)?;
        self.by_field.get(&id(nf)).map(|(_, t)| &**t)
    }

    /// Bytes of packed tables held.
    pub fn bytes(&self) -> usize {
        self.by_field.values().map(|(_, t)| t.bytes()).sum()
    }
}

/// The packed tables a render query reads for node `node`: only at `Precision::Bf16`.
pub(crate) fn for_node<'a>(
    scene: &NeuralScene,
    node: usize,
    q: &Query<'a>,
) -> Option<&'a PackedTables> {
    match *q {
        Query::Render {
            precision: Precision::Bf16,
            tables: Some(t),
            ..
        } => t.get(scene, node),
        _ => None,
    }
}
