//! `assist bench field`: training-step and inference throughput of the field engine;
//! `assist bench prior`: the built-in background priors against background ground truth.

use std::time::Instant;

use assist_core::Rng;
use assist_field::{Adam, Field, FieldConfig, OccupancyGrid, PhaseTimes, Precision, Samples, Tape};
use assist_simd::Products;
use clap::{Args, Subcommand};
use serde_json::{Value, json};

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Field throughput: training step (forward + backward + Adam) and inference, in
    /// samples/s, at Nerfacto size and at object size, with a time breakdown.
    Field(FieldBenchArgs),
    /// Background priors: each built-in fill (push-pull, exemplar) against a dataset's
    /// `background/` ground truth under the objects, and its time per view.
    Prior(PriorBenchArgs),
    /// The viewer's latency on a trained scene: preview frame, full frame, drag update
    /// (with the drag cache), and preview frames/s with 1, 2 and 4 clients.
    View(crate::cmd_bench_view::ViewBenchArgs),
    /// A training run's speed on either device: steps and samples per second, each
    /// phase's time per step, the held-out PSNR reached (as `train`, nothing kept).
    Train(crate::cmd_bench_train::TrainBenchArgs),
    /// A rendered frame's cost on a scene's held-out views: samples per ray marched and
    /// queried, time per stage, and the PSNR each renderer setting costs.
    Render(crate::cmd_bench_render::RenderBenchArgs),
    /// Exported meshes against a dataset's ground truth (instance masks with depth,
    /// back-projected): Chamfer distance both ways and extraction time per node.
    Mesh(crate::cmd_bench_mesh::MeshBenchArgs),
    /// Embedding a scene's nodes with CLIP, and resolving object phrases by meaning.
    Embed(crate::cmd_bench_embed::EmbedBenchArgs),
    /// `assist process` on a posed dataset's photographs against its own poses:
    /// registration, camera-centre error after a similarity, time per stage.
    Process(crate::cmd_bench_process::ProcessBenchArgs),
    /// Masks derived from object boxes on a scene trained without masks, against the
    /// dataset's instance masks: IoU per object, mIoU, time.
    Split(crate::cmd_bench_split::SplitBenchArgs),
    /// `assist generate merge` on a run split into many shards: time and peak memory.
    Merge(crate::cmd_bench_merge::MergeBenchArgs),
    /// Segment Anything on this machine: load, embedding a photograph, one prompt's
    /// masks (a random ViT-B unless --checkpoint).
    Sam(crate::cmd_bench_sam::SamBenchArgs),
}

