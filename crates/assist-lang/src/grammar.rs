//! Stage one: tokens → raw commands (an operation, the object phrases it names and the raw
//! quantities and words that configure it), knowing nothing about any scene.

use assist_core::Operation;
use assist_core::Operation::*;

use crate::LangError;
use crate::tokens::Tok;
use crate::words::{
    CREATED, FILLER, GENERIC, GROW, MEANING_CHANGING, PRONOUNS, RELATIVE_PLACEMENT, SHRINK, Verb,
    axis_word, direction_word, unit_word, verb_at, word,
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
    /// "everything", "all objects" (`None`: every object of the scene), "all the balls",
    /// "every ball" (every object the words name).
    All(Option<Vec<String>>),
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
    /// Directions after the first ("10 cm left and 3 cm down"), in order.
    pub more_directions: Vec<Direction>,
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
    /// After "except", "but" (after a quantifier), "other than", "apart from", "excluding":
    /// objects taken out of the targets.
    pub excluded: Vec<ObjectRef>,
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
    /// A quantifier ("all", "every", "each", "both") opened the phrase being read.
    quantified: bool,
    /// An exclusion word was read: what follows is taken out of the targets.
    in_excluded: bool,
    targets: Vec<ObjectRef>,
    partners: Vec<ObjectRef>,
    excluded: Vec<ObjectRef>,
}

