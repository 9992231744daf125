//! The instruction table: plain-language instructions with the actions they must give, and
//! instructions that must be refused with a clear error.

use assist_core::{DMat3, DQuat, DVec3, Scene, SceneSource};
use assist_lang::{LangError, ParseOptions, TextEmbedder, parse};
use serde_json::{Value, json};

mod common;
use common::node;

fn scene() -> Scene {
    let mut bg = node(0, "background", [0.0, 0.0, 1.0]);
    bg.half_size = DVec3::splat(2.0);
    Scene::with_nodes(
        vec![
            bg,
            node(1, "yellow rubber duck", [-0.5, 0.0, 0.8]),
            node(2, "spot the cow figurine (textured)", [-0.3, 0.0, 0.8]),
            node(3, "red ceramic mug", [-0.1, 0.0, 0.8]),
            node(4, "blue Utah teapot", [0.1, 0.0, 0.8]),
            node(
                5,
                "green toy building brick (2x2 Duplo-style)",
                [0.3, 0.0, 0.8],
            ),
            node(6, "robot arm", [0.5, 0.0, 0.8]),
            node(7, "red box", [-0.5, 0.4, 0.8]),
            node(8, "blue striped box", [-0.3, 0.4, 0.8]),
            node(9, "lego", [-0.1, 0.4, 0.8]),
            node(10, "chair", [0.1, 0.4, 0.5]),
        ],
        DVec3::Z,
    )
}

struct Other;
impl SceneSource for Other {
    fn load_scene(&mut self, path: &str) -> Result<Scene, String> {
        if path != "../other.assist" {
            return Err(format!("{path}: no such scene"));
        }
        let mut s = scene();
        s.nodes = vec![
            s.nodes[0].clone(),
            node(1, "studio microphone", [0.0, 0.0, 1.0]),
        ];
        Ok(s)
    }
}

/// `id op {config}` joined by ` | `.
fn expected(spec: &str) -> Vec<Value> {
    spec.split(" | ")
        .map(|one| {
            let mut it = one.splitn(3, ' ');
            let id: u16 = it.next().unwrap().parse().unwrap();
            let op = it.next().unwrap();
            let cfg: Value = serde_json::from_str(it.next().unwrap_or("{}")).unwrap();
            json!({"instance_id": id, "operation": op, "config": cfg})
        })
        .collect()
}

fn close(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            (x.as_f64().unwrap() - y.as_f64().unwrap()).abs() <= 1e-9
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| close(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| close(v, w)))
        }
        _ => a == b,
    }
}

