//! `assist edit` from the command line: scripts, dry runs, undo, and bad input that must
//! leave the scene on disk untouched.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::common::{assist, s, write_scene};

fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

#[test]
fn dry_run_prints_resolved_actions_and_writes_nothing() {
    let tmp = assist_testkit::TempDir::new("cli-dry");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    let before = snapshot(tmp.path());
    let (ok, out, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "move the mug 10 cm left, then duplicate the duck",
        "--dry-run",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v[0]["instance_id"], 3);
    assert_eq!(v[0]["operation"], "translate");
    assert_eq!(
        v[0]["config"]["vector"],
        serde_json::json!([-0.1, 0.0, 0.0])
    );
    assert_eq!(v[1]["operation"], "replicate");
    assert_eq!(v[1]["config"]["new_id"], 4);
    assert!(snapshot(tmp.path()) == before, "a dry run must not write");
}

/// Issue 47: "remove everything except the mug" deleted the mug, with exit 0. It deletes
/// everything else; what the grammar does not read is refused by name, exit 1.
#[test]
fn except_keeps_the_object_it_names() {
    let tmp = assist_testkit::TempDir::new("cli-except");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    for text in [
        "remove everything except the mug",
        "delete everything but the mug",
        "remove all objects except the mug",
    ] {
        let (ok, out, err) = assist(&["edit", s(&scene), "--do", text, "--dry-run", "--json"]);
        assert!(ok, "{text}: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let deleted: Vec<u64> = v
            .as_array()
            .unwrap()
            .iter()
            .map(|a| {
                assert_eq!(a["operation"], "delete", "{text}: {v}");
                a["instance_id"].as_u64().unwrap()
            })
            .collect();
        assert_eq!(deleted, vec![1], "{text}: the duck goes, the mug (3) stays");
    }
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "delete the mug but not the duck",
        "--dry-run",
    ]);
    assert!(!ok && err.contains("\"but\""), "{err}");
}

#[test]
fn script_applies_and_undo_restores_the_scene_file() {
    let tmp = assist_testkit::TempDir::new("cli-undo");
    let (a, b, c) = (
        tmp.path().join("a.assist"),
        tmp.path().join("b.assist"),
        tmp.path().join("c.assist"),
    );
    write_scene(&a);
    // The desk benchmark's edit form, pretty-printed.
    let script = tmp.path().join("edit.json");
    std::fs::write(&script, "{\n  \"instance_id\": 3,\n  \"operation\": \"translate\",\n  \"config\": {\"offset\": [-0.17, 0.12, 0.0]}\n}\n").unwrap();
    let (ok, _, err) = assist(&["edit", s(&a), "--actions", s(&script), "--out", s(&b)]);
    assert!(ok, "{err}");
    let moved: serde_json::Value =
        serde_json::from_slice(&std::fs::read(b.join("scene.json")).unwrap()).unwrap();
    let t = &moved["nodes"][2]["world_from_local"]["translation"];
    assert!(
        (t[0].as_f64().unwrap() + 0.37).abs() < 1e-12
            && (t[1].as_f64().unwrap() - 0.12).abs() < 1e-12,
        "{t}"
    );
    let (ok, _, err) = assist(&["edit", s(&b), "--undo", "1", "--out", s(&c)]);
    assert!(ok, "{err}");
    assert_eq!(
        std::fs::read(a.join("scene.json")).unwrap(),
        std::fs::read(c.join("scene.json")).unwrap()
    );
    let (ok, _, err) = assist(&[
        "edit",
        s(&c),
        "--undo",
        "1",
        "--out",
        s(&tmp.path().join("d.assist")),
    ]);
    assert!(!ok && err.contains("only 0 edit(s) to undo"), "{err}");
}

