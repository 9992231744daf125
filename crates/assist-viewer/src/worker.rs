//! One client's worker: a thread that owns the client's [`Session`], applies its messages
//! in order and renders. Views are coalesced (only the newest is rendered); after any
//! change a low-resolution preview goes out at once, and the full frame follows only if no
//! new message arrived meanwhile.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::Instant;

use assist_core::{
    Action, ActionConfig, AxisSpec, Camera, DVec3, InstanceId, Operation, SceneNode,
};
use assist_data::visual::{depth_image, ids_image};
use assist_data::{DatasetWriter, Output as WriterOutput, ViewImages};
use assist_session::{DragCache, RenderRequest, Session, Steps};

use crate::protocol::{ClientMsg, DragOp, DragPhase, NodeState, Output, ServerMsg, View};

/// What the worker sends back: a JSON message, or a frame's JPEG bytes.
#[derive(Debug)]
pub enum Outgoing {
    Json(ServerMsg),
    Jpeg(Vec<u8>),
}

/// Preview frames have this fraction of the full frame's width and height.
pub const PREVIEW_DIVISOR: u32 = 4;

/// JPEG quality of the frames.
const JPEG_QUALITY: u8 = 85;

/// The state of a drag in progress: the undo depth before it began, and whether a preview
/// edit is applied.
struct Drag {
    applied: bool,
}

/// The scenes a client may take nodes from: those named on the command line (by file
/// name) and any under one folder (relative paths without `..`).
#[derive(Debug, Clone, Default)]
pub struct OtherScenes {
    pub named: Vec<PathBuf>,
    pub folder: Option<PathBuf>,
}

impl OtherScenes {
    /// The path a client's scene name stands for.
    pub fn resolve(&self, name: &str) -> Result<PathBuf, String> {
        if let Some(p) = self
            .named
            .iter()
            .find(|p| p.file_name().is_some_and(|f| f.to_string_lossy() == name))
        {
            return Ok(p.clone());
        }
        let Some(dir) = &self.folder else {
            return Err(format!(
                "scene {name:?} is not one of the scenes this viewer was given ({}); name other scenes on the command line or give --scenes DIR",
                self.names().join(", ")
            ));
        };
        let rel = Path::new(name);
        let plain = !name.is_empty()
            && rel
                .components()
                .all(|c| matches!(c, std::path::Component::Normal(_)));
        if !plain {
            return Err(format!(
                "scene {name:?}: expected a path inside the scenes folder (no .., no absolute path)"
            ));
        }
        let p = dir.join(rel);
        if !p.join("scene.json").is_file() {
            return Err(format!("scene {name:?}: no scene.json in {}", p.display()));
        }
        Ok(p)
    }

    pub fn names(&self) -> Vec<String> {
        self.named
            .iter()
            .filter_map(|p| p.file_name().map(|f| f.to_string_lossy().into_owned()))
            .collect()
    }
}

pub struct Worker {
    others: OtherScenes,
    session: Session,
    /// Where `save` without a path writes.
    scene_path: PathBuf,
    view: Option<View>,
    output: Output,
    seq: u64,
    drag: Option<Drag>,
    /// What a drag's frames keep between updates (the camera and the other nodes stay).
    cache: DragCache,
    log: Vec<String>,
    /// Nodes this client hides (frames and clicks do not see them).
    hidden: std::collections::BTreeSet<InstanceId>,
    /// The opened scene's `scene.json` as this worker last read or wrote it: a save over
    /// the scene is refused when another process changed it since.
    disk: Option<u64>,
}

/// A digest of a scene's `scene.json` (`None` when it cannot be read).
pub fn disk_stamp(scene: &Path) -> Option<u64> {
    use std::hash::{Hash, Hasher};
    let bytes = std::fs::read(scene.join("scene.json")).ok()?;
    let mut h = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut h);
    Some(h.finish())
}

