//! Units of an instruction: every length unit the grammar reads converts to metres, and a
//! word after a number that is not a unit is refused by name, never read as an object
//! ("move the ball 3 furlongs left" once said "no object called furlongs").

use assist_core::{DVec3, Scene};
use assist_lang::{ParseOptions, parse};

mod common;
use common::{NoScenes, node};

fn scene() -> Scene {
    let mut bg = node(0, "background", [0.0, 0.0, 1.0]);
    bg.half_size = DVec3::splat(2.0);
    Scene::with_nodes(
        vec![
            bg,
            node(1, "blue ball", [-0.5, 0.0, 0.8]),
            node(2, "red mug", [0.5, 0.0, 0.8]),
        ],
        DVec3::Z,
    )
}

/// The length of the first action's offset, in metres.
fn metres(text: &str) -> Result<f64, String> {
    let actions = parse(text, &scene(), &ParseOptions::default(), &mut NoScenes)
        .map_err(|e| e.to_string())?;
    let c = &actions[0].config;
    let scale = match c.unit.as_deref() {
        Some("m") | None => 1.0,
        Some("cm") => 0.01,
        Some("mm") => 0.001,
        other => panic!("{text:?}: unit {other:?}"),
    };
    let v = c
        .vector
        .map(|v| DVec3::from_array(v).length())
        .or(c.distance)
        .unwrap_or_else(|| panic!("{text:?}: no offset in {c:?}"));
    Ok(v * scale)
}

#[test]
fn every_length_unit_reads_in_metres() {
    let table: &[(&str, f64)] = &[
        ("move the blue ball 3 cm left", 0.03),
        ("move the blue ball 3 centimetres left", 0.03),
        ("move the blue ball 30 mm left", 0.03),
        ("move the blue ball 0.5 m left", 0.5),
        ("move the blue ball 2 in left", 0.0508),
        ("move the blue ball 2 inches left", 0.0508),
        ("move the blue ball 1 ft left", 0.3048),
        ("move the blue ball 1 yard left", 0.9144),
        ("move the blue ball 0.001 km left", 1.0),
        ("move the blue ball 0.001 kilometres left", 1.0),
        ("move the blue ball 0.0001 miles left", 0.1609344),
        ("move the blue ball 3 left", 3.0),
    ];
    let mut failures = Vec::new();
    for (text, want) in table {
        match metres(text) {
            Ok(got) if (got - want).abs() < 1e-9 => {}
            other => failures.push(format!("{text:?}: {other:?}, expected {want} m")),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_word_after_a_number_that_is_no_unit_is_refused_by_name() {
    for (text, word) in [
        ("move the blue ball 3 furlongs left", "\"furlongs\""),
        ("move the blue ball 2 parsecs to the right", "\"parsecs\""),
        ("rotate the red mug 30 gradians", "\"gradians\""),
        ("move the blue ball 5 px up", "\"px\""),
    ] {
        let e = metres(text).expect_err(text);
        assert!(
            e.contains(word) && e.contains("expected a unit") && !e.contains("no object"),
            "{text:?}: {e}"
        );
    }
    // A huge distance in a known unit is refused by the scene's range, and the message
    // prints the number in exponent form, not as hundreds of digits.
    let e = metres("move the blue ball 1000000000 km left").unwrap_err();
    assert!(e.contains("within ±1e9") && !e.contains("no object"), "{e}");
    assert!(e.len() < 250, "{e}");
}
