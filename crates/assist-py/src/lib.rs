//! `import assist`: Python over the session layer — load a scene, edit it in words or
//! actions, undo and redo, pick, save, and render to numpy arrays (the GIL released while
//! rendering). Every library error becomes `assist.AssistError` with the library's message;
//! no panic crosses the boundary (pyo3 turns one into `PanicException`).

#![forbid(unsafe_code)]

use std::path::PathBuf;

use assist_core::action::NodeRef;
use assist_core::{Action, ActionConfig, Camera as CoreCamera, DMat4, Intrinsics, Operation, Pose};
use assist_session::{Orbit, RenderRequest, Session, SplitChoice};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

pyo3::create_exception!(
    assist,
    AssistError,
    PyException,
    "An error of the assist library (bad file, field, value, unknown object, …)."
);

fn err(e: impl std::fmt::Display) -> PyErr {
    AssistError::new_err(e.to_string())
}

/// JSON text → Python objects (through the standard library's `json`).
fn to_py<'py>(py: Python<'py>, v: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let s = serde_json::to_string(v).map_err(err)?;
    py.import("json")?.call_method1("loads", (s,))
}

/// Python objects → a JSON value (through `json.dumps`).
fn from_py(obj: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    let s: String = obj
        .py()
        .import("json")?
        .call_method1("dumps", (obj,))?
        .extract()?;
    serde_json::from_str(&s).map_err(err)
}

/// A camera: pinhole intrinsics and a pose (4×4 world-from-camera, OpenGL convention: the
/// camera looks down −z, y up).
#[pyclass(module = "assist", frozen)]
#[derive(Clone)]
struct Camera {
    inner: CoreCamera,
    #[pyo3(get)]
    name: String,
    #[pyo3(get)]
    split: Option<String>,
}

#[pymethods]
impl Camera {
    /// `Camera(pose, fx, fy, cx, cy, width, height, name="camera")`: `pose` a 4×4
    /// world-from-camera matrix (OpenGL convention).
    #[new]
    #[pyo3(signature = (pose, fx, fy, cx, cy, width, height, name = "camera".to_string()))]
    fn new(
        pose: PyReadonlyArray2<'_, f64>,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
        name: String,
    ) -> PyResult<Self> {
        let a = pose.as_array();
        if a.shape() != [4, 4] {
            return Err(err(format!(
                "pose: expected a 4×4 matrix, got {:?}",
                a.shape()
            )));
        }
        let mut cols = [0.0; 16];
        for c in 0..4 {
            for r in 0..4 {
                cols[c * 4 + r] = a[[r, c]];
            }
        }
        let pose = Pose::from_matrix(DMat4::from_cols_array(&cols), "pose").map_err(err)?;
        let intrinsics = Intrinsics {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: Default::default(),
        };
        intrinsics.validate("camera").map_err(err)?;
        Ok(Camera {
            inner: CoreCamera { intrinsics, pose },
            name,
            split: None,
        })
    }

    /// The 4×4 world-from-camera matrix.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let m = self.inner.pose.to_matrix().transpose().to_cols_array();
        Ok(PyArray1::from_vec(py, m.to_vec())
            .reshape([4, 4])?
            .into_any())
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }

    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }

    /// `(fx, fy, cx, cy)` in pixels.
    #[getter]
    fn intrinsics(&self) -> (f64, f64, f64, f64) {
        let i = &self.inner.intrinsics;
        (i.fx, i.fy, i.cx, i.cy)
    }

    fn __repr__(&self) -> String {
        format!(
            "Camera({:?}, {}×{}{})",
            self.name,
            self.inner.width(),
            self.inner.height(),
            self.split
                .as_ref()
                .map(|s| format!(", split {s:?}"))
                .unwrap_or_default()
        )
    }
}

/// A dataset's cameras (any format assist reads).
#[pyclass(module = "assist", frozen)]
struct Dataset {
    #[pyo3(get)]
    cameras: Vec<Camera>,
    #[pyo3(get)]
    path: PathBuf,
}

