//! Stage two: raw commands → validated actions for one scene. Objects are found by id,
//! label (`names`), pronoun or "the copy"; quantities become configs; every action is
//! validated by assist-core against the scene as the previous actions left it, so an
//! instruction either yields actions that apply or an error saying what is wrong.

use std::collections::BTreeSet;

use assist_core::action::{ActionConfig, NodeRef, describe_nodes};
use assist_core::{Action, DMat3, DVec3, InstanceId, Operation, Scene, SceneSource};

use crate::LangError;
use crate::grammar::{Direction, ObjectRef, RawCommand, SizeWord, Unit};
use crate::names::{Found, NotFound, TextEmbedder, find};

mod actions;
mod relations;
pub use actions::resolve;

/// Amounts an instruction leaves unsaid: a move "to the right" goes 10 cm ("a bit",
/// "slightly", "a little": 5 cm), a turn 90° (15°), "bigger" is ×1.25 and "smaller" its
/// inverse, ×0.8 (×1.1 and ×1/1.1).
pub const DEFAULT_DISTANCE_M: [f64; 2] = [0.10, 0.05];
pub const DEFAULT_ANGLE_DEG: [f64; 2] = [90.0, 15.0];
pub const DEFAULT_GROW: [f64; 2] = [1.25, 1.1];

/// What the parser may know besides the text.
#[derive(Default)]
pub struct ParseOptions<'a> {
    /// Camera-to-world rotation of the view the user looks through: left/right/forward/back
    /// are then relative to it (projected onto the floor); without it they are world axes.
    pub camera: Option<DMat3>,
    /// What "it" means before any object is named (e.g. the selected node).
    pub last: Option<InstanceId>,
    pub embedder: Option<&'a dyn TextEmbedder>,
    /// Scale about the box centre; by default an object is scaled about its resting point
    /// (the middle of its box's lowest face along the scene's up), so that "make the cone
    /// twice as big" keeps its base on the table.
    pub scale_about_center: bool,
}

/// Where a node rests: the point of its box lowest along `up`, moved under the box centre.
fn resting_point(node: &assist_core::SceneNode, up: DVec3) -> DVec3 {
    let up = up.normalize();
    let c = node.world_from_local.translation;
    let low = node
        .world_corners()
        .iter()
        .map(|p| p.dot(up))
        .fold(f64::INFINITY, f64::min);
    c - up * (c.dot(up) - low)
}

struct State {
    scene: Scene,
    last: Vec<InstanceId>,
    created: Option<InstanceId>,
}

/// World direction of a direction word.
pub fn direction_vector(d: Direction, up: DVec3, camera: Option<DMat3>) -> DVec3 {
    let up = up.normalize();
    let flat = |v: DVec3| {
        let f = v - up * v.dot(up);
        (f.length() > 1e-6).then(|| f.normalize())
    };
    let (right, forward) = match camera {
        Some(r) => {
            let right = flat(r * DVec3::X).unwrap_or_else(|| default_right(up));
            let forward = flat(r * DVec3::NEG_Z)
                .or_else(|| flat(r * DVec3::Y))
                .unwrap_or_else(|| up.cross(right));
            (right, forward)
        }
        None => {
            let right = default_right(up);
            (right, up.cross(right))
        }
    };
    match d {
        Direction::Left => -right,
        Direction::Right => right,
        Direction::Up => up,
        Direction::Down => -up,
        Direction::Forward => forward,
        Direction::Back => -forward,
    }
}

fn default_right(up: DVec3) -> DVec3 {
    let x = if up.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    (x - up * x.dot(up)).normalize()
}

fn clause_err(cmd: &RawCommand, what: &str, message: impl Into<String>) -> LangError {
    LangError::BadValue {
        what: what.into(),
        clause: cmd.text.clone(),
        message: message.into(),
    }
}

fn candidates(scene: &Scene, ids: &[InstanceId]) -> String {
    ids.iter()
        .filter_map(|id| scene.node(*id))
        .map(|n| format!("{} {:?}", n.id, n.label))
        .collect::<Vec<_>>()
        .join(", ")
}

