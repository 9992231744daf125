//! A contracted node's samples drawn from its proposal field: as many per ray as it asks
//! for, at the contracted points of the ray, inside its march, with the coarse samples
//! kept for the loss; and a proposal trained on the interlevel loss alone learns where a
//! ray's weight lies, so the samples drawn from it crowd there.

mod common;

use std::sync::Arc;

use assist_core::{DVec3, NodeSpace, Ray, Rng, Similarity3};
use assist_field::contraction::contract_to_unit;
use assist_field::{Adam, Proposal, ProposalConfig, ProposalField, ProposalTape};
use assist_render::proposal::{interlevel, weights, weights_backward};
use assist_render::{RayBatch, SampleOptions, Traced, sample_rays};
use assist_scene::NeuralScene;
use common::{constant_field, node, scene};

const SAMPLES: usize = 24;

/// A contracted background of half size 1 with a fresh proposal, and rays from inside
/// its box in every direction.
fn setup(n_rays: usize) -> (NeuralScene, RayBatch, Vec<Ray>) {
    let mut bg = node(0, "bg", 1.0, Similarity3::IDENTITY);
    bg.space = NodeSpace::Contracted;
    let mut s = scene(
        vec![bg],
        vec![("bg", constant_field(1.0, [0.5; 3], false, 1))],
        1.0 / 256.0,
    );
    let cfg = ProposalConfig {
        log2_table_size: 14,
        max_resolution: 64,
        ..ProposalConfig::default()
    };
    let nf = Arc::make_mut(s.fields.get_mut("bg").unwrap());
    nf.proposal = Some(Proposal {
        field: ProposalField::new(cfg, 5).unwrap(),
        samples: SAMPLES,
    });
    let mut rng = Rng::new(9);
    let mut rays = RayBatch::default();
    let mut world = Vec::new();
    for _ in 0..n_rays {
        let o = DVec3::new(
            rng.range(-0.3, 0.3),
            rng.range(-0.3, 0.3),
            rng.range(-0.3, 0.3),
        );
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
    (s, rays, world)
}

fn options(jitter: bool, seed: u64) -> SampleOptions {
    SampleOptions {
        jitter,
        seed,
        max_per_node: 4096,
        step_scale: 1.0,
        keep_proposal: true,
    }
}

#[test]
fn drawn_samples_are_contracted_ray_points_inside_the_march() {
    let (s, rays, world) = setup(48);
    for jitter in [false, true] {
        let mut traced = Traced::default();
        sample_rays(&s, &rays, &options(jitter, 3), &mut traced);
        let ns = &traced.nodes[0];
        let rec = traced
            .proposal
            .as_ref()
            .expect("the coarse samples are kept");
        assert_eq!(rec.spans.len(), ns.len());
        for (r, ray) in world.iter().enumerate() {
            let range = ns.range(r);
            assert_eq!(range.len(), SAMPLES, "ray {r}");
            let coarse = rec.range(r);
            assert!(coarse.len() > 4, "ray {r}: {} coarse", coarse.len());
            // The march's steps in world distance (the node's pose has scale 1).
            let first = rec.steps[coarse.start];
            let last = rec.steps[coarse.end - 1];
            let mut before = f32::NEG_INFINITY;
            for i in range.clone() {
                let t = ns.t[i];
                assert!(t >= before, "ray {r}: t goes back");
                assert!(
                    t >= first.t - 1e-5 && t <= last.t + last.dt + 1e-3,
                    "ray {r}: {t}"
                );
                before = t;
                let want = contract_to_unit(ray.at(t as f64).as_vec3().to_array());
                for a in 0..3 {
                    assert!((ns.pos[a][i] - want[a]).abs() < 1e-3, "ray {r} at {t}");
                }
            }
            if !jitter {
                // The fine intervals cover the coarse ones end to end (in box diagonals).
                let fine: f32 = ns.dt[range].iter().sum();
                let all: f32 = rec.delta[coarse].iter().sum();
                assert!((fine - all).abs() < 1e-3 * all, "ray {r}: {fine} vs {all}");
            }
        }
    }
    // Rendering's draws are deterministic.
    let (mut a, mut b) = (Traced::default(), Traced::default());
    sample_rays(&s, &rays, &options(false, 1), &mut a);
    sample_rays(&s, &rays, &options(false, 2), &mut b);
    assert_eq!(a.nodes[0].t, b.nodes[0].t);
}

/// The world radius of the surface the training target puts each ray's weight on.
const SHELL: f32 = 2.0;

/// Density of the target: a shell of width 0.2 at radius [`SHELL`] (world units).
fn target_sigma(p: [f32; 3]) -> f32 {
    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    if (r - SHELL).abs() < 0.1 { 400.0 } else { 0.0 }
}

/// The share of the drawn samples within 0.15 of the shell's radius.
fn share_on_shell(s: &NeuralScene, rays: &RayBatch, world: &[Ray]) -> f64 {
    let mut traced = Traced::default();
    sample_rays(s, rays, &options(false, 0), &mut traced);
    let ns = &traced.nodes[0];
    let mut on = 0;
    for (r, ray) in world.iter().enumerate() {
        for i in ns.range(r) {
            let p = ray.at(ns.t[i] as f64);
            on += ((p.length() as f32 - SHELL).abs() < 0.15) as usize;
        }
    }
    on as f64 / ns.len() as f64
}

#[test]
fn a_proposal_trained_on_the_interlevel_loss_draws_where_the_weight_is() {
    let (mut s, rays, world) = setup(96);
    let before = share_on_shell(&s, &rays, &world);
    let mut adam: Option<Adam> = None;
    let mut tape = ProposalTape::default();
    let mut losses = Vec::new();
    for step in 0..150 {
        let mut traced = Traced::default();
        sample_rays(&s, &rays, &options(true, step), &mut traced);
        let ns = &traced.nodes[0];
        let rec = traced.proposal.as_ref().unwrap();
        let mut d_sigma = vec![0.0f32; rec.sigma.len()];
        let mut loss = 0.0;
        for (r, ray) in world.iter().enumerate() {
            let (c, f) = (rec.range(r), ns.range(r));
            // The "field": the shell's density at the drawn samples.
            let sig_f: Vec<f32> = f
                .clone()
                .map(|i| target_sigma(ray.at(ns.t[i] as f64).as_vec3().to_array()))
                .collect();
            let mut w_f = vec![0.0; f.len()];
            weights(&sig_f, &ns.dt[f.clone()], &mut w_f);
            let mut w_c = vec![0.0; c.len()];
            weights(&rec.sigma[c.clone()], &rec.delta[c.clone()], &mut w_c);
            let mut g = vec![0.0; c.len()];
            loss += interlevel(&rec.steps[c.clone()], &w_c, &rec.spans[f], &w_f, &mut g);
            weights_backward(
                &rec.sigma[c.clone()],
                &rec.delta[c.clone()],
                &g,
                &mut d_sigma[c],
            );
        }
        losses.push(loss / world.len() as f32);
        let nf = Arc::make_mut(s.fields.get_mut("bg").unwrap());
        let p = &mut nf.proposal.as_mut().unwrap().field;
        let pos = [&rec.pos[0][..], &rec.pos[1][..], &rec.pos[2][..]];
        p.forward_train(pos, &mut tape);
        let mut grad = vec![0.0; p.params.len()];
        d_sigma.iter_mut().for_each(|d| *d /= world.len() as f32);
        p.backward(pos, &tape, &d_sigma, &mut grad);
        let a = adam.get_or_insert_with(|| {
            let mut a = Adam::new(p.params.len());
            a.sparse_range = 0..p.mlp_start();
            a
        });
        a.update(1e-2, &mut p.params, &mut grad);
    }
    let after = share_on_shell(&s, &rays, &world);
    let first: f32 = losses[..10].iter().sum::<f32>() / 10.0;
    let last: f32 = losses[losses.len() - 10..].iter().sum::<f32>() / 10.0;
    eprintln!("on the shell: {before:.3} → {after:.3}; loss {first:.4} → {last:.4}");
    assert!(last < 0.5 * first, "loss {first} → {last}");
    // The coarse intervals there are longer than the shell is wide, and the padding
    // spreads a fifth of the samples over every interval: what counts is that each ray
    // now has a few samples on the surface, where it had one at most.
    assert!(
        after > 3.0 * before && after * SAMPLES as f64 >= 2.0,
        "on the shell: {before} → {after}"
    );
}
