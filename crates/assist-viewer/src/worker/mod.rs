//! One client's worker: a thread that owns the client's [`Session`], applies its messages
//! in order and renders. Views are coalesced (only the newest is rendered); after any
//! change a low-resolution preview goes out at once, and the full frame follows only if no
//! new message arrived meanwhile.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::Instant;

use assist_core::{
    Action, ActionConfig, AxisSpec, Camera, DVec3, InstanceId, Obb, Operation, SceneNode,
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

mod handlers;
mod new_object;

/// What a handled message changed: the frame (render again) and the scene's state (send
/// the client the node list and history again).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Changed {
    pub frame: bool,
    pub state: bool,
}

impl Changed {
    const NOTHING: Changed = Changed {
        frame: false,
        state: false,
    };
    const FRAME: Changed = Changed {
        frame: true,
        state: false,
    };
    const STATE: Changed = Changed {
        frame: false,
        state: true,
    };
    const ALL: Changed = Changed {
        frame: true,
        state: true,
    };
}

/// Why a message was not served; the client is sent its text.
#[derive(Debug, thiserror::Error)]
pub(crate) enum Refused {
    /// The session refused the request (a bad edit, a failed save, …).
    #[error(transparent)]
    Session(#[from] assist_session::SessionError),
    /// The message asks for something this client cannot have (no selection, no such
    /// scene, a name outside the scenes folder, …).
    #[error("{0}")]
    Request(String),
    /// The output folder may not be written (in use, not assist's, no space).
    #[error(transparent)]
    Output(#[from] assist_fs::FsError),
    /// Writing a saved view failed.
    #[error(transparent)]
    Write(#[from] assist_data::DataError),
}

impl From<String> for Refused {
    fn from(s: String) -> Self {
        Refused::Request(s)
    }
}

impl From<&str> for Refused {
    fn from(s: &str) -> Self {
        Refused::Request(s.to_string())
    }
}

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
        // A link inside the folder may point anywhere: the scene it names must lie inside.
        let inside = match (
            dir.canonicalize(),
            p.canonicalize(),
            p.join("scene.json").canonicalize(),
        ) {
            (Ok(d), Ok(q), Ok(f)) => q.starts_with(&d) && f.starts_with(&d),
            _ => false,
        };
        if !inside {
            return Err(format!(
                "scene {name:?}: it lies outside the scenes folder {} (through a link)",
                dir.display()
            ));
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
    /// Set when the client's socket closes: a frame in progress stops.
    gone: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// The dataset the viewer was given (`--data`), for new objects.
    data: Option<PathBuf>,
    /// Set by the socket when the client sends `stop` (or leaves): a split under way
    /// stops. Cleared when the split ends and when the worker reads the `stop` itself.
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
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
            gone: None,
            data: None,
            stop: Default::default(),
        }
    }

    /// Handles messages until the channel closes; `send` returns false when the client is
    /// gone.
    pub fn run(mut self, rx: Receiver<ClientMsg>, send: impl Fn(Outgoing) -> bool) {
        let mut pending: VecDeque<ClientMsg> = VecDeque::new();
        if !send(Outgoing::Json(self.state())) {
            return;
        }
        // A preview went out and its full frame has not: owed even when the messages that
        // came in between changed nothing the frame shows (the page had been left on a
        // preview when one such arrived between the two).
        let mut owed = false;
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
                let changed = self.handle(m, &send);
                dirty |= changed.frame;
                state |= changed.state;
            }
            if state && !send(Outgoing::Json(self.state())) {
                return;
            }
            if !dirty && !owed {
                continue;
            }
            // While a node is dragged, full frames come from the drag cache at once.
            if self.drag.is_some() {
                owed = false;
                if !self.frame(false, &send) {
                    return;
                }
                continue;
            }
            if dirty {
                self.cache.clear();
                if !self.frame(true, &send) {
                    return;
                }
                owed = true;
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
            owed = false;
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

    /// Applies one message; returns what it changed (a refusal is sent to the client).
    fn handle(&mut self, m: ClientMsg, send: &impl Fn(Outgoing) -> bool) -> Changed {
        let r: Result<Changed, Refused> = match m {
            ClientMsg::View { view } => {
                self.view = Some(view);
                Ok(Changed::FRAME)
            }
            ClientMsg::Output { output } => {
                self.output = output;
                Ok(Changed::FRAME)
            }
            ClientMsg::Click { x, y } => self.click(x, y),
            ClientMsg::Select { id } => self
                .session
                .select(id)
                .map(|_| Changed::ALL)
                .map_err(Refused::from),
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
                    Changed::ALL
                })
                .map_err(Refused::from),
            ClientMsg::Open { scene } => self.open(&scene, send),
            ClientMsg::AddFrom { scene, node, x, y } => self.add_from(&scene, node, x, y),
            ClientMsg::SwapWith { scene, node } => self.swap_with(&scene, node),
            ClientMsg::Rename { id, label } => self
                .session
                .rename(id, &label)
                .map(|_| {
                    self.log.push(format!("node {id} renamed {label:?}"));
                    Changed::STATE
                })
                .map_err(Refused::from),
            ClientMsg::Hide { id, hidden } => {
                if self.session.node(id).is_none() {
                    Err(format!("hide: no node with id {id}").into())
                } else {
                    if hidden {
                        self.hidden.insert(id);
                    } else {
                        self.hidden.remove(&id);
                    }
                    self.cache = DragCache::default();
                    Ok(Changed::ALL)
                }
            }
            ClientMsg::Propose { x, y } => self.propose(x, y, send),
            ClientMsg::Reshape { center, size, yaw } => self.reshape(center, size, yaw, send),
            ClientMsg::MakeObject {
                center,
                size,
                yaw,
                label,
                iters,
            } => self.make_object((center, size, yaw), &label, iters, send),
            ClientMsg::Stop => {
                // Read after the split it stopped (or with none under way): cleared so
                // that the next split starts.
                self.stop.store(false, std::sync::atomic::Ordering::SeqCst);
                Ok(Changed::NOTHING)
            }
            ClientMsg::Undo => Ok(if self.session.undo() {
                self.log.push("undo".into());
                Changed::ALL
            } else {
                Changed::NOTHING
            }),
            ClientMsg::Redo => Ok(if self.session.redo() {
                self.log.push("redo".into());
                Changed::ALL
            } else {
                Changed::NOTHING
            }),
            ClientMsg::Save { path, force } => self.save(path.as_deref(), force, send),
            ClientMsg::SaveView => self.save_view(send),
        };
        r.unwrap_or_else(|e| {
            self.error(send, e.to_string());
            Changed::NOTHING
        })
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
            cancel: self.gone.clone(),
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
    // jpeg-encoder (SIMD where the CPU has it) rather than `image`'s encoder: the same
    // quality at full chroma resolution, faster, and a drag sends a frame per update.
    let mut enc = jpeg_encoder::Encoder::new(&mut out, JPEG_QUALITY);
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_4_4);
    // Sizes are bounded by the protocol (well under 65,536) and the buffer matches them,
    // so this cannot fail.
    let _ = enc.encode(
        &bytes,
        w.min(u16::MAX as u32) as u16,
        h.min(u16::MAX as u32) as u16,
        jpeg_encoder::ColorType::Rgb,
    );
    out
}
