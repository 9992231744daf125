//! Rendering with the fields queried on the GPU ([`GpuBackend`] behind
//! `RenderOptions::backend`) against rendering on the CPU: a scene of three nodes whose
//! fields have every parameter random, the same camera, the same image within f32
//! rounding, also when queries are submitted in many parts and two nodes share a field;
//! and a field changed after a render is uploaded again, not rendered stale.

mod common;

use std::sync::Arc;

use assist_core::{Camera, DVec3, Intrinsics, Pose};
use assist_field::{FieldConfig, OccupancyGrid};
use assist_gpu::GpuBackend;
use assist_render::{Precision, RenderOptions, RenderedImage, render_camera};
use assist_scene::{NeuralScene, NodeField};
use assist_testkit::scenes::node;
use common::{gpu, random_field};

/// A background and two boxes whose fields are random, each field's density scaled down
/// so that rays pass through several nodes (the compositing sees them all).
fn scene() -> NeuralScene {
    let cfg = FieldConfig {
        log2_table_size: 12,
        ..FieldConfig::nerfacto(4)
    };
    let nodes = vec![
        node(0, "background", 1.5, DVec3::ZERO),
        node(1, "a", 0.2, DVec3::new(-0.2, 0.0, 0.1)),
        node(2, "b", 0.15, DVec3::new(0.25, 0.1, 0.0)),
    ];
    let mut fields = std::collections::BTreeMap::new();
    for (k, n) in nodes.iter().enumerate() {
        let f = random_field(cfg.clone(), 11 + k as u64);
        let nf = NodeField::new(f, OccupancyGrid::new(16), n.half_size);
        fields.insert(n.field.clone(), Arc::new(nf));
    }
    NeuralScene {
        scene: assist_core::Scene::with_nodes(nodes, DVec3::Z),
        fields,
    }
}

fn camera() -> Camera {
    Camera {
        intrinsics: Intrinsics::from_fov_x(40, 30, 1.0),
        pose: Pose::look_at(DVec3::new(1.2, -1.0, 0.6), DVec3::ZERO, DVec3::Z).unwrap(),
    }
}

/// The largest difference of any channel of any pixel.
fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn cpu(scene: &NeuralScene) -> RenderedImage {
    let opts = RenderOptions {
        precision: Precision::F32,
        ..RenderOptions::default()
    };
    render_camera(scene, &camera(), u32::MAX, &opts)
}

fn on(scene: &NeuralScene, backend: &Arc<GpuBackend>, layers: bool) -> RenderedImage {
    let opts = RenderOptions {
        precision: Precision::F32,
        backend: Some(backend.clone()),
        layers,
        // Pruning is asked for: with a backend it is skipped, not run on the CPU.
        prune_eps: 1e-4,
        ..RenderOptions::default()
    };
    render_camera(scene, &camera(), u32::MAX, &opts)
}

#[test]
fn a_frame_rendered_on_the_gpu_matches_the_cpu() {
    let Some(g) = gpu() else { return };
    let backend = Arc::new(GpuBackend::new(g));
    let s = scene();
    let want = cpu(&s);
    let got = on(&s, &backend, false);
    assert!(backend.failure().is_none(), "{:?}", backend.failure());
    let opaque = want.opacity.iter().filter(|&&o| o > 0.5).count();
    assert!(
        opaque > want.opacity.len() / 4 && want.rgb.iter().any(|&v| v > 0.05),
        "the scene is visible: {opaque} opaque pixels"
    );
    let d = max_diff(&got.rgb, &want.rgb);
    assert!(d < 1e-4, "rgb differs by {d}");
    let d = max_diff(&got.opacity, &want.opacity);
    assert!(d < 1e-4, "opacity differs by {d}");
    let d = max_diff(&got.depth, &want.depth);
    assert!(d < 1e-3, "depth differs by {d}");
    let same = got
        .panoptic
        .iter()
        .zip(&want.panoptic)
        .filter(|(a, b)| a == b)
        .count();
    assert!(
        same * 100 >= got.panoptic.len() * 99,
        "panoptic ids agree on {same} of {} pixels",
        got.panoptic.len()
    );
}

#[test]
fn queries_in_parts_and_a_shared_field_render_the_same() {
    let Some(g) = gpu() else { return };
    // 97 samples a part: every node's query is split, parts of one field queued back
    // to back before the one wait.
    let backend = Arc::new(GpuBackend::with_part(g, 97));
    let mut s = scene();
    // Node b shows node a's field (a duplicate): one field, two queries in one call.
    s.scene.nodes[2].field = "f1".into();
    s.scene.nodes[2].half_size = s.scene.nodes[1].half_size;
    let want = cpu(&s);
    let got = on(&s, &backend, false);
    assert!(backend.failure().is_none(), "{:?}", backend.failure());
    let d = max_diff(&got.rgb, &want.rgb);
    assert!(d < 1e-4, "rgb differs by {d}");
    let d = max_diff(&got.opacity, &want.opacity);
    assert!(d < 1e-4, "opacity differs by {d}");
}

#[test]
fn a_field_changed_after_a_render_is_uploaded_again() {
    let Some(g) = gpu() else { return };
    let backend = Arc::new(GpuBackend::new(g));
    let mut s = scene();
    let before = on(&s, &backend, true);
    // Change one object's nets in place (same allocation, as a training step does).
    let nf = Arc::get_mut(s.fields.get_mut("f1").expect("f1")).expect("not shared");
    let at = nf.field.layout.color[0].b;
    for v in &mut nf.field.params[at..at + 16] {
        *v += 2.0;
    }
    let want = cpu(&s);
    let got = on(&s, &backend, true);
    let changed = max_diff(&before.layers[1].rgb, &got.layers[1].rgb);
    assert!(
        changed > 0.01,
        "the change shows in the object's layer: {changed}"
    );
    let d = max_diff(&got.rgb, &want.rgb);
    assert!(d < 1e-4, "after the change the GPU's render differs by {d}");
}

/// Fields that know where their codes' photographs were taken render a novel view with
/// the blend of the nearest ones' codes (`Field::novel_code`): the same on the GPU as on
/// the CPU, and not the average code's image.
#[test]
fn a_novel_views_blended_code_matches_the_cpu() {
    let Some(g) = gpu() else { return };
    let backend = Arc::new(GpuBackend::new(g));
    let plain = scene();
    let mut s = plain.clone();
    for (k, nf) in s.fields.values_mut().enumerate() {
        let nf = Arc::make_mut(nf);
        // Four cameras around the node, the first nearest this test's camera.
        nf.field.anchors = (0..4)
            .map(|i| {
                let a = (i as f32 + 0.1 * k as f32) * std::f32::consts::FRAC_PI_2;
                [2.0 * a.cos(), -2.0 * a.sin(), 0.5]
            })
            .collect();
    }
    let want = cpu(&s);
    let got = on(&s, &backend, false);
    assert!(backend.failure().is_none(), "{:?}", backend.failure());
    let d = max_diff(&got.rgb, &want.rgb);
    assert!(d < 1e-4, "rgb differs by {d}");
    let average = cpu(&plain);
    let moved = max_diff(&want.rgb, &average.rgb);
    assert!(moved > 1e-3, "the blend changed nothing ({moved})");
    // The GPU goes back to the average code for a scene without anchors.
    let back = on(&plain, &backend, false);
    assert!(max_diff(&back.rgb, &average.rgb) < 1e-4);
}
