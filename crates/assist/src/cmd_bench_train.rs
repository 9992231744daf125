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
    let v = json!({
        "data": a.data.display().to_string(),
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
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let parts: Vec<String> = phases
            .iter()
            .map(|(n, t)| format!("{n} {:.1}", t.as_f64().unwrap_or(0.0)))
            .collect();
        println!(
            "{}: {} steps in {:.1} s on {} ({:.2} steps/s, {:.0} rays/s, {:.2} M samples/s); {}\nms per step: {}",
            a.data.display(),
            r.steps,
            r.seconds,
            device.name(),
            r.steps as f64 / r.seconds.max(1e-9),
            r.rays_per_sec,
            r.samples_per_sec / 1e6,
            held.map_or("no held-out views measured".into(), |h| format!(
                "held-out PSNR {:.2} dB, SSIM {:.3} ({} {} views)",
                h.psnr, h.ssim, h.views, h.split
            )),
            parts.join(", ")
        );
    }
    Ok(())
}