#[test]
fn bad_input_is_refused_and_the_scene_is_untouched() {
    let tmp = assist_testkit::TempDir::new("cli-bad");
    let a = tmp.path().join("a.assist");
    write_scene(&a);
    let before = snapshot(&a);
    let bad = tmp.path().join("bad.jsonl");
    std::fs::write(&bad, "{\"instance_id\": 1, \"operation\": \"delete\", \"config\": {}}\n\n{\"instance_id\": 3, \"operation\": \"translate\", \"config\": {\"axis\": \"x\", \"distance\": 1}\n").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["--actions".into(), s(&bad).into()], "line 3"),
        (
            vec!["--do".into(), "delete object 42".into()],
            "no object called \"object 42\"",
        ),
        (
            vec![
                "--do".into(),
                "add the mic from /nonexistent/other.assist".into(),
            ],
            "/nonexistent/other.assist",
        ),
        (
            vec!["--do".into(), "scale the mug by 0".into()],
            "factor > 0",
        ),
        (
            vec!["--do".into(), "dance with the duck".into()],
            "no operation understood",
        ),
    ];
    for (extra, want) in cases {
        let mut args: Vec<String> = vec!["edit".into(), s(&a).into()];
        args.extend(extra.clone());
        args.extend(["--out".into(), s(&a).into(), "--force".into()]);
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, _, err) = assist(&argv);
        assert!(!ok, "{extra:?} succeeded");
        assert!(
            err.contains(want),
            "{extra:?}: {err:?} does not say {want:?}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            snapshot(&a) == before,
            "{extra:?} changed the scene's files"
        );
        assert_eq!(
            std::fs::read_dir(tmp.path()).unwrap().count(),
            2,
            "{extra:?} left files behind"
        );
    }
    // An action naming a missing id, from a script.
    let script = tmp.path().join("missing.jsonl");
    std::fs::write(&script, "{\"instance_id\": 9, \"operation\": \"rotate\", \"config\": {\"axis\": \"z\", \"degrees\": 90}}\n").unwrap();
    let (ok, _, err) = assist(&[
        "edit",
        s(&a),
        "--actions",
        s(&script),
        "--out",
        s(&tmp.path().join("o.assist")),
    ]);
    assert!(!ok && err.contains("instance_id 9: no such node"), "{err}");
    assert!(!tmp.path().join("o.assist").exists());
    // --out exists without --force.
    let (ok, _, err) = assist(&["edit", s(&a), "--do", "delete the duck", "--out", s(&a)]);
    assert!(!ok && err.contains("--force"), "{err}");
}

/// Edits that would leave a pose the scene file cannot hold (infinite after two 1e308 m
/// moves, or a scale beyond the limits after repeated scaling) are refused, naming the
/// action; the scene on disk is untouched and still loads; `--force` onto the same scene
/// cannot lose it either.
#[test]
fn edits_that_would_save_an_unloadable_scene_are_refused() {
    let tmp = assist_testkit::TempDir::new("cli-unloadable");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    let before = snapshot(&scene);
    let many_scales = vec!["make the mug 1000 times bigger"; 120].join(", then ");
    for text in [
        "move the mug 1e308 m left, then move it 1e308 m left",
        many_scales.as_str(),
    ] {
        for out in [s(&tmp.path().join("b.assist")), s(&scene)] {
            let args = vec!["edit", s(&scene), "--do", text, "--out", out, "--force"];
            let (ok, _, err) = assist(&args);
            assert!(!ok, "accepted: {text}");
            assert!(!err.contains("panicked"), "{err}");
            assert!(
                err.contains("refused") && (err.contains("translate") || err.contains("scale")),
                "the error should name the action: {err}"
            );
            assert_eq!(snapshot(&scene), before, "the scene changed");
        }
    }
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "move the mug 1 cm left",
        "--dry-run",
    ]);
    assert!(ok, "the scene no longer loads: {err}");
}

/// A corrupted history (a snapshot with an infinite pose, as older builds could write) is
/// an error naming history.json and the snapshot's field; undo cannot write it.
#[test]
fn a_history_snapshot_that_cannot_load_is_an_error_naming_it() {
    let tmp = assist_testkit::TempDir::new("cli-bad-history");
    let a = tmp.path().join("a.assist");
    write_scene(&a);
    let (scene, hist, mut h) = edited_once(&a, &tmp.path().join("b.assist"));
    h["undo"][0]["scene"]["nodes"][1]["world_from_local"]["scale"] =
        serde_json::json!([1e300, 1.0, 1.0]);
    std::fs::write(&hist, serde_json::to_vec(&h).unwrap()).unwrap();
    let before = snapshot(&scene);
    let c = tmp.path().join("c.assist");
    let (ok, _, err) = assist(&["edit", s(&scene), "--undo", "1", "--out", s(&c)]);
    assert!(!ok, "undo of a corrupted history succeeded");
    assert!(!c.exists());
    assert!(
        err.contains("history.json")
            && err.contains("undo[0].scene.nodes[1].world_from_local.scale"),
        "{err}"
    );
    assert_eq!(snapshot(&scene), before);
}

