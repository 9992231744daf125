//! `assist.Scene`: a session in Python — load, list nodes, apply words or actions, plan,
//! undo and redo, pick, add from another scene, save, export and render to numpy.

use super::*;
use assist_core::action::NodeRef;
use assist_core::{Action, ActionConfig, Operation};
use assist_session::{RenderRequest, Session};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::sync::{Arc, Mutex, MutexGuard, TryLockError};
use std::time::Duration;

/// A trained scene in memory: nodes, edits with undo and redo, rendering. Threads share
/// it: a call waits (the GIL released) while another thread's call runs.
#[pyclass(module = "assist", frozen)]
pub(crate) struct Scene {
    session: Arc<Mutex<Session>>,
    /// The GPU its renders query (`device=`), to warn when it failed part-way.
    gpu: Option<Arc<assist_gpu::GpuBackend>>,
}

impl Scene {
    /// The session, once no other thread holds it; Ctrl+C while waiting raises.
    pub(crate) fn lock(&self, py: Python<'_>) -> PyResult<MutexGuard<'_, Session>> {
        loop {
            match self.session.try_lock() {
                Ok(g) => return Ok(g),
                // A call that panicked left the session as its last whole edit.
                Err(TryLockError::Poisoned(p)) => return Ok(p.into_inner()),
                Err(TryLockError::WouldBlock) => {
                    py.detach(|| std::thread::sleep(Duration::from_millis(2)));
                    py.check_signals()?;
                }
            }
        }
    }

    /// Runs `work` on the session in a worker thread while this thread answers Ctrl+C:
    /// on an interrupt `cancel` is set (a render stops at its next batch of rays) and
    /// `KeyboardInterrupt` is raised at once; work that cannot stop finishes unseen.
    fn interruptible<T: Send + 'static>(
        &self,
        py: Python<'_>,
        cancel: Option<Arc<AtomicBool>>,
        work: impl FnOnce(&mut Session) -> T + Send + 'static,
    ) -> PyResult<T> {
        let session = self.session.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("assist-scene".into())
            .spawn(move || {
                let mut s = session.lock().unwrap_or_else(|p| p.into_inner());
                let _ = tx.send(work(&mut s));
            })
            .map_err(|e| err(format!("cannot start a worker thread: {e}")))?;
        let mut rx = rx;
        loop {
            // The receiver travels into the GIL-free wait and back (it is not Sync).
            let (got, back) = py.detach(move || (rx.recv_timeout(Duration::from_millis(50)), rx));
            rx = back;
            match got {
                Ok(v) => return Ok(v),
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(err("the scene's worker thread failed (a panic)"));
                }
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals() {
                        if let Some(c) = &cancel {
                            c.store(true, Ordering::Relaxed);
                        }
                        return Err(e);
                    }
                }
            }
        }
    }
}

pub(crate) fn node_ref(obj: &Bound<'_, PyAny>) -> PyResult<NodeRef> {
    if let Ok(i) = obj.extract::<u16>() {
        return Ok(NodeRef::Id(i));
    }
    if let Ok(s) = obj.extract::<String>() {
        return Ok(NodeRef::Label(s));
    }
    Err(err("node: expected an id (int) or a label (str)"))
}

/// One action (a dict) or a list of them.
pub(crate) fn actions_from(what: &Bound<'_, PyAny>) -> PyResult<Vec<Action>> {
    let v = from_py(what, "actions")?;
    match v {
        serde_json::Value::Array(_) => crate::from_value(v, "actions"),
        other => crate::from_value(other, "actions").map(|a| vec![a]),
    }
}

fn actions_of(session: &Session, edits: &[assist_core::Edit]) -> Vec<Action> {
    let mpu = session.description().meters_per_unit;
    edits.iter().map(|e| e.to_action(mpu)).collect()
}

#[pymethods]
impl Scene {
    /// Opens a `NAME.assist` scene with its history; its renders query the fields on
    /// `device` ("cpu", "gpu" or "auto", as `--device`; marching and compositing run on the
    /// CPU either way).
    #[staticmethod]
    #[pyo3(signature = (path, device="cpu"))]
    fn load(py: Python<'_>, path: PathBuf, device: &str) -> PyResult<Scene> {
        let backend = crate::device::open(py, device)?;
        let mut session = py.detach(|| Session::open(&path)).map_err(err)?;
        session.set_backend(crate::device::field_backend(&backend));
        Ok(Scene {
            session: Arc::new(Mutex::new(session)),
            gpu: backend,
        })
    }

    /// What queries the fields of this scene's renders: the GPU adapter's name, or "cpu".
    #[getter]
    fn device(&self, py: Python<'_>) -> PyResult<String> {
        Ok(self
            .lock(py)?
            .backend()
            .map_or_else(|| "cpu".to_string(), |b| b.name()))
    }

