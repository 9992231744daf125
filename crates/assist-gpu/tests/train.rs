//! GPU training kernels against the CPU reference: the gradient of every parameter group
//! after forward + backward, the parameters after Adam steps, and the occupancy grid
//! refreshed from the GPU's density. On lavapipe in CI (with
//! `ASSIST_REQUIRE_GPU=1`), skipped loudly without any adapter elsewhere.

mod common;

use std::sync::Arc;

use assist_core::{DVec3, Rng};
use assist_field::{Adam, OccupancyGrid, Samples, Tape};
use assist_gpu::{GpuField, GpuOptimizer, GpuTrainer};
use assist_scene::NodeField;
use assist_train::{CpuOptimizer, NodeOptimizer};
use common::{configs, gpu, random_field};

struct Batch {
    pos: [Vec<f32>; 3],
    dir: [Vec<f32>; 3],
    image: Vec<u32>,
    d_sigma: Vec<f32>,
    d_rgb: Vec<f32>,
}

/// Rays of 16 samples each with one image per ray (as training batches are), a few
/// with the average code, and random loss gradients.
fn batch(rays: usize, images: usize, seed: u64) -> Batch {
    let mut rng = Rng::new(seed);
    let mut b = Batch {
        pos: Default::default(),
        dir: Default::default(),
        image: Vec::new(),
        d_sigma: Vec::new(),
        d_rgb: Vec::new(),
    };
    for r in 0..rays {
        let img = if r % 7 == 3 {
            u32::MAX
        } else {
            rng.below(images.max(1) as u64) as u32
        };
        let d = [rng.normal(), rng.normal(), rng.normal()];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        for _ in 0..16 {
            for a in 0..3 {
                b.pos[a].push(rng.f32());
                b.dir[a].push((d[a] / len) as f32);
            }
            b.image.push(img);
            b.d_sigma.push((rng.f32() - 0.5) * 1e-2);
            for _ in 0..3 {
                b.d_rgb.push(rng.f32() - 0.5);
            }
        }
    }
    b
}

fn samples(b: &Batch) -> Samples<'_> {
    Samples {
        pos: [&b.pos[0], &b.pos[1], &b.pos[2]],
        dir: [&b.dir[0], &b.dir[1], &b.dir[2]],
        image: &b.image,
    }
}

/// ‖a − b‖ / ‖b‖ over a range.
fn rel(a: &[f32], b: &[f32]) -> f64 {
    let (mut d, mut n) = (0f64, 0f64);
    for (x, y) in a.iter().zip(b) {
        assert!(x.is_finite(), "not finite: {x}");
        d += ((x - y) as f64).powi(2);
        n += (*y as f64).powi(2);
    }
    (d / n.max(1e-30)).sqrt()
}

/// `dw_groups`: the weight-gradient dispatches' workgroups at most (few: each loops over
/// several tiles).
fn check_gradients(float_atomics: bool, tile: Option<u32>, dw_groups: Option<u32>) {
    let Some(gpu) = gpu() else { return };
    for (seed, (name, cfg)) in configs().into_iter().enumerate() {
        let field = random_field(cfg, 3 + seed as u64);
        // 187 rays × 16 = 2992 samples: a partial last tile.
        let b = batch(187, field.config.num_images, 21 + seed as u64);
        let s = samples(&b);
        let n = s.len();
        let mut tape = Tape::default();
        let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
        field.forward_train(&s, &mut tape, &mut sig, &mut rgb);
        let mut g_cpu = vec![0.0f32; field.param_count()];
        field.backward(&s, &mut tape, &b.d_sigma, &b.d_rgb, &mut g_cpu);

        let mut gf = GpuField::with_tile(&gpu, &field, tile).expect("upload");
        let adam = Adam::for_field(&field);
        let mut tr = GpuTrainer::with_atomics(&gpu, &gf, &field, &adam, float_atomics)
            .expect("training kernels");
        if let Some(g) = dw_groups {
            tr.set_dw_groups(g);
        }
        gf.load(&gpu, &s).expect("load");
        tr.set_loss_grads(&gpu, &gf, &field, &b.d_sigma, &b.d_rgb)
            .expect("loss gradients");
        tr.submit_step(&gpu, &gf, 1).expect("step");
        let g_gpu = tr.read_grad(&gpu).expect("read");
        for (group, start, len) in field.layout.groups(&field.config) {
            let r = rel(&g_gpu[start..start + len], &g_cpu[start..start + len]);
            let norm: f64 = g_cpu[start..start + len]
                .iter()
                .map(|v| (*v as f64).powi(2))
                .sum();
            assert!(
                norm > 0.0 || group.starts_with("grid"),
                "{name}: {group} has no gradient"
            );
            assert!(
                r < 1e-4,
                "{name} (float atomics {float_atomics}): {group}: relative error {r:.2e}"
            );
        }
        eprintln!(
            "{name} (float atomics {float_atomics}): gradients within {:.1e}",
            rel(&g_gpu, &g_cpu)
        );
    }
}