/// One instruction is one undo step, recorded with its words and resolved actions:
/// "duplicate … and move the copy …" then `--undo 1` leaves no copy behind; `--history`
/// lists the steps; `--undo N --dry-run` says what would change and writes nothing; a
/// history saved before steps carried their instruction still loads and undoes.
#[test]
fn one_instruction_is_one_undo_step_with_its_words() {
    let tmp = assist_testkit::TempDir::new("cli-history");
    let a = tmp.path().join("a.assist");
    write_scene(&a);
    let nodes = |p: &Path| -> Vec<u64> {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(p.join("scene.json")).unwrap()).unwrap();
        v["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["id"].as_u64().unwrap())
            .collect()
    };
    let (b, c, d) = (
        tmp.path().join("b.assist"),
        tmp.path().join("c.assist"),
        tmp.path().join("d.assist"),
    );
    let text = "duplicate the duck and move the copy 20 cm left";
    let (ok, _, err) = assist(&["edit", s(&a), "--do", text, "--out", s(&b)]);
    assert!(ok, "{err}");
    assert_eq!(nodes(&b).len(), nodes(&a).len() + 1);
    let (ok, _, err) = assist(&["edit", s(&b), "--do", "delete the mug", "--out", s(&c)]);
    assert!(ok, "{err}");

    // The history: two steps, each with its instruction and actions.
    let (ok, out, err) = assist(&["edit", s(&c), "--history", "--json"]);
    assert!(ok, "{err}");
    let h: serde_json::Value = serde_json::from_str(&out).unwrap();
    let undo = h["undo"].as_array().unwrap();
    assert_eq!(undo.len(), 2, "{h}");
    assert_eq!(undo[0]["text"], text);
    let ops: Vec<&str> = undo[0]["actions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["operation"].as_str().unwrap())
        .collect();
    assert_eq!(ops, ["replicate", "translate"]);
    assert_eq!(undo[1]["text"], "delete the mug");
    let (ok, out, _) = assist(&["edit", s(&c), "--history"]);
    assert!(
        ok && out.contains(text) && out.contains("delete the mug"),
        "{out}"
    );

    // A dry run of two undos names both steps and what they change, and writes nothing.
    let before = snapshot(tmp.path());
    let (ok, out, err) = assist(&["edit", s(&c), "--undo", "2", "--dry-run", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["undo"].as_array().unwrap().len(), 2, "{v}");
    let changes = v["changes"].to_string();
    assert!(
        changes.contains("\"added\"") && changes.contains("\"deleted\""),
        "the mug comes back, the copy goes: {v}"
    );
    let (ok, out, _) = assist(&["edit", s(&c), "--undo", "1", "--dry-run"]);
    assert!(
        ok && out.contains("delete the mug") && out.contains("added"),
        "{out}"
    );
    assert!(snapshot(tmp.path()) == before, "a dry run must not write");

    // `--undo 2` is back to the original: the copy is gone with its move.
    let (ok, _, err) = assist(&["edit", s(&c), "--undo", "2", "--out", s(&d)]);
    assert!(ok, "{err}");
    assert_eq!(nodes(&d), nodes(&a));
    let (ok, out, _) = assist(&["edit", s(&d), "--history", "--json"]);
    assert!(ok);
    let h: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(h["undo"].as_array().unwrap().len(), 0);
    assert_eq!(h["redo"][0]["text"], text, "the next redo first: {h}");

    // A history of bare snapshots (older scenes) loads, lists and undoes.
    let hist = c.join("history.json");
    let mut h: serde_json::Value = serde_json::from_slice(&std::fs::read(&hist).unwrap()).unwrap();
    for step in h["undo"].as_array_mut().unwrap() {
        *step = step["scene"].clone();
    }
    std::fs::write(&hist, serde_json::to_vec(&h).unwrap()).unwrap();
    let (ok, out, err) = assist(&["edit", s(&c), "--history"]);
    assert!(ok && out.contains("not recorded"), "{out}{err}");
    let e = tmp.path().join("e.assist");
    let (ok, _, err) = assist(&["edit", s(&c), "--undo", "2", "--out", s(&e)]);
    assert!(ok, "{err}");
    assert_eq!(nodes(&e), nodes(&a));
}

/// "make the duck twice as big" keeps its resting point: the box's lowest point along up
/// stays where it was (it does not sink into the table); `--pivot center` keeps the box
/// centre instead.
#[test]
fn scaling_in_words_keeps_the_object_on_its_support() {
    let tmp = assist_testkit::TempDir::new("cli-scale-base");
    let a = tmp.path().join("a.assist");
    write_scene(&a);
    let node = |p: &Path, id: u64| -> assist_core::SceneNode {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(p.join("scene.json")).unwrap()).unwrap();
        let n = v["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["id"] == id)
            .unwrap()
            .clone();
        serde_json::from_value(n).unwrap()
    };
    let up = {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(a.join("scene.json")).unwrap()).unwrap();
        let u: [f64; 3] = serde_json::from_value(v["up"].clone()).unwrap();
        assist_core::DVec3::from(u).normalize()
    };
    let low = |n: &assist_core::SceneNode| {
        n.world_corners()
            .iter()
            .map(|c| c.dot(up))
            .fold(f64::INFINITY, f64::min)
    };
    let duck = node(&a, 1);
    let (b, c) = (tmp.path().join("b.assist"), tmp.path().join("c.assist"));
    let text = "make the duck twice as big";
    let (ok, _, err) = assist(&["edit", s(&a), "--do", text, "--out", s(&b)]);
    assert!(ok, "{err}");
    let big = node(&b, 1);
    assert!((big.world_from_local.scale.x - 2.0).abs() < 1e-9);
    assert!(
        (low(&big) - low(&duck)).abs() < 1e-9,
        "the base moved from {} to {}",
        low(&duck),
        low(&big)
    );
    let (ok, _, err) = assist(&[
        "edit",
        s(&a),
        "--do",
        text,
        "--pivot",
        "center",
        "--out",
        s(&c),
    ]);
    assert!(ok, "{err}");
    let centred = node(&c, 1);
    assert!(
        (centred.world_from_local.translation - duck.world_from_local.translation).length() < 1e-9
    );
    assert!(
        low(&centred) < low(&duck) - 1e-3,
        "about the centre the base sinks"
    );
}

/// An edit of poses shares the weights on disk: each field file of the edited scene is the
/// original's file under a second name (a hard link), and deleting the original leaves
/// the edited scene whole.
#[cfg(unix)]
#[test]
fn edits_share_weights_on_disk_and_survive_the_original() {
    use std::os::unix::fs::MetadataExt;
    let tmp = assist_testkit::TempDir::new("cli-shared-fields");
    let (a, b) = (tmp.path().join("a.assist"), tmp.path().join("b.assist"));
    write_scene(&a);
    let (ok, _, err) = assist(&[
        "edit",
        s(&a),
        "--do",
        "move the mug 5 cm left",
        "--out",
        s(&b),
    ]);
    assert!(ok, "{err}");
    let fields: Vec<PathBuf> = std::fs::read_dir(a.join("fields"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert!(!fields.is_empty());
    for f in &fields {
        let g = b.join("fields").join(f.file_name().unwrap());
        let (mf, mg) = (
            std::fs::metadata(f).unwrap(),
            std::fs::metadata(&g).unwrap(),
        );
        assert_eq!(mf.ino(), mg.ino(), "{} was written again", g.display());
    }
    let before = snapshot(&b);
    std::fs::remove_dir_all(&a).unwrap();
    assert_eq!(snapshot(&b), before);
    let (ok, _, err) = assist(&["edit", s(&b), "--do", "delete the mug", "--dry-run"]);
    assert!(ok, "the edited scene no longer loads: {err}");
}

/// A scene at `scene` on a table (the background: a dense slab whose top is at z = 0.75)
/// with `objects` (id, label, centre, size) of constant dense fields.
fn table_scene(scene: &std::path::Path, objects: &[(u16, &str, [f64; 3], f64)]) {
    use std::sync::Arc;

    use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode};
    use assist_field::{Field, OccupancyGrid};
    use assist_scene::{NeuralScene, NodeField};
    let table = SceneNode::from_obb(
        0,
        "background",
        "background",
        &Obb::new(
            DVec3::new(0.0, 0.0, 0.625),
            DVec3::new(2.0, 2.0, 0.25),
            DMat3::IDENTITY,
        ),
    );
    let mut nodes = vec![table];
    for (id, label, at, size) in objects {
        nodes.push(SceneNode::from_obb(
            *id,
            label,
            label,
            &Obb::new(DVec3::from_array(*at), DVec3::splat(*size), DMat3::IDENTITY),
        ));
    }
    let mut fields = BTreeMap::new();
    for n in &nodes {
        let f = Field::constant(1000.0, [0.5; 3], false, 1).unwrap();
        fields.insert(
            n.field.clone(),
            Arc::new(NodeField::new(f, OccupancyGrid::new(8), n.half_size)),
        );
    }
    let ns = NeuralScene {
        scene: Scene::with_nodes(nodes, DVec3::Z),
        fields,
    };
    assist_scene::scene_file::save(scene, &ns, serde_json::Value::Null, false).unwrap();
}

/// A mug resting on a table moved 5 cm down sinks into it: a warning, or under `--strict`
/// a refusal that writes nothing; moved sideways, nothing is said.
#[test]
fn an_object_pushed_into_its_support_is_warned_about() {
    let tmp = assist_testkit::TempDir::new("cli-sink");
    let scene = tmp.path().join("a.assist");
    table_scene(&scene, &[(1, "mug", [0.0, 0.0, 0.8], 0.1)]);
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "move the mug 5 cm down",
        "--dry-run",
    ]);
    assert!(ok, "{err}");
    assert!(
        err.contains("warning") && err.contains("sink about 5 cm"),
        "{err}"
    );
    for fine in [
        "move the mug 5 cm up",
        "move the mug 20 cm left",
        "move the mug 1 cm down",
    ] {
        let (ok, _, err) = assist(&["edit", s(&scene), "--do", fine, "--dry-run"]);
        assert!(ok && !err.contains("sink"), "{fine}: {err}");
    }
    let e = tmp.path().join("e.assist");
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "move the mug 5 cm down",
        "--strict",
        "--out",
        s(&e),
    ]);
    assert!(
        !ok && err.contains("--strict") && err.contains("sink"),
        "{err}"
    );
    assert!(!e.exists());
}

