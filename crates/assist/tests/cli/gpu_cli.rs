//! `--device` as a user meets it: `assist bench field --device gpu` on whatever adapter
//! is present (lavapipe in CI, where `ASSIST_REQUIRE_GPU=1`); `train` with the fields'
//! backward passes and Adam there, and `render` and `eval` with the fields queried there,
//! against the CPU's output (`generate`'s is in
//! `generate_cli.rs`, on its trained scene); and the clear
//! refusal or CPU fallback when no Vulkan driver is found.

use crate::common;

use std::path::Path;

use serde_json::Value;

fn assist(args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let mut c = common::bin();
    c.args(args).env("XDG_RUNTIME_DIR", std::env::temp_dir());
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("run assist")
}

const SMALL: [&str; 9] = [
    "bench",
    "field",
    "--nerfacto-only",
    "--rays",
    "32",
    "--samples-per-ray",
    "32",
    "--steps",
    "1",
];

/// Whether `out` failed for want of an adapter where that is allowed (a loud skip).
fn no_adapter(out: &std::process::Output) -> bool {
    common::no_gpu_adapter(out, "this --device gpu test")
}

#[test]
fn bench_field_on_the_gpu_reports_training_and_inference() {
    let mut args = SMALL.to_vec();
    args.extend(["--device", "gpu", "--json"]);
    let out = assist(&args, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    if no_adapter(&out) {
        return;
    }
    assert!(out.status.success(), "{err}");
    let v: Value = serde_json::from_slice(&out.stdout).expect("json");
    assert!(v["device"].as_str().is_some_and(|d| !d.is_empty()), "{v}");
    let g = &v["fields"][0]["gpu"];
    for k in [
        "train_samples_per_sec",
        "infer_samples_per_sec",
        "density_samples_per_sec",
    ] {
        assert!(g[k].as_f64().is_some_and(|x| x > 0.0), "{k}: {g}");
    }
    for stage in [
        "encode",
        "forward_nets",
        "backward_nets",
        "weight_grads",
        "grid_grads",
        "adam",
    ] {
        assert!(
            g["train_stage_seconds"][stage]
                .as_f64()
                .is_some_and(|x| x > 0.0),
            "{stage}: {g}"
        );
    }
    let d = &g["max_relative_difference"];
    assert!(
        d["sigma"].as_f64().unwrap() < 1e-4 && d["rgb"].as_f64().unwrap() < 1e-4,
        "{d}"
    );
    // The kernels' settings forced for benchmarks; a value that is not one is refused by
    // the variable's name.
    let forced = [("ASSIST_GPU_TILE", "16"), ("ASSIST_GPU_DW_GROUPS", "3")];
    let out = assist(&args, &forced);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (k, v, expected) in [
        ("ASSIST_GPU_TILE", "48", "expected 16, 32 or 64"),
        ("ASSIST_GPU_DW_GROUPS", "0", "expected a positive number"),
    ] {
        let out = assist(&args, &[(k, v)]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{k}={v}: {err}");
        assert!(
            err.contains(k) && err.contains(expected) && !err.contains("panicked"),
            "{k}={v}: {err}"
        );
    }
}

#[test]
fn without_a_vulkan_driver_gpu_is_refused_and_auto_runs_on_the_cpu() {
    // The Vulkan loader finds no driver at all.
    let none = [
        ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
        ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
    ];
    let mut args = SMALL.to_vec();
    args.extend(["--device", "gpu"]);
    let out = assist(&args, &none);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no GPU adapter") && err.contains("--device cpu") && !err.contains("panicked"),
        "{err}"
    );
    let mut args = SMALL.to_vec();
    args.extend(["--device", "auto", "--json"]);
    let out = assist(&args, &none);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let v: Value = serde_json::from_slice(&out.stdout).expect("json");
    assert!(
        v["device"].is_null() && v["fields"][0]["gpu"].is_null(),
        "{v}"
    );
    assert!(v["train_samples_per_sec"].as_f64().unwrap() > 0.0);
    // A choice that is not one is refused by name.
    let mut args = SMALL.to_vec();
    args.extend(["--device", "cuda"]);
    let out = assist(&args, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("cuda") && err.contains("auto, cpu or gpu"),
        "{err}"
    );
}

/// Every PNG under `dir` (sorted), relative to it.
fn pngs(dir: &Path) -> Vec<std::path::PathBuf> {
    common::run_tree(dir)
        .into_keys()
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect()
}

#[test]
fn render_and_eval_on_the_gpu_match_the_cpu() {
    let dir = assist_testkit::TempDir::new("gpu-cli-render");
    let tmp = dir.path();
    let (data, scene) = common::tiny_scene(tmp);
    let (data, scene) = (common::s(&data), common::s(&scene));
    // render: the same views on each device, image for image.
    let render = |dev: &str| {
        let out = tmp.join(format!("r_{dev}"));
        let o = assist(
            &[
                "render",
                scene,
                "--cameras",
                data,
                "--out",
                common::s(&out),
                "--device",
                dev,
                "--json",
            ],
            &[],
        );
        (o, out)
    };
    let (o, on_gpu) = render("gpu");
    if no_adapter(&o) {
        return;
    }
    let v: Value = serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).unwrap();
    assert!(v["device"].as_str().is_some_and(|d| d != "cpu"), "{v}");
    let (o, on_cpu) = render("cpu");
    let v: Value = serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).unwrap();
    assert_eq!(v["device"], "cpu", "{v}");
    let images = pngs(&on_cpu.join("images"));
    assert!(!images.is_empty() && images == pngs(&on_gpu.join("images")));
    for p in &images {
        let q = common::png_psnr(
            &on_cpu.join("images").join(p),
            &on_gpu.join("images").join(p),
        );
        assert!(q > 40.0, "{}: {q:.1} dB between the devices", p.display());
    }
    // eval: the same PSNR within 0.1 dB.
    let eval = |dev: &str| {
        let o = assist(
            &["eval", scene, "--data", data, "--device", dev, "--json"],
            &[],
        );
        let v: Value = serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).unwrap();
        v["psnr"].as_f64().expect("psnr")
    };
    let (g, c) = (eval("gpu"), eval("cpu"));
    assert!(
        (g - c).abs() <= 0.1,
        "eval PSNR {g:.3} on the GPU, {c:.3} on the CPU"
    );
}