#[pymethods]
impl Dataset {
    /// Reads the dataset at `path` (every split).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Dataset> {
        let p = path.clone();
        let ds = py
            .detach(|| assist_data::load(&p, &assist_data::LoadOptions::default()))
            .map_err(err)?;
        let cameras = ds
            .frames
            .iter()
            .map(|f| Camera {
                inner: f.camera,
                name: f.name.clone(),
                split: Some(f.split.name().to_string()),
            })
            .collect();
        Ok(Dataset { cameras, path })
    }

    fn __len__(&self) -> usize {
        self.cameras.len()
    }
}

/// A trained scene in memory: nodes, edits with undo and redo, rendering.
#[pyclass(module = "assist")]
struct Scene {
    session: Session,
}

fn node_ref(obj: &Bound<'_, PyAny>) -> PyResult<NodeRef> {
    if let Ok(i) = obj.extract::<u16>() {
        return Ok(NodeRef::Id(i));
    }
    if let Ok(s) = obj.extract::<String>() {
        return Ok(NodeRef::Label(s));
    }
    Err(err("node: expected an id (int) or a label (str)"))
}

/// One action (a dict) or a list of them.
fn actions_from(what: &Bound<'_, PyAny>) -> PyResult<Vec<Action>> {
    let v = from_py(what)?;
    match v {
        serde_json::Value::Array(_) => serde_json::from_value(v),
        other => serde_json::from_value(other).map(|a| vec![a]),
    }
    .map_err(|e| err(format!("actions: {e}")))
}

impl Scene {
    fn actions_of(&self, edits: &[assist_core::Edit]) -> Vec<Action> {
        let mpu = self.session.description().meters_per_unit;
        edits.iter().map(|e| e.to_action(mpu)).collect()
    }
}

