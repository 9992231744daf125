//! `assist generate` as a user meets it, on a trained synthetic scene: 100 samples with a
//! library object; the same run as 4 shards in separate processes plus `merge` equals it
//! file for file; 3 samples replayed with `assist edit` + `assist render` reproduce their
//! images bit for bit; a restart skips what is done; bad specs are refused naming the
//! field; the annotations are read back by pycocotools (`generate_check.py`, in the venv
//! named by `ASSIST_PYTHON`). Desk's generation is in `desk_cli.rs`.

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::{ok, pycoco_check, refused, run, run_tree, s};

/// One shard deleted and one file of another truncated: `status` names both, `merge`
/// refuses, a rerun of a complete shard does nothing, and rerunning the two then merging
/// gives `whole` again, file for file.
fn shards_damaged_and_remade(sp: &Path, dir: &Path, whole: &BTreeMap<PathBuf, Vec<u8>>) {
    let status = |extra: &[&str]| {
        let mut args = vec!["generate", "status", s(dir)];
        args.extend_from_slice(extra);
        let o = run(&args);
        ok(&o);
        o
    };
    let st: serde_json::Value = serde_json::from_slice(&status(&["--json"]).stdout).unwrap();
    assert_eq!(st["shards"], 4, "{st}");
    assert_eq!(st["complete"], serde_json::json!([0, 1, 2, 3]), "{st}");
    // Shard 1 deleted (its samples and its record), a file of shard 2 truncated.
    for i in (1..100).step_by(4) {
        std::fs::remove_dir_all(dir.join(format!("samples/{i:06}"))).unwrap();
    }
    std::fs::remove_file(dir.join("shards/1-of-4.json")).unwrap();
    let img = dir.join("samples/000042/views/images/v0.png");
    let bytes = std::fs::read(&img).unwrap();
    std::fs::write(&img, &bytes[..bytes.len() / 2]).unwrap();
    let st: serde_json::Value = serde_json::from_slice(&status(&["--json"]).stdout).unwrap();
    assert_eq!(st["missing"], serde_json::json!([1]), "{st}");
    assert_eq!(st["partial"], serde_json::json!([2]), "{st}");
    assert_eq!(st["samples_done"], 74, "{st}");
    let text = String::from_utf8_lossy(&status(&[]).stdout).into_owned();
    assert!(
        text.contains("shard 1/4 missing") && text.contains("sample 000042"),
        "{text}"
    );
    assert_eq!(
        String::from_utf8_lossy(&status(&["--rerun"]).stdout).trim(),
        "1,2"
    );
    let m = run(&["generate", "merge", s(dir)]);
    refused(
        &m,
        &[
            "2 shards not complete",
            "1/4 missing",
            "2/4 partial",
            "000042",
        ],
    );
    // A complete shard: nothing to do, nothing loaded.
    let again = run(&[
        "generate",
        "--spec",
        s(sp),
        "--out",
        s(dir),
        "--shard",
        "3/4",
    ]);
    ok(&again);
    assert!(
        String::from_utf8_lossy(&again.stderr).contains("is complete"),
        "{}",
        String::from_utf8_lossy(&again.stderr)
    );
    for i in ["1/4", "2/4"] {
        ok(&run(&[
            "generate",
            "--spec",
            s(sp),
            "--out",
            s(dir),
            "--shard",
            i,
        ]));
    }
    ok(&run(&["generate", "merge", s(dir)]));
    assert!(
        run_tree(dir) == *whole,
        "the remade shards differ from the whole run"
    );
}

/// One shard made with the fields queried on the GPU (`--device gpu`: lavapipe in CI): its
/// images are the single run's within 8-bit rounding. Skipped loudly without an adapter
/// unless `ASSIST_REQUIRE_GPU=1`.
fn on_the_gpu(sp: &Path, root: &Path, full: &Path) {
    let out = root.join("gpu");
    let o = run(&[
        "generate",
        "--spec",
        s(sp),
        "--out",
        s(&out),
        "--shard",
        "0/100",
        "--device",
        "gpu",
    ]);
    if common::no_gpu_adapter(&o, "generate --device gpu") {
        return;
    }
    ok(&o);
    let views = Path::new("samples/000000/views/images");
    let images: Vec<_> = std::fs::read_dir(full.join(views))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(!images.is_empty());
    for f in &images {
        let q = common::png_psnr(&full.join(views).join(f), &out.join(views).join(f));
        assert!(q > 40.0, "{f:?}: {q:.1} dB between the devices");
    }
}

