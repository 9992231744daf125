//! Editing a scene with its weights: validates actions (assist-core), brings in the fields
//! of nodes added from other scenes, applies the edits and keeps the undo/redo history.
//!
//! Replicas share one `Arc<NodeField>`: duplicating a node allocates no weights. A field
//! imported from another scene is loaded once and stored under a key unique in this scene.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use assist_core::{Action, ActionError, Edit, History, Scene, SceneSource};

use crate::node::{NeuralScene, NodeField};
use crate::scene_file::{self, SceneFileError};

#[derive(Debug, thiserror::Error)]
pub enum EditError {
    #[error("action {index}: {source}")]
    Action {
        /// 1-based position in the list of actions.
        index: usize,
        source: ActionError,
    },
    #[error(transparent)]
    File(#[from] SceneFileError),
    /// A new label that cannot be given to node `id`.
    #[error("label of node {id}: {message}")]
    Label { id: u16, message: String },
    /// Metres per unit out of range.
    #[error("meters_per_unit: {0}")]
    Unit(String),
}

pub use assist_core::scene::MAX_LABEL_CHARS;

/// Other scenes read from disk (`scene.json` only; weights are loaded when a node is added),
/// each read once, and the fields imported from them, each loaded once (clones share both,
/// so sessions forked from one another do not read a file twice). Relative paths are taken
/// as given (relative to the working directory).
#[derive(Default, Clone)]
pub struct SceneFiles {
    cache: BTreeMap<String, Scene>,
    fields: Arc<Mutex<BTreeMap<FieldKey, Arc<NodeField>>>>,
}

/// An imported field: its scene folder, key there, and the box and space it is loaded for.
type FieldKey = (PathBuf, String, [u64; 3], bool);

impl SceneFiles {
    pub fn dir_of(path: &str) -> PathBuf {
        let p = Path::new(path);
        if p.is_file() {
            p.parent().unwrap_or(Path::new(".")).to_path_buf()
        } else {
            p.to_path_buf()
        }
    }
}

impl SceneSource for SceneFiles {
    fn load_scene(&mut self, path: &str) -> Result<Scene, String> {
        if let Some(s) = self.cache.get(path) {
            return Ok(s.clone());
        }
        let (scene, _) = scene_file::load_scene_json(Path::new(path)).map_err(|e| e.to_string())?;
        self.cache.insert(path.to_string(), scene.clone());
        Ok(scene)
    }
}

/// A scene being edited.
pub struct Editor {
    pub scene: NeuralScene,
    pub history: History,
    pub info: serde_json::Value,
    pub sources: SceneFiles,
}

impl Editor {
    pub fn new(scene: NeuralScene) -> Self {
        Editor {
            scene,
            history: History::default(),
            info: serde_json::Value::Null,
            sources: SceneFiles::default(),
        }
    }

    /// Opens a scene directory with its history.
    pub fn open(path: &Path) -> Result<Self, SceneFileError> {
        let (scene, history, info) = scene_file::load_with_history(path)?;
        Ok(Editor {
            scene,
            history,
            info,
            sources: SceneFiles::default(),
        })
    }

    /// Field keys an imported node must not take (the scene's and its history's).
    pub fn taken(&self) -> BTreeSet<String> {
        let mut t = self.history.field_keys();
        t.extend(self.scene.fields.keys().cloned());
        t
    }

    /// Validates `actions` in order against the evolving scene without touching weights or
    /// history: the edits that `apply_all` would make.
    pub fn plan(&mut self, actions: &[Action]) -> Result<Vec<Edit>, EditError> {
        Ok(self.plan_scenes(actions, false)?.0)
    }

    /// [`plan`](Self::plan), with the scene after each edit (`every`) or after the last
    /// only (one undo step needs no more, and a copy per edit would make a long script
    /// quadratic): every action is validated and applied once, here; applying the plan
    /// only installs its results.
    pub fn plan_scenes(
        &mut self,
        actions: &[Action],
        every: bool,
    ) -> Result<(Vec<Edit>, Vec<Scene>), EditError> {
        let mut scene = self.scene.scene.clone();
        let mut taken = self.taken();
        let mut edits = Vec::with_capacity(actions.len());
        let mut after = Vec::with_capacity(actions.len());
        for (i, a) in actions.iter().enumerate() {
            let wrap = |source| EditError::Action {
                index: i + 1,
                source,
            };
            let e = a
                .validate(&scene, &mut self.sources, &taken)
                .map_err(wrap)?;
            assist_core::edit::apply(&mut scene, &e).map_err(wrap)?;
            if let Some(im) = imported(&e) {
                taken.insert(im.node.field.clone());
            }
            edits.push(e);
            if every {
                after.push(scene.clone());
            }
        }
        if !every && !edits.is_empty() {
            after.push(scene);
        }
        Ok((edits, after))
    }

