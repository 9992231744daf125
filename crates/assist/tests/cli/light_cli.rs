//! `assist scene light`: the lamp found from a scene's shadow grids, written with each
//! object's cast; on an edited scene, each object's cast is where it stood before the edit.

use std::sync::Arc;

use crate::common::*;
use assist_core::{DVec3, KeyLight};
use assist_field::{OccupancyGrid, ShadeGrid};
use assist_render::light::{Occluder, light_points};

/// `write_scene`'s duck and mug made opaque cubes standing on z = 0.75, with the shadow
/// grids a lamp casts (at the lattice points near the table).
fn lit_scene(dir: &std::path::Path) {
    write_scene(dir);
    let (mut scene, _) = assist_scene::scene_file::load(dir).unwrap();
    let lamp = KeyLight {
        position: DVec3::new(0.6, -0.5, 2.2),
        radius: 0.1,
    };
    let lights = light_points(&lamp, DVec3::Z);
    for i in 1..scene.scene.nodes.len() {
        let n = scene.scene.nodes[i].clone();
        let mut occ = OccupancyGrid::new(8);
        occ.density = vec![1e4; 512];
        let o = Occluder {
            occupancy: &occ,
            half_size: n.half_size,
            pose: &n.world_from_local,
        };
        let res = 24;
        let mut g = ShadeGrid::new(res, 3.0);
        let c = |i: usize| (i as f64 / (res - 1) as f64 * 2.0 - 1.0) * 3.0;
        for k in 0..res * res * res {
            let b = DVec3::new(c(k % res), c(k / res % res), c(k / (res * res)));
            let p = n.world_from_local.transform_point(b * n.half_size);
            if (p.z - 0.75).abs() > 0.02 {
                continue;
            }
            let v = o.visibility(p, &lights);
            let jitter = 0.001 * (k % 7) as f32;
            for ch in 0..3 {
                g.values[3 * k + ch] = 1.0 - 0.5 * (1.0 - v) - jitter;
            }
        }
        let nf = Arc::make_mut(scene.fields.get_mut(&n.field).unwrap());
        nf.occupancy = occ;
        nf.shade = Some(g);
    }
    assist_scene::scene_file::save(dir, &scene, serde_json::Value::Null, true).unwrap();
}

fn scene_json(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("scene.json")).unwrap()).unwrap()
}

