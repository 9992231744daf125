//! The viewer's messages, version 1. Every client message is one JSON text frame
//! `{"type": …, …}`; unknown types and unknown fields are refused, and every error is
//! answered with an `error` message while the session goes on. The server sends JSON
//! text frames and, after each `frame` message, one binary frame holding its JPEG.

use assist_core::{Action, Camera, DMat4, InstanceId, Intrinsics, Pose};
use serde::{Deserialize, Serialize};

/// Bumped when a message changes meaning.
pub const PROTOCOL_VERSION: u32 = 1;

/// Largest client message accepted, in bytes (an instruction or an action list fits with
/// room to spare; a larger message is answered with an error).
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;

/// Largest frame a client may ask for, each way.
pub const MAX_FRAME_SIDE: u32 = 2048;

/// A view as the page holds it: camera-to-world in the OpenGL convention (+x right, +y
/// up, looking −z), row-major, with a vertical field of view and the canvas size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    pub world_from_camera: [[f64; 4]; 4],
    pub fov_y_degrees: f64,
    pub width: u32,
    pub height: u32,
}

/// What the frame shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Output {
    #[default]
    Rgb,
    Depth,
    Panoptic,
    /// The selected node alone (its own colour over black).
    Selected,
    /// The background node alone.
    Background,
}

/// A drag's operation, in the paper's keys: `t`, `r`, `x`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DragOp {
    Translate,
    Rotate,
    Scale,
}

/// Where a drag is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DragPhase {
    /// The amount so far (the preview replaces the previous one).
    Move,
    /// Keep the last amount as one undo step.
    Commit,
    /// Back to where the drag started.
    Cancel,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMsg {
    /// The view to render (the newest one wins; older ones are dropped).
    View {
        view: View,
    },
    /// Select the node under pixel `(x, y)` of the current view (nothing there: none).
    Click {
        x: f64,
        y: f64,
    },
    /// Select a node by id (`null`: none).
    Select {
        id: Option<InstanceId>,
    },
    /// Delete (`-`) or replicate (`+`) the selected node.
    Delete,
    Replicate,
    /// Drag the selected node: metres for translate, degrees for rotate, a factor for
    /// scale; `axis` is `x`, `y`, `z` (world) or `view` (translate in the image plane:
    /// `amount` is then ignored and `dx`, `dy` are in pixels).
    Drag {
        op: DragOp,
        axis: String,
        #[serde(default)]
        amount: f64,
        #[serde(default)]
        dx: f64,
        #[serde(default)]
        dy: f64,
        phase: DragPhase,
    },
    /// A plain-language instruction (the parser of `assist edit`), relative to the view.
    Text {
        text: String,
        /// Resolve and show the actions without applying them.
        #[serde(default)]
        dry_run: bool,
    },
    /// Actions in the JSON form of `assist edit --actions`.
    Actions {
        actions: Vec<Action>,
    },
    /// List another scene's nodes (`c`): a scene named on the command line, or a path
    /// under the server's `--scenes` folder.
    Open {
        scene: String,
    },
    /// Add a node of another scene (`a`) at the surface under pixel `(x, y)`.
    AddFrom {
        scene: String,
        node: InstanceId,
        x: f64,
        y: f64,
    },
    /// Swap the selected node with a node of another scene (`s`).
    SwapWith {
        scene: String,
        node: InstanceId,
    },
    /// Give node `id` a new label (one undo step; its class stays).
    Rename {
        id: InstanceId,
        label: String,
    },
    /// Hide node `id` from this client's frames and clicks (or show it again); the scene
    /// is not changed.
    Hide {
        id: InstanceId,
        hidden: bool,
    },
    /// New-object mode: propose an object under pixel `(x, y)` of the current view of a
    /// scene where it is part of the background (the reply is a `proposal`).
    Propose {
        x: f64,
        y: f64,
    },
    /// The proposal with its box changed: centre and size in world units, yaw in degrees
    /// about the scene's up.
    Reshape {
        center: [f64; 3],
        size: [f64; 3],
        #[serde(default)]
        yaw: f64,
    },
    /// Make the box an object node (`assist scene split`: masks, its field from the
    /// background's, a fine-tune of `iters` steps): the scene is written beside this one
    /// and opened (one undo step merges the object back).
    MakeObject {
        center: [f64; 3],
        size: [f64; 3],
        #[serde(default)]
        yaw: f64,
        label: String,
        #[serde(default = "default_split_iters")]
        iters: usize,
    },
    /// Stop a new object's split under way: before its fine-tune nothing is written;
    /// during it, the scene fine-tuned so far is written and opened. Handled as soon as
    /// it arrives, not after the split.
    Stop,
    Undo,
    Redo,
    Output {
        output: Output,
    },
    /// Write the current view at full size (RGB, depth, instance ids) as a one-view
    /// dataset in a new folder beside the scene.
    SaveView,
    /// Save to the scene's own path, or as `path` (a name beside it, `.assist` added when
    /// missing), which must not exist: save as never replaces anything. `force` is
    /// accepted and ignored.
    Save {
        #[serde(default)]
        path: Option<String>,
        #[serde(default)]
        force: bool,
    },
}