    /// Loads the weights of every node `edits` import from other scenes.
    fn import_fields(&mut self, edits: &[Edit]) -> Result<(), EditError> {
        let mut new_fields = Vec::new();
        for (i, e) in edits.iter().enumerate() {
            if let Some(im) = imported(e) {
                let dir = SceneFiles::dir_of(&im.source);
                let key: FieldKey = (
                    dir.clone(),
                    im.source_field.clone(),
                    im.node.half_size.to_array().map(f64::to_bits),
                    im.node.space.is_box(),
                );
                let cached = self
                    .sources
                    .fields
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .get(&key)
                    .cloned();
                let nf = match cached {
                    Some(f) => f,
                    None => {
                        let f = Arc::new(scene_file::load_field(
                            &dir.join("scene.json"),
                            &dir,
                            &im.source_field,
                            &format!("action {}: node {} field", i + 1, im.source_id),
                            im.node.half_size,
                            im.node.space,
                        )?);
                        self.sources
                            .fields
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .insert(key, f.clone());
                        f
                    }
                };
                new_fields.push((im.node.field.clone(), nf));
            }
        }
        for (k, f) in new_fields {
            self.scene.fields.insert(k, f);
        }
        Ok(())
    }

    /// Validates and applies `actions` in order, one undo step per edit; all or nothing
    /// (on error the scene and history are as before).
    pub fn apply_all(&mut self, actions: &[Action]) -> Result<Vec<Edit>, EditError> {
        let (edits, after) = self.plan_scenes(actions, true)?;
        self.install(edits, after, false, None)
    }

    /// Like [`apply_all`](Self::apply_all), as one undo step (one instruction).
    pub fn apply_as_one(&mut self, actions: &[Action]) -> Result<Vec<Edit>, EditError> {
        let (edits, after) = self.plan_scenes(actions, false)?;
        self.install(edits, after, true, None)
    }

    /// Installs edits validated against the current scene (by [`plan`](Self::plan) or
    /// the language resolver), given with the scene after each (or, with `one_step`,
    /// after the last only): imports the fields of
    /// added nodes, then records one undo step per edit or, with `one_step`, one in all;
    /// each step keeps `text` (the instruction, or where the actions came from) and its
    /// resolved actions.
    pub fn install(
        &mut self,
        edits: Vec<Edit>,
        after: Vec<Scene>,
        one_step: bool,
        text: Option<String>,
    ) -> Result<Vec<Edit>, EditError> {
        assert!(
            edits.len() == after.len() || (one_step && after.len() == 1),
            "one scene after each edit, or the last for one step"
        );
        self.import_fields(&edits)?;
        let mpu = self.scene.scene.meters_per_unit;
        if one_step {
            if let Some(next) = after.into_iter().last() {
                let before = std::mem::replace(&mut self.scene.scene, next);
                let actions = edits.iter().map(|e| e.to_action(mpu)).collect();
                self.history.record(before, text, actions);
            }
        } else {
            for (next, e) in after.into_iter().zip(&edits) {
                let before = std::mem::replace(&mut self.scene.scene, next);
                self.history
                    .record(before, text.clone(), vec![e.to_action(mpu)]);
            }
        }
        Ok(edits)
    }

    /// A new editor over this one's scene as it is now, without history, sharing the
    /// scenes and fields already read from other scenes (weights are shared, not copied).
    pub fn fork(&self) -> Editor {
        Editor {
            scene: self.scene.clone(),
            history: History::default(),
            info: self.info.clone(),
            sources: self.sources.clone(),
        }
    }

    pub fn undo(&mut self) -> bool {
        self.history.undo(&mut self.scene.scene)
    }

    /// Sets the embedding of every node drawn by one of `by_field`'s fields — in the
    /// scene and in every undo/redo snapshot, so that undoing an earlier edit does not
    /// bring back a node without it. An embedding describes the object (its field), like
    /// its weights: not an edit, not an undo step; replicas share it.
    pub fn set_embeddings(&mut self, by_field: &std::collections::BTreeMap<String, Vec<f32>>) {
        let set = |scene: &mut assist_core::Scene| {
            for n in &mut scene.nodes {
                if let Some(e) = by_field.get(&n.field) {
                    n.embedding = Some(e.clone());
                }
            }
        };
        set(&mut self.scene.scene);
        for step in self
            .history
            .undo
            .iter_mut()
            .chain(self.history.redo.iter_mut())
        {
            set(&mut step.scene);
        }
    }

