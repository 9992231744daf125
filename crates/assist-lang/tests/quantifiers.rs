//! Negations, quantifiers and relations: "everything except the mug" must never delete the
//! mug. Each instruction resolves to exactly the objects it means, or is refused naming
//! the word or phrase the grammar does not read.

use assist_core::{DVec3, Scene};
use assist_lang::{ParseOptions, parse};

mod common;
use common::{NoScenes, node};

/// A duck (1), a cow (2), a mug (3), a teapot (4), a red box (5) and a blue striped box (6).
fn scene() -> Scene {
    let mut bg = node(0, "background", [0.0, 0.0, 1.0]);
    bg.half_size = DVec3::splat(2.0);
    Scene::with_nodes(
        vec![
            bg,
            node(1, "yellow rubber duck", [-0.5, 0.0, 0.8]),
            node(2, "spot the cow figurine", [-0.3, 0.0, 0.8]),
            node(3, "red ceramic mug", [-0.1, 0.0, 0.8]),
            node(4, "blue Utah teapot", [0.1, 0.0, 0.8]),
            node(5, "red box", [0.3, 0.0, 0.8]),
            node(6, "blue striped box", [0.5, 0.0, 0.8]),
        ],
        DVec3::Z,
    )
}

/// The (operation, id) of each action.
fn ops(text: &str) -> Result<Vec<(String, u16)>, String> {
    parse(text, &scene(), &ParseOptions::default(), &mut NoScenes)
        .map(|a| {
            a.iter()
                .map(|a| (a.operation.to_string(), a.instance_id))
                .collect()
        })
        .map_err(|e| e.to_string())
}

fn deletes(ids: &[u16]) -> Vec<(String, u16)> {
    ids.iter().map(|i| ("delete".to_string(), *i)).collect()
}

/// Instructions with "except", "but", "all", "every", "other than", "only", and the ids
/// they delete.
const NEGATIONS_AND_QUANTIFIERS: &[(&str, &[u16])] = &[
    ("remove everything except the mug", &[1, 2, 4, 5, 6]),
    ("delete everything but the mug", &[1, 2, 4, 5, 6]),
    ("remove all objects except the mug", &[1, 2, 4, 5, 6]),
    ("delete all but the mug", &[1, 2, 4, 5, 6]),
    ("delete all except for the mug", &[1, 2, 4, 5, 6]),
    ("delete every object other than the mug", &[1, 2, 4, 5, 6]),
    ("delete everything excluding the mug", &[1, 2, 4, 5, 6]),
    (
        "delete all objects apart from the mug and the duck",
        &[2, 4, 5, 6],
    ),
    (
        "remove everything except the mug and the teapot",
        &[1, 2, 5, 6],
    ),
    ("delete everything", &[1, 2, 3, 4, 5, 6]),
    ("delete all objects", &[1, 2, 3, 4, 5, 6]),
    ("delete every box", &[5, 6]),
    ("delete all the boxes", &[5, 6]),
    ("delete both boxes", &[5, 6]),
    ("delete the boxes except the red one", &[6]),
    ("delete all boxes but the blue one", &[5]),
    ("delete only the mug", &[3]),
    ("just delete the mug", &[3]),
    ("delete the mug only", &[3]),
];

