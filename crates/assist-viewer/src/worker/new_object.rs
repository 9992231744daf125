//! New-object mode: a click on an object the scene still holds in its background proposes
//! a box (the session's click finder) and shows the pixels it would own; the page may
//! reshape the box; confirming runs `assist scene split` on this client's session (masks,
//! the node's field from the background's, a short fine-tune), writes the scene beside
//! the one opened and opens it.

use base64::Engine;

use super::*;
use assist_session::split::click::{self, ClickOptions};
use assist_session::split::targets::{Objects, upright};
use assist_session::split::{SplitConfig, SplitEvent, SplitJob};

/// The yaw about `up` (degrees) of a box standing along it.
fn yaw_of(obb: &Obb, up: DVec3) -> f64 {
    let reference = upright(up, 0.0).col(0);
    let x = obb.rotation.col(0);
    let up = up.normalize();
    up.dot(reference.cross(x))
        .atan2(reference.dot(x))
        .to_degrees()
}

/// A mask as a PNG data URL: `rgba` where set, transparent elsewhere.
fn mask_png(w: usize, h: usize, mask: &[bool], rgba: [u8; 4]) -> Result<String, String> {
    let mut px = vec![0u8; 4 * w * h];
    for (p, &m) in px.chunks_exact_mut(4).zip(mask) {
        if m {
            p.copy_from_slice(&rgba);
        }
    }
    let img = image::RgbaImage::from_raw(w as u32, h as u32, px).ok_or("mask: bad size")?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| format!("mask: {e}"))?;
    Ok(format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes.into_inner())
    ))
}

impl Worker {
    /// The dataset the scene was trained on (the viewer's `--data`, else the scene's
    /// record of it).
    fn dataset_path(&self) -> Result<PathBuf, String> {
        self.data
            .clone()
            .or_else(|| {
                self.session
                    .info()
                    .get("dataset")
                    .and_then(|d| d.as_str())
                    .map(PathBuf::from)
            })
            .ok_or_else(|| {
                "new object: the scene does not record its dataset; start the viewer with --data DATA".to_string()
            })
    }

    /// Sends the proposal of box `obb`: its numbers, corners and mask in the current view.
    fn send_proposal(&self, obb: &Obb, send: &impl Fn(Outgoing) -> bool) -> Result<(), Refused> {
        let cam = self.camera()?;
        let size = ((cam.width() / 2).max(1), (cam.height() / 2).max(1));
        let (w, h, mask) = self
            .session
            .box_mask_in_view(&cam, obb, Some(size))
            .map_err(Refused::from)?;
        let up = self.session.description().up;
        let node = SceneNode::from_obb(0, "", "", obb);
        send(Outgoing::Json(ServerMsg::Proposal {
            center: obb.center.to_array(),
            size: obb.size().to_array(),
            yaw: yaw_of(obb, up),
            corners: node.world_corners().iter().map(|c| c.to_array()).collect(),
            mask: mask_png(w, h, &mask, [255, 0, 200, 110])?,
            pixels: mask.iter().filter(|&&m| m).count(),
        }));
        Ok(())
    }

    pub(super) fn propose(
        &mut self,
        x: f64,
        y: f64,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let cam = self.camera()?;
        let data = self.dataset_path()?;
        let ds = assist_data::load(&data, &Default::default())?;
        let cameras: Vec<Camera> = ds
            .frames
            .iter()
            .filter(|f| f.split == assist_data::Split::Train)
            .map(|f| f.camera)
            .collect();
        let hidden: Vec<InstanceId> = self.hidden.iter().copied().collect();
        let seen = self.session.without(&hidden);
        let obb = click::box_at_click(&seen, &cam, (x, y), &cameras, &ClickOptions::default())
            .map_err(Refused::from)?;
        self.send_proposal(&obb, send)?;
        Ok(Changed::NOTHING)
    }

