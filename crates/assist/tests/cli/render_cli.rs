//! `assist render` writes a dataset others can read back, with every requested output;
//! `assist demo` runs end to end (briefly trained).

use crate::common;

use crate::common::{assist, s, write_scene};

#[test]
fn render_orbit_writes_every_output_as_a_readable_dataset() {
    let tmp = assist_testkit::TempDir::new("cli-render");
    let scene = tmp.path().join("a.assist");
    write_scene(&scene);
    // Replicate the duck so two nodes share a label (one semantic class, two instances).
    let edited = tmp.path().join("b.assist");
    let (ok, _, err) = assist(&[
        "edit",
        s(&scene),
        "--do",
        "duplicate the duck, then select the mug",
        "--out",
        s(&edited),
    ]);
    assert!(ok, "{err}");
    let out = tmp.path().join("out");
    let (ok, _, err) = assist(&[
        "render",
        s(&edited),
        "--out",
        s(&out),
        "--cameras",
        "orbit",
        "--frames",
        "3",
        "--size",
        "40x30",
        "--outputs",
        "rgb,depth,panoptic,semantic,objects,background",
    ]);
    assert!(ok, "{err}");
    for k in 0..3 {
        let name = format!("orbit_{k:03}");
        for f in [
            format!("images/{name}.png"),
            format!("depth/{name}.png"),
            format!("depth/{name}.npy"),
            format!("panoptic/{name}.png"),
            format!("semantic/{name}.png"),
            format!("background/{name}.png"),
            format!("objects/1/{name}.png"),
            format!("objects/4/{name}.png"),
        ] {
            assert!(out.join(&f).is_file(), "missing {f}");
        }
    }
    // `--quality draft`: the same views with steps twice as long, close to the full ones.
    let draft = tmp.path().join("draft");
    let (ok, _, err) = assist(&[
        "render",
        s(&edited),
        "--out",
        s(&draft),
        "--frames",
        "3",
        "--size",
        "40x30",
        "--outputs",
        "rgb",
        "--quality",
        "draft",
    ]);
    assert!(ok, "{err}");
    let read = |p: &std::path::Path| assist_data::image_io::read_rgb(p, [0.0; 3]).unwrap().0.data;
    let (full, fast) = (
        read(&out.join("images/orbit_001.png")),
        read(&draft.join("images/orbit_001.png")),
    );
    let mean = full
        .iter()
        .zip(&fast)
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>()
        / full.len() as f32;
    assert!(
        full != fast && mean < 0.05,
        "draft differs by {mean} on average"
    );
    let (ok, _, err) = assist(&[
        "render",
        s(&edited),
        "--out",
        s(&draft),
        "--quality",
        "nope",
    ]);
    assert!(!ok && err.contains("draft"), "{err}");
    let legend: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("panoptic_legend.json")).unwrap()).unwrap();
    // The copy is named "yellow rubber duck 2" and is of the duck's class.
    assert_eq!(legend["4"], "yellow rubber duck 2");
    let sem: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("semantic_legend.json")).unwrap()).unwrap();
    assert_eq!(
        sem.as_object().unwrap().len(),
        3,
        "background, duck, mug: {sem}"
    );
    assert_eq!(sem["1"], "yellow rubber duck", "{sem}");
    assert_eq!(sem["2"], "red ceramic mug", "{sem}");
    // Deleting the duck and its copy leaves the mug at class 2 in every later render.
    let gone = tmp.path().join("c.assist");
    let (ok, _, err) = assist(&[
        "edit",
        s(&edited),
        "--do",
        "delete object 1 and object 4",
        "--out",
        s(&gone),
    ]);
    assert!(ok, "{err}");
    let out2 = tmp.path().join("out2");
    let (ok, _, err) = assist(&[
        "render",
        s(&gone),
        "--out",
        s(&out2),
        "--frames",
        "1",
        "--size",
        "40x30",
        "--outputs",
        "rgb,semantic",
    ]);
    assert!(ok, "{err}");
    let sem2: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out2.join("semantic_legend.json")).unwrap()).unwrap();
    assert_eq!(sem2["2"], "red ceramic mug", "{sem2}");
    // The output reads back as a dataset with the rendered cameras.
    let ds = assist_data::load(&out, &assist_data::LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 3);
    assert_eq!(ds.frames[0].camera.width(), 40);
    let report = assist_data::validate::validate(&ds);
    assert!(report.errors.is_empty(), "{:?}", report.errors);
    // Its transforms.json declares no split, so rendering with its cameras takes every
    // frame; --split test takes the hold-out rule's test frames (every 8th: one of three).
    let cameras = out.join("transforms.json");
    for (split, n) in [(None, 3), (Some("test"), 1)] {
        let again = tmp.path().join(format!("again-{n}"));
        let mut args = vec![
            "render",
            s(&edited),
            "--out",
            s(&again),
            "--cameras",
            s(&cameras),
            "--outputs",
            "rgb",
        ];
        args.extend(split.map(|v| ["--split", v]).into_iter().flatten());
        let (ok, _, err) = assist(&args);
        assert!(ok, "{err}");
        let rendered = std::fs::read_dir(again.join("images")).unwrap().count();
        assert_eq!(rendered, n, "--split {split:?}");
    }
    // Bad options are clear errors.
    let (ok, _, err) = assist(&[
        "render",
        s(&edited),
        "--out",
        s(&tmp.path().join("x")),
        "--outputs",
        "rgb,normals",
    ]);
    assert!(!ok && err.contains("unknown output \"normals\""), "{err}");
    let (ok, _, err) = assist(&["render", s(&edited), "--out", s(&out), "--frames", "1"]);
    assert!(!ok && err.contains("--force"), "{err}");
}

