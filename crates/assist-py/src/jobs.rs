//! The long jobs from Python: `assist.generate` (samples in memory, as an iterator) and
//! `assist.train` (events to a callback, Ctrl+C saves).

use super::*;

/// Samples of a generation spec, made on demand (`assist.generate`).
#[pyclass(module = "assist")]
pub(crate) struct Samples {
    generator: std::sync::Arc<assist_generate::Generator>,
    next: u64,
    end: u64,
    /// The GPU its renders query (`device=`), to warn when it failed part-way.
    gpu: Option<std::sync::Arc<assist_gpu::GpuBackend>>,
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
        crate::device::report(py, &self.gpu)?;
        let d = PyDict::new(py);
        d.set_item("index", s.index)?;
        d.set_item("actions", to_py(py, &s.actions)?)?;
        d.set_item("objects", to_py(py, &s.record["objects"])?)?;
        d.set_item("gave_up", to_py(py, &s.record["gave_up"])?)?;
        let views = PyList::empty(py);
        let mpu = s.writer.meters_per_unit as f32;
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
#[pyo3(signature = (spec, seed=None, count=None, start=Whole::of(0), device="cpu"))]
pub(crate) fn generate(
    py: Python<'_>,
    spec: &Bound<'_, PyAny>,
    seed: Option<Whole>,
    count: Option<Whole>,
    start: Whole,
    device: &str,
) -> PyResult<Samples> {
    let start: u64 = start.get("start")?;
    let gpu = crate::device::open(py, device)?;
    let spec = crate::shards::load_spec(spec, seed, count)?;
    let end = spec.count;
    let backend = crate::device::field_backend(&gpu);
    let g = py
        .detach(|| assist_generate::Generator::prepare_on(spec, backend, &mut ()))
        .map_err(err)?;
    Ok(Samples {
        generator: std::sync::Arc::new(g),
        next: start.min(end),
        end,
        gpu,
    })
}

/// Trains a scene on the dataset at `data` into `out` (`NAME.assist`), as `assist train`
/// does; `options` are `assist train`'s flags with `_` for `-` (`downscale=2`, `seed=1`,
/// `resume=True`, `force=True`, `shadows="off"`, `lambda_obj_share=0.0`, …). `callback`, if given, is called with every
/// event as a dict (`{"event": "step", "stats": {...}, "eta_seconds": ...}`, `loading`,
/// `saved`, …). `device` is where the fields' forward and backward passes and Adam run
/// ("cpu", "gpu" or "auto", as `--device`). Ctrl+C saves the scene, then raises
/// `KeyboardInterrupt`. Returns the
/// report: iterations, seconds, what stopped it (`stopped_by`), the last step's figures.
#[pyfunction]
#[pyo3(signature = (data, out, max_time=None, iters=None, callback=None, device="cpu", **options))]
pub(crate) fn train<'py>(
    py: Python<'py>,
    data: PathBuf,
    out: PathBuf,
    max_time: Option<f64>,
    iters: Option<Whole>,
    callback: Option<Py<PyAny>>,
    device: &str,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let mut cfg = match options {
        Some(o) => {
            let v = from_py(o.as_any(), "options")?;
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
            crate::from_value::<assist_session::TrainConfig>(v, "train options")?
        }
        None => assist_session::TrainConfig::default(),
    };
    cfg.data = data;
    cfg.out = out;
    if let Some(t) = max_time {
        cfg.max_time = Some(t);
    }
    if let Some(n) = whole_opt::<usize>("iters", iters)? {
        cfg.iters = Some(n);
    }
    let mut job = assist_session::TrainJob::new(cfg);
    job.validate().map_err(err)?;
    if let Some(f) = crate::device::optimizers(&crate::device::open(py, device)?) {
        job = job.with_optimizers(f);
    }
    let cancel = job.cancel_handle();
    let mut relay = Relay::new(callback.as_ref(), &cancel);
    let outcome = py.detach(|| job.run(|e| relay.event(e)));
    relay.finish()?;
    let outcome = outcome.map_err(err)?;
    to_py(py, &outcome.report)
}

/// A long job's events relayed to a Python callback. Ctrl+C and a callback that raises
/// both stop the job (through `cancel`); the first of each error is kept, Ctrl+C's first.
struct Relay<'a> {
    callback: Option<&'a Py<PyAny>>,
    cancel: &'a std::sync::atomic::AtomicBool,
    interrupted: Option<PyErr>,
    failed: Option<PyErr>,
}

impl<'a> Relay<'a> {
    fn new(callback: Option<&'a Py<PyAny>>, cancel: &'a std::sync::atomic::AtomicBool) -> Self {
        Relay {
            callback,
            cancel,
            interrupted: None,
            failed: None,
        }
    }

    fn event(&mut self, e: &impl serde::Serialize) {
        Python::attach(|py| {
            if self.interrupted.is_none()
                && let Err(e) = py.check_signals()
            {
                self.cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                self.interrupted = Some(e);
            }
            if let (Some(cb), None) = (self.callback, &self.failed) {
                let r = to_py(py, e).and_then(|ev| cb.call1(py, (ev,)));
                if let Err(e) = r {
                    self.cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                    self.failed = Some(e);
                }
            }
        })
    }