impl Worker {
    pub fn new(session: Session, scene_path: &Path, others: OtherScenes) -> Self {
        Worker {
            others,
            session,
            scene_path: scene_path.to_path_buf(),
            view: None,
            output: Output::Rgb,
            seq: 0,
            drag: None,
            cache: DragCache::default(),
            log: Vec::new(),
            hidden: Default::default(),
            disk: None,
        }
    }

    /// Handles messages until the channel closes; `send` returns false when the client is
    /// gone.
    pub fn run(mut self, rx: Receiver<ClientMsg>, send: impl Fn(Outgoing) -> bool) {
        let mut pending: VecDeque<ClientMsg> = VecDeque::new();
        if !send(Outgoing::Json(self.state())) {
            return;
        }
        loop {
            if pending.is_empty() {
                match rx.recv() {
                    Ok(m) => pending.push_back(m),
                    Err(_) => return,
                }
            }
            loop {
                match rx.try_recv() {
                    Ok(m) => pending.push_back(m),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => return,
                }
            }
            let mut dirty = false;
            let mut state = false;
            while let Some(m) = pending.pop_front() {
                let (d, s) = self.handle(m, &send);
                dirty |= d;
                state |= s;
            }
            if state && !send(Outgoing::Json(self.state())) {
                return;
            }
            if !dirty {
                continue;
            }
            // While a node is dragged, full frames come from the drag cache at once.
            if self.drag.is_some() {
                if !self.frame(false, &send) {
                    return;
                }
                continue;
            }
            self.cache.clear();
            if !self.frame(true, &send) {
                return;
            }
            // Full resolution only if nothing newer is waiting.
            match rx.try_recv() {
                Ok(m) => {
                    pending.push_back(m);
                    continue;
                }
                Err(TryRecvError::Disconnected) => return,
                Err(TryRecvError::Empty) => {}
            }
            if !self.frame(false, &send) {
                return;
            }
        }
    }

    fn error(&self, send: &impl Fn(Outgoing) -> bool, message: impl Into<String>) {
        send(Outgoing::Json(ServerMsg::Error {
            message: message.into(),
        }));
    }

    /// Applies one message; returns (the frame changed, the scene state changed).
    fn handle(&mut self, m: ClientMsg, send: &impl Fn(Outgoing) -> bool) -> (bool, bool) {
        let r: Result<(bool, bool), String> = match m {
            ClientMsg::View { view } => {
                self.view = Some(view);
                Ok((true, false))
            }
            ClientMsg::Output { output } => {
                self.output = output;
                Ok((true, false))
            }
            ClientMsg::Click { x, y } => self.click(x, y),
            ClientMsg::Select { id } => self
                .session
                .select(id)
                .map(|_| (true, true))
                .map_err(|e| e.to_string()),
            ClientMsg::Delete => self.on_selected(Operation::Delete, ActionConfig::default()),
            ClientMsg::Replicate => self.on_selected(Operation::Replicate, ActionConfig::default()),
            ClientMsg::Drag {
                op,
                axis,
                amount,
                dx,
                dy,
                phase,
            } => self.drag(op, &axis, amount, (dx, dy), phase),
            ClientMsg::Text { text, dry_run } => self.text(&text, dry_run, send),
            ClientMsg::Actions { actions } => self
                .session
                .apply_with(&actions, Steps::One)
                .map(|edits| {
                    self.log.push(format!("{} action(s) applied", edits.len()));
                    (true, true)
                })
                .map_err(|e| e.to_string()),
            ClientMsg::Open { scene } => self.open(&scene, send),
            ClientMsg::AddFrom { scene, node, x, y } => self.add_from(&scene, node, x, y),
            ClientMsg::SwapWith { scene, node } => self.swap_with(&scene, node),
            ClientMsg::Rename { id, label } => self
                .session
                .rename(id, &label)
                .map(|_| {
                    self.log.push(format!("node {id} renamed {label:?}"));
                    (false, true)
                })
                .map_err(|e| e.to_string()),
            ClientMsg::Hide { id, hidden } => {
                if self.session.node(id).is_none() {
                    Err(format!("hide: no node with id {id}"))
                } else {
                    if hidden {
                        self.hidden.insert(id);
                    } else {
                        self.hidden.remove(&id);
                    }
                    self.cache = DragCache::default();
                    Ok((true, true))
                }
            }
            ClientMsg::Undo => Ok(if self.session.undo() {
                self.log.push("undo".into());
                (true, true)
            } else {
                (false, false)
            }),
            ClientMsg::Redo => Ok(if self.session.redo() {
                self.log.push("redo".into());
                (true, true)
            } else {
                (false, false)
            }),
            ClientMsg::Save { path, force } => self.save(path.as_deref(), force, send),
            ClientMsg::SaveView => self.save_view(send),
        };
        r.unwrap_or_else(|message| {
            self.error(send, message);
            (false, false)
        })
    }

