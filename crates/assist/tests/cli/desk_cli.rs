//! Desk (the shared capture), trained briefly at a quarter of its size, as a user meets
//! it: generated samples that pycocotools and the BOP readers load, meshes with the
//! objects' true topology that MuJoCo keeps at rest on the table, and a moved object that
//! leaves no stain where it stood. One training serves all three (it is the costly part).

use crate::common;

use std::path::Path;

use crate::common::{ok, pycoco_check, run, s};

#[test]
fn desk_trained_briefly() {
    let Some(desk) = assist_testkit::shared_dataset("desk_trained_briefly", "desk") else {
        return;
    };
    let tmp = assist_testkit::TempDir::new("desk");
    let root = tmp.path().to_path_buf();
    let scene = root.join("desk.assist");
    common::train_quarter(&desk, &scene, 600, &[]);
    generates_on_the_table(&desk, &scene, &root);
    meshes_are_true_and_rest_in_mujoco(&scene, &root);
    a_moved_object_leaves_no_stain(&desk, &scene, &root);
    the_render_benches_run(&desk, &scene);
    frames_on_the_gpu_score_as_on_the_cpu(&desk, &scene);
}

/// Two held-out desk frames (quarter size) with the fields queried on the GPU (lavapipe in
/// CI) score within 0.1 dB of the CPU's, as issue 45 asks. Skipped loudly without an
/// adapter unless `ASSIST_REQUIRE_GPU=1`.
fn frames_on_the_gpu_score_as_on_the_cpu(desk: &Path, scene: &Path) {
    let eval = |device: &str| {
        run(&[
            "eval",
            s(scene),
            "--data",
            s(desk),
            "--stride",
            "10",
            "--device",
            device,
            "--json",
        ])
    };
    let o = eval("gpu");
    if common::no_gpu_adapter(&o, "desk's frames on the GPU") {
        return;
    }
    let psnr = |o: &std::process::Output| {
        let v: serde_json::Value = serde_json::from_str(&common::ok_stdout(o)).unwrap();
        assert_eq!(v["images"].as_u64(), Some(2), "{v}");
        v["psnr"].as_f64().expect("psnr")
    };
    let (g, c) = (psnr(&o), psnr(&eval("cpu")));
    assert!(
        c > 20.0 && (g - c).abs() <= 0.1,
        "{g:.3} dB on the GPU, {c:.3} dB on the CPU"
    );
}

/// `bench render` and `bench view` on the trained scene at small sizes, so the benchmarks
/// BENCHMARKS.md quotes cannot rot: every figure there, pruning dropping samples and
/// changing the render by little.
fn the_render_benches_run(desk: &Path, scene: &Path) {
    let o = run(&[
        "bench",
        "render",
        s(scene),
        "--data",
        s(desk),
        "--views",
        "1",
        "--runs",
        "1",
        "--json",
    ]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let set = v["settings"].as_array().unwrap();
    assert_eq!(set.len(), 2, "{v}");
    let f = |k: usize, key: &str| set[k][key].as_f64().unwrap_or(f64::NAN);
    for k in 0..2 {
        assert!(f(k, "frame_s") > 0.0, "{v}");
        assert!(f(k, "psnr") > 20.0, "{v}");
        assert!(f(k, "marched_per_ray") >= f(k, "queried_per_ray"), "{v}");
    }
    assert_eq!(f(0, "marched_per_ray"), f(0, "queried_per_ray"), "{v}");
    assert!(f(1, "queried_per_ray") < f(1, "marched_per_ray"), "{v}");
    assert!(f(1, "psnr_vs_first") > 45.0, "{v}");
    let o = run(&[
        "bench",
        "view",
        s(scene),
        "--data",
        s(desk),
        "--width",
        "120",
        "--height",
        "90",
        "--frames",
        "3",
        "--json",
    ]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for key in ["preview_ms", "full_ms", "drag_ms"] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{v}");
    }
}

/// 100 samples whose COCO masks pycocotools reads back, with every placed object on
/// desk's table top (its ground truth, `table_top_z`) and no two objects overlapping.
fn generates_on_the_table(desk: &Path, scene: &Path, root: &Path) {
    let sp = root.join("desk.toml");
    std::fs::write(
        &sp,
        format!(
            "count = 100\nseed = 3\n[[scenes]]\npath = \"{}\"\ndata = \"{}\"\n[output]\nwidth = 120\nheight = 90\n",
            scene.display(),
            desk.display()
        ),
    )
    .unwrap();
    let out = root.join("gen");
    let o = run(&["generate", "--spec", s(&sp), "--out", s(&out), "--json"]);
    ok(&o);
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["merged"]["samples"], 100, "{summary}");
    eprintln!("desk: {summary}");
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(desk.join("transforms.json")).unwrap()).unwrap();
    let table = t["table_top_z"].as_f64().expect("desk's table_top_z");
    pycoco_check(&out, table);
}

