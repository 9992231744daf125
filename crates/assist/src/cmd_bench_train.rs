//! `assist bench train`: a training run as a benchmark, on either device. It trains as
//! `assist train` does (the same flags and defaults) into a temporary folder that is
//! removed afterwards, then reports steps and samples per second, each phase's
//! milliseconds per step and the held-out PSNR, naming the device and the CPU's SIMD.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use assist_session::{TrainConfig, TrainEvent, TrainJob};
use clap::Args;
use serde_json::json;

use crate::cmd_train::flag_error;

#[derive(Args, Debug)]
pub struct TrainBenchArgs {
    /// Dataset (any format `train` reads).
    pub data: PathBuf,
    /// The run's settings, as `train` takes them (give --iters N or --max-time S: the
    /// default is `train`'s 5,000 steps). --out, --resume and --force do not apply.
    #[command(flatten)]
    pub train: TrainConfig,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Train this many times, with seeds --seed, --seed + 1, …, and report each run and
    /// the held-out PSNR's mean, lowest and highest: what the seed alone moves, against
    /// which a change in quality is to be judged.
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u64).range(1..=64))]
    pub seeds: u64,
    /// Where the fields' forward and backward passes and Adam run (as `train --device`).
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

/// A folder removed when dropped (the run's scene and checkpoints).
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub fn run(a: TrainBenchArgs) -> anyhow::Result<()> {
    if a.train.resume {
        anyhow::bail!("--resume: bench train starts afresh (it keeps no scene)");
    }
    if a.seeds == 1 {
        let v = one(&a, a.train.seed)?;
        return show(&a, &v);
    }
    let mut runs = Vec::new();
    for k in 0..a.seeds {
        let seed = a.train.seed.wrapping_add(k);
        eprintln!("seed {seed} ({} of {}):", k + 1, a.seeds);
        let v = one(&a, seed)?;
        if !a.json {
            show(&a, &v)?;
        }
        runs.push(v);
    }
    let psnr: Vec<f64> = runs
        .iter()
        .filter_map(|v| v["held_out"]["psnr"].as_f64())
        .collect();
    let spread = seed_spread(&psnr);
    let v = json!({
        "data": a.data.display().to_string(),
        "seeds": runs.iter().map(|v| v["seed"].clone()).collect::<Vec<_>>(),
        "held_out_psnr": spread.map(|(mean, min, max)| json!({
            "mean": mean, "min": min, "max": max, "spread": max - min,
        })),
        "runs": runs,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if let Some((mean, min, max)) = spread {
        println!(
            "held-out PSNR over {} seeds: mean {mean:.2} dB, lowest {min:.2}, highest {max:.2} (spread {:.2} dB)",
            psnr.len(),
            max - min
        );
    } else {
        println!(
            "{} seeds: no held-out views measured (--eval-views 0)",
            a.seeds
        );
    }
    Ok(())
}

/// The mean, lowest and highest of the runs' held-out PSNRs; none where no run measured
/// any.
fn seed_spread(psnr: &[f64]) -> Option<(f64, f64, f64)> {
    if psnr.is_empty() {
        return None;
    }
    let mean = psnr.iter().sum::<f64>() / psnr.len() as f64;
    let min = psnr.iter().copied().fold(f64::INFINITY, f64::min);
    let max = psnr.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Some((mean, min, max))
}

/// One training run with `seed`, as a benchmark: its figures.
fn one(a: &TrainBenchArgs, seed: u64) -> anyhow::Result<serde_json::Value> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let scratch = Scratch(
        std::env::temp_dir().join(format!("assist-bench-train-{}-{nanos}", std::process::id())),
    );
    std::fs::create_dir_all(&scratch.0)
        .with_context(|| format!("creating {}", scratch.0.display()))?;
    let config = TrainConfig {
        data: a.data.clone(),
        out: scratch.0.join("bench.assist"),
        seed,
        ..a.train.clone()
    };
    let mut job = TrainJob::new(config);
    job.validate().map_err(flag_error)?;
    let device = a.device.open()?;
    if let Some(t) = device.training() {
        job = job.with_optimizers(t);
    }
    // Progress: a line about every 10 s (step, PSNR of the batch, time left).
    let mut shown = Instant::now();
    let outcome = job
        .run(|ev| {
            if let TrainEvent::Step {
                stats, eta_seconds, ..
            } = ev
                && shown.elapsed().as_secs_f64() >= 10.0
            {
                shown = Instant::now();
                eprintln!(
                    "step {} ({:.0} s): batch PSNR {:.2} dB{}",
                    stats.iteration,
                    stats.elapsed,
                    stats.psnr,
                    eta_seconds.map_or(String::new(), |e| format!(", {e:.0} s left"))
                );
            }
        })
        .map_err(flag_error)?;
    device.report();
    let r = &outcome.report;
    let steps = r.steps.max(1) as f64;
    let phases: serde_json::Map<String, serde_json::Value> = r
        .phases
        .named()
        .iter()
        .map(|(n, t)| (n.to_string(), json!(t * 1e3 / steps)))
        .collect();
    let held = outcome.held_out.as_ref();
    Ok(json!({
        "data": a.data.display().to_string(),
        "seed": seed,
        "device": device.name(),
        "simd": assist_simd::level().name(),
        "threads": rayon::current_num_threads(),
        "steps": r.steps,
        "seconds": r.seconds,
        "steps_per_sec": r.steps as f64 / r.seconds.max(1e-9),
        "rays_per_sec": r.rays_per_sec,
        "samples_per_sec": r.samples_per_sec,
        "ms_per_step": phases,
        "batch_psnr": r.final_stats.psnr,
        "held_out": held.map(|h| json!({
            "split": h.split, "views": h.views, "psnr": h.psnr, "ssim": h.ssim,
        })),
    }))
}

/// Prints one run's figures (JSON with --json, else two lines).
fn show(a: &TrainBenchArgs, v: &serde_json::Value) -> anyhow::Result<()> {
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let f = |k: &str| v[k].as_f64().unwrap_or(0.0);
    let parts: Vec<String> = v["ms_per_step"]
        .as_object()
        .into_iter()
        .flatten()
        .map(|(n, t)| format!("{n} {:.1}", t.as_f64().unwrap_or(0.0)))
        .collect();
    let held = &v["held_out"];
    println!(
        "{}: {} steps in {:.1} s on {} ({:.2} steps/s, {:.0} rays/s, {:.2} M samples/s); {}\nms per step: {}",
        a.data.display(),
        v["steps"],
        f("seconds"),
        v["device"].as_str().unwrap_or("?"),
        f("steps_per_sec"),
        f("rays_per_sec"),
        f("samples_per_sec") / 1e6,
        match held["psnr"].as_f64() {
            Some(p) => format!(
                "held-out PSNR {p:.2} dB, SSIM {:.3} ({} {} views)",
                held["ssim"].as_f64().unwrap_or(0.0),
                held["views"],
                held["split"].as_str().unwrap_or("?")
            ),
            None => "no held-out views measured".into(),
        },
        parts.join(", ")
    );
    Ok(())
}
