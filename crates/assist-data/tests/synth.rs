//! The built-in scene generator: format, determinism, multi-view consistency, boxes that
//! contain their objects, and edits that do what edit.json says.

use assist_core::DVec3;
use assist_data::consistency::reproject;
use assist_data::image_io::{read_depth_png, read_ids};
use assist_data::synth::{CameraPath, SynthConfig, generate};
use assist_data::{LoadOptions, Split, load};
use assist_testkit::TempDir;

fn small(seed: u64) -> SynthConfig {
    SynthConfig {
        seed,
        views: 24,
        width: 96,
        height: 72,
        objects: 4,
        spp: 2,
        shadow_samples: 2,
        path: CameraPath::Spiral,
    }
}

#[test]
fn a_walk_goes_once_around_the_table_in_small_steps() {
    let mut rng = assist_core::Rng::new(3);
    let cams = assist_data::synth::scene::cameras(&mut rng, 48, 64, 48, CameraPath::Walk);
    let centres: Vec<DVec3> = cams.iter().map(|c| c.pose.center()).collect();
    let mut turned = 0.0;
    for (k, c) in centres.iter().enumerate() {
        let next = centres[(k + 1) % centres.len()];
        // Neighbours (the last and the first too) a few centimetres apart.
        assert!(c.distance(next) < 0.15, "{k}: {}", c.distance(next));
        let (a, b) = (c.y.atan2(c.x), next.y.atan2(next.x));
        turned +=
            (b - a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        // Every camera looks at the table's centre, from above.
        assert!(c.z > 0.9 && cams[k].pose.forward().z < -0.3, "{k}: {c}");
    }
    assert!(
        (turned - std::f64::consts::TAU).abs() < 1e-6,
        "turned {turned}"
    );
}

#[test]
fn writes_a_valid_desk_format_dataset() {
    let tmp = TempDir::new("synth-valid");
    let out = tmp.join("scene");
    let s = generate(&small(1), &out, false, &|_, _| {}).unwrap();
    assert_eq!((s.views, s.train, s.test), (24, 20, 4));
    let ds = load(&out, &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 24);
    assert_eq!(ds.count(Split::Test), 4);
    assert_eq!(ds.instances.len(), 4);
    assert_eq!(ds.meters_per_unit, Some(1.0));
    // Marked as rendered, so training takes no appearance codes by default.
    assert!(ds.rendered);
    let report = assist_data::validate::validate(&ds);
    assert!(report.errors.is_empty(), "{:?}", report.errors);
    assert!(report.undeclared_ids.is_empty());
    // Every declared object is seen in some view.
    let mut seen = std::collections::BTreeSet::new();
    for f in &ds.frames {
        seen.extend(
            read_ids(f.instance_mask_path.as_ref().unwrap())
                .unwrap()
                .data
                .into_iter()
                .filter(|&v| v > 0),
        );
    }
    assert_eq!(seen.len(), 4, "objects seen: {seen:?}");
    // background/ and three edits, each a loadable dataset over the test views.
    let bg = load(&out.join("background"), &LoadOptions::default()).unwrap();
    assert_eq!(bg.frames.len(), 4);
    assert_eq!(s.edits.len(), 3);
    for e in &s.edits {
        let ed = load(&out.join("edits").join(e), &LoadOptions::default()).unwrap();
        assert_eq!(ed.frames.len(), 4);
        assert!(assist_data::validate::validate(&ed).errors.is_empty());
    }
    // Refuses to overwrite without force; replaces with force.
    let err = generate(&small(1), &out, false, &|_, _| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("--force"), "{err}");
    generate(&small(2), &out, true, &|_, _| {}).unwrap();
}

#[test]
fn deterministic_for_a_seed() {
    let tmp = TempDir::new("synth-det");
    let mut cfg = small(7);
    cfg.views = 6;
    generate(&cfg, &tmp.join("a"), false, &|_, _| {}).unwrap();
    generate(&cfg, &tmp.join("b"), false, &|_, _| {}).unwrap();
    cfg.seed = 8;
    generate(&cfg, &tmp.join("c"), false, &|_, _| {}).unwrap();
    for f in [
        "transforms.json",
        "images/r_000.png",
        "depth/r_003.png",
        "instances/r_005.png",
        "background/images/r_003.png",
    ] {
        let a = std::fs::read(tmp.join("a").join(f)).unwrap();
        assert_eq!(
            a,
            std::fs::read(tmp.join("b").join(f)).unwrap(),
            "{f} differs for the same seed"
        );
    }
    assert_ne!(
        std::fs::read(tmp.join("a/images/r_000.png")).unwrap(),
        std::fs::read(tmp.join("c/images/r_000.png")).unwrap()
    );
}

/// Threshold: median |ΔRGB| below 4/255 over depth-consistent pixels (colour is
/// anti-aliased and noisy at 2 spp; depth is sampled at pixel centres), ≥ 70% consistent.
#[test]
fn depth_reprojects_between_views_with_matching_colour() {
    let tmp = TempDir::new("synth-reproj");
    let mut cfg = small(3);
    cfg.spp = 16;
    cfg.shadow_samples = 4;
    cfg.width = 128;
    cfg.height = 96;
    generate(&cfg, &tmp.join("s"), false, &|_, _| {}).unwrap();
    let ds = load(&tmp.join("s"), &LoadOptions::default()).unwrap();
    for a in [0, 5, 10, 20] {
        // The nearest other camera (views on a Fibonacci spiral: neighbours are not index
        // neighbours).
        let ca = ds.frames[a].camera.pose.center();
        let b = (0..ds.frames.len())
            .filter(|&b| b != a)
            .min_by(|&x, &y| {
                let dx = (ds.frames[x].camera.pose.center() - ca).length();
                let dy = (ds.frames[y].camera.pose.center() - ca).length();
                dx.total_cmp(&dy)
            })
            .unwrap();
        let r = reproject(&ds, a, b, 2, None).unwrap();
        eprintln!(
            "synth {a}->{b}: {r:?} median |dRGB| {:.2}/255",
            r.median_abs_rgb * 255.0
        );
        assert!(
            r.depth_consistent > 300 && r.consistent_fraction() > 0.7,
            "{a}->{b}: {r:?}"
        );
        assert!(r.median_abs_rgb < 4.0 / 255.0, "{a}->{b}: {r:?}");
    }
}

/// Every pixel of instance k, back-projected with its depth, lies in box k (1 mm + half a
/// millimetre of depth quantisation); and an edit's masks lie in the edited boxes.
#[test]
fn masks_lie_in_their_boxes_before_and_after_edits() {
    let tmp = TempDir::new("synth-boxes");
    let s = generate(&small(4), &tmp.join("s"), false, &|_, _| {}).unwrap();
    let mut dirs = vec![tmp.join("s")];
    dirs.extend(s.edits.iter().map(|e| tmp.join("s/edits").join(e)));
    for dir in dirs {
        let ds = load(&dir, &LoadOptions::default()).unwrap();
        let mut checked = 0;
        for f in &ds.frames {
            let ids = read_ids(f.instance_mask_path.as_ref().unwrap()).unwrap();
            let depth = read_depth_png(f.depth_path.as_ref().unwrap(), f.depth_scale).unwrap();
            for j in 0..ids.height {
                for i in 0..ids.width {
                    let k = (j * ids.width + i) as usize;
                    let id = ids.data[k];
                    if id == 0 {
                        continue;
                    }
                    let inst = ds
                        .instance(id)
                        .unwrap_or_else(|| panic!("{}: undeclared id {id}", dir.display()));
                    let p = f
                        .camera
                        .unproject(i as f64 + 0.5, j as f64 + 0.5, depth.data[k] as f64)
                        .unwrap();
                    let tol = 0.0015
                        / f.camera
                            .pose
                            .forward()
                            .dot((p - f.camera.pose.center()).normalize())
                            .abs()
                            .max(0.2);
                    assert!(
                        inst.bbox.unwrap().contains(p, tol),
                        "{}: pixel ({i},{j}) of id {id} outside its box",
                        dir.display()
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 100, "{}: {checked}", dir.display());
    }
    // The delete edit removed its instance from the masks and from the box list.
    let del = s.edits.iter().find(|e| e.starts_with("delete_")).unwrap();
    let edit: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.join("s/edits").join(del).join("edit.json")).unwrap(),
    )
    .unwrap();
    let gone = edit["instance_id"].as_u64().unwrap() as u16;
    let ds = load(&tmp.join("s/edits").join(del), &LoadOptions::default()).unwrap();
    assert!(ds.instance(gone).is_none());
    for f in &ds.frames {
        assert!(
            !read_ids(f.instance_mask_path.as_ref().unwrap())
                .unwrap()
                .data
                .contains(&gone)
        );
    }
    // The translate edit moved the box by its offset.
    let tr = s
        .edits
        .iter()
        .find(|e| e.starts_with("translate_"))
        .unwrap();
    let edit: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.join("s/edits").join(tr).join("edit.json")).unwrap(),
    )
    .unwrap();
    let id = edit["instance_id"].as_u64().unwrap() as u16;
    let off: Vec<f64> = edit["config"]["offset"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let before = load(&tmp.join("s"), &LoadOptions::default())
        .unwrap()
        .instance(id)
        .unwrap()
        .bbox
        .unwrap()
        .center;
    let after = ds_instance_center(&tmp.join("s/edits").join(tr), id);
    assert!((after - before - DVec3::new(off[0], off[1], off[2])).length() < 1e-9);
}

fn ds_instance_center(dir: &std::path::Path, id: u16) -> DVec3 {
    load(dir, &LoadOptions::default())
        .unwrap()
        .instance(id)
        .unwrap()
        .bbox
        .unwrap()
        .center
}