#[pymethods]
impl Scene {
    /// Opens a `NAME.assist` scene with its history.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Scene> {
        let session = py.detach(|| Session::open(&path)).map_err(err)?;
        Ok(Scene { session })
    }

    /// The nodes: dicts with `id`, `label`, `class` (its semantic class: the label, or for
    /// a copy "mug 2" the original's "mug"), `half_size` (3,), `pose` (4×4 world-from-box,
    /// scale included), `background` (bool) and `embedding` (the node's CLIP embedding,
    /// float32, or None; `assist embed` makes them).
    #[getter]
    fn nodes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        for n in self.session.nodes() {
            let d = PyDict::new(py);
            d.set_item("id", n.id)?;
            d.set_item("label", &n.label)?;
            d.set_item("class", n.class_name())?;
            d.set_item("background", n.is_background())?;
            match &n.embedding {
                Some(e) => d.set_item("embedding", PyArray1::from_vec(py, e.clone()))?,
                None => d.set_item("embedding", py.None())?,
            }
            d.set_item(
                "half_size",
                PyArray1::from_vec(py, n.half_size.to_array().to_vec()),
            )?;
            let m = n.world_from_local.to_affine();
            let m4 = DMat4::from(m).transpose().to_cols_array();
            d.set_item("pose", PyArray1::from_vec(py, m4.to_vec()).reshape([4, 4])?)?;
            out.append(d)?;
        }
        Ok(out)
    }

    /// Metres per scene unit.
    #[getter]
    fn meters_per_unit(&self) -> f64 {
        self.session.description().meters_per_unit
    }

    /// Applies an instruction in words (`"move the mug 10 cm left"`) or a list of actions
    /// (`[{"instance_id": 3, "operation": "delete", "config": {}}]`) as one undo step;
    /// returns the resolved actions as dicts (world units). Raises `AssistError` naming the
    /// unknown object, the ambiguous candidates or the bad field.
    fn apply<'py>(
        &mut self,
        py: Python<'py>,
        what: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let edits = if let Ok(text) = what.extract::<String>() {
            self.session.apply_text(&text, None).map_err(err)?
        } else {
            let actions = actions_from(what)?;
            self.session.apply(&actions).map_err(err)?
        };
        to_py(py, &self.actions_of(&edits))
    }

    /// What an instruction or actions would do, without applying them.
    fn plan<'py>(
        &mut self,
        py: Python<'py>,
        what: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let edits = if let Ok(text) = what.extract::<String>() {
            self.session.resolve(&text, None).map_err(err)?.edits
        } else {
            let actions = actions_from(what)?;
            self.session.plan(&actions).map_err(err)?
        };
        to_py(py, &self.actions_of(&edits))
    }

    /// Gives node `id` a new label as one undo step (its semantic class stays); a taken,
    /// empty or overlong label raises `AssistError`.
    fn rename(&mut self, id: u16, label: &str) -> PyResult<()> {
        self.session.rename(id, label).map_err(err)
    }

    /// Undoes the last `apply`; False when there is nothing to undo.
    fn undo(&mut self) -> bool {
        self.session.undo()
    }

    /// Redoes the last undone `apply`; False when there is nothing to redo.
    fn redo(&mut self) -> bool {
        self.session.redo()
    }

    /// Selects (highlights) node `id`, or clears the selection with None.
    #[pyo3(signature = (id=None))]
    fn select(&mut self, id: Option<u16>) -> PyResult<()> {
        self.session.select(id).map_err(err)
    }

    /// The object seen at pixel `(x, y)` of `camera`, or None for the background.
    fn pick(&self, py: Python<'_>, camera: &Camera, x: f64, y: f64) -> PyResult<Option<u16>> {
        let c = camera.inner;
        let s = &self.session;
        py.detach(|| s.pick(&c, x, y)).map_err(err)
    }

    /// Adds node `node` (id or label) of the scene at `scene_path`, its box centred at
    /// `position` (world units) or where it stands there; returns the resolved actions.
    #[pyo3(signature = (scene_path, node, position=None))]
    fn add_from<'py>(
        &mut self,
        py: Python<'py>,
        scene_path: PathBuf,
        node: &Bound<'py, PyAny>,
        position: Option<[f64; 3]>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let id = self.session.description().fresh_id();
        let a = Action {
            instance_id: id,
            operation: Operation::Add,
            config: ActionConfig {
                scene: Some(scene_path.to_string_lossy().into_owned()),
                node: Some(node_ref(node)?),
                position,
                unit: position.map(|_| "units".to_string()),
                ..Default::default()
            },
        };
        let edits = self.session.apply(&[a]).map_err(err)?;
        to_py(py, &self.actions_of(&edits))
    }

    /// Saves scene, weights and history atomically (`force` to replace a scene assist
    /// wrote).
    #[pyo3(signature = (path, force=false))]
    fn save(&self, py: Python<'_>, path: PathBuf, force: bool) -> PyResult<()> {
        let s = &self.session;
        py.detach(|| s.save(&path, force)).map_err(err)
    }

    /// Exports nodes as meshes or point clouds into the folder `out`, as `assist export`
    /// does (same defaults): `nodes` ids or names, `"all"` (every object) or
    /// `"background"`; `format` obj, ply, glb or points; `frame` world or node (default:
    /// world, node with `sim`); `sim` "mjcf" or "urdf" for a simulator model. Returns the
    /// summary: `out`, `model` and per node `id`, `label`, `file`, `vertices`,
    /// `triangles`, `closed`, `volume_m3`, `seconds`.
    #[pyo3(signature = (out, nodes=vec!["all".to_string()], format="obj", frame=None, resolution=assist_session::DEFAULT_RESOLUTION, density=assist_session::DEFAULT_DENSITY, smooth=assist_session::DEFAULT_SMOOTH, triangles=assist_session::DEFAULT_MAX_TRIANGLES, min_part=assist_session::DEFAULT_MIN_PART, points=assist_session::DEFAULT_POINTS, sim=None, material_density=assist_session::DEFAULT_MATERIAL_DENSITY, force=false))]
    fn export<'py>(
        &mut self,
        py: Python<'py>,
        out: PathBuf,
        nodes: Vec<String>,
        format: &str,
        frame: Option<&str>,
        resolution: u32,
        density: f32,
        smooth: f32,
        triangles: usize,
        min_part: f64,
        points: usize,
        sim: Option<&str>,
        material_density: f64,
        force: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        fn pick<T: serde::de::DeserializeOwned>(what: &str, v: &str) -> PyResult<T> {
            serde_json::from_value(serde_json::Value::String(v.to_ascii_lowercase()))
                .map_err(|_| err(format!("{what}: unknown value {v:?}")))
        }
        let job = assist_session::ExportJob {
            nodes,
            format: assist_session::MeshFormat::parse(format).ok_or_else(|| {
                err(format!(
                    "format: expected obj, ply, glb or points, got {format:?}"
                ))
            })?,
            frame: frame
                .map(|f| pick("frame (world or node)", f))
                .transpose()?,
            sim: sim.map(|m| pick("sim (mjcf or urdf)", m)).transpose()?,
            extract: assist_session::ExtractOptions {
                resolution,
                density,
                min_part,
                smooth,
                max_triangles: triangles,
            },
            points,
            material_density,
            out,
            force,
        };
        let s = &mut self.session;
        let done = py.detach(|| s.export(&job, |_, _, _| {})).map_err(err)?;
        to_py(py, &done)
    }

    /// Renders `camera`: a dict with any of `rgb` (H×W×3 float32 in [0, 1]), `depth`
    /// (H×W float32 z-depth in metres, 0 where nothing is hit), `instance` (H×W uint16,
    /// 0 = background) and `opacity` (H×W float32). `width`/`height` rescale the camera.
    /// The selected node, if any, is highlighted as `assist render` does.
    #[pyo3(signature = (camera, outputs=vec!["rgb".to_string(), "depth".to_string(), "instance".to_string()], width=None, height=None))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        camera: &Camera,
        outputs: Vec<String>,
        width: Option<u32>,
        height: Option<u32>,
    ) -> PyResult<Bound<'py, PyDict>> {
        for o in &outputs {
            if !["rgb", "depth", "instance", "opacity"].contains(&o.as_str()) {
                return Err(err(format!(
                    "outputs: unknown output {o:?}; expected rgb, depth, instance or opacity"
                )));
            }
        }
        let size = match (width, height) {
            (None, None) => None,
            (Some(w), Some(h)) => Some((w, h)),
            (Some(w), None) => {
                let h = (camera.inner.height() as f64 * w as f64 / camera.inner.width() as f64)
                    .round() as u32;
                Some((w, h.max(1)))
            }
            (None, Some(h)) => {
                let w = (camera.inner.width() as f64 * h as f64 / camera.inner.height() as f64)
                    .round() as u32;
                Some((w.max(1), h))
            }
        };
        let req = RenderRequest {
            size,
            highlight: true,
            ..Default::default()
        };
        let c = camera.inner;
        let s = &self.session;
        let frame = py.detach(|| s.render(&c, &req)).map_err(err)?;
        let mpu = self.session.description().meters_per_unit as f32;
        let (w, h) = (frame.width as usize, frame.height as usize);
        // The frame's buffers become the arrays (no copy).
        let assist_session::Frame {
            rgb,
            mut depth,
            opacity,
            panoptic,
            ..
        } = frame;
        let (mut rgb, mut depth_m, mut opacity, mut panoptic) =
            (Some(rgb), Some(&mut depth), Some(opacity), Some(panoptic));
        let d = PyDict::new(py);
        for o in &outputs {
            match o.as_str() {
                "rgb" => {
                    if let Some(v) = rgb.take() {
                        d.set_item("rgb", PyArray1::from_vec(py, v).reshape([h, w, 3])?)?
                    }
                }
                "depth" => {
                    if let Some(v) = depth_m.take() {
                        if mpu != 1.0 {
                            v.iter_mut().for_each(|z| *z *= mpu);
                        }
                        d.set_item(
                            "depth",
                            PyArray1::from_vec(py, std::mem::take(v)).reshape([h, w])?,
                        )?
                    }
                }
                "instance" => {
                    if let Some(v) = panoptic.take() {
                        d.set_item("instance", PyArray1::from_vec(py, v).reshape([h, w])?)?
                    }
                }
                _ => {
                    if let Some(v) = opacity.take() {
                        d.set_item("opacity", PyArray1::from_vec(py, v).reshape([h, w])?)?
                    }
                }
            }
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!("Scene({} nodes)", self.session.nodes().len())
    }
}

