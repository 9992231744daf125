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
pub use names::TextEmbedder;
pub use resolve::{ParseOptions, Resolved, direction_vector};

#[derive(Debug, thiserror::Error)]
pub enum LangError {
    #[error(
        "no operation understood in {text:?}: expected move/translate, rotate/turn, scale/make bigger/shrink, duplicate/copy, delete/remove, swap, add … from SCENE, or select/highlight"
    )]
    NoAction { text: String },
    #[error("no object called {phrase:?} (the scene has {candidates})")]
    UnknownObject { phrase: String, candidates: String },
    #[error(
        "{phrase:?} could mean several objects: {candidates}; say which (by a colour, another word of its label, or 'object N')"
    )]
    Ambiguous { phrase: String, candidates: String },
    #[error("in {clause:?}: 'it'/'the copy' does not refer to any object yet")]
    NoAntecedent { clause: String },
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
    let toks = tokens::tokenize(text);
    let raw = grammar::parse_raw(&toks)?;
    Ok(resolve::resolve(&raw, scene, opts, sources, &Default::default())?.actions)
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
    let toks = tokens::tokenize(text);
    let raw = grammar::parse_raw(&toks)?;
    resolve::resolve(&raw, scene, opts, sources, taken_fields)
}
