//! `assist dataset boxes` and `assist train --boxes`: the boxes a scene is built with can be
//! listed, edited and given back; bad box files are clear errors.

use crate::common;

use std::process::Output;

use crate::common::{ok_stdout as ok, run as assist, s};
use assist_core::{DMat3, DQuat, DVec3};
use assist_testkit::TempDir;
use serde_json::{Value, json};

fn fails_with(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "error should mention {n:?}: {err}");
    }
}

fn vec3(v: &Value) -> DVec3 {
    DVec3::new(
        v[0].as_f64().unwrap(),
        v[1].as_f64().unwrap(),
        v[2].as_f64().unwrap(),
    )
}

#[test]
fn boxes_are_listed_carved_overridden_and_checked() {
    let tmp = TempDir::new("cli-boxes");
    let data = tmp.join("synth");
    common::synth_small(&data, 24);
    // The dataset's true boxes, then the same dataset without instance 2's box: its box
    // must be carved from the masks and hold the true one.
    let tf_path = data.join("transforms.json");
    let mut tf: Value = serde_json::from_slice(&std::fs::read(&tf_path).unwrap()).unwrap();
    let truth = tf["instances"][1]["bbox"].clone();
    assert_eq!(tf["instances"][1]["id"], 2);
    tf["instances"][1].as_object_mut().unwrap().remove("bbox");
    std::fs::write(&tf_path, serde_json::to_vec_pretty(&tf).unwrap()).unwrap();

    let listed: Value =
        serde_json::from_str(&ok(&assist(&["dataset", "boxes", s(&data), "--json"]))).unwrap();
    let inst = listed["instances"].as_array().unwrap();
    assert_eq!(inst.len(), 3);
    assert_eq!(inst[0]["source"], "dataset");
    assert_eq!(inst[1]["source"], "carved");
    let (c, half) = (
        vec3(&inst[1]["bbox"]["center"]),
        vec3(&inst[1]["bbox"]["size"]) * 0.5,
    );
    let (tc, th) = (vec3(&truth["center"]), vec3(&truth["size"]) * 0.5);
    let rot = DMat3::from_cols(
        vec3(&json!([
            truth["rotation"][0][0],
            truth["rotation"][1][0],
            truth["rotation"][2][0]
        ])),
        vec3(&json!([
            truth["rotation"][0][1],
            truth["rotation"][1][1],
            truth["rotation"][2][1]
        ])),
        vec3(&json!([
            truth["rotation"][0][2],
            truth["rotation"][1][2],
            truth["rotation"][2][2]
        ])),
    );
    // Every corner of the true box lies in the carved box (within 2 cm), and the carved box
    // is not much larger than the true box's axis-aligned bounds.
    let mut true_aabb_half = DVec3::ZERO;
    for k in 0..8 {
        let sgn = DVec3::new(
            if k & 1 == 0 { -1.0 } else { 1.0 },
            if k & 2 == 0 { -1.0 } else { 1.0 },
            if k & 4 == 0 { -1.0 } else { 1.0 },
        );
        let p = tc + rot * (sgn * th);
        true_aabb_half = true_aabb_half.max((p - tc).abs());
        let d = (p - c).abs() - half;
        assert!(
            d.max_element() < 0.02,
            "true corner {p} outside carved box {c} ± {half}"
        );
    }
    assert!(
        (half - true_aabb_half).max_element() < 0.5 * true_aabb_half.max_element(),
        "carved box {half} much larger than the truth {true_aabb_half}"
    );

    // Edit the listing: instance 1 by label, rotated and moved; train with it.
    let label = inst[0]["label"].as_str().unwrap().to_string();
    let r = DMat3::from_quat(DQuat::from_rotation_z(0.5));
    let rows: Vec<[f64; 3]> = (0..3).map(|i| r.row(i).to_array()).collect();
    let given_center = vec3(&inst[0]["bbox"]["center"]) + DVec3::new(0.01, -0.02, 0.0);
    let given_size = DVec3::new(0.3, 0.25, 0.2);
    let boxes = json!({"instances": [{
        "label": label,
        "bbox": {"center": given_center.to_array(), "size": given_size.to_array(), "rotation": rows}
    }]});
    let boxes_path = tmp.join("boxes.json");
    std::fs::write(&boxes_path, serde_json::to_vec(&boxes).unwrap()).unwrap();
    let listed2: Value = serde_json::from_str(&ok(&assist(&[
        "dataset",
        "boxes",
        s(&data),
        "--json",
        "--boxes",
        s(&boxes_path),
    ])))
    .unwrap();
    assert_eq!(listed2["instances"][0]["source"], "user");
    assert_eq!(listed2["instances"][1], listed["instances"][1]);
    let scene = tmp.join("s.assist");
    ok(&assist(&[
        "train",
        s(&data),
        "--out",
        s(&scene),
        "--iters",
        "2",
        "--boxes",
        s(&boxes_path),
        "--json",
    ]));
    let (trained, _) = assist_scene::scene_file::load(&scene).unwrap();
    let node = trained.scene.nodes.iter().find(|n| n.id == 1).unwrap();
    assert!(
        (node.half_size - given_size * 0.5).length() < 1e-6,
        "{:?}",
        node.half_size
    );
    assert!((node.world_from_local.translation - given_center).length() < 1e-6);
    let q = DQuat::from_mat3(&r);
    assert!(node.world_from_local.rotation.angle_between(q) < 1e-6);
    let carved = trained.scene.nodes.iter().find(|n| n.id == 2).unwrap();
    assert!((carved.half_size - half).length() < 1e-6);

    // Bad box files: no such instance, contradicting id and label, a broken box, resume.
    let bad = |name: &str, v: Value| {
        let p = tmp.join(name);
        std::fs::write(&p, serde_json::to_vec(&v).unwrap()).unwrap();
        p
    };
    let unit = json!({"center": [0, 0, 0], "size": [0.1, 0.1, 0.1]});
    let p = bad(
        "nolabel.json",
        json!({"instances": [{"label": "giraffe", "bbox": unit}]}),
    );
    let out2 = tmp.join("x.assist");
    fails_with(
        &assist(&[
            "train",
            s(&data),
            "--out",
            s(&out2),
            "--iters",
            "1",
            "--boxes",
            s(&p),
        ]),
        &["nolabel.json", "instances[0]", "names no instance", &label],
    );
    assert!(!out2.exists());
    let p = bad(
        "clash.json",
        json!({"instances": [{"id": 2, "label": label, "bbox": unit}]}),
    );
    fails_with(
        &assist(&["dataset", "boxes", s(&data), "--boxes", s(&p)]),
        &["clash.json", "instances[0]", "different instances"],
    );
    let p = bad(
        "twice.json",
        json!({"instances": [{"id": 1, "bbox": unit}, {"label": label, "bbox": unit}]}),
    );
    fails_with(
        &assist(&["dataset", "boxes", s(&data), "--boxes", s(&p)]),
        &[
            "twice.json",
            "instances[0]",
            "instances[1]",
            "both give a box",
        ],
    );
    let p = bad(
        "flat.json",
        json!({"instances": [{"id": 2, "bbox": {"center": [0, 0, 0], "size": [0.1, 0, 0.1]}}]}),
    );
    fails_with(
        &assist(&["train", s(&data), "--out", s(&out2), "--boxes", s(&p)]),
        &["flat.json", "instances[0].bbox.size", "positive"],
    );
    let before = std::fs::read(scene.join("scene.json")).unwrap();
    fails_with(
        &assist(&[
            "train",
            s(&data),
            "--out",
            s(&scene),
            "--resume",
            "--boxes",
            s(&boxes_path),
        ]),
        &["--boxes", "resumed"],
    );
    assert_eq!(before, std::fs::read(scene.join("scene.json")).unwrap());
    // Fractions and transmittances are refused outside [0, 1], naming the flag.
    for flag in ["--object-rays", "--hidden-stop"] {
        for bad in ["1.5", "-0.1", "NaN"] {
            let arg = format!("{flag}={bad}");
            fails_with(
                &assist(&["train", s(&data), "--out", s(&out2), "--iters", "1", &arg]),
                &[flag, "between 0 and 1", bad],
            );
            assert!(!out2.exists());
        }
    }
    for bad in ["0", "9", "NaN"] {
        let arg = format!("--step-scale={bad}");
        fails_with(
            &assist(&["train", s(&data), "--out", s(&out2), "--iters", "1", &arg]),
            &["--step-scale", "between 0.25 and 8", bad],
        );
        assert!(!out2.exists());
    }
    // `--no-objects` trains the capture as nobody labelled it: the background alone
    // (masks and boxes ignored); with `--boxes` it is a contradiction, refused.
    let unlabelled = tmp.join("unlabelled.assist");
    ok(&assist(&[
        "train",
        s(&data),
        "--out",
        s(&unlabelled),
        "--iters",
        "2",
        "--no-objects",
    ]));
    let (one, _) = assist_scene::scene_file::load(&unlabelled).unwrap();
    assert_eq!(one.scene.nodes.len(), 1);
    assert!(one.scene.nodes[0].is_background());
    fails_with(
        &assist(&[
            "train",
            s(&data),
            "--out",
            s(&out2),
            "--no-objects",
            "--boxes",
            s(&boxes_path),
        ]),
        &["--no-objects", "--boxes"],
    );
    // Loss weights are refused when negative or not a number, naming the flag.
    for flag in ["--lambda-empty", "--lambda-distortion"] {
        for bad in ["-1", "NaN", "inf"] {
            let arg = format!("{flag}={bad}");
            fails_with(
                &assist(&["train", s(&data), "--out", s(&out2), "--iters", "1", &arg]),
                &[flag, "finite weight of 0 or more"],
            );
            assert!(!out2.exists());
        }
    }
}

