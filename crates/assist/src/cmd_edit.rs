//! `assist edit SCENE (--do TEXT | --actions FILE.jsonl | --undo N | --redo N) --out NEW`:
//! applies actions (from plain language, an edit script, or an LLM) as one undo step, or
//! steps through the scene's edit history, and saves the result atomically. `--dry-run
//! --json` prints the resolved actions (or the steps an undo would take back and what they
//! change) and touches nothing; `--history` lists the steps.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_core::{Action, HistoryStep, Scene};
use assist_session::{Resolved, Session, Steps};
use clap::Args;

#[derive(Args, Debug)]
pub struct EditArgs {
    /// Scene directory to edit.
    pub scene: PathBuf,
    /// A plain-language instruction, e.g. "move the mug 10 cm left and rotate it 90 degrees".
    #[arg(long = "do", value_name = "TEXT")]
    pub text: Option<String>,
    /// An edit script: JSON Lines of actions (or one JSON array / object).
    #[arg(long, value_name = "FILE")]
    pub actions: Option<PathBuf>,
    /// Undo this many earlier edits (from the scene's history).
    #[arg(long, value_name = "N")]
    pub undo: Option<usize>,
    /// Redo this many undone edits.
    #[arg(long, value_name = "N")]
    pub redo: Option<usize>,
    /// List the scene's edit history (each step's instruction and resolved actions) and
    /// exit.
    #[arg(long)]
    pub history: bool,
    /// Where to save the edited scene (the scene itself, with --force, edits in place).
    /// Refused if it exists, unless --force.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the resolved actions (with --undo/--redo: the steps and what they would
    /// change); write nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Machine-readable output on stdout (progress and messages stay on stderr).
    #[arg(long)]
    pub json: bool,
    /// CLIP weights for phrases no label matches, resolved by meaning against the nodes'
    /// embeddings (`assist embed`) [default: $ASSIST_CLIP].
    #[arg(long)]
    pub clip: Option<PathBuf>,
    /// Replace --out if it exists (only a scene assist wrote; give the scene itself to
    /// edit in place).
    #[arg(long)]
    pub force: bool,
    /// Interpret left/right/forward/back relative to a camera of this dataset (with
    /// --frame; also given as --data).
    #[arg(long, visible_alias = "data", value_name = "DATA")]
    pub camera: Option<PathBuf>,
    /// The camera's frame name in --camera.
    #[arg(long, value_name = "NAME")]
    pub frame: Option<String>,
    /// Refuse an edit that takes an object out of the captured region (the background's
    /// box), sinks it 3 cm or more into the surface under it, pushes it into another
    /// object or leaves it floating, instead of warning.
    #[arg(long)]
    pub strict: bool,
    /// Accept objects inside one another or floating without a warning.
    #[arg(long)]
    pub allow_overlap: bool,
    /// Lower an object the edit leaves floating onto what is under it (the table, or the
    /// top of another object), as part of the same edit.
    #[arg(long)]
    pub settle: bool,
    /// What a scale in words keeps in place: base (the object's resting point, so it
    /// stays on its support) or center (its box centre).
    #[arg(long, default_value = "base", value_parser = ["base", "center"])]
    pub pivot: String,
    /// Ask the LLM provider set by ASSIST_LLM_URL / ASSIST_LLM_MODEL / ASSIST_LLM_API_KEY
    /// instead of the built-in parser (its answer is validated the same way).
    #[arg(long)]
    pub llm: bool,
}

/// Reads an edit script: JSON Lines (blank lines and `#` comments skipped), a JSON array,
/// or a single (possibly pretty-printed) JSON object. Errors name the file and line.
pub fn read_actions(path: &Path) -> anyhow::Result<Vec<Action>> {
    let text = assist_fs::read_text(path)?;
    let t = text.trim_start();
    if t.starts_with('[') {
        return serde_json::from_str(&text).map_err(|e| {
            anyhow::anyhow!(
                "{} line {} column {}: not a JSON array of actions {{instance_id, operation, config}}: {e}",
                path.display(),
                e.line(),
                e.column()
            )
        });
    }
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        match serde_json::from_str::<Action>(l) {
            Ok(a) => out.push(a),
            Err(e) => {
                // A single pretty-printed object is not JSON Lines but is unambiguous.
                if out.is_empty()
                    && let Ok(a) = serde_json::from_str::<Action>(&text)
                {
                    return Ok(vec![a]);
                }
                bail!(
                    "{} line {}: not an action {{instance_id, operation, config}}: {e}",
                    path.display(),
                    n + 1
                );
            }
        }
    }
    if out.is_empty() {
        bail!("{}: no actions in the file", path.display());
    }
    Ok(out)
}

