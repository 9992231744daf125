//! What `assist edit` checks before an edit lands: objects leaving the captured region,
//! sinking into their support, inside one another or floating (warnings, or refusals
//! under `--strict`), and the moves `--settle` adds.

use anyhow::bail;
use assist_core::{Action, Scene};
use assist_session::{Resolved, Session};

use crate::cmd_edit::EditArgs;

/// Objects an edit takes out of the captured region: their box centre seen by none of
/// the training cameras (in front of it, inside its image), or a box corner more than
/// 1 cm outside the background node's box — where it was inside before (or is new).
/// Without the training cameras (the dataset moved) only the background's box counts.
fn leaving_capture(before: &Scene, after: &Scene, cams: &[assist_core::Camera]) -> Vec<String> {
    let tol = 0.01 / after.meters_per_unit.max(1e-12);
    let bg = after.nodes.iter().find(|n| n.is_background());
    // How far outside the background's box (world units), and whether any view sees it.
    let state = |n: &assist_core::SceneNode| -> (f64, bool) {
        let out = bg.map_or(0.0, |bg| {
            let inv = &bg.world_from_local;
            n.world_corners()
                .iter()
                .map(|c| {
                    let l = inv.local_from_world_point(*c);
                    let d = (l.abs() - bg.half_size).max(assist_core::DVec3::ZERO);
                    d.length() * inv.scale.x
                })
                .fold(0.0, f64::max)
        });
        let c = n.world_from_local.translation;
        let seen = cams.is_empty()
            || cams.iter().any(|cam| {
                cam.project(c).is_some_and(|(p, _)| {
                    (0.0..cam.width() as f64).contains(&p.x)
                        && (0.0..cam.height() as f64).contains(&p.y)
                })
            });
        (out, seen)
    };
    let mut warnings = Vec::new();
    for n in after.nodes.iter().filter(|n| !n.is_background()) {
        let was = before.nodes.iter().find(|b| b.id == n.id).map(state);
        let (out, seen) = state(n);
        let (was_out, was_seen) = was.unwrap_or((0.0, true));
        if out > tol && was_out <= tol {
            warnings.push(format!(
                "node {} {:?} would stand {:.2} m outside the captured region (the background's box): what it shows there was never seen",
                n.id,
                n.label,
                out * after.meters_per_unit
            ));
        } else if !seen && was_seen {
            warnings.push(format!(
                "node {} {:?} would stand where no training camera looked (its centre is in none of the {} training views): the background around it was never seen",
                n.id,
                n.label,
                cams.len()
            ));
        }
    }
    warnings
}

/// Objects an edit pushes into the surface under them: moved, resized or new nodes whose
/// base lies at least 3 cm below the support level the background shows around them
/// ([`assist_core::edit::sinking_depth`]), 2 cm deeper than before the edit (a trained
/// surface is only good to a centimetre or so).
fn sinking(weights: &assist_session::NeuralScene, before: &Scene, after: &Scene) -> Vec<String> {
    let Some(bg) = weights.scene.nodes.iter().position(|n| n.is_background()) else {
        return Vec::new();
    };
    let mut density = |pts: &[assist_core::DVec3]| weights.density_at_world(bg, pts);
    let mut depth = |n: &assist_core::SceneNode| {
        assist_core::edit::sinking_depth(n, after.up, after.meters_per_unit, &mut density)
    };
    let mut warnings = Vec::new();
    for n in after.nodes.iter().filter(|n| !n.is_background()) {
        let was = before.nodes.iter().find(|b| b.id == n.id);
        if was
            .is_some_and(|b| b.world_from_local == n.world_from_local && b.half_size == n.half_size)
        {
            continue;
        }
        let Some(d) = depth(n) else { continue };
        let d0 = was.and_then(&mut depth).unwrap_or(0.0);
        if d >= 0.03 && d > d0 + 0.02 {
            warnings.push(format!(
                "node {} {:?} would sink about {:.0} cm into the surface under it (its base would be that far below the level the background shows around it)",
                n.id,
                n.label,
                d * 100.0
            ));
        }
    }
    warnings
}

