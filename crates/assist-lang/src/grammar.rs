//! Stage one: tokens → raw commands (an operation, the object phrases it names and the raw
//! quantities and words that configure it), knowing nothing about any scene.

use assist_core::Operation;
use assist_core::Operation::*;

use crate::LangError;
use crate::tokens::Tok;
use crate::words::{
    CREATED, FILLER, GENERIC, GROW, PRONOUNS, SHRINK, axis_word, direction_word, unit_word,
    verb_at, word,
};
pub use crate::words::{Direction, Unit};

/// An object as the text names it.
#[derive(Debug, Clone, PartialEq)]
pub enum ObjectRef {
    /// "object 3", "#3", "id 3".
    Id(u16),
    /// Content words, e.g. `["red", "mug"]`.
    Phrase(Vec<String>),
    /// "it", "them", "that one", "the object".
    Last,
    /// "the copy", "the duplicate", "the new one".
    Created,
}

/// Size words of a scale instruction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SizeWord {
    Bigger,
    Smaller,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawParams {
    /// Numbers in order, with the unit that followed each.
    pub quantities: Vec<(f64, Option<Unit>)>,
    /// `x`, `-y`, `up`.
    pub axis: Option<String>,
    pub direction: Option<Direction>,
    /// Axes named in the object's own frame ("its own x axis", "local y").
    pub frame_object: bool,
    pub clockwise: Option<bool>,
    pub size: Option<SizeWord>,
    /// "half", "a quarter", "a third" (as a factor).
    pub fraction: Option<f64>,
    /// "quarter turn" / "half turn" / "full turn" / "turn around", in degrees.
    pub turn: Option<f64>,
    /// "by" came before the quantity ("shrink by half"), "to" ("shrink to half").
    pub by: bool,
    pub to: bool,
    /// "as big as" / "twice as" — the quantity is the resulting size.
    pub as_: bool,
    pub path: Option<String>,
    /// Three numbers after "at" or "to", with their unit.
    pub position: Option<([f64; 3], Option<Unit>)>,
    /// "another", "one more", "a second".
    pub another: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RawCommand {
    pub op: Operation,
    pub targets: Vec<ObjectRef>,
    /// After "with" (swap).
    pub partners: Vec<ObjectRef>,
    pub params: RawParams,
    /// The clause's words, for error messages.
    pub text: String,
}

/// Object phrases being read: the current phrase, and the objects named so far as targets
/// or (after "with") partners.
#[derive(Default)]
struct Refs {
    phrase: Vec<String>,
    /// A generic noun ("the object") was read: it names the last object.
    generic: bool,
    in_partner: bool,
    targets: Vec<ObjectRef>,
    partners: Vec<ObjectRef>,
}

impl Refs {
    fn push(&mut self, r: ObjectRef) {
        if self.in_partner {
            self.partners.push(r)
        } else {
            self.targets.push(r)
        }
    }
    /// Closes the phrase being read into the current role.
    fn close(&mut self) {
        let r = if !self.phrase.is_empty() {
            Some(ObjectRef::Phrase(std::mem::take(&mut self.phrase)))
        } else if self.generic {
            Some(ObjectRef::Last)
        } else {
            None
        };
        self.generic = false;
        if let Some(r) = r {
            self.push(r);
        }
    }
}

/// Splits `toks` into clauses and parses each.
pub fn parse_raw(toks: &[Tok]) -> Result<Vec<RawCommand>, LangError> {
    let mut clauses: Vec<Vec<Tok>> = vec![Vec::new()];
    for (i, t) in toks.iter().enumerate() {
        let split = match t {
            Tok::Sep => true,
            Tok::Word(w) if w == "then" || w == "afterwards" => true,
            Tok::Word(w) if w == "and" => {
                let mut j = i + 1;
                while j < toks.len() && matches!(word(&toks[j]), Some("then" | "also" | "please")) {
                    j += 1;
                }
                verb_at(toks, j).is_some()
            }
            _ => false,
        };
        if split {
            clauses.push(Vec::new());
            if matches!(t, Tok::Word(w) if w == "and") {
                continue;
            }
            continue;
        }
        clauses.last_mut().expect("non-empty").push(t.clone());
    }
    let mut out: Vec<RawCommand> = Vec::new();
    let empty = |c: &Vec<Tok>| {
        c.iter()
            .all(|t| matches!(word(t), Some("and" | "also" | "please" | "then" | "now")))
    };
    for c in clauses.iter().filter(|c| !empty(c)) {
        parse_clause(c, &mut out)?;
    }
    if out.is_empty() {
        return Err(LangError::NoAction { text: render(toks) });
    }
    Ok(out)
}

fn render(toks: &[Tok]) -> String {
    toks.iter()
        .map(|t| match t {
            Tok::Word(w) => w.clone(),
            Tok::Num(n) => format!("{n}"),
            Tok::Path(p) => p.clone(),
            Tok::Sep => ",".into(),
        })
        .collect::<Vec<_>>()
        .join(" ")
}

fn parse_clause(toks: &[Tok], out: &mut Vec<RawCommand>) -> Result<(), LangError> {
    let text = render(toks);
    let verb = (0..toks.len()).find_map(|i| verb_at(toks, i).map(|(v, n)| (i, v, n)));
    let mut p = RawParams::default();
    let mut refs = Refs::default();
    let mut after_from = false;
    let (vi, vn) = verb.map(|(i, _, n)| (i, n)).unwrap_or((usize::MAX, 0));
    let mut op = verb.map(|(_, v, _)| v.op);
    if let Some((_, v, _)) = verb {
        p.direction = v.direction;
        if let Some(f) = v.factor {
            p.quantities.push((f, Some(Unit::Times)));
        }
        if SHRINK.contains(&v.words[0]) {
            p.size = Some(SizeWord::Smaller);
        } else if GROW.contains(&v.words[0]) {
            p.size = Some(SizeWord::Bigger);
        }
    }
    let mut i = 0;
    while i < toks.len() {
        if i == vi {
            i += vn;
            continue;
        }
        let t = &toks[i];
        let next = toks.get(i + 1).and_then(word);
        match t {
            Tok::Sep => {}
            Tok::Path(path) => {
                refs.close();
                p.path = Some(path.clone());
            }
            Tok::Num(n) => {
                refs.close();
                // Three numbers in a row after "at"/"to": a position.
                let prev = i.checked_sub(1).and_then(|j| toks.get(j)).and_then(word);
                if (matches!(prev, Some("at" | "to"))
                    || (prev == Some("position") && op == Some(Translate)))
                    && let (Some(Tok::Num(b)), Some(Tok::Num(c))) =
                        (toks.get(i + 1), toks.get(i + 2))
                {
                    let unit = toks.get(i + 3).and_then(word).and_then(unit_word);
                    p.position = Some(([*n, *b, *c], unit));
                    i += 3 + usize::from(unit.is_some());
                    continue;
                }
                match next.and_then(unit_word) {
                    Some(u) => {
                        p.quantities.push((*n, Some(u)));
                        i += 2;
                        continue;
                    }
                    None => p.quantities.push((*n, None)),
                }
            }
            Tok::Word(w) => {
                let w = w.as_str();
                if w == "one"
                    && let Some(u) = next.and_then(unit_word)
                {
                    refs.close();
                    p.quantities.push((1.0, Some(u)));
                    i += 2;
                    continue;
                }
                if matches!(w, "copies" | "copy" | "duplicates" | "clones" | "replicas")
                    && op == Some(Scale)
                    && verb.is_some_and(|(_, v, _)| v.words == ["make"])
                {
                    op = Some(Replicate);
                    i += 1;
                    continue;
                }
                let is_id_word =
                    matches!(w, "object" | "node" | "instance" | "id" | "number" | "no");
                if is_id_word && let Some(Tok::Num(n)) = toks.get(i + 1) {
                    refs.close();
                    if *n < 0.0 || n.fract() != 0.0 || *n > u16::MAX as f64 {
                        return Err(LangError::BadValue {
                            what: "object id".into(),
                            clause: text,
                            message: format!("expected a whole number, got {n}"),
                        });
                    }
                    refs.push(ObjectRef::Id(*n as u16));
                    i += 2;
                    continue;
                }
                if matches!(w, "local" | "own")
                    || (w == "object"
                        && matches!(
                            next,
                            Some("frame" | "axis" | "x" | "y" | "z" | "coordinates")
                        ))
                {
                    p.frame_object = true;
                } else if matches!(w, "world" | "global") {
                    p.frame_object = false;
                } else if matches!(w, "negative" | "minus")
                    && let Some(a) = next.and_then(axis_word)
                {
                    p.axis = Some(format!("-{}", a.trim_start_matches('-')));
                    i += 2;
                    continue;
                } else if matches!(w, "positive" | "plus")
                    && let Some(a) = next.and_then(axis_word)
                {
                    p.axis = Some(a.to_string());
                    i += 2;
                    continue;
                } else if let Some(a) = axis_word(w) {
                    refs.close();
                    p.axis = Some(a.to_string());
                } else if w == "times" {
                    // "2 times": the unit of the number before.
                    if let Some(last) = p.quantities.last_mut()
                        && last.1.is_none()
                    {
                        last.1 = Some(Unit::Times);
                    }
                } else if w == "twice" || w == "thrice" {
                    p.quantities
                        .push((if w == "twice" { 2.0 } else { 3.0 }, Some(Unit::Times)));
                } else if matches!(w, "double" | "triple" | "quadruple") {
                    let f = match w {
                        "double" => 2.0,
                        "triple" => 3.0,
                        _ => 4.0,
                    };
                    p.quantities.push((f, Some(Unit::Times)));
                } else if matches!(w, "quarter" | "half" | "third") {
                    let is_turn =
                        matches!(next, Some("turn" | "rotation" | "revolution" | "circle"));
                    let f = match w {
                        "quarter" => 0.25,
                        "half" => 0.5,
                        _ => 1.0 / 3.0,
                    };
                    if is_turn {
                        p.turn = Some(360.0 * f);
                        i += 2;
                        continue;
                    }
                    p.fraction = Some(f);
                } else if matches!(w, "full" | "complete" | "whole")
                    && matches!(next, Some("turn" | "rotation" | "revolution" | "circle"))
                {
                    p.turn = Some(360.0);
                    i += 2;
                    continue;
                } else if w == "clockwise" {
                    p.clockwise = Some(true);
                } else if w == "counterclockwise" {
                    p.clockwise = Some(false);
                } else if matches!(
                    w,
                    "bigger"
                        | "larger"
                        | "big"
                        | "large"
                        | "huge"
                        | "taller"
                        | "tall"
                        | "grow"
                        | "wider"
                        | "longer"
                ) {
                    refs.close();
                    p.size = Some(SizeWord::Bigger);
                    if matches!(w, "taller" | "tall") && p.axis.is_none() {
                        p.axis = Some("up".into());
                    }
                } else if matches!(
                    w,
                    "smaller"
                        | "small"
                        | "tiny"
                        | "tinier"
                        | "shorter"
                        | "short"
                        | "narrower"
                        | "thinner"
                ) {
                    refs.close();
                    p.size = Some(SizeWord::Smaller);
                    if matches!(w, "shorter" | "short") && p.axis.is_none() {
                        p.axis = Some("up".into());
                    }
                } else if w == "as" {
                    refs.close();
                    p.as_ = true;
                } else if w == "by" {
                    refs.close();
                    p.by = true;
                } else if w == "to" {
                    refs.close();
                    p.to = true;
                } else if w == "at" {
                    refs.close();
                } else if w == "from" {
                    refs.close();
                    after_from = true;
                } else if w == "with" || w == "for" {
                    refs.close();
                    refs.in_partner = true;
                } else if w == "and" || w == "&" || w == "plus" {
                    refs.close();
                } else if w == "around"
                    && op == Some(Rotate)
                    && !toks[i + 1..].iter().any(|t| {
                        matches!(t, Tok::Num(_)) || word(t).is_some_and(|w| axis_word(w).is_some())
                    })
                {
                    refs.close();
                    p.turn.get_or_insert(180.0);
                } else if matches!(w, "another" | "more" | "second" | "extra") {
                    p.another = true;
                    if op == Some(Add) {
                        op = Some(Replicate);
                    }
                } else if let Some(d) = direction_word(w).filter(|_| op != Some(Select)) {
                    refs.close();
                    p.direction = Some(d);
                } else if PRONOUNS.contains(&w) && !(w == "that" || w == "this") {
                    refs.close();
                    refs.push(ObjectRef::Last);
                } else if (w == "that" || w == "this")
                    && matches!(
                        next,
                        None | Some("one" | "object" | "thing" | "to" | "by" | "and" | "with")
                    )
                {
                    refs.close();
                    refs.push(ObjectRef::Last);
                    if next == Some("one") {
                        i += 1;
                    }
                } else if CREATED.contains(&w)
                    && (i == 0
                        || matches!(
                            toks.get(i - 1).and_then(word),
                            Some("the" | "that" | "this" | "a" | "new")
                        ))
                    && !(w == "new"
                        && next.is_some_and(|n| !GENERIC.contains(&n) && !CREATED.contains(&n)))
                {
                    refs.close();
                    refs.push(ObjectRef::Created);
                    if w == "new" && next.is_some() {
                        i += 1;
                    }
                } else if GENERIC.contains(&w) {
                    refs.generic = true;
                } else if after_from
                    && matches!(w, "scene" | "table" | "desk" | "room" | "floor")
                    && refs.phrase.is_empty()
                {
                    // "remove the duck from the scene"
                } else if FILLER.contains(&w) {
                    if !refs.phrase.is_empty() && !matches!(w, "the" | "a" | "an") {
                        refs.close();
                    }
                } else {
                    refs.phrase.push(w.to_string());
                }
            }
        }
        i += 1;
    }
    refs.close();
    let Refs {
        mut targets,
        partners,
        ..
    } = refs;
    let Some(mut op) = op else {
        // No verb: a continuation of the previous command.
        let Some(prev) = out.last().cloned() else {
            return Err(LangError::NoAction { text });
        };
        let has_params = !p.quantities.is_empty()
            || p.direction.is_some()
            || p.axis.is_some()
            || p.turn.is_some()
            || p.position.is_some();
        if !has_params && !targets.is_empty() {
            out.last_mut().expect("prev").targets.extend(targets);
            return Ok(());
        }
        if !has_params {
            return Err(LangError::NoAction { text });
        }
        out.push(RawCommand {
            op: prev.op,
            targets: if targets.is_empty() {
                vec![ObjectRef::Last]
            } else {
                targets
            },
            partners,
            params: p,
            text,
        });
        return Ok(());
    };
    if op == Translate && p.path.is_some() {
        op = Add; // "put the mic from ../b.assist at …"
    }
    if op == Scale
        && verb.is_some_and(|(_, v, _)| v.words == ["make"])
        && p.size.is_none()
        && p.quantities.is_empty()
        && p.fraction.is_none()
    {
        return Err(LangError::NoAction { text });
    }
    if targets.is_empty() && partners.is_empty() {
        targets.push(ObjectRef::Last);
    }
    out.push(RawCommand {
        op,
        targets,
        partners,
        params: p,
        text,
    });
    Ok(())
}
