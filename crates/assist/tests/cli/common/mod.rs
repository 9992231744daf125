//! A small scene on disk (random weights) and a way to run the built binary.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;

use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode};
use assist_field::{Field, FieldConfig, OccupancyGrid};
use assist_scene::{NeuralScene, NodeField};

pub fn small_field(seed: u64) -> Field {
    let mut cfg = FieldConfig::object(0);
    cfg.appearance_dim = 0;
    cfg.log2_table_size = 10;
    cfg.levels = 2;
    Field::new(cfg, seed).unwrap()
}

/// A scene with a duck (1) and a mug (3) on a background, saved to `dir`.
pub fn write_scene(dir: &Path) {
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
        scene: Scene::with_nodes(nodes, DVec3::Z),
        fields,
    };
    assist_scene::scene_file::save(dir, &s, serde_json::Value::Null, false).unwrap();
}

pub fn assist(args: &[&str]) -> (bool, String, String) {
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

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The built binary as a command.
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_assist"));
    child_threads(&mut c);
    c
}

/// `ASSIST_TEST_CHILD_THREADS=N` (set by `.ci/run`) runs the processes the tests start
/// with N worker threads (`RAYON_NUM_THREADS`). The test runner already keeps every core
/// busy with tests side by side, and a process's fork-join steps would wait on a thread
/// the other test's process holds off its core (measured in docs/history.md, CI time).
/// The tests that run in the test process itself keep every thread.
pub fn child_threads(c: &mut Command) {
    if let Ok(n) = std::env::var("ASSIST_TEST_CHILD_THREADS") {
        c.env("RAYON_NUM_THREADS", n);
    }
}

/// Runs the built binary and returns its output; says how long it took (seen with
/// `--nocapture` or when the test fails: where a slow test spends its time).
pub fn run(args: &[&str]) -> std::process::Output {
    let t = std::time::Instant::now();
    let out = bin().args(args).output().expect("run assist");
    let head: Vec<&str> = args.iter().take(3).copied().collect();
    eprintln!(
        "[{:.1} s] assist {}",
        t.elapsed().as_secs_f64(),
        head.join(" ")
    );
    out
}

/// Succeeds (or fails the test with its stderr); returns stderr.
pub fn ok(out: &std::process::Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

/// Succeeds (or fails the test with its stderr); returns stdout.
pub fn ok_stdout(out: &std::process::Output) -> String {
    ok(out);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Fails cleanly (exit 1, no panic), naming every needle; returns stderr.
pub fn refused(out: &std::process::Output, needles: &[&str]) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "error should mention {n:?}: {err}");
    }
    err
}

/// Whether `out` (a `--device gpu` command) failed for want of a GPU adapter where that
/// is allowed: a loud skip of `what`. `ASSIST_REQUIRE_GPU=1` (CI, lavapipe) disallows it.
pub fn no_gpu_adapter(out: &std::process::Output, what: &str) -> bool {
    let err = String::from_utf8_lossy(&out.stderr);
    let skip = !out.status.success()
        && err.contains("no GPU adapter")
        && std::env::var("ASSIST_REQUIRE_GPU").as_deref() != Ok("1");
    if skip {
        eprintln!("SKIPPED {what}: no GPU adapter (install mesa-vulkan-drivers for lavapipe)");
    }
    skip
}

/// A tiny built-in capture (8 views of 32×24, 3 objects) at `dir`.
pub fn tiny_capture(dir: &Path, seed: u64) {
    let seed = seed.to_string();
    ok(&run(&[
        "synth",
        "--out",
        s(dir),
        "--views",
        "8",
        "--width",
        "32",
        "--height",
        "24",
        "--objects",
        "3",
        "--seed",
        &seed,
        "--spp",
        "1",
        "--shadow-samples",
        "1",
    ]));
}

/// `tiny_capture` at `root/cap` and a scene trained on it for 3 iterations at
/// `root/s.assist`.
pub fn tiny_scene(root: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let data = root.join("cap");
    tiny_capture(&data, 0);
    let sc = root.join("s.assist");
    ok(&run(&[
        "train",
        s(&data),
        "--out",
        s(&sc),
        "--iters",
        "3",
        "--batch-samples",
        "4096",
    ]));
    (data, sc)
}

/// `assist synth --out DIR --views VIEWS --width 64 --height 48 --objects 3`, which must
/// succeed: a small synthetic capture with three objects.
pub fn synth_small(dir: &Path, views: u32) {
    let views = views.to_string();
    ok(&run(&[
        "synth",
        "--out",
        s(dir),
        "--views",
        &views,
        "--width",
        "64",
        "--height",
        "48",
        "--objects",
        "3",
    ]));
}

/// `assist train DATA --out OUT --downscale 4 --iters ITERS EXTRA…`, which must succeed:
/// a shared capture trained briefly at a quarter of its size.
pub fn train_quarter(data: &Path, out: &Path, iters: u32, extra: &[&str]) {
    let iters = iters.to_string();
    let mut args = vec![
        "train",
        s(data),
        "--out",
        s(out),
        "--downscale",
        "4",
        "--iters",
        &iters,
    ];
    args.extend_from_slice(extra);
    ok(&run(&args));
}