/// `frames` cameras on a circle around `scene`'s objects, looking at their centre.
#[pyfunction]
#[pyo3(signature = (scene, frames=24, width=480, height=360, fov=50.0, elevation=30.0, radius=None))]
fn orbit(
    scene: &Scene,
    frames: usize,
    width: u32,
    height: u32,
    fov: f64,
    elevation: f64,
    radius: Option<f64>,
) -> PyResult<Vec<Camera>> {
    let o = Orbit {
        frames,
        width,
        height,
        fov_deg: fov,
        elevation_deg: elevation,
        radius,
    };
    let cams = assist_session::orbit(scene.session.description(), &o).map_err(err)?;
    Ok(cams
        .into_iter()
        .map(|c| Camera {
            inner: c.camera,
            name: c.name,
            split: None,
        })
        .collect())
}

/// The cameras of a dataset split (`"train"`, `"test"`, `"val"`, `"all"`).
#[pyfunction]
#[pyo3(signature = (path, split="all"))]
fn cameras(py: Python<'_>, path: PathBuf, split: &str) -> PyResult<Vec<Camera>> {
    let s = SplitChoice::parse(split).ok_or_else(|| {
        err(format!(
            "split: expected train, val, test, all or auto, got {split:?}"
        ))
    })?;
    let cams = py
        .detach(|| assist_session::dataset_cameras(&path, s, 1))
        .map_err(err)?;
    Ok(cams
        .into_iter()
        .map(|c| Camera {
            inner: c.camera,
            name: c.name,
            split: Some(split.to_string()),
        })
        .collect())
}

