//! Editing scene nodes, checked by rendering: masks move by the projected offset, identity
//! edits change nothing, delete reveals the background, replicas share weights, nodes come
//! in from other scenes where placed, swaps exchange masks, undo restores the file exactly.

mod common;

use std::path::Path;
use std::sync::Arc;

use assist_core::{Action, Camera, DVec3, Intrinsics, Pose, Similarity3};
use assist_render::{RenderOptions, RenderedImage, render_camera};
use assist_scene::{Editor, NeuralScene, scene_file};
use common::{constant_field, node, scene};

const GREY: [f32; 3] = [0.5, 0.5, 0.5];
const W: u32 = 128;

/// A grey floor (the background node, top face at z = −0.2) with a red cube (id 1) and a
/// view-dependent cube (id 2) standing on it.
fn base() -> NeuralScene {
    let bg = node(
        0,
        "bg",
        2.0,
        Similarity3::from_translation(DVec3::new(0.0, 0.0, -2.2)),
    );
    let a = node(
        1,
        "red",
        0.25,
        Similarity3::from_translation(DVec3::new(-0.6, 0.0, 0.05)),
    );
    let b = node(
        2,
        "shiny",
        0.25,
        Similarity3::from_translation(DVec3::new(0.6, 0.0, 0.05)),
    );
    scene(
        vec![bg, a, b],
        vec![
            ("bg", constant_field(200.0, GREY, false, 1)),
            ("red", constant_field(200.0, [0.9, 0.1, 0.1], false, 2)),
            ("shiny", constant_field(200.0, [0.0; 3], true, 3)),
        ],
        0.0,
    )
}

fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics::from_fov_x(W, W, 10f64.to_radians()),
        pose: Pose::look_at(DVec3::new(0.0, 0.0, 20.0), DVec3::ZERO, DVec3::Y).unwrap(),
    }
}

fn render(s: &NeuralScene) -> RenderedImage {
    render_camera(s, &camera(), u32::MAX, &RenderOptions::default())
}

fn act(json: &str) -> Action {
    serde_json::from_str(json).unwrap()
}

/// Mean pixel position and pixel count of instance `id`.
fn centroid(img: &RenderedImage, id: u16) -> (f64, f64, usize) {
    let (mut x, mut y, mut n) = (0.0, 0.0, 0usize);
    for (k, &p) in img.panoptic.iter().enumerate() {
        if p == id {
            x += (k % img.width as usize) as f64 + 0.5;
            y += (k / img.width as usize) as f64 + 0.5;
            n += 1;
        }
    }
    (x / n.max(1) as f64, y / n.max(1) as f64, n)
}

