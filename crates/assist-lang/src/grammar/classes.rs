//! The word classes of a clause: ids, quantifiers and exclusions, axes, amounts,
//! connectives and object words. Each method reads one class of words and returns how
//! many tokens it used, or `None` when the word is not of its class.

use super::*;

impl Clause<'_> {
    /// "one metre", "make two copies", "object 3".
    pub(super) fn id_word(
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
                    message: format!("expected a whole number, got {}", assist_core::fmt_num(*n)),
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
    pub(super) fn quantifier_word(
        &mut self,
        w: &str,
        next: Option<&str>,
    ) -> Result<Option<usize>, LangError> {
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
            "on" | "upon" | "onto" | "atop"
                if self.toks[self.pos + 1..]
                    .iter()
                    .filter_map(word)
                    .find(|w| !matches!(*w, "the" | "a" | "an" | "top" | "of"))
                    .is_some_and(|w| {
                        axis_word(w).is_none()
                            && !matches!(w, "its" | "own" | "local" | "world" | "axis")
                    }) =>
            {
                let mut k = 1;
                while matches!(
                    self.toks.get(self.pos + k).and_then(word),
                    Some("top" | "of")
                ) {
                    k += 1;
                }
                self.relation(w, Relation::On).map(|()| Some(k))
            }
            "next" if next == Some("to") => {
                self.relation("next to", Relation::NextTo).map(|()| Some(2))
            }
            "beside" | "near" | "alongside" => self.relation(w, Relation::NextTo).map(|()| Some(1)),
            "front" => {
                let k = if next == Some("of") { 2 } else { 1 };
                self.relation("in front of", Relation::InFront)
                    .map(|()| Some(k))
            }
            "behind" => self.relation(w, Relation::Behind).map(|()| Some(1)),
            "between" => self.relation(w, Relation::Between).map(|()| Some(1)),
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

    /// A place relative to the objects named next (they become the partners): read for a
    /// move, refused naming the words for anything else.
    fn relation(&mut self, words: &str, r: Relation) -> Result<(), LangError> {
        if self.op != Some(Translate) || self.p.relation.is_some() {
            return Err(self.not_understood(words, RELATIVE_PLACEMENT));
        }
        self.refs.close();
        self.refs.in_partner = true;
        self.p.relation = Some((r, words.to_string()));
        Ok(())
    }

    pub(super) fn not_understood(&self, word: &str, message: &str) -> LangError {
        LangError::NotUnderstood {
            word: word.to_string(),
            clause: self.text.clone(),
            message: message.to_string(),
        }
    }

    /// Axes and their frame: "its own x axis", "negative z", "up".
    pub(super) fn axis_word(&mut self, w: &str, next: Option<&str>) -> Option<usize> {
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
    pub(super) fn amount_word(&mut self, w: &str, next: Option<&str>) -> Option<usize> {
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
        } else if matches!(w, "slightly" | "bit" | "tad")
            || (w == "little" && next.is_none_or(is_amount_word))
        {
            // "a bit", "slightly", "a little": the smaller default amount.
            p.slight = true;
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
    pub(super) fn connective_word(&mut self, i: usize, w: &str) -> Option<usize> {
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
    /// A content word right after a bare number, once the clause has named its object
    /// ("move the mug 3 furlongs left"), is an unknown unit: refused by name, never read
    /// as an object.
    pub(super) fn object_word(
        &mut self,
        i: usize,
        w: &str,
        next: Option<&str>,
    ) -> Result<usize, LangError> {
        let after_bare_number = i > 0
            && matches!(self.toks[i - 1], Tok::Num(_))
            && matches!(self.p.quantities.last(), Some((_, None)));
        let prev = i
            .checked_sub(1)
            .and_then(|j| self.toks.get(j))
            .and_then(word);
        let filler = FILLER.contains(&w) && !names_a_can(i, w, prev, next);
        let content =
            !(PRONOUNS.contains(&w) || CREATED.contains(&w) || GENERIC.contains(&w) || filler);
        if after_bare_number && content && !self.refs.targets.is_empty() {
            return Err(LangError::NotUnderstood {
                word: w.to_string(),
                clause: self.text.clone(),
                message: format!("expected a unit after the number ({UNITS_KNOWN})"),
            });
        }
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
                return Ok(2);
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
                return Ok(2);
            }
        } else if GENERIC.contains(&w) {
            refs.generic = true;
        } else if self.after_from
            && matches!(w, "scene" | "table" | "desk" | "room" | "floor")
            && refs.phrase.is_empty()
        {
            // "remove the duck from the scene"
        } else if filler {
            if !refs.phrase.is_empty() && !matches!(w, "the" | "a" | "an") {
                refs.close();
            }
        } else {
            refs.phrase.push(w.to_string());
        }
        Ok(1)
    }
}

/// Whether "can" at token `i` (between `prev` and `next`) names an object ("move the can",
/// "the red can", "move can 5 cm left") rather than asking ("can you move …", "you can
/// move …"): a modal opens the clause or stands beside its subject.
fn names_a_can(i: usize, w: &str, prev: Option<&str>, next: Option<&str>) -> bool {
    const SUBJECTS: &[&str] = &["you", "i", "we", "u", "please"];
    w == "can"
        && i > 0
        && !prev.is_some_and(|p| SUBJECTS.contains(&p))
        && !next.is_some_and(|n| SUBJECTS.contains(&n))
}