/// Samples of a generation spec, made on demand (`assist.generate`).
#[pyclass(module = "assist")]
struct Samples {
    generator: std::sync::Arc<assist_generate::Generator>,
    next: u64,
    end: u64,
}

#[pymethods]
impl Samples {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __len__(&self) -> usize {
        (self.end - self.next) as usize
    }

    /// The next sample: a dict with `index`, `actions`, `objects`, `gave_up` and `views`
    /// (each with `name`, `camera`, `rgb` H×W×3 float32, `depth` H×W float32 metres,
    /// `instance` and `semantic` H×W uint16, `unobserved` H×W bool, `annotations`).
    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        if self.next >= self.end {
            return Ok(None);
        }
        let i = self.next;
        self.next += 1;
        let g = self.generator.clone();
        let s = py.detach(move || g.sample(i, true)).map_err(err)?;
        let d = PyDict::new(py);
        d.set_item("index", s.index)?;
        d.set_item("actions", to_py(py, &s.actions)?)?;
        d.set_item("objects", to_py(py, &s.record["objects"])?)?;
        d.set_item("gave_up", to_py(py, &s.record["gave_up"])?)?;
        let views = PyList::empty(py);
        let mpu = s.meters_per_unit as f32;
        let notes = s.record["views"].as_array().cloned().unwrap_or_default();
        for (k, v) in s.views.into_iter().enumerate() {
            let (w, h) = (v.frame.width as usize, v.frame.height as usize);
            let vd = PyDict::new(py);
            vd.set_item("name", &v.camera.name)?;
            vd.set_item(
                "camera",
                Camera {
                    inner: v.camera.camera,
                    name: v.camera.name.clone(),
                    split: None,
                },
            )?;
            let assist_session::Frame {
                rgb,
                mut depth,
                panoptic,
                ..
            } = v.frame;
            if mpu != 1.0 {
                depth.iter_mut().for_each(|z| *z *= mpu);
            }
            vd.set_item("rgb", PyArray1::from_vec(py, rgb).reshape([h, w, 3])?)?;
            vd.set_item("depth", PyArray1::from_vec(py, depth).reshape([h, w])?)?;
            vd.set_item(
                "instance",
                PyArray1::from_vec(py, panoptic).reshape([h, w])?,
            )?;
            vd.set_item(
                "semantic",
                PyArray1::from_vec(py, v.semantic).reshape([h, w])?,
            )?;
            let unseen: Vec<bool> = v.unobserved.iter().map(|&m| m != 0).collect();
            vd.set_item(
                "unobserved",
                PyArray1::from_vec(py, unseen).reshape([h, w])?,
            )?;
            if let Some(note) = notes.get(k) {
                vd.set_item("annotations", to_py(py, note)?)?;
            }
            views.append(vd)?;
        }
        d.set_item("views", views)?;
        Ok(Some(d))
    }
}

