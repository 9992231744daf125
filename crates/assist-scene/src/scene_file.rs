//! `NAME.assist/` scene directories: `scene.json` (format, version, up, metres per unit,
//! background colour, nodes with id, label, box, pose, field key, embedding) and one
//! safetensors file per field in `fields/` (weights, config, occupancy). Replicas name the
//! same field key. Saving writes a complete temporary directory and renames it into place;
//! loading validates everything and names the file and field that is wrong.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use assist_core::{History, Scene, SceneNode};
use serde::{Deserialize, Serialize};

use crate::node::{NeuralScene, NodeField};

pub const FORMAT: &str = "assist-scene";
pub const VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum SceneFileError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {field}: {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error("{path} already exists (pass --force to replace it)")]
    Exists { path: PathBuf },
    /// Writing the new folder failed (a full disk): what was at `path` is as it was.
    #[error("{}: saving failed while writing {file}, and what was there is unchanged: {source}", .path.display())]
    Save {
        path: PathBuf,
        file: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    Field(#[from] assist_field::FieldError),
    #[error(transparent)]
    Output(#[from] assist_fs::FsError),
}

fn invalid(path: &Path, field: impl Into<String>, message: impl Into<String>) -> SceneFileError {
    SceneFileError::Invalid {
        path: path.to_path_buf(),
        field: field.into(),
        message: message.into(),
    }
}

#[derive(Serialize, Deserialize)]
struct SceneJson {
    format: String,
    version: u32,
    #[serde(flatten)]
    scene: Scene,
    /// Free-form provenance (dataset, training statistics).
    #[serde(default, skip_serializing_if = "serde_json::Value::is_null")]
    info: serde_json::Value,
}

/// Path of a field's weights inside a scene directory.
pub fn field_path(dir: &Path, key: &str) -> PathBuf {
    dir.join("fields").join(format!("{key}.safetensors"))
}

fn valid_key(key: &str) -> bool {
    !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// Saves `scene` to `dir` atomically. An existing `dir` is replaced only with `force`.
pub fn save(
    dir: &Path,
    scene: &NeuralScene,
    info: serde_json::Value,
    force: bool,
) -> Result<(), SceneFileError> {
    save_with_history(dir, scene, &History::default(), info, force)
}

/// Saves `scene` and its edit history (`history.json`, only when not empty). The fields
/// written are those the scene or its history refer to.
pub fn save_with_history(
    dir: &Path,
    scene: &NeuralScene,
    history: &History,
    info: serde_json::Value,
    force: bool,
) -> Result<(), SceneFileError> {
    // Nothing is written that would not load again.
    check_scenes(&dir.join("scene.json"), Some(&scene.scene), history)?;
    // Replace only what assist wrote, claim the name against other processes, and write a
    // complete folder beside it before swapping it in.
    assist_fs::check_replaceable_as(dir, force, assist_fs::Kind::Scene)?;
    let staging = assist_fs::Staging::begin(dir, "saving a scene")?;
    let tmp = staging.dir().to_path_buf();
    // An error names the folder being saved, not the temporary that is removed.
    write_staged(&tmp, dir, scene, history, info).map_err(|e| match e {
        SceneFileError::Io { path, source } if path.starts_with(&tmp) => SceneFileError::Save {
            path: dir.to_path_buf(),
            file: path
                .strip_prefix(&tmp)
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
            source,
        },
        e => e,
    })?;
    staging.commit()?;
    Ok(())
}

/// Writes the scene's files into the staging folder `tmp` (errors name `dir`'s fields).
fn write_staged(
    tmp: &Path,
    dir: &Path,
    scene: &NeuralScene,
    history: &History,
    info: serde_json::Value,
) -> Result<(), SceneFileError> {
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |e| SceneFileError::Io { path: p, source: e }
    };
    std::fs::create_dir_all(tmp.join("fields")).map_err(io(tmp))?;
    for node in &scene.scene.nodes {
        if !valid_key(&node.field) {
            return Err(invalid(
                dir,
                format!("nodes[id={}].field", node.id),
                format!(
                    "field key {:?} must be letters, digits, '_' or '-'",
                    node.field
                ),
            ));
        }
    }
    let mut keys = history.field_keys();
    keys.extend(scene.scene.nodes.iter().map(|n| n.field.clone()));
    for key in &keys {
        let nf = scene.fields.get(key).ok_or_else(|| {
            invalid(
                dir,
                "fields",
                format!("no weights loaded for field key {key:?}"),
            )
        })?;
        write_field(&field_path(tmp, key), nf)?;
    }
    if !history.is_empty() {
        let text = serde_json::to_string(history)
            .map_err(|e| invalid(dir, "history.json", format!("cannot serialise: {e}")))?;
        let p = tmp.join("history.json");
        std::fs::write(&p, text).map_err(io(&p))?;
    }
    let json = SceneJson {
        format: FORMAT.into(),
        version: VERSION,
        scene: scene.scene.clone(),
        info,
    };
    let text = serde_json::to_string_pretty(&json)
        .map_err(|e| invalid(dir, "scene.json", format!("cannot serialise: {e}")))?;
    let p = tmp.join("scene.json");
    std::fs::write(&p, text).map_err(io(&p))
}

/// Writes a node's weights to `dest`, or hard-links the file they were read from when it
/// holds exactly these bytes: an edit that moves nodes writes kilobytes, not the weights
/// again. A link is a second name for the same file, so deleting either scene leaves the
/// other whole.
fn write_field(dest: &Path, nf: &NodeField) -> Result<(), SceneFileError> {
    let bytes = assist_field::io::to_bytes_node(
        &nf.field,
        Some(&nf.occupancy),
        nf.shade.as_ref(),
        nf.proposal.as_ref(),
    )?;
    if let Some(origin) = &nf.origin
        && std::fs::metadata(origin).is_ok_and(|m| m.len() == bytes.len() as u64)
        && std::fs::read(origin).is_ok_and(|b| b == bytes)
        && std::fs::hard_link(origin, dest).is_ok()
    {
        return Ok(());
    }
    std::fs::write(dest, &bytes).map_err(|e| SceneFileError::Io {
        path: dest.to_path_buf(),
        source: e,
    })
}

/// Parses and validates a `history.json` (every snapshot as a scene file must hold it);
/// `path` names the file in errors.
pub fn parse_history(path: &Path, text: &str) -> Result<History, SceneFileError> {
    let history: History = serde_json::from_str(text).map_err(|e| {
        invalid(
            path,
            format!("line {} column {}", e.line(), e.column()),
            format!("not an edit history: {e}"),
        )
    })?;
    check_scenes(path, None, &history)?;
    Ok(history)
}

/// Parses and validates the text of a `scene.json` (no weights); `path` names the file in
/// errors.
pub fn parse_scene_json(
    path: &Path,
    text: &str,
) -> Result<(Scene, serde_json::Value), SceneFileError> {
    scene_json_from_text(path, text)
}

/// Loads and validates a scene directory (or its `scene.json`).
pub fn load(path: &Path) -> Result<(NeuralScene, serde_json::Value), SceneFileError> {
    let (scene, _, info) = load_with_history(path)?;
    Ok((scene, info))
}

/// Reads and validates only `scene.json` (nodes, units; no weights): what an `add` from
/// another scene needs to find and place a node.
pub fn load_scene_json(path: &Path) -> Result<(Scene, serde_json::Value), SceneFileError> {
    let (_, file) = locate(path);
    read_scene_json(&file)
}

fn locate(path: &Path) -> (PathBuf, PathBuf) {
    if path.is_dir() {
        (path.to_path_buf(), path.join("scene.json"))
    } else {
        (
            path.parent().unwrap_or(Path::new(".")).to_path_buf(),
            path.to_path_buf(),
        )
    }
}

/// Loads a scene directory with its edit history (empty when it has none).
pub fn load_with_history(
    path: &Path,
) -> Result<(NeuralScene, History, serde_json::Value), SceneFileError> {
    let (dir, file) = locate(path);
    let (scene, info) = read_scene_json(&file)?;
    let hist_path = dir.join("history.json");
    let history: History = if hist_path.exists() {
        parse_history(&hist_path, &assist_fs::read_text(&hist_path)?)?
    } else {
        History::default()
    };
    let mut fields = BTreeMap::new();
    let keys: Vec<(String, String)> = scene
        .nodes
        .iter()
        .map(|n| (n.field.clone(), format!("nodes[id={}].field", n.id)))
        .chain(
            history
                .field_keys()
                .into_iter()
                .map(|k| (k, "history.json".to_string())),
        )
        .collect();
    for (key, what) in keys {
        if fields.contains_key(&key) {
            continue;
        }
        let (half, space) = scene
            .nodes
            .iter()
            .chain(
                history
                    .undo
                    .iter()
                    .chain(&history.redo)
                    .flat_map(|s| &s.scene.nodes),
            )
            .find(|n| n.field == key)
            .map(|n| (n.half_size, n.space))
            .expect("key comes from a node");
        fields.insert(
            key.clone(),
            Arc::new(load_field(&file, &dir, &key, &what, half, space)?),
        );
    }
    Ok((NeuralScene { scene, fields }, history, info))
}

/// Loads field `key` of the scene directory `dir` for a node box of half extents `half`.
pub fn load_field(
    file: &Path,
    dir: &Path,
    key: &str,
    what: &str,
    half: assist_core::DVec3,
    space: assist_core::NodeSpace,
) -> Result<NodeField, SceneFileError> {
    let fp = field_path(dir, key);
    if !fp.exists() {
        return Err(invalid(
            file,
            what,
            format!("field file {} is missing", fp.display()),
        ));
    }
    let l = assist_field::io::load_node(&fp)?;
    let occ = l
        .occupancy
        .unwrap_or_else(|| assist_field::OccupancyGrid::new(64));
    let mut nf = NodeField::with_space(l.field, occ, half, space);
    nf.shade = l.shade;
    nf.proposal = l.proposal;
    nf.origin = Some(fp);
    Ok(nf)
}

fn read_scene_json(file: &Path) -> Result<(Scene, serde_json::Value), SceneFileError> {
    let file = file.to_path_buf();
    let text = assist_fs::read_text(&file)?;
    scene_json_from_text(&file, &text)
}

fn scene_json_from_text(
    file: &Path,
    text: &str,
) -> Result<(Scene, serde_json::Value), SceneFileError> {
    let file = file.to_path_buf();
    let raw: serde_json::Value = serde_json::from_str(text).map_err(|e| {
        invalid(
            &file,
            format!("line {} column {}", e.line(), e.column()),
            e.to_string(),
        )
    })?;
    match raw.get("format").and_then(|v| v.as_str()) {
        Some(FORMAT) => {}
        other => {
            return Err(invalid(
                &file,
                "format",
                format!("expected \"{FORMAT}\", got {other:?}"),
            ));
        }
    }
    match raw.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == VERSION as u64 => {}
        other => {
            return Err(invalid(
                &file,
                "version",
                format!("expected {VERSION} (this build's scene format), got {other:?}"),
            ));
        }
    }
    if let Some(obj) = raw.as_object()
        && let Some(k) = obj.keys().find(|k| !SCENE_KEYS.contains(&k.as_str()))
    {
        return Err(invalid(
            &file,
            k.as_str(),
            format!(
                "unknown key (a scene file has {}); it would be lost on the next save",
                SCENE_KEYS.join(", ")
            ),
        ));
    }
    let json: SceneJson = serde_json::from_value(raw).map_err(|e| {
        invalid(
            &file,
            "scene",
            format!("does not match the scene format: {e}"),
        )
    })?;
    let scene = json.scene;
    check_structure(&file, "", &scene)?;
    check_scene_values(&file, "", &scene)?;
    Ok((scene, json.info))
}

/// The top-level keys of `scene.json`.
const SCENE_KEYS: &[&str] = &[
    "format",
    "version",
    "info",
    "nodes",
    "up",
    "meters_per_unit",
    "background_color",
    "backdrop",
    "selected",
    "near",
    "classes",
    "light",
    "relight",
];

/// Everything a scene (the file's, or a history snapshot) must hold to load and render:
/// at least one node, a background node's field shared by no object, unique ids, field
/// keys that are file names, each node's values, and the scene-wide values.
fn check_structure(file: &Path, prefix: &str, scene: &Scene) -> Result<(), SceneFileError> {
    let nodes = format!("{prefix}nodes");
    if scene.nodes.len() > assist_core::scene::MAX_NODES {
        return Err(invalid(
            file,
            nodes,
            format!(
                "{} nodes; a scene holds at most {}",
                scene.nodes.len(),
                assist_core::scene::MAX_NODES
            ),
        ));
    }
    if scene.nodes.is_empty() {
        return Err(invalid(
            file,
            nodes,
            "expected at least one node (a background, id 0, or an object); the list is empty",
        ));
    }
    // A scene of objects alone (a Blender capture on a plain backdrop) has no background.
    let bg = scene.nodes.iter().find(|n| n.is_background());
    let mut seen = std::collections::HashSet::new();
    for (i, n) in scene.nodes.iter().enumerate() {
        let f = |x: &str| format!("{prefix}nodes[{i}].{x}");
        if !seen.insert(n.id) {
            return Err(invalid(file, f("id"), format!("id {} is used twice", n.id)));
        }
        if !valid_key(&n.field) {
            return Err(invalid(
                file,
                f("field"),
                "expected letters, digits, '_' or '-'",
            ));
        }
        if let Some(bg) = bg
            && !n.is_background()
            && n.field == bg.field
        {
            return Err(invalid(
                file,
                f("field"),
                format!(
                    "node {} shares the background's field {:?}; an object needs its own",
                    n.id, n.field
                ),
            ));
        }
        check_node(file, &f, n)?;
    }
    check_scene_values(file, prefix, scene)
}

/// The scene-wide values: units, up, near plane, background colour, and a selection that
/// names one of the scene's nodes.
fn check_scene_values(file: &Path, prefix: &str, s: &Scene) -> Result<(), SceneFileError> {
    let f = |x: &str| format!("{prefix}{x}");
    if !(s.meters_per_unit.is_finite() && s.meters_per_unit > 0.0) {
        return Err(invalid(
            file,
            f("meters_per_unit"),
            format!("expected a positive number, got {}", s.meters_per_unit),
        ));
    }
    let up = s.up;
    if !(up.is_finite() && up.length() > 1e-9) {
        return Err(invalid(
            file,
            f("up"),
            format!("expected a finite non-zero direction, got {up:?}"),
        ));
    }
    if !(s.near.is_finite() && (0.0..=1e9).contains(&s.near)) {
        return Err(invalid(
            file,
            f("near"),
            format!("expected 0 to 1e9 world units, got {}", s.near),
        ));
    }
    if s.background_color.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(invalid(
            file,
            f("background_color"),
            format!(
                "expected 3 numbers from 0 to 1, got {:?}",
                s.background_color
            ),
        ));
    }
    if let Some(l) = &s.light {
        if !(l.position.is_finite()
            && l.position.abs().max_element() <= assist_core::scene::MAX_COORDINATE)
        {
            return Err(invalid(
                file,
                f("light.position"),
                format!(
                    "expected coordinates within ±{:e}, got {:?}",
                    assist_core::scene::MAX_COORDINATE,
                    l.position.to_array()
                ),
            ));
        }
        if !(l.radius.is_finite() && (0.0..=assist_core::scene::MAX_COORDINATE).contains(&l.radius))
        {
            return Err(invalid(
                file,
                f("light.radius"),
                format!(
                    "expected a radius of 0 or more world units, got {}",
                    l.radius
                ),
            ));
        }
    }
    if let Some(id) = s.selected
        && s.node(id).is_none()
    {
        return Err(invalid(
            file,
            f("selected"),
            format!("no node with id {id} in the scene"),
        ));
    }
    Ok(())
}

fn check_node(
    file: &Path,
    f: &dyn Fn(&str) -> String,
    n: &SceneNode,
) -> Result<(), SceneFileError> {
    n.check()
        .map_err(|(field, message)| invalid(file, f(field), message))
}

/// Every node of `scene` (when given) and of every history snapshot holds values a scene
/// file can hold (checked before saving and when loading).
fn check_scenes(
    file: &Path,
    scene: Option<&Scene>,
    history: &History,
) -> Result<(), SceneFileError> {
    let check = |prefix: String, s: &Scene| check_structure(file, &prefix, s);
    if let Some(s) = scene {
        check(String::new(), s)?;
    }
    for (k, s) in history.undo.iter().enumerate() {
        check(format!("undo[{k}].scene."), &s.scene)?;
    }
    for (k, s) in history.redo.iter().enumerate() {
        check(format!("redo[{k}].scene."), &s.scene)?;
    }
    Ok(())
}
