//! assist-session: the application layer every front end shares — the CLI, the viewer,
//! the generator and the Python bindings hold a [`Session`] instead of re-assembling the
//! libraries themselves.
//!
//! A session is one scene in memory, nodes and fields: edits in words or as actions go
//! through one validation path (each action is validated and applied once, by the
//! editor), one call is one undo step, renders come back as typed frames, `pick` names
//! the node under a pixel, and `save` writes atomically. Nothing touches the disk after
//! loading except `save` and an `add … from SCENE` that imports another scene's node.

#![forbid(unsafe_code)]

mod cameras;
mod embed;
mod export;
mod frames;
mod held_out;
mod jobs;
mod render_job;
mod scale;
pub mod split;
mod train_checks;
mod train_config;
mod train_job;
mod train_shadows;

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use assist_core::{Action, Camera, Edit, InstanceId, Scene, SceneNode};
use assist_scene::{EditError, Editor, SceneFileError};

pub use assist_clip as clip;
pub use assist_core::placement::{Placement, Problem};
pub use assist_data::Output;
pub use assist_lang::{LlmProvider, Resolved};
pub use assist_mesh::write::{Format as MeshFormat, mesh_ply};
pub use assist_mesh::{
    DEFAULT_CLOSE, DEFAULT_DENSITY, DEFAULT_MAX_TRIANGLES, DEFAULT_MIN_PART, DEFAULT_OPACITY,
    DEFAULT_RESOLUTION, DEFAULT_SMOOTH, ExtractOptions, MeshFrame, NodeMesh,
};
/// `assist process`: a video or photographs → a posed dataset (ffmpeg, COLMAP).
pub use assist_process as process;
pub use assist_render::RenderedImage as Frame;
pub use assist_render::{DragCache, FieldBackend, RenderOptions, render_camera};
pub use assist_scene::scene_file;
pub use assist_scene::{NeuralScene, NodeField};
pub use assist_train::NodeBox;
pub use assist_train::{StepStats, StopReason};
pub use cameras::{
    CameraSource, MAX_ORBIT_FRAMES, NamedCamera, Orbit, SplitChoice, dataset_cameras, objects_box,
    orbit,
};
pub use embed::{
    CONTEXT as EMBED_CONTEXT, DEFAULT_EMBED_VIEWS, EmbedEvent, EmbedJob, EmbedSummary, EmbeddedNode,
};
pub use export::{
    DEFAULT_MATERIAL_DENSITY, DEFAULT_POINTS, ExportJob, ExportSummary, ExportedNode, SimModel,
};
pub use frames::{MAX_CAMERA_RADII, RenderRequest};
pub use held_out::HELD_OUT_MAX_PIXELS;
pub use jobs::{
    EvalJob, EvalReport, EvaluatedView, LIGHT_MIN_EXPLAINED, LightEstimate, LightJob, Photograph,
    dataset_boxes, photograph, recorded_dataset, trained_downscale,
};
pub use render_job::{
    DatasetOutput, Highlight, Quality, RenderJob, RenderSummary, ViewDone, frame_layers,
    view_images,
};
pub use scale::{ScaleFlags, ScaleTarget, Scaled, ScaledObject};
pub use train_config::{
    Appearance, DEFAULT_EVAL_VIEWS, Every, LambdaOverrides, MAX_BATCH_SAMPLES, MIN_BATCH_SAMPLES,
    OnOff, Shadows, TrainConfig, lambda_key, lambdas,
};
pub use train_job::{HeldOut, TrainEvent, TrainJob, TrainOutcome, preview_path};

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    File(#[from] SceneFileError),
    #[error(transparent)]
    Edit(#[from] EditError),
    #[error(transparent)]
    Language(#[from] assist_lang::LangError),
    #[error(transparent)]
    Data(assist_data::DataError),
    #[error(transparent)]
    Train(#[from] assist_train::TrainError),
    /// An output folder that may not be written (not assist's, in use, no space).
    #[error(transparent)]
    Output(assist_fs::FsError),
    /// The output of a training run exists and neither `force` nor `resume` was given.
    #[error("{} already exists (replace it with force, or continue it with resume)", .0.display())]
    OutExists(PathBuf),
    /// A request that cannot be served (a size, a pixel, an id).
    #[error("{what}: {message}")]
    Request { what: String, message: String },
    /// A save that failed (a full disk), with what stands in the output and how to go on.
    #[error("{0}")]
    SaveFailed(String),
    /// A render stopped by its cancel flag.
    #[error("cancelled")]
    Cancelled,
}

pub type Result<T> = std::result::Result<T, SessionError>;

pub(crate) fn request(what: &str, message: String) -> SessionError {
    SessionError::Request {
        what: what.into(),
        message,
    }
}

/// How many undo steps an application of several actions makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Steps {
    /// One for all (an instruction, as a viewer applies it).
    One,
    /// One per action (an edit script, as `assist edit` applies it).
    PerAction,
}

/// A scene being viewed and edited.
pub struct Session {
    editor: Editor,
    clip: ClipSlot,
    /// Packed hash tables of the fields rendered so far (see `frames.rs`), shared by forks.
    tables: Arc<std::sync::Mutex<Arc<assist_render::SceneTables>>>,
    /// Where renders query the fields when not on this CPU (a GPU: `--device`), shared
    /// by forks.
    backend: Option<Arc<dyn crate::FieldBackend>>,
}

/// The session's CLIP model: where it comes from (`ASSIST_CLIP` by default), loaded on
/// first use — when a phrase's words match no label and the scene has embeddings — and
/// shared by forks.
#[derive(Clone, Default)]
struct ClipSlot {
    path: Option<PathBuf>,
    loaded: Arc<OnceLock<std::result::Result<Arc<clip::Clip>, String>>>,
}

impl ClipSlot {
    fn from_env() -> Self {
        ClipSlot {
            path: std::env::var_os(clip::ENV)
                .filter(|v| !v.is_empty())
                .map(PathBuf::from),
            loaded: Arc::default(),
        }
    }

    fn configured(&self) -> bool {
        self.path.is_some() || self.loaded.get().is_some()
    }

    fn get(&self) -> std::result::Result<Arc<clip::Clip>, String> {
        self.loaded
            .get_or_init(|| match &self.path {
                Some(p) => clip::Clip::load(p).map(Arc::new).map_err(|e| e.to_string()),
                None => Err("no CLIP weights configured".into()),
            })
            .clone()
    }
}

/// A session's CLIP text encoder as the parser's embedder (normalised text features);
/// remembers why it could not embed.
struct ClipText<'a> {
    slot: &'a ClipSlot,
    error: std::cell::RefCell<Option<String>>,
}

impl assist_lang::TextEmbedder for ClipText<'_> {
    fn embed(&self, text: &str) -> Option<Vec<f32>> {
        let r = self
            .slot
            .get()
            .and_then(|c| c.text_features(&[text]).map_err(|e| e.to_string()));
        match r {
            Ok(mut v) => Some(clip::normalize(&v.swap_remove(0))),
            Err(e) => {
                *self.error.borrow_mut() = Some(e);
                None
            }
        }
    }
}

