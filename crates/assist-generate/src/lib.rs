//! assist-generate: randomized, physically plausible, labelled variations of trained
//! scenes — `assist generate` and, later, Python's `assist.generate` — on the session layer.
//!
//! A sample is a pure function of (spec, seed, index): its random stream is
//! `Rng::stream(seed, index)`, every base scene is prepared the same way in every process,
//! and the sample's edits are *actions* applied through a [`Session`], written to its
//! `actions.jsonl`, so `assist edit` + `assist render` replay it bit for bit. Samples are
//! written atomically, each in its own folder, so shards of one run can share an output
//! folder and a restart skips what is done; [`merge`] joins them into dataset-wide indices.
//! The layout is documented in `docs/generate.md`.

#![forbid(unsafe_code)]

mod bop;
pub mod coco;
pub mod integrity;
mod merge;
pub mod place;
mod plan;
mod run;
mod sample;
pub mod shards;
pub mod spec;
pub mod surface;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use assist_core::action::NodeRef;
use assist_core::{Action, ActionConfig, Operation};
use assist_data::Output;
use assist_session::{NamedCamera, Session, SessionError, SplitChoice};

pub use coco::CocoMasks;
pub use merge::{GENERATED, MergeSummary, merge};
pub use run::{RunEvent, RunOptions, RunSummary};
pub use sample::{GaveUp, Sample, SampleReport, View};
pub use shards::{ShardState, Status, status};
pub use spec::Spec;

use place::Shape;
use spec::CameraFrom;
use surface::{SeenView, SupportMap};

#[derive(Debug, thiserror::Error)]
pub enum GenError {
    /// A spec value that cannot be used.
    #[error("{path}: {field}: {message}", path = path.display())]
    Spec {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Data(#[from] assist_data::DataError),
    #[error(transparent)]
    Output(#[from] assist_fs::FsError),
    #[error("sample {index}: {message}")]
    Sample { index: u64, message: String },
    #[error("{path}: {message}", path = path.display())]
    Folder { path: PathBuf, message: String },
}

pub type Result<T> = std::result::Result<T, GenError>;

/// Which samples this process makes: those with `index % count == index_of_shard`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// 0-based.
    pub index: u64,
    pub count: u64,
}

impl Shard {
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// `i/n` with `0 ≤ i < n`.
    pub fn parse(s: &str) -> std::result::Result<Shard, String> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| format!("expected i/n (e.g. 3/16, 0-based), got {s:?}"))?;
        let i: u64 = i
            .trim()
            .parse()
            .map_err(|_| format!("expected a shard index in {s:?}"))?;
        let n: u64 = n
            .trim()
            .parse()
            .map_err(|_| format!("expected a shard count in {s:?}"))?;
        if n == 0 || i >= n {
            return Err(format!(
                "expected 0 ≤ i < n in i/n, got {s:?} (shards are numbered from 0)"
            ));
        }
        Ok(Shard { index: i, count: n })
    }

    /// The shard of a Slurm array task (`SLURM_ARRAY_TASK_ID` − `SLURM_ARRAY_TASK_MIN` of
    /// `SLURM_ARRAY_TASK_COUNT`) or a Kubernetes Indexed Job (`JOB_COMPLETION_INDEX` of
    /// `JOB_COMPLETIONS`, which the Job's manifest sets), when one is set.
    pub fn from_env(
        get: impl Fn(&str) -> Option<String>,
    ) -> std::result::Result<Option<Shard>, String> {
        let num = |k: &str| -> std::result::Result<Option<u64>, String> {
            match get(k) {
                None => Ok(None),
                Some(v) => v
                    .trim()
                    .parse()
                    .map(Some)
                    .map_err(|_| format!("{k}={v:?}: expected a whole number")),
            }
        };
        if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let count = num("SLURM_ARRAY_TASK_COUNT")?
                .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let index = id
                .checked_sub(min)
                .ok_or("SLURM_ARRAY_TASK_ID is below SLURM_ARRAY_TASK_MIN")?;
            return Shard::parse(&format!("{index}/{count}")).map(Some);
        }
        if let Some(index) = num("JOB_COMPLETION_INDEX")? {
            let count = num("JOB_COMPLETIONS")?.ok_or(
                "JOB_COMPLETION_INDEX is set but JOB_COMPLETIONS is not (set it in the Job's env to its completions)",
            )?;
            return Shard::parse(&format!("{index}/{count}")).map(Some);
        }
        Ok(None)
    }

    pub fn owns(&self, sample: u64) -> bool {
        sample % self.count == self.index
    }
}