/// Issue 47, item 6: "move the mug 25 cm left" put it inside the duck and "move the
/// brick 12 cm up" left it floating, without a word. Each is a warning naming both
/// objects or the gap, `--strict` refuses it, `--allow-overlap` accepts it silently, and
/// `--settle` lowers a floating object onto the table in the same edit.
#[test]
fn edits_that_interpenetrate_or_float_are_warned_about() {
    let tmp = assist_testkit::TempDir::new("cli-overlap");
    let scene = tmp.path().join("a.assist");
    table_scene(
        &scene,
        &[
            (1, "mug", [0.0, 0.0, 0.8], 0.1),
            (2, "duck", [-0.25, 0.0, 0.8], 0.1),
        ],
    );
    let edit = |text: &str, extra: &[&str]| {
        let mut args = vec!["edit", s(&scene), "--do", text, "--dry-run", "--json"];
        args.extend_from_slice(extra);
        assist(&args)
    };
    let (ok, _, err) = edit("move the mug 22 cm left", &[]);
    assert!(ok, "{err}");
    assert!(
        err.contains("warning") && err.contains("\"mug\" would reach") && err.contains("\"duck\""),
        "{err}"
    );
    let (ok, _, err) = edit("move the mug 12 cm up", &[]);
    assert!(
        ok && err.contains("would float 12 cm") && err.contains("--settle"),
        "{err}"
    );
    for (text, extra) in [
        ("move the mug 22 cm left", vec!["--strict"]),
        ("move the mug 12 cm up", vec!["--strict"]),
    ] {
        let (ok, _, err) = edit(text, &extra);
        assert!(!ok && err.contains("--strict"), "{text}: {err}");
    }
    for (text, extra) in [
        ("move the mug 22 cm left", vec!["--allow-overlap"]),
        ("move the mug 12 cm up", vec!["--allow-overlap"]),
        ("move the mug 10 cm right", vec![]),
        ("move the mug 1 cm up", vec![]),
    ] {
        let (ok, _, err) = edit(text, &extra);
        assert!(ok && !err.contains("warning"), "{text}: {err}");
    }
    // --settle: the move up, then a move down onto the table, in one step.
    let (ok, out, err) = edit("move the mug 12 cm up", &["--settle"]);
    assert!(ok && !err.contains("warning"), "{err}");
    let actions: serde_json::Value = serde_json::from_str(&out).unwrap();
    let z: Vec<f64> = actions
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["config"]["vector"][2].as_f64().unwrap())
        .collect();
    assert_eq!(z.len(), 2, "{out}");
    assert!(
        (z[0] - 0.12).abs() < 1e-9 && (z[0] + z[1]).abs() < 0.005,
        "{z:?}"
    );
}