/// The camera left/right/forward are relative to (`--camera DATA --frame NAME`).
fn camera(a: &EditArgs) -> anyhow::Result<Option<assist_core::Camera>> {
    let Some(data) = &a.camera else {
        if a.frame.is_some() {
            bail!("--frame needs --camera DATA");
        }
        return Ok(None);
    };
    let ds = assist_data::load(data, &assist_data::LoadOptions::default())
        .with_context(|| format!("--camera: loading {}", data.display()))?;
    let name = a.frame.as_deref().context("--camera needs --frame NAME")?;
    let f = ds.frames.iter().find(|f| f.name == name).with_context(|| {
        format!(
            "--frame: no frame named {name:?} in {} (e.g. {})",
            data.display(),
            ds.frames
                .iter()
                .take(3)
                .map(|f| f.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    Ok(Some(f.camera))
}

/// A history step as JSON: its instruction and actions.
fn step_json(s: &HistoryStep) -> serde_json::Value {
    serde_json::json!({"text": s.text, "actions": s.actions})
}

/// A history step in one line: the instruction and a short form of each action.
fn step_line(s: &HistoryStep) -> String {
    let text = s.text.as_deref().unwrap_or("(not recorded)");
    let acts: Vec<String> = s
        .actions
        .iter()
        .map(|a| format!("{:?} {}", a.operation, a.instance_id).to_lowercase())
        .collect();
    format!("{text:?} → {}", acts.join(", "))
}

/// What changes between two states of a scene, node by node: added, deleted, moved,
/// turned, resized or relabelled (lengths in metres).
fn scene_changes(from: &Scene, to: &Scene) -> Vec<serde_json::Value> {
    let mpu = to.meters_per_unit;
    let mut out = Vec::new();
    for b in &to.nodes {
        match from.nodes.iter().find(|a| a.id == b.id) {
            None => out.push(serde_json::json!({"id": b.id, "label": b.label, "change": "added"})),
            Some(a) => {
                let (pa, pb) = (&a.world_from_local, &b.world_from_local);
                let moved = (pb.translation - pa.translation).length() * mpu;
                let turned = pa.rotation.angle_between(pb.rotation).to_degrees();
                let scaled = pb.scale.x / pa.scale.x.max(1e-12);
                let mut what = Vec::new();
                if moved > 1e-6 {
                    what.push(format!("moved {:.3} m", moved));
                }
                if turned > 1e-4 {
                    what.push(format!("turned {turned:.1}°"));
                }
                if (scaled - 1.0).abs() > 1e-6 || a.half_size != b.half_size {
                    what.push(format!("scaled ×{scaled:.3}"));
                }
                if a.label != b.label {
                    what.push(format!("relabelled {:?} → {:?}", a.label, b.label));
                }
                if !what.is_empty() {
                    out.push(serde_json::json!({"id": b.id, "label": b.label, "change": what.join(", ")}));
                }
            }
        }
    }
    for a in &from.nodes {
        if !to.nodes.iter().any(|b| b.id == a.id) {
            out.push(serde_json::json!({"id": a.id, "label": a.label, "change": "deleted"}));
        }
    }
    out
}

/// `--history`: the steps to undo (oldest first) and to redo (the next redo first).
fn print_history(session: &Session, json: bool) -> anyhow::Result<()> {
    let h = session.history();
    if json {
        let undo: Vec<_> = h.undo.iter().map(step_json).collect();
        let redo: Vec<_> = h.redo.iter().rev().map(step_json).collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({"undo": undo, "redo": redo}))?
        );
        return Ok(());
    }
    if h.undo.is_empty() && h.redo.is_empty() {
        println!("no edits in the history");
        return Ok(());
    }
    let n = h.undo.len();
    for (i, s) in h.undo.iter().enumerate() {
        println!("undo {:>3}  {}", n - i, step_line(s));
    }
    for (i, s) in h.redo.iter().rev().enumerate() {
        println!("redo {:>3}  {}", i + 1, step_line(s));
    }
    println!("(`--undo N` goes back N steps; `--redo N` forward N)");
    Ok(())
}

/// `--undo N` / `--redo N` with `--dry-run`: the steps and what they would change.
fn preview_steps(session: &Session, undo: bool, n: usize, json: bool) -> anyhow::Result<()> {
    let h = session.history();
    let list = if undo { &h.undo } else { &h.redo };
    let what = if undo { "undo" } else { "redo" };
    if n > list.len() {
        bail!(
            "--{what} {n}: the scene has only {} step(s) to {what}",
            list.len()
        );
    }
    let steps: Vec<&HistoryStep> = list.iter().rev().take(n).collect();
    let now = &session.description();
    let target = match steps.last() {
        Some(s) => &s.scene,
        None => now,
    };
    let changes = scene_changes(now, target);
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                what: steps.iter().map(|s| step_json(s)).collect::<Vec<_>>(),
                "changes": changes,
            }))?
        );
    } else {
        for s in &steps {
            println!("would {what} {}", step_line(s));
        }
        for c in &changes {
            println!(
                "  node {} {:?}: {}",
                c["id"],
                c["label"].as_str().unwrap_or(""),
                c["change"].as_str().unwrap_or("")
            );
        }
        if changes.is_empty() {
            println!("  (no node would change)");
        }
    }
    Ok(())
}