/// What an instruction's scale keeps in place.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pivot {
    /// The object's resting point: the middle of its box's lowest face (it stays on its
    /// support).
    #[default]
    Base,
    /// The box centre.
    Center,
}

impl Session {
    /// Opens a `NAME.assist` scene with its history.
    pub fn open(path: &Path) -> Result<Self> {
        Ok(Session {
            editor: Editor::open(path)?,
            clip: ClipSlot::from_env(),
            tables: Arc::default(),
            backend: None,
        })
    }

    /// A session over a scene already in memory (no history).
    pub fn new(scene: NeuralScene) -> Self {
        Session {
            editor: Editor::new(scene),
            clip: ClipSlot::from_env(),
            tables: Arc::default(),
            backend: None,
        }
    }

    /// A new session over this one's scene as it is now, without undo history, sharing
    /// its weights and the other scenes it has read (cheap: nothing is copied but the
    /// scene description). A generator forks one per sample.
    pub fn fork(&self) -> Session {
        Session {
            editor: self.editor.fork(),
            clip: self.clip.clone(),
            tables: self.tables.clone(),
            backend: self.backend.clone(),
        }
    }

    /// Renders from now on query the fields on `backend` (a GPU; `None`: this CPU).
    pub fn set_backend(&mut self, backend: Option<Arc<dyn crate::FieldBackend>>) {
        self.backend = backend;
    }

    /// Where renders query the fields (`None`: this CPU).
    pub fn backend(&self) -> Option<&Arc<dyn crate::FieldBackend>> {
        self.backend.as_ref()
    }

    /// The options of renders that measure the scene rather than show it: the hash tables
    /// as trained (not packed), the MLP products at this CPU's rendering precision, and
    /// always on this CPU (the reference), whatever the session's backend. What is
    /// decided from them (where the generator may place an object) is then the same on
    /// every device of one machine; a GPU's last bits would otherwise move a support
    /// cell's count across a threshold, and a placement by a whole cell.
    pub fn survey_options(&self) -> RenderOptions {
        RenderOptions::default()
    }

