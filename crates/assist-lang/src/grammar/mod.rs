//! Stage one: tokens → raw commands (an operation, the object phrases it names and the raw
//! quantities and words that configure it), knowing nothing about any scene.

use assist_core::Operation;
use assist_core::Operation::*;

use crate::LangError;
use crate::tokens::Tok;
use crate::words::{
    CREATED, FILLER, GENERIC, GROW, MEANING_CHANGING, PRONOUNS, RELATIVE_PLACEMENT, SHRINK,
    UNITS_KNOWN, Verb, axis_word, direction_word, is_amount_word, unit_word, verb_at, word,
};
pub use crate::words::{Direction, Unit};

mod classes;

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

/// A place relative to other objects (the partners of the command): "next to", "beside",
/// "near"; "on", "onto", "on top of"; "in front of"; "behind"; "between".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Relation {
    NextTo,
    On,
    InFront,
    Behind,
    Between,
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
    /// "a bit", "slightly", "a little": a smaller default amount.
    pub slight: bool,
    /// A place relative to the partners, with the words that said it.
    pub relation: Option<(Relation, String)>,
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
            Tok::Num(n) => assist_core::fmt_num(*n),
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
                        None => match self
                            .axis_word(w, next)
                            .or_else(|| self.amount_word(w, next))
                            .or_else(|| self.connective_word(i, w))
                        {
                            Some(k) => k,
                            None => self.object_word(i, w, next)?,
                        },
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