/// Samples of a generation spec (a TOML/JSON file, or a dict of the same fields; see
/// `docs/generate.md`) as dicts of numpy arrays, made on demand without touching the disk;
/// `seed` and `count` override the spec's, `start` is the first index. The same index
/// gives the same sample as `assist generate`.
#[pyfunction]
#[pyo3(signature = (spec, seed=None, count=None, start=0))]
fn generate(
    py: Python<'_>,
    spec: &Bound<'_, PyAny>,
    seed: Option<u64>,
    count: Option<u64>,
    start: u64,
) -> PyResult<Samples> {
    let (mut spec, name) = if let Ok(p) = spec.extract::<PathBuf>() {
        (assist_generate::Spec::load(&p).map_err(err)?, p)
    } else {
        let v = from_py(spec)?;
        let s: assist_generate::Spec =
            serde_json::from_value(v).map_err(|e| err(format!("spec: {e}")))?;
        (s, PathBuf::from("spec"))
    };
    if let Some(s) = seed {
        spec.seed = s;
    }
    if let Some(c) = count {
        spec.count = c;
    }
    spec.check(&name).map_err(err)?;
    let end = spec.count;
    let g = py
        .detach(|| assist_generate::Generator::prepare(spec, &mut ()))
        .map_err(err)?;
    Ok(Samples {
        generator: std::sync::Arc::new(g),
        next: start.min(end),
        end,
    })
}

