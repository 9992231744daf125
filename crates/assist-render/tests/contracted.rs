//! Contracted nodes (unbounded backgrounds): samples lie where the contraction puts the
//! world points of the ray, in order, reaching far beyond the box with a bounded count;
//! pruning occluded samples changes renders by less than its threshold.

mod common;

use assist_core::{Camera, DQuat, DVec3, Intrinsics, NodeSpace, Pose, Ray, Rng, Similarity3};
use assist_field::contraction::{FAR_RADIUS, contract_to_unit};
use assist_render::{RayBatch, RenderOptions, SampleOptions, Traced, render_camera, sample_rays};
use common::{constant_field, node, scene};

#[test]
fn contracted_samples_are_the_contracted_ray_points() {
    let pose = Similarity3::new(
        DQuat::from_rotation_z(0.4),
        DVec3::new(1.0, -2.0, 0.5),
        DVec3::splat(1.0),
    )
    .unwrap();
    let mut bg = node(0, "bg", 2.0, pose);
    bg.space = NodeSpace::Contracted;
    let s = scene(
        vec![bg.clone()],
        vec![("bg", constant_field(1.0, [0.5; 3], false, 1))],
        1.0 / 256.0,
    );
    let mut rng = Rng::new(9);
    let mut rays = RayBatch::default();
    let mut world = Vec::new();
    for _ in 0..64 {
        let o = pose.transform_point(DVec3::new(
            rng.range(-1.5, 1.5),
            rng.range(-1.5, 1.5),
            rng.range(-1.5, 1.5),
        ));
        let d = DVec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        )
        .normalize();
        let ray = Ray { origin: o, dir: d };
        rays.push(&ray, 0);
        world.push(ray);
    }
    let mut traced = Traced::default();
    sample_rays(
        &s,
        &rays,
        &SampleOptions {
            jitter: true,
            seed: 3,
            max_per_node: 4096,
        },
        &mut traced,
    );
    let ns = &traced.nodes[0];
    for (r, ray) in world.iter().enumerate() {
        let range = ns.range(r);
        assert!(range.len() > 10, "ray {r}: {} samples", range.len());
        // Every ray from inside the box goes to the far shell in a bounded number of steps.
        assert!(range.len() < 1500, "ray {r}: {} samples", range.len());
        let mut last_t = -1.0f32;
        let last = range.end - 1;
        for i in range {
            let t = ns.t[i];
            assert!(t > last_t, "ray {r}: t not increasing");
            last_t = t;
            let local = pose.local_from_world_point(ray.at(t as f64)) / bg.half_size;
            let want = contract_to_unit(local.as_vec3().to_array());
            for a in 0..3 {
                let got = ns.pos[a][i];
                assert!(
                    (got - want[a]).abs() < 1e-3,
                    "ray {r} sample at t {t}: {got} vs {}",
                    want[a]
                );
            }
        }
        // The last interval reaches the far end of the march (it stands for everything
        // beyond): the box diagonal is the density unit, and the pose has scale 1.
        let unit = (bg.half_size * 2.0).length();
        let end = ns.t[last] as f64 + ns.dt[last] as f64 * unit;
        let far = (pose.local_from_world_point(ray.at(end)) / bg.half_size)
            .abs()
            .max_element();
        assert!(
            far > FAR_RADIUS as f64 * 0.9,
            "ray {r} ends at radius {far}"
        );
    }
}

#[test]
fn pruning_changes_renders_by_less_than_its_threshold() {
    // A dense contracted background and a dense object in front of part of it.
    let mut bg = node(0, "bg", 1.0, Similarity3::IDENTITY);
    bg.space = NodeSpace::Contracted;
    let obj = node(
        1,
        "obj",
        0.3,
        Similarity3::from_translation(DVec3::new(0.2, 0.0, 0.0)),
    );
    let s = scene(
        vec![bg, obj],
        vec![
            ("bg", constant_field(40.0, [0.2, 0.6, 0.3], true, 1)),
            ("obj", constant_field(200.0, [0.9, 0.1, 0.1], true, 2)),
        ],
        1.0 / 256.0,
    );
    let camera = Camera {
        intrinsics: Intrinsics::from_fov_x(32, 24, 1.0),
        pose: Pose::look_at(
            DVec3::new(0.0, -0.8, 0.1),
            DVec3::new(0.2, 0.0, 0.0),
            DVec3::Z,
        )
        .unwrap(),
    };
    let full = render_camera(
        &s,
        &camera,
        u32::MAX,
        &RenderOptions {
            prune_eps: 0.0,
            ..Default::default()
        },
    );
    let eps = 1e-4;
    let pruned = render_camera(
        &s,
        &camera,
        u32::MAX,
        &RenderOptions {
            prune_eps: eps,
            ..Default::default()
        },
    );
    let mut worst = 0.0f32;
    for (a, b) in full.rgb.iter().zip(&pruned.rgb) {
        worst = worst.max((a - b).abs());
    }
    for (a, b) in full.opacity.iter().zip(&pruned.opacity) {
        worst = worst.max((a - b).abs());
    }
    // bf16 products may differ in the last bits between the two runs' batches.
    assert!(worst < 2.0 * eps + 1e-5, "largest change {worst}");
    assert_eq!(full.panoptic, pruned.panoptic);
}
