//! `assist bench field --device gpu`: the GPU kernels' throughput on the batch the CPU
//! figures use, beside them, with the largest difference from the CPU's outputs.

use std::time::Instant;

use assist_field::{Adam, Field, Samples};
use assist_gpu::{Gpu, GpuField, GpuTrainer};
use serde_json::{Value, json};

/// Runs queued back to back per resident timing.
const QUEUED: usize = 8;

use crate::cmd_bench::median_of as median;

/// Inference and density over `s` on `gpu`, the median of `steps` timings after one
/// warm-up: resident (the batch already in GPU memory, as rendering and training use it;
/// `QUEUED` runs back to back per timing, so that one submission's latency is spread),
/// one run waited for alone (what a single frame's batch sees), and with the batch's
/// upload and the outputs' read-back.
pub fn field(
    gpu: &Gpu,
    field: &Field,
    s: &Samples,
    loss: (&[f32], &[f32]),
    steps: usize,
    show: bool,
) -> anyhow::Result<Value> {
    let n = s.len();
    let t0 = Instant::now();
    let mut gf = GpuField::new(gpu, field)?;
    let (mut sig, mut rgb) = (vec![0.0f32; n], vec![0.0f32; 3 * n]);
    gf.forward(gpu, s, &mut sig, &mut rgb)?;
    let setup = t0.elapsed().as_secs_f64();
    let (mut sig_c, mut rgb_c) = (vec![0.0f32; n], vec![0.0f32; 3 * n]);
    field.forward(s, &mut sig_c, &mut rgb_c);
    let diff = |g: &[f32], c: &[f32]| {
        g.iter()
            .zip(c)
            .map(|(g, c)| (g - c).abs() / (c.abs() + 1e-3))
            .fold(
                0.0f32,
                |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) },
            )
    };
    let (d_sigma, d_rgb) = (diff(&sig, &sig_c), diff(&rgb, &rgb_c));
    let timed = |f: &mut dyn FnMut() -> anyhow::Result<()>| -> anyhow::Result<f64> {
        f()?;
        let mut t = Vec::with_capacity(steps);
        for _ in 0..steps {
            let t0 = Instant::now();
            f()?;
            t.push(t0.elapsed().as_secs_f64());
        }
        Ok(median(t))
    };
    gf.load(gpu, s)?;
    let q = QUEUED as f64;
    let infer = timed(&mut || Ok(gf.run_forward(gpu, QUEUED)?))? / q;
    let density = timed(&mut || Ok(gf.run_density(gpu, QUEUED)?))? / q;
    let single = timed(&mut || Ok(gf.run_forward(gpu, 1)?))?;
    // Training steps as the CPU figure counts them: forward with its record, backward,
    // Adam; the loss's gradients are the CPU bench's.
    let mut tr = GpuTrainer::new(gpu, &gf, field, &Adam::for_field(field))?;
    tr.set_loss_grads(gpu, &gf, field, loss.0, loss.1)?;
    let stages = tr.time_stages(gpu, &gf, QUEUED)?;
    let train = timed(&mut || {
        for _ in 0..QUEUED {
            tr.submit_step(gpu, &gf, 1)?;
            tr.submit_adam(gpu, 1e-2);
        }
        Ok(gpu.wait()?)
    })? / q;
    let backward = timed(&mut || {
        tr.submit_step(gpu, &gf, QUEUED)?;
        Ok(gpu.wait()?)
    })? / q;
    let round_trip = timed(&mut || Ok(gf.forward(gpu, s, &mut sig, &mut rgb)?))?;
    let v = json!({
        "adapter": gpu.name(),
        "infer_samples_per_sec": n as f64 / infer,
        "infer_seconds": infer,
        "density_samples_per_sec": n as f64 / density,
        "infer_single_seconds": single,
        "train_samples_per_sec": n as f64 / train,
        "train_step_seconds": train,
        "forward_backward_seconds": backward,
        "train_stage_seconds": stages.iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<_, _>>(),
        "infer_with_transfers_samples_per_sec": n as f64 / round_trip,
        "setup_seconds": setup,
        "max_relative_difference": {"sigma": d_sigma, "rgb": d_rgb},
    });
    if show {
        eprintln!(
            "{:>9}  GPU {}: train {:.1} M samples/s ({:.2} ms/step; forward + backward {:.2} ms), infer {:.1} M samples/s ({:.2} ms; {:.2} ms waited for alone), density {:.1} M samples/s, infer with upload and read-back {:.1} M samples/s | largest relative difference from the CPU: σ {d_sigma:.1e}, rgb {d_rgb:.1e}",
            "",
            gpu.name(),
            n as f64 / train / 1e6,
            train * 1e3,
            backward * 1e3,
            n as f64 / infer / 1e6,
            infer * 1e3,
            single * 1e3,
            n as f64 / density / 1e6,
            n as f64 / round_trip / 1e6,
        );
        let parts: Vec<String> = stages
            .iter()
            .map(|(k, v)| format!("{k} {:.2} ms", v * 1e3))
            .collect();
        eprintln!(
            "{:>9}  GPU training step by stage: {}",
            "",
            parts.join(", ")
        );
    }
    Ok(v)
}