/// A node as the page lists it and draws its box.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NodeState {
    pub id: InstanceId,
    pub label: String,
    pub background: bool,
    /// Its colour in panoptic frames (sRGB bytes).
    pub color: [u8; 3],
    /// The box's eight corners in world coordinates.
    pub corners: Vec<[f64; 3]>,
}

/// A dataset camera the page can jump to.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraState {
    pub name: String,
    pub view: View,
    /// The camera's photograph, small (a JPEG data URL), when the dataset has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thumbnail: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMsg {
    Hello {
        version: u32,
        scene: String,
        /// Other scenes a client may open by name (`--scenes` allows more).
        others: Vec<String>,
        up: [f64; 3],
        /// Metres per world unit (drags of the axis handles send metres).
        meters_per_unit: f64,
        cameras: Vec<CameraState>,
        max_message_bytes: usize,
    },
    State {
        nodes: Vec<NodeState>,
        selected: Option<InstanceId>,
        /// Nodes this client hides.
        hidden: Vec<InstanceId>,
        undo: usize,
        redo: usize,
        log: Vec<String>,
    },
    /// The next binary message is this frame's JPEG.
    Frame {
        seq: u64,
        width: u32,
        height: u32,
        output: Output,
        /// A low-resolution frame; the full one follows when the view rests.
        preview: bool,
        milliseconds: f64,
    },
    /// Actions resolved from a `text` message (applied unless it was a dry run).
    Resolved {
        text: String,
        actions: Vec<serde_json::Value>,
        applied: bool,
    },
    Saved {
        path: String,
    },
    /// Another scene's nodes, after `open`.
    Other {
        scene: String,
        nodes: Vec<NodeState>,
    },
    /// A proposed object (new-object mode): its box (centre and size in world units, yaw
    /// in degrees about up, the eight corners) and, over the current view, the pixels it
    /// would own (a PNG data URL, transparent elsewhere; `pixels` of them).
    Proposal {
        center: [f64; 3],
        size: [f64; 3],
        yaw: f64,
        corners: Vec<[f64; 3]>,
        mask: String,
        pixels: usize,
    },
    /// Long work under way (`task`), `done` of 1.
    Progress {
        task: String,
        done: f64,
    },
    Error {
        message: String,
    },
}

/// Fine-tune steps of a `make_object` that names none (few: the page waits for them).
pub const VIEWER_SPLIT_ITERS: usize = 300;

fn default_split_iters() -> usize {
    VIEWER_SPLIT_ITERS
}

/// The client messages that carry nothing but their type.
const NO_FIELDS: &[&str] = &["delete", "replicate", "stop", "undo", "redo", "save_view"];

/// Reads one client message: size, JSON, known type and fields, then values.
pub fn parse_client(text: &str) -> Result<ClientMsg, String> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(format!(
            "message of {} bytes; expected at most {MAX_MESSAGE_BYTES}",
            text.len()
        ));
    }
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| format!("bad message: {e}"))?;
    // Messages without fields take none: serde lets a unit variant of a tagged enum carry
    // any keys, and a field a message does not have must never be ignored.
    if let Some(obj) = value.as_object()
        && let Some(kind) = obj.get("type").and_then(|t| t.as_str())
        && NO_FIELDS.contains(&kind)
        && let Some(extra) = obj.keys().find(|k| *k != "type")
    {
        return Err(format!(
            "bad message: unknown field `{extra}`: a {kind:?} message takes no fields"
        ));
    }
    let msg: ClientMsg = serde_json::from_value(value).map_err(|e| format!("bad message: {e}"))?;
    match &msg {
        ClientMsg::View { view } => {
            view.camera()?;
        }
        ClientMsg::Reshape { center, size, yaw } => check_box(center, size, *yaw)?,
        ClientMsg::MakeObject {
            center,
            size,
            yaw,
            label,
            iters,
        } => {
            check_box(center, size, *yaw)?;
            if label.trim().is_empty() || label.len() > 200 {
                return Err("make_object.label: expected a name of 1 to 200 bytes".into());
            }
            if *iters > 100_000 {
                return Err(format!(
                    "make_object.iters: expected at most 100000 steps, got {iters}"
                ));
            }
        }
        _ => {}
    }
    Ok(msg)
}

