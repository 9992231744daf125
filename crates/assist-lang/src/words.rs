//! The vocabulary of the grammar: verbs (with what they imply), units, directions, axes,
//! and the words that carry no meaning for it.

use assist_core::Operation;

use crate::tokens::Tok;

pub struct Verb {
    pub words: &'static [&'static str],
    pub op: Operation,
    pub direction: Option<Direction>,
    pub factor: Option<f64>,
}

const fn v(words: &'static [&'static str], op: Operation) -> Verb {
    Verb {
        words,
        op,
        direction: None,
        factor: None,
    }
}

use Operation::*;

/// A horizontal or vertical direction word.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    Left,
    Right,
    Up,
    Down,
    Forward,
    Back,
}

/// A unit attached to a number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Unit {
    /// Metres per unit.
    Length(f64),
    Degrees,
    Radians,
    Percent,
    Times,
}

/// Verbs, longest phrases first where they share a first word.
const VERBS: &[Verb] = &[
    v(&["get", "rid", "of"], Delete),
    v(&["take", "away"], Delete),
    v(&["take", "out"], Delete),
    v(&["make", "a", "copy", "of"], Replicate),
    v(&["make", "another"], Replicate),
    v(&["make", "copies", "of"], Replicate),
    v(&["bring", "in"], Add),
    v(&["move"], Translate),
    v(&["translate"], Translate),
    v(&["shift"], Translate),
    v(&["slide"], Translate),
    v(&["push"], Translate),
    v(&["pull"], Translate),
    v(&["nudge"], Translate),
    v(&["drag"], Translate),
    v(&["displace"], Translate),
    v(&["relocate"], Translate),
    v(&["carry"], Translate),
    v(&["put"], Translate),
    v(&["place"], Translate),
    v(&["position"], Translate),
    v(&["bring"], Translate),
    Verb {
        words: &["raise"],
        op: Translate,
        direction: Some(Direction::Up),
        factor: None,
    },
    Verb {
        words: &["lift"],
        op: Translate,
        direction: Some(Direction::Up),
        factor: None,
    },
    Verb {
        words: &["elevate"],
        op: Translate,
        direction: Some(Direction::Up),
        factor: None,
    },
    Verb {
        words: &["lower"],
        op: Translate,
        direction: Some(Direction::Down),
        factor: None,
    },
    Verb {
        words: &["drop"],
        op: Translate,
        direction: Some(Direction::Down),
        factor: None,
    },
    v(&["rotate"], Rotate),
    v(&["turn"], Rotate),
    v(&["spin"], Rotate),
    v(&["twist"], Rotate),
    v(&["revolve"], Rotate),
    v(&["pivot"], Rotate),
    v(&["swivel"], Rotate),
    v(&["yaw"], Rotate),
    v(&["scale"], Scale),
    v(&["rescale"], Scale),
    v(&["resize"], Scale),
    v(&["make"], Scale),
    v(&["stretch"], Scale),
    Verb {
        words: &["enlarge"],
        op: Scale,
        direction: None,
        factor: None,
    },
    v(&["grow"], Scale),
    v(&["expand"], Scale),
    v(&["shrink"], Scale),
    v(&["reduce"], Scale),
    v(&["squash"], Scale),
    v(&["squeeze"], Scale),
    v(&["compress"], Scale),
    Verb {
        words: &["double"],
        op: Scale,
        direction: None,
        factor: Some(2.0),
    },
    Verb {
        words: &["triple"],
        op: Scale,
        direction: None,
        factor: Some(3.0),
    },
    Verb {
        words: &["halve"],
        op: Scale,
        direction: None,
        factor: Some(0.5),
    },
    v(&["delete"], Delete),
    v(&["remove"], Delete),
    v(&["erase"], Delete),
    v(&["eliminate"], Delete),
    v(&["discard"], Delete),
    v(&["destroy"], Delete),
    v(&["duplicate"], Replicate),
    v(&["copy"], Replicate),
    v(&["replicate"], Replicate),
    v(&["clone"], Replicate),
    v(&["swap"], Swap),
    v(&["exchange"], Swap),
    v(&["switch"], Swap),
    v(&["interchange"], Swap),
    v(&["trade"], Swap),
    v(&["add"], Add),
    v(&["insert"], Add),
    v(&["import"], Add),
    v(&["load"], Add),
    v(&["select"], Select),
    v(&["highlight"], Select),
    v(&["pick"], Select),
    v(&["choose"], Select),
    v(&["mark"], Select),
    v(&["focus"], Select),
];

pub const SHRINK: &[&str] = &["shrink", "reduce", "squash", "squeeze", "compress"];
pub const GROW: &[&str] = &["enlarge", "grow", "expand"];

pub fn word(t: &Tok) -> Option<&str> {
    match t {
        Tok::Word(w) => Some(w),
        _ => None,
    }
}

/// The verb starting at `i`, with its length in tokens.
pub fn verb_at(toks: &[Tok], i: usize) -> Option<(&'static Verb, usize)> {
    for verb in VERBS {
        let n = verb.words.len();
        if i + n <= toks.len()
            && verb
                .words
                .iter()
                .zip(&toks[i..i + n])
                .all(|(w, t)| word(t) == Some(w))
        {
            return Some((verb, n));
        }
    }
    None
}