    /// The render options every render of this session starts from: its packed tables
    /// and its backend.
    pub fn base_options(&self) -> RenderOptions {
        RenderOptions {
            tables: self.packed_tables(),
            backend: self.backend.clone(),
            ..RenderOptions::default()
        }
    }

    /// Where this session's CLIP weights are (`None`: none, not even `ASSIST_CLIP`);
    /// loaded when first needed.
    pub fn set_clip_path(&mut self, path: Option<PathBuf>) {
        self.clip = ClipSlot {
            path,
            loaded: Arc::default(),
        };
    }

    /// Uses an already loaded CLIP model.
    pub fn set_clip(&mut self, model: Arc<clip::Clip>) {
        let loaded = OnceLock::new();
        let _ = loaded.set(Ok(model));
        self.clip = ClipSlot {
            path: None,
            loaded: Arc::new(loaded),
        };
    }

    /// The session's CLIP model, loading it now if needed; `None` when none is configured.
    pub fn clip(&self) -> Result<Option<Arc<clip::Clip>>> {
        if !self.clip.configured() {
            return Ok(None);
        }
        self.clip.get().map(Some).map_err(|e| request("clip", e))
    }

    /// The scene's `info` (training provenance: dataset, iterations, options).
    pub fn info(&self) -> &serde_json::Value {
        &self.editor.info
    }

    pub fn scene(&self) -> &NeuralScene {
        &self.editor.scene
    }

    /// The scene's nodes (background first when it has one).
    pub fn nodes(&self) -> &[SceneNode] {
        &self.editor.scene.scene.nodes
    }

    pub fn node(&self, id: InstanceId) -> Option<&SceneNode> {
        self.nodes().iter().find(|n| n.id == id)
    }

    /// Validates and applies `actions` in order, all or nothing, as one undo step.
    pub fn apply(&mut self, actions: &[Action]) -> Result<Vec<Edit>> {
        self.apply_with(actions, Steps::One)
    }

    /// [`apply`](Self::apply) with a choice of undo steps.
    pub fn apply_with(&mut self, actions: &[Action], steps: Steps) -> Result<Vec<Edit>> {
        self.apply_noted(actions, steps, None)
    }

    /// [`apply_with`](Self::apply_with), the history step(s) noting `text` (where the
    /// actions came from, e.g. an edit script's name).
    pub fn apply_noted(
        &mut self,
        actions: &[Action],
        steps: Steps,
        text: Option<String>,
    ) -> Result<Vec<Edit>> {
        let (edits, after) = self
            .editor
            .plan_scenes(actions, steps == Steps::PerAction)?;
        Ok(self
            .editor
            .install(edits, after, steps == Steps::One, text)?)
    }

    /// What an instruction in words resolves to — actions, each validated once against
    /// the scene as the previous ones leave it, with its edit — without applying it.
    /// `view` makes left/right/forward relative to that camera; "it" before any object is
    /// named means the selected node.
    pub fn resolve(&mut self, text: &str, view: Option<&Camera>) -> Result<Resolved> {
        self.resolve_with(text, view, Pivot::Base)
    }

    /// [`resolve`](Self::resolve), choosing what a scale in words keeps in place.
    pub fn resolve_with(
        &mut self,
        text: &str,
        view: Option<&Camera>,
        pivot: Pivot,
    ) -> Result<Resolved> {
        let encoder = ClipText {
            slot: &self.clip,
            error: Default::default(),
        };
        let opts = assist_lang::ParseOptions {
            camera: view.map(|c| c.pose.rotation()),
            last: self.editor.scene.scene.selected,
            embedder: self
                .clip
                .configured()
                .then_some(&encoder as &dyn assist_lang::TextEmbedder),
            scale_about_center: pivot == Pivot::Center,
        };
        let taken = self.editor.taken();
        let r = assist_lang::resolve_text(
            text,
            &self.editor.scene.scene,
            &opts,
            &mut self.editor.sources,
            &taken,
        );
        match (r, encoder.error.into_inner()) {
            (
                Err(assist_lang::LangError::UnknownObject {
                    phrase, candidates, ..
                }),
                Some(e),
            ) => Err(assist_lang::LangError::UnknownObject {
                phrase,
                candidates,
                hint: format!("; CLIP could not embed the phrase: {e}"),
            }
            .into()),
            (r, _) => Ok(r?),
        }
    }