const TABLE: &[(&str, &str)] = &[
    // The issue's examples.
    (
        "move the robot arm 10 cm along the x axis",
        r#"6 translate {"axis":"x","distance":0.1,"unit":"m"}"#,
    ),
    (
        "rotate the duck by 90 degrees around z",
        r#"1 rotate {"angle":90,"unit":"deg","axis":"z"}"#,
    ),
    ("make the mug twice as big", r#"3 scale {"factor":2}"#),
    (
        "select the mug, then shrink it by half along y",
        r#"3 select | 3 scale {"factor":0.5,"axis":"y"}"#,
    ),
    ("delete the chair", "10 delete"),
    (
        "duplicate the lego and move the copy 20 cm left",
        r#"9 replicate {"new_id":11} | 11 translate {"vector":[-0.2,0,0],"unit":"m"}"#,
    ),
    ("swap the duck and the mug", r#"1 swap {"with":3}"#),
    (
        "add the mic from ../other.assist",
        r#"11 add {"scene":"../other.assist","node":1}"#,
    ),
    ("select the red box", "7 select"),
    // Moving.
    (
        "move the mug 10 cm left and 3 cm down",
        r#"3 translate {"vector":[-0.1,0,-0.03],"unit":"m"}"#,
    ),
    (
        "move the mug left 10 cm and up 2 cm",
        r#"3 translate {"vector":[-0.1,0,0.02],"unit":"m"}"#,
    ),
    (
        "Move the duck 5cm to the right.",
        r#"1 translate {"vector":[0.05,0,0],"unit":"m"}"#,
    ),
    (
        "shift the teapot 3 mm along -y",
        r#"4 translate {"axis":"-y","distance":0.003,"unit":"m"}"#,
    ),
    (
        "raise the mug by 2 cm",
        r#"3 translate {"vector":[0,0,0.02],"unit":"m"}"#,
    ),
    (
        "lower the teapot 1 cm",
        r#"4 translate {"vector":[0,0,-0.01],"unit":"m"}"#,
    ),
    (
        "push the cow 10 centimeters forward",
        r#"2 translate {"vector":[0,0.1,0],"unit":"m"}"#,
    ),
    (
        "pull the brick back 4 cm",
        r#"5 translate {"vector":[0,-0.04,0],"unit":"m"}"#,
    ),
    (
        "slide the red mug 0.5 m along negative x",
        r#"3 translate {"axis":"-x","distance":0.5,"unit":"m"}"#,
    ),
    (
        "nudge object 4 up by 1 cm",
        r#"4 translate {"vector":[0,0,0.01],"unit":"m"}"#,
    ),
    (
        "move the duck by 0.1 0.2 0 m",
        r#"1 translate {"vector":[0.1,0.2,0],"unit":"m"}"#,
    ),
    (
        "move the mug to 0.5 0.5 0.8",
        r#"3 translate {"vector":[0.6,0.5,0],"unit":"m"}"#,
    ),
    (
        "translate the teapot 2 inches along its own x axis",
        r#"4 translate {"axis":"x","distance":0.0508,"unit":"m","frame":"object"}"#,
    ),
    (
        "move the chair 1 foot back",
        r#"10 translate {"vector":[0,-0.3048,0],"unit":"m"}"#,
    ),
    (
        "lift the robot arm 5 mm",
        r#"6 translate {"vector":[0,0,0.005],"unit":"m"}"#,
    ),
    (
        "please move the yellow rubber duck 2 cm right",
        r#"1 translate {"vector":[0.02,0,0],"unit":"m"}"#,
    ),
    (
        "move the duck and the cow 5 cm forward",
        r#"1 translate {"vector":[0,0.05,0],"unit":"m"} | 2 translate {"vector":[0,0.05,0],"unit":"m"}"#,
    ),
    (
        "move the duck 10 cm left, and then 5 cm up",
        r#"1 translate {"vector":[-0.1,0,0],"unit":"m"} | 1 translate {"vector":[0,0,0.05],"unit":"m"}"#,
    ),
    (
        "could you drag the cup 7 cm towards the left",
        r#"3 translate {"vector":[-0.07,0,0],"unit":"m"}"#,
    ),
    // Rotating.
    (
        "turn the cow 45 degrees",
        r#"2 rotate {"angle":45,"unit":"deg"}"#,
    ),
    (
        "rotate the brick 90 degrees clockwise",
        r#"5 rotate {"angle":-90,"unit":"deg"}"#,
    ),
    (
        "spin the duck counter-clockwise by 30°",
        r#"1 rotate {"angle":30,"unit":"deg"}"#,
    ),
    (
        "rotate the teapot a quarter turn",
        r#"4 rotate {"angle":90,"unit":"deg"}"#,
    ),
    (
        "turn the mug around",
        r#"3 rotate {"angle":180,"unit":"deg"}"#,
    ),
    (
        "rotate the blue box by 0.5 rad about the x-axis",
        r#"8 rotate {"angle":28.64788975654116,"unit":"deg","axis":"x"}"#,
    ),
    (
        "yaw the robot arm by -20 degrees",
        r#"6 rotate {"angle":-20,"unit":"deg"}"#,
    ),
    (
        "rotate the teapot 90 degrees around its local y axis",
        r#"4 rotate {"angle":90,"unit":"deg","axis":"y","frame":"object"}"#,
    ),
    (
        "Rotate the Spot figurine by 180°",
        r#"2 rotate {"angle":180,"unit":"deg"}"#,
    ),
    (
        "twist the lego a half turn around the vertical axis",
        r#"9 rotate {"angle":180,"unit":"deg","axis":"up"}"#,
    ),
    // Scaling.
    ("scale the teapot by 1.5", r#"4 scale {"factor":1.5}"#),
    ("make the duck 50% bigger", r#"1 scale {"factor":1.5}"#),
    (
        "make the cow 3 times smaller",
        r#"2 scale {"factor":0.3333333333333333}"#,
    ),
    ("shrink the brick by 20%", r#"5 scale {"factor":0.8}"#),
    (
        "enlarge the lego by a factor of 2",
        r#"9 scale {"factor":2}"#,
    ),
    ("double the size of the mug", r#"3 scale {"factor":2}"#),
    ("halve the teapot", r#"4 scale {"factor":0.5}"#),
    ("make the red box half as big", r#"7 scale {"factor":0.5}"#),
    (
        "stretch the blue box along z by 2",
        r#"8 scale {"factor":2,"axis":"z"}"#,
    ),
    (
        "make the duck taller by 50%",
        r#"1 scale {"factor":1.5,"axis":"up"}"#,
    ),
    ("scale the chair to 80%", r#"10 scale {"factor":0.8}"#),
    ("grow the duck by half", r#"1 scale {"factor":1.5}"#),
    ("resize the robot arm to 2x", r#"6 scale {"factor":2}"#),
    // Deleting.
    ("remove the teapot", "4 delete"),
    ("get rid of the cow", "2 delete"),
    ("delete the boxes", "7 delete | 8 delete"),
    ("delete the duck and the cow", "1 delete | 2 delete"),
    ("remove the mug from the scene", "3 delete"),
    (
        "delete the duck, the cow and the teapot",
        "1 delete | 2 delete | 4 delete",
    ),
    // Replicating.
    ("copy the teapot", r#"4 replicate {"new_id":11}"#),
    (
        "make a copy of the brick and move it 10 cm up",
        r#"5 replicate {"new_id":11} | 11 translate {"vector":[0,0,0.1],"unit":"m"}"#,
    ),
    (
        "clone the duck 15 cm to the left",
        r#"1 replicate {"vector":[-0.15,0,0],"unit":"m","new_id":11}"#,
    ),
    (
        "make 2 copies of the mug",
        r#"3 replicate {"new_id":11} | 3 replicate {"new_id":12}"#,
    ),
    ("add another duck", r#"1 replicate {"new_id":11}"#),
    (
        "duplicate the chair, then rotate the new one by 90 degrees",
        r#"10 replicate {"new_id":11} | 11 rotate {"angle":90,"unit":"deg"}"#,
    ),
    // Swapping and adding across scenes.
    ("exchange the teapot with the cow", r#"4 swap {"with":2}"#),
    (
        "switch the positions of object 1 and object 2",
        r#"1 swap {"with":2}"#,
    ),
    (
        "swap the mug with the microphone from ../other.assist",
        r#"3 swap {"with":1,"scene":"../other.assist","new_id":11}"#,
    ),
    (
        "insert the mic from ../other.assist at 0.1 0.2 0.8",
        r#"11 add {"scene":"../other.assist","node":1,"position":[0.1,0.2,0.8],"unit":"m"}"#,
    ),
    // Coordinates written with commas, signs and a unit: one position, not three clauses.
    (
        "add the mic from ../other.assist at 0.1, -0.2, 80 cm",
        r#"11 add {"scene":"../other.assist","node":1,"position":[0.1,-0.2,80.0],"unit":"cm"}"#,
    ),
    (
        "bring in the microphone from ../other.assist",
        r#"11 add {"scene":"../other.assist","node":1}"#,
    ),
    // Selecting.
    ("highlight the cup", "3 select"),
    ("pick the green brick", "5 select"),
    ("select the duplo block", "5 select"),
    // Several actions in one sentence.
    (
        "move the duck 10 cm left, then rotate it 90 degrees",
        r#"1 translate {"vector":[-0.1,0,0],"unit":"m"} | 1 rotate {"angle":90,"unit":"deg"}"#,
    ),
    (
        "move the mug up 3 cm and rotate it by 45 degrees around z, then make it twice as big",
        r#"3 translate {"vector":[0,0,0.03],"unit":"m"} | 3 rotate {"angle":45,"unit":"deg","axis":"z"} | 3 scale {"factor":2}"#,
    ),
];

#[test]
fn instruction_table() {
    assert!(
        TABLE.len() >= 60,
        "the table has {} instructions",
        TABLE.len()
    );
    let s = scene();
    let mut failures = Vec::new();
    // The table is about words; where a scale keeps the object is tested below.
    let opts = ParseOptions {
        scale_about_center: true,
        ..Default::default()
    };
    for (text, spec) in TABLE {
        let want = expected(spec);
        match parse(text, &s, &opts, &mut Other) {
            Ok(actions) => {
                let got: Vec<Value> = actions
                    .iter()
                    .map(|a| serde_json::to_value(a).unwrap())
                    .collect();
                if got.len() != want.len() || !got.iter().zip(&want).all(|(g, w)| close(g, w)) {
                    failures.push(format!(
                        "{text:?}\n   got  {}\n   want {}",
                        Value::Array(got),
                        Value::Array(want)
                    ));
                }
            }
            Err(e) => failures.push(format!("{text:?}: error {e}")),
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} failed:\n{}",
        failures.len(),
        TABLE.len(),
        failures.join("\n")
    );
}

const ERRORS: &[(&str, &str)] = &[
    ("move the mug 10 cm left and down", "one each"),
    ("move the sofa 10 cm left", "no object called \"sofa\""),
    (
        "rotate the box 90 degrees",
        "could mean several objects: 7 \"red box\", 8 \"blue striped box\"",
    ),
    ("scale the mug by 0", "expected a scale factor > 0, got 0"),
    ("scale the teapot by -2", "expected a scale factor > 0"),
    (
        "move the duck by NaN cm along x",
        "expected a finite number",
    ),
    ("move the duck 10 cm", "which way"),
    ("scale the mug", "by how much"),
    ("rotate it 90 degrees", "does not refer to any object"),
    ("move 10 cm left", "no object named"),
    ("move 10 cm left", "1 \"yellow rubber duck\""),
    ("blah blah blah", "no operation understood"),
    ("delete the red chair", "no object called \"red chair\""),
    ("delete the blue duck", "no object called \"blue duck\""),
    ("delete the background", "cannot be deleted"),
    (
        "move the duck 10 degrees left",
        "an angle is not a distance",
    ),
    ("add the mic", "add what from where"),
    (
        "add the piano from ../other.assist",
        "no object called \"piano\"",
    ),
    ("add the mic from ../missing.assist", "no such scene"),
    ("swap the duck", "swap needs two objects"),
    ("make 1000 copies of the mug", "number of copies"),
    ("delete object 42", "no object called \"object 42\""),
];

#[test]
fn refused_instructions() {
    let s = scene();
    let mut failures = Vec::new();
    for (text, want) in ERRORS {
        match parse(text, &s, &ParseOptions::default(), &mut Other) {
            Ok(a) => failures.push(format!(
                "{text:?}: accepted as {}",
                serde_json::to_string(&a).unwrap()
            )),
            Err(e) => {
                let msg = e.to_string();
                if !msg.contains(want) {
                    failures.push(format!("{text:?}: error {msg:?} does not say {want:?}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn directions_follow_the_camera() {
    // A camera looking along +x with z up: its right is −y, so "left" is +y.
    let forward = DVec3::X;
    let up = DVec3::Z;
    let right = forward.cross(up);
    let cam = DMat3::from_cols(right, up, -forward);
    let opts = ParseOptions {
        camera: Some(cam),
        ..Default::default()
    };
    let s = scene();
    let a = parse("move the duck 10 cm left", &s, &opts, &mut Other).unwrap();
    assert_eq!(
        a[0].config
            .vector
            .map(|v| v.map(|x| (x * 1e9).round() / 1e9)),
        Some([0.0, 0.1, 0.0])
    );
    let a = parse("push the duck forward 10 cm", &s, &opts, &mut Other).unwrap();
    assert_eq!(
        a[0].config
            .vector
            .map(|v| v.map(|x| (x * 1e9).round() / 1e9)),
        Some([0.1, 0.0, 0.0])
    );
    // A tilted camera (looking down 30°): forward is still along the floor.
    let tilt = DQuat::from_axis_angle(right, -0.5);
    let cam2 = DMat3::from_quat(tilt) * cam;
    let opts = ParseOptions {
        camera: Some(cam2),
        ..Default::default()
    };
    let a = parse("move the duck 10 cm forward", &s, &opts, &mut Other).unwrap();
    let v = a[0].config.vector.unwrap();
    assert!(
        (v[0] - 0.1).abs() < 1e-9 && v[1].abs() < 1e-9 && v[2].abs() < 1e-9,
        "{v:?}"
    );
}

/// "can" names an object where it stands as a noun, and is a polite modal elsewhere.
#[test]
fn a_can_is_an_object_where_it_is_a_noun() {
    let mut bg = node(0, "background", [0.0, 0.0, 1.0]);
    bg.half_size = DVec3::splat(2.0);
    let s = Scene::with_nodes(
        vec![
            bg,
            node(1, "red soda can", [-0.5, 0.0, 0.8]),
            node(2, "mug", [0.5, 0.0, 0.8]),
        ],
        DVec3::Z,
    );
    for (text, id) in [
        ("move the can 10 cm left", 1),
        ("move can 10 cm left", 1),
        ("move the red can 10 cm left", 1),
        ("can you move the can 10 cm left", 1),
        ("please can you move the mug 10 cm left", 2),
        ("you can move the mug 10 cm left", 2),
        ("could you move the soda can 10 cm left", 1),
    ] {
        let a = parse(text, &s, &ParseOptions::default(), &mut Other)
            .unwrap_or_else(|e| panic!("{text:?}: {e}"));
        assert_eq!(a.len(), 1, "{text:?}: {a:?}");
        assert_eq!(a[0].instance_id, id, "{text:?}");
        let cfg = serde_json::to_value(&a[0]).unwrap()["config"].clone();
        assert!(
            close(&cfg, &json!({"vector": [-0.1, 0, 0], "unit": "m"})),
            "{text:?}: {cfg}"
        );
    }
    // "can't" still refuses by naming "not".
    let e = parse(
        "you can't move the can",
        &s,
        &ParseOptions::default(),
        &mut Other,
    );
    assert!(e.unwrap_err().to_string().contains("not"));
}

#[test]
fn it_refers_to_the_given_last_object() {
    let s = scene();
    let opts = ParseOptions {
        last: Some(4),
        ..Default::default()
    };
    let a = parse("rotate it 90 degrees", &s, &opts, &mut Other).unwrap();
    assert_eq!(a[0].instance_id, 4);
}

struct Letters;
impl TextEmbedder for Letters {
    fn embed(&self, text: &str) -> Option<Vec<f32>> {
        let mut v = vec![0.0f32; 26];
        for c in text.chars().filter(|c| c.is_ascii_lowercase()) {
            v[(c as u8 - b'a') as usize] += 1.0;
        }
        Some(v)
    }
}

#[test]
fn embeddings_resolve_what_labels_do_not() {
    let mut s = scene();
    // Node 10's label says nothing a user would type; its embedding does.
    s.nodes[10].label = "object_0042".into();
    s.nodes[10].embedding = Letters.embed("wooden chair");
    let opts = ParseOptions {
        embedder: Some(&Letters),
        ..Default::default()
    };
    let a = parse("delete the wooden chair", &s, &opts, &mut Other).unwrap();
    assert_eq!(a[0].instance_id, 10);
    // Without an embedder the same text is an unknown object.
    assert!(matches!(
        parse(
            "delete the wooden chair",
            &s,
            &ParseOptions::default(),
            &mut Other
        ),
        Err(LangError::UnknownObject { .. })
    ));
}

/// An embedder with fixed vectors for the phrases a test uses (as a CLIP text encoder
/// would give), unit length.
struct Table(Vec<(&'static str, [f32; 3])>);
impl TextEmbedder for Table {
    fn embed(&self, text: &str) -> Option<Vec<f32>> {
        self.0.iter().find(|(t, _)| *t == text).map(|(_, v)| {
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.iter().map(|x| x / n).collect()
        })
    }
}

fn embedded() -> Scene {
    let mut s = scene();
    s.nodes.truncate(5);
    s.nodes[1].embedding = Some(vec![1.0, 0.0, 0.0]); // duck
    s.nodes[2].embedding = Some(vec![0.0, 1.0, 0.0]); // cow
    s.nodes[3].embedding = Some(vec![0.0, 0.0, 1.0]); // mug
    s.nodes[4].embedding = Some(vec![0.0, 0.6, 0.8]); // teapot: mug-like and cow-like
    s
}

#[test]
fn meaning_finds_a_clear_winner() {
    let s = embedded();
    // (The phrase the parser hands over: articles and verbs gone.)
    let t = Table(vec![
        ("drinking vessel", [0.1, 0.0, 1.0]),
        ("toy", [1.0, 0.3, 0.0]),
    ]);
    let opts = ParseOptions {
        embedder: Some(&t),
        ..Default::default()
    };
    let a = parse("delete the drinking vessel", &s, &opts, &mut Other).unwrap();
    assert_eq!(a[0].instance_id, 3);
    // The paper's example: the whole description is compared, not only the words the
    // parser keeps ("drink").
    let t = Table(vec![("thing you drink from", [0.1, 0.0, 1.0])]);
    let opts = ParseOptions {
        embedder: Some(&t),
        ..Default::default()
    };
    for text in [
        "delete the thing you drink from",
        "move the thing you drink from 5 cm to the left",
        "please rotate the thing you drink from by 90 degrees",
    ] {
        let a = parse(text, &s, &opts, &mut Other).unwrap_or_else(|e| panic!("{text}: {e}"));
        assert_eq!(a[0].instance_id, 3, "{text}");
    }
    // "toy" is a synonym group of "figurine" (the cow's label): labels decide first.
    let a = parse("delete the toy", &s, &opts, &mut Other).unwrap();
    assert_eq!(a[0].instance_id, 2);
}

#[test]
fn meaning_too_close_to_call_is_an_error_with_scores() {
    let s = embedded();
    // Equally close to the mug (0,0,1) and the teapot (0,.6,.8)? cos to mug = b,
    // to teapot = .6a' + .8b: pick a vector on the bisector.
    let t = Table(vec![("hot drink vessel", [0.0, 0.333, 1.0])]);
    let opts = ParseOptions {
        embedder: Some(&t),
        ..Default::default()
    };
    let e = parse("move the hot drink vessel left", &s, &opts, &mut Other).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, LangError::TooClose { .. }), "{msg}");
    assert!(
        msg.contains("3 \"red ceramic mug\" 0.9") && msg.contains("4 \"blue Utah teapot\" 0.9"),
        "{msg}"
    );
    assert!(!msg.contains("duck"), "{msg}");
}

#[test]
fn meaning_without_embeddings_or_encoder_says_what_to_provide() {
    let t = Table(vec![("drinking vessel", [0.0, 0.0, 1.0])]);
    let opts = ParseOptions {
        embedder: Some(&t),
        ..Default::default()
    };
    let e = parse("delete the drinking vessel", &scene(), &opts, &mut Other)
        .unwrap_err()
        .to_string();
    assert!(e.contains("assist embed"), "{e}");
    let e = parse(
        "delete the drinking vessel",
        &embedded(),
        &ParseOptions::default(),
        &mut Other,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("ASSIST_CLIP"), "{e}");
}

/// Words that fit several labels, told apart by meaning; replicas (one embedding) stay
/// ambiguous.
#[test]
fn meaning_separates_what_labels_cannot() {
    let mut s = embedded();
    s.nodes[1].label = "glass mug".into();
    // "porcelain" is no label's word: the words leave both mugs.
    let t = Table(vec![("porcelain mug", [0.0, 0.1, 1.0])]);
    let opts = ParseOptions {
        embedder: Some(&t),
        ..Default::default()
    };
    let a = parse("delete the porcelain mug", &s, &opts, &mut Other);
    assert_eq!(a.unwrap()[0].instance_id, 3);
    s.nodes[1].embedding = s.nodes[3].embedding.clone();
    let e = parse("delete the porcelain mug", &s, &opts, &mut Other).unwrap_err();
    assert!(matches!(e, LangError::Ambiguous { .. }), "{e}");
}

/// By default a scale keeps the object's resting point (the middle of its box's lowest
/// face), after the instruction's earlier moves.
#[test]
fn a_scale_in_words_is_about_the_resting_point() {
    let s = scene();
    let a = parse(
        "move the mug up 3 cm and make it twice as big",
        &s,
        &ParseOptions::default(),
        &mut Other,
    )
    .unwrap();
    let mug = s.node(3).unwrap();
    let low = mug
        .world_corners()
        .iter()
        .map(|c| c.dot(s.up.normalize()))
        .fold(f64::INFINITY, f64::min);
    let c = a[1].config.center.expect("a pivot");
    let t = mug.world_from_local.translation;
    assert!(
        (c[0] - t.x).abs() < 1e-9 && (c[1] - t.y).abs() < 1e-9,
        "{c:?}"
    );
    assert!((c[2] - (low + 0.03)).abs() < 1e-9, "{c:?} vs lowest {low}");
}

/// The scene after "duplicate the red ceramic mug": node 11 is "red ceramic mug 2", of
/// class "red ceramic mug".
fn with_replica() -> Scene {
    let mut s = scene();
    let mut copy = node(11, "red ceramic mug 2", [-0.1, 0.2, 0.8]);
    copy.class = Some("red ceramic mug".into());
    s.nodes.push(copy);
    s
}

#[test]
fn replicas_are_named_by_their_number() {
    let s = with_replica();
    let o = ParseOptions::default();
    for (text, id) in [
        ("delete mug 2", 11),
        ("delete the mug 2", 11),
        ("delete the red ceramic mug 2", 11),
        ("remove the copy", 11),
        // the number is a quantity when a unit follows it
        ("move object 3 2 cm left", 3),
    ] {
        let a = parse(text, &s, &o, &mut Other).unwrap_or_else(|e| panic!("{text}: {e}"));
        assert_eq!(a[0].instance_id, id, "{text}");
    }
    // "make the copy twice as big" in a later instruction scales the copy.
    let a = parse("make the copy twice as big", &s, &o, &mut Other).unwrap();
    assert_eq!(
        (a[0].instance_id, a[0].operation),
        (11, assist_core::Operation::Scale)
    );
    // "mug 2 cm": a unit follows, so "the mug" is the original or the copy: ambiguous.
    assert!(matches!(
        parse("move the mug 2 cm left", &s, &o, &mut Other),
        Err(LangError::Ambiguous { .. })
    ));
    // A node labelled like an id ("object 3" on node 12) does not take over "object 3".
    let mut odd = with_replica();
    odd.nodes.push(node(12, "object 3", [0.7, 0.4, 0.8]));
    let a = parse("delete object 3", &odd, &o, &mut Other).unwrap();
    assert_eq!(a[0].instance_id, 3);
    // Without a replica, "the copy" refers to nothing.
    assert!(matches!(
        parse("remove the copy", &scene(), &o, &mut Other),
        Err(LangError::NoAntecedent { .. })
    ));
}