#[test]
fn scene_light_finds_the_lamp_and_edits_keep_where_shadows_were_learned() {
    let tmp = assist_testkit::TempDir::new("cli-light");
    let (a, b, c, d) = (
        tmp.path().join("a.assist"),
        tmp.path().join("b.assist"),
        tmp.path().join("c.assist"),
        tmp.path().join("d.assist"),
    );
    lit_scene(&a);
    let o = run(&["scene", "light", s(&a), "--out", s(&b), "--json"]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let p = &v["light"]["light"]["position"];
    assert!(p.is_array(), "{v}");
    let scene = scene_json(&b);
    assert_eq!(scene["light"]["position"], *p);
    for n in scene["nodes"].as_array().unwrap().iter().skip(1) {
        let k = n["cast"]["strength"][0].as_f64().unwrap();
        assert!((k - 0.5).abs() < 0.15, "{n}");
        assert_eq!(n["cast"]["pose"], n["world_from_local"]);
    }
    // The lamp's direction from the objects (0, 0, 0.8) as made.
    let dir = DVec3::new(
        p[0].as_f64().unwrap(),
        p[1].as_f64().unwrap(),
        p[2].as_f64().unwrap() - 0.8,
    );
    let angle = dir.angle_between(DVec3::new(0.6, -0.5, 1.4)).to_degrees();
    assert!(angle < 10.0, "{angle}° off: {v}");
    // `scene info` tells it.
    let info = String::from_utf8_lossy(&run(&["scene", "info", s(&b)]).stdout).into_owned();
    assert!(info.contains("key light: at"), "{info}");
    let info = String::from_utf8_lossy(&run(&["scene", "info", s(&a)]).stdout).into_owned();
    assert!(info.contains("key light: none"), "{info}");
    // An existing output is refused without --force, and left as it was.
    let before = std::fs::read(b.join("scene.json")).unwrap();
    refused(
        &run(&["scene", "light", s(&a), "--out", s(&b)]),
        &["--force"],
    );
    assert_eq!(before, std::fs::read(b.join("scene.json")).unwrap());

    // Edited before the light was found: the mug's shadow was learned where it stood.
    let script = tmp.path().join("edit.json");
    std::fs::write(
        &script,
        r#"{"instance_id": 3, "operation": "translate", "config": {"offset": [-0.1, 0.1, 0.0]}}"#,
    )
    .unwrap();
    ok(&run(&[
        "edit",
        s(&a),
        "--actions",
        s(&script),
        "--out",
        s(&c),
    ]));
    let o = run(&["scene", "light", s(&c), "--out", s(&d)]);
    ok(&o);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("key light: at"), "{text}");
    let edited = scene_json(&d);
    let mug = &edited["nodes"][2];
    assert_eq!(mug["cast"]["pose"], scene["nodes"][2]["world_from_local"]);
    assert_ne!(mug["cast"]["pose"], mug["world_from_local"]);
    // The same light as on the unedited scene, and undo keeps it.
    assert_eq!(edited["light"], scene["light"]);
    let e = tmp.path().join("e.assist");
    ok(&run(&["edit", s(&d), "--undo", "1", "--out", s(&e)]));
    let undone = scene_json(&e);
    assert_eq!(undone["light"], scene["light"]);
    assert_eq!(undone["nodes"][2]["cast"], mug["cast"]);

    // Relighting is the scene's: set, told by `scene info`, kept by an undo, set off.
    let (f, g) = (tmp.path().join("f.assist"), tmp.path().join("g.assist"));
    ok(&run(&[
        "scene",
        "light",
        s(&d),
        "--out",
        s(&f),
        "--relight",
        "on",
    ]));
    assert_eq!(scene_json(&f)["relight"], true);
    let info = String::from_utf8_lossy(&run(&["scene", "info", s(&f)]).stdout).into_owned();
    assert!(info.contains("shaded by it where they stand"), "{info}");
    ok(&run(&["edit", s(&f), "--undo", "1", "--out", s(&g)]));
    assert_eq!(scene_json(&g)["relight"], true);
    let off = ["scene", "light", s(&g), "--out", s(&g), "--force"];
    ok(&run(&[&off[..], &["--relight", "off"]].concat()));
    assert!(scene_json(&g).get("relight").is_none());
    // A bad value is a usage error naming the flag and its values.
    let o = run(&[&off[..], &["--relight", "maybe"]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--relight") && err.contains("on, off"),
        "{err}"
    );

    // Bad values in a scene file are named, nothing is written, and nothing panics.
    for (field, value, what) in [
        (
            "light",
            serde_json::json!({"position": [0.0, 0.0, 1.0], "radius": -1.0}),
            "light.radius",
        ),
        (
            "cast",
            serde_json::json!({"pose": mug["cast"]["pose"], "strength": [0.5, 2.0, 0.5]}),
            "cast.strength",
        ),
    ] {
        let bad = tmp.path().join(format!("bad-{field}.assist"));
        let out = tmp.path().join(format!("bad-{field}-out.assist"));
        ok(&run(&["scene", "light", s(&a), "--out", s(&bad)]));
        let mut j = scene_json(&bad);
        if field == "light" {
            j["light"] = value;
        } else {
            j["nodes"][2]["cast"] = value;
        }
        std::fs::write(bad.join("scene.json"), serde_json::to_vec(&j).unwrap()).unwrap();
        let err = refused(
            &run(&["scene", "light", s(&bad), "--out", s(&out)]),
            &["scene.json", what],
        );
        assert!(!out.exists(), "{err}");
    }
}