impl State {
    fn objects(
        &self,
        r: &ObjectRef,
        cmd: &RawCommand,
        embedder: Option<&dyn TextEmbedder>,
    ) -> Result<Vec<InstanceId>, LangError> {
        match r {
            ObjectRef::Id(id) => {
                if self.scene.node(*id).is_none() {
                    return Err(LangError::UnknownObject {
                        phrase: format!("object {id}"),
                        candidates: describe_nodes(&self.scene),
                        hint: String::new(),
                    });
                }
                Ok(vec![*id])
            }
            ObjectRef::Last => {
                if self.last.is_empty() {
                    Err(LangError::NoAntecedent {
                        clause: cmd.text.clone(),
                        candidates: describe_nodes(&self.scene),
                    })
                } else {
                    Ok(self.last.clone())
                }
            }
            ObjectRef::Created => {
                // The copy this instruction made, else the newest copy in the scene (a
                // replica: its label is not its class).
                self.created
                    .or_else(|| {
                        self.scene
                            .nodes
                            .iter()
                            .filter(|n| n.class.as_deref().is_some_and(|c| c != n.label))
                            .map(|n| n.id)
                            .max()
                    })
                    .map(|c| vec![c])
                    .ok_or_else(|| LangError::NoAntecedent {
                        clause: cmd.text.clone(),
                        candidates: describe_nodes(&self.scene),
                    })
            }
            ObjectRef::Phrase(words) => {
                let said = described(cmd, words);
                phrase_said(words, &said, &self.scene, embedder)
            }
            ObjectRef::All(None) => {
                let ids: Vec<InstanceId> = self
                    .scene
                    .nodes
                    .iter()
                    .filter(|n| !n.is_background())
                    .map(|n| n.id)
                    .collect();
                if ids.is_empty() {
                    return Err(clause_err(cmd, "objects", "the scene has no objects"));
                }
                Ok(ids)
            }
            // "every ball", "all the mugs": every node the words name, one or many.
            ObjectRef::All(Some(words)) => match find(words, &words.join(" "), &self.scene, None) {
                Ok(Found::One(id)) => Ok(vec![id]),
                Ok(Found::Many(ids)) | Err(NotFound::Ambiguous(ids)) => Ok(ids),
                Err(_) => phrase_said(words, &words.join(" "), &self.scene, embedder),
            },
        }
    }

    /// The objects an exclusion names. Its words are read among the targets first ("the
    /// boxes except the red one": the red box, though a red mug is in the scene too).
    fn excluded(
        &self,
        r: &ObjectRef,
        targets: &[InstanceId],
        cmd: &RawCommand,
        embedder: Option<&dyn TextEmbedder>,
    ) -> Result<Vec<InstanceId>, LangError> {
        if let ObjectRef::Phrase(words) = r
            && let Err(NotFound::Ambiguous(ids)) = find(words, &words.join(" "), &self.scene, None)
        {
            let inside: Vec<InstanceId> = ids
                .iter()
                .copied()
                .filter(|i| targets.contains(i))
                .collect();
            if inside.len() == 1 {
                return Ok(inside);
            }
        }
        self.objects(r, cmd, embedder)
    }

    /// The targets of `cmd` less the objects it excludes ("everything except the mug");
    /// each excluded object must be among the targets, and something must be left.
    fn targets(
        &self,
        cmd: &RawCommand,
        embedder: Option<&dyn TextEmbedder>,
    ) -> Result<Vec<InstanceId>, LangError> {
        let mut ids = Vec::new();
        for r in &cmd.targets {
            for id in self.objects(r, cmd, embedder)? {
                if !ids.contains(&id) {
                    ids.push(id);
                }
            }
        }
        for r in &cmd.excluded {
            for id in self.excluded(r, &ids, cmd, embedder)? {
                let Some(k) = ids.iter().position(|x| *x == id) else {
                    let label = self.scene.node(id).map_or("?", |n| n.label.as_str());
                    return Err(clause_err(
                        cmd,
                        "except",
                        format!("object {id} {label:?} is not among the objects named before it"),
                    ));
                };
                ids.remove(k);
            }
        }
        if !cmd.excluded.is_empty() && ids.is_empty() {
            return Err(clause_err(
                cmd,
                "except",
                "nothing is left once the excepted objects are taken out",
            ));
        }
        Ok(ids)
    }
}