/// Trains a scene on the dataset at `data` into `out` (`NAME.assist`), as `assist train`
/// does; `options` are `assist train`'s flags with `_` for `-` (`downscale=2`, `seed=1`,
/// `resume=True`, `force=True`, `shadows="off"`, `lambda_obj_share=0.0`, …). `callback`, if given, is called with every
/// event as a dict (`{"event": "step", "stats": {...}, "eta_seconds": ...}`, `loading`,
/// `saved`, …). Ctrl+C saves the scene, then raises `KeyboardInterrupt`. Returns the
/// report: iterations, seconds, what stopped it (`stopped_by`), the last step's figures.
#[pyfunction]
#[pyo3(signature = (data, out, max_time=None, iters=None, callback=None, **options))]
fn train<'py>(
    py: Python<'py>,
    data: PathBuf,
    out: PathBuf,
    max_time: Option<f64>,
    iters: Option<usize>,
    callback: Option<Py<PyAny>>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let mut cfg = match options {
        Some(o) => {
            let v = from_py(o.as_any())?;
            let known =
                serde_json::to_value(assist_session::TrainConfig::default()).map_err(err)?;
            if let (Some(given), Some(known)) = (v.as_object(), known.as_object()) {
                for k in given.keys() {
                    if !known.contains_key(k) || k == "data" || k == "out" {
                        let mut names: Vec<&String> = known
                            .keys()
                            .filter(|n| *n != "data" && *n != "out")
                            .collect();
                        names.sort();
                        return Err(err(format!(
                            "train: unknown option {k:?} (options: {})",
                            names
                                .iter()
                                .map(|n| n.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )));
                    }
                }
            }
            serde_json::from_value::<assist_session::TrainConfig>(v)
                .map_err(|e| err(format!("train options: {e}")))?
        }
        None => assist_session::TrainConfig::default(),
    };
    cfg.data = data;
    cfg.out = out;
    if let Some(t) = max_time {
        cfg.max_time = Some(t);
    }
    if let Some(n) = iters {
        cfg.iters = n;
    }
    let job = assist_session::TrainJob::new(cfg);
    job.validate().map_err(err)?;
    let cancel = job.cancel_handle();
    let mut interrupted: Option<PyErr> = None;
    let mut failed: Option<PyErr> = None;
    let outcome = py.detach(|| {
        job.run(|e| {
            Python::attach(|py| {
                if interrupted.is_none()
                    && let Err(e) = py.check_signals()
                {
                    cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                    interrupted = Some(e);
                }
                if let (Some(cb), None) = (&callback, &failed) {
                    let r = to_py(py, e).and_then(|ev| cb.call1(py, (ev,)));
                    if let Err(e) = r {
                        cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                        failed = Some(e);
                    }
                }
            })
        })
    });
    if let Some(e) = interrupted.or(failed) {
        return Err(e);
    }
    let outcome = outcome.map_err(err)?;
    to_py(py, &outcome.report)
}

/// A CLIP model from weights on disk (see `assist embed --help` for the files):
/// `Clip(path=None)`, `None` meaning the `ASSIST_CLIP` environment variable.
#[pyclass(module = "assist", frozen)]
struct Clip {
    inner: std::sync::Arc<assist_session::clip::Clip>,
}

fn rows_to_array<'py>(
    py: Python<'py>,
    rows: Vec<Vec<f32>>,
    dim: usize,
    normalize: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let n = rows.len();
    let flat: Vec<f32> = rows
        .into_iter()
        .flat_map(|r| {
            if normalize {
                assist_session::clip::normalize(&r)
            } else {
                r
            }
        })
        .collect();
    Ok(PyArray1::from_vec(py, flat).reshape([n, dim])?.into_any())
}

#[pymethods]
impl Clip {
    #[new]
    #[pyo3(signature = (path=None))]
    fn new(py: Python<'_>, path: Option<PathBuf>) -> PyResult<Self> {
        let clip = py
            .detach(move || match path {
                Some(p) => Some(assist_session::clip::Clip::load(&p)),
                None => assist_session::clip::Clip::from_env(),
            })
            .ok_or_else(|| {
                err("no CLIP weights: pass a path or set ASSIST_CLIP to a folder holding them")
            })?
            .map_err(err)?;
        Ok(Clip {
            inner: std::sync::Arc::new(clip),
        })
    }