impl Refs {
    fn push(&mut self, r: ObjectRef) {
        if self.in_excluded {
            self.excluded.push(r)
        } else if self.in_partner {
            self.partners.push(r)
        } else {
            self.targets.push(r)
        }
    }
    /// Closes the phrase being read into the current role.
    fn close(&mut self) {
        let quantified = std::mem::take(&mut self.quantified);
        let r = if quantified {
            let words = std::mem::take(&mut self.phrase);
            Some(ObjectRef::All((!words.is_empty()).then_some(words)))
        } else if !self.phrase.is_empty() {
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
    let mut c = Clause::new(toks);
    let (vi, vn) = c.verb.map(|(i, _, n)| (i, n)).unwrap_or((usize::MAX, 0));
    let mut i = 0;
    while i < toks.len() {
        i += if i == vi { vn } else { c.token(i)? };
    }
    c.refs.close();
    c.finish(out)
}

/// One clause being read: its verb, the operation so far, the parameters and the object
/// phrases. Each `*_word` method reads one class of words and returns how many tokens it
/// used, or `None` when the word is not of its class.
struct Clause<'a> {
    toks: &'a [Tok],
    text: String,
    /// The verb: its token index, its entry and its word count.
    verb: Option<(usize, &'static Verb, usize)>,
    op: Option<Operation>,
    p: RawParams,
    refs: Refs,
    /// "from" was read: "the scene", "the table" after it name no object.
    after_from: bool,
    /// The index of the token being read.
    pos: usize,
}

impl<'a> Clause<'a> {
    fn new(toks: &'a [Tok]) -> Self {
        let verb = (0..toks.len()).find_map(|i| verb_at(toks, i).map(|(v, n)| (i, v, n)));
        let mut p = RawParams::default();
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
        Clause {
            toks,
            text: render(toks),
            verb,
            op: verb.map(|(_, v, _)| v.op),
            p,
            refs: Refs::default(),
            after_from: false,
            pos: 0,
        }
    }

    fn word_at(&self, i: usize) -> Option<&'a str> {
        self.toks.get(i).and_then(word)
    }

    fn verb_is_make(&self) -> bool {
        self.verb.is_some_and(|(_, v, _)| v.words == ["make"])
    }

    /// Reads the token at `i`; returns how many tokens it used.
    fn token(&mut self, i: usize) -> Result<usize, LangError> {
        self.pos = i;
        Ok(match &self.toks[i] {
            Tok::Sep => 1,
            Tok::Path(path) => {
                self.refs.close();
                self.p.path = Some(path.clone());
                1
            }
            Tok::Num(n) => self.number(i, *n),
            Tok::Word(w) => {
                let (w, next) = (w.as_str(), self.word_at(i + 1));
                match self.id_word(i, w, next)? {
                    Some(k) => k,
                    None => match self.quantifier_word(w, next)? {
                        Some(k) => k,
                        None => self
                            .axis_word(w, next)
                            .or_else(|| self.amount_word(w, next))
                            .or_else(|| self.connective_word(i, w))
                            .unwrap_or_else(|| self.object_word(i, w, next)),
                    },
                }
            }
        })
    }

    /// A number: a position after "at"/"to" (three numbers), or a quantity with the unit
    /// that follows it.
    fn number(&mut self, i: usize, n: f64) -> usize {
        let toks = self.toks;
        self.refs.close();
        let prev = i.checked_sub(1).and_then(|j| self.word_at(j));
        if (matches!(prev, Some("at" | "to"))
            || (prev == Some("position") && self.op == Some(Translate)))
            && let (Some(Tok::Num(b)), Some(Tok::Num(c))) = (toks.get(i + 1), toks.get(i + 2))
        {
            let unit = self.word_at(i + 3).and_then(unit_word);
            self.p.position = Some(([n, *b, *c], unit));
            return 3 + usize::from(unit.is_some());
        }
        match self.word_at(i + 1).and_then(unit_word) {
            Some(u) => {
                self.p.quantities.push((n, Some(u)));
                2
            }
            None => {
                self.p.quantities.push((n, None));
                1
            }
        }
    }

    /// "one metre", "make two copies", "object 3".
    fn id_word(
        &mut self,
        i: usize,
        w: &str,
        next: Option<&str>,
    ) -> Result<Option<usize>, LangError> {
        if w == "one"
            && let Some(u) = next.and_then(unit_word)
        {
            self.refs.close();
            self.p.quantities.push((1.0, Some(u)));
            return Ok(Some(2));
        }
        if matches!(w, "copies" | "copy" | "duplicates" | "clones" | "replicas")
            && self.op == Some(Scale)
            && self.verb_is_make()
            // "make the copy twice as big" names an object; "make a copy", "make two copies" do not
            && !matches!(
                i.checked_sub(1).and_then(|j| self.toks.get(j)),
                Some(Tok::Word(p)) if matches!(p.as_str(), "the" | "that" | "this")
            )
        {
            self.op = Some(Replicate);
            return Ok(Some(1));
        }
        let is_id_word = matches!(w, "object" | "node" | "instance" | "id" | "number" | "no");
        if is_id_word && let Some(Tok::Num(n)) = self.toks.get(i + 1) {
            self.refs.close();
            if *n < 0.0 || n.fract() != 0.0 || *n > u16::MAX as f64 {
                return Err(LangError::BadValue {
                    what: "object id".into(),
                    clause: self.text.clone(),
                    message: format!("expected a whole number, got {n}"),
                });
            }
            self.refs.push(ObjectRef::Id(*n as u16));
            return Ok(Some(2));
        }
        Ok(None)
    }

    /// Quantifiers and exclusions: "everything", "all", "every", "each", "both", "only";
    /// "except (for)", "but" after a quantifier, "other than", "apart from", "aside from",
    /// "excluding". Words that would change which objects are meant but that this grammar
    /// does not read (negations, "the others", "besides", relations to other objects)
    /// are refused, naming the word, rather than dropped from the phrase.
    fn quantifier_word(&mut self, w: &str, next: Option<&str>) -> Result<Option<usize>, LangError> {
        let refs = &mut self.refs;
        let exclusion = match (w, next) {
            ("except", Some("for"))
            | ("other", Some("than"))
            | ("apart" | "aside", Some("from")) => Some(2),
            ("except" | "excluding", _) => Some(1),
            ("but", _) => {
                refs.close();
                let after_all = refs.in_excluded
                    || matches!(refs.targets.last(), Some(ObjectRef::All(_)))
                    || refs.targets.is_empty() && refs.quantified;
                if !after_all {
                    return Err(self.not_understood(
                        "but",
                        "'but' is read only after 'all' or 'everything' ('delete everything but the mug')",
                    ));
                }
                Some(1)
            }
            _ => None,
        };
        if let Some(n) = exclusion {
            refs.close();
            if refs.targets.is_empty() {
                return Err(self.not_understood(
                    w,
                    "name the objects to take something out of before it ('delete everything except the mug')",
                ));
            }
            refs.in_excluded = true;
            refs.in_partner = false;
            return Ok(Some(n));
        }
        match w {
            "everything" | "everyone" | "all" | "every" | "each" | "both" => {
                refs.close();
                if refs.in_excluded {
                    return Err(self.not_understood(
                        w,
                        "what is excepted must be named ('everything except the mug')",
                    ));
                }
                if matches!(w, "everything" | "everyone") {
                    refs.push(ObjectRef::All(None));
                } else {
                    refs.quantified = true;
                }
                Ok(Some(1))
            }
            // A focus word: "delete only the mug" deletes the mug.
            "only" | "just" => Ok(Some(1)),
            // "put the mug on the teapot": a place relative to another object. ("rotate it
            // on its own axis", "move it on the x axis" are not.)
            "on" | "upon"
                if self.op == Some(Translate)
                    && self.toks[self.pos + 1..]
                        .iter()
                        .filter_map(word)
                        .find(|w| !matches!(*w, "the" | "a" | "an" | "top" | "of"))
                        .is_some_and(|w| {
                            axis_word(w).is_none()
                                && !matches!(w, "its" | "own" | "local" | "world" | "axis")
                        }) =>
            {
                Err(self.not_understood(w, RELATIVE_PLACEMENT))
            }
            _ => {
                if let Some(why) = MEANING_CHANGING
                    .iter()
                    .find(|(words, _)| words.contains(&w))
                    .map(|(_, why)| *why)
                    // "no 3" is object 3; "next" is refused only in "next to".
                    .filter(|_| {
                        !(w == "no" && matches!(self.toks.get(self.pos + 1), Some(Tok::Num(_))))
                    })
                    .filter(|_| w != "next" || next == Some("to"))
                {
                    return Err(self.not_understood(w, why));
                }
                Ok(None)
            }
        }
    }

    fn not_understood(&self, word: &str, message: &str) -> LangError {
        LangError::NotUnderstood {
            word: word.to_string(),
            clause: self.text.clone(),
            message: message.to_string(),
        }
    }

    /// Axes and their frame: "its own x axis", "negative z", "up".
    fn axis_word(&mut self, w: &str, next: Option<&str>) -> Option<usize> {
        if matches!(w, "local" | "own")
            || (w == "object"
                && matches!(
                    next,
                    Some("frame" | "axis" | "x" | "y" | "z" | "coordinates")
                ))
        {
            self.p.frame_object = true;
        } else if matches!(w, "world" | "global") {
            self.p.frame_object = false;
        } else if matches!(w, "negative" | "minus")
            && let Some(a) = next.and_then(axis_word)
        {
            self.p.axis = Some(format!("-{}", a.trim_start_matches('-')));
            return Some(2);
        } else if matches!(w, "positive" | "plus")
            && let Some(a) = next.and_then(axis_word)
        {
            self.p.axis = Some(a.to_string());
            return Some(2);
        } else if let Some(a) = axis_word(w) {
            self.refs.close();
            self.p.axis = Some(a.to_string());
        } else {
            return None;
        }
        Some(1)
    }

    /// Factors, fractions, turns, senses of rotation and size words.
    fn amount_word(&mut self, w: &str, next: Option<&str>) -> Option<usize> {
        let p = &mut self.p;
        let turn_word = matches!(next, Some("turn" | "rotation" | "revolution" | "circle"));
        if w == "times" {
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
            let f = match w {
                "quarter" => 0.25,
                "half" => 0.5,
                _ => 1.0 / 3.0,
            };
            if turn_word {
                p.turn = Some(360.0 * f);
                return Some(2);
            }
            p.fraction = Some(f);
        } else if matches!(w, "full" | "complete" | "whole") && turn_word {
            p.turn = Some(360.0);
            return Some(2);
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
            self.refs.close();
            p.size = Some(SizeWord::Bigger);
            if matches!(w, "taller" | "tall") && p.axis.is_none() {
                p.axis = Some("up".into());
            }
        } else if matches!(
            w,
            "smaller" | "small" | "tiny" | "tinier" | "shorter" | "short" | "narrower" | "thinner"
        ) {
            self.refs.close();
            p.size = Some(SizeWord::Smaller);
            if matches!(w, "shorter" | "short") && p.axis.is_none() {
                p.axis = Some("up".into());
            }
        } else {
            return None;
        }
        Some(1)
    }

    /// Words that end an object phrase and say how what follows is meant: "as", "by",
    /// "to", "at", "from", "with", "and", "around", "another", directions.
    fn connective_word(&mut self, i: usize, w: &str) -> Option<usize> {
        let (p, refs) = (&mut self.p, &mut self.refs);
        match w {
            "as" => p.as_ = true,
            "by" => p.by = true,
            "to" => p.to = true,
            "at" => {}
            "from" => self.after_from = true,
            "with" | "for" => {
                refs.close();
                refs.in_partner = true;
                return Some(1);
            }
            "and" | "&" | "plus" => {}
            "around"
                if self.op == Some(Rotate)
                    && !self.toks[i + 1..].iter().any(|t| {
                        matches!(t, Tok::Num(_)) || word(t).is_some_and(|w| axis_word(w).is_some())
                    }) =>
            {
                refs.close();
                p.turn.get_or_insert(180.0);
                return Some(1);
            }
            "another" | "more" | "second" | "extra" => {
                p.another = true;
                if self.op == Some(Add) {
                    self.op = Some(Replicate);
                }
                return Some(1);
            }
            _ => {
                let d = direction_word(w).filter(|_| self.op != Some(Select))?;
                refs.close();
                if p.direction.is_some() {
                    p.more_directions.push(d);
                } else {
                    p.direction = Some(d);
                }
                return Some(1);
            }
        }
        refs.close();
        Some(1)
    }

    /// Words that name objects: pronouns, "the copy", generic nouns, fillers, and the
    /// content words of a phrase.
    fn object_word(&mut self, i: usize, w: &str, next: Option<&str>) -> usize {
        let refs = &mut self.refs;
        if PRONOUNS.contains(&w) && !(w == "that" || w == "this") {
            // "all of them" are the objects named before.
            refs.quantified = false;
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
                return 2;
            }
        } else if CREATED.contains(&w)
            && (i == 0
                || matches!(
                    i.checked_sub(1)
                        .and_then(|j| self.toks.get(j))
                        .and_then(word),
                    Some("the" | "that" | "this" | "a" | "new")
                ))
            && !(w == "new" && next.is_some_and(|n| !GENERIC.contains(&n) && !CREATED.contains(&n)))
        {
            refs.close();
            refs.push(ObjectRef::Created);
            if w == "new" && next.is_some() {
                return 2;
            }
        } else if GENERIC.contains(&w) {
            refs.generic = true;
        } else if self.after_from
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
        1
    }

    /// The clause as a command; a clause without a verb continues the previous command.
    fn finish(self, out: &mut Vec<RawCommand>) -> Result<(), LangError> {
        let make = self.verb_is_make();
        let Clause {
            text, op, p, refs, ..
        } = self;
        let Refs {
            mut targets,
            partners,
            excluded,
            ..
        } = refs;
        let Some(mut op) = op else {
            let Some(prev) = out.last().cloned() else {
                return Err(LangError::NoAction { text });
            };
            let has_params = !p.quantities.is_empty()
                || p.direction.is_some()
                || p.axis.is_some()
                || p.turn.is_some()
                || p.position.is_some();
            if !has_params && !targets.is_empty() {
                let last = out.last_mut().expect("prev");
                last.targets.extend(targets);
                last.excluded.extend(excluded);
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
                excluded,
                params: p,
                text,
            });
            return Ok(());
        };
        if op == Translate && p.path.is_some() {
            op = Add; // "put the mic from ../b.assist at …"
        }
        if op == Scale
            && make
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
            excluded,
            params: p,
            text,
        });
        Ok(())
    }
}
