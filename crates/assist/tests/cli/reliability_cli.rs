//! Regression tests for the hostile inputs of the reliability issue: each case used to
//! panic or abort; each must now be a clear error (file and field named, exit 1, no
//! panic, nothing allocated from a header before it is checked).

use std::process::Output;

use assist_testkit::TempDir;

use crate::common;

use crate::common::{refused, s};

fn assist(args: &[&str]) -> Output {
    common::run(args)
}

/// A one-frame nerfstudio capture declaring a `w`×`h` image (the image itself is tiny).
fn capture(tmp: &TempDir, name: &str, w: u64, h: u64) -> std::path::PathBuf {
    let dir = tmp.join(name);
    std::fs::create_dir_all(dir.join("images")).unwrap();
    image::RgbImage::new(4, 4)
        .save(dir.join("images/a.png"))
        .unwrap();
    let tf = serde_json::json!({
        "camera_model": "OPENCV",
        "fl_x": 100.0, "fl_y": 100.0, "cx": 2.0, "cy": 2.0, "w": w, "h": h,
        "frames": [{"file_path": "images/a.png", "transform_matrix":
            [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]}]
    });
    std::fs::write(dir.join("transforms.json"), tf.to_string()).unwrap();
    dir
}

#[test]
fn huge_declared_images_are_refused_before_anything_is_allocated() {
    let tmp = TempDir::new("huge-images");
    for (w, h) in [
        (65_536, 65_536),
        (100_000, 100_000),
        (1 << 31, 4),
        (20_000, 20_000),
    ] {
        let data = capture(&tmp, &format!("c{w}x{h}"), w, h);
        for args in [
            vec!["dataset", "info", s(&data)],
            vec![
                "train",
                s(&data),
                "--out",
                &format!("{}.assist", data.display()),
                "--iters",
                "1",
            ],
        ] {
            let out = assist(&args);
            // (2^31 does not fit the field's type: the reader's own error.)
            let needles: &[&str] = if w == 1 << 31 {
                &["transforms.json", "w"]
            } else {
                &["larger than supported", "w/h"]
            };
            refused(&out, needles);
        }
    }
}

#[test]
fn a_blender_field_of_view_of_half_a_turn_or_more_is_refused() {
    let tmp = TempDir::new("blender-fov");
    for fov in [std::f64::consts::PI, 4.0, 7.0] {
        let dir = tmp.join(format!("fov{fov}"));
        std::fs::create_dir_all(dir.join("train")).unwrap();
        image::RgbaImage::new(4, 4)
            .save(dir.join("train/r_0.png"))
            .unwrap();
        let tf = serde_json::json!({
            "camera_angle_x": fov,
            "frames": [{"file_path": "./train/r_0", "transform_matrix":
                [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]}]
        });
        std::fs::write(dir.join("transforms_train.json"), tf.to_string()).unwrap();
        let out = assist(&["dataset", "info", s(&dir)]);
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!out.status.success(), "fov {fov} accepted");
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            err.contains("camera_angle_x") || err.contains("fx/fy") || err.contains("fx"),
            "fov {fov}: {err}"
        );
    }
}

#[test]
fn an_absurd_batch_size_or_time_budget_is_refused() {
    let tmp = TempDir::new("absurd-batch");
    let data = capture(&tmp, "small", 4, 4);
    let out_scene = tmp.join("x.assist");
    for (flag, value, needle) in [
        ("--batch-samples", "18446744073709551615", "batch-samples"),
        ("--batch-samples", "3", "batch-samples"),
        ("--max-time", "-5", "max-time"),
        ("--max-time", "NaN", "max-time"),
    ] {
        let arg = format!("{flag}={value}");
        let out = assist(&[
            "train",
            s(&data),
            "--out",
            s(&out_scene),
            &arg,
            "--iters",
            "1",
        ]);
        refused(&out, &[needle]);
        assert!(!out_scene.exists(), "{flag} {value}: a scene was written");
    }
}