/// A base scene ready to sample from.
pub(crate) struct Base {
    pub path: PathBuf,
    pub session: Session,
    /// Cameras samples start from (the spec's split).
    pub cameras: Vec<NamedCamera>,
    /// The training views at low resolution, with the depth the scene shows there.
    pub seen: Vec<SeenView>,
    pub support: SupportMap,
    /// Occupied shapes by field key.
    pub shapes: BTreeMap<String, Option<Shape>>,
    /// Each library entry as it stands when added to this scene.
    pub library: Vec<LibNode>,
}

/// A library node as added to one base scene.
#[derive(Clone)]
pub(crate) struct LibNode {
    pub scene: String,
    pub id: u16,
    pub label: String,
    pub node: assist_core::SceneNode,
    pub shape: Option<Shape>,
}

/// A prepared generation run.
pub struct Generator {
    pub spec: Spec,
    pub(crate) bases: Vec<Base>,
    pub(crate) classes: Vec<String>,
    pub(crate) outputs: Vec<Output>,
}

/// Progress while preparing.
pub trait Progress {
    fn preparing(&mut self, _what: &str) {}
}

impl Progress for () {}

/// Each base scene's own class list (its stable ids), then the library's classes.
fn class_list(bases: &[Base]) -> Vec<String> {
    let mut classes = vec!["background".to_string()];
    for b in bases {
        for c in b.session.description().class_names().into_iter().skip(1) {
            if !classes.contains(&c) {
                classes.push(c);
            }
        }
    }
    if let Some(b) = bases.first() {
        for l in &b.library {
            let c = l.node.class_name().to_string();
            if !classes.contains(&c) {
                classes.push(c);
            }
        }
    }
    classes
}

/// `cameras.look_at` must name an object some sample can have: a node of a base scene or
/// a library object's label (a sample that deleted it aims as if none were named).
fn check_look_at(spec: &Spec, bases: &[Base]) -> Result<()> {
    let Some(r) = &spec.cameras.look_at else {
        return Ok(());
    };
    let names = |n: &assist_core::SceneNode| match r {
        NodeRef::Id(i) => n.id == *i,
        NodeRef::Label(l) => n.label == *l,
    };
    let found = bases.iter().any(|b| {
        b.session
            .description()
            .nodes
            .iter()
            .any(|n| !n.is_background() && names(n))
            || (matches!(r, NodeRef::Label(_)) && b.library.iter().any(|l| names(&l.node)))
    });
    if found {
        return Ok(());
    }
    Err(GenError::Spec {
        path: "spec".into(),
        field: "cameras.look_at".into(),
        message: format!(
            "expected an object of a base scene or the library, got {}",
            match r {
                NodeRef::Id(i) => format!("id {i}"),
                NodeRef::Label(l) => format!("{l:?}"),
            }
        ),
    })
}

/// The dataset base scene `k` was trained on: as the spec gives it, else as the scene
/// records it (its cameras and views are needed).
fn base_data(k: usize, b: &spec::BaseScene, session: &Session) -> Result<PathBuf> {
    if let Some(d) = &b.data {
        return Ok(d.clone());
    }
    let message = match assist_session::recorded_dataset(&b.path, session.info()) {
        Ok(Some(d)) => return Ok(d),
        Ok(None) => "the scene does not record its training dataset; give it as data = \"…\" (its cameras and views are needed)".into(),
        Err(e) => e.to_string(),
    };
    Err(GenError::Spec {
        path: b.path.clone(),
        field: format!("scenes[{k}].data"),
        message,
    })
}

