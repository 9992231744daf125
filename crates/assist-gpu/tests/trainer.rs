//! The trainer with its fields' optimizers on the GPU (`train --device gpu`): the stepped
//! parameters stay on the device between steps, and reach the scene where the CPU reads
//! it (a pull in the step callback, the checkpoints, the end of a run), equal to the CPU
//! run's within rounding. On lavapipe in CI, skipped loudly without any adapter elsewhere.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use assist_data::synth::{SynthConfig, generate};
use assist_data::{Dataset, LoadOptions, Split};
use assist_gpu::GpuTraining;
use assist_testkit::TempDir;
use assist_train::{PriorKind, SetupOptions, TrainOptions, Trainer};
use assist_train::{background_color, build_scene, fill_prior, load_views};

type Params = BTreeMap<String, Vec<f32>>;

fn params(t: &Trainer) -> Params {
    t.scene
        .fields
        .iter()
        .map(|(k, f)| (k.clone(), f.field.params.clone()))
        .collect()
}

/// ‖a − b‖ over every field.
fn dist(a: &Params, b: &Params) -> f64 {
    let mut d = 0f64;
    for (k, pb) in b {
        for (x, y) in a[k].iter().zip(pb) {
            d += ((x - y) as f64).powi(2);
        }
    }
    d.sqrt()
}

/// A small built-in capture in `tmp`.
fn synth(tmp: &TempDir) -> Dataset {
    let data = tmp.join("synth");
    let cfg = SynthConfig {
        views: 12,
        width: 48,
        height: 36,
        objects: 3,
        spp: 1,
        shadow_samples: 1,
        ..Default::default()
    };
    generate(&cfg, &data, false, &|_, _| {}).unwrap();
    assist_data::load(&data, &LoadOptions::default()).unwrap()
}

fn trainer(ds: &Dataset, gpu: Option<&GpuTraining>, out: &Path, refine_poses: bool) -> Trainer {
    let mut views = load_views(ds, Split::Train, background_color(ds)).unwrap();
    for v in views.iter_mut() {
        fill_prior(v, PriorKind::PushPull);
    }
    let setup = SetupOptions {
        background_grid: 32,
        object_grid: 16,
        ..Default::default()
    };
    let scene = build_scene(ds, &views, &setup).unwrap();
    let opts = TrainOptions {
        iters: 6,
        seed: 3,
        checkpoint: Some(out.to_path_buf()),
        checkpoint_every: 1e9,
        refine_poses,
        ..Default::default()
    };
    let mut t = Trainer::new(scene, views, opts).unwrap();
    if let Some(g) = gpu {
        t.use_optimizers(g).unwrap();
    }
    t
}

#[test]
fn the_gpu_trainer_pulls_its_parameters_where_the_cpu_reads_them() {
    let Some(gpu) = common::gpu() else { return };
    let tmp = TempDir::new("gpu-trainer");
    let ds = synth(&tmp);
    let training = GpuTraining::new(Arc::new(gpu));

    // Three steps on each device, the fields read in the callback after the third.
    let run = |gpu: Option<&GpuTraining>, name: &str| {
        let out = tmp.join(name);
        let mut t = trainer(&ds, gpu, &out, false);
        let start = params(&t);
        let (mut first, mut third) = (None, None);
        t.opts.checkpoint_every = 1e9;
        t.run(|s, t| match s.iteration {
            0 => first = Some(params(t)),
            2 => {
                t.pull().unwrap();
                third = Some(params(t));
                // From here on, a checkpoint after every step.
                t.opts.checkpoint_every = 0.0;
            }
            _ => {}
        })
        .unwrap();
        let (saved, _) = assist_scene::scene_file::load(&out).unwrap();
        let saved: Params = saved
            .fields
            .iter()
            .map(|(k, f)| (k.clone(), f.field.params.clone()))
            .collect();
        (start, first.unwrap(), third.unwrap(), params(&t), saved)
    };
    let (start, first, third_g, end_g, saved_g) = run(Some(&training), "gpu.assist");
    let (_, first_c, third_c, end_c, saved_c) = run(None, "cpu.assist");

    // Between steps the GPU's fields stay as they were; the CPU steps its own.
    assert_eq!(
        first, start,
        "the GPU's parameters came back without a pull"
    );
    assert!(
        dist(&first_c, &start) > 0.0,
        "the CPU's first step moved nothing"
    );
    // Pulled in the callback, at the end, and in the checkpoints: the CPU run's, against
    // how far that moved from the start.
    for (what, g, c) in [
        ("after 3 steps, pulled", &third_g, &third_c),
        ("at the end", &end_g, &end_c),
        ("in the last checkpoint", &saved_g, &saved_c),
    ] {
        let (off, moved) = (dist(g, c), dist(c, &start));
        eprintln!("{what}: the GPU's parameters {off:.2e} from the CPU's, which moved {moved:.2e}");
        assert!(off < 0.01 * moved, "{what}: {off:e} off, moved {moved:e}");
    }
    assert_eq!(saved_g, end_g, "the last checkpoint is the end of the run");
}

/// With poses refined, each step's forward pass runs on the CPU (the poses' gradient needs
/// its tapes, and the nets' backward pass into them, which the GPU's gradient does not
/// leave there): the fields are pulled for it, so the fields and the poses follow the CPU
/// run's. (Before, the poses of a GPU run did not move at all.)
#[test]
fn with_poses_refined_the_cpus_forward_pass_sees_the_gpus_steps() {
    let Some(gpu) = common::gpu() else { return };
    let tmp = TempDir::new("gpu-trainer-poses");
    let ds = synth(&tmp);
    let training = GpuTraining::new(Arc::new(gpu));
    let run = |gpu: Option<&GpuTraining>, name: &str| {
        let mut t = trainer(&ds, gpu, &tmp.join(name), true);
        // Two steps: further on, the runs drift apart as any two do whose rays move with
        // the poses (a pose moved by a hair draws other samples); without the pull the
        // second step's CPU forward pass saw the first fields and the two were 13% (the
        // fields) and 29% (the poses) apart after it.
        t.opts.iters = 2;
        let start = params(&t);
        t.run(|_, _| {}).unwrap();
        let poses = t.resume_state(0.0).pose_corrections.expect("refined poses");
        (start, params(&t), poses)
    };
    let (start, end_g, poses_g) = run(Some(&training), "gpu.assist");
    let (_, end_c, poses_c) = run(None, "cpu.assist");
    let (off, moved) = (dist(&end_g, &end_c), dist(&end_c, &start));
    let norm = |v: &[f32]| v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    let pose_off = norm(
        &poses_g
            .iter()
            .zip(&poses_c)
            .map(|(a, b)| a - b)
            .collect::<Vec<_>>(),
    );
    eprintln!(
        "poses refined: fields {off:.2e} apart (moved {moved:.2e}), poses {pose_off:.2e} apart (moved {:.2e})",
        norm(&poses_c)
    );
    assert!(off < 0.01 * moved, "fields {off:e} apart, moved {moved:e}");
    assert!(norm(&poses_c) > 0.0, "the poses did not move");
    assert!(pose_off < 0.01 * norm(&poses_c), "poses {pose_off:e} apart");
}