    fn finish(self) -> PyResult<()> {
        match self.interrupted.or(self.failed) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// `assist.process`: a video or a folder of photographs → a posed dataset (ffmpeg,
/// COLMAP), as `assist process` does; `callback` gets each event (a dict with `kind`
/// "stage" or "progress"); Ctrl+C stops the running program and writes nothing.
#[pyfunction]
#[pyo3(signature = (input, out, frames=Whole::of(assist_session::process::DEFAULT_FRAMES as i64), matcher=None, cameras=None, scale_by=None, force=false, callback=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn process<'py>(
    py: Python<'py>,
    input: PathBuf,
    out: PathBuf,
    frames: Whole,
    matcher: Option<&str>,
    cameras: Option<&str>,
    scale_by: Option<&str>,
    force: bool,
    callback: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    use assist_session::process::{Cameras, Matcher, ProcessJob, ScaleBy};
    let cameras = match cameras {
        None => Cameras::default(),
        Some(c) => serde_json::from_value(serde_json::Value::from(c))
            .map_err(|e| err(format!("cameras: {e}")))?,
    };
    let matcher = match matcher {
        None | Some("auto") => None,
        Some("sequential") => Some(Matcher::Sequential),
        Some("exhaustive") => Some(Matcher::Exhaustive),
        Some(m) => {
            return Err(err(format!(
                "matcher: expected auto, sequential or exhaustive, got {m:?}"
            )));
        }
    };
    let scale_by = scale_by
        .map(|s| {
            s.parse::<ScaleBy>()
                .map_err(|e| err(format!("scale_by: {e}")))
        })
        .transpose()?;
    let job = ProcessJob {
        input,
        out,
        frames: frames.get("frames")?,
        matcher,
        cameras,
        scale_by,
        force,
        cancel: Default::default(),
    };
    let cancel = job.cancel.clone();
    let mut relay = Relay::new(callback.as_ref(), &cancel);
    let outcome = py.detach(|| job.run(&mut |e| relay.event(e)));
    relay.finish()?;
    let summary = outcome.map_err(err)?;
    to_py(py, &summary)
}

/// `assist.split`: object nodes cut out of a scene trained without masks, from boxes
/// (`"cx,cy,cz,sx,sy,sz[,yaw]"`) or clicks (`"VIEW:u,v"`), as `assist scene split` does;
/// `callback` gets each event (a dict with `kind`: "clicked", "masks", "distilled",
/// "step"); returns the objects made (id, label, box), the masks' summary and the
/// held-out figure of the fine-tune.
#[pyfunction]
#[pyo3(signature = (scene, out, boxes=Vec::new(), clicks=Vec::new(), labels=Vec::new(), iters=None, max_time=None, data=None, masks_out=None, no_train=false, force=false, sam=None, callback=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn split<'py>(
    py: Python<'py>,
    scene: PathBuf,
    out: PathBuf,
    boxes: Vec<String>,
    clicks: Vec<String>,
    labels: Vec<String>,
    iters: Option<Whole>,
    max_time: Option<f64>,
    data: Option<PathBuf>,
    masks_out: Option<PathBuf>,
    no_train: bool,
    force: bool,
    sam: Option<PathBuf>,
    callback: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    use assist_session::split::targets::Objects;
    use assist_session::split::{MaskProgress, SplitConfig, SplitEvent, SplitJob};
    if let Some(t) = max_time
        && !(t.is_finite() && t > 0.0)
    {
        return Err(err(format!("max_time: expected seconds above 0, got {t}")));
    }
    let objects = Objects {
        boxes,
        clicks,
        labels,
        sam,
        ..Objects::default()
    };
    let mut config = SplitConfig::new(scene, out, objects);
    config.iters = whole_opt::<usize>("iters", iters)?;
    config.max_time = max_time;
    config.data = data;
    config.masks_out = masks_out;
    config.no_train = no_train;
    config.force = force;
    let job = SplitJob::new(config);
    let cancel = job.cancel_handle();
    let mut relay = Relay::new(callback.as_ref(), &cancel);
    let outcome = py.detach(|| {
        job.run(|e| {
            let v = match e {
                SplitEvent::Clicked { click, obb } => serde_json::json!({
                    "kind": "clicked", "click": click,
                    "center": obb.center.to_array(), "size": obb.size().to_array(),
                }),
                SplitEvent::Masks(MaskProgress::Rendering { done, total })
                | SplitEvent::Masks(MaskProgress::Refining { done, total }) => {
                    serde_json::json!({"kind": "masks", "done": done, "total": total})
                }
                SplitEvent::Distilled { id, label, report } => serde_json::json!({
                    "kind": "distilled", "id": id, "label": label, "report": report,
                }),
                SplitEvent::Cleared(report) => serde_json::json!({
                    "kind": "cleared", "report": report,
                }),
                SplitEvent::Train(assist_session::TrainEvent::Step { stats, .. }) => {
                    serde_json::json!({"kind": "step", "iteration": stats.iteration, "psnr": stats.psnr})
                }
                _ => return,
            };
            relay.event(&v);
        })
    });
    relay.finish()?;
    let outcome = outcome.map_err(err)?;
    let summary = serde_json::json!({
        "out": outcome.out,
        "objects": outcome.objects.iter().map(|b| serde_json::json!({
            "id": b.id, "label": b.label,
            "center": b.obb.center.to_array(), "size": b.obb.size().to_array(),
        })).collect::<Vec<_>>(),
        "masks": outcome.masks,
        "held_out": outcome.trained.as_ref().and_then(|t| t.held_out.as_ref()),
    });
    to_py(py, &summary)
}