/// Where fields are queried (a GPU: `--device`), shared by every session of a run.
pub type Backend = std::sync::Arc<dyn assist_session::FieldBackend>;

/// What preparing a base scene shares with the others: the backend and the library
/// scenes surveyed so far (by canonical path).
struct Where<'a> {
    backend: Option<Backend>,
    surveyed: &'a mut BTreeMap<String, Option<Survey>>,
}

/// Base scene `k` loaded and surveyed: its cameras, what its training views saw, the
/// surfaces objects may stand on, each object's shape and the library as it stands there.
fn prepare_base(
    spec: &Spec,
    k: usize,
    b: &spec::BaseScene,
    at: Where<'_>,
    progress: &mut dyn Progress,
) -> Result<Base> {
    progress.preparing(&format!("loading {}", b.path.display()));
    let mut session = Session::open(&b.path)?;
    session.set_backend(at.backend.clone());
    let data = base_data(k, b, &session)?;
    progress.preparing(&format!("reading the cameras of {}", data.display()));
    let train = assist_session::dataset_cameras(&data, SplitChoice::Train, 1)?;
    let cameras = match spec.cameras.from {
        CameraFrom::Train | CameraFrom::Orbit => train.clone(),
        CameraFrom::Test => assist_session::dataset_cameras(&data, SplitChoice::Test, 1)?,
        CameraFrom::All => assist_session::dataset_cameras(&data, SplitChoice::All, 1)?,
    };
    progress.preparing(&format!(
        "surveying {} training views for support surfaces",
        train.len().min(48)
    ));
    let views = surface::small_views(&train, 96, 48);
    let (seen, points) = surface::survey(session.scene(), &views, &session.survey_options());
    let scene = session.description();
    let mpu = scene.meters_per_unit;
    let no_surface = || GenError::Spec {
        path: b.path.clone(),
        field: "placement.surfaces".into(),
        message: "the training views show no upward-facing surface to place objects on".into(),
    };
    let all =
        surface::support_map(scene.up, &points, 0.01 / mpu, 0.005 / mpu).ok_or_else(no_surface)?;
    let shapes = object_shapes(&session, &all);
    let up = surface::UpFrame::new(scene.up);
    let levels: Vec<f64> = scene
        .nodes
        .iter()
        .filter(|n| !n.is_background())
        .filter_map(|n| {
            let s = shapes.get(&n.field)?.as_ref()?;
            Some(place::Posed::of(n).bottom(s, up.up))
        })
        .collect();
    let mut support = all;
    if spec.placement.surfaces == spec::Surfaces::Objects {
        support.restrict_to_levels(&levels, spec.placement.level_m / mpu);
    }
    if support.allowed.is_empty() {
        return Err(no_surface());
    }
    let mut library = Vec::new();
    for (j, l) in spec.library.iter().enumerate() {
        library.push(lib_node(&session, j, l)?);
    }
    let library = library_shapes(&session, &b.path, &shapes, library, at, progress);
    Ok(Base {
        path: b.path.clone(),
        session,
        cameras,
        seen,
        support,
        shapes,
        library,
    })
}

/// Each object field's shape without what lies below the surface it stood on (or its
/// whole occupancy when nothing is left), by field key.
fn object_shapes(session: &Session, all: &surface::SupportMap) -> BTreeMap<String, Option<Shape>> {
    let scene = session.description();
    let (mpu, up) = (scene.meters_per_unit, surface::UpFrame::new(scene.up));
    // Raw shapes give the levels objects stood at (surfaces = "objects").
    let raw: BTreeMap<String, Option<Shape>> = scene
        .nodes
        .iter()
        .filter(|n| !n.is_background())
        .map(|n| {
            let nf = &session.scene().fields[&n.field];
            let ax = place::up_axis(&n.world_from_local, scene.up);
            (n.field.clone(), Shape::of(nf, ax, |_| true))
        })
        .collect();
    let mut shapes = BTreeMap::new();
    for n in scene.nodes.iter().filter(|n| !n.is_background()) {
        if shapes.contains_key(&n.field) {
            continue;
        }
        let nf = &session.scene().fields[&n.field];
        let ax = place::up_axis(&n.world_from_local, scene.up);
        let keep = above_support(n, all, up, mpu);
        let s = Shape::of(nf, ax, keep).or_else(|| raw[&n.field].clone());
        shapes.insert(n.field.clone(), s);
    }
    shapes
}