/// Issue 47, items 13, 16 and 18: scene files that loaded though they could not be used
/// (a 1e308 box, an object sharing the background's field, an unknown key
/// that the next save would drop, no nodes at all — which made `render` panic —, a colour
/// out of range, empty or control-character labels), and an undo snapshot with two nodes
/// of one id, which `--undo` installed and every later command then failed on. Each is
/// refused on load naming `scene.json` (or `history.json`) and the field, exit 1. (A scene
/// without a background node is legitimate: a Blender capture's objects on a plain
/// backdrop.)
#[test]
fn corrupted_scene_files_are_refused_naming_the_field() {
    let tmp = assist_testkit::TempDir::new("cli-corrupt");
    let good = tmp.path().join("good.assist");
    write_scene(&good);
    let text = std::fs::read_to_string(good.join("scene.json")).unwrap();
    let base: serde_json::Value = serde_json::from_str(&text).unwrap();
    type Corrupt = fn(&mut serde_json::Value);
    let cases: &[(&str, Corrupt, &str)] = &[
        (
            "huge box",
            |v| v["nodes"][1]["half_size"] = serde_json::json!([1e308, 0.05, 0.05]),
            "nodes[1].half_size",
        ),
        (
            "shared background field",
            |v| v["nodes"][2]["field"] = v["nodes"][0]["field"].clone(),
            "shares the background's field",
        ),
        (
            "unknown key",
            |v| v["colour"] = serde_json::json!(1),
            "colour: unknown key",
        ),
        (
            "no nodes",
            |v| v["nodes"] = serde_json::json!([]),
            "at least one node",
        ),
        (
            "colour out of range",
            |v| v["background_color"] = serde_json::json!([2.0, -1.0, 0.5]),
            "background_color",
        ),
        (
            "empty label",
            |v| v["nodes"][1]["label"] = serde_json::json!(""),
            "nodes[1].label",
        ),
        (
            "control characters",
            |v| v["nodes"][1]["label"] = serde_json::json!("duck\u{7}"),
            "nodes[1].label",
        ),
    ];
    for (what, corrupt, field) in cases {
        let dir = tmp.path().join(what.replace(' ', "_") + ".assist");
        copy_dir(&good, &dir);
        let mut v = base.clone();
        corrupt(&mut v);
        std::fs::write(dir.join("scene.json"), serde_json::to_vec(&v).unwrap()).unwrap();
        for args in [
            vec!["scene", "info", s(&dir)],
            vec![
                "render",
                s(&dir),
                "--out",
                "unused",
                "--frames",
                "1",
                "--size",
                "8x8",
            ],
        ] {
            let (ok, _, err) = assist(&args);
            assert!(!ok, "{what}: {args:?} accepted the scene");
            assert!(
                err.contains("scene.json") && err.contains(field) && !err.contains("panicked"),
                "{what}: {args:?}: {err}"
            );
        }
    }
    // Objects without a background (a Blender capture's scene) load as they are.
    let objects_only = tmp.path().join("objects_only.assist");
    copy_dir(&good, &objects_only);
    let mut v = base.clone();
    v["nodes"].as_array_mut().unwrap().remove(0);
    std::fs::write(
        objects_only.join("scene.json"),
        serde_json::to_vec(&v).unwrap(),
    )
    .unwrap();
    let (ok, _, err) = assist(&["scene", "info", s(&objects_only)]);
    assert!(ok, "a scene of objects alone must load: {err}");
    // An undo snapshot with two nodes of one id: refused, the scene kept as it was.
    let (scene, hist, mut h) = edited_once(&good, &tmp.path().join("b.assist"));
    h["undo"][0]["scene"]["nodes"][2]["id"] = h["undo"][0]["scene"]["nodes"][1]["id"].clone();
    std::fs::write(&hist, serde_json::to_vec(&h).unwrap()).unwrap();
    let before = snapshot(&scene);
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--undo",
        "1",
        "--out",
        s(&scene),
        "--force",
    ]);
    assert!(!ok, "undo installed a snapshot with a repeated id");
    assert!(
        err.contains("history.json") && err.contains("undo[0].scene.nodes[2].id"),
        "{err}"
    );
    assert_eq!(snapshot(&scene), before);
}

fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// `from` edited once ("move the mug 1 cm left") into `out`: the scene, its history file
/// and that file's JSON.
fn edited_once(
    from: &std::path::Path,
    out: &std::path::Path,
) -> (std::path::PathBuf, std::path::PathBuf, serde_json::Value) {
    let (ok, _, err) = assist(&[
        "edit",
        s(from),
        "--do",
        "move the mug 1 cm left",
        "--out",
        s(out),
    ]);
    assert!(ok, "{err}");
    let hist = out.join("history.json");
    let h = serde_json::from_slice(&std::fs::read(&hist).unwrap()).unwrap();
    (out.to_path_buf(), hist, h)
}

/// Issue 47, item 10: `scene info` cut labels at 32 characters.
#[test]
fn scene_info_shows_whole_labels() {
    let tmp = assist_testkit::TempDir::new("cli-info-labels");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    let long = "green toy building brick (2x2 Duplo-style), the one by the mug";
    let mut v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scene.join("scene.json")).unwrap()).unwrap();
    v["nodes"][1]["label"] = long.into();
    std::fs::write(scene.join("scene.json"), serde_json::to_vec(&v).unwrap()).unwrap();
    let (ok, out, err) = assist(&["scene", "info", s(&scene)]);
    assert!(ok, "{err}");
    assert!(out.contains(long), "{out}");
}

