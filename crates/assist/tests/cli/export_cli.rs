//! `assist export` as a user meets it: a built-in capture trained briefly, its objects
//! exported in every format and with both simulator models, then read back by trimesh,
//! MuJoCo and an XML parser (`export_check.py`, in the venv named by `ASSIST_PYTHON`);
//! bad requests refused by name, and nothing a user had overwritten.

use crate::common;

use std::path::Path;

use crate::common::{ok, refused, run, s};

fn export(scene: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["export", s(scene), "--out", s(out), "--json"];
    args.extend_from_slice(extra);
    let o = run(&args);
    ok(&o);
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn export_meshes_points_and_models_read_back() {
    let tmp = assist_testkit::TempDir::new("export-cli");
    let root = tmp.path().to_path_buf();
    let (cap, scene) = common::generator_scene(&root);

    let obj = root.join("obj");
    let summary = export(&scene, &obj, &["--resolution", "64"]);
    let nodes = summary["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 4, "{summary}");
    for n in nodes {
        assert_eq!(n["closed"], true, "{n}");
        assert!(n["volume_m3"].as_f64().unwrap() > 0.0, "{n}");
        assert!(obj.join(n["file"].as_str().unwrap()).is_file());
        // Issue 47 item 3: the genus is reported, not hidden behind "closed".
        assert!(
            n["genus"].as_i64().is_some() && n["components"].as_u64() >= Some(1),
            "{n}"
        );
        assert!(n["occupancy_m3"].as_f64().unwrap() > 0.0, "{n}");
    }
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(obj.join("export.json")).unwrap()).unwrap();
    // Each object is cut at the table it stands on: its base is flat on the support, not
    // reaching into it (a simulator would throw it out of the table).
    let table = {
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(cap.join("transforms.json")).unwrap()).unwrap();
        t["table_top_z"].as_f64().unwrap_or(0.75)
    };
    for n in index["nodes"].as_array().unwrap() {
        let cut = n["cut_at_support_m"]
            .as_f64()
            .unwrap_or_else(|| panic!("no support found: {n}"));
        assert!(
            (cut - table).abs() < 0.01,
            "cut at {cut}, the table is at {table}: {n}"
        );
        let low = n["bounds"][0][2].as_f64().unwrap();
        assert!(
            low >= cut - 1e-3,
            "the mesh reaches {low} below its support {cut}: {n}"
        );
    }
    assert_eq!(index["frame"], "world");
    // A small triangle budget: reduced by edge collapse, still closed.
    let small = export(
        &scene,
        &root.join("small"),
        &["--resolution", "64", "--triangles", "2000"],
    );
    for n in small["nodes"].as_array().unwrap() {
        assert!(n["triangles"].as_u64().unwrap() <= 2000, "{n}");
        assert_eq!(n["closed"], true, "{n}");
    }
    // One node by name and one by id.
    let label = nodes[0]["label"].as_str().unwrap().to_string();
    let one = export(
        &scene,
        &root.join("one"),
        &["--node", &label, "--format", "ply"],
    );
    assert_eq!(one["nodes"].as_array().unwrap().len(), 1);
    assert_eq!(one["nodes"][0]["id"], nodes[0]["id"]);

    let (ply, glb, pts, mjcf, urdf) = (
        root.join("ply"),
        root.join("glb"),
        root.join("pts"),
        root.join("mjcf"),
        root.join("urdf"),
    );
    let res = ["--resolution", "64"];
    export(&scene, &ply, &[&res[..], &["--format", "ply"]].concat());
    export(&scene, &glb, &[&res[..], &["--format", "glb"]].concat());
    export(
        &scene,
        &pts,
        &[&res[..], &["--format", "points", "--points", "5000"]].concat(),
    );
    let m = export(&scene, &mjcf, &[&res[..], &["--sim", "mjcf"]].concat());
    assert_eq!(m["model"], "scene.xml");
    let mi: serde_json::Value =
        serde_json::from_slice(&std::fs::read(mjcf.join("export.json")).unwrap()).unwrap();
    assert_eq!(mi["frame"], "node", "--sim exports in the nodes' frames");
    // Every base pad in the index is in the model, a few centimetres a side.
    let pads: Vec<&serde_json::Value> = mi["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|n| n["base_pad"].as_object().map(|_| &n["base_pad"]))
        .collect();
    assert!(!pads.is_empty(), "{mi}");
    for p in &pads {
        for h in p["half_size_m"].as_array().unwrap() {
            assert!((0.002..0.5).contains(&h.as_f64().unwrap()), "{p}");
        }
    }
    let model = std::fs::read_to_string(mjcf.join("scene.xml")).unwrap();
    assert_eq!(model.matches("_pad\" type=\"box\"").count(), pads.len());
    export(&scene, &urdf, &[&res[..], &["--sim", "urdf"]].concat());

    // Refusals: named, exit 1, nothing written.
    let bad = root.join("bad");
    refused(
        &run(&[
            "export",
            s(&scene),
            "--out",
            s(&bad),
            "--node",
            "purple giraffe",
        ]),
        &["purple giraffe"],
    );
    refused(
        &run(&["export", s(&scene), "--out", s(&bad), "--node", "77"]),
        &["77"],
    );
    // An empty name is named as such, not blamed on "'it'/'the copy'" (issue 47 item 18).
    let e = refused(
        &run(&["export", s(&scene), "--out", s(&bad), "--node", ""]),
        &["empty name"],
    );
    assert!(!e.contains("the copy"), "{e}");
    refused(
        &run(&[
            "export",
            s(&scene),
            "--out",
            s(&bad),
            "--format",
            "ply",
            "--sim",
            "urdf",
        ]),
        &["obj"],
    );
    refused(
        &run(&["export", s(&scene), "--out", s(&bad), "--resolution", "1"]),
        &["resolution"],
    );
    // Issue 47 item 17: a density of 1e308 kg/m³ wrote a mass of 5e304 into the MJCF; an
    // empty surface exported "0 vertices" with exit 0.
    refused(
        &run(&[
            "export",
            s(&scene),
            "--out",
            s(&bad),
            "--sim",
            "mjcf",
            "--material-density",
            "1e308",
        ]),
        &["material density", "1e308"],
    );
    refused(
        &run(&[
            "export",
            s(&scene),
            "--out",
            s(&bad),
            "--opacity",
            "0",
            "--density",
            "1e7",
        ]),
        &["no surface", "--density"],
    );
    refused(
        &run(&[
            "export",
            s(&scene),
            "--out",
            s(&bad),
            "--opacity",
            "0.99999",
        ]),
        &["no surface", "--opacity"],
    );
    assert!(!bad.exists());
    // An existing folder is kept without --force; a user's own folder even with it.
    let before = std::fs::read(obj.join("export.json")).unwrap();
    refused(&run(&["export", s(&scene), "--out", s(&obj)]), &["--force"]);
    assert_eq!(std::fs::read(obj.join("export.json")).unwrap(), before);
    let mine = root.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), "mine").unwrap();
    refused(
        &run(&["export", s(&scene), "--out", s(&mine), "--force"]),
        &["mine"],
    );
    assert_eq!(std::fs::read(mine.join("notes.txt")).unwrap(), b"mine");
    export(&scene, &obj, &["--resolution", "64", "--force"]);

    let dirs = [&cap, &obj, &ply, &glb, &pts, &mjcf, &urdf].map(|p| p.as_os_str());
    common::python_check("export_check.py", &dirs, "trimesh and mujoco");
}