/// A built-in capture small enough to train in a blink (8 views of 40×30, 3 objects), in
/// `tmp/synth`.
fn tiny_synth(tmp: &TempDir) -> std::path::PathBuf {
    let data = tmp.join("synth");
    ok(&assist(&[
        "synth",
        "--out",
        s(&data),
        "--views",
        "8",
        "--size",
        "40x30",
        "--objects",
        "3",
    ]));
    data
}

/// `train DATA --out OUT --iters 25 --seed 3` with `extra` flags, which must succeed.
fn train_tiny(data: &std::path::Path, out: &std::path::Path, extra: &[&str]) {
    let mut args = vec![
        "train",
        s(data),
        "--out",
        s(out),
        "--iters",
        "25",
        "--seed",
        "3",
    ];
    args.extend_from_slice(extra);
    ok(&assist(&args));
}

#[test]
fn the_same_seed_trains_the_same_bits() {
    // Two runs of the same command write the same weights: the MLP gradient is summed in
    // a fixed order whatever thread took which chunk (it was not, and CI compared a
    // generator's images with a scene trained in another process).
    let tmp = TempDir::new("cli-train-bits");
    let data = tiny_synth(&tmp);
    let mut weights = Vec::new();
    for name in ["a.assist", "b.assist"] {
        let out = tmp.join(name);
        train_tiny(&data, &out, &[]);
        let mut files: Vec<_> = std::fs::read_dir(out.join("fields"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert!(files.len() >= 4, "background and three objects: {files:?}");
        weights.push(
            files
                .iter()
                .map(|f| std::fs::read(f).unwrap())
                .collect::<Vec<_>>(),
        );
    }
    assert!(weights[0] == weights[1], "the two runs' weights differ");
}

#[test]
fn bench_train_reports_each_seed_and_their_spread() {
    // `bench train --seeds N` trains once per seed from --seed on and reports what the
    // seed alone moves: each run as one would get it alone (the same seed, the same
    // figure), and the held-out PSNR's mean, lowest and highest over the runs.
    let tmp = TempDir::new("cli-bench-seeds");
    let data = tiny_synth(&tmp);
    let scratch = tmp.join("tmp");
    std::fs::create_dir_all(&scratch).unwrap();
    let bench = |extra: &[&str]| -> Value {
        let mut args = vec![
            "bench",
            "train",
            s(&data),
            "--iters",
            "3",
            "--eval-views",
            "2",
        ];
        args.extend_from_slice(extra);
        args.push("--json");
        let out = crate::common::bin()
            .args(&args)
            .env("TMPDIR", &scratch)
            .output()
            .unwrap();
        serde_json::from_str(&ok(&out)).expect("json")
    };
    let v = bench(&["--seed", "5", "--seeds", "3"]);
    assert_eq!(v["seeds"], json!([5, 6, 7]), "{v}");
    let runs = v["runs"].as_array().expect("runs");
    let psnr: Vec<f64> = runs
        .iter()
        .map(|r| r["held_out"]["psnr"].as_f64().expect("held-out PSNR"))
        .collect();
    assert_eq!(psnr.len(), 3, "{v}");
    let spread = &v["held_out_psnr"];
    let (lo, hi) = (
        psnr.iter().copied().fold(f64::INFINITY, f64::min),
        psnr.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );
    assert!(hi > lo, "three seeds gave the same PSNR: {psnr:?}");
    let mean = psnr.iter().sum::<f64>() / 3.0;
    for (k, want) in [
        ("mean", mean),
        ("min", lo),
        ("max", hi),
        ("spread", hi - lo),
    ] {
        let got = spread[k].as_f64().unwrap();
        assert!((got - want).abs() < 1e-9, "{k}: {got} against {want}");
    }
    // The second run is the one `--seed 6` gives alone.
    let alone = bench(&["--seed", "6"]);
    assert_eq!(alone["seed"], 6, "{alone}");
    assert_eq!(alone["held_out"]["psnr"].as_f64(), Some(psnr[1]), "{alone}");
    let out = assist(&["bench", "train", s(&data), "--iters", "1", "--seeds", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--seeds"), "{err}");
    let left: Vec<_> = std::fs::read_dir(&scratch).unwrap().collect();
    assert!(left.is_empty(), "bench train left {left:?}");
}

/// The `config` a field file records (its safetensors header's metadata).
fn field_config(path: &std::path::Path) -> Value {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    serde_json::from_str(header["__metadata__"]["config"].as_str().unwrap()).unwrap()
}

#[test]
fn reflect_on_gives_the_objects_the_reflected_direction() {
    // `--reflect on`: every object's field predicts a normal and sees the reflected
    // direction, the background's does not; the choice is recorded and the scene renders.
    let tmp = TempDir::new("cli-train-reflect");
    let data = tiny_synth(&tmp);
    let out = tmp.join("r.assist");
    train_tiny(&data, &out, &["--reflect", "on"]);
    let mut objects = 0;
    for e in std::fs::read_dir(out.join("fields")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        let cfg = field_config(&p);
        let object = name.starts_with("object");
        objects += usize::from(object);
        assert_eq!(cfg["reflect"], json!(object), "{name}: {cfg}");
    }
    assert_eq!(objects, 3);
    let scene: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("scene.json")).unwrap()).unwrap();
    assert_eq!(scene["info"]["train_config"]["reflect"], json!("on"));
    let frames = tmp.join("frames");
    ok(&assist(&[
        "render",
        s(&out),
        "--out",
        s(&frames),
        "--cameras",
        "orbit",
        "--frames",
        "2",
        "--size",
        "40x30",
        "--outputs",
        "rgb",
    ]));
    assert!(frames.join("images/orbit_001.png").is_file());
}