/// The library's shapes as they stand in base scene `path`: a node from this same scene
/// keeps its cut shape; from another scene, it is cut at the surface it stood on there
/// (that scene surveyed once), or keeps its whole occupancy when that scene's capture is
/// not at hand.
fn library_shapes(
    session: &Session,
    path: &Path,
    shapes: &BTreeMap<String, Option<Shape>>,
    library: Vec<(LibNode, std::sync::Arc<assist_session::NodeField>)>,
    at: Where<'_>,
    progress: &mut dyn Progress,
) -> Vec<LibNode> {
    let scene = session.description();
    let this = std::fs::canonicalize(path).ok();
    library
        .into_iter()
        .map(|(mut ln, nf)| {
            let own = scene.nodes.iter().find(|n| n.id == ln.id);
            ln.shape = match own {
                Some(n)
                    if this.as_deref().map(|p| p.to_string_lossy().to_string())
                        == Some(ln.scene.clone()) =>
                {
                    shapes[&n.field].clone()
                }
                _ => {
                    let ax = place::up_axis(&ln.node.world_from_local, scene.up);
                    let survey = at.surveyed.entry(ln.scene.clone()).or_insert_with(|| {
                        progress.preparing(&format!(
                            "surveying {} for the surfaces its objects stood on",
                            ln.scene
                        ));
                        Survey::of(Path::new(&ln.scene), at.backend.clone())
                    });
                    survey
                        .as_ref()
                        .and_then(|sv| {
                            let n = sv.session.node(ln.id)?;
                            Shape::of(&nf, ax, above_support(n, &sv.support, sv.up, sv.mpu))
                        })
                        .or_else(|| Shape::of(&nf, ax, |_| true))
                }
            };
            ln
        })
        .collect()
}

impl Generator {
    /// Loads the base scenes and library, and surveys each base scene's training views
    /// (support surfaces, what was seen).
    pub fn prepare(spec: Spec, progress: &mut dyn Progress) -> Result<Generator> {
        Self::prepare_on(spec, None, progress)
    }

    /// [`prepare`](Self::prepare), every render of the run querying its fields on
    /// `backend` (a GPU: `--device`; `None`: this CPU).
    pub fn prepare_on(
        spec: Spec,
        backend: Option<Backend>,
        progress: &mut dyn Progress,
    ) -> Result<Generator> {
        let outputs = spec.output.outputs().map_err(|m| GenError::Spec {
            path: "spec".into(),
            field: "output.images".into(),
            message: m,
        })?;
        let mut bases = Vec::new();
        // Library scenes surveyed so far (by canonical path).
        let mut surveyed: BTreeMap<String, Option<Survey>> = BTreeMap::new();
        for (k, b) in spec.scenes.iter().enumerate() {
            let at = Where {
                backend: backend.clone(),
                surveyed: &mut surveyed,
            };
            bases.push(prepare_base(&spec, k, b, at, progress)?);
        }
        check_look_at(&spec, &bases)?;
        let classes = class_list(&bases);
        Ok(Generator {
            spec,
            bases,
            classes,
            outputs,
        })
    }

    /// Semantic classes of every sample: 0 = background, then the base scenes' labels (by
    /// id) and the library's, in spec order.
    pub fn classes(&self) -> &[String] {
        &self.classes
    }

    /// What a folder of this run records about it (`generate.json`): the spec with
    /// absolute paths and the classes; shards and restarts must agree on it.
    pub fn manifest(&self) -> serde_json::Value {
        serde_json::json!({
            "format": "assist-generate",
            "version": 1,
            "spec": self.spec,
            "classes": self.classes,
        })
    }
}

