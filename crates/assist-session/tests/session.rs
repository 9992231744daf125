//! A session in memory: load a scene once, then edit in words, render, pick and undo with
//! no disk access.

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{Camera, DVec3, Intrinsics, NodeSpace, Pose, Scene, SceneNode, Similarity3};
use assist_field::{Field, OccupancyGrid};
use assist_scene::{NeuralScene, NodeField};
use assist_session::{RenderRequest, Session, SessionError};
use assist_testkit::TempDir;

fn node(id: u16, label: &str, half: f64, at: DVec3) -> SceneNode {
    SceneNode {
        id,
        label: label.into(),
        embedding: None,
        class: None,
        field: format!("f{id}"),
        half_size: DVec3::splat(half),
        world_from_local: Similarity3::from_translation(at),
        space: NodeSpace::Box,
        cast: None,
    }
}

/// A grey room-sized background with a red and a green cube on the floor.
fn table_scene() -> NeuralScene {
    let nodes = vec![
        node(0, "background", 1.5, DVec3::new(0.0, 0.0, 0.0)),
        node(1, "red box", 0.05, DVec3::new(-0.15, 0.0, 0.05)),
        node(2, "green box", 0.05, DVec3::new(0.15, 0.0, 0.05)),
    ];
    let fields = [
        Field::constant(3.0, [0.5, 0.5, 0.5], false, 1),
        Field::constant(3000.0, [0.9, 0.1, 0.1], false, 2),
        Field::constant(3000.0, [0.1, 0.8, 0.2], false, 3),
    ];
    let mut map = BTreeMap::new();
    for (n, f) in nodes.iter().zip(fields) {
        let nf = NodeField::new(f.unwrap(), OccupancyGrid::new(16), n.half_size);
        map.insert(n.field.clone(), Arc::new(nf));
    }
    NeuralScene {
        scene: Scene {
            nodes,
            up: DVec3::Z,
            meters_per_unit: 1.0,
            background_color: [0.0; 3],
            backdrop: Default::default(),
            selected: None,
            near: 0.0,
            classes: Vec::new(),
            light: None,
        },
        fields: map,
    }
}

fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics {
            width: 64,
            height: 48,
            fx: 60.0,
            fy: 60.0,
            cx: 32.0,
            cy: 24.0,
            distortion: Default::default(),
        },
        pose: Pose::look_at(
            DVec3::new(0.0, -0.8, 0.5),
            DVec3::new(0.0, 0.0, 0.05),
            DVec3::Z,
        )
        .unwrap(),
    }
}

#[test]
fn edit_render_pick_and_undo_in_memory() {
    let dir = TempDir::new("session");
    let path = dir.join("table.assist");
    assist_scene::scene_file::save(&path, &table_scene(), serde_json::Value::Null, false).unwrap();
    let mut s = Session::open(&path).unwrap();
    // Nothing below reads the disk again.
    drop(dir);
    let cam = camera();
    let req = RenderRequest::default();
    let first = s.render(&cam, &req).unwrap();
    let before = s.node(1).unwrap().world_from_local.translation;

    let edits = s.apply_text("move the red box 10 cm left", None).unwrap();
    assert_eq!(edits.len(), 1);
    let after = s.node(1).unwrap().world_from_local.translation;
    assert!(
        ((after - before).length() - 0.1).abs() < 1e-9,
        "moved {}",
        after - before
    );
    let moved = s.render(&cam, &req).unwrap();
    assert_ne!(first.rgb, moved.rgb);

    // The moved cube's centre, seen by the camera, is the red box.
    let (px, _) = cam.project(after).unwrap();
    assert_eq!(s.pick(&cam, px.x, px.y).unwrap(), Some(1));
    let q = px.y as usize * 64 + px.x as usize;
    assert_eq!(moved.panoptic[q], 1);
    // Where it stood, the background (or nothing) is seen now.
    let (old, _) = cam.project(before).unwrap();
    assert_eq!(s.pick(&cam, old.x, old.y).unwrap(), None);
    // The green box is still where it was.
    let (g, _) = cam
        .project(s.node(2).unwrap().world_from_local.translation)
        .unwrap();
    assert_eq!(s.pick(&cam, g.x, g.y).unwrap(), Some(2));

    // Undo: the first render again, bit for bit.
    assert!(s.undo());
    let again = s.render(&cam, &req).unwrap();
    assert_eq!(first.rgb, again.rgb);
    assert_eq!(first.depth, again.depth);
    assert_eq!(first.panoptic, again.panoptic);
    assert!(s.redo());
    assert_eq!(s.render(&cam, &req).unwrap().rgb, moved.rgb);
}

#[test]
fn one_instruction_is_one_undo_step() {
    let mut s = Session::new(table_scene());
    let first = s.description().clone();
    s.apply_text(
        "duplicate the green box and move the copy 20 cm right, then delete the red box",
        None,
    )
    .unwrap();
    assert_eq!(s.nodes().len(), 3);
    assert_eq!(s.undo_steps(), 1);
    assert!(s.undo());
    assert_eq!(s.description(), &first);
}

#[test]
fn bad_requests_are_errors_naming_what_was_asked() {
    let mut s = Session::new(table_scene());
    let cam = camera();
    let e = s.apply_text("move the blue ball left", None).unwrap_err();
    assert!(matches!(e, SessionError::Language(_)), "{e}");
    assert!(e.to_string().contains("red box"), "{e}");
    assert_eq!(s.undo_steps(), 0);
    let e = s.pick(&cam, 64.0, 3.0).unwrap_err().to_string();
    assert!(e.contains("outside"), "{e}");
    let e = s.select(Some(9)).unwrap_err().to_string();
    assert!(
        e.contains("no node with id 9") && e.contains("green box"),
        "{e}"
    );
    let e = s
        .render(
            &cam,
            &RenderRequest {
                size: Some((0, 10)),
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
    assert!(e.contains("size"), "{e}");
    // A smaller render of the same camera.
    let small = s
        .render(
            &cam,
            &RenderRequest {
                size: Some((32, 24)),
                ..Default::default()
            },
        )
        .unwrap();
    assert_eq!(
        (small.width, small.height, small.rgb.len()),
        (32, 24, 32 * 24 * 3)
    );
    s.select(Some(2)).unwrap();
    assert_eq!(s.description().selected, Some(2));
}