#[test]
fn gradients_match_cpu_with_float_atomics() {
    // With 64 samples per workgroup, which adapters with 64-wide subgroups get (lavapipe
    // and NVIDIA get 32).
    check_gradients(true, Some(64), None);
}

#[test]
fn gradients_match_cpu_with_compare_exchange() {
    // Also with the smallest tile (16 samples per workgroup), which narrow adapters get,
    // and 5 weight-gradient workgroups for the batch's 187 tiles.
    check_gradients(false, Some(16), Some(5));
}

#[test]
fn adam_steps_match_cpu() {
    let Some(gpu) = gpu() else { return };
    let (_, cfg) = configs().remove(0);
    let mut field = random_field(cfg, 5);
    let b = batch(64, field.config.num_images, 2);
    let s = samples(&b);
    let n = s.len();
    let mut gf = GpuField::new(&gpu, &field).expect("upload");
    let mut adam = Adam::for_field(&field);
    adam.weight_decay = 1e-3;
    adam.decay_range = field.layout.mlp_start()..field.layout.appearance;
    adam.table_decay = 0.5;
    // The same steps on the CPU without the tables' decay: what the GPU must not match.
    let (mut undecayed, mut adam0) = (field.clone(), adam.clone());
    adam0.table_decay = 0.0;
    let mut tr = GpuTrainer::new(&gpu, &gf, &field, &adam).expect("kernels");
    gf.load(&gpu, &s).expect("load");
    tr.set_loss_grads(&gpu, &gf, &field, &b.d_sigma, &b.d_rgb)
        .expect("grads");
    let mut tape = Tape::default();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    let mut grad = vec![0.0f32; field.param_count()];
    // Three steps on each: the parameters move and the two stay together.
    let before = field.params.clone();
    for _ in 0..3 {
        field.forward_train(&s, &mut tape, &mut sig, &mut rgb);
        field.backward(&s, &mut tape, &b.d_sigma, &b.d_rgb, &mut grad);
        adam.update(1e-2, &mut field.params, &mut grad);
        undecayed.forward_train(&s, &mut tape, &mut sig, &mut rgb);
        undecayed.backward(&s, &mut tape, &b.d_sigma, &b.d_rgb, &mut grad);
        adam0.update(1e-2, &mut undecayed.params, &mut grad);
        tr.submit_step(&gpu, &gf, 1).expect("step");
        tr.submit_adam(&gpu, 1e-2);
    }
    let p_gpu = gf.read_params(&gpu).expect("read");
    let moved = rel(&field.params, &before);
    let off = rel(&p_gpu, &field.params);
    eprintln!("3 Adam steps: parameters moved {moved:.2e}, GPU from CPU {off:.2e}");
    assert!(moved > 1e-3, "Adam did not move the parameters ({moved:e})");
    assert!(
        off < 1e-4 * moved.max(1e-3) * 1e3,
        "GPU parameters differ by {off:e}"
    );
    let by_decay = rel(&undecayed.params, &field.params);
    eprintln!("the tables' decay moved the CPU's parameters {by_decay:.2e}");
    assert!(
        off < 0.1 * by_decay,
        "GPU {off:e} off, the decay {by_decay:e}"
    );
    // Untouched hash entries stay exactly as they were on both.
    let grid = field.layout.grid.param_count();
    let same_cpu = (0..grid).filter(|&i| field.params[i] == before[i]).count();
    let same_gpu = (0..grid).filter(|&i| p_gpu[i] == before[i]).count();
    assert_eq!(same_cpu, same_gpu, "untouched table entries differ");
    assert!(same_cpu > 0);
    assert!(
        tr.read_grad(&gpu).expect("grad").iter().all(|&g| g == 0.0),
        "Adam leaves the gradient zeroed"
    );
    // The per-code biases (the average code's too: every seventh ray has no image) are
    // refreshed after Adam: the GPU's colours are the CPU's.
    let (mut sig_c, mut rgb_c) = (vec![0.0; n], vec![0.0; 3 * n]);
    field.forward(&s, &mut sig_c, &mut rgb_c);
    gf.forward(&gpu, &s, &mut sig, &mut rgb).expect("forward");
    let (r_sig, r_rgb) = (rel(&sig, &sig_c), rel(&rgb, &rgb_c));
    eprintln!("outputs after Adam: σ {r_sig:.1e}, rgb {r_rgb:.1e} from the CPU's");
    assert!(r_sig < 1e-4 && r_rgb < 1e-4, "σ {r_sig:e}, rgb {r_rgb:e}");
    // Without the refresh (the biases of the field as it was), the colours are off.
    let mut stale = field.clone();
    stale.params[field.layout.appearance..].copy_from_slice(&before[field.layout.appearance..]);
    stale.forward(&s, &mut sig_c, &mut rgb_c);
    let r_stale = rel(&rgb, &rgb_c);
    assert!(
        r_stale > 10.0 * r_rgb,
        "stale codes {r_stale:e}, GPU {r_rgb:e}"
    );
}

