//! `assist scene info SCENE [--json]`: what a trained scene holds — its nodes (id, label,
//! box, pose, field file and size), its edit history and how it was trained — read from
//! `scene.json` and `history.json` without loading any weights; `assist scene light SCENE
//! --out OUT`: the lamp that casts the objects' shadows, found from their shadow grids
//! ([`assist_session::LightJob`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use assist_core::{History, Scene, SceneNode};
use assist_session::scene_file;
use clap::{Args, Subcommand};
use serde_json::{Value, json};

#[derive(Subcommand, Debug)]
pub enum SceneCommand {
    /// List a scene's nodes (id, label, box, pose, field file, size), its edit history and
    /// its training provenance.
    Info(InfoArgs),
    /// Find the light that casts the objects' shadows from their learned shadow grids, so
    /// that a moved object's shadow is re-cast under it (training does this at its end;
    /// this is for scenes trained before, or to look again). Writes the scene to `--out`.
    Light(LightArgs),
    /// Make object nodes in a scene trained without masks, from boxes or clicks: masks
    /// derived for every image, each node's field started from the background's, then a
    /// short fine-tune. One undo step (undo merges the objects back). Writes `--out`.
    Split(crate::cmd_scene_split::SplitArgs),
    /// Set the scene's metres per unit from an object's known height (a capture processed
    /// without --scale-by is in COLMAP's arbitrary unit, read as metres by edits, the
    /// generator, depth and export). One undo step. Writes `--out`.
    Scale(ScaleArgs),
}

#[derive(Args, Debug)]
pub struct ScaleArgs {
    /// Scene directory (or its scene.json).
    pub scene: PathBuf,
    /// Where to write the scene (may be the scene itself, with --force).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub target: assist_session::ScaleFlags,
    /// Replace --out if it exists.
    #[arg(long)]
    pub force: bool,
    /// Machine-readable output on stdout.
    #[arg(long)]
    pub json: bool,
}

fn scale(a: ScaleArgs) -> anyhow::Result<()> {
    let target = a.target.target()?;
    let mut session = assist_session::Session::open(&a.scene)?;
    let done = session.scale_to(&target)?;
    session.save(&a.out, a.force)?;
    if a.json {
        let mut v = serde_json::to_value(&done)?;
        v["out"] = json!(a.out);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        if let Some(m) = &done.object {
            println!(
                "{:?} is {:.4} units tall: {} m",
                m.label, m.height_units, m.height_m
            );
        }
        println!(
            "{:.6} m per unit (was {}); saved {}",
            done.meters_per_unit,
            done.before,
            a.out.display()
        );
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct LightArgs {
    /// Scene directory (or its scene.json).
    pub scene: PathBuf,
    /// Where to write the scene with its light (may be the scene itself, with --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it exists.
    #[arg(long)]
    pub force: bool,
    /// Shade objects moved or turned from where they were photographed by the light where
    /// they stand now (their photographed shading exchanged for the light's at the new
    /// pose), or keep the shading they were photographed with [default: as the scene has
    /// it, off for a scene never set]
    #[arg(long, value_enum)]
    pub relight: Option<assist_session::OnOff>,
    /// Machine-readable output on stdout.
    #[arg(long)]
    pub json: bool,
}

/// One line on what [`assist_session::LightJob`] found.
pub fn describe_light(e: &assist_session::LightEstimate) -> String {
    match &e.light {
        Some(l) => format!(
            "key light: at {:.3?}, disc radius {:.3}, explains {:.0}% of the shadows ({} lattice points); moved objects' shadows are re-cast under it",
            l.position.to_array(),
            l.radius,
            100.0 * e.explained,
            e.points
        ),
        None => format!(
            "key light: none explains the shadows (best {:.0}% of {} lattice points, {:.0}% needed); moved objects keep their shadows as learned",
            100.0 * e.explained.max(0.0),
            e.points,
            100.0 * assist_session::LIGHT_MIN_EXPLAINED
        ),
    }
}

fn light(a: LightArgs) -> anyhow::Result<()> {
    let job = assist_session::LightJob {
        scene: a.scene.clone(),
        out: a.out.clone(),
        force: a.force,
        relight: a.relight.map(|r| r == assist_session::OnOff::On),
    };
    let e = job.run()?;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({"light": e, "out": a.out}))?
        );
    } else {
        println!("{}", describe_light(&e));
        println!("saved {}", a.out.display());
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Scene directory (or its scene.json).
    pub scene: PathBuf,
    /// Machine-readable output on stdout: an object with `nodes`, `history` and `training`.
    #[arg(long)]
    pub json: bool,
}

pub fn run(c: SceneCommand) -> anyhow::Result<()> {
    match c {
        SceneCommand::Info(a) => info(a),
        SceneCommand::Light(a) => light(a),
        SceneCommand::Split(a) => crate::cmd_scene_split::run(a),
        SceneCommand::Scale(a) => scale(a),
    }
}

/// A node as `scene info` reports it (lengths in metres).
fn node_json(dir: &Path, n: &SceneNode, mpu: f64, up: assist_core::DVec3) -> Value {
    let p = &n.world_from_local;
    let file = scene_file::field_path(dir, &n.field);
    let bytes = std::fs::metadata(&file).map(|m| m.len()).ok();
    // Yaw: the turn about the scene's up of the node's first local axis.
    let (e1, e2) = up.normalize().any_orthonormal_pair();
    let x = p.rotation * assist_core::DVec3::X;
    let yaw = e2.dot(x).atan2(e1.dot(x)).to_degrees();
    json!({
        "id": n.id,
        "label": n.label,
        "kind": if n.is_background() { "background" } else { "object" },
        "space": n.space,
        "size_m": (n.half_size * p.scale * 2.0 * mpu).to_array(),
        "position_m": (p.translation * mpu).to_array(),
        "rotation_xyzw": p.rotation.to_array(),
        "yaw_deg": yaw,
        "scale": p.scale.to_array(),
        "field": n.field,
        "field_file": file.strip_prefix(dir).unwrap_or(&file),
        "field_bytes": bytes,
        "embedding": n.embedding.is_some(),
        "embedding_dim": n.embedding.as_ref().map(Vec::len),
    })
}