#[test]
fn training_on_the_gpu_matches_the_cpu() {
    let dir = assist_testkit::TempDir::new("gpu-cli-train");
    let data = dir.path().join("cap");
    common::synth_small(&data, 24);
    let data = common::s(&data);
    // The held-out PSNR of a scene trained `iters` steps on `dev` (same seed), by `eval`
    // and by `train`'s own measure at the end.
    let trained = |dev: &str, iters: &str| -> Option<(f64, f64)> {
        let out = dir.path().join(format!("{dev}_{iters}.assist"));
        let o = assist(
            &[
                "train",
                data,
                "--out",
                common::s(&out),
                "--iters",
                iters,
                "--seed",
                "1",
                "--device",
                dev,
                "--json",
            ],
            &[],
        );
        if no_adapter(&o) {
            return None;
        }
        let t: Value = serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).unwrap();
        let o = assist(&["eval", common::s(&out), "--data", data, "--json"], &[]);
        let v: Value = serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).unwrap();
        Some((v["psnr"].as_f64()?, t["held_out"]["psnr"].as_f64()?))
    };
    let Some((gpu, gpu_train)) = trained("gpu", "12") else {
        return;
    };
    let (cpu, _) = trained("cpu", "12").unwrap();
    let (start, start_train) = trained("cpu", "1").unwrap();
    assert!(
        cpu > start + 1.0,
        "12 steps train the scene: {start:.2} → {cpu:.2} dB"
    );
    assert!(
        (gpu - cpu).abs() <= 0.05,
        "after 12 steps: {gpu:.3} dB on the GPU, {cpu:.3} dB on the CPU"
    );
    // `bench train` runs the same training on each device (the CPU's 1 step: enough to
    // compare), names it, keeps no scene, and reaches what `train` measured.
    let scratch = dir.path().join("tmp");
    std::fs::create_dir_all(&scratch).unwrap();
    let benched = |dev: &str, iters: usize| -> Value {
        let iters = iters.to_string();
        let o = assist(
            &[
                "bench", "train", data, "--iters", &iters, "--seed", "1", "--device", dev, "--json",
            ],
            &[("TMPDIR", common::s(&scratch))],
        );
        serde_json::from_slice(&common::ok_stdout(&o).into_bytes()).expect("json")
    };
    for (dev, iters, psnr) in [("cpu", 1, start_train), ("gpu", 12, gpu_train)] {
        let v = benched(dev, iters);
        assert_eq!(v["steps"], iters, "{v}");
        assert_eq!(v["device"] == "cpu", dev == "cpu", "{v}");
        for k in ["steps_per_sec", "samples_per_sec", "rays_per_sec"] {
            assert!(v[k].as_f64().is_some_and(|x| x > 0.0), "{k}: {v}");
        }
        assert!(v["ms_per_step"]["forward"].as_f64().is_some(), "{v}");
        let held = v["held_out"]["psnr"].as_f64().expect("held-out PSNR");
        assert!(
            (held - psnr).abs() <= 0.05,
            "{dev}: bench train {held:.3} dB, train {psnr:.3} dB"
        );
    }
    let left: Vec<_> = std::fs::read_dir(&scratch).unwrap().collect();
    assert!(left.is_empty(), "bench train left {left:?}");
}
