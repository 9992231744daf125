//! Places relative to other objects: "next to", "beside", "near"; "on", "onto", "on top
//! of"; "in front of"; "behind"; "between". Each becomes one move of the object's box:
//!
//! - next to: beside the other object on the side where the object already is (seen from
//!   above; the right, as directions read, when it stands right on top), its box a gap
//!   from the other's;
//! - in front of / behind: on the other object's side towards / away from the viewer —
//!   the camera the instruction is read through (`--data DATA --frame NAME`, or the
//!   viewer's view), else the world's back (−y for a z-up scene: "back" as the direction
//!   words read) / forward;
//! - on: centred over the other object, its base on the other's top;
//! - between: centred between two objects.
//!
//! Beside, in front and behind keep the object resting where the other one rests (its
//! base at the other's base). The gap is 2 cm, or the distance the instruction gives
//! ("5 cm behind the cow").

use super::*;
use crate::grammar::Relation;

/// The gap between two boxes placed side by side, metres.
pub const GAP_M: f64 = 0.02;

/// The move that puts node `id` where `cmd`'s relation to its partners says.
pub(super) fn place(
    id: InstanceId,
    cmd: &RawCommand,
    st: &State,
    opts: &ParseOptions,
) -> Result<ActionConfig, LangError> {
    let (rel, words) = cmd.params.relation.clone().expect("a relation");
    let scene = &st.scene;
    let up = scene.up.normalize();
    let mpu = scene.meters_per_unit;
    let partners: Vec<InstanceId> = cmd
        .partners
        .iter()
        .map(|r| one(st, r, cmd, opts))
        .collect::<Result<_, _>>()?;
    let want = if rel == Relation::Between { 2 } else { 1 };
    if partners.len() != want {
        return Err(clause_err(
            cmd,
            &words,
            format!(
                "{words:?} needs {want} other object{}, got {}",
                if want == 1 { "" } else { "s" },
                partners.len()
            ),
        ));
    }
    if partners.contains(&id) {
        return Err(clause_err(
            cmd,
            &words,
            "an object cannot be placed relative to itself",
        ));
    }
    let node = scene.node(id).expect("resolved");
    let others: Vec<&assist_core::SceneNode> = partners
        .iter()
        .map(|p| scene.node(*p).expect("resolved"))
        .collect();
    let gap = match distance(cmd)? {
        Some(d) if d >= 0.0 => d / mpu,
        Some(d) => {
            return Err(clause_err(
                cmd,
                "distance",
                format!("expected a gap of 0 or more, got {d} m"),
            ));
        }
        None => GAP_M / mpu,
    };
    let flat = |v: DVec3| v - up * v.dot(up);
    let centre = |n: &assist_core::SceneNode| n.world_from_local.translation;
    let (o, c) = (others[0], centre(node));
    // Where the node's centre goes, horizontally, and the level its base goes to.
    let (spot, base_to) = match rel {
        Relation::NextTo | Relation::InFront | Relation::Behind => {
            let d = match rel {
                Relation::InFront => direction_vector(Direction::Back, up, opts.camera),
                Relation::Behind => direction_vector(Direction::Forward, up, opts.camera),
                _ => {
                    let away = flat(c - centre(o));
                    if away.length() > 1e-9 {
                        away.normalize()
                    } else {
                        direction_vector(Direction::Right, up, opts.camera)
                    }
                }
            };
            let reach = extent(o, d) + extent(node, d) + gap;
            (flat(centre(o)) + d * reach, base(o, up))
        }
        Relation::On => (flat(centre(o)), top(o, up)),
        Relation::Between => {
            let p = others[1];
            (
                flat((centre(o) + centre(p)) / 2.0),
                (base(o, up) + base(p, up)) / 2.0,
            )
        }
    };
    let target = spot + up * (c.dot(up) + base_to - base(node, up));
    Ok(ActionConfig {
        vector: Some(((target - c) * mpu).to_array()),
        unit: Some("m".into()),
        ..Default::default()
    })
}

/// How far `n`'s box reaches from its centre along the unit direction `d`.
fn extent(n: &assist_core::SceneNode, d: DVec3) -> f64 {
    let w = &n.world_from_local;
    (0..3)
        .map(|a| (w.rotation * DVec3::AXES[a]).dot(d).abs() * n.half_size[a] * w.scale[a])
        .sum()
}

fn base(n: &assist_core::SceneNode, up: DVec3) -> f64 {
    n.world_corners()
        .iter()
        .map(|c| c.dot(up))
        .fold(f64::INFINITY, f64::min)
}

fn top(n: &assist_core::SceneNode, up: DVec3) -> f64 {
    n.world_corners()
        .iter()
        .map(|c| c.dot(up))
        .fold(f64::NEG_INFINITY, f64::max)
}
