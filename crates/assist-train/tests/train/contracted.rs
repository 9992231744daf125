//! The contracted background's training: pruning by transmittance, a continued run's
//! step count, and the proposal sampler trained beside it.

use assist_core::Camera;
use assist_data::{LoadOptions, Split};
use assist_render::{RenderOptions, render_camera};
use assist_testkit::TempDir;
use assist_train::load_views;
use assist_train::{SetupOptions, TrainOptions, Trainer, background_color, build_scene};

use super::{setup, synth};

/// The synth scene's background alone, contracted (no object nodes), with its views.
fn contracted_background() -> (assist_scene::NeuralScene, Vec<assist_train::View>) {
    let ds = assist_data::load(synth(), &LoadOptions::default()).unwrap();
    let views = load_views(&ds, Split::Train, background_color(&ds)).unwrap();
    let setup = SetupOptions {
        background_space: assist_train::BackgroundSpace::Contracted,
        boxes: Vec::new(),
        ..SetupOptions::default()
    };
    let mut scene = build_scene(&ds, &views, &setup).unwrap();
    scene.scene.nodes.retain(|n| n.label == "background");
    scene.fields.retain(|k, _| k == "background");
    (scene, views)
}

/// The density pass that drops samples behind surfaces (`prune_eps`) runs on a step only
/// when it is a look every 100 steps or the pass before it dropped at least 30% of what it
/// queried; a contracted background (here the synth scene's, with no object nodes) has
/// more than 32 samples per ray, so every pass queries all of its samples. A threshold of
/// 0.5 drops enough of this short run's samples for both cases to occur.
#[test]
fn pruning_runs_only_while_it_pays() {
    let (scene, views) = contracted_background();
    let opts = TrainOptions {
        prune_eps: 0.5,
        iters: 260,
        batch_samples: 16384,
        ..TrainOptions::default()
    };
    let mut t = Trainer::new(scene, views, opts).unwrap();
    let stats: Vec<_> = (0..260).map(|_| t.step(0.0).unwrap()).collect();
    let pays = |s: &assist_train::StepStats| s.pruned as f64 >= 0.3 * s.candidates as f64;
    let (mut ran, mut paid) = (0, 0);
    for (i, s) in stats.iter().enumerate() {
        assert!(s.samples + s.pruned == s.candidates, "step {i}: {s:?}");
        if s.pruned > 0 {
            ran += 1;
            assert!(
                i % 100 == 0 || pays(&stats[i - 1]),
                "step {i} pruned {} of {} after a pass that did not pay ({} of {})",
                s.pruned,
                s.candidates,
                stats[i - 1].pruned,
                stats[i - 1].candidates
            );
        }
        paid += pays(s) as usize;
    }
    let f: Vec<String> = stats
        .iter()
        .step_by(20)
        .map(|s| format!("{:.2}", s.pruned as f64 / s.candidates as f64))
        .collect();
    eprintln!("dropped share every 20 steps: {}", f.join(" "));
    assert!(ran > 3 && paid > 0, "{ran} steps pruned, {paid} paid");
}

/// A run that continues a scene (as `train --resume` does) reports its own steps beside
/// the total: its phase times and rates are over its own steps.
#[test]
fn a_continued_run_counts_its_own_steps() {
    let ds = assist_data::load(synth(), &LoadOptions::default()).unwrap();
    let mut t = setup(&ds);
    t.opts.iters = 3;
    let first = t.run(|_, _| {}).unwrap();
    t.opts.iters = 5;
    let second = t.run(|_, _| {}).unwrap();
    assert_eq!((first.iterations, first.steps), (3, 3));
    assert_eq!((second.iterations, second.steps), (5, 2));
}