/// Issue 47 items 2 and 3: each object's mesh has its true genus (the duck, the cow: 0;
/// the mug and the teapot: 1, their handles), encloses about what its occupancy holds,
/// and MuJoCo keeps every object within 1 cm of its pose for 2 s on the exported
/// supports.
fn meshes_are_true_and_rest_in_mujoco(scene: &Path, root: &Path) {
    let out = root.join("mjcf");
    ok(&run(&[
        "export",
        s(scene),
        "--out",
        s(&out),
        "--sim",
        "mjcf",
    ]));
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("export.json")).unwrap()).unwrap();
    let nodes = index["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 5, "{index}");
    for n in nodes {
        let label = n["label"].as_str().unwrap();
        let genus = n["genus"].as_u64().unwrap_or(u64::MAX);
        eprintln!(
            "{label}: genus {genus}, {:.0} cm³ against {:.0} cm³ occupied, cut at {}",
            n["mass_properties"]["volume"].as_f64().unwrap_or(f64::NAN) * 1e6,
            n["occupancy_m3"].as_f64().unwrap() * 1e6,
            n["cut_at_support_m"]
        );
        // The brick: 0 as measured (16 to 18 before meshes were taken by opacity); one
        // groove its briefly trained field carves deeper than the closing is allowed.
        let (lo, hi) = match label {
            l if l.contains("duck") || l.contains("cow") => (0, 0),
            l if l.contains("mug") || l.contains("teapot") => (1, 1),
            _ => (0, 1),
        };
        assert!((lo..=hi).contains(&genus), "{label}: genus {genus}");
        assert_eq!(n["closed"], true, "{label}");
        let share =
            n["mass_properties"]["volume"].as_f64().unwrap() / n["occupancy_m3"].as_f64().unwrap();
        assert!(
            (0.6..1.5).contains(&share),
            "{label}: volume {share} × occupancy"
        );
        assert!(n["cut_at_support_m"].as_f64().is_some(), "{label}: not cut");
    }
    // Every object is cut flat at the table, so each stands on a base pad.
    let model = std::fs::read_to_string(out.join("scene.xml")).unwrap();
    assert_eq!(model.matches("_pad\" type=\"box\"").count(), 5, "{model}");
    common::python_check("mujoco_settle.py", &[out.as_os_str()], "mujoco");
}

/// Issue 47 item 7: where the mug stood before it was moved 15 cm, the edited scene's
/// render is the background's own render (the held-out views, a quarter size): no red
/// tint or residue of the mug is left there. Pixels other objects or shadows cover are
/// compared too, so the bounds leave room for shadows, not for a stain's redness.
fn a_moved_object_leaves_no_stain(desk: &Path, scene: &Path, root: &Path) {
    let moved = root.join("moved.assist");
    ok(&run(&[
        "edit",
        s(scene),
        "--do",
        "move the mug 15 cm right",
        "--allow-overlap",
        "--out",
        s(&moved),
    ]));
    let render = |scene: &Path, out: &Path, outputs: &str| {
        ok(&run(&[
            "render",
            s(scene),
            "--cameras",
            s(desk),
            "--downscale",
            "4",
            "--outputs",
            outputs,
            "--out",
            s(out),
        ]))
    };
    let (before, after) = (root.join("before"), root.join("after"));
    render(scene, &before, "panoptic");
    render(&moved, &after, "rgb,panoptic,background,unseen");
    let mut pixels = 0usize;
    let (mut diff, mut redder, mut stained) = (0.0f64, 0.0f64, 0usize);
    for entry in std::fs::read_dir(before.join("panoptic")).unwrap() {
        let name = entry.unwrap().file_name();
        let ids = |dir: &Path| {
            image::open(dir.join("panoptic").join(&name))
                .unwrap()
                .to_luma16()
        };
        let rgb =
            |dir: &Path, what: &str| image::open(dir.join(what).join(&name)).unwrap().to_rgb8();
        let (was, now) = (ids(&before), ids(&after));
        // What no ray met is no object's: an unseen pixel has no id.
        let unseen = image::open(after.join("unseen").join(&name))
            .unwrap()
            .to_luma8();
        assert_eq!(unseen.dimensions(), now.dimensions());
        for (u, id) in unseen.pixels().zip(now.pixels()) {
            assert!(u[0] == 0 || (u[0] == 255 && id[0] == 0), "{name:?}");
        }
        let (edited, bg) = (rgb(&after, "images"), rgb(&after, "background"));
        for (x, y, p) in was.enumerate_pixels() {
            if p[0] != 3 || now.get_pixel(x, y)[0] != 0 {
                continue;
            }
            let [a, b] = [edited.get_pixel(x, y), bg.get_pixel(x, y)]
                .map(|c| c.0.map(|v| f64::from(v) / 255.0));
            let red = |c: [f64; 3]| c[0] - (c[1] + c[2]) / 2.0;
            pixels += 1;
            diff += (0..3).map(|i| (a[i] - b[i]).abs()).sum::<f64>() / 3.0;
            redder += red(a) - red(b);
            stained += usize::from(red(a) - red(b) > 0.1);
        }
    }
    assert!(pixels > 1000, "only {pixels} pixels where the mug stood");
    let n = pixels as f64;
    eprintln!(
        "where the mug stood ({pixels} pixels): mean difference {:.4}, red excess {:.4}, {:.2}% stained",
        diff / n,
        redder / n,
        100.0 * stained as f64 / n
    );
    assert!(redder / n < 0.01, "red excess {}", redder / n);
    assert!(
        (stained as f64) < 0.01 * n,
        "{stained} of {pixels} pixels redder by 0.1"
    );
    assert!(diff / n < 0.03, "mean difference {}", diff / n);
}