#[test]
fn negations_and_quantifiers_mean_what_they_say() {
    let mut failures = Vec::new();
    for (text, want) in NEGATIONS_AND_QUANTIFIERS {
        match ops(text) {
            Ok(got) if got == deletes(want) => {}
            Ok(got) => failures.push(format!("{text:?}: got {got:?}, want deletes of {want:?}")),
            Err(e) => failures.push(format!("{text:?}: refused: {e}")),
        }
    }
    // Other operations take the same sets; "all of them" are the objects named before.
    let t = ops("move all the boxes 10 cm left").unwrap();
    assert_eq!(t, vec![("translate".into(), 5), ("translate".into(), 6)]);
    let t = ops("select the duck and the mug, then delete all of them").unwrap();
    assert_eq!(
        t,
        vec![
            ("select".into(), 1),
            ("select".into(), 3),
            ("delete".into(), 1),
            ("delete".into(), 3)
        ]
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Instructions refused, and what the error must say (the word it did not read, or why).
const REFUSED: &[(&str, &str)] = &[
    (
        "delete the mug but not the duck",
        "\"but\" is not understood",
    ),
    ("do not delete the mug", "\"not\" is not understood"),
    ("don't delete the mug", "\"not\" is not understood"),
    ("delete nothing", "\"nothing\" is not understood"),
    ("delete the others", "\"others\" is not understood"),
    ("delete the rest", "\"rest\" is not understood"),
    ("delete the other box", "\"other\" is not understood"),
    ("delete anything red", "\"anything\" is not understood"),
    (
        "delete the duck besides the mug",
        "\"besides\" is not understood",
    ),
    (
        "delete the mug without the duck",
        "\"without\" is not understood",
    ),
    (
        "except the mug delete everything",
        "\"except\" is not understood",
    ),
    (
        "delete everything except everything",
        "\"everything\" is not understood",
    ),
    (
        "delete everything except the sofa",
        "no object called \"sofa\"",
    ),
    (
        "delete the mug except the duck",
        "is not among the objects named before it",
    ),
    (
        "delete all boxes except the red box and the blue striped box",
        "nothing is left",
    ),
    ("swap all boxes with the mug", "not 'all' or 'except'"),
];

#[test]
fn what_is_not_understood_is_refused_by_name() {
    let mut failures = Vec::new();
    for (text, want) in REFUSED {
        match ops(text) {
            Ok(got) => failures.push(format!("{text:?}: accepted as {got:?}")),
            Err(e) if !e.contains(want) => {
                failures.push(format!("{text:?}: error {e:?} does not say {want:?}"))
            }
            Err(_) => {}
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The actions an instruction resolves to: (operation, id, vector or factor).
fn resolved(text: &str) -> Result<Vec<(String, u16, Vec<f64>)>, String> {
    parse(text, &scene(), &ParseOptions::default(), &mut NoScenes)
        .map(|a| {
            a.iter()
                .map(|a| {
                    let c = &a.config;
                    let v = c
                        .vector
                        .map(|v| v.to_vec())
                        .or(c.factor.map(|f| vec![f]))
                        .unwrap_or_default();
                    (a.operation.to_string(), a.instance_id, v)
                })
                .collect()
        })
        .map_err(|e| e.to_string())
}

/// Places relative to other objects, each resolved to one move (metres): every object
/// here is a cube of edge `e` standing at z = 0.8, in a row along x (duck −0.5, cow −0.3,
/// mug −0.1, teapot 0.1); "in front of" is towards the viewer, the world's −y without a
/// camera; the gap is 2 cm unless given.
#[test]
fn relative_places_resolve_to_moves() {
    let s = scene();
    let e = {
        let c = s.node(3).unwrap().world_corners();
        c.iter().map(|p| p.x).fold(f64::MIN, f64::max)
            - c.iter().map(|p| p.x).fold(f64::MAX, f64::min)
    };
    let g = 0.02;
    let table: Vec<(&str, u16, [f64; 3])> = vec![
        ("put the mug next to the teapot", 3, [0.2 - e - g, 0.0, 0.0]),
        ("put the cow beside the teapot", 2, [0.4 - e - g, 0.0, 0.0]),
        ("move the mug near the duck", 3, [-0.4 + e + g, 0.0, 0.0]),
        ("move the mug onto the teapot", 3, [0.2, 0.0, e]),
        ("put the mug on top of the teapot", 3, [0.2, 0.0, e]),
        ("put the mug on the teapot", 3, [0.2, 0.0, e]),
        ("put the mug in front of the cow", 3, [-0.2, -(e + g), 0.0]),
        ("move the duck behind the mug", 1, [0.4, e + g, 0.0]),
        ("put the mug 5 cm behind the cow", 3, [-0.2, e + 0.05, 0.0]),
        (
            "put the mug between the duck and the cow",
            3,
            [-0.3, 0.0, 0.0],
        ),
    ];
    let mut failures = Vec::new();
    for (text, id, want) in &table {
        match resolved(text) {
            Ok(got) => {
                let ok = matches!(got.as_slice(), [(op, i, v)] if op == "translate" && i == id
                    && v.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-9));
                if !ok {
                    failures.push(format!("{text:?}: {got:?}, expected {id} by {want:?}"));
                }
            }
            Err(e) => failures.push(format!("{text:?}: {e}")),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Amounts left unsaid get the documented defaults; counts of copies are read.
#[test]
fn unsaid_amounts_get_their_defaults() {
    let one = |text: &str| resolved(text).unwrap_or_else(|e| panic!("{text}: {e}"));
    assert_eq!(one("make the duck smaller")[0].2, vec![0.8]);
    assert!((one("make the duck a bit smaller")[0].2[0] - 1.0 / 1.1).abs() < 1e-12);
    assert_eq!(one("make the duck bigger")[0].2, vec![1.25]);
    assert_eq!(
        one("move the cow a bit to the right")[0].2,
        vec![0.05, 0.0, 0.0]
    );
    assert_eq!(
        one("move the cow slightly left")[0].2,
        vec![-0.05, 0.0, 0.0]
    );
    assert_eq!(one("move the cow to the right")[0].2, vec![0.1, 0.0, 0.0]);
    for (text, n) in [
        ("duplicate the duck 3 times", 3),
        ("duplicate the duck twice", 2),
        ("make 4 copies of the duck", 4),
    ] {
        let got = one(text);
        assert!(
            got.len() == n && got.iter().all(|(op, id, _)| op == "replicate" && *id == 1),
            "{text}: {got:?}"
        );
    }
}

/// What cannot be placed is refused naming the words.
const RELATIONS_REFUSED: &[(&str, &str)] = &[
    ("put the mug next to", "\"next to\" needs 1 other object"),
    (
        "put the mug between the duck",
        "\"between\" needs 2 other objects",
    ),
    ("put the mug next to the mug", "relative to itself"),
    ("delete the mug next to the teapot", "\"next to\""),
    ("put the mug under the teapot", "\"under\""),
    ("put the mug inside the teapot", "\"inside\""),
    (
        "put the mug and the duck next to the cow",
        "one object at a time",
    ),
];

#[test]
fn relations_that_cannot_be_placed_are_refused_by_name() {
    let mut failures = Vec::new();
    for (text, want) in RELATIONS_REFUSED {
        match resolved(text) {
            Ok(got) => failures.push(format!("{text:?}: accepted as {got:?}")),
            Err(e) if !e.contains(want) => {
                failures.push(format!("{text:?}: {e:?} does not say {want}"))
            }
            Err(_) => {}
        }
    }
    // What is not a relation still reads: an axis after "on", a turn on its own axis.
    assert!(ops("move the mug 10 cm on the x axis").is_ok());
    assert!(ops("rotate the mug 90 degrees on its own z axis").is_ok());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