#[test]
fn occupancy_refresh_on_the_gpu_matches_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let (_, cfg) = configs().remove(0);
    let nf = NodeField::new(random_field(cfg, 9), OccupancyGrid::new(64), DVec3::ONE);
    let (mut on_cpu, mut on_gpu) = (nf.clone(), nf);
    let mut cpu = CpuOptimizer::new(&on_cpu, 0.0);
    let mut opt = GpuOptimizer::new(Arc::new(gpu), &on_gpu, 0.0).expect("GPU optimizer");
    let (mut r1, mut r2) = (Rng::new(4), Rng::new(4));
    for round in 0..2 {
        cpu.refresh_occupancy(&mut on_cpu, &mut r1, round);
        opt.refresh_occupancy(&mut on_gpu, &mut r2, round);
    }
    assert!(!opt.fell_back(), "the refresh ran on the CPU");
    let (c, g) = (&on_cpu.occupancy, &on_gpu.occupancy);
    let worst = c
        .density
        .iter()
        .zip(&g.density)
        .map(|(a, b)| (a - b).abs() / (a.abs() + 1e-3))
        .fold(0f32, f32::max);
    eprintln!("occupancy densities: GPU within {worst:.1e} of the CPU");
    assert!(worst < 1e-4, "densities differ by {worst:e}");
    // The same cells occupied, but where a density lies within rounding of the threshold
    // (the mean density, or the grid's own threshold below it).
    let mean = c.density.iter().map(|&d| d as f64).sum::<f64>() / c.density.len() as f64;
    let thr = c.threshold.min(mean as f32);
    let mut differ = 0;
    for cell in 0..c.cells() {
        if c.is_occupied_cell(cell) != g.is_occupied_cell(cell) {
            differ += 1;
            let d = c.density[cell];
            assert!(
                (d - thr).abs() <= 1e-4 * thr.abs().max(1e-6),
                "cell {cell}: density {d} against threshold {thr}, occupied on one only"
            );
        }
    }
    let occupied = c.occupied_fraction();
    eprintln!("{occupied:.3} of the cells occupied, {differ} differ at the threshold");
    assert!(occupied > 0.01 && occupied < 0.99, "occupied {occupied}");
}