/// A box of a proposal: finite centre and yaw, sizes above 0.
fn check_box(center: &[f64; 3], size: &[f64; 3], yaw: f64) -> Result<(), String> {
    if !(center.iter().all(|v| v.is_finite()) && yaw.is_finite()) {
        return Err("box: expected finite center and yaw".into());
    }
    if !size.iter().all(|v| v.is_finite() && *v > 0.0) {
        return Err(format!("box.size: expected sizes above 0, got {size:?}"));
    }
    Ok(())
}

impl View {
    /// The camera this view describes; errors name the field.
    pub fn camera(&self) -> Result<Camera, String> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 || w > MAX_FRAME_SIDE || h > MAX_FRAME_SIDE {
            return Err(format!(
                "view.width/height: expected 1 to {MAX_FRAME_SIDE} pixels, got {w}×{h}"
            ));
        }
        if !(self.fov_y_degrees.is_finite() && (1.0..=170.0).contains(&self.fov_y_degrees)) {
            return Err(format!(
                "view.fov_y_degrees: expected 1 to 170, got {}",
                self.fov_y_degrees
            ));
        }
        let m = self.world_from_camera;
        let f = 0.5 * h as f64 / (0.5 * self.fov_y_degrees.to_radians()).tan();
        let intrinsics = Intrinsics {
            width: w,
            height: h,
            fx: f,
            fy: f,
            cx: 0.5 * w as f64,
            cy: 0.5 * h as f64,
            distortion: Default::default(),
        };
        let pose = Pose::from_matrix(
            DMat4::from_cols_array_2d(&m).transpose(),
            "view.world_from_camera",
        )
        .map_err(|e| e.to_string())?;
        Ok(Camera { intrinsics, pose })
    }

    /// The view of a camera (its vertical field of view; principal point assumed central).
    pub fn of_camera(c: &Camera) -> View {
        let m = c.pose.to_matrix().transpose().to_cols_array_2d();
        let h = c.height();
        View {
            world_from_camera: m,
            fov_y_degrees: (2.0 * (0.5 * h as f64 / c.intrinsics.fy).atan()).to_degrees(),
            width: c.width(),
            height: h,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view_json(extra: &str) -> String {
        format!(
            r#"{{"type":"view","view":{{"world_from_camera":[[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]],"fov_y_degrees":50,"width":64,"height":48{extra}}}}}"#
        )
    }

    #[test]
    fn messages_parse_and_bad_ones_are_named() {
        assert!(matches!(
            parse_client(&view_json("")),
            Ok(ClientMsg::View { .. })
        ));
        assert!(matches!(
            parse_client(r#"{"type":"undo"}"#),
            Ok(ClientMsg::Undo)
        ));
        assert_eq!(parse_client(r#"{"type":"stop"}"#), Ok(ClientMsg::Stop));
        let e = parse_client(r#"{"type":"stop","now":true}"#).unwrap_err();
        assert!(e.contains("takes no fields"), "{e}");
        let e = parse_client(r#"{"type":"fly"}"#).unwrap_err();
        assert!(e.contains("unknown variant"), "{e}");
        let e = parse_client(&view_json(r#","extra":1"#)).unwrap_err();
        assert!(e.contains("unknown field"), "{e}");
        let e = parse_client("{not json").unwrap_err();
        assert!(e.starts_with("bad message"), "{e}");
        let big = format!(
            r#"{{"type":"text","text":"{}"}}"#,
            "a".repeat(MAX_MESSAGE_BYTES)
        );
        assert!(parse_client(&big).unwrap_err().contains("at most"));
        let e =
            parse_client(&view_json("").replace("\"width\":64", "\"width\":100000")).unwrap_err();
        assert!(e.contains("view.width"), "{e}");
        let skew = view_json("").replace("[1,0,0,0]", "[2,0,0,0]");
        let e = parse_client(&skew).unwrap_err();
        assert!(e.contains("view.world_from_camera"), "{e}");
    }

    #[test]
    fn a_camera_round_trips_through_a_view() {
        let c = View {
            world_from_camera: [
                [1.0, 0.0, 0.0, 0.3],
                [0.0, 0.0, -1.0, -2.0],
                [0.0, 1.0, 0.0, 0.5],
                [0.0, 0.0, 0.0, 1.0],
            ],
            fov_y_degrees: 40.0,
            width: 80,
            height: 60,
        }
        .camera()
        .unwrap();
        let v = View::of_camera(&c);
        assert!((v.fov_y_degrees - 40.0).abs() < 1e-9);
        let c2 = v.camera().unwrap();
        assert!((c2.pose.center() - c.pose.center()).length() < 1e-12);
        assert!((c2.intrinsics.fy - c.intrinsics.fy).abs() < 1e-9);
    }
}