    pub(super) fn reshape(
        &mut self,
        center: [f64; 3],
        size: [f64; 3],
        yaw: f64,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let up = self.session.description().up;
        let obb = Obb::new(
            DVec3::from(center),
            DVec3::from(size),
            upright(up, yaw.to_radians()),
        );
        self.send_proposal(&obb, send)?;
        Ok(Changed::NOTHING)
    }

    /// Splits the object off (see the module's note) and opens the scene written.
    pub(super) fn make_object(
        &mut self,
        (center, size, yaw): ([f64; 3], [f64; 3], f64),
        label: &str,
        iters: usize,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let data = self.dataset_path()?;
        let out = free_name_beside(&self.scene_path, "objects");
        let b = format!(
            "{},{},{},{},{},{},{}",
            center[0], center[1], center[2], size[0], size[1], size[2], yaw
        );
        let objects = Objects {
            boxes: vec![b],
            labels: vec![label.trim().to_string()],
            ..Objects::default()
        };
        let mut config = SplitConfig::new(self.scene_path.clone(), out.clone(), objects);
        config.data = Some(data);
        config.iters = Some(iters);
        let job = SplitJob::new(config).with_cancel(self.stop.clone());
        let progress = |task: &str, done: f64| {
            send(Outgoing::Json(ServerMsg::Progress {
                task: task.to_string(),
                done,
            }));
        };
        let outcome = job.run_on(&self.session, |e| match e {
            SplitEvent::Masks(assist_session::split::MaskProgress::Rendering { done, total }) => {
                progress("rendering views", done as f64 / total.max(1) as f64)
            }
            SplitEvent::Masks(assist_session::split::MaskProgress::Refining { done, total }) => {
                progress("masks", done as f64 / total.max(1) as f64)
            }
            SplitEvent::Distilled { .. } => progress("field from the background", 1.0),
            SplitEvent::Cleared(_) => progress("background emptied in the object", 1.0),
            SplitEvent::Train(assist_session::TrainEvent::Step { stats, .. }) => {
                progress("fine-tune", stats.progress)
            }
            _ => {}
        });
        self.stop.store(false, std::sync::atomic::Ordering::SeqCst);
        let outcome = match outcome {
            Err(assist_session::SessionError::Cancelled) => {
                return Err("new object: stopped before its fine-tune; nothing was written".into());
            }
            r => r.map_err(Refused::from)?,
        };
        let backend = self.session.backend().cloned();
        self.session = Session::open(&out).map_err(Refused::from)?;
        self.session.set_backend(backend);
        self.scene_path = out.clone();
        self.disk = disk_stamp(&out);
        self.cache.clear();
        let id = outcome.objects.first().map(|b| b.id);
        self.session.select(id).map_err(Refused::from)?;
        let stopped = match &outcome.trained {
            Some(t) if t.report.cancelled => {
                format!(" (fine-tune stopped after {} steps)", t.report.iterations)
            }
            _ => String::new(),
        };
        self.log.push(format!(
            "new object {} {:?}: scene written to {}{stopped}",
            id.unwrap_or(0),
            label.trim(),
            out.display()
        ));
        send(Outgoing::Json(ServerMsg::Saved {
            path: out.display().to_string(),
        }));
        Ok(Changed::ALL)
    }
}

/// `NAME-WHAT.assist` beside `scene` (`NAME-WHAT-2.assist`, … when taken).
fn free_name_beside(scene: &Path, what: &str) -> PathBuf {
    let stem = scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let stem = stem
        .split(&format!("-{what}"))
        .next()
        .unwrap_or(&stem)
        .to_string();
    let parent = scene.parent().unwrap_or(Path::new("."));
    (1..)
        .map(|k| match k {
            1 => parent.join(format!("{stem}-{what}.assist")),
            k => parent.join(format!("{stem}-{what}-{k}.assist")),
        })
        .find(|p| !p.exists())
        .unwrap_or_else(|| parent.join(format!("{stem}-{what}.assist")))
}
