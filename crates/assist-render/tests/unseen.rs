//! What no sample reaches: under a last-sample backdrop (a captured room) a pixel whose ray
//! meets no node is marked unseen and filled from the seen pixels around it, never black;
//! under a colour backdrop it shows that colour. A drag fills exactly as a full render.

mod common;

use assist_core::{Backdrop, Camera, DVec3, Intrinsics, Pose, Similarity3};
use assist_render::{DragCache, RenderOptions, render_camera, render_camera_moving};
use assist_scene::NeuralScene;
use common::{constant_field, node, scene};

const GREY: [f32; 3] = [0.5, 0.5, 0.5];

/// A grey floor box (top face at z = 0) and a red cube on it, seen from above at a slant
/// so that the top rows of the image look past the floor's far edge into nothing.
fn room(backdrop: Backdrop) -> (NeuralScene, Camera) {
    let floor = node(
        0,
        "floor",
        2.0,
        Similarity3::from_translation(DVec3::new(0.0, 0.0, -2.0)),
    );
    let cube = node(
        1,
        "cube",
        0.2,
        Similarity3::from_translation(DVec3::new(0.0, 0.0, 0.2)),
    );
    let mut s = scene(
        vec![floor, cube],
        vec![
            ("floor", constant_field(200.0, GREY, false, 1)),
            ("cube", constant_field(200.0, [0.9, 0.1, 0.1], false, 2)),
        ],
        0.0,
    );
    s.scene.backdrop = backdrop;
    let camera = Camera {
        intrinsics: Intrinsics::from_fov_x(64, 48, 60f64.to_radians()),
        pose: Pose::look_at(
            DVec3::new(0.0, -1.5, 1.0),
            DVec3::new(0.0, 0.5, 0.2),
            DVec3::Z,
        )
        .unwrap(),
    };
    (s, camera)
}

#[test]
fn pixels_no_ray_sees_are_filled_from_their_surroundings() {
    // The floor alone (the cube's red would show in the fill near it).
    let (mut s, cam) = room(Backdrop::LastSample);
    s.scene.nodes.retain(|n| n.is_background());
    let img = render_camera(&s, &cam, u32::MAX, &RenderOptions::default());
    let n = img.unseen.iter().filter(|&&u| u).count();
    assert!(n > 100 && n < img.unseen.len() / 2, "{n} unseen pixels");
    // The unseen pixels are the top rows (past the floor), and they take the floor's grey
    // and a depth that continues it; their opacity stays 0.
    for q in (0..img.unseen.len()).filter(|&q| img.unseen[q]) {
        assert!(q / 64 < 24, "pixel {q} unseen below the horizon");
        let c = &img.rgb[3 * q..3 * q + 3];
        assert!(c.iter().all(|v| (v - 0.5).abs() < 1e-3), "pixel {q}: {c:?}");
        assert!(img.depth[q] > 1.0, "pixel {q}: depth {}", img.depth[q]);
        assert_eq!(img.opacity[q], 0.0);
        assert_eq!(img.panoptic[q], 0);
    }
    // Under a colour backdrop the same pixels show that colour and nothing is unseen.
    let (mut s, cam) = room(Backdrop::Color);
    s.scene.nodes.retain(|n| n.is_background());
    let img = render_camera(&s, &cam, u32::MAX, &RenderOptions::default());
    assert!(img.unseen.iter().all(|&u| !u));
    assert_eq!(&img.rgb[..3], &[0.0, 0.0, 1.0]);
    assert_eq!(img.depth[0], 0.0);
}

#[test]
fn a_drag_fills_exactly_as_a_full_render() {
    let (mut s, cam) = room(Backdrop::LastSample);
    let opts = RenderOptions::default();
    let mut cache = DragCache::default();
    let _ = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
    for step in 1..=2 {
        // The cube rises into the part of the view that sees nothing behind it.
        s.scene.nodes[1].world_from_local.translation.z += 0.4 * step as f64;
        let dragged = render_camera_moving(&s, &cam, u32::MAX, &opts, 1, &mut cache);
        let full = render_camera(&s, &cam, u32::MAX, &opts);
        assert_eq!(dragged.unseen, full.unseen, "step {step}");
        assert_eq!(dragged.rgb, full.rgb, "step {step}");
        assert_eq!(dragged.depth, full.depth, "step {step}");
        assert!(full.unseen.iter().any(|&u| u));
    }
}