    /// Sizes, activation, normalisation and where the files came from.
    #[getter]
    fn config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.config();
        let f = &self.inner.files;
        to_py(
            py,
            &serde_json::json!({
                "embed_dim": c.embed_dim,
                "image_size": c.vision.image_size,
                "patch_size": c.vision.patch_size,
                "vision_width": c.vision.width,
                "vision_layers": c.vision.layers,
                "vision_heads": c.vision.heads,
                "context_length": c.text.context_length,
                "vocab_size": c.text.vocab_size,
                "text_width": c.text.width,
                "text_layers": c.text.layers,
                "text_heads": c.text.heads,
                "quick_gelu": c.activation == assist_session::clip::Activation::QuickGelu,
                "mean": c.mean,
                "std": c.std,
                "logit_scale": self.inner.logit_scale(),
                "weights": f.weights,
                "vocab": f.vocab,
                "layout": format!("{:?}", f.layout),
            }),
        )
    }

    /// The token ids of `text` (start, BPE tokens, end, zero padding to the context).
    fn tokenize<'py>(&self, py: Python<'py>, text: &str) -> Bound<'py, PyArray1<i64>> {
        let t: Vec<i64> = self
            .inner
            .tokenizer()
            .tokenize(text)
            .into_iter()
            .map(i64::from)
            .collect();
        PyArray1::from_vec(py, t)
    }

    /// Text features, `len(texts) × embed_dim` float32 (unit length if `normalize`).
    #[pyo3(signature = (texts, normalize=false))]
    fn encode_text<'py>(
        &self,
        py: Python<'py>,
        texts: Vec<String>,
        normalize: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.clone();
        let rows = py
            .detach(move || {
                let t: Vec<&str> = texts.iter().map(String::as_str).collect();
                c.text_features(&t)
            })
            .map_err(err)?;
        rows_to_array(py, rows, self.inner.config().embed_dim, normalize)
    }

    /// Image features, `n × embed_dim` float32 (unit length if `normalize`). `images`:
    /// uint8 RGB, `H×W×3` or `n×H×W×3` (resized, centre-cropped and normalised as
    /// open_clip's evaluation transform), or float32 `n×3×S×S` already preprocessed.
    #[pyo3(signature = (images, normalize=false))]
    fn encode_image<'py>(
        &self,
        py: Python<'py>,
        images: &Bound<'py, PyAny>,
        normalize: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.clone();
        let s = c.config().vision.image_size;
        let rows = if let Ok(a) = images.extract::<PyReadonlyArrayDyn<'_, u8>>() {
            let shape = a.shape().to_vec();
            let (n, h, w) = match shape[..] {
                [h, w, 3] => (1, h, w),
                [n, h, w, 3] => (n, h, w),
                _ => {
                    return Err(err(format!(
                        "images: expected H×W×3 or n×H×W×3 uint8, got shape {shape:?}"
                    )));
                }
            };
            let data = a.as_slice().map_err(err)?.to_vec();
            py.detach(move || {
                let imgs: Vec<image::RgbImage> = data
                    .chunks(h * w * 3)
                    .take(n)
                    .map(|px| {
                        image::RgbImage::from_raw(w as u32, h as u32, px.to_vec())
                            .expect("a full image")
                    })
                    .collect();
                c.embed_images(&imgs)
            })
        } else if let Ok(a) = images.extract::<PyReadonlyArrayDyn<'_, f32>>() {
            let shape = a.shape().to_vec();
            if !matches!(shape[..], [_, 3, h, w] if h == s && w == s) {
                return Err(err(format!(
                    "images: expected float32 n×3×{s}×{s}, got shape {shape:?}"
                )));
            }
            let data = a.as_slice().map_err(err)?.to_vec();
            py.detach(move || {
                let px: Vec<Vec<f32>> = data.chunks(3 * s * s).map(<[f32]>::to_vec).collect();
                c.image_features(&px)
            })
        } else {
            return Err(err(
                "images: expected a numpy array, uint8 H×W×3 / n×H×W×3 or float32 n×3×S×S",
            ));
        }
        .map_err(err)?;
        rows_to_array(py, rows, self.inner.config().embed_dim, normalize)
    }
}

#[pymodule]
fn assist(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("AssistError", m.py().get_type::<AssistError>())?;
    m.add_class::<Scene>()?;
    m.add_class::<Camera>()?;
    m.add_class::<Dataset>()?;
    m.add_function(wrap_pyfunction!(orbit, m)?)?;
    m.add_function(wrap_pyfunction!(cameras, m)?)?;
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(train, m)?)?;
    m.add_class::<Samples>()?;
    m.add_class::<Clip>()?;
    Ok(())
}