/// Through the trainer's seam: the GPU's steps leave the field as it was until it is
/// pulled, then it holds what the CPU's optimizer made of the same steps; a field changed
/// on the CPU while the GPU is ahead is refused, and after a pull it is uploaded.
#[test]
fn stepped_parameters_stay_on_the_gpu_until_pulled() {
    let Some(gpu) = gpu() else { return };
    let (_, cfg) = configs().remove(0);
    let nf = NodeField::new(random_field(cfg, 6), OccupancyGrid::new(16), DVec3::ONE);
    let b = batch(64, nf.field.config.num_images, 3);
    let s = samples(&b);
    let (mut on_cpu, mut on_gpu) = (nf.clone(), nf.clone());
    let mut cpu = CpuOptimizer::new(&on_cpu, 0.0);
    let gpu = Arc::new(gpu);
    let mut opt = GpuOptimizer::new(gpu.clone(), &on_gpu, 0.0).expect("GPU optimizer");
    // Nothing to collect before a pass is started.
    let e = opt.forward_finish(&mut [], &mut []).unwrap_err();
    assert!(e.contains("no forward pass"), "{e}");
    // The trainer's way: the forward pass first (its record kept), then the gradient.
    let mut fwd_first = nf.clone();
    let mut opt2 = GpuOptimizer::new(gpu, &fwd_first, 0.0).expect("GPU optimizer");
    let mut tape = Tape::default();
    let n = s.len();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    let (mut sig_g, mut rgb_g) = (vec![0.0; n], vec![0.0; 3 * n]);
    for _ in 0..3 {
        opt2.forward(&fwd_first, &s, &mut sig_g, &mut rgb_g)
            .expect("a GPU forward pass")
            .unwrap();
        // (Pulled for the CPU's forward pass, as the trainer pulls before one.)
        opt2.pull(&mut fwd_first).unwrap();
        fwd_first.field.forward(&s, &mut sig, &mut rgb);
        let (r_sig, r_rgb) = (rel(&sig_g, &sig), rel(&rgb_g, &rgb));
        assert!(r_sig < 1e-4 && r_rgb < 1e-4, "σ {r_sig:e}, rgb {r_rgb:e}");
        opt2.accumulate(&fwd_first, &s, &mut tape, &b.d_sigma, &b.d_rgb)
            .unwrap();
        opt2.step(&mut fwd_first, 1e-2).unwrap();
        on_cpu
            .field
            .forward_train(&s, &mut tape, &mut sig, &mut rgb);
        cpu.accumulate(&on_cpu, &s, &mut tape, &b.d_sigma, &b.d_rgb)
            .unwrap();
        cpu.step(&mut on_cpu, 1e-2).unwrap();
        opt.accumulate(&on_gpu, &s, &mut tape, &b.d_sigma, &b.d_rgb)
            .unwrap();
        opt.step(&mut on_gpu, 1e-2).unwrap();
    }
    assert_eq!(
        on_gpu.field.params, nf.field.params,
        "read back before a pull"
    );
    opt.pull(&mut on_gpu).unwrap();
    let moved = rel(&on_cpu.field.params, &nf.field.params);
    let off = rel(&on_gpu.field.params, &on_cpu.field.params);
    eprintln!("pulled after 3 steps: moved {moved:.2e}, GPU from CPU {off:.2e}");
    assert!(
        moved > 1e-3,
        "the steps did not move the parameters ({moved:e})"
    );
    assert!(off < 0.1 * moved, "GPU parameters differ by {off:e}");
    // The same steps from the kept record: the same parameters.
    opt2.pull(&mut fwd_first).unwrap();
    let apart = rel(&fwd_first.field.params, &on_gpu.field.params);
    eprintln!("from the forward pass's record: {apart:.1e} from the full steps'");
    assert!(apart < 1e-3 * moved, "{apart:e}");
    // A second pull reads nothing new: the field stays as pulled.
    let pulled = on_gpu.field.params.clone();
    opt.pull(&mut on_gpu).unwrap();
    assert_eq!(on_gpu.field.params, pulled);

    // Changed on the CPU while the GPU is ahead: both calls refuse, nothing is lost.
    opt.accumulate(&on_gpu, &s, &mut tape, &b.d_sigma, &b.d_rgb)
        .unwrap();
    opt.step(&mut on_gpu, 1e-2).unwrap();
    let k = on_gpu.field.layout.mlp_start();
    let kept = on_gpu.field.params[k];
    on_gpu.field.params[k] += 1.0;
    let e = opt
        .accumulate(&on_gpu, &s, &mut tape, &b.d_sigma, &b.d_rgb)
        .unwrap_err();
    assert!(e.contains("changed on the CPU"), "{e}");
    assert!(
        opt.pull(&mut on_gpu)
            .unwrap_err()
            .contains("changed on the CPU")
    );
    // Put back, it pulls; a change then is uploaded and its forward pass is the CPU's.
    on_gpu.field.params[k] = kept;
    opt.pull(&mut on_gpu).unwrap();
    assert_ne!(on_gpu.field.params, pulled, "the fourth step came back");
    on_gpu.field.params[k] += 0.5;
    opt.forward(&on_gpu, &s, &mut sig_g, &mut rgb_g)
        .expect("a GPU forward pass")
        .unwrap();
    on_gpu.field.forward(&s, &mut sig, &mut rgb);
    let (r_sig, r_rgb) = (rel(&sig_g, &sig), rel(&rgb_g, &rgb));
    assert!(r_sig < 1e-4 && r_rgb < 1e-4, "σ {r_sig:e}, rgb {r_rgb:e}");
}
