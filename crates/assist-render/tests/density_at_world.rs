//! `NeuralScene::density_at_world` (the edit checks' view of a field) agrees with what the
//! renderer integrates: at the world point of every sample, its density times the sample's
//! world interval is the sample's optical depth, for a turned, scaled box node and inside
//! a contracted node's box; outside a box it is 0.

mod common;

use assist_core::{DQuat, DVec3, NodeSpace, Ray, Rng, Similarity3};
use assist_field::{Field, FieldConfig};
use assist_render::{RayBatch, SampleOptions, Traced, sample_rays};
use common::{node, scene};

fn random_field(seed: u64) -> Field {
    let mut cfg = FieldConfig::object(0);
    cfg.appearance_dim = 0;
    cfg.log2_table_size = 12;
    Field::new(cfg, seed).unwrap()
}

#[test]
fn density_at_world_times_interval_is_the_rendered_optical_depth() {
    for space in [NodeSpace::Box, NodeSpace::Contracted] {
        let pose = Similarity3::new(
            DQuat::from_rotation_z(0.7) * DQuat::from_rotation_x(0.3),
            DVec3::new(0.4, -0.2, 1.1),
            DVec3::splat(1.7),
        )
        .unwrap();
        let mut n = node(0, "f", 0.6, pose);
        n.space = space;
        let s = scene(vec![n.clone()], vec![("f", random_field(5))], 0.0);
        let nf = s.field_of(0);
        let mut rng = Rng::new(2);
        let mut rays = RayBatch::default();
        let mut world = Vec::new();
        for _ in 0..16 {
            let o =
                pose.transform_point(DVec3::new(-2.0, rng.range(-0.3, 0.3), rng.range(-0.3, 0.3)));
            let to =
                pose.transform_point(DVec3::new(0.0, rng.range(-0.3, 0.3), rng.range(-0.3, 0.3)));
            let ray = Ray {
                origin: o,
                dir: (to - o).normalize(),
            };
            rays.push(&ray, 0);
            world.push(ray);
        }
        let mut traced = Traced::default();
        let so = SampleOptions {
            jitter: false,
            seed: 0,
            max_per_node: 4096,
            step_scale: 1.0,
            keep_proposal: false,
        };
        sample_rays(&s, &rays, &so, &mut traced);
        let ns = &traced.nodes[0];
        let mut checked = 0;
        for (r, ray) in world.iter().enumerate() {
            let range = ns.range(r);
            for i in range.start..range.end.saturating_sub(1) {
                let p = ray.at(ns.t[i] as f64);
                let local = pose.local_from_world_point(p);
                if (local.abs() - n.half_size).max_element() > -1e-3 {
                    continue; // the box's own interior (contracted space is linear there)
                }
                let mut sigma = [0.0f32];
                nf.field.density(
                    [&[ns.pos[0][i]], &[ns.pos[1][i]], &[ns.pos[2][i]]],
                    &mut sigma,
                );
                let want = sigma[0] as f64 * ns.dt[i] as f64;
                let got = s.density_at_world(0, &[p])[0] as f64 * (ns.t[i + 1] - ns.t[i]) as f64;
                assert!(
                    (got - want).abs() <= 2e-3 * want.abs() + 1e-7,
                    "{space:?} ray {r} sample {i}: {got} vs {want}"
                );
                checked += 1;
            }
        }
        assert!(checked > 200, "{space:?}: only {checked} samples checked");
        // Outside a box node there is nothing.
        if space == NodeSpace::Box {
            let out = pose.transform_point(DVec3::new(0.0, 0.0, 0.61));
            assert_eq!(s.density_at_world(0, &[out]), [0.0]);
        }
    }
}