/// The `info` of a scene's `scene.json` (training state, provenance).
pub fn scene_info(scene: &Path) -> serde_json::Value {
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scene.join("scene.json")).unwrap()).unwrap();
    v["info"].clone()
}

/// Temporaries and lock files left in `dir` (`.NAME.tmp-*`, `.NAME.old-*`, `*.lock`).
pub fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-") || n.contains(".old-") || n.ends_with(".lock"))
        .collect()
}

/// `assist edit SCENE --do TEXT --out SCENE --force`: an in-place edit.
pub fn edit_in_place(scene: &Path, text: &str) -> std::process::Output {
    run(&["edit", s(scene), "--do", text, "--out", s(scene), "--force"])
}

/// No temporaries or lock files are left in `dir`.
pub fn assert_no_leftovers(dir: &Path) {
    let left = leftovers(dir);
    assert!(left.is_empty(), "{left:?}");
}

/// Runs `tests/SCRIPT ARGS…` with the Python of `ASSIST_PYTHON` and returns its output,
/// failing the test when it fails; without one, skips loudly (`None`) unless
/// `ASSIST_REQUIRE_PYTHON` is set. `needs` names the packages, for the messages.
pub fn python_check(script: &str, args: &[&std::ffi::OsStr], needs: &str) -> Option<String> {
    match std::env::var("ASSIST_PYTHON") {
        Ok(py) => {
            let o = Command::new(&py)
                .arg(format!("{}/tests/{script}", env!("CARGO_MANIFEST_DIR")))
                .args(args)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "{script}: {}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            );
            let out = String::from_utf8_lossy(&o.stdout).into_owned();
            eprintln!("{script}: {out}");
            Some(out)
        }
        Err(_) if std::env::var("ASSIST_REQUIRE_PYTHON").is_ok() => {
            panic!("ASSIST_REQUIRE_PYTHON is set but ASSIST_PYTHON (a python with {needs}) is not")
        }
        Err(_) => {
            eprintln!("SKIPPED {script}: set ASSIST_PYTHON to a python with {needs}");
            None
        }
    }
}

/// The generator's outputs read back: COCO by pycocotools (`generate_check.py OUT
/// TABLE`, objects on the table top at `table`) and BOP as the bop_toolkit reads it.
pub fn pycoco_check(out: &Path, table: f64) {
    let needs = "pycocotools, numpy and pillow";
    let table = table.to_string();
    python_check(
        "generate_check.py",
        &[out.as_os_str(), table.as_ref()],
        needs,
    );
    python_check("bop_check.py", &[out.as_os_str()], needs);
}

/// Every file of a generate run's folder `dir` (relative path → bytes) but the shards'
/// completion records (`shards/`: which shards ran, so a sharded run's differ from a whole
/// run's).
pub fn run_tree(dir: &Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                if p != dir.join("shards") {
                    stack.push(p);
                }
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

/// PSNR between two 8-bit RGB PNGs of the same size.
pub fn png_psnr(a: &Path, b: &Path) -> f64 {
    let (a, b) = (
        image::open(a).unwrap().to_rgb8(),
        image::open(b).unwrap().to_rgb8(),
    );
    assert_eq!(a.dimensions(), b.dimensions());
    assist_testkit::psnr_u8(a.as_raw(), b.as_raw())
}

/// The built-in capture the generator's tests use (30 views of 96×72, 4 objects) and a
/// scene trained on it enough for the generator to find its table (400 steps), trained
/// once for every test process that asks ([`generator_fixture`]) and copied into `root`:
/// (`root/cap`, `root/s.assist`).
pub fn generator_scene(root: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = generator_fixture();
    let (cap, scene) = (root.join("cap"), root.join("s.assist"));
    assist_testkit::copy_dir(&dir.join("cap"), &cap);
    assist_testkit::copy_dir(&dir.join("s.assist"), &scene);
    (cap, scene)
}

/// The folder that holds [`generator_scene`]'s capture and scene, made once by the first
/// test process to ask (`assist_testkit::shared_fixture`); the Python suite is given it.
pub fn generator_fixture() -> std::path::PathBuf {
    let synth = [
        "synth",
        "--views",
        "30",
        "--width",
        "96",
        "--height",
        "72",
        "--objects",
        "4",
    ];
    let train = ["train", "--iters", "400"];
    let recipe = format!("{synth:?} {train:?}");
    let bin = Path::new(env!("CARGO_BIN_EXE_assist"));
    assist_testkit::shared_fixture("generator-scene", bin, &recipe, |dir| {
        let (cap, scene) = (dir.join("cap"), dir.join("s.assist"));
        let mut args = synth.to_vec();
        args.extend(["--out", s(&cap)]);
        ok(&run(&args));
        let mut args = train.to_vec();
        args.extend([s(&cap), "--out", s(&scene)]);
        ok(&run(&args));
    })
}
