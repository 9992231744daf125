//! A session in memory: load a scene once, then edit in words, render, pick and undo with
//! no disk access.

use assist_core::{Camera, DVec3, Intrinsics, Pose};
use assist_scene::NeuralScene;
use assist_session::{RenderRequest, Session, SessionError};
use assist_testkit::TempDir;

/// A grey room-sized background with a red and a green cube on the floor.
fn table_scene() -> NeuralScene {
    assist_testkit::scenes::two_boxes(0.05)
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

/// Issue 47 item 18: a camera at 1e100 made a 64×48 frame take seconds (a 2048² frame
/// about 45 minutes), and a render could not be stopped. Far cameras are refused before
/// any ray is traced, and a render stops when its cancel flag is set.
#[test]
fn far_cameras_are_refused_and_renders_can_be_cancelled() {
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let s = Session::new(table_scene());
    for far in [1e100, 1e7, 1e150] {
        let mut cam = camera();
        cam.pose = Pose::look_at(DVec3::new(far, -far, far), DVec3::ZERO, DVec3::Z).unwrap();
        let t = std::time::Instant::now();
        let e = s.render(&cam, &RenderRequest::default()).unwrap_err();
        assert!(
            e.to_string().contains("scene radii") && e.to_string().len() < 300,
            "{e}"
        );
        assert!(t.elapsed().as_secs_f64() < 1.0);
        assert!(s.pick(&cam, 3.0, 3.0).is_err());
    }
    // A camera just outside the room renders.
    let mut near = camera();
    near.pose = Pose::look_at(DVec3::new(0.0, -4.0, 1.0), DVec3::ZERO, DVec3::Z).unwrap();
    assert!(s.render(&near, &RenderRequest::default()).is_ok());
    let flag = Arc::new(AtomicBool::new(true));
    let req = RenderRequest {
        cancel: Some(flag),
        ..RenderRequest::default()
    };
    assert!(matches!(
        s.render(&camera(), &req),
        Err(SessionError::Cancelled)
    ));
}