#[derive(Args, Debug)]
pub struct PriorBenchArgs {
    /// Dataset with instance masks and a `background/` folder (desk format).
    pub data: std::path::PathBuf,
    /// Views to fill: train, val, test or all (those with a background/ view count).
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args, Debug)]
pub struct FieldBenchArgs {
    /// Rays per batch (samples = rays × samples-per-ray).
    #[arg(long, default_value_t = 4096)]
    pub rays: usize,
    /// Samples along each ray.
    #[arg(long, default_value_t = 64)]
    pub samples_per_ray: usize,
    /// Timed steps (after 2 warm-up steps); the median is reported.
    #[arg(long, default_value_t = 8)]
    pub steps: usize,
    /// Only the Nerfacto-size field.
    #[arg(long)]
    pub nerfacto_only: bool,
    /// Also time the field's inference on a GPU: auto (a hardware adapter if present),
    /// gpu (any adapter, lavapipe included; an error without one) or cpu (none).
    #[arg(long, default_value = "cpu")]
    pub device: assist_gpu::DeviceChoice,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(c: BenchCommand) -> anyhow::Result<()> {
    match c {
        BenchCommand::Field(a) => field(a),
        BenchCommand::Prior(a) => prior(a),
        BenchCommand::View(a) => crate::cmd_bench_view::run(a),
        BenchCommand::Render(a) => crate::cmd_bench_render::run(a),
        BenchCommand::Train(a) => crate::cmd_bench_train::run(a),
        BenchCommand::Mesh(a) => crate::cmd_bench_mesh::run(a),
        BenchCommand::Embed(a) => crate::cmd_bench_embed::run(a),
        BenchCommand::Process(a) => crate::cmd_bench_process::run(a),
        BenchCommand::Split(a) => crate::cmd_bench_split::run(a),
        BenchCommand::Merge(a) => crate::cmd_bench_merge::run(a),
        BenchCommand::Sam(a) => crate::cmd_bench_sam::run(a),
    }
}

/// A training-like batch: rays through the unit box, evenly spaced samples inside it.
struct Batch {
    pos: [Vec<f32>; 3],
    dir: [Vec<f32>; 3],
    image: Vec<u32>,
}

fn make_batch(rays: usize, spr: usize, images: usize, rng: &mut Rng) -> Batch {
    let n = rays * spr;
    let mut b = Batch {
        pos: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        dir: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        image: vec![0; n],
    };
    for r in 0..rays {
        // Entry and exit points on the box surface (random points on two random faces).
        let face_point = |rng: &mut Rng| {
            let mut p = [rng.f32(), rng.f32(), rng.f32()];
            p[rng.below(3) as usize] = if rng.f32() < 0.5 { 0.0 } else { 1.0 };
            p
        };
        let (a, e) = (face_point(rng), face_point(rng));
        let d = [e[0] - a[0], e[1] - a[1], e[2] - a[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
        let img = rng.below(images.max(1) as u64) as u32;
        for k in 0..spr {
            let t = (k as f32 + rng.f32()) / spr as f32;
            let i = r * spr + k;
            for ax in 0..3 {
                b.pos[ax][i] = a[ax] + d[ax] * t;
                b.dir[ax][i] = d[ax] / len;
            }
            b.image[i] = img;
        }
    }
    b
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The median (the upper one of an even count) of timings; the benches quote medians.
pub(crate) fn median_of(mut v: Vec<f64>) -> f64 {
    median(&mut v)
}

fn bench_one(
    name: &str,
    cfg: FieldConfig,
    grid_res: u32,
    a: &FieldBenchArgs,
    show: bool,
    gpu: Option<&assist_gpu::Gpu>,
) -> anyhow::Result<Value> {
    let mut rng = Rng::new(1);
    let images = cfg.num_images;
    let mut field = Field::new(cfg, 1)?;
    let b = make_batch(a.rays, a.samples_per_ray, images, &mut rng);
    let s = Samples {
        pos: [&b.pos[0], &b.pos[1], &b.pos[2]],
        dir: [&b.dir[0], &b.dir[1], &b.dir[2]],
        image: &b.image,
    };
    let n = s.len();
    let d_sigma: Vec<f32> = (0..n).map(|_| (rng.f32() - 0.5) * 1e-3).collect();
    let d_rgb: Vec<f32> = (0..3 * n).map(|_| (rng.f32() - 0.5) * 1e-3).collect();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    let mut grad = vec![0.0f32; field.param_count()];
    let mut adam = Adam::for_field(&field);
    let mut tape = Tape::default();
    let (mut step_times, mut adam_times) = (Vec::new(), Vec::new());
    let mut phases = PhaseTimes::default();
    let mut swept = field.param_count();
    for i in 0..a.steps + 2 {
        tape.times = PhaseTimes::default();
        let t0 = Instant::now();
        field.forward_train(&s, &mut tape, &mut sig, &mut rgb);
        field.backward(&s, &mut tape, &d_sigma, &d_rgb, &mut grad);
        if i == 0 {
            // Every step's batch is the same, so its lines are the same.
            swept = swept_params(&adam, &grad);
        }
        let t1 = Instant::now();
        adam.update(1e-2, &mut field.params, &mut grad);
        let t2 = Instant::now();
        if i >= 2 {
            step_times.push((t2 - t0).as_secs_f64());
            adam_times.push((t2 - t1).as_secs_f64());
            let t = tape.times;
            phases.encode_forward += t.encode_forward / a.steps as f64;
            phases.mlp_forward += t.mlp_forward / a.steps as f64;
            phases.mlp_backward += t.mlp_backward / a.steps as f64;
            phases.encode_backward += t.encode_backward / a.steps as f64;
        }
    }
    // Inference as `assist render` runs it (the fastest precision here, the hash tables
    // packed as bf16 pairs), and in f32 from the parameters.
    let tables = field.pack_tables();
    let mut infer_at = |precision: Precision| {
        let packed = (precision == Precision::Bf16)
            .then_some(tables.as_ref())
            .flatten();
        let mut times = Vec::new();
        let mut scratch = Tape::default();
        for i in 0..a.steps + 1 {
            let t0 = Instant::now();
            field.forward_at(
                precision,
                packed,
                None,
                &s,
                &mut scratch,
                &mut sig,
                &mut rgb,
            );
            if i >= 1 {
                times.push(t0.elapsed().as_secs_f64());
            }
        }
        median(&mut times)
    };
    let precision = Precision::fastest();
    let infer = infer_at(precision);
    let label = match (precision, assist_simd::products()) {
        (Precision::Bf16, Products::Bf16) => "bf16",
        (Precision::Bf16, Products::Fixed16) => "bf16 tables, 16-bit fixed-point products",
        (Precision::Bf16, Products::F32) => "bf16 tables, f32 products",
        (Precision::F32, _) => "f32",
    };
    let (occupancy_t, occupancy_cells) = occupancy_round(&field, grid_res, a.steps, &mut rng);
    let infer_f32 = infer_at(Precision::F32);
    let step = median(&mut step_times);
    let adam_t = median(&mut adam_times);
    let macs = field.mlp_macs_per_sample() as f64;
    let train_sps = n as f64 / step;
    let infer_sps = n as f64 / infer;
    let mlp_train_gflops =
        3.0 * 2.0 * macs * n as f64 / (phases.mlp_forward + phases.mlp_backward) / 1e9;
    let gpu = match gpu {
        Some(g) => crate::cmd_bench_gpu::field(g, &field, &s, (&d_sigma, &d_rgb), a.steps, show)?,
        None => Value::Null,
    };
    let v = json!({
        "gpu": gpu,
        "field": name,
        "params": field.param_count(),
        "batch_samples": n,
        "train_samples_per_sec": train_sps,
        "infer_samples_per_sec": infer_sps,
        "train_step_seconds": step,
        "infer_seconds": infer,
        "infer_precision": label,
        "infer_f32_samples_per_sec": n as f64 / infer_f32,
        "breakdown_seconds": {
            "encode_forward": phases.encode_forward,
            "mlp_forward": phases.mlp_forward,
            "mlp_backward": phases.mlp_backward,
            "encode_backward": phases.encode_backward,
            "adam": adam_t,
        },
        "occupancy_grid": grid_res,
        "occupancy_cells_per_round": occupancy_cells,
        "occupancy_round_seconds": occupancy_t,
        "mlp_macs_per_sample": macs,
        "mlp_train_gflops": mlp_train_gflops,
        "adam_swept_params": swept,
        "adam_gbytes_per_sec": 7.0 * 4.0 * swept as f64 / adam_t / 1e9,
    });
    if show {
        eprintln!(
            "{name:>9}: train {:.3} M samples/s ({:.1} ms/step of {n}), infer {:.3} M samples/s ({}; f32 {:.3} M) | encode fwd {:.1} ms, mlp fwd {:.1} ms, mlp bwd {:.1} ms, encode bwd {:.1} ms, adam {:.1} ms | MLP {:.1} GFLOP/s | occupancy round ({}³ grid, {} cells) {:.1} ms",
            train_sps / 1e6,
            step * 1e3,
            infer_sps / 1e6,
            label,
            n as f64 / infer_f32 / 1e6,
            phases.encode_forward * 1e3,
            phases.mlp_forward * 1e3,
            phases.mlp_backward * 1e3,
            phases.encode_backward * 1e3,
            adam_t * 1e3,
            mlp_train_gflops,
            grid_res,
            occupancy_cells,
            occupancy_t * 1e3
        );
    }
    Ok(v)
}

/// One occupancy-grid update round as training runs it (every 16 steps), on a grid of the
/// size training gives this field: the median seconds over rounds (the first, which
/// allocates, not timed) and the cells a round refreshes.
fn occupancy_round(field: &Field, grid_res: u32, steps: usize, rng: &mut Rng) -> (f64, usize) {
    let mut grid = OccupancyGrid::new(grid_res);
    let mut times = Vec::new();
    for round in 0..steps.max(grid.parts()) + 1 {
        let t0 = Instant::now();
        grid.update_round(field, rng, round);
        if round >= 1 {
            times.push(t0.elapsed().as_secs_f64());
        }
    }
    (median(&mut times), grid.cells() / grid.parts())
}

/// Parameters Adam's sweep reads and writes: every one outside the hash tables, and the
/// tables' lines of 16 values that hold a gradient (it skips the others whole).
fn swept_params(adam: &Adam, grad: &[f32]) -> usize {
    let tables = &grad[adam.sparse_range.clone()];
    let lines = tables
        .chunks(16)
        .filter(|l| l.iter().any(|&g| g != 0.0))
        .count();
    grad.len() - tables.len() + lines * 16
}

/// GFLOP/s of the MLP product kernel on one core (64×64 weights times 64×64 samples, as
/// in one chunk of a layer), at every SIMD level this CPU has.
fn gemm_gflops() -> Value {
    use assist_simd::gemm::{Gemm, gemm_at};
    let (m, n, k) = (64, 64, 64);
    let a = vec![0.5f32; m * k];
    let b = vec![0.25f32; k * n];
    let mut c = vec![0.0f32; m * n];
    let mut out = serde_json::Map::new();
    for level in [
        assist_simd::Level::Scalar,
        assist_simd::Level::Avx2,
        assist_simd::Level::Avx512,
    ] {
        if !level.supported() {
            continue;
        }
        let g = Gemm {
            m,
            n,
            k,
            a: &a,
            lda: k,
            b: &b,
            ldb: n,
            ldc: n,
            accumulate: true,
        };
        let start = Instant::now();
        let mut iters = 0u64;
        while start.elapsed().as_secs_f64() < 0.2 {
            for _ in 0..100 {
                gemm_at(level, &g, &mut c);
            }
            iters += 100;
        }
        let gf = 2.0 * (m * n * k) as f64 * iters as f64 / start.elapsed().as_secs_f64() / 1e9;
        out.insert(level.name().to_string(), json!(gf));
    }
    if assist_simd::bf16::cpu_has_bf16() {
        // The bf16 kernel as inference runs it: activations packed, then the product.
        use assist_simd::bf16;
        let level = assist_simd::Level::Avx512;
        let pa = bf16::PackedA::new(&a, m, k, k);
        let mut bp = vec![0u32; k.div_ceil(2) * n];
        let start = Instant::now();
        let mut iters = 0u64;
        while start.elapsed().as_secs_f64() < 0.2 {
            for _ in 0..100 {
                bf16::pack_b(level, &b, k, n, n, &mut bp);
                bf16::gemm(level, &pa, &bp, n, &mut c, n);
            }
            iters += 100;
        }
        let gf = 2.0 * (m * n * k) as f64 * iters as f64 / start.elapsed().as_secs_f64() / 1e9;
        out.insert("avx512bf16 (pack + product)".to_string(), json!(gf));
    }
    // The fixed-point kernel as inference runs it: activations scaled and packed, then the
    // product; at the AVX2 level, and at AVX-512 with VNNI where the CPU has it.
    use assist_simd::{Level, fixed16};
    for (level, name) in [
        (Level::Avx2, "avx2 fixed16 (scale + product)"),
        (Level::Avx512, "avx512vnni fixed16 (scale + product)"),
    ] {
        if !level.supported() || (level == Level::Avx512 && !fixed16::vnni()) {
            continue;
        }
        let qa = fixed16::QuantA::new(&a, m, k, k);
        let (mut bp, mut sb) = (vec![0u32; k.div_ceil(2) * n], vec![0.0f32; n]);
        let start = Instant::now();
        let mut iters = 0u64;
        while start.elapsed().as_secs_f64() < 0.2 {
            for _ in 0..100 {
                fixed16::quant_b(level, &b, k, n, n, &mut bp, &mut sb);
                fixed16::gemm(level, &qa, &bp, &sb, n, &mut c, n);
            }
            iters += 100;
        }
        let gf = 2.0 * (m * n * k) as f64 * iters as f64 / start.elapsed().as_secs_f64() / 1e9;
        out.insert(name.to_string(), json!(gf));
    }
    std::hint::black_box(&c);
    Value::Object(out)
}

fn field(a: FieldBenchArgs) -> anyhow::Result<()> {
    for (name, v) in [
        ("--rays", a.rays),
        ("--samples-per-ray", a.samples_per_ray),
        ("--steps", a.steps),
    ] {
        if v == 0 {
            anyhow::bail!("{name}: expected a whole number ≥ 1, got 0");
        }
    }
    if a.rays.saturating_mul(a.samples_per_ray) > 1 << 24 {
        anyhow::bail!(
            "--rays × --samples-per-ray: expected at most 16,777,216 samples per batch, got {}",
            a.rays.saturating_mul(a.samples_per_ray)
        );
    }
    let level = assist_simd::level();
    let threads = rayon::current_num_threads();
    let peak_core = assist_simd::peak::fma_gflops(level, 0.3);
    let memory = assist_simd::peak::memory_gbytes(0.3, threads);
    let show = !a.json;
    let gemm = gemm_gflops();
    if show {
        eprintln!(
            "SIMD {} · {threads} threads · measured FMA peak {peak_core:.1} GFLOP/s per core ({:.1} total) · memory {memory:.1} GB/s",
            level.name(),
            peak_core * threads as f64
        );
        eprintln!("MLP product kernel (64×64×64, one core), GFLOP/s: {gemm}");
    }
    // The occupancy grids training builds for a background and for an object.
    let grids = assist_train::SetupOptions::default();
    let gpu = assist_gpu::Gpu::open(a.device)?;
    if show {
        match &gpu {
            Some(g) => eprintln!("GPU: {}", g.name()),
            None if a.device == assist_gpu::DeviceChoice::Auto => {
                eprintln!("GPU: none found (auto): CPU figures only")
            }
            None => {}
        }
    }
    let mut results = vec![bench_one(
        "nerfacto",
        FieldConfig::nerfacto(100),
        grids.background_grid,
        &a,
        show,
        gpu.as_ref(),
    )?];
    if !a.nerfacto_only {
        results.push(bench_one(
            "object",
            FieldConfig::object(100),
            grids.object_grid,
            &a,
            show,
            gpu.as_ref(),
        )?);
    }
    // How far each phase is from what bounds it: the nets' products from the FMA peak of
    // every thread, Adam's sweep from the memory's bandwidth.
    for v in &mut results {
        let mlp = v["mlp_train_gflops"].as_f64().unwrap_or(0.0) / (peak_core * threads as f64);
        let adam = v["adam_gbytes_per_sec"].as_f64().unwrap_or(0.0) / memory;
        v["mlp_share_of_peak"] = json!(mlp);
        v["adam_share_of_bandwidth"] = json!(adam);
        if show {
            eprintln!(
                "{:>9}: the MLP at {:.0}% of the FMA peak, Adam at {:.0}% of the memory bandwidth",
                v["field"].as_str().unwrap_or(""),
                mlp * 100.0,
                adam * 100.0
            );
        }
    }
    let nerf = &results[0];
    let out = json!({
        "train_samples_per_sec": nerf["train_samples_per_sec"],
        "infer_samples_per_sec": nerf["infer_samples_per_sec"],
        "simd": level.name(),
        "device": gpu.as_ref().map(|g| g.name()),
        "threads": threads,
        "peak_gflops_per_core": peak_core,
        "peak_gflops_total": peak_core * threads as f64,
        "memory_gbytes_per_sec": memory,
        "gemm_gflops_per_core": gemm,
        "fields": results,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    Ok(())
}

fn prior(a: PriorBenchArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use assist_train::PriorKind;
    use std::io::IsTerminal;
    let split = crate::cmd_eval::parse_split(&a.split)?;
    let ds = assist_data::load(&a.data, &Default::default())
        .with_context(|| format!("loading dataset {}", a.data.display()))?;
    let bar = crate::progress::bar(!a.json && std::io::stderr().is_terminal(), "prior");
    let kinds = [
        PriorKind::PushPull,
        PriorKind::Exemplar,
        PriorKind::MultiView,
    ];
    let r = assist_train::evaluate_priors(&ds, split, &kinds, crate::progress::steps(&bar))?;
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{} views, {} pixels under objects",
            r.views, r.occluded_pixels
        );
        for s in &r.scores {
            println!(
                "{:>10}: {:.2} dB under the objects, {:.3} s per view",
                serde_json::to_value(s.prior)?.as_str().unwrap_or("?"),
                s.occluded_psnr,
                s.seconds_per_view
            );
        }
    }
    Ok(())
}