/// Objects leaving the captured region, sinking, inside one another or floating: a
/// warning on stderr, or under `--strict` a refusal before anything changes. Returns the
/// moves `--settle` adds (one per floating object, lowering it onto its support).
pub(crate) fn check_region(
    a: &EditArgs,
    session: &mut Session,
    resolved: Option<&Resolved>,
    actions: &[Action],
) -> anyhow::Result<Vec<Action>> {
    let before = session.description().clone();
    let after = match resolved {
        Some(r) => r.scenes.last().cloned(),
        None => {
            let mut sc = before.clone();
            for e in &session.plan(actions)? {
                assist_core::edit::apply(&mut sc, e)?;
            }
            Some(sc)
        }
    };
    // The training cameras, when the scene names a dataset that is still there.
    let cams: Vec<assist_core::Camera> = assist_session::recorded_dataset(&a.scene, session.info())
        .ok()
        .flatten()
        .and_then(|d| {
            assist_session::dataset_cameras(&d, assist_session::SplitChoice::Train, 1).ok()
        })
        .map(|v| v.into_iter().map(|n| n.camera).collect())
        .unwrap_or_default();
    let mut settle = Vec::new();
    let warnings = after
        .map(|after| {
            let mut w = leaving_capture(&before, &after, &cams);
            w.extend(sinking(session.scene(), &before, &after));
            if !a.allow_overlap {
                let (problems, unchecked) = session.placement_problems(&before, &after);
                if unchecked > 0 {
                    w.push(format!(
                        "{unchecked} more changed objects were not checked for overlaps or floating (the first {} were)",
                        assist_core::placement::MAX_CHECKED
                    ));
                }
                for p in problems {
                    match (&p.problem, a.settle) {
                        (assist_session::Problem::Floating { gap_m, .. }, true) => {
                            settle.push(settle_action(p.id, *gap_m, &after));
                        }
                        (assist_session::Problem::Floating { .. }, false) => w.push(format!(
                            "{p} (--settle lowers it onto its support; --allow-overlap accepts it)"
                        )),
                        _ => w.push(format!("{p} (--allow-overlap accepts it)")),
                    }
                }
            }
            w
        })
        .unwrap_or_default();
    // A few of many (a thousand copies in one spot would print half a million lines).
    const SHOWN: usize = 10;
    let more = warnings.len().saturating_sub(SHOWN);
    let tail = (more > 0).then(|| format!("… and {more} more"));
    if a.strict && !warnings.is_empty() {
        let mut w: Vec<&str> = warnings.iter().take(SHOWN).map(String::as_str).collect();
        w.extend(tail.as_deref());
        bail!("--strict: {}", w.join("; "));
    }
    for w in warnings.iter().take(SHOWN) {
        eprintln!("warning: {w}");
    }
    if let Some(t) = tail {
        eprintln!("warning: {t}");
    }
    Ok(settle)
}

/// A move of node `id` down by `gap_m` metres along the scene's up.
fn settle_action(id: assist_core::InstanceId, gap_m: f64, scene: &Scene) -> Action {
    let down = -scene.up.normalize() * gap_m;
    Action::new(
        id,
        assist_core::Operation::Translate,
        assist_core::ActionConfig {
            vector: Some(down.to_array()),
            unit: Some("m".into()),
            ..Default::default()
        },
    )
}

/// The edit with `--settle`'s moves appended (an instruction becomes its resolved actions,
/// so that the whole is one undo step).
pub(crate) fn with_settle(
    resolved: Option<Resolved>,
    mut actions: Vec<Action>,
    settle: Vec<Action>,
    mpu: f64,
) -> (Option<Resolved>, Vec<Action>) {
    if settle.is_empty() {
        return (resolved, actions);
    }
    if let Some(r) = resolved {
        actions = r.edits.iter().map(|e| e.to_action(mpu)).collect();
    }
    actions.extend(settle);
    (None, actions)
}
