//! A camera whose fields are queried elsewhere (`RenderOptions::backend`, a GPU) renders
//! its batches overlapped: one queried while the one before is composited and the one
//! after marched. The image must be the same bits as one batch at a time on this CPU.

mod common;
use common::{constant_field, node, scene};

use std::sync::atomic::{AtomicUsize, Ordering};

use assist_core::{Camera, DVec3, Intrinsics, Pose, Similarity3};
use assist_field::{Field, FieldBackend, FieldQuery, Samples, Tape};
use assist_render::{Precision, RenderOptions, render_camera, render_camera_timed};

/// A backend that queries on this CPU as the render would (f32), counting its calls.
#[derive(Debug, Default)]
struct ThisCpu {
    batches: AtomicUsize,
}

impl FieldBackend for ThisCpu {
    fn name(&self) -> String {
        "this CPU, as a backend".into()
    }

    fn forward(
        &self,
        field: &Field,
        s: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Result<(), String> {
        field.forward_at(
            Precision::F32,
            None,
            None,
            s,
            &mut Tape::default(),
            sigma,
            rgb,
        );
        Ok(())
    }

    fn forward_all(&self, queries: &mut [FieldQuery<'_>]) -> Result<(), String> {
        self.batches.fetch_add(1, Ordering::Relaxed);
        for q in queries {
            let s = q.samples;
            q.field.forward_at(
                Precision::F32,
                None,
                q.novel,
                &s,
                &mut Tape::default(),
                q.sigma,
                q.rgb,
            );
        }
        Ok(())
    }
}

#[test]
fn batches_queried_elsewhere_overlap_and_render_the_same_bits() {
    let s = scene(
        vec![
            node(
                1,
                "a",
                0.5,
                Similarity3::from_translation(DVec3::new(0.0, 0.0, 0.0)),
            ),
            node(
                2,
                "b",
                0.4,
                Similarity3::from_translation(DVec3::new(0.3, 0.5, 0.2)),
            ),
        ],
        vec![
            ("a", constant_field(8.0, [0.8, 0.3, 0.1], true, 1)),
            ("b", constant_field(3.0, [0.1, 0.4, 0.9], true, 2)),
        ],
        0.0,
    );
    // 512 × 400 = 204,800 rays: four batches at the backend's fewest rays per batch, so
    // one batch is queried while one is composited and another marched.
    let cam = Camera {
        intrinsics: Intrinsics::from_fov_x(512, 400, 0.9),
        pose: Pose::look_at(DVec3::new(2.5, -2.0, 1.5), DVec3::ZERO, DVec3::Z).unwrap(),
    };
    let plain = RenderOptions {
        precision: Precision::F32,
        prune_eps: 0.0,
        layers: true,
        ..Default::default()
    };
    let want = render_camera(&s, &cam, u32::MAX, &plain);
    assert!(
        want.opacity.iter().filter(|&&o| o > 0.5).count() > 20_000,
        "the nodes fill part of the view"
    );
    assert!(want.panoptic.contains(&1) && want.panoptic.contains(&2));

    let backend = std::sync::Arc::new(ThisCpu::default());
    let elsewhere = RenderOptions {
        backend: Some(backend.clone()),
        ..plain.clone()
    };
    let (got, st) = render_camera_timed(&s, &cam, u32::MAX, &elsewhere);
    assert_eq!(backend.batches.load(Ordering::Relaxed), 4);
    assert_eq!(st.rays, 512 * 400);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&got.rgb), bits(&want.rgb));
    assert_eq!(bits(&got.depth), bits(&want.depth));
    assert_eq!(bits(&got.opacity), bits(&want.opacity));
    assert_eq!(got.panoptic, want.panoptic);
    assert_eq!(got.layers.len(), 2);
    for (g, w) in got.layers.iter().zip(&want.layers) {
        assert_eq!(bits(&g.rgb), bits(&w.rgb));
        assert_eq!(bits(&g.opacity), bits(&w.opacity));
    }
}