/// How the user described the one object a clause names, for comparing meanings: the
/// clause without its verb, numbers, units, directions, axes and articles ("move
/// the thing you drink from 5 cm left" → "thing you drink from"). The parser's phrase
/// keeps only content words ("drink"); meaning needs the whole description. A clause
/// naming several objects gives the phrase's words.
fn described(cmd: &RawCommand, words: &[String]) -> String {
    use crate::tokens::{Tok, tokenize};
    use crate::words::{axis_word, direction_word, unit_word, verb_at};
    let plain = words.join(" ");
    if cmd.targets.len() + cmd.partners.len() != 1 {
        return plain;
    }
    let toks = tokenize(&cmd.text);
    let mut out: Vec<&str> = Vec::new();
    let mut i = 0;
    while i < toks.len() {
        if let Some((_, n)) = verb_at(&toks, i) {
            i += n;
            continue;
        }
        if let Tok::Word(w) = &toks[i] {
            let w = w.as_str();
            let skip = unit_word(w).is_some()
                || direction_word(w).is_some()
                || axis_word(w).is_some()
                || matches!(
                    w,
                    "by" | "to"
                        | "degrees"
                        | "degree"
                        | "times"
                        | "percent"
                        | "please"
                        | "and"
                        | "the"
                        | "a"
                        | "an"
                );
            if !skip {
                out.push(w);
            }
        }
        i += 1;
    }
    // Only a description that still holds every word of the phrase.
    if out.is_empty() || !words.iter().all(|w| out.contains(&w.as_str())) {
        return plain;
    }
    out.join(" ")
}

fn phrase_in(
    words: &[String],
    scene: &Scene,
    embedder: Option<&dyn TextEmbedder>,
) -> Result<Vec<InstanceId>, LangError> {
    phrase_said(words, &words.join(" "), scene, embedder)
}

/// [`phrase_in`], comparing meanings with `said` (the object as described).
fn phrase_said(
    words: &[String],
    said: &str,
    scene: &Scene,
    embedder: Option<&dyn TextEmbedder>,
) -> Result<Vec<InstanceId>, LangError> {
    match find(words, said, scene, embedder) {
        Ok(Found::One(id)) => Ok(vec![id]),
        Ok(Found::Many(ids)) => Ok(ids),
        Err(NotFound::Unknown(why)) => Err(LangError::UnknownObject {
            phrase: words.join(" "),
            candidates: describe_nodes(scene),
            hint: why.hint().to_string(),
        }),
        Err(NotFound::TooClose(scores)) => Err(LangError::TooClose {
            phrase: said.to_string(),
            scores: scores
                .iter()
                .map(|(id, s)| {
                    let label = scene.node(*id).map(|n| n.label.as_str()).unwrap_or("?");
                    format!("{id} {label:?} {s:.3}")
                })
                .collect::<Vec<_>>()
                .join(", "),
        }),
        Err(NotFound::Ambiguous(ids)) => Err(LangError::Ambiguous {
            phrase: words.join(" "),
            candidates: candidates(scene, &ids),
        }),
    }
}

/// The distance of a translate: the first length (or unitless number = metres).
fn distance(cmd: &RawCommand) -> Result<Option<f64>, LangError> {
    if let Some(&(v, u)) = cmd.params.quantities.first() {
        match u {
            None => return Ok(Some(v)),
            Some(Unit::Length(m)) => return Ok(Some(v * m)),
            Some(Unit::Degrees | Unit::Radians) => {
                return Err(clause_err(cmd, "distance", "an angle is not a distance"));
            }
            Some(_) => {
                return Err(clause_err(
                    cmd,
                    "distance",
                    "expected a length such as 10 cm",
                ));
            }
        }
    }
    Ok(None)
}

