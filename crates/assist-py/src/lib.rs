//! `import assist`: Python over the session layer — load a scene, edit it in words or
//! actions, undo and redo, pick, save, and render to numpy arrays (the GIL released while
//! rendering). Every library error becomes `assist.AssistError` with the library's message;
//! no panic crosses the boundary (pyo3 turns one into `PanicException`).

#![forbid(unsafe_code)]

use std::path::PathBuf;

use assist_core::{Camera as CoreCamera, DMat4, Intrinsics, Pose};
use assist_session::{Orbit, SplitChoice};
use numpy::{
    PyArray1, PyArrayMethods, PyReadonlyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

mod args;
mod clip;
mod device;
mod jobs;
mod scene;
mod shards;

use args::{Whole, whole_opt};
use clip::Clip;
use jobs::{Samples, generate, process, split, train};
use scene::Scene;

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

/// Python objects → a JSON value; `what` names the argument in errors (see [`args::to_json`]).
fn from_py(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<serde_json::Value> {
    args::to_json(obj, what)
}

/// A JSON value (from Python's arguments) → `T`; an error names `what` and the place in it
/// that does not fit (`train options: reflect: expected "on", …`, `actions: [1].node: …`).
fn from_value<T: serde::de::DeserializeOwned>(v: serde_json::Value, what: &str) -> PyResult<T> {
    serde_path_to_error::deserialize(v).map_err(|e| {
        // The whole value's path is "."; a part's is named before what it lacks.
        let at = match e.path().to_string() {
            p if p == "." => String::new(),
            p => format!("{p}: "),
        };
        err(format!("{what}: {at}{}", e.inner()))
    })
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
        width: Whole,
        height: Whole,
        name: String,
    ) -> PyResult<Self> {
        let (width, height) = (width.get("width")?, height.get("height")?);
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

/// `frames` cameras on a circle around `scene`'s objects, looking at their centre.
#[pyfunction]
#[pyo3(signature = (scene, frames=Whole::of(24), width=Whole::of(480), height=Whole::of(360), fov=50.0, elevation=30.0, radius=None))]
fn orbit(
    py: Python<'_>,
    scene: &Scene,
    frames: Whole,
    width: Whole,
    height: Whole,
    fov: f64,
    elevation: f64,
    radius: Option<f64>,
) -> PyResult<Vec<Camera>> {
    let o = Orbit {
        frames: frames.get("frames")?,
        width: width.get("width")?,
        height: height.get("height")?,
        fov_deg: fov,
        elevation_deg: elevation,
        radius,
    };
    let cams = assist_session::orbit(scene.lock(py)?.description(), &o).map_err(err)?;
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

#[pymodule]
#[pyo3(name = "_assist")]
fn assist(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("AssistError", m.py().get_type::<AssistError>())?;
    m.add_class::<Scene>()?;
    m.add_class::<Camera>()?;
    m.add_class::<Dataset>()?;
    m.add_function(wrap_pyfunction!(orbit, m)?)?;
    m.add_function(wrap_pyfunction!(cameras, m)?)?;
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(train, m)?)?;
    m.add_function(wrap_pyfunction!(process, m)?)?;
    m.add_function(wrap_pyfunction!(split, m)?)?;
    m.add_function(wrap_pyfunction!(shards::generate_shard, m)?)?;
    m.add_function(wrap_pyfunction!(shards::merge, m)?)?;
    m.add_function(wrap_pyfunction!(shards::status, m)?)?;
    m.add_class::<Samples>()?;
    m.add_class::<Clip>()?;
    Ok(())
}