fn max_rgb_diff(a: &RenderedImage, b: &RenderedImage) -> f32 {
    a.rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn translating_moves_the_mask_by_the_projected_offset() {
    let mut ed = Editor::new(base());
    let before = render(&ed.scene);
    let (x0, y0, n0) = centroid(&before, 1);
    assert!(n0 > 100, "cube 1 covers {n0} pixels");
    ed.apply_all(&[act(r#"{"instance_id":1,"operation":"translate","config":{"vector":[0.4,0.25,0],"unit":"units"}}"#)])
        .unwrap();
    let after = render(&ed.scene);
    let (x1, y1, n1) = centroid(&after, 1);
    let cam = camera();
    let p0 = cam.project(DVec3::new(-0.6, 0.0, 0.05)).unwrap().0;
    let p1 = cam.project(DVec3::new(-0.2, 0.25, 0.05)).unwrap().0;
    let (dx, dy) = (x1 - x0, y1 - y0);
    let (ex, ey) = (p1.x - p0.x, p1.y - p0.y);
    assert!(
        (dx - ex).abs() < 0.6 && (dy - ey).abs() < 0.6,
        "mask moved ({dx:.2}, {dy:.2}) px, projected offset ({ex:.2}, {ey:.2}) px"
    );
    assert!(
        ex.abs() > 5.0 && ey.abs() > 3.0,
        "the offset must be visible"
    );
    assert!((n1 as f64 - n0 as f64).abs() < 0.1 * n0 as f64);
}

#[test]
fn full_turns_and_unit_scales_change_nothing() {
    let mut ed = Editor::new(base());
    let before = render(&ed.scene);
    ed.apply_all(&[
        act(r#"{"instance_id":2,"operation":"rotate","config":{"axis":"z","degrees":360}}"#),
        act(r#"{"instance_id":2,"operation":"rotate","config":{"axis":[1,1,0],"angle":6.283185307179586,"unit":"rad"}}"#),
        act(r#"{"instance_id":2,"operation":"scale","config":{"factor":1}}"#),
        act(r#"{"instance_id":1,"operation":"scale","config":{"factors":[1,1,1]}}"#),
    ])
    .unwrap();
    let after = render(&ed.scene);
    assert!(
        max_rgb_diff(&before, &after) < 1e-4,
        "diff {}",
        max_rgb_diff(&before, &after)
    );
    assert_eq!(before.panoptic, after.panoptic);
    // The same check can fail: a quarter turn of the view-dependent cube changes its colours.
    ed.apply_all(&[act(
        r#"{"instance_id":2,"operation":"rotate","config":{"axis":"x","degrees":90}}"#,
    )])
    .unwrap();
    assert!(max_rgb_diff(&before, &render(&ed.scene)) > 1e-2);
}

#[test]
fn delete_removes_the_mask_and_reveals_the_background() {
    let mut ed = Editor::new(base());
    let before = render(&ed.scene);
    ed.apply_all(&[act(r#"{"instance_id":1,"operation":"delete","config":{}}"#)])
        .unwrap();
    let after = render(&ed.scene);
    assert_eq!(centroid(&after, 1).2, 0);
    let mut revealed = 0;
    for (k, &p) in before.panoptic.iter().enumerate() {
        if p == 1 {
            assert_eq!(after.panoptic[k], 0, "pixel {k}");
            for c in 0..3 {
                assert!(
                    (after.rgb[k * 3 + c] - GREY[c]).abs() < 0.02,
                    "pixel {k} is not background"
                );
            }
            revealed += 1;
        }
    }
    assert!(revealed > 100);
}

#[test]
fn replicate_adds_a_mask_with_a_new_id_and_no_new_weights() {
    let mut ed = Editor::new(base());
    let fields_before = ed.scene.fields.len();
    let original = Arc::clone(&ed.scene.fields["shiny"]);
    let edits = ed
        .apply_all(&[act(
            r#"{"instance_id":2,"operation":"replicate","config":{}}"#,
        )])
        .unwrap();
    let new_id = edits[0].created().unwrap();
    assert_eq!(new_id, 3);
    assert_eq!(ed.scene.fields.len(), fields_before, "no new field");
    let copy = ed.scene.scene.node(3).unwrap();
    assert_eq!(copy.field, "shiny");
    assert!(Arc::ptr_eq(&original, &ed.scene.fields["shiny"]));
    // Both strong counts: the editor's map and `original` — nothing else holds a copy.
    assert_eq!(Arc::strong_count(&original), 2);
    let img = render(&ed.scene);
    let (_, _, n2) = centroid(&img, 2);
    let (_, _, n3) = centroid(&img, 3);
    assert!(
        n2 > 100 && n3 > 100,
        "masks: original {n2} px, copy {n3} px"
    );
}

#[test]
fn swap_exchanges_masks() {
    let mut ed = Editor::new(base());
    let before = render(&ed.scene);
    ed.apply_all(&[act(
        r#"{"instance_id":1,"operation":"swap","config":{"with":2}}"#,
    )])
    .unwrap();
    let after = render(&ed.scene);
    let mut wrong = 0;
    let mut counted = 0;
    for (k, &p) in before.panoptic.iter().enumerate() {
        let want = match p {
            1 => 2,
            2 => 1,
            o => o,
        };
        counted += usize::from(p != 0);
        wrong += usize::from(after.panoptic[k] != want);
    }
    assert!(counted > 200);
    assert!(
        wrong * 100 <= counted,
        "{wrong} of {counted} object pixels did not swap"
    );
}

/// A second scene, in units of half a metre, holding a cube labelled "mic".
fn other_scene(dir: &Path) {
    let mut mic = node(
        1,
        "mic",
        0.25,
        Similarity3::from_translation(DVec3::new(2.0, 2.0, 2.0)),
    );
    mic.label = "mic".into();
    // Every scene has a background node; this one is empty.
    let mut bg = node(0, "room", 4.0, Similarity3::IDENTITY);
    bg.label = "background".into();
    let mut s = scene(
        vec![bg, mic],
        vec![
            ("room", constant_field(0.01, [0.5; 3], false, 8)),
            ("mic", constant_field(200.0, [0.1, 0.2, 0.9], false, 9)),
        ],
        0.0,
    );
    s.scene.meters_per_unit = 0.5;
    scene_file::save(dir, &s, serde_json::Value::Null, true).unwrap();
}

#[test]
fn cross_scene_add_renders_the_node_where_placed() {
    let tmp = assist_testkit::TempDir::new("edit-add");
    let other = tmp.path().join("other.assist");
    other_scene(&other);
    let mut ed = Editor::new(base());
    let path = other.to_string_lossy().to_string();
    let a: Action = serde_json::from_value(serde_json::json!({
        "instance_id": 0, "operation": "add",
        "config": {"scene": path, "node": "mic", "position": [0.0, 0.7, 0.0], "unit": "m"}
    }))
    .unwrap();
    let edits = ed.apply_all(&[a]).unwrap();
    let id = edits[0].created().unwrap();
    let n = ed.scene.scene.node(id).unwrap().clone();
    // Re-expressed in this scene's metres: the 0.4-unit cube is 0.2 m here.
    assert!((n.world_from_local.scale - DVec3::splat(0.5)).length() < 1e-12);
    let img = render(&ed.scene);
    let (x, y, count) = centroid(&img, id);
    let p = camera().project(DVec3::new(0.0, 0.7, 0.0)).unwrap().0;
    assert!(
        (x - p.x).abs() < 0.6 && (y - p.y).abs() < 0.6,
        "at ({x:.1}, {y:.1}), placed at ({:.1}, {:.1})",
        p.x,
        p.y
    );
    let (_, _, red) = centroid(&img, 1);
    let ratio = count as f64 / red as f64;
    assert!(
        (ratio - 0.25).abs() < 0.06,
        "area ratio {ratio} (expected about 1/4)"
    );
    // Its colour comes from the other scene's weights.
    let k = (y as usize) * W as usize + x as usize;
    assert!(
        img.rgb[k * 3 + 2] > 0.8 && img.rgb[k * 3] < 0.2,
        "{:?}",
        &img.rgb[k * 3..k * 3 + 3]
    );
}

fn read_dir_files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().to_string(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn undo_restores_the_exact_scene_file_and_redo_the_edit() {
    let tmp = assist_testkit::TempDir::new("edit-undo");
    let (d1, d2, d3, d4) = (
        tmp.path().join("a.assist"),
        tmp.path().join("b.assist"),
        tmp.path().join("c.assist"),
        tmp.path().join("d.assist"),
    );
    let other = tmp.path().join("other.assist");
    other_scene(&other);
    scene_file::save(&d1, &base(), serde_json::json!({"note": "original"}), false).unwrap();
    let mut ed = Editor::open(&d1).unwrap();
    let script = format!(
        r#"{{"instance_id":1,"operation":"translate","config":{{"axis":"x","distance":12,"unit":"cm"}}}}
{{"instance_id":2,"operation":"rotate","config":{{"axis":"z","angle":30}}}}
{{"instance_id":2,"operation":"replicate","config":{{}}}}
{{"instance_id":0,"operation":"add","config":{{"scene":{:?},"node":1}}}}
{{"instance_id":2,"operation":"delete","config":{{}}}}"#,
        other.to_string_lossy()
    );
    let actions: Vec<Action> = script
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    ed.apply_all(&actions).unwrap();
    ed.save(&d2, false).unwrap();
    let mut ed = Editor::open(&d2).unwrap();
    assert_eq!(ed.history.undo.len(), 5);
    for _ in 0..5 {
        assert!(ed.undo());
    }
    assert!(!ed.undo(), "nothing more to undo");
    ed.save(&d3, false).unwrap();
    assert_eq!(
        std::fs::read(d1.join("scene.json")).unwrap(),
        std::fs::read(d3.join("scene.json")).unwrap(),
        "undo must restore scene.json byte for byte"
    );
    for (name, bytes) in read_dir_files(&d1.join("fields")) {
        let restored = std::fs::read(d3.join("fields").join(&name)).unwrap();
        let first_diff = bytes.iter().zip(&restored).position(|(a, b)| a != b);
        assert!(
            restored == bytes,
            "fields/{name}: {} vs {} bytes, first difference at {first_diff:?}: {:?} vs {:?}",
            bytes.len(),
            restored.len(),
            String::from_utf8_lossy(&bytes[..300.min(bytes.len())]),
            String::from_utf8_lossy(&restored[..300.min(restored.len())])
        );
    }
    for _ in 0..5 {
        assert!(ed.redo());
    }
    ed.save(&d4, false).unwrap();
    assert_eq!(
        std::fs::read(d2.join("scene.json")).unwrap(),
        std::fs::read(d4.join("scene.json")).unwrap()
    );
}

#[test]
fn bad_actions_are_refused_and_change_nothing() {
    let tmp = assist_testkit::TempDir::new("edit-bad");
    let mut ed = Editor::new(base());
    let before = ed.scene.scene.clone();
    let missing = tmp.path().join("missing.assist");
    let cases = [
        (
            serde_json::json!({"instance_id": 0, "operation": "add", "config": {"scene": missing.to_string_lossy(), "node": 1}}),
            "missing.assist",
        ),
        (
            serde_json::json!({"instance_id": 42, "operation": "delete", "config": {}}),
            "instance_id 42: no such node",
        ),
        (
            serde_json::json!({"instance_id": 1, "operation": "scale", "config": {"factor": 0.0}}),
            "factor > 0",
        ),
        (
            serde_json::json!({"instance_id": 1, "operation": "translate", "config": {"axis": "x"}}),
            "distance",
        ),
        (
            serde_json::json!({"instance_id": 0, "operation": "delete", "config": {}}),
            "background",
        ),
    ];
    for (json, want) in cases {
        let a: Action = serde_json::from_value(json.clone()).unwrap();
        // A valid edit first: all or nothing means it must not stay applied either.
        let ok = act(r#"{"instance_id":1,"operation":"translate","config":{"vector":[1,0,0]}}"#);
        let e = ed.apply_all(&[ok, a]).unwrap_err().to_string();
        assert!(
            e.contains(want),
            "{json}: error {e:?} does not say {want:?}"
        );
        assert_eq!(ed.scene.scene, before, "{json}: the scene changed");
        assert!(ed.history.is_empty());
    }
    // Another format version.
    let other = tmp.path().join("v99.assist");
    other_scene(&other);
    let text = std::fs::read_to_string(other.join("scene.json"))
        .unwrap()
        .replace("\"version\": 1", "\"version\": 99");
    std::fs::write(other.join("scene.json"), text).unwrap();
    let a: Action = serde_json::from_value(serde_json::json!({"instance_id": 0, "operation": "add", "config": {"scene": other.to_string_lossy(), "node": 1}})).unwrap();
    let e = ed.apply_all(&[a]).unwrap_err().to_string();
    assert!(e.contains("version") && e.contains("99"), "{e}");
    // Unknown fields are refused when the JSON is read.
    let e = serde_json::from_str::<Action>(
        r#"{"instance_id":1,"operation":"translate","config":{"distanse":1}}"#,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("distanse"), "{e}");
}

/// A drag under a fixed camera re-renders only the moving node, and gives exactly what a
/// full render of the edited scene gives; anything else changing (another node, the
/// camera) renders everything again.
#[test]
fn a_drag_rerenders_the_moving_node_alone_and_bit_for_bit() {
    drag_bit_for_bit(false, false);
    // A node that casts a shadow moves it: the floor's shading changes with the drag.
    drag_bit_for_bit(true, false);
    // Under a key light, with a second caster: the moved node's shadow is re-cast at
    // every step, and where the two regions overlap the factors multiply.
    drag_bit_for_bit(true, true);
    // Three casters whose shadows overlap where the moved one's falls: a sample that two
    // others shade gets the whole product again, one that one other shades the product
    // of two factors.
    drag_bit_for_bit_at(true, true, true, 0.0, false);
}

/// The same with the scene relighting moved objects: the moved node's colours change
/// with its pose at every update, as a full render's do.
#[test]
fn a_relit_drag_is_bit_for_bit_too() {
    RELIGHT.with(|r| r.set(true));
    drag_bit_for_bit_at(true, true, false, 0.0, false);
}

thread_local! {
    static RELIGHT: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn drag_bit_for_bit(shadow: bool, lit: bool) {
    // f32 without pruning; and pruned (each ray by each node's own density) on the packed
    // tables a session renders with.
    for (eps, packed) in [(0.0, false), (1e-4, true)] {
        drag_bit_for_bit_at(shadow, lit, false, eps, packed);
    }
}

/// The red cube casts a shadow on the floor (half of its grid shades nothing, as in
/// trained grids, the rest varies); `lit`: under a key light, the shiny cube casting too,
/// moved since its shadow was learned.
fn cast_shadows(s: &mut NeuralScene, lit: bool) {
    // Half of the region shades nothing (factors exactly 1, as in trained grids,
    // which a drag skips), the rest varies.
    let mut g = assist_field::ShadeGrid::new(5, 2.5);
    for (i, v) in g.values.iter_mut().enumerate() {
        let x = (i / 3) % 5;
        *v = if x <= 2 {
            1.0
        } else {
            0.3 + 0.07 * (i % 10) as f32
        };
    }
    Arc::make_mut(s.fields.get_mut("red").unwrap()).shade = Some(g.clone());
    if lit {
        let key = s.scene.nodes[2].field.clone();
        Arc::make_mut(s.fields.get_mut(&key).unwrap()).shade = Some(g);
        s.scene.light = Some(assist_core::KeyLight {
            position: s.scene.nodes[1].world_from_local.translation
                + assist_core::DVec3::new(0.5, -0.3, 1.5),
            radius: 0.2,
        });
        s.scene.nodes[1].cast = Some(assist_core::ShadowCast {
            pose: s.scene.nodes[1].world_from_local,
            strength: [0.6, 0.5, 0.4],
        });
        // The other caster was moved since its shadow was learned: its grid is
        // re-cast under the light too.
        let mut learned_at = s.scene.nodes[2].world_from_local;
        learned_at.translation.x += 0.05;
        s.scene.nodes[2].cast = Some(assist_core::ShadowCast {
            pose: learned_at,
            strength: [0.5, 0.5, 0.5],
        });
        s.scene.relight = RELIGHT.with(|r| r.get());
    }
}

fn drag_bit_for_bit_at(shadow: bool, lit: bool, crowded: bool, prune_eps: f32, packed: bool) {
    use assist_render::{DragCache, render_camera_moving};
    let mut s = base();
    if shadow {
        cast_shadows(&mut s, lit);
        if crowded {
            // The shiny cube beside the red one, and a third red one behind both: the
            // shading halves of all three regions overlap.
            s.scene.nodes[2].world_from_local.translation.x = -0.3;
            let at = DVec3::new(-0.45, 0.25, 0.05);
            let mut third = node(3, "red", 0.25, Similarity3::from_translation(at));
            third.label = "third".into();
            s.scene.nodes.push(third);
        }
    }
    // Half the width of the other tests' views: 32 pixels across each shadow region, and
    // the seven configurations below render about a hundred frames.
    let cam = Camera {
        intrinsics: Intrinsics::from_fov_x(W / 2, W / 2, 10f64.to_radians()),
        ..camera()
    };
    let opts = RenderOptions {
        rays_per_batch: 4096,
        prune_eps,
        precision: assist_field::Precision::Bf16,
        tables: packed.then(|| Arc::new(assist_render::SceneTables::of(&s))),
        ..RenderOptions::default()
    };
    let mut cache = DragCache::default();
    let first = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
    assert!(cache.is_warm());
    let plain = render_camera(&s, &cam, u32::MAX, &opts);
    assert_eq!(first.rgb, plain.rgb);
    for step in 1..=3 {
        s.scene.nodes[1].world_from_local.translation.y += 0.1 * step as f64;
        let cached = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
        let full = render_camera(&s, &cam, u32::MAX, &opts);
        assert_eq!(cached.rgb, full.rgb, "step {step}");
        assert_eq!(cached.depth, full.depth, "step {step}");
        assert_eq!(cached.panoptic, full.panoptic, "step {step}");
        assert_ne!(cached.panoptic, first.panoptic, "the node moved");
    }
    if lit {
        // The re-cast shadow shows.
        let mut unlit = s.clone();
        unlit.scene.light = None;
        assert_ne!(
            render_camera(&unlit, &cam, u32::MAX, &opts).rgb,
            render_camera(&s, &cam, u32::MAX, &opts).rgb
        );
        if s.scene.relight {
            // So does the moved node's new shading.
            let mut baked = s.clone();
            baked.scene.relight = false;
            assert_ne!(
                render_camera(&baked, &cam, u32::MAX, &opts).rgb,
                render_camera(&s, &cam, u32::MAX, &opts).rgb
            );
        }
        // A light moved between two updates of the same drag re-casts every shadow.
        let mut light = s.scene.light.unwrap();
        light.position += assist_core::DVec3::new(1.0, 0.6, -0.6);
        s.scene.light = Some(light);
        let cached = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
        assert_eq!(cached.rgb, render_camera(&s, &cam, u32::MAX, &opts).rgb);
    }
    // Another node moving invalidates the cache: still the same image as a full render.
    s.scene.nodes[2].world_from_local.translation.x -= 0.2;
    let cached = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
    assert_eq!(cached.rgb, render_camera(&s, &cam, u32::MAX, &opts).rgb);
    // So does a deleted moving node.
    s.scene.nodes.remove(1);
    let cached = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
    assert!(!cache.is_warm());
    assert_eq!(cached.rgb, render_camera(&s, &cam, u32::MAX, &opts).rgb);
}

/// The background alone, taken from the samples of the full render (one pass), is the
/// render of the scene without its objects, bit for bit: with the objects' shadows on the
/// floor and a key light (which darken only the full image), over a colour or the last
/// sample (rays that miss the floor show what no view saw, filled), pruned on the packed
/// tables or not.
#[test]
fn the_background_alone_comes_from_the_same_pass_bit_for_bit() {
    // Wide enough that the corner rays miss the floor.
    let cam = Camera {
        intrinsics: Intrinsics::from_fov_x(W / 2, W / 2, 16f64.to_radians()),
        ..camera()
    };
    for backdrop in [
        assist_core::Backdrop::Color,
        assist_core::Backdrop::LastSample,
    ] {
        for (prune_eps, packed) in [(0.0, false), (1e-4, true)] {
            let mut s = base();
            cast_shadows(&mut s, true);
            s.scene.backdrop = backdrop;
            let opts = RenderOptions {
                rays_per_batch: 1000,
                prune_eps,
                precision: assist_field::Precision::Bf16,
                tables: packed.then(|| Arc::new(assist_render::SceneTables::of(&s))),
                ..RenderOptions::default()
            };
            let with = RenderOptions {
                background_alone: true,
                layers: true,
                ..opts.clone()
            };
            let full = render_camera(&s, &cam, u32::MAX, &with);
            let mut bg = s.clone();
            bg.scene.nodes.retain(|n| n.is_background());
            let alone = render_camera(&bg, &cam, u32::MAX, &opts);
            let case = format!("{backdrop:?}, pruned at {prune_eps}");
            assert_eq!(full.background, alone.rgb, "{case}");
            // The rest of the frame is what it is without the option.
            assert_eq!(
                full.rgb,
                render_camera(&s, &cam, u32::MAX, &opts).rgb,
                "{case}"
            );
            // The objects are gone from it, and the floor's shadows with them.
            assert_ne!(full.background, full.rgb, "{case}");
            let missed = alone.unseen.iter().filter(|&&u| u).count();
            match backdrop {
                assist_core::Backdrop::LastSample => assert!(missed > 0, "{case}"),
                assist_core::Backdrop::Color => assert_eq!(missed, 0, "{case}"),
            }
        }
    }
}