    /// The nodes: dicts with `id`, `label`, `class` (its semantic class: the label, or for
    /// a copy "mug 2" the original's "mug"), `half_size` (3,), `pose` (4×4 world-from-box,
    /// scale included), `background` (bool) and `embedding` (the node's CLIP embedding,
    /// float32, or None; `assist embed` makes them).
    #[getter]
    fn nodes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        for n in self.lock(py)?.nodes() {
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
    fn meters_per_unit(&self, py: Python<'_>) -> PyResult<f64> {
        Ok(self.lock(py)?.description().meters_per_unit)
    }

    /// Applies an instruction in words (`"move the mug 10 cm left"`) or a list of actions
    /// (`[{"instance_id": 3, "operation": "delete", "config": {}}]`) as one undo step;
    /// returns the resolved actions as dicts (world units). Raises `AssistError` naming the
    /// unknown object, the ambiguous candidates or the bad field.
    fn apply<'py>(&self, py: Python<'py>, what: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let text = what.extract::<String>().ok();
        let actions = match text {
            Some(_) => Vec::new(),
            None => actions_from(what)?,
        };
        let mut s = self.lock(py)?;
        let s = &mut *s;
        let actions = py
            .detach(|| {
                let edits = match &text {
                    Some(t) => s.apply_text(t, None)?,
                    None => s.apply(&actions)?,
                };
                Ok::<_, assist_session::SessionError>(actions_of(s, &edits))
            })
            .map_err(err)?;
        to_py(py, &actions)
    }