/// Adds library entry `j` to a fork of `session` where the node stands in its own scene,
/// to learn how it stands in this one (units, orientation) and load its field.
/// Keeps what of node `n`'s unit cube lies above the support surface near it (down to
/// 2 mm below), so that a table slab inside an object's box is not taken for its bottom.
fn above_support(
    n: &assist_core::SceneNode,
    all: &surface::SupportMap,
    up: surface::UpFrame,
    mpu: f64,
) -> impl Fn([f64; 3]) -> bool {
    let posed = place::Posed::of(n);
    let centre = up.plane(n.world_from_local.translation);
    let reach = (n.half_size * n.world_from_local.scale).max_element() * 1.5 + 0.03 / mpu;
    let level = all.level_near(centre, reach);
    move |u: [f64; 3]| {
        let p = posed.world(u);
        level.is_none_or(|h| up.height(p) >= h - 0.002 / mpu)
    }
}

/// Another scene's support surfaces, for cutting its objects used as library objects.
struct Survey {
    session: Session,
    support: surface::SupportMap,
    up: surface::UpFrame,
    mpu: f64,
}

impl Survey {
    /// `None` when the scene, its recorded capture or a surface in it is missing (its
    /// objects then keep their whole occupancy).
    fn of(path: &Path, backend: Option<Backend>) -> Option<Survey> {
        let mut session = Session::open(path).ok()?;
        session.set_backend(backend);
        let data = assist_session::recorded_dataset(path, session.info()).ok()??;
        let train = assist_session::dataset_cameras(&data, SplitChoice::Train, 1).ok()?;
        let views = surface::small_views(&train, 96, 48);
        let (_, points) = surface::survey(session.scene(), &views, &session.survey_options());
        let scene = session.description();
        let mpu = scene.meters_per_unit;
        let support = surface::support_map(scene.up, &points, 0.01 / mpu, 0.005 / mpu)?;
        let up = surface::UpFrame::new(scene.up);
        Some(Survey {
            session,
            support,
            up,
            mpu,
        })
    }
}

fn lib_node(
    session: &Session,
    j: usize,
    l: &spec::LibraryEntry,
) -> Result<(LibNode, std::sync::Arc<assist_session::NodeField>)> {
    let bad = |message: String| GenError::Spec {
        path: l.scene.clone(),
        field: format!("library[{j}]"),
        message,
    };
    let scene_path = std::fs::canonicalize(&l.scene)
        .map_err(|e| bad(format!("scene {}: {e}", l.scene.display())))?;
    let scene_str = scene_path.to_string_lossy().to_string();
    let other = Session::describe(&scene_path).map_err(|e| bad(e.to_string()))?;
    let found = other.nodes.iter().find(|n| match &l.node {
        NodeRef::Id(i) => n.id == *i,
        NodeRef::Label(s) => n.label == *s,
    });
    let Some(src) = found else {
        let have: Vec<String> = other
            .nodes
            .iter()
            .map(|n| format!("{} {:?}", n.id, n.label))
            .collect();
        return Err(bad(format!(
            "node {}: no such node in {} (it has {})",
            l.node,
            scene_path.display(),
            have.join(", ")
        )));
    };
    if src.is_background() {
        return Err(bad(format!(
            "node {}: is the background of {}; only objects can be added",
            l.node,
            scene_path.display()
        )));
    }
    let mut fork = session.fork();
    let id = fork.description().fresh_id();
    let action = Action {
        instance_id: id,
        operation: Operation::Add,
        config: ActionConfig {
            scene: Some(scene_str.clone()),
            node: Some(NodeRef::Id(src.id)),
            ..Default::default()
        },
    };
    fork.apply(&[action]).map_err(|e| bad(e.to_string()))?;
    let node = fork
        .node(id)
        .cloned()
        .ok_or_else(|| bad("the added node is missing".into()))?;
    let nf = fork.scene().fields[&node.field].clone();
    Ok((
        LibNode {
            scene: scene_str,
            id: src.id,
            label: src.label.clone(),
            node,
            shape: None,
        },
        nf,
    ))
}