    /// Installs what [`resolve`](Self::resolve) returned (the scene must not have changed
    /// since) without validating it again; the history step(s) note `text`, the
    /// instruction it came from.
    pub fn install(
        &mut self,
        resolved: Resolved,
        steps: Steps,
        text: Option<String>,
    ) -> Result<Vec<Edit>> {
        Ok(self
            .editor
            .install(resolved.edits, resolved.scenes, steps == Steps::One, text)?)
    }

    /// Applies an instruction in words as one undo step.
    pub fn apply_text(&mut self, text: &str, view: Option<&Camera>) -> Result<Vec<Edit>> {
        let r = self.resolve(text, view)?;
        self.install(r, Steps::One, Some(text.to_string()))
    }

    /// The edit history: steps that can be undone (oldest first) and redone (the next
    /// redo last).
    pub fn history(&self) -> &assist_core::History {
        &self.editor.history
    }

    /// Asks an LLM provider for the actions of an instruction (validated against the
    /// scene, not applied).
    pub fn ask_llm(
        &mut self,
        provider: &assist_lang::LlmProvider,
        text: &str,
    ) -> Result<Vec<Action>> {
        Ok(provider.parse(text, &self.editor.scene.scene, &mut self.editor.sources)?)
    }

    /// The edits `actions` would make, validated against the scene, without applying them.
    pub fn plan(&mut self, actions: &[Action]) -> Result<Vec<Edit>> {
        Ok(self.editor.plan(actions)?)
    }

    /// Undoes the last call to `apply`; false when there is nothing to undo.
    pub fn undo(&mut self) -> bool {
        self.editor.undo()
    }

    pub fn redo(&mut self) -> bool {
        self.editor.redo()
    }

    /// Undo steps available.
    pub fn undo_steps(&self) -> usize {
        self.editor.history.undo.len()
    }

    /// Redo steps available.
    pub fn redo_steps(&self) -> usize {
        self.editor.history.redo.len()
    }

    /// Selects (highlights) a node, or clears the selection; not an undoable edit.
    pub fn select(&mut self, id: Option<InstanceId>) -> Result<()> {
        if let Some(id) = id
            && self.node(id).is_none()
        {
            return Err(request(
                "select",
                format!("no node with id {id} (the scene has {})", self.ids()),
            ));
        }
        self.editor.scene.scene.selected = id;
        Ok(())
    }

    /// Gives node `id` a new label as one undo step; its semantic class stays (see
    /// `Editor::rename` for what is refused).
    pub fn rename(&mut self, id: InstanceId, label: &str) -> Result<()> {
        Ok(self.editor.rename(id, label)?)
    }

    /// A fork of this session without the nodes `hidden` (for views that hide some:
    /// renders and picks see the rest; weights are shared, nothing is copied).
    pub fn without(&self, hidden: &[InstanceId]) -> Session {
        let mut s = self.fork();
        s.editor
            .scene
            .scene
            .nodes
            .retain(|n| !hidden.contains(&n.id));
        if s.editor
            .scene
            .scene
            .selected
            .is_some_and(|id| hidden.contains(&id))
        {
            s.editor.scene.scene.selected = None;
        }
        s
    }

    pub(crate) fn ids(&self) -> String {
        let ids: Vec<String> = self
            .nodes()
            .iter()
            .map(|n| format!("{} {:?}", n.id, n.label))
            .collect();
        ids.join(", ")
    }

    /// What `after` (this scene edited) does wrong that `before` did not: objects inside
    /// one another or floating above what carries them (see
    /// [`assist_core::placement::placement_problems`]; the background's trained surface
    /// is what carries them), and how many changed objects were left unchecked.
    pub fn placement_problems(&self, before: &Scene, after: &Scene) -> (Vec<Placement>, usize) {
        let weights = self.scene();
        let bg = weights.scene.nodes.iter().position(|n| n.is_background());
        let mut density = |pts: &[assist_core::DVec3]| match bg {
            Some(k) => weights.density_at_world(k, pts),
            None => vec![0.0; pts.len()],
        };
        assist_core::placement::placement_problems(before, after, &mut density)
    }

    /// Another scene's description (nodes, units; no weights), for cross-scene edits.
    pub fn describe(path: &Path) -> Result<Scene> {
        Ok(assist_scene::scene_file::load_scene_json(path)?.0)
    }

    /// Saves scene, fields and history atomically (`force` to replace an existing `path`).
    pub fn save(&self, path: &Path, force: bool) -> Result<()> {
        Ok(self.editor.save(path, force)?)
    }

    /// The scene description (nodes, up, units) without the fields.
    pub fn description(&self) -> &Scene {
        &self.editor.scene.scene
    }
}