    /// What an instruction or actions would do, without applying them.
    /// Ctrl+C raises at once.
    fn plan<'py>(&self, py: Python<'py>, what: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let text = what.extract::<String>().ok();
        let actions = match text {
            Some(_) => Vec::new(),
            None => actions_from(what)?,
        };
        let planned = self.interruptible(py, None, move |s| {
            let edits = match &text {
                Some(t) => s.resolve(t, None).map(|r| r.edits)?,
                None => s.plan(&actions)?,
            };
            Ok::<_, assist_session::SessionError>(actions_of(s, &edits))
        })?;
        to_py(py, &planned.map_err(err)?)
    }

    /// Gives node `id` a new label as one undo step (its semantic class stays); a taken,
    /// empty or overlong label raises `AssistError`.
    fn rename(&self, py: Python<'_>, id: Whole, label: &str) -> PyResult<()> {
        let id = id.get("id")?;
        self.lock(py)?.rename(id, label).map_err(err)
    }

    /// Sets metres per world unit, one undo step: from `node` (an id or a name) being
    /// `height_m` metres tall along the scene's up (what its field occupies), or to
    /// `meters_per_unit`. A capture processed without `scale_by` is in COLMAP's arbitrary
    /// unit. Returns the new metres per unit.
    #[pyo3(signature = (node=None, height_m=None, meters_per_unit=None))]
    fn set_scale(
        &self,
        py: Python<'_>,
        node: Option<String>,
        height_m: Option<f64>,
        meters_per_unit: Option<f64>,
    ) -> PyResult<f64> {
        let target = match (node, height_m, meters_per_unit) {
            (Some(node), Some(meters), None) => {
                if !(meters.is_finite() && meters > 0.0) {
                    return Err(AssistError::new_err(format!(
                        "height_m: expected a positive number of metres, got {meters}"
                    )));
                }
                assist_session::ScaleTarget::Height { node, meters }
            }
            (None, None, Some(m)) => assist_session::ScaleTarget::MetersPerUnit(m),
            _ => {
                return Err(AssistError::new_err(
                    "give node and height_m, or meters_per_unit alone",
                ));
            }
        };
        let done = self.lock(py)?.scale_to(&target).map_err(err)?;
        Ok(done.meters_per_unit)
    }

    /// Undoes the last `apply`; False when there is nothing to undo.
    fn undo(&self, py: Python<'_>) -> PyResult<bool> {
        Ok(self.lock(py)?.undo())
    }

    /// Redoes the last undone `apply`; False when there is nothing to redo.
    fn redo(&self, py: Python<'_>) -> PyResult<bool> {
        Ok(self.lock(py)?.redo())
    }

    /// Selects (highlights) node `id`, or clears the selection with None.
    #[pyo3(signature = (id=None))]
    fn select(&self, py: Python<'_>, id: Option<Whole>) -> PyResult<()> {
        let id = whole_opt("id", id)?;
        self.lock(py)?.select(id).map_err(err)
    }

    /// The object seen at pixel `(x, y)` of `camera`, or None for the background.
    fn pick(&self, py: Python<'_>, camera: &Camera, x: f64, y: f64) -> PyResult<Option<u16>> {
        let c = camera.inner;
        self.interruptible(py, None, move |s| s.pick(&c, x, y))?
            .map_err(err)
    }

    /// Adds node `node` (id or label) of the scene at `scene_path`, its box centred at
    /// `position` (world units) or where it stands there; returns the resolved actions.
    #[pyo3(signature = (scene_path, node, position=None))]
    fn add_from<'py>(
        &self,
        py: Python<'py>,
        scene_path: PathBuf,
        node: &Bound<'py, PyAny>,
        position: Option<[f64; 3]>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let mut s = self.lock(py)?;
        let id = s.description().fresh_id();
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
        let edits = s.apply(&[a]).map_err(err)?;
        to_py(py, &actions_of(&s, &edits))
    }

    /// Saves scene, weights and history atomically (`force` to replace a scene assist
    /// wrote).
    #[pyo3(signature = (path, force=false))]
    fn save(&self, py: Python<'_>, path: PathBuf, force: bool) -> PyResult<()> {
        let s = self.lock(py)?;
        let s = &*s;
        py.detach(|| s.save(&path, force)).map_err(err)
    }

    /// Exports nodes as meshes or point clouds into the folder `out`, as `assist export`
    /// does (same defaults): `nodes` ids or names, `"all"` (every object) or
    /// `"background"`; `format` obj, ply, glb or points; `frame` world or node (default:
    /// world, node with `sim`); `sim` "mjcf" or "urdf" for a simulator model. Returns the
    /// summary: `out`, `model` and per node `id`, `label`, `file`, `vertices`,
    /// `triangles`, `closed`, `volume_m3`, `seconds`.
    #[pyo3(signature = (out, nodes=vec!["all".to_string()], format="obj", frame=None, resolution=Whole::of(assist_session::DEFAULT_RESOLUTION as i64), density=assist_session::DEFAULT_DENSITY, smooth=assist_session::DEFAULT_SMOOTH, triangles=Whole::of(assist_session::DEFAULT_MAX_TRIANGLES as i64), min_part=assist_session::DEFAULT_MIN_PART, points=Whole::of(assist_session::DEFAULT_POINTS as i64), close=Whole::of(assist_session::DEFAULT_CLOSE as i64), opacity=assist_session::DEFAULT_OPACITY, sim=None, material_density=assist_session::DEFAULT_MATERIAL_DENSITY, force=false))]
    fn export<'py>(
        &self,
        py: Python<'py>,
        out: PathBuf,
        nodes: Vec<String>,
        format: &str,
        frame: Option<&str>,
        resolution: Whole,
        density: f32,
        smooth: f32,
        triangles: Whole,
        min_part: f64,
        points: Whole,
        close: Whole,
        opacity: f32,
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
                resolution: resolution.get("resolution")?,
                density,
                min_part,
                smooth,
                max_triangles: triangles.get("triangles")?,
                close: close.get("close")?,
                opacity,
            },
            points: points.get("points")?,
            material_density,
            out,
            force,
        };
        let mut s = self.lock(py)?;
        let s = &mut *s;
        let done = py.detach(|| s.export(&job, |_, _, _| {})).map_err(err)?;
        to_py(py, &done)
    }

    /// Renders `camera`: a dict with any of `rgb` (H×W×3 float32 in [0, 1]), `depth`
    /// (H×W float32 z-depth in metres, 0 where nothing is hit), `instance` (H×W uint16,
    /// 0 = background), `opacity` (H×W float32) and `unseen` (H×W bool: no ray met a
    /// sample, its colour and depth continued from the seen pixels around it).
    /// `width`/`height` rescale the camera.
    /// The selected node, if any, is highlighted as `assist render` does.
    #[pyo3(signature = (camera, outputs=vec!["rgb".to_string(), "depth".to_string(), "instance".to_string()], width=None, height=None))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        camera: &Camera,
        outputs: Vec<String>,
        width: Option<Whole>,
        height: Option<Whole>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let width: Option<u32> = whole_opt("width", width)?;
        let height: Option<u32> = whole_opt("height", height)?;
        for (what, v) in [("width", width), ("height", height)] {
            if let Some(v) = v
                && !(1..=1 << 14).contains(&v)
            {
                return Err(err(format!("{what}: expected 1 to 16384 pixels, got {v}")));
            }
        }
        for o in &outputs {
            if !["rgb", "depth", "instance", "opacity", "unseen"].contains(&o.as_str()) {
                return Err(err(format!(
                    "outputs: unknown output {o:?}; expected rgb, depth, instance, opacity or unseen"
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
        let cancel = Arc::new(AtomicBool::new(false));
        let req = RenderRequest {
            size,
            highlight: true,
            cancel: Some(cancel.clone()),
            ..Default::default()
        };
        let c = camera.inner;
        let (frame, mpu) = self.interruptible(py, Some(cancel), move |s| {
            (s.render(&c, &req), s.description().meters_per_unit as f32)
        })?;
        let frame = frame.map_err(err)?;
        crate::device::report(py, &self.gpu)?;
        let (w, h) = (frame.width as usize, frame.height as usize);
        // The frame's buffers become the arrays (no copy).
        let assist_session::Frame {
            rgb,
            mut depth,
            opacity,
            panoptic,
            unseen,
            ..
        } = frame;
        let (mut rgb, mut depth_m, mut opacity, mut panoptic, mut unseen) = (
            Some(rgb),
            Some(&mut depth),
            Some(opacity),
            Some(panoptic),
            Some(unseen),
        );
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
                "unseen" => {
                    if let Some(v) = unseen.take() {
                        d.set_item("unseen", PyArray1::from_vec(py, v).reshape([h, w])?)?
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

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!("Scene({} nodes)", self.lock(py)?.nodes().len()))
    }
}