#[test]
fn bad_scene_values_are_blamed_on_the_scene_not_on_flags_never_passed() {
    let tmp = TempDir::new("scene-values");
    let (_, sc) = common::tiny_scene(tmp.path());
    let edit_json = |name: &str, f: &dyn Fn(&mut serde_json::Value)| {
        let dir = tmp.join(name);
        std::fs::create_dir_all(dir.join("fields")).unwrap();
        for e in std::fs::read_dir(sc.join("fields")).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.join("fields").join(e.file_name())).unwrap();
        }
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(sc.join("scene.json")).unwrap()).unwrap();
        f(&mut v);
        std::fs::write(dir.join("scene.json"), v.to_string()).unwrap();
        dir
    };
    // A selection naming no node: the scene file's field, not `--select`.
    let sel = edit_json("sel.assist", &|v| v["selected"] = 99.into());
    let out = assist(&[
        "render",
        s(&sel),
        "--out",
        s(&tmp.join("r1")),
        "--frames",
        "1",
    ]);
    let err = refused(&out, &["scene.json", "selected", "99"]);
    assert!(!err.contains("--select"), "{err}");
    // Boxes too large to orbit: the scene's boxes, not `--radius`.
    let big = edit_json("big.assist", &|v| {
        v["nodes"][1]["half_size"] = serde_json::json!([1e6, 1e6, 1e6]);
        v["nodes"][1]["world_from_local"]["scale"] = serde_json::json!([1e6, 1e6, 1e6]);
    });
    let out = assist(&[
        "render",
        s(&big),
        "--out",
        s(&tmp.join("r2")),
        "--frames",
        "1",
    ]);
    let err = refused(&out, &["boxes"]);
    assert!(
        !err.contains("--radius") && !err.contains("got inf"),
        "{err}"
    );
}

#[test]
fn reader_errors_name_the_file_the_frame_and_the_byte() {
    let tmp = TempDir::new("reader-errors");
    let bl = tmp.join("bl");
    std::fs::create_dir_all(bl.join("train")).unwrap();
    std::fs::write(bl.join("train/r_0.png"), "not a png").unwrap();
    std::fs::write(
        bl.join("transforms_train.json"),
        r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    refused(
        &assist(&["dataset", "info", s(&bl)]),
        &["transforms_train.json", "frames[0].file_path", "r_0.png"],
    );
    std::fs::write(
        bl.join("transforms_train.json"),
        b"{\"camera_angle_x\": 0.7,\n \"frames\": [\xff]}",
    )
    .unwrap();
    refused(
        &assist(&["dataset", "info", s(&bl)]),
        &["transforms_train.json", "line 2, byte 36", "not UTF-8"],
    );
}

/// Issue 47, item 14: `render --frames 1000000000` grew to 2.5 GB before anything was
/// said. An orbit holds at most `MAX_ORBIT_FRAMES` cameras; more is refused at once,
/// naming the count, and nothing is written.
#[test]
fn an_absurd_number_of_frames_is_refused_before_any_work() {
    let tmp = TempDir::new("rel-frames");
    let scene = tmp.join("s.assist");
    common::write_scene(&scene);
    let out = tmp.join("r");
    let t0 = std::time::Instant::now();
    let o = assist(&[
        "render",
        s(&scene),
        "--out",
        s(&out),
        "--frames",
        "1000000000",
        "--size",
        "8x8",
    ]);
    refused(&o, &["1000000000 frames", "100000"]);
    assert!(t0.elapsed().as_secs() < 20, "took {:?}", t0.elapsed());
    assert!(!out.exists());
}

/// Issue 47, item 10: an error chain printed the same cause twice ("… No such file or
/// directory (os error 2)" then "No such file or directory (os error 2)").
#[test]
fn an_error_chain_says_each_cause_once() {
    let tmp = TempDir::new("rel-chain");
    let o = assist(&[
        "eval",
        s(&tmp.join("nowhere.assist")),
        "--data",
        s(&tmp.join("nodata")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
}