fn history_json(h: &History) -> Value {
    let step = |s: &assist_core::HistoryStep| json!({"text": s.text, "actions": s.actions.len()});
    json!({
        "undo": h.undo.iter().map(step).collect::<Vec<_>>(),
        "redo": h.redo.iter().rev().map(step).collect::<Vec<_>>(),
    })
}

fn info(a: InfoArgs) -> anyhow::Result<()> {
    let (scene, meta): (Scene, Value) = scene_file::load_scene_json(&a.scene)
        .with_context(|| format!("reading scene {}", a.scene.display()))?;
    let dir = if a.scene.is_dir() {
        a.scene.clone()
    } else {
        a.scene
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."))
    };
    let hist_path = dir.join("history.json");
    let history = if hist_path.exists() {
        scene_file::parse_history(&hist_path, &assist_fs::read_text(&hist_path)?)?
    } else {
        History::default()
    };
    let mpu = scene.meters_per_unit;
    let nodes: Vec<Value> = scene
        .nodes
        .iter()
        .map(|n| node_json(&dir, n, mpu, scene.up))
        .collect();
    let training = json!({
        "dataset": meta.get("dataset"),
        "iterations": meta.get("iteration"),
        "seconds": meta.get("elapsed_seconds"),
        "options": meta.get("options"),
    });
    if a.json {
        let v = json!({
            "scene": dir,
            "meters_per_unit": mpu,
            "up": scene.up.to_array(),
            "selected": scene.selected,
            "light": scene.light,
            "relight": scene.relight,
            "nodes": nodes,
            "history": history_json(&history),
            "training": training,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{}: {} node(s), {} m per unit, up {:?}",
        dir.display(),
        nodes.len(),
        mpu,
        scene.up.to_array()
    );
    match &scene.light {
        Some(l) => println!(
            "key light: at {:.3?} m, disc radius {:.3} m (moved objects' shadows are re-cast under it{})",
            (l.position * mpu).to_array(),
            l.radius * mpu,
            if scene.relight {
                ", and they are shaded by it where they stand"
            } else {
                ""
            }
        ),
        None => println!("key light: none (moved objects keep their shadows as learned)"),
    }
    // Labels are shown whole (issue 47: they were cut at 32 characters); the column is as
    // wide as the longest.
    let lw = nodes
        .iter()
        .map(|n| n["label"].as_str().unwrap_or("").chars().count())
        .max()
        .unwrap_or(0)
        .max(5);
    println!(
        "{:>4}  {:<lw$} {:<10} {:>22}  {:>24}  {:>7}  field",
        "id", "label", "kind", "size (m)", "position (m)", "yaw °"
    );
    let f3 = |v: &Value| {
        let a: Vec<f64> = serde_json::from_value(v.clone()).unwrap_or_default();
        a.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    for n in &nodes {
        let bytes = n["field_bytes"]
            .as_u64()
            .map(|b| format!("{:.1} MB", b as f64 / 1e6))
            .unwrap_or_else(|| "missing".into());
        let label = n["label"].as_str().unwrap_or("");
        let selected = if scene.selected.map(u64::from) == n["id"].as_u64() {
            " (selected)"
        } else {
            ""
        };
        println!(
            "{:>4}  {:<lw$} {:<10} {:>22}  {:>24}  {:>7.1}  {} ({bytes}){selected}",
            n["id"].as_u64().unwrap_or(0),
            label,
            n["kind"].as_str().unwrap_or(""),
            f3(&n["size_m"]),
            f3(&n["position_m"]),
            n["yaw_deg"].as_f64().unwrap_or(0.0),
            n["field_file"].as_str().unwrap_or(""),
        );
    }
    let embedded: Vec<String> = nodes
        .iter()
        .filter(|n| n["embedding"].as_bool() == Some(true))
        .map(|n| n["id"].to_string())
        .collect();
    match embedded.len() {
        0 => println!("embeddings: none (assist embed gives each node a CLIP embedding)"),
        k if k == nodes.len() => println!(
            "embeddings: every node ({}-d CLIP)",
            nodes[0]["embedding_dim"]
        ),
        _ => println!(
            "embeddings: nodes {} ({}-d CLIP); the others have none",
            embedded.join(", "),
            nodes
                .iter()
                .find_map(|n| n["embedding_dim"].as_u64())
                .unwrap_or(0)
        ),
    }
    let n_undo = history.undo.len();
    println!(
        "history: {n_undo} step(s) to undo, {} to redo",
        history.redo.len()
    );
    for (i, s) in history.undo.iter().enumerate() {
        println!(
            "  undo {:>3}  {}",
            n_undo - i,
            s.text.as_deref().unwrap_or("(not recorded)")
        );
    }
    match meta.get("dataset").and_then(Value::as_str) {
        Some(d) => println!(
            "trained on {d}: {} iterations in {:.0} s",
            meta.get("iteration").and_then(Value::as_u64).unwrap_or(0),
            meta.get("elapsed_seconds")
                .and_then(Value::as_f64)
                .unwrap_or(0.0)
        ),
        None => println!("training: not recorded"),
    }
    Ok(())
}