fn spec(dir: &Path, scene: &Path, extra: &str) -> PathBuf {
    let p = dir.join(format!("spec{}.toml", extra.len()));
    std::fs::write(
        &p,
        format!(
            r#"count = 100
seed = 7

[[scenes]]
path = "{scene}"

[objects]
keep = 0.8
move = 0.8

[[library]]
scene = "{scene}"
node = 1
min = 0
max = 1

[placement]
yaw_deg = [-180, 180]
scale = [0.9, 1.1]

[output]
width = 64
height = 48
{extra}
"#,
            scene = scene.display()
        ),
    )
    .unwrap();
    p
}

#[test]
fn generate_shards_replays_and_annotations() {
    let tmp = assist_testkit::TempDir::new("generate-cli");
    let root = tmp.path().to_path_buf();
    let (cap, scene) = common::generator_scene(&root);
    let sp = spec(&root, &scene, "");

    // One run of 100 samples, merged.
    let full = root.join("full");
    let out = run(&["generate", "--spec", s(&sp), "--out", s(&full), "--json"]);
    ok(&out);
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["made"], 100, "{summary}");
    assert_eq!(summary["merged"]["samples"], 100, "{summary}");
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(full.join("index.json")).unwrap()).unwrap();
    let placed: u64 = (0..100)
        .map(|i| {
            let sj: serde_json::Value = serde_json::from_slice(
                &std::fs::read(full.join(format!("samples/{i:06}/sample.json"))).unwrap(),
            )
            .unwrap();
            sj["objects"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|o| o["status"] != "stays")
                .count() as u64
        })
        .sum();
    assert!(
        placed >= 150,
        "only {placed} objects placed in 100 samples: {index}"
    );

    // A restart makes nothing and changes nothing.
    let before = run_tree(&full);
    let again = run(&["generate", "--spec", s(&sp), "--out", s(&full), "--json"]);
    ok(&again);
    let again: serde_json::Value = serde_json::from_slice(&again.stdout).unwrap();
    assert_eq!(again["made"], 0);
    assert_eq!(again["skipped"], 100);
    assert_eq!(run_tree(&full), before, "a restart rewrote files");

    // 4 shards as separate processes into one folder, then merge: file for file the same.
    let sharded = root.join("sharded");
    let kids: Vec<_> = (0..4)
        .map(|i| {
            common::bin()
                .args(["generate", "--spec", s(&sp), "--out", s(&sharded)])
                .env("SLURM_ARRAY_TASK_ID", (i + 1).to_string())
                .env("SLURM_ARRAY_TASK_MIN", "1")
                .env("SLURM_ARRAY_TASK_COUNT", "4")
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for k in kids {
        ok(&k.wait_with_output().unwrap());
    }
    assert!(!sharded.join("index.json").exists(), "a shard merged");
    ok(&run(&["generate", "merge", s(&sharded)]));
    let a = run_tree(&full);
    let b = run_tree(&sharded);
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the shards wrote other files"
    );
    for (k, v) in &a {
        assert!(
            b[k] == *v,
            "{} differs between the sharded and the single run",
            k.display()
        );
    }
    shards_damaged_and_remade(&sp, &sharded, &a);
    on_the_gpu(&sp, &root, &full);

    // Replaying 3 samples' actions reproduces their images bit for bit.
    for i in [0, 37, 99] {
        let dir = full.join(format!("samples/{i:06}"));
        let edited = root.join(format!("replay{i}.assist"));
        ok(&run(&[
            "edit",
            s(&scene),
            "--actions",
            s(&dir.join("actions.jsonl")),
            "--out",
            s(&edited),
        ]));
        let r = root.join(format!("replay{i}"));
        ok(&run(&[
            "render",
            s(&edited),
            "--cameras",
            s(&dir.join("views")),
            "--split",
            "all",
            "--outputs",
            "rgb,depth,panoptic,semantic",
            "--out",
            s(&r),
        ]));
        for f in [
            "images/v0.png",
            "depth/v0.png",
            "depth/v0.npy",
            "panoptic/v0.png",
        ] {
            assert!(
                std::fs::read(r.join(f)).unwrap()
                    == std::fs::read(dir.join("views").join(f)).unwrap(),
                "sample {i}: replayed {f} differs"
            );
        }
    }

    // A dry run plans and writes actions, no images.
    let dry = root.join("dry");
    ok(&run(&[
        "generate",
        "--spec",
        s(&sp),
        "--out",
        s(&dry),
        "--count",
        "5",
        "--dry-run",
    ]));
    assert!(dry.join("plans/000004/actions.jsonl").is_file());
    assert!(!dry.join("plans/000004/views").exists());
    assert_eq!(
        std::fs::read(dry.join("plans/000003/actions.jsonl")).unwrap(),
        std::fs::read(full.join("samples/000003/actions.jsonl")).unwrap(),
        "a dry run plans what the run makes"
    );

    // A library object from another scene is cut at the surface it stood on there, as
    // one from the base scene is: with the library taken from a copy of the scene, every
    // plan is the same (before, the copy's object kept its whole occupancy, table slab
    // included, and stood on it).
    let copy = root.join("copy.assist");
    assert!(
        Command::new("cp")
            .arg("-r")
            .arg(&scene)
            .arg(&copy)
            .status()
            .unwrap()
            .success()
    );
    let canon = |p: &Path| std::fs::canonicalize(p).unwrap().display().to_string();
    let text = std::fs::read_to_string(&sp).unwrap();
    let lib = format!("[[library]]\nscene = \"{}\"", scene.display());
    assert!(text.contains(&lib), "{text}");
    let sp2 = root.join("spec-copy.toml");
    std::fs::write(
        &sp2,
        text.replace(
            &lib,
            &format!("[[library]]\nscene = \"{}\"", copy.display()),
        ),
    )
    .unwrap();
    let dry2 = root.join("dry-copy");
    let dry1 = root.join("dry-same");
    for (spec_file, out) in [(&sp, &dry1), (&sp2, &dry2)] {
        ok(&run(&[
            "generate",
            "--spec",
            s(spec_file),
            "--out",
            s(out),
            "--count",
            "30",
            "--dry-run",
        ]));
    }
    let mut added = 0;
    for i in 0..30 {
        let f = format!("plans/{i:06}/actions.jsonl");
        let a = std::fs::read_to_string(dry1.join(&f)).unwrap();
        let b = std::fs::read_to_string(dry2.join(&f)).unwrap();
        added += b.matches(&canon(&copy)).count();
        assert_eq!(a, b.replace(&canon(&copy), &canon(&scene)), "plan {i}");
    }
    assert!(added > 0, "no library object was added in 30 plans");

    // Another spec into the same folder is refused, naming what differs.
    let other = spec(&root, &scene, "images = [\"rgb\"]");
    refused(
        &run(&["generate", "--spec", s(&other), "--out", s(&full)]),
        &["another spec", "output", "--force"],
    );

    // Bad specs: clear errors naming the field, no panic.
    let bad = |name: &str, text: &str, needles: &[&str]| {
        let p = root.join(name);
        std::fs::write(&p, text).unwrap();
        refused(
            &run(&["generate", "--spec", s(&p), "--out", s(&root.join("never"))]),
            needles,
        );
        assert!(!root.join("never").exists());
    };
    let head = format!("[[scenes]]\npath = \"{}\"\n", scene.display());
    bad(
        "unknown.toml",
        &format!("{head}colour = 3\n"),
        &["unknown field", "colour"],
    );
    bad("negative.toml", &format!("count = -3\n{head}"), &["count"]);
    bad(
        "range.toml",
        &format!("{head}[placement]\nscale = [2.0, 1.0]\n"),
        &["placement.scale"],
    );
    bad(
        "library.toml",
        &format!("{head}[[library]]\nscene = \"nowhere.assist\"\nnode = 1\n"),
        &["library[0]", "nowhere.assist"],
    );
    bad(
        "node.toml",
        &format!(
            "{head}[[library]]\nscene = \"{}\"\nnode = \"giraffe\"\n",
            scene.display()
        ),
        &["library[0]", "giraffe", "no such node"],
    );
    // Issue 47 item 17: a camera aimed at no object was accepted silently.
    bad(
        "look_at.toml",
        &format!("{head}[cameras]\nlook_at = \"giraffe\"\n"),
        &["cameras.look_at", "giraffe"],
    );
    // An impossible placement is a per-sample reason, not an error.
    let huge = root.join("huge.toml");
    std::fs::write(
        &huge,
        format!(
            "count = 2\n{head}[objects]\nkeep = 1.0\nmove = 1.0\n[placement]\nscale = [15.0, 15.0]\ntries = 5\n[output]\nwidth = 32\nheight = 24\n"
        ),
    )
    .unwrap();
    let h = root.join("huge");
    ok(&run(&["generate", "--spec", s(&huge), "--out", s(&h)]));
    let sj: serde_json::Value =
        serde_json::from_slice(&std::fs::read(h.join("samples/000000/sample.json")).unwrap())
            .unwrap();
    let gave = sj["gave_up"].as_array().unwrap();
    assert!(!gave.is_empty(), "{sj}");
    assert!(
        gave[0]["reasons"]
            .to_string()
            .contains("off the supported area")
            || gave[0]["reasons"].to_string().contains("overlaps"),
        "{sj}"
    );

    // Orbit views stand where the capture stood: each within 20° of a capture camera's
    // direction from the point the views look at, no nearer or farther than the capture.
    let orbit = root.join("orbit.toml");
    let orbit_spec = |el: &str| {
        format!(
            "count = 3\n{head}[cameras]\nfrom = \"orbit\"\nviews = 4\nelevation_deg = {el}\n[output]\nwidth = 32\nheight = 24\nimages = [\"rgb\"]\n"
        )
    };
    std::fs::write(&orbit, orbit_spec("[-10, 80]")).unwrap();
    let o = root.join("orbit");
    ok(&run(&["generate", "--spec", s(&orbit), "--out", s(&o)]));
    let poses = |file: &Path| -> Vec<(assist_core::DVec3, assist_core::DVec3)> {
        let t: serde_json::Value = serde_json::from_slice(&std::fs::read(file).unwrap()).unwrap();
        t["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| {
                let m: Vec<Vec<f64>> =
                    serde_json::from_value(f["transform_matrix"].clone()).unwrap();
                let eye = assist_core::DVec3::new(m[0][3], m[1][3], m[2][3]);
                // OpenGL convention: the camera looks down its −z axis.
                let fwd = -assist_core::DVec3::new(m[0][2], m[1][2], m[2][2]).normalize();
                (eye, fwd)
            })
            .collect()
    };
    let capture = poses(&cap.join("transforms.json"));
    for i in 0..3 {
        let views = poses(&o.join(format!("samples/{i:06}/views/transforms.json")));
        assert_eq!(views.len(), 4);
        // The point the views look at: closest to their four axes (least squares).
        let (mut a, mut b) = (assist_core::DMat3::ZERO, assist_core::DVec3::ZERO);
        for (eye, d) in &views {
            let p = assist_core::DMat3::IDENTITY
                - assist_core::DMat3::from_cols(*d * d.x, *d * d.y, *d * d.z);
            a += p;
            b += p * *eye;
        }
        let centre = a.inverse() * b;
        let dist = |e: assist_core::DVec3| (e - centre).length();
        let (near, far) = capture
            .iter()
            .map(|(e, _)| dist(*e))
            .fold((f64::INFINITY, 0.0f64), |(x, y), d| (x.min(d), y.max(d)));
        for (eye, _) in &views {
            let dir = (*eye - centre).normalize();
            let best = capture
                .iter()
                .map(|(e, _)| {
                    (*e - centre)
                        .normalize()
                        .dot(dir)
                        .clamp(-1.0, 1.0)
                        .acos()
                        .to_degrees()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                best <= 20.5,
                "sample {i}: an orbit view {best:.1}° from every capture camera"
            );
            let r = dist(*eye);
            assert!(
                r >= near * 0.99 && r <= far * 1.01,
                "sample {i}: orbit distance {r:.3} outside the capture's {near:.3}–{far:.3}"
            );
        }
    }
    // An orbit below everything the capture saw is an error that says why.
    std::fs::write(&orbit, orbit_spec("[-80, -70]")).unwrap();
    refused(
        &run(&[
            "generate",
            "--spec",
            s(&orbit),
            "--out",
            s(&root.join("below")),
            "--force",
        ]),
        &["no orbit view within 20°", "cameras.elevation_deg"],
    );

    // The annotations as pycocotools reads them; placed objects on the synthetic table top
    // (its ground truth height, not our estimate).
    let table = {
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(cap.join("transforms.json")).unwrap()).unwrap();
        t["table_top_z"].as_f64().unwrap_or(0.75)
    };
    pycoco_check(&full, table);
    // Issue 47 item 8: polygons by default (above); exact RLE on request.
    let coco = |dir: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(dir.join("annotations/instances.json")).unwrap())
            .unwrap()
    };
    let c = coco(&full);
    assert_eq!(c["info"]["masks"], "polygon");
    assert!(c["annotations"][0]["segmentation"].is_array());
    ok(&run(&[
        "generate",
        "merge",
        s(&full),
        "--coco-masks",
        "rle",
    ]));
    let c = coco(&full);
    assert_eq!(c["info"]["masks"], "rle");
    assert!(c["annotations"][0]["segmentation"]["counts"].is_string());
    pycoco_check(&full, table);

    // `--force` replaces a whole run made from another spec: everything in it (the BOP
    // models included) is assist's own.
    assert!(full.join("models/models_info.json").is_file());
    ok(&run(&[
        "generate",
        "--spec",
        s(&other),
        "--out",
        s(&full),
        "--count",
        "1",
        "--force",
    ]));
    assert!(!full.join("samples/000001").exists());
    assert!(full.join("samples/000000/sample.json").is_file());
}