pub fn run(a: EditArgs) -> anyhow::Result<()> {
    let sources = [
        a.text.is_some(),
        a.actions.is_some(),
        a.undo.is_some() || a.redo.is_some(),
        a.history,
    ];
    if sources.iter().filter(|s| **s).count() != 1 || (a.undo.is_some() && a.redo.is_some()) {
        bail!("give exactly one of --do TEXT, --actions FILE, --undo N, --redo N or --history");
    }
    if a.history {
        let session = Session::open(&a.scene)
            .with_context(|| format!("loading scene {}", a.scene.display()))?;
        return print_history(&session, a.json);
    }
    // A read-modify-write: the scene (and --out) are claimed from loading to saving, so a
    // second process editing either gets an error instead of silently losing an edit.
    let mut _locks = Vec::new();
    if !a.dry_run {
        _locks.push(assist_fs::lock(&a.scene, "assist edit")?);
        if let Some(out) = &a.out {
            assist_fs::check_replaceable_as(out, a.force, assist_fs::Kind::Scene)?;
            _locks.push(assist_fs::lock(out, "assist edit")?);
        }
    }
    let mut session =
        Session::open(&a.scene).with_context(|| format!("loading scene {}", a.scene.display()))?;
    if let Some(c) = &a.clip {
        session.set_clip_path(Some(c.clone()));
    }
    let mpu = session.description().meters_per_unit;
    // What to apply: an instruction resolved by the built-in parser (validated once, by
    // it), or actions (from a script or an LLM) that the editor validates.
    let mut resolved: Option<Resolved> = None;
    let mut actions: Vec<Action> = Vec::new();
    // What the history step will say made it.
    let mut note = None;
    if let Some(text) = &a.text {
        if a.llm {
            let p = assist_session::LlmProvider::from_env()
                .context("--llm: set ASSIST_LLM_URL (and ASSIST_LLM_MODEL, ASSIST_LLM_API_KEY) to an OpenAI-compatible endpoint")?;
            actions = session.ask_llm(&p, text)?;
            note = Some(format!("{text} (LLM)"));
        } else {
            let view = camera(&a)?;
            let pivot = if a.pivot == "center" {
                assist_session::Pivot::Center
            } else {
                assist_session::Pivot::Base
            };
            resolved = Some(session.resolve_with(text, view.as_ref(), pivot)?);
            note = Some(text.clone());
        }
    } else if let Some(f) = &a.actions {
        actions = read_actions(f)?;
        note = Some(format!("actions from {}", f.display()));
    }
    if a.dry_run && (a.undo.is_some() || a.redo.is_some()) {
        let (undo, n) = match (a.undo, a.redo) {
            (Some(n), _) => (true, n),
            (_, n) => (false, n.unwrap_or(0)),
        };
        return preview_steps(&session, undo, n, a.json);
    }
    if a.dry_run {
        let settle =
            crate::edit_checks::check_region(&a, &mut session, resolved.as_ref(), &actions)?;
        let (resolved, actions) = crate::edit_checks::with_settle(resolved, actions, settle, mpu);
        let edits = match resolved {
            Some(r) => r.edits,
            None => session.plan(&actions)?,
        };
        let resolved: Vec<Action> = edits.iter().map(|e| e.to_action(mpu)).collect();
        if a.json {
            println!("{}", serde_json::to_string_pretty(&resolved)?);
        } else {
            for r in &resolved {
                println!("{}", serde_json::to_string(r)?);
            }
        }
        return Ok(());
    }
    let out = a
        .out
        .as_ref()
        .context("--out NEW.assist is required (or --dry-run)")?;
    let mut applied = Vec::new();
    if let Some(n) = a.undo {
        for i in 0..n {
            if !session.undo() {
                bail!("--undo {n}: the scene has only {i} edit(s) to undo");
            }
        }
    } else if let Some(n) = a.redo {
        for i in 0..n {
            if !session.redo() {
                bail!("--redo {n}: the scene has only {i} undone edit(s) to redo");
            }
        }
    } else {
        let settle =
            crate::edit_checks::check_region(&a, &mut session, resolved.as_ref(), &actions)?;
        let (resolved, actions) = crate::edit_checks::with_settle(resolved, actions, settle, mpu);
        // One instruction (or one edit script) is one undo step.
        let edits = match resolved {
            Some(r) => session.install(r, Steps::One, note)?,
            None => session.apply_noted(&actions, Steps::One, note)?,
        };
        applied = edits.iter().map(|e| e.to_action(mpu)).collect();
    }
    session
        .save(out, a.force)
        .with_context(|| format!("saving {}", out.display()))?;
    let nodes = session.nodes().len();
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "out": out,
                "actions": applied,
                "nodes": nodes,
                "undo": session.undo_steps(),
                "redo": session.redo_steps(),
            })
        );
    } else {
        for r in &applied {
            eprintln!("applied {}", serde_json::to_string(r)?);
        }
        eprintln!(
            "saved {} ({} nodes; {} edit(s) to undo, {} to redo)",
            out.display(),
            nodes,
            session.undo_steps(),
            session.redo_steps()
        );
    }
    Ok(())
}