pub fn length_unit(w: &str) -> Option<f64> {
    Some(match w {
        "m" | "meter" | "meters" | "metre" | "metres" => 1.0,
        "cm" | "centimeter" | "centimeters" | "centimetre" | "centimetres" | "cms" => 0.01,
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => 0.001,
        "in" | "inch" | "inches" => 0.0254,
        "ft" | "foot" | "feet" => 0.3048,
        "km" | "kilometer" | "kilometers" | "kilometre" | "kilometres" => 1000.0,
        "yd" | "yard" | "yards" => 0.9144,
        "mi" | "mile" | "miles" => 1609.344,
        _ => return None,
    })
}

/// The units the grammar reads, for messages.
pub const UNITS_KNOWN: &str = "m, cm, mm, km, in, ft, yd, mi, degrees, radians, %, times";

pub fn unit_word(w: &str) -> Option<Unit> {
    if let Some(m) = length_unit(w) {
        return Some(Unit::Length(m));
    }
    Some(match w {
        "degree" | "degrees" | "deg" | "degs" => Unit::Degrees,
        "radian" | "radians" | "rad" | "rads" => Unit::Radians,
        "percent" | "pct" => Unit::Percent,
        "times" | "x" | "fold" => Unit::Times,
        _ => return None,
    })
}

pub fn direction_word(w: &str) -> Option<Direction> {
    Some(match w {
        "left" | "leftward" | "leftwards" => Direction::Left,
        "right" | "rightward" | "rightwards" => Direction::Right,
        "up" | "upward" | "upwards" | "higher" => Direction::Up,
        "down" | "downward" | "downwards" => Direction::Down,
        "forward" | "forwards" | "ahead" | "away" | "further" | "farther" => Direction::Forward,
        "back" | "backward" | "backwards" | "closer" | "nearer" => Direction::Back,
        _ => return None,
    })
}

pub fn axis_word(w: &str) -> Option<&'static str> {
    Some(match w {
        "x" | "+x" => "x",
        "y" | "+y" => "y",
        "z" | "+z" => "z",
        "-x" => "-x",
        "-y" => "-y",
        "-z" => "-z",
        "vertical" | "vertically" => "up",
        _ => return None,
    })
}

/// Words that carry no meaning for the parser.
pub const FILLER: &[&str] = &[
    "the",
    "a",
    "an",
    "please",
    "now",
    "also",
    "just",
    "can",
    "could",
    "would",
    "will",
    "you",
    "kindly",
    "i",
    "we",
    "want",
    "wanna",
    "like",
    "lets",
    "let",
    "us",
    "go",
    "of",
    "its",
    "their",
    "my",
    "our",
    "so",
    "that",
    "is",
    "it's",
    "be",
    "some",
    "bit",
    "little",
    "slightly",
    "amount",
    "distance",
    "axis",
    "axes",
    "direction",
    "size",
    "factor",
    "degrees",
    "should",
    "position",
    "positions",
    "places",
    "place",
    "spot",
    "spots",
    "around",
    "about",
    "along",
    "over",
    "in",
    "on",
    "onto",
    "into",
    "towards",
    "toward",
    "across",
    "through",
    "same",
    "scene",
    "much",
    "than",
    "original",
    "current",
    "instead",
    "please",
    "too",
    "then",
    "next",
    "finally",
    "afterwards",
    "after",
    "first",
    "there",
    "here",
    "way",
    "side",
];

/// Generic nouns: "the object", "the thing" mean the last object named.
pub const GENERIC: &[&str] = &[
    "object", "thing", "item", "one", "node", "instance", "objects", "things", "items",
];
pub const PRONOUNS: &[&str] = &[
    "it", "them", "this", "that", "these", "those", "itself", "him", "her",
];
pub const CREATED: &[&str] = &["copy", "duplicate", "clone", "replica", "new"];

/// Words that would change which objects an instruction means but that the grammar does
/// not read, with what to say instead. An instruction with one of them is refused, naming
/// it, rather than read without it ("remove everything but the mug" must never delete
/// the mug).
pub const MEANING_CHANGING: &[(&[&str], &str)] = &[
    (
        &[
            "not", "no", "don't", "dont", "never", "nor", "neither", "none", "nothing", "unless",
            "without",
        ],
        "negations are not understood; name the objects to act on",
    ),
    (
        &[
            "others",
            "rest",
            "remaining",
            "any",
            "anything",
            "besides",
            "except",
        ],
        "say which objects: 'everything except the mug', or name them",
    ),
    (
        &["other"],
        "'other' is read only as 'other than' ('every object other than the mug')",
    ),
    (
        &["underneath", "beneath", "under", "below", "inside"],
        "placing an object under or inside another is not supported: say 'next to', 'on', 'in front of', 'behind' or 'between', or give a distance and a direction ('10 cm left')",
    ),
];

/// Why a place relative to another object is refused where it is not a move.
pub const RELATIVE_PLACEMENT: &str = "a place relative to another object is read for a move ('put the mug next to the duck'); give a distance and a direction ('10 cm left') or a position ('at 0.1, 0.2, 0.8') otherwise";

/// Words that can follow "a little" as an amount: directions, size words, "more", "to".
pub fn is_amount_word(w: &str) -> bool {
    direction_word(w).is_some()
        || matches!(
            w,
            "more"
                | "less"
                | "to"
                | "bigger"
                | "smaller"
                | "larger"
                | "taller"
                | "shorter"
                | "wider"
                | "narrower"
                | "higher"
                | "lower"
                | "further"
                | "closer"
        )
}