    /// Gives node `id` a new label, as one undo step ("rename …", no actions). Its
    /// semantic class stays what it was (renders keep their class ids). Refused: an
    /// unknown node, an empty or overlong label, or one another node has (names must
    /// resolve to one node).
    pub fn rename(&mut self, id: u16, label: &str) -> Result<(), EditError> {
        let bad = |message: String| EditError::Label { id, message };
        let label = label.trim();
        let Some(node) = self.scene.scene.node(id) else {
            return Err(bad("no such node".into()));
        };
        if label.is_empty() || label.chars().count() > MAX_LABEL_CHARS {
            return Err(bad(format!(
                "expected 1 to {MAX_LABEL_CHARS} characters, got {}",
                label.chars().count()
            )));
        }
        if label.chars().any(char::is_control) {
            return Err(bad("control characters are not allowed".into()));
        }
        if let Some(other) = self
            .scene
            .scene
            .nodes
            .iter()
            .find(|n| n.id != id && n.label.eq_ignore_ascii_case(label))
        {
            return Err(bad(format!(
                "node {} is already called {:?}",
                other.id, other.label
            )));
        }
        let old = node.label.clone();
        if old == label {
            return Ok(());
        }
        let mut next = self.scene.scene.clone();
        if let Some(n) = next.node_mut(id) {
            n.class = Some(n.class_name().to_string());
            n.label = label.to_string();
        }
        let before = std::mem::replace(&mut self.scene.scene, next);
        self.history.record(
            before,
            Some(format!("rename node {id} {old:?} to {label:?}")),
            Vec::new(),
        );
        Ok(())
    }

    /// Sets the scene's metres per world unit (a capture in COLMAP's arbitrary unit, sized
    /// after training), one undo step; `why` is the history's note.
    pub fn set_meters_per_unit(&mut self, mpu: f64, why: &str) -> Result<(), EditError> {
        if !(mpu.is_finite() && (1e-9..=1e9).contains(&mpu)) {
            return Err(EditError::Unit(format!(
                "expected metres per unit between 1e-9 and 1e9, got {mpu}"
            )));
        }
        let mut next = self.scene.scene.clone();
        next.meters_per_unit = mpu;
        let before = std::mem::replace(&mut self.scene.scene, next);
        self.history
            .record(before, Some(why.to_string()), Vec::new());
        Ok(())
    }

    pub fn redo(&mut self) -> bool {
        self.history.redo(&mut self.scene.scene)
    }

    /// Saves scene, fields and history atomically (`force` to replace `dir`).
    pub fn save(&self, dir: &Path, force: bool) -> Result<(), SceneFileError> {
        scene_file::save_with_history(dir, &self.scene, &self.history, self.info.clone(), force)
    }
}

fn imported(e: &Edit) -> Option<&assist_core::action::Imported> {
    match e {
        Edit::Add { imported } | Edit::SwapIn { imported, .. } => Some(imported),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::sync::Arc;

    use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode};
    use assist_field::{Field, OccupancyGrid};

    use super::*;

    fn two_nodes() -> NeuralScene {
        let node = |id: u16, label: &str, x: f64| {
            SceneNode::from_obb(
                id,
                label,
                "f",
                &Obb::new(DVec3::new(x, 0.0, 0.0), DVec3::splat(0.1), DMat3::IDENTITY),
            )
        };
        let mut fields = BTreeMap::new();
        fields.insert(
            "f".to_string(),
            Arc::new(NodeField::new(
                Field::constant(1.0, [0.5; 3], false, 1).unwrap(),
                OccupancyGrid::new(4),
                DVec3::splat(0.05),
            )),
        );
        NeuralScene {
            scene: Scene::with_nodes(vec![node(1, "mug", 0.0), node(2, "duck", 0.5)], DVec3::Z),
            fields,
        }
    }

    #[test]
    fn rename_is_one_undo_step_keeps_the_class_and_refuses_taken_names() {
        let mut ed = Editor::new(two_nodes());
        ed.rename(1, "  coffee mug ").unwrap();
        let n = ed.scene.scene.node(1).unwrap();
        assert_eq!(n.label, "coffee mug");
        assert_eq!(n.class_name(), "mug");
        assert_eq!(ed.history.undo.len(), 1);
        assert!(
            ed.history.undo[0]
                .text
                .as_deref()
                .unwrap()
                .contains("coffee mug")
        );
        let e = ed.rename(2, "Coffee Mug").unwrap_err().to_string();
        assert!(e.contains("node 1 is already called"), "{e}");
        assert!(ed.rename(2, "").is_err());
        assert!(ed.rename(2, "a\nb").is_err());
        assert!(
            ed.rename(9, "x")
                .unwrap_err()
                .to_string()
                .contains("no such node")
        );
        assert!(ed.undo());
        assert_eq!(ed.scene.scene.node(1).unwrap().label, "mug");
    }
}