    fn open(
        &mut self,
        name: &str,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<(bool, bool), String> {
        let path = self.others.resolve(name)?;
        let other = Session::describe(&path).map_err(|e| e.to_string())?;
        send(Outgoing::Json(ServerMsg::Other {
            scene: name.to_string(),
            nodes: other.nodes.iter().map(node_state).collect(),
        }));
        Ok((false, false))
    }

    fn add_from(
        &mut self,
        name: &str,
        node: InstanceId,
        x: f64,
        y: f64,
    ) -> Result<(bool, bool), String> {
        let path = self.others.resolve(name)?;
        let cam = self.camera()?;
        let at = self
            .session
            .surface(&cam, x, y)
            .map_err(|e| e.to_string())?
            .ok_or("add: no surface under that pixel to put the node on")?;
        let other = Session::describe(&path).map_err(|e| e.to_string())?;
        let n = other
            .nodes
            .iter()
            .find(|n| n.id == node)
            .ok_or_else(|| format!("scene {name:?} has no node {node}"))?;
        // The node rests on the surface: its centre half its height above the point.
        let up = self.session.description().up.normalize();
        let scale = self.session.description().meters_per_unit / other.meters_per_unit;
        let half = (n.half_size * n.world_from_local.scale).z / scale.max(1e-12);
        let centre = at + up * half;
        let config = ActionConfig {
            scene: Some(path.display().to_string()),
            node: Some(assist_core::NodeRef::Id(node)),
            position: Some(centre.to_array()),
            unit: Some("units".into()),
            ..ActionConfig::default()
        };
        let edits = self
            .session
            .apply_with(&[Action::new(0, Operation::Add, config)], Steps::One)
            .map_err(|e| e.to_string())?;
        if let Some(assist_core::Edit::Add { imported }) = edits.first() {
            let id = imported.node.id;
            self.session.select(Some(id)).map_err(|e| e.to_string())?;
            self.log.push(format!("added object {id} from {name}"));
        }
        Ok((true, true))
    }

    fn swap_with(&mut self, name: &str, node: InstanceId) -> Result<(bool, bool), String> {
        let path = self.others.resolve(name)?;
        let config = ActionConfig {
            scene: Some(path.display().to_string()),
            with: Some(assist_core::NodeRef::Id(node)),
            ..ActionConfig::default()
        };
        self.on_selected(Operation::Swap, config)
    }

    fn camera(&self) -> Result<Camera, String> {
        self.view
            .as_ref()
            .ok_or_else(|| "no view yet: send a view message first".to_string())?
            .camera()
    }

    fn click(&mut self, x: f64, y: f64) -> Result<(bool, bool), String> {
        let cam = self.camera()?;
        let hidden: Vec<InstanceId> = self.hidden.iter().copied().collect();
        let id = if hidden.is_empty() {
            self.session.pick(&cam, x, y)
        } else {
            self.session.without(&hidden).pick(&cam, x, y)
        }
        .map_err(|e| e.to_string())?;
        self.session.select(id).map_err(|e| e.to_string())?;
        Ok((true, true))
    }

    fn selected(&self) -> Result<InstanceId, String> {
        self.session
            .description()
            .selected
            .ok_or_else(|| "no object selected: click one first".to_string())
    }

    fn on_selected(&mut self, op: Operation, config: ActionConfig) -> Result<(bool, bool), String> {
        let id = self.selected()?;
        let action = Action::new(id, op, config);
        self.session
            .apply_with(&[action], Steps::One)
            .map_err(|e| e.to_string())?;
        if op == Operation::Delete {
            self.session.select(None).map_err(|e| e.to_string())?;
        }
        self.log.push(format!("{} object {id}", op_name(op)));
        Ok((true, true))
    }

    /// A drag: each move undoes the previous preview and applies the new amount; commit
    /// keeps it as one undo step; cancel undoes it.
    fn drag(
        &mut self,
        op: DragOp,
        axis: &str,
        amount: f64,
        (dx, dy): (f64, f64),
        phase: DragPhase,
    ) -> Result<(bool, bool), String> {
        let id = self.selected()?;
        let applied = self.drag.as_ref().is_some_and(|d| d.applied);
        if applied {
            self.session.undo();
        }
        self.drag = None;
        if phase == DragPhase::Cancel {
            return Ok((true, true));
        }
        let config = self.drag_config(op, axis, amount, (dx, dy), id)?;
        let operation = match op {
            DragOp::Translate => Operation::Translate,
            DragOp::Rotate => Operation::Rotate,
            DragOp::Scale => Operation::Scale,
        };
        self.session
            .apply_with(&[Action::new(id, operation, config)], Steps::One)
            .map_err(|e| e.to_string())?;
        if phase == DragPhase::Commit {
            self.log.push(format!("{} object {id}", op_name(operation)));
        } else {
            self.drag = Some(Drag { applied: true });
        }
        Ok((true, phase == DragPhase::Commit))
    }

    fn drag_config(
        &self,
        op: DragOp,
        axis: &str,
        amount: f64,
        (dx, dy): (f64, f64),
        id: InstanceId,
    ) -> Result<ActionConfig, String> {
        let mut c = ActionConfig::default();
        if !(amount.is_finite() && dx.is_finite() && dy.is_finite()) {
            return Err("drag: expected finite amounts".into());
        }
        match (op, axis) {
            (DragOp::Translate, "view") => {
                // Pixels → world at the object's depth, in the image plane.
                let cam = self.camera()?;
                let node = self
                    .session
                    .node(id)
                    .ok_or_else(|| format!("no node {id}"))?;
                let centre = node.world_from_local.translation;
                let depth = (centre - cam.pose.center())
                    .dot(cam.pose.forward())
                    .max(1e-3);
                let m = cam.pose.to_matrix();
                let right = m.x_axis.truncate();
                let up = m.y_axis.truncate();
                let v: DVec3 = (right * dx - up * dy) * depth / cam.intrinsics.fx;
                c.vector = Some(v.to_array());
                c.unit = Some("units".into());
            }
            (_, "x" | "y" | "z" | "-x" | "-y" | "-z") => {
                c.axis = Some(AxisSpec::Name(axis.to_string()));
                match op {
                    DragOp::Translate => {
                        c.distance = Some(amount);
                        c.unit = Some("m".into());
                    }
                    DragOp::Rotate => c.degrees = Some(amount),
                    DragOp::Scale => c.factor = Some(amount),
                }
            }
            (DragOp::Scale, "all") => c.factor = Some(amount),
            _ => {
                return Err(format!(
                    "drag.axis: expected x, y, z, -x, -y, -z (or view for translate, all for scale), got {axis:?}"
                ));
            }
        }
        Ok(c)
    }

    fn text(
        &mut self,
        text: &str,
        dry_run: bool,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<(bool, bool), String> {
        let cam = self.camera().ok();
        let resolved = self
            .session
            .resolve(text, cam.as_ref())
            .map_err(|e| e.to_string())?;
        let actions = resolved
            .actions
            .iter()
            .map(|a| serde_json::to_value(a).unwrap_or(serde_json::Value::Null))
            .collect();
        if !dry_run {
            self.session
                .install(resolved, Steps::One, Some(text.to_string()))
                .map_err(|e| e.to_string())?;
            self.log.push(text.to_string());
        }
        send(Outgoing::Json(ServerMsg::Resolved {
            text: text.to_string(),
            actions,
            applied: !dry_run,
        }));
        Ok((!dry_run, !dry_run))
    }

    /// The stamp of the scene on disk when the session was read (see [`disk_stamp`]).
    pub fn with_disk_stamp(mut self, stamp: Option<u64>) -> Self {
        self.disk = stamp;
        self
    }

    fn save(
        &mut self,
        path: Option<&str>,
        force: bool,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<(bool, bool), String> {
        let target = match path {
            None => self.scene_path.clone(),
            Some(p) => {
                let ok = !p.is_empty()
                    && !p.contains(['/', '\\'])
                    && !p.starts_with('.')
                    && p.ends_with(".assist");
                if !ok {
                    return Err(format!(
                        "save.path: expected a NAME.assist beside the scene (no folders), got {p:?}"
                    ));
                }
                self.scene_path.parent().unwrap_or(Path::new(".")).join(p)
            }
        };
        // Saving over the opened scene is what "save" means; anything else needs force.
        let over_own = target == self.scene_path;
        let force = force || over_own;
        // Held across the check and the write, so no other process saves in between.
        let _lock = assist_fs::lock(&target, "assist view").map_err(|e| e.to_string())?;
        if over_own && disk_stamp(&target) != self.disk {
            return Err(format!(
                "save: {} was changed by another program since this viewer opened it; save under another name (save as) to keep both",
                target.display()
            ));
        }
        self.session
            .save(&target, force)
            .map_err(|e| e.to_string())?;
        if over_own {
            self.disk = disk_stamp(&target);
        }
        self.log.push(format!("saved {}", target.display()));
        send(Outgoing::Json(ServerMsg::Saved {
            path: target.display().to_string(),
        }));
        Ok((false, true))
    }

    /// Writes the current view through the dataset writer into `NAME-view-K/` beside the
    /// scene (the first K not taken).
    fn save_view(&mut self, send: &impl Fn(Outgoing) -> bool) -> Result<(bool, bool), String> {
        let cam = self.camera()?;
        let frame = self
            .session
            .render(&cam, &RenderRequest::default())
            .map_err(|e| e.to_string())?;
        let parent = self.scene_path.parent().unwrap_or(Path::new("."));
        let stem = self
            .scene_path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        let dir = (1..10_000)
            .map(|k| parent.join(format!("{stem}-view-{k}")))
            .find(|d| !d.exists())
            .ok_or("save view: no free folder name")?;
        let cfg = self.session.writer_config(vec![
            WriterOutput::Rgb,
            WriterOutput::Depth,
            WriterOutput::Panoptic,
        ]);
        let w = DatasetWriter::create(&dir, cfg, false).map_err(|e| e.to_string())?;
        let view = ViewImages {
            width: frame.width,
            height: frame.height,
            rgb: &frame.rgb,
            depth: &frame.depth,
            panoptic: &frame.panoptic,
            ..Default::default()
        };
        w.write(0, "view", &cam, &view).map_err(|e| e.to_string())?;
        w.finish().map_err(|e| e.to_string())?;
        self.log.push(format!("view saved in {}", dir.display()));
        send(Outgoing::Json(ServerMsg::Saved {
            path: dir.display().to_string(),
        }));
        Ok((false, true))
    }

    pub fn state(&self) -> ServerMsg {
        let d = self.session.description();
        ServerMsg::State {
            nodes: d.nodes.iter().map(node_state).collect(),
            selected: d.selected,
            hidden: self.hidden.iter().copied().collect(),
            undo: self.session.undo_steps(),
            redo: self.session.redo_steps(),
            log: self.log.iter().rev().take(50).rev().cloned().collect(),
        }
    }

    /// Renders the current view (a preview or the full frame) and sends it.
    fn frame(&mut self, preview: bool, send: &impl Fn(Outgoing) -> bool) -> bool {
        let Some(view) = self.view else {
            return true;
        };
        let cam = match view.camera() {
            Ok(c) => c,
            Err(e) => {
                self.error(send, e);
                return true;
            }
        };
        let size = if preview {
            Some((
                (view.width / PREVIEW_DIVISOR).max(1),
                (view.height / PREVIEW_DIVISOR).max(1),
            ))
        } else {
            None
        };
        let t = Instant::now();
        let alone = match self.output {
            Output::Selected => self.session.description().selected,
            Output::Background => self
                .session
                .nodes()
                .iter()
                .find(|n| n.is_background())
                .map(|n| n.id),
            _ => None,
        };
        let req = RenderRequest {
            size,
            highlight: alone.is_none(),
            layers: alone.is_some(),
            ..RenderRequest::default()
        };
        let hidden: Vec<InstanceId> = self.hidden.iter().copied().collect();
        let visible = (!hidden.is_empty()).then(|| self.session.without(&hidden));
        let session = visible.as_ref().unwrap_or(&self.session);
        let selected = session.description().selected;
        let rendered = match (&self.drag, selected) {
            (Some(_), Some(id)) if !preview => {
                session.render_moving(&cam, &req, id, &mut self.cache)
            }
            _ => session.render(&cam, &req),
        };
        let frame = match rendered {
            Ok(f) => f,
            Err(e) => {
                self.error(send, e.to_string());
                return true;
            }
        };
        let (w, h) = (frame.width, frame.height);
        let img = match self.output {
            Output::Rgb => frame.rgb,
            Output::Depth => depth_image(w, h, &frame.depth).data,
            Output::Panoptic => ids_image(w, h, &frame.panoptic).data,
            Output::Selected | Output::Background => {
                match frame.layers.iter().find(|l| Some(l.id) == alone) {
                    Some(l) => l.rgb.clone(),
                    None => vec![0.0; 3 * (w * h) as usize],
                }
            }
        };
        let jpeg = encode_jpeg(&img, w, h);
        self.seq += 1;
        send(Outgoing::Json(ServerMsg::Frame {
            seq: self.seq,
            width: w,
            height: h,
            output: self.output,
            preview,
            milliseconds: t.elapsed().as_secs_f64() * 1e3,
        })) && send(Outgoing::Jpeg(jpeg))
    }
}

fn op_name(op: Operation) -> &'static str {
    match op {
        Operation::Select => "selected",
        Operation::Translate => "moved",
        Operation::Rotate => "rotated",
        Operation::Scale => "scaled",
        Operation::Replicate => "duplicated",
        Operation::Delete => "deleted",
        Operation::Add => "added",
        Operation::Swap => "swapped",
    }
}

pub fn node_state(n: &SceneNode) -> NodeState {
    NodeState {
        id: n.id,
        label: n.label.clone(),
        background: n.is_background(),
        color: assist_data::visual::id_color(n.id).map(|c| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8),
        corners: n.world_corners().iter().map(|c| c.to_array()).collect(),
    }
}

/// RGB floats in [0, 1] → a baseline JPEG.
pub fn encode_jpeg(rgb: &[f32], w: u32, h: u32) -> Vec<u8> {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
        .collect();
    let mut out = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY);
    // Sizes are bounded by the protocol and the buffer matches them, so this cannot fail.
    let _ = image::ImageEncoder::write_image(enc, &bytes, w, h, image::ExtendedColorType::Rgb8);
    out
}
