//! `assist scene split SCENE --out OUT (--box … | --click VIEW:u,v)… [--label …]`: new
//! object nodes cut out of a scene trained without masks, by boxes or clicks; masks
//! derived for every image, the nodes' fields started from the background's, then a short
//! fine-tune ([`assist_session::split::SplitJob`]). One undo step of the scene's history.

use std::io::IsTerminal;

use assist_session::TrainEvent;
use assist_session::split::{MaskProgress, SplitConfig, SplitEvent, SplitJob};
use clap::Args;
use serde_json::json;

use crate::cmd_dataset_masks::vec3;

#[derive(Args, Debug)]
pub struct SplitArgs {
    #[command(flatten)]
    pub config: SplitConfig,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: SplitArgs) -> anyhow::Result<()> {
    let masks_out = a.config.masks_out.clone();
    let job = SplitJob::new(a.config);
    // Ctrl+C or SIGTERM: before the fine-tune, stop and write nothing; during it, save the
    // scene fine-tuned so far. A second one quits at once.
    let cancel = job.cancel_handle();
    let _ = ctrlc::set_handler(move || {
        if cancel.swap(true, std::sync::atomic::Ordering::SeqCst) {
            eprintln!("\ninterrupted again: quitting without saving");
            std::process::exit(130);
        }
        eprintln!("\ninterrupted: stopping the split (interrupt again to quit at once)");
    });
    let show = !a.json && std::io::stderr().is_terminal();
    let text = !a.json;
    let bar = crate::progress::bar(show, "split");
    let mut last_line = std::time::Instant::now();
    let outcome = job.run(|e| match e {
        SplitEvent::Clicked { click, obb } if text => eprintln!(
            "--click {click}: box centre {} size {}",
            vec3(obb.center),
            vec3(obb.size())
        ),
        SplitEvent::Masks(MaskProgress::Rendering { done, total }) => {
            bar.set_message("rendering views");
            crate::progress::steps(&bar)(done, total)
        }
        SplitEvent::Masks(MaskProgress::Refining { done, total }) => {
            bar.set_message("masks");
            crate::progress::steps(&bar)(done, total)
        }
        SplitEvent::Distilled { id, label, report } if text => eprintln!(
            "{id:>3}  {label}: field started from the background's ({} steps, log-density error {:.3}, colour error {:.3}, {:.1} s)",
            report.steps, report.density_error, report.color_error, report.seconds
        ),
        SplitEvent::Cleared(report) if text => eprintln!(
            "background emptied inside the new objects above their supports ({} steps, log-density there {:.3} -> {:.3}, around them changed by {:.3}, elsewhere by {:.3}, {:.1} s)",
            report.steps,
            report.cleared_before,
            report.cleared_after,
            report.held_change,
            report.held_elsewhere,
            report.seconds
        ),
        SplitEvent::Train(TrainEvent::Step { stats, eta_seconds, .. }) => {
            bar.set_message(format!(
                "fine-tune it {} psnr {:.2}",
                stats.iteration, stats.psnr
            ));
            crate::progress::steps(&bar)((stats.progress * 1000.0) as usize, 1000);
            if text && !show && last_line.elapsed().as_secs_f64() > 10.0 {
                last_line = std::time::Instant::now();
                let eta = eta_seconds
                    .map(|e| format!("  ETA {e:.0} s"))
                    .unwrap_or_default();
                eprintln!(
                    "fine-tune it {:>6}  {:>6.1} s{eta}  loss {:.5}  psnr {:.2}",
                    stats.iteration, stats.elapsed, stats.loss, stats.psnr
                );
            }
        }
        _ => {}
    });
    bar.finish_and_clear();
    let outcome = outcome?;
    // Saved, but the fine-tune did not finish: scripts must not take it for a whole split.
    let stopped = outcome.trained.as_ref().is_some_and(|t| t.report.cancelled);
    if a.json {
        let v = json!({
            "out": outcome.out,
            "objects": outcome.objects.iter().map(|b| json!({
                "id": b.id,
                "label": b.label,
                "center": b.obb.center.to_array(),
                "size": b.obb.size().to_array(),
            })).collect::<Vec<_>>(),
            "masks": outcome.masks,
            "fine_tune": outcome.trained.as_ref().map(|t| &t.report),
            "held_out": outcome.trained.as_ref().and_then(|t| t.held_out.as_ref()),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        if stopped {
            std::process::exit(130);
        }
        return Ok(());
    }
    for (b, o) in outcome.objects.iter().zip(&outcome.masks.objects) {
        println!(
            "{:>3}  {:<24} box centre {} size {}  {} mask pixels over {} images",
            b.id,
            b.label,
            vec3(b.obb.center),
            vec3(b.obb.size()),
            o.pixels,
            outcome.masks.images
        );
    }
    match &outcome.trained {
        Some(t) => println!(
            "fine-tuned {} steps{} in {:.0} s (last batch psnr {:.2}{}) -> {} (undo merges the objects back)",
            t.report.iterations,
            if stopped { " (interrupted)" } else { "" },
            t.report.seconds,
            t.report.final_stats.psnr,
            t.held_out
                .as_ref()
                .map(|h| format!(
                    ", held-out {:.2} dB on {} {} views",
                    h.psnr, h.views, h.split
                ))
                .unwrap_or_default(),
            outcome.out.display()
        ),
        None => println!(
            "saved {} without the fine-tune: continue with `assist train DATA --out {} --resume --masks {}`",
            outcome.out.display(),
            outcome.out.display(),
            masks_out
                .as_ref()
                .map(|m| m.display().to_string())
                .unwrap_or_default()
        ),
    }
    if stopped {
        std::process::exit(130);
    }
    Ok(())
}
