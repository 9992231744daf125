//! `assist dataset info` end to end: correct reports on every shared dataset, and clear
//! errors (file + field, non-zero exit, no panic) on bad input.

use std::path::Path;
use std::process::Output;

use assist_testkit::{TempDir, shared_data};
use serde_json::Value;

fn assist(args: &[&str]) -> Output {
    crate::common::bin()
        .args(args)
        .output()
        .expect("run assist")
}

fn info_json(path: &Path) -> Value {
    let out = assist(&["dataset", "info", "--json", path.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

/// Runs `dataset info` on bad input: must fail cleanly, naming every `needles` item.
fn expect_error(path: &Path, needles: &[&str]) -> String {
    let out = assist(&["dataset", "info", path.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        !out.status.success(),
        "expected failure for {}",
        path.display()
    );
    assert_eq!(
        out.status.code(),
        Some(1),
        "exit code for {}: {err}",
        path.display()
    );
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "error should mention {n:?}: {err}");
    }
    err
}

#[test]
fn reports_every_shared_dataset() {
    let Some(data) = shared_data("reports_every_shared_dataset") else {
        return;
    };
    let lego = info_json(&data.join("lego_400"));
    assert_eq!(lego["format"], "blender");
    assert_eq!(lego["splits"]["train"], 100);
    assert_eq!(lego["splits"]["test"], 200);
    assert_eq!(
        (lego["width"].as_u64(), lego["height"].as_u64()),
        (Some(400), Some(400))
    );
    assert_eq!(lego["has_masks"], true);
    assert_eq!(lego["validation"]["errors"].as_array().unwrap().len(), 0);
    let mic = info_json(&data.join("mic_400"));
    assert_eq!(
        (mic["frames"].as_u64(), mic["splits"]["train"].as_u64()),
        (Some(300), Some(100))
    );

    let beer = info_json(&data.join("beer"));
    assert_eq!(beer["format"], "colmap-binary");
    assert_eq!(beer["frames"], 71);
    assert_eq!(beer["camera_model"], "SIMPLE_RADIAL");
    assert_eq!(
        (beer["width"].as_u64(), beer["height"].as_u64()),
        (Some(720), Some(1280))
    );
    assert!(beer["sparse_points"].as_u64().unwrap() > 1000);

    let fern = info_json(&data.join("fern"));
    assert_eq!(fern["format"], "llff");
    assert_eq!(fern["frames"], 20);
    assert_eq!(
        (fern["width"].as_u64(), fern["height"].as_u64()),
        (Some(504), Some(378))
    );

    let desk = info_json(&data.join("desk"));
    assert_eq!(desk["format"], "nerfstudio");
    assert_eq!(desk["frames"], 120);
    assert_eq!(desk["splits"]["train"], 100);
    assert_eq!(desk["splits"]["test"], 20);
    assert_eq!(desk["camera_model"], "OPENCV");
    assert_eq!(desk["has_instance_masks"], true);
    assert_eq!(desk["has_depth"], true);
    let labels: Vec<&str> = desk["instances"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| i["label"].as_str().unwrap())
        .collect();
    assert_eq!(labels.len(), 5);
    assert_eq!(labels[0], "yellow rubber duck");
    assert_eq!(labels[2], "red ceramic mug");
    assert_eq!(desk["instances"][2]["id"], 3);
    assert_eq!(desk["meters_per_unit"], 1.0);
    assert_eq!(desk["validation"]["files_checked"], 360);

    // The same datasets addressed by file, and COLMAP forced on beer's LLFF twin.
    let by_file = info_json(&data.join("lego_400/transforms_train.json"));
    assert_eq!(by_file["format"], "blender");
    let out = assist(&[
        "dataset",
        "info",
        "--json",
        "--format",
        "llff",
        data.join("beer").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn synth_then_info() {
    let tmp = TempDir::new("cli-synth");
    let out = tmp.join("scene");
    let r = assist(&[
        "synth",
        "--out",
        out.to_str().unwrap(),
        "--views",
        "12",
        "--width",
        "64",
        "--height",
        "48",
        "--objects",
        "3",
        "--json",
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let summary: Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(summary["views"], 12);
    let info = info_json(&out);
    assert_eq!(info["instances"].as_array().unwrap().len(), 3);
    assert_eq!(info["splits"]["test"], 2);
    // A second run without --force refuses and leaves the scene alone.
    let before = std::fs::read(out.join("transforms.json")).unwrap();
    let r = assist(&[
        "synth",
        "--out",
        out.to_str().unwrap(),
        "--seed",
        "9",
        "--views",
        "12",
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("--force"));
    assert_eq!(before, std::fs::read(out.join("transforms.json")).unwrap());
    // Bad arguments are errors, not panics.
    let r = assist(&[
        "synth",
        "--out",
        tmp.join("x").to_str().unwrap(),
        "--objects",
        "9",
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("--objects"));
}

/// A tiny valid nerfstudio dataset (2 frames, 8×6 PNGs) to break in different ways.
fn tiny_nerfstudio(dir: &Path) -> Value {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for k in 0..2 {
        let img = assist_data::ImageF32 {
            width: 8,
            height: 6,
            channels: 3,
            data: vec![0.5; 8 * 6 * 3],
        };
        assist_data::image_io::write_rgb_png(&dir.join(format!("images/{k}.png")), &img).unwrap();
    }
    let frame = |k: usize| serde_json::json!({"file_path": format!("images/{k}.png"), "transform_matrix": [[1,0,0,k],[0,1,0,0],[0,0,1,2],[0,0,0,1]]});
    let v = serde_json::json!({"camera_model": "OPENCV", "fl_x": 10.0, "fl_y": 10.0, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6, "frames": [frame(0), frame(1)]});
    std::fs::write(
        dir.join("transforms.json"),
        serde_json::to_string_pretty(&v).unwrap(),
    )
    .unwrap();
    v
}

#[test]
fn bad_input_gives_clear_errors() {
    let tmp = TempDir::new("cli-bad");
    // The untouched tiny dataset is valid (so each failure below is caused by its one change).
    let ok = tmp.join("ok");
    tiny_nerfstudio(&ok);
    assert_eq!(info_json(&ok)["frames"], 2);

    // Malformed JSON.
    let d = tmp.join("malformed");
    tiny_nerfstudio(&d);
    let text = std::fs::read_to_string(d.join("transforms.json")).unwrap();
    std::fs::write(d.join("transforms.json"), &text[..text.len() / 2]).unwrap();
    expect_error(&d, &["transforms.json", "not valid JSON", "line"]);

    // Missing image.
    let d = tmp.join("missing");
    tiny_nerfstudio(&d);
    std::fs::remove_file(d.join("images/1.png")).unwrap();
    expect_error(&d, &["images/1.png", "frames[1].file_path", "not found"]);

    // Image of the wrong size.
    let d = tmp.join("wrongsize");
    tiny_nerfstudio(&d);
    let img = assist_data::ImageF32 {
        width: 9,
        height: 6,
        channels: 3,
        data: vec![0.5; 9 * 6 * 3],
    };
    assist_data::image_io::write_rgb_png(&d.join("images/0.png"), &img).unwrap();
    expect_error(
        &d,
        &["images/0.png", "9x6", "expected 8x6", "frames[0].file_path"],
    );

    // Unknown camera model.
    let d = tmp.join("model");
    let mut v = tiny_nerfstudio(&d);
    v["camera_model"] = "EQUIRECTANGULAR".into();
    std::fs::write(d.join("transforms.json"), v.to_string()).unwrap();
    expect_error(
        &d,
        &[
            "transforms.json",
            "camera_model",
            "EQUIRECTANGULAR",
            "PINHOLE",
        ],
    );

    // NaN in a pose (as Python's json module writes it).
    let d = tmp.join("nan");
    let v = tiny_nerfstudio(&d);
    let text = serde_json::to_string_pretty(&v).unwrap();
    let text = text.replacen(
        "\"transform_matrix\": [\n        [\n          1,",
        "\"transform_matrix\": [\n        [\n          NaN,",
        1,
    );
    assert!(text.contains("NaN"));
    std::fs::write(d.join("transforms.json"), text).unwrap();
    expect_error(
        &d,
        &[
            "transforms.json",
            "frames[0].transform_matrix[0][0]",
            "finite",
            "NaN",
        ],
    );

    // Missing required field.
    let d = tmp.join("nofocal");
    let mut v = tiny_nerfstudio(&d);
    v.as_object_mut().unwrap().remove("fl_x");
    v.as_object_mut().unwrap().remove("fl_y");
    std::fs::write(d.join("transforms.json"), v.to_string()).unwrap();
    expect_error(&d, &["transforms.json", "fl_x", "missing"]);

    // Nothing there.
    expect_error(&tmp.join("nope"), &["nope", "no such file"]);
    let empty = tmp.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    expect_error(&empty, &["empty", "no dataset found"]);
}

#[test]
fn truncated_colmap_and_npy_are_clear_errors() {
    let Some(data) = shared_data("truncated_colmap_and_npy_are_clear_errors") else {
        return;
    };
    let tmp = TempDir::new("cli-trunc");
    // A copy of beer's model with images.bin cut in the middle of a record.
    let d = tmp.join("beer");
    std::fs::create_dir_all(d.join("sparse/0")).unwrap();
    std::os::unix::fs::symlink(data.join("beer/images"), d.join("images")).unwrap();
    for f in ["cameras.bin", "points3D.bin"] {
        std::fs::copy(
            data.join("beer/sparse/0").join(f),
            d.join("sparse/0").join(f),
        )
        .unwrap();
    }
    let bytes = std::fs::read(data.join("beer/sparse/0/images.bin")).unwrap();
    std::fs::write(d.join("sparse/0/images.bin"), &bytes[..bytes.len() / 3]).unwrap();
    expect_error(&d, &["images.bin", "truncated", "image"]);
    // cameras.bin cut inside the parameters.
    let cams = std::fs::read(data.join("beer/sparse/0/cameras.bin")).unwrap();
    std::fs::copy(
        data.join("beer/sparse/0/images.bin"),
        d.join("sparse/0/images.bin"),
    )
    .unwrap();
    std::fs::write(d.join("sparse/0/cameras.bin"), &cams[..8 + 24 + 12]).unwrap();
    expect_error(&d, &["cameras.bin", "truncated"]);
    // LLFF poses_bounds.npy cut short.
    let f = tmp.join("fern");
    std::fs::create_dir_all(&f).unwrap();
    std::os::unix::fs::symlink(data.join("fern/images_8"), f.join("images_8")).unwrap();
    let npy = std::fs::read(data.join("fern/poses_bounds.npy")).unwrap();
    std::fs::write(f.join("poses_bounds.npy"), &npy[..npy.len() - 100]).unwrap();
    expect_error(&f, &["poses_bounds.npy", "truncated"]);
    // NaN in an LLFF pose.
    let mut npy2 = npy.clone();
    let hdr = npy.len() - 20 * 17 * 8;
    npy2[hdr..hdr + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    std::fs::write(f.join("poses_bounds.npy"), &npy2).unwrap();
    expect_error(&f, &["poses_bounds.npy", "row 0", "finite"]);
}

#[test]
fn bench_rejects_empty_batches_cleanly() {
    for args in [
        ["--steps", "0"],
        ["--rays", "0"],
        ["--samples-per-ray", "0"],
    ] {
        let out = assist(&["bench", "field", "--nerfacto-only", args[0], args[1]]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(args[0]) && !err.contains("panicked"), "{err}");
    }
}

/// `assist bench field` at a small size on the CPU: each field's throughput and phases,
/// and how far the nets and Adam stand from the machine's measured limits (issue 44's
/// "what bounds it"), as positive figures that are fractions of those limits.
#[test]
fn bench_field_reports_each_phase_against_the_machines_limits() {
    let out = assist(&[
        "bench",
        "field",
        "--rays",
        "64",
        "--samples-per-ray",
        "32",
        "--steps",
        "1",
        "--json",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    for k in [
        "peak_gflops_total",
        "memory_gbytes_per_sec",
        "train_samples_per_sec",
    ] {
        assert!(v[k].as_f64().is_some_and(|x| x > 0.0), "{k}: {v}");
    }
    let fields = v["fields"].as_array().expect("fields");
    assert_eq!(fields.len(), 2, "{v}");
    for f in fields {
        for k in [
            "encode_forward",
            "mlp_forward",
            "mlp_backward",
            "encode_backward",
            "adam",
        ] {
            let t = f["breakdown_seconds"][k].as_f64();
            assert!(t.is_some_and(|x| x > 0.0), "{k}: {f}");
        }
        // Shares of a limit: above zero, and not far beyond the limit (the limits are
        // measured, so a share may exceed 1 a little on a noisy host, never by 3×).
        for k in ["mlp_share_of_peak", "adam_share_of_bandwidth"] {
            let r = f[k].as_f64();
            assert!(r.is_some_and(|x| x > 0.0 && x < 3.0), "{k}: {f}");
        }
    }
}

/// `assist bench sam` on a small random checkpoint: every stage timed, its sizes read
/// from the file; a bad size or checkpoint is refused by name.
#[test]
fn bench_sam_times_a_checkpoint() {
    let tmp = TempDir::new("bench-sam");
    let ckpt = tmp.path().join("small.safetensors");
    assist_sam::random::write_random(&ckpt, &assist_sam::random::RandomSpec::tiny(), 3).unwrap();
    let c = ckpt.to_str().unwrap();
    let out = assist(&[
        "bench",
        "sam",
        "--checkpoint",
        c,
        "--runs",
        "1",
        "--size",
        "80x60",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["encoder"]["img_size"], 64, "{v}");
    assert!(v["embed_seconds"].as_f64().unwrap() > 0.0, "{v}");
    for (args, needle) in [
        (vec!["--checkpoint", c, "--size", "80by60"], "--size"),
        (vec!["--checkpoint", "/nonexistent/sam.pth"], "sam.pth"),
    ] {
        let mut all = vec!["bench", "sam"];
        all.extend(args);
        let out = assist(&all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(needle) && !err.contains("panicked"), "{err}");
    }
}
