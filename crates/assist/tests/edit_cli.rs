//! `assist edit` from the command line: scripts, dry runs, undo, and bad input that must
//! leave the scene on disk untouched.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode};
use assist_field::{Field, FieldConfig, OccupancyGrid};
use assist_render::{NeuralScene, NodeField};

fn small_field(seed: u64) -> Field {
    let mut cfg = FieldConfig::object(0);
    cfg.appearance_dim = 0;
    cfg.log2_table_size = 10;
    cfg.levels = 2;
    Field::new(cfg, seed).unwrap()
}

/// A scene with a duck (1) and a mug (3) on a background, saved to `dir`.
fn write_scene(dir: &Path) {
    let n = |id: u16, label: &str, key: &str, at: [f64; 3]| {
        SceneNode::from_obb(
            id,
            label,
            key,
            &Obb::new(DVec3::from_array(at), DVec3::splat(0.05), DMat3::IDENTITY),
        )
    };
    let nodes = vec![
        n(0, "background", "background", [0.0, 0.0, 0.5]),
        n(1, "yellow rubber duck", "duck", [0.2, 0.0, 0.8]),
        n(3, "red ceramic mug", "mug", [-0.2, 0.0, 0.8]),
    ];
    let mut fields = BTreeMap::new();
    for (i, k) in ["background", "duck", "mug"].iter().enumerate() {
        let half = nodes.iter().find(|n| n.field == *k).unwrap().half_size;
        fields.insert(
            k.to_string(),
            Arc::new(NodeField::new(
                small_field(i as u64),
                OccupancyGrid::new(8),
                half,
            )),
        );
    }
    let s = NeuralScene {
        scene: Scene {
            nodes,
            up: DVec3::Z,
            meters_per_unit: 1.0,
            background_color: [0.0; 3],
            selected: None,
        },
        fields,
    };
    assist_render::scene_file::save(dir, &s, serde_json::Value::Null, false).unwrap();
}

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

fn assist(args: &[&str]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_assist"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
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