#[test]
fn scene_scale_sets_metres_from_an_objects_height_and_edits_follow() {
    let tmp = assist_testkit::TempDir::new("cli-scale");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    let out_scene = tmp.path().join("b.assist");
    // The mug's box is 0.05 units tall and its grid fully occupied: 20 cm makes a unit 4 m.
    let (ok, out, err) = assist(&[
        "scene",
        "scale",
        s(&scene),
        "--out",
        s(&out_scene),
        "--object",
        "mug",
        "--height",
        "20cm",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let mpu = v["meters_per_unit"].as_f64().unwrap();
    assert!((mpu - 4.0).abs() < 1e-9, "{v}");
    assert_eq!(v["object"]["label"], "red ceramic mug");
    // An edit in centimetres moves by the new unit (10 cm = 0.025 units); one undo step
    // goes back to 1 m.
    let moved = tmp.path().join("m.assist");
    let (ok, _, err) = assist(&[
        "edit",
        s(&out_scene),
        "--do",
        "move the mug 10 cm left",
        "--out",
        s(&moved),
        "--allow-overlap",
    ]);
    assert!(ok, "{err}");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(moved.join("scene.json")).unwrap()).unwrap();
    let mug = m["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["id"] == 3)
        .unwrap();
    let x = mug["world_from_local"]["translation"][0].as_f64().unwrap();
    assert!((x - (-0.225)).abs() < 1e-9, "the mug at x = {x}");
    let undone = tmp.path().join("c.assist");
    let (ok, _, err) = assist(&["edit", s(&out_scene), "--undo", "1", "--out", s(&undone)]);
    assert!(ok, "{err}");
    let (ok, out, _) = assist(&["scene", "info", s(&undone), "--json"]);
    assert!(ok);
    let info: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(info["meters_per_unit"].as_f64(), Some(1.0), "{info}");
    // Bad input names what is wrong and writes nothing.
    let before = snapshot(tmp.path());
    for (args, want) in [
        (vec!["--object", "mug", "--height", "20"], "unit"),
        (vec!["--object", "mug", "--height=-3cm"], "positive"),
        (
            vec!["--object", "background", "--height", "1m"],
            "background",
        ),
        (vec!["--object", "teapot", "--height", "1m"], "teapot"),
        (vec!["--meters-per-unit", "0"], "meters_per_unit"),
    ] {
        let mut a = vec!["scene", "scale", s(&scene), "--out"];
        let dest = tmp.path().join("d.assist");
        a.push(s(&dest));
        a.extend(args);
        let (ok, _, err) = assist(&a);
        assert!(!ok && err.contains(want), "{a:?}: {err}");
    }
    assert_eq!(before, snapshot(tmp.path()), "nothing written");
}