#[test]
fn demo_runs_end_to_end() {
    let tmp = assist_testkit::TempDir::new("cli-demo");
    let out = tmp.path().join("demo");
    let (ok, stdout, err) = assist(&[
        "demo",
        "--out",
        s(&out),
        "--train-seconds",
        "6",
        "--other-seconds",
        "3",
        // In iterations, not seconds: the same plain scene however busy the machine is.
        "--plain-iters",
        "400",
    ]);
    assert!(ok, "{err}");
    // The object made from one click on the scene trained without masks.
    let iou: f64 = err
        .split("test views: IoU ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no click step in {err}"));
    assert!(iou >= 0.7, "the clicked object's mask IoU {iou}");
    assert!(stdout.contains("contact_sheet.png"), "{stdout}");
    assert!(out.join("contact_sheet.png").is_file());
    let log = std::fs::read_to_string(out.join("edits.jsonl")).unwrap();
    let ops: Vec<String> = log
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["operation"]
                .as_str()
                .unwrap()
                .to_string()
        })
        .collect();
    assert_eq!(
        ops,
        [
            "translate",
            "rotate",
            "replicate",
            "translate",
            "delete",
            "add"
        ]
    );
    let (edited, _) = assist_scene::scene_file::load(&out.join("edited.assist")).unwrap();
    // 5 objects + background, one deleted, one copy, one inserted.
    assert_eq!(edited.scene.nodes.len(), 7);
}

#[test]
fn select_takes_a_name_as_edit_does() {
    let tmp = assist_testkit::TempDir::new("render-select-name");
    let (_, sc) = common::tiny_scene(tmp.path());
    let render = |sel: &str, out: &str| {
        common::run(&[
            "render",
            common::s(&sc),
            "--out",
            common::s(&tmp.join(out)),
            "--frames",
            "1",
            "--size",
            "16x12",
            "--select",
            sel,
        ])
    };
    common::ok(&render("ball", "by-name"));
    common::ok(&render("2", "by-id"));
    common::refused(&render("duck", "nothing"), &["--select", "duck", "ball"]);
    common::refused(&render("99", "no-id"), &["--select", "99"]);
}

/// `assist eval --sheet`: a row per measured view (photograph, render, depth), the
/// masks' split of the error and the colour-corrected PSNR in the report, and an existing
/// sheet kept without `--force`.
#[test]
fn eval_writes_a_contact_sheet_and_the_masks_split() {
    let tmp = assist_testkit::TempDir::new("eval-sheet");
    let (data, sc) = common::tiny_scene(tmp.path());
    let sheet = tmp.join("sheet.png");
    let eval = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            s(&sc),
            "--data",
            s(&data),
            "--split",
            "all",
            "--json",
            "--sheet",
            s(&sheet),
        ];
        args.extend_from_slice(extra);
        common::run(&args)
    };
    let r: serde_json::Value = serde_json::from_str(&common::ok_stdout(&eval(&[]))).unwrap();
    let views = r["per_image"].as_array().unwrap().len();
    assert_eq!(views, 8);
    for k in ["object_pixels_psnr", "other_pixels_psnr"] {
        assert!(r[k].as_f64().is_some_and(f64::is_finite), "{k}: {r}");
    }
    // The share of the photographs' fine detail the renders keep: the objects' edges and
    // the floor's texture are learnt in place, so some and at most about all of it.
    for k in ["detail", "object_pixels_detail", "other_pixels_detail"] {
        assert!(
            r[k].as_f64().is_some_and(|d| d > 0.0 && d < 1.5),
            "{k}: {r}"
        );
    }
    // A view's best gain and offset can only bring its render nearer the photograph.
    let (p, c) = (
        r["psnr"].as_f64().unwrap(),
        r["color_corrected_psnr"].as_f64(),
    );
    assert!(c.is_some_and(|c| c.is_finite() && c >= p - 1e-9), "{r}");
    let img = image::open(&sheet).unwrap();
    // Three tiles of 32 pixels and their 2-pixel gaps a row; a row per view.
    assert_eq!(img.width(), 3 * (32 + 2));
    assert_eq!(img.height() % 8, 0);
    assert!(img.height() / 8 > 24);
    let before = std::fs::read(&sheet).unwrap();
    common::refused(&eval(&[]), &["--sheet", "sheet.png", "--force"]);
    assert_eq!(std::fs::read(&sheet).unwrap(), before);
    common::ok_stdout(&eval(&["--force"]));
}