/// The offset of a translate or replicate, in metres (None when none was given).
fn offset(
    cmd: &RawCommand,
    st: &State,
    opts: &ParseOptions,
) -> Result<Option<ActionConfig>, LangError> {
    let p = &cmd.params;
    let lengths: Vec<f64> = p
        .quantities
        .iter()
        .filter_map(|&(v, u)| match u {
            None => Some(v),
            Some(Unit::Length(m)) => Some(v * m),
            _ => None,
        })
        .collect();
    if lengths.len() == 3 && p.direction.is_none() && p.axis.is_none() {
        return Ok(Some(ActionConfig {
            vector: Some([lengths[0], lengths[1], lengths[2]]),
            unit: Some("m".into()),
            frame: p.frame_object.then(|| "object".into()),
            ..Default::default()
        }));
    }
    // "10 cm left and 3 cm down": one distance per direction, the offsets summed.
    if let Some(first) = p.direction
        && !p.more_directions.is_empty()
    {
        let dirs: Vec<_> = std::iter::once(first)
            .chain(p.more_directions.iter().copied())
            .collect();
        if lengths.len() != dirs.len() || p.quantities.len() != dirs.len() || p.axis.is_some() {
            return Err(clause_err(
                cmd,
                "direction",
                format!(
                    "{} directions need {} distances, one each (e.g. \"10 cm left and 3 cm down\")",
                    dirs.len(),
                    dirs.len()
                ),
            ));
        }
        let v = dirs
            .iter()
            .zip(&lengths)
            .map(|(&dir, &d)| direction_vector(dir, st.scene.up, opts.camera) * d)
            .fold(DVec3::ZERO, |a, b| a + b);
        return Ok(Some(ActionConfig {
            vector: Some(v.to_array()),
            unit: Some("m".into()),
            ..Default::default()
        }));
    }
    let d = distance(cmd)?;
    match (d, p.direction, &p.axis) {
        (None, None, None) => Ok(None),
        (Some(d), None, Some(axis)) => Ok(Some(ActionConfig {
            axis: Some(assist_core::AxisSpec::Name(axis.clone())),
            distance: Some(d),
            unit: Some("m".into()),
            frame: p.frame_object.then(|| "object".into()),
            ..Default::default()
        })),
        (Some(d), Some(dir), None) => {
            let v = direction_vector(dir, st.scene.up, opts.camera) * d;
            Ok(Some(ActionConfig {
                vector: Some(v.to_array()),
                unit: Some("m".into()),
                ..Default::default()
            }))
        }
        (Some(_), Some(_), Some(_)) => Err(clause_err(
            cmd,
            "direction",
            "give either an axis or a direction word, not both",
        )),
        (Some(_), None, None) => Err(clause_err(
            cmd,
            "direction",
            "which way? give an axis (x, y, z) or a direction (left, right, up, down, forward, back)",
        )),
        (None, Some(dir), None) if p.quantities.is_empty() => {
            let d = DEFAULT_DISTANCE_M[usize::from(p.slight)];
            let v = direction_vector(dir, st.scene.up, opts.camera) * d;
            Ok(Some(ActionConfig {
                vector: Some(v.to_array()),
                unit: Some("m".into()),
                ..Default::default()
            }))
        }
        (None, _, _) => Err(clause_err(
            cmd,
            "distance",
            "how far? give a distance such as 10 cm",
        )),
    }
}