/// The interlevel loss (mean per ray) of `scene`'s proposal against its field along
/// `camera`'s rays through every 7th pixel.
fn interlevel_of(scene: &assist_scene::NeuralScene, camera: &Camera) -> f64 {
    use assist_render::proposal::{interlevel, weights};
    let mut rays = assist_render::RayBatch::default();
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    for p in (0..w * h).step_by(7) {
        if let Some(r) = camera.pixel_ray(p % w, p / w) {
            rays.push(&r, 0);
        }
    }
    let so = assist_render::SampleOptions {
        keep_proposal: true,
        ..Default::default()
    };
    let mut traced = assist_render::Traced::default();
    assist_render::sample_rays(scene, &rays, &so, &mut traced);
    assist_render::query_fields(
        scene,
        &mut traced,
        &mut Vec::new(),
        assist_render::Query::Train,
    );
    let rec = traced.proposal.as_ref().expect("drawn by a proposal");
    let ns = &traced.nodes[rec.node];
    let mut loss = 0.0;
    for r in 0..rays.len() {
        let (c, f) = (rec.range(r), ns.range(r));
        let (mut w_f, mut w_c) = (vec![0.0; f.len()], vec![0.0; c.len()]);
        weights(&ns.sigma[f.clone()], &ns.dt[f.clone()], &mut w_f);
        weights(&rec.sigma[c.clone()], &rec.delta[c.clone()], &mut w_c);
        let g = &mut vec![0.0; c.len()];
        loss += interlevel(&rec.steps[c], &w_c, &rec.spans[f], &w_f, g) as f64;
    }
    loss / rays.len() as f64
}

/// `proposal_samples`: the contracted background's samples are drawn from a proposal
/// field, that many per ray, and the proposal learns to bound the field's weights (on the
/// field as trained, its loss is far below a fresh proposal's); the scene file keeps it,
/// and the scene read back renders the same image.
#[test]
fn a_proposal_trains_beside_the_background_and_is_saved_with_it() {
    let (scene, views) = contracted_background();
    let camera = views[0].camera;
    let opts = TrainOptions {
        proposal_samples: 16,
        prune_eps: 1e-4,
        iters: 150,
        batch_samples: 8192,
        ..TrainOptions::default()
    };
    let mut t = Trainer::new(scene, views, opts).unwrap();
    for _ in 0..150 {
        let s = t.step(0.0).unwrap();
        // Every ray draws its 16 (none is pruned: the loss pairs them with their spans).
        assert_eq!(s.samples, 16 * s.rays, "{s:?}");
        assert!(s.pruned == 0 && s.interlevel.is_finite());
    }
    let trained = interlevel_of(&t.scene, &camera);
    let mut fresh = t.scene.clone();
    let nf = std::sync::Arc::make_mut(fresh.fields.get_mut("background").unwrap());
    let p = nf.proposal.as_mut().unwrap();
    p.field = assist_field::ProposalField::new(p.field.config.clone(), 1).unwrap();
    let untrained = interlevel_of(&fresh, &camera);
    eprintln!("interlevel loss: trained {trained:.5}, fresh {untrained:.5}");
    assert!(
        trained < 0.3 * untrained,
        "trained {trained}, fresh {untrained}"
    );
    let tmp = TempDir::new("train-proposal");
    let path = tmp.join("p.assist");
    assist_scene::scene_file::save(&path, &t.scene, serde_json::json!({}), false).unwrap();
    let (back, _) = assist_scene::scene_file::load(&path).unwrap();
    let p = back.fields["background"]
        .proposal
        .as_ref()
        .expect("saved with its proposal");
    assert_eq!(Some(p), t.scene.fields["background"].proposal.as_ref());
    let opts = RenderOptions::default();
    let a = render_camera(&t.scene, &camera, u32::MAX, &opts);
    let b = render_camera(&back, &camera, u32::MAX, &opts);
    assert_eq!(a.rgb, b.rgb);
}

/// Two runs with the same seed give the same fields bit for bit, a proposal's included
/// (its gradient was once summed over rayon's adaptive splits, and the occupancy
/// threshold's mean too, so that runs drifted apart within a few steps). More threads
/// than the machine has, so that the work is shared differently from run to run.
#[test]
fn training_with_a_proposal_repeats_bit_for_bit() {
    let run = || {
        let (scene, views) = contracted_background();
        let opts = TrainOptions {
            proposal_samples: 16,
            iters: 40,
            batch_samples: 8192,
            occupancy_every: 4,
            ..TrainOptions::default()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(5)
            .build()
            .unwrap();
        pool.install(|| {
            let mut t = Trainer::new(scene, views, opts).unwrap();
            for _ in 0..40 {
                t.step(0.0).unwrap();
            }
            let nf = &t.scene.fields["background"];
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                bits(&nf.field.params),
                bits(&nf.proposal.as_ref().unwrap().field.params),
            )
        })
    };
    let first = run();
    for again in 1..3 {
        let other = run();
        assert!(other.0 == first.0, "run {again}: the field differs");
        assert!(other.1 == first.1, "run {again}: the proposal differs");
    }
}
