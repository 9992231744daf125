//! `--device` as a user meets it: `assist bench field --device gpu` on whatever adapter
//! is present (lavapipe in CI, where `ASSIST_REQUIRE_GPU=1`), and the clear refusal or
//! CPU fallback when no Vulkan driver is found.

use std::process::Command;

use serde_json::Value;

fn assist(args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_assist"));
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

#[test]
fn bench_field_on_the_gpu_reports_training_and_inference() {
    let mut args = SMALL.to_vec();
    args.extend(["--device", "gpu", "--json"]);
    let out = assist(&args, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success()
        && err.contains("no GPU adapter")
        && std::env::var("ASSIST_REQUIRE_GPU").as_deref() != Ok("1")
    {
        eprintln!("SKIPPED: no GPU adapter (install mesa-vulkan-drivers for lavapipe)");
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