fn angle(cmd: &RawCommand) -> Result<f64, LangError> {
    let p = &cmd.params;
    let a = match p.quantities.first() {
        None => None,
        Some(&(v, u)) => Some(match u {
            None | Some(Unit::Degrees) => v,
            Some(Unit::Radians) => v.to_degrees(),
            Some(Unit::Length(_)) => {
                return Err(clause_err(cmd, "angle", "a length is not an angle"));
            }
            Some(_) => {
                return Err(clause_err(
                    cmd,
                    "angle",
                    "expected an angle such as 90 degrees",
                ));
            }
        }),
    };
    let a = a
        .or(p.turn)
        .unwrap_or(DEFAULT_ANGLE_DEG[usize::from(p.slight)]);
    Ok(if p.clockwise == Some(true) { -a } else { a })
}

fn factor(cmd: &RawCommand) -> Result<f64, LangError> {
    let p = &cmd.params;
    let q = p
        .quantities
        .iter()
        .find(|(_, u)| !matches!(u, Some(Unit::Length(_) | Unit::Degrees | Unit::Radians)));
    let f = match (q, p.fraction) {
        (Some(&(v, Some(Unit::Percent))), _) => {
            let pct = v / 100.0;
            match p.size {
                _ if p.to => pct,
                Some(SizeWord::Bigger) => 1.0 + pct,
                Some(SizeWord::Smaller) => 1.0 - pct,
                None => pct,
            }
        }
        (Some(&(v, _)), _) => match p.size {
            Some(SizeWord::Smaller) if v > 1.0 => 1.0 / v,
            Some(SizeWord::Smaller) if p.by && !p.to && v < 1.0 => 1.0 - v,
            Some(SizeWord::Bigger) if p.by && !p.to && v < 1.0 => 1.0 + v,
            _ => v,
        },
        (None, Some(f)) => match p.size {
            Some(SizeWord::Bigger) if !p.as_ && !p.to => 1.0 + f,
            _ => f,
        },
        (None, None) => match p.size {
            Some(SizeWord::Bigger) => DEFAULT_GROW[usize::from(p.slight)],
            Some(SizeWord::Smaller) => 1.0 / DEFAULT_GROW[usize::from(p.slight)],
            None => {
                return Err(clause_err(
                    cmd,
                    "factor",
                    "by how much? give a factor such as 2, 'twice as big' or 50%",
                ));
            }
        },
    };
    Ok(f)
}

/// An instruction resolved against a scene: its actions, each validated once against the
/// scene as the previous ones left it, with the edit it makes and the scene after it.
/// An editor installs these as they are, without validating again.
#[derive(Debug, Clone, Default)]
pub struct Resolved {
    pub actions: Vec<Action>,
    pub edits: Vec<assist_core::Edit>,
    pub scenes: Vec<Scene>,
}

fn single(ids: Vec<InstanceId>, words: &[String], scene: &Scene) -> Result<InstanceId, LangError> {
    match ids.as_slice() {
        [one] => Ok(*one),
        _ => Err(LangError::Ambiguous {
            phrase: words.join(" "),
            candidates: candidates(scene, &ids),
        }),
    }
}

fn one(
    st: &State,
    r: &ObjectRef,
    cmd: &RawCommand,
    opts: &ParseOptions,
) -> Result<InstanceId, LangError> {
    let ids = st.objects(r, cmd, opts.embedder)?;
    match ids.as_slice() {
        [one] => Ok(*one),
        _ => Err(LangError::Ambiguous {
            phrase: format!("{r:?}"),
            candidates: candidates(&st.scene, &ids),
        }),
    }
}

fn unit_metres(u: Option<Unit>) -> f64 {
    match u {
        Some(Unit::Length(m)) => m,
        _ => 1.0,
    }
}

fn unit_name(u: Option<Unit>, cmd: &RawCommand) -> Result<String, LangError> {
    match u {
        None => Ok("m".into()),
        Some(Unit::Length(1.0)) => Ok("m".into()),
        Some(Unit::Length(0.01)) => Ok("cm".into()),
        Some(Unit::Length(0.001)) => Ok("mm".into()),
        _ => Err(clause_err(
            cmd,
            "position",
            "expected a position in m, cm or mm",
        )),
    }
}
