//! assist-lang: plain-language instructions → validated `Action`s.
//!
//! A deterministic offline parser in two stages, as everywhere in assist:
//! `tokens` + `grammar` turn text into raw commands (an operation, object phrases, raw
//! quantities and words) without looking at any scene; `resolve` finds the objects in the
//! scene (id, label with plurals/synonyms/colours, pronouns, "the copy", embedding
//! similarity when an embedder is given), turns quantities into configs and validates every
//! action with assist-core against the scene as the earlier actions left it. Unknown or
//! ambiguous objects, impossible values and text with no operation are errors that say
//! what was not understood and list the candidates — never a guess.
//!
//! `llm` is an optional provider: any OpenAI-compatible chat-completions endpoint answers
//! with action JSON, which is validated exactly like the parser's output.

#![forbid(unsafe_code)]

mod grammar;
mod llm;
mod names;
mod resolve;
mod tokens;
mod words;

use assist_core::{Action, ActionError, Scene, SceneSource};

pub use llm::{LlmProvider, actions_from_answer};
pub use names::{MEANING_MARGIN, NoMeaning, TextEmbedder};
pub use resolve::{ParseOptions, Resolved, direction_vector};

#[derive(Debug, thiserror::Error)]
pub enum LangError {
    #[error(
        "no operation understood in {text:?}: expected move/translate, rotate/turn, scale/make bigger/shrink, duplicate/copy, delete/remove, swap, add … from SCENE, or select/highlight"
    )]
    NoAction { text: String },
    #[error("no object called {phrase:?} (the scene has {candidates}){hint}")]
    UnknownObject {
        phrase: String,
        candidates: String,
        /// What would let the phrase be found by meaning ("" when nothing would).
        hint: String,
    },
    #[error(
        "{phrase:?} is too close to call by meaning: {scores}; say which (by its label or 'object N')"
    )]
    TooClose { phrase: String, scores: String },
    #[error(
        "{phrase:?} could mean several objects: {candidates}; say which (by a colour, another word of its label, or 'object N')"
    )]
    Ambiguous { phrase: String, candidates: String },
    /// A word that would change which objects are meant, which the grammar does not
    /// read: refused rather than guessed.
    #[error("in {clause:?}: {word:?} is not understood here: {message}")]
    NotUnderstood {
        word: String,
        clause: String,
        message: String,
    },
    #[error(
        "in {clause:?}: no object named, and 'it'/'the copy' does not refer to any object yet (the scene has {candidates})"
    )]
    NoAntecedent { clause: String, candidates: String },
    #[error("in {clause:?}: {what}: {message}")]
    BadValue {
        what: String,
        clause: String,
        message: String,
    },
    #[error("in {clause:?}: {source}")]
    Action { clause: String, source: ActionError },
    #[error("LLM provider: {0}")]
    Llm(String),
}

/// Parses `text` into actions for `scene` (validated in order; see the crate docs).
pub fn parse(
    text: &str,
    scene: &Scene,
    opts: &ParseOptions,
    sources: &mut dyn SceneSource,
) -> Result<Vec<Action>, LangError> {
    let text = numbered_names(text, scene);
    let toks = tokens::tokenize(&text);
    let raw = grammar::parse_raw(&toks)?;
    Ok(resolve::resolve(&raw, scene, opts, sources, &Default::default())?.actions)
}

/// Replicas are named "mug 2", "mug 3": a mention of such a name (its last words with the
/// number, "mug 2" or "the red mug 2") becomes "object N" before parsing, so the number is
/// not read as a quantity — unless a unit follows it ("the mug 2 cm left").
fn numbered_names(text: &str, scene: &Scene) -> String {
    let mut out = text.to_string();
    let mut replicas: Vec<(&assist_core::SceneNode, Vec<String>)> = scene
        .nodes
        .iter()
        .filter_map(|n| {
            let words: Vec<String> = n.label.split_whitespace().map(str::to_lowercase).collect();
            let last = words.last()?;
            // "object 6" is already how an id is named: not a name to rewrite.
            let id_word = matches!(
                words.first().map(String::as_str),
                Some("object" | "node" | "instance" | "id" | "number" | "no")
            );
            (words.len() >= 2 && !id_word && last.chars().all(|c| c.is_ascii_digit()))
                .then_some((n, words))
        })
        .collect();
    // Longer names first, so "red mug 2" is not half-replaced by "mug 2".
    replicas.sort_by_key(|(_, w)| std::cmp::Reverse(w.len()));
    for (n, words) in replicas {
        for start in 0..words.len() - 1 {
            let phrase = words[start..].join(" ");
            if let Some(new) = replace_name(&out, &phrase, n.id) {
                out = new;
                break;
            }
        }
    }
    out
}

/// `text` with the first whole-word mention of `phrase` (and a "the" before it) replaced
/// by "object ID", unless a unit word follows it.
fn replace_name(text: &str, phrase: &str, id: assist_core::InstanceId) -> Option<String> {
    let lower = text.to_lowercase();
    let boundary = |c: Option<char>| c.is_none_or(|c| !c.is_alphanumeric());
    let mut from = 0;
    while let Some(k) = lower[from..].find(phrase) {
        let (a, b) = (from + k, from + k + phrase.len());
        from = b;
        if !boundary(lower[..a].chars().last()) || !boundary(lower[b..].chars().next()) {
            continue;
        }
        let next = lower[b..].split_whitespace().next().unwrap_or("");
        let next = next.trim_matches(|c: char| !c.is_alphanumeric() && c != '%');
        if next == "%" || words::unit_word(next).is_some() {
            continue;
        }
        let a = if lower[..a].ends_with("the ") {
            a - 4
        } else {
            a
        };
        return Some(format!("{}object {id}{}", &text[..a], &text[b..]));
    }
    None
}

/// Like [`parse`], keeping what validation made of each action (see [`Resolved`]); field
/// keys in `taken_fields` are not given to imported nodes.
pub fn resolve_text(
    text: &str,
    scene: &Scene,
    opts: &ParseOptions,
    sources: &mut dyn SceneSource,
    taken_fields: &std::collections::BTreeSet<String>,
) -> Result<Resolved, LangError> {
    let text = numbered_names(text, scene);
    let toks = tokens::tokenize(&text);
    let raw = grammar::parse_raw(&toks)?;
    resolve::resolve(&raw, scene, opts, sources, taken_fields)
}
