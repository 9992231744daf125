//! `assist.Scene`: a session in Python — load, list nodes, apply words or actions, plan,
//! undo and redo, pick, add from another scene, save, export and render to numpy.

use super::*;
use assist_core::action::NodeRef;
use assist_core::{Action, ActionConfig, Operation};
use assist_session::{RenderRequest, Session};

/// A trained scene in memory: nodes, edits with undo and redo, rendering.
#[pyclass(module = "assist")]
pub(crate) struct Scene {
    pub(crate) session: Session,
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
