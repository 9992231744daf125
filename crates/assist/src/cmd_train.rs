//! `assist train DATA --out NAME.assist`: trains a compositional scene and saves it.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_session::StopReason;
use assist_session::{Every, TrainConfig, TrainEvent, TrainJob};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Dataset (any supported format: desk, nerfstudio, Blender, COLMAP, LLFF); also
    /// given as --data.
    #[arg(required_unless_present = "data_flag")]
    pub data: Option<PathBuf>,
    /// The dataset, as every other command takes it.
    #[arg(
        long = "data",
        id = "data_flag",
        value_name = "DATA",
        conflicts_with = "data"
    )]
    pub data_flag: Option<PathBuf>,
    /// Output scene directory (NAME.assist). Refused if it exists, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Everything the run is configured with (the session's `TrainConfig`).
    #[command(flatten)]
    pub train: TrainConfig,
    /// CLIP weights: after training, give each node a CLIP embedding (as `assist embed`)
    /// [default: $ASSIST_CLIP when set; without either, no embeddings].
    #[arg(long)]
    pub clip: Option<PathBuf>,
    /// Write the training log to FILE as JSON Lines (one object per line: "kind" is
    /// "step" every --log-every iterations, "held_out" per evaluation, "end" once), to
    /// plot with pandas.read_json(FILE, lines=True). Refused if it exists, unless --force
    /// (or --resume, which appends).
    #[arg(long, value_name = "FILE")]
    pub log: Option<PathBuf>,
    /// How often the log gets a "step" line: every N iterations ("50") or every S seconds
    /// ("1s"); the last step is always logged.
    #[arg(long, value_name = "N|Ss", default_value = "1s")]
    pub log_every: Every,
    /// Print each step's phases, loss terms and occupancy (about every 10 s) instead of a
    /// short progress line.
    #[arg(long)]
    pub verbose: bool,
    /// Read flags from a TOML file (keys are the long flag names; flags on the command
    /// line win).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Print the whole configuration (every flag, defaults included) as TOML for
    /// --config, and exit.
    #[arg(long)]
    pub print_config: bool,
    /// Print one JSON object (the report) on stdout instead of text on stderr.
    #[arg(long)]
    pub json: bool,
    /// Where the fields' forward and backward passes and Adam steps run (sampling and
    /// compositing stay on the CPU, the forward pass too with --refine-poses; the
    /// parameters come back after every step).
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

impl TrainArgs {
    /// The dataset, positional or --data.
    pub fn dataset(&self) -> &std::path::Path {
        self.data
            .as_deref()
            .or(self.data_flag.as_deref())
            .unwrap_or(std::path::Path::new(""))
    }

    /// The command line as a job configuration.
    pub fn config(&self) -> anyhow::Result<TrainConfig> {
        Ok(TrainConfig {
            data: self.dataset().to_path_buf(),
            out: self.out.clone(),
            ..self.train.clone()
        })
    }
}

/// Flag names for the fields a job's configuration errors name.
pub(crate) fn flag_error(e: assist_session::SessionError) -> anyhow::Error {
    use assist_session::SessionError;
    match e {
        SessionError::OutExists(path) => anyhow::anyhow!(
            "{} already exists (pass --force to replace it, or --resume to continue it)",
            path.display()
        ),
        SessionError::Request { what, message } => {
            let flag = match what.as_str() {
                "data" => "DATA".to_string(),
                other => format!("--{}", other.replace('_', "-")),
            };
            anyhow::anyhow!("{flag}: {message}")
        }
        other => other.into(),
    }
}

/// The training log (`--log`): JSON Lines, flushed per line so a crashed run keeps what
/// it logged. The file is created at the first line, so a run refused before it starts
/// leaves none.
struct Log {
    file: Option<std::io::BufWriter<std::fs::File>>,
    path: PathBuf,
    append: bool,
    error: Option<std::io::Error>,
}

impl Log {
    fn new(path: &std::path::Path, append: bool, force: bool) -> anyhow::Result<Log> {
        if path.exists() && !append && !force {
            anyhow::bail!(
                "--log: {} already exists (pass --force to replace it; --resume appends to it)",
                path.display()
            );
        }
        Ok(Log {
            file: None,
            path: path.to_path_buf(),
            append,
            error: None,
        })
    }

    /// Appends one line (the first write error is kept and reported at the end).
    fn line(&mut self, v: serde_json::Value) {
        use std::io::Write;
        if self.error.is_some() {
            return;
        }
        if self.file.is_none() {
            match std::fs::OpenOptions::new()
                .create(true)
                .write(true)
                .append(self.append)
                .truncate(!self.append)
                .open(&self.path)
            {
                Ok(f) => self.file = Some(std::io::BufWriter::new(f)),
                Err(e) => {
                    self.error = Some(e);
                    return;
                }
            }
        }
        let Some(f) = self.file.as_mut() else { return };
        if let Err(e) = writeln!(f, "{v}").and_then(|_| f.flush()) {
            self.error = Some(e);
        }
    }
}

/// A step as a log line: losses, PSNR, speed, learning rate and phase times.
fn step_line(s: &assist_session::StepStats) -> serde_json::Value {
    let step_s = s.phase.total();
    let phases: serde_json::Map<String, serde_json::Value> = s.phase.named()[..6]
        .iter()
        .map(|(n, t)| (format!("{n}_ms"), (t * 1e3).into()))
        .collect();
    let mut v = serde_json::json!({
        "kind": "step",
        "iteration": s.iteration,
        "elapsed": s.elapsed,
        "loss": s.loss,
        "psnr": s.psnr,
        "lr": s.lr,
        "rays": s.rays,
        "samples": s.samples,
        "rays_per_sec": if step_s > 0.0 { s.rays as f64 / step_s } else { 0.0 },
    });
    for (name, value) in s.terms.named() {
        v[name] = value.into();
    }
    v["phases"] = phases.into();
    v
}

/// A held-out measurement in words.
fn held_out_text(h: &assist_session::HeldOut) -> String {
    let size = if h.scale > 1 {
        format!(" at 1/{} size (`assist eval` measures full size)", h.scale)
    } else {
        String::new()
    };
    format!(
        "held-out PSNR {:.2} dB, SSIM {:.3} ({} {} view(s){size}, {:.1} s)",
        h.psnr, h.ssim, h.views, h.split, h.seconds
    )
}

/// With CLIP weights (`--clip` or `ASSIST_CLIP`), each node's embedding, saved into the
/// trained scene; `None` without weights.
fn embed_after_training(
    a: &TrainArgs,
    out: &std::path::Path,
) -> anyhow::Result<Option<assist_session::EmbedSummary>> {
    let configured = std::env::var_os(assist_session::clip::ENV).is_some_and(|v| !v.is_empty());
    if a.clip.is_none() && !configured {
        return Ok(None);
    }
    let clip = crate::cmd_embed::load_clip(a.clip.as_deref())?;
    let mut session = assist_session::Session::open(out)
        .with_context(|| format!("loading the trained scene {}", out.display()))?;
    let mut job = assist_session::EmbedJob::new(a.dataset().to_path_buf());
    job.replace = true;
    job.load.downscale = a.train.downscale;
    let s = crate::cmd_embed::embed_session(&mut session, &clip, &job, a.json)?;
    session
        .save(out, true)
        .with_context(|| format!("saving {}", out.display()))?;
    Ok(Some(s))
}

/// What `assist train` shows and logs while the job runs.
struct Reporter {
    log: Option<Log>,
    log_every: Every,
    /// Training seconds of the last logged step, and its iteration.
    last_log: Option<f64>,
    logged: Option<usize>,
    /// The latest held-out PSNR, for the progress line.
    held: Option<f64>,
    bar: ProgressBar,
    /// A progress bar on a terminal.
    show: bool,
    /// Detailed step lines on stderr (--verbose).
    verbose: bool,
    /// Text on stderr (no --json).
    text: bool,
    data: String,
}

impl Reporter {
    fn new(a: &TrainArgs, log: Option<Log>) -> Reporter {
        let show = !a.json && std::io::stderr().is_terminal();
        let bar = ProgressBar::new(1000);
        if !show {
            bar.set_draw_target(ProgressDrawTarget::hidden());
        }
        bar.set_style(
            ProgressStyle::with_template(
                "train [{bar:30}] {percent}% {elapsed_precise} ETA {eta} {msg}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        let verbose = !a.json && a.verbose;
        let text = !a.json;
        let data = a.dataset().display().to_string();
        Reporter {
            log,
            log_every: a.log_every,
            last_log: None,
            logged: None,
            held: None,
            bar,
            show,
            verbose,
            text,
            data,
        }
    }

    fn event(&mut self, ev: &TrainEvent) {
        match ev {
            TrainEvent::Loading { images, data } if self.text => {
                eprintln!("loading {images} training images from {} …", data.display());
            }
            TrainEvent::UserPrior { folder } if self.text => {
                eprintln!(
                    "background prior from {}: {} of {} training images ({} with depth){}",
                    folder.folder.display(),
                    folder.images,
                    folder.train_frames,
                    folder.depths,
                    match folder.missing.first() {
                        Some(m) => format!(
                            "; {} (e.g. {m}) keep the built-in fill",
                            folder.missing.len()
                        ),
                        None => String::new(),
                    }
                );
            }
            TrainEvent::Stage { name } if self.text => eprintln!("{name} …"),
            TrainEvent::Prior { seen_share } if self.text => eprintln!(
                "background prior: {:.0}% of the pixels objects cover are seen by other views, the rest filled by push-pull",
                100.0 * seen_share
            ),
            TrainEvent::Carved { nodes } if self.text => {
                let parts: Vec<String> = nodes
                    .iter()
                    .map(|(k, f)| format!("{k} {:.0}%", 100.0 * f))
                    .collect();
                eprintln!(
                    "free space carved from the depth maps: {}",
                    parts.join(", ")
                );
            }
            TrainEvent::Shadows {
                objects,
                covered,
                seen,
                estimated,
            } if self.text => eprintln!(
                "shadows: {objects} object(s) learn their shadow, first estimated from {estimated} pixels; shadow-free background prior on {covered} pixels under objects and {seen} around them"
            ),
            TrainEvent::NoMasks { unused } if self.text => eprintln!(
                "no instance masks in {} (an instance_mask_path per frame, or a masks/ folder beside the images): training the background only{}",
                self.data,
                if unused.is_empty() {
                    String::new()
                } else {
                    let u: Vec<String> = unused.iter().map(|p| p.display().to_string()).collect();
                    format!(
                        "; {} hold masks for other image sizes (masks_N/ is used with --downscale N)",
                        u.join(", ")
                    )
                }
            ),
            TrainEvent::Light(e) if self.text => {
                eprintln!("{}", crate::cmd_scene::describe_light(e))
            }
            TrainEvent::Layout {
                layout,
                given,
                gap_degrees,
                walk_around_defaults,
            } if self.text => eprintln!(
                "{}",
                assist_train::describe_layout(*layout, *given, *gap_degrees, *walk_around_defaults)
            ),
            TrainEvent::Nodes { nodes } if self.text => {
                let n: Vec<String> = nodes.iter().map(|(id, l)| format!("{id} {l:?}")).collect();
                eprintln!("nodes: {}", n.join(", "));
            }
            TrainEvent::ObjectRays(o) if self.text => eprintln!(
                "object rays: objects cover {:.0}% of the pixels; {:.0}% of each batch drawn from them{}",
                100.0 * o.share,
                100.0 * o.extra,
                if o.extra == 0.0 {
                    " (they need no more than a uniform draw gives)"
                } else {
                    ""
                }
            ),
            TrainEvent::HeldOut(h) => {
                self.held = Some(h.psnr);
                if let Some(l) = self.log.as_mut() {
                    let mut v = serde_json::to_value(h).unwrap_or_default();
                    v["kind"] = "held_out".into();
                    l.line(v);
                }
                if self.text {
                    let msg = format!(
                        "it {:>6}  {}{}",
                        h.iteration,
                        held_out_text(h),
                        h.preview
                            .as_ref()
                            .map(|p| format!("; preview {}", p.display()))
                            .unwrap_or_default()
                    );
                    if self.show {
                        self.bar.println(msg);
                    } else {
                        eprintln!("{msg}");
                    }
                }
            }
            TrainEvent::Step {
                stats,
                occupancy,
                eta_seconds,
            } => self.step(stats, occupancy.as_deref(), *eta_seconds),
            _ => {}
        }
    }

    /// A training step: the log's step line when due, the progress line, and every ~10 s
    /// a line on stderr without a terminal (phases, terms and occupancy with --verbose).
    fn step(
        &mut self,
        s: &assist_session::StepStats,
        occupancy: Option<&[(String, f64)]>,
        eta_seconds: Option<f64>,
    ) {
        if let Some(l) = self.log.as_mut()
            && self
                .log_every
                .due(s.iteration, s.elapsed, &mut self.last_log)
        {
            l.line(step_line(s));
            self.logged = Some(s.iteration);
        }
        let held = self
            .held
            .map(|p| format!(" held-out {p:.2} dB"))
            .unwrap_or_default();
        self.bar.set_position((s.progress * 1000.0) as u64);
        self.bar.set_message(format!(
            "it {} loss {:.5} psnr {:.2}{held}",
            s.iteration, s.loss, s.psnr
        ));
        // Without a terminal: a short line every ~10 s (the phases and terms with
        // --verbose).
        if occupancy.is_some() && self.text && !self.show && !self.verbose {
            let eta = eta_seconds
                .map(|e| format!("  ETA {e:.0} s"))
                .unwrap_or_default();
            eprintln!(
                "it {:>6}  {:>6.1} s{eta}  loss {:.5}  psnr {:.2}{held}",
                s.iteration, s.elapsed, s.loss, s.psnr
            );
        }
        if let Some(occupancy) = occupancy.as_ref().filter(|_| self.verbose) {
            let ms: Vec<String> = s.phase.named()[..6]
                .iter()
                .map(|(n, t)| format!("{n} {:.0}", t * 1e3))
                .collect();
            eprintln!(
                "it {:>6}  {:>5.1}s  loss {:.5}  psnr {:.2}  rays {}  samples {}  lr {:.2e}  ms per phase: {}",
                s.iteration,
                s.elapsed,
                s.loss,
                s.psnr,
                s.rays,
                s.samples,
                s.lr,
                ms.join(", ")
            );
            let occ: Vec<String> = occupancy
                .iter()
                .map(|(k, f)| format!("{k} {:.1}%", f * 100.0))
                .collect();
            let terms: Vec<String> = s
                .terms
                .named()
                .iter()
                .map(|(n, v)| format!("{n} {v:.5}"))
                .collect();
            eprintln!(
                "         pruned {} of {} samples; samples/ray {:.1?} terms: {}; occupied: {}",
                s.pruned,
                s.candidates,
                s.samples_per_ray,
                terms.join(" "),
                occ.join(", ")
            );
        }
    }
}

/// The report of a finished run: JSON on stdout with --json, text on stderr otherwise.
fn print_report(a: &TrainArgs, outcome: &assist_session::TrainOutcome) -> anyhow::Result<()> {
    let report = &outcome.report;
    if a.json {
        let mut v = serde_json::to_value(report)?;
        v["held_out"] = serde_json::to_value(&outcome.held_out)?;
        if !report.cancelled {
            v["embedding"] = serde_json::to_value(embed_after_training(a, &outcome.out)?)?;
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if report.cancelled {
        eprintln!(
            "interrupted at iteration {} ({:.1} s): saved {}\ncontinue with: assist train {} --out {} --resume",
            report.iterations,
            report.seconds,
            outcome.out.display(),
            a.dataset().display(),
            outcome.out.display()
        );
    } else {
        let why = match report.stopped_by {
            StopReason::Iterations => format!("reached --iters {}", a.train.iters_limit()),
            StopReason::Time => match a.train.iters {
                Some(n) => format!(
                    "--max-time {} s was spent before --iters {n}",
                    a.train.max_time.unwrap_or_default()
                ),
                None => format!("--max-time {} s", a.train.max_time.unwrap_or_default()),
            },
            StopReason::Cancelled => "interrupted".to_string(),
        };
        eprintln!(
            "trained {} iterations in {:.1} s ({why}; {:.0} rays/s, {:.2} M samples/s)\nlast training batch PSNR {:.2} dB; {}\nsaved {}",
            report.iterations,
            report.seconds,
            report.rays_per_sec,
            report.samples_per_sec / 1e6,
            report.final_stats.psnr,
            match &outcome.held_out {
                Some(h) => held_out_text(h),
                None if a.train.eval_views == 0 =>
                    "held-out views not measured (--eval-views 0)".into(),
                None => "no held-out views (the dataset has no test or val split)".into(),
            },
            outcome.out.display()
        );
        let per_step = 1e3 / report.steps.max(1) as f64;
        let parts: Vec<String> = report
            .phases
            .named()
            .iter()
            .map(|(n, t)| format!("{n} {:.1}", t * per_step))
            .collect();
        eprintln!("ms per step: {}", parts.join(", "));
    }
    Ok(())
}

pub fn run(a: TrainArgs) -> anyhow::Result<()> {
    let mut job = TrainJob::new(a.config()?);
    job.validate().map_err(flag_error)?;
    if let Some(t) = a.device.open()?.training() {
        job = job.with_optimizers(t);
    }
    let log = match &a.log {
        Some(p) => Some(Log::new(p, a.train.resume, a.train.force)?),
        None => None,
    };
    // Ctrl+C or SIGTERM: stop after the current step and save; a second one quits at once.
    let cancel = job.cancel_handle();
    let _ = ctrlc::set_handler(move || {
        if cancel.swap(true, std::sync::atomic::Ordering::SeqCst) {
            eprintln!("\ninterrupted again: quitting without saving");
            std::process::exit(130);
        }
        eprintln!(
            "\ninterrupted: saving the scene trained so far (interrupt again to quit without saving)"
        );
    });
    let mut r = Reporter::new(&a, log);
    let outcome = job.run(|ev| r.event(ev));
    r.bar.finish_and_clear();
    let outcome = outcome.map_err(flag_error)?;
    let report = &outcome.report;
    if let Some(mut l) = r.log.take() {
        // The last step, and the held-out views measured at the end, as rows of their own.
        let last = &outcome.report.final_stats;
        if outcome.report.iterations > 0 && r.logged != Some(last.iteration) {
            l.line(step_line(last));
        }
        if let Some(h) = &outcome.held_out {
            let mut v = serde_json::to_value(h).unwrap_or_default();
            v["kind"] = "held_out".into();
            l.line(v);
        }
        l.line(serde_json::json!({
            "kind": "end",
            "iteration": report.iterations,
            "elapsed": report.seconds,
            "stopped_by": report.stopped_by,
            "psnr": report.final_stats.psnr,
            "held_out_psnr": outcome.held_out.as_ref().map(|h| h.psnr),
            "held_out_ssim": outcome.held_out.as_ref().map(|h| h.ssim),
        }));
        if let Some(e) = l.error {
            anyhow::bail!("--log: writing {} failed: {e}", l.path.display());
        }
    }
    print_report(&a, &outcome)?;
    if report.cancelled {
        // Saved, but not finished: scripts must not mistake it for a complete run.
        std::process::exit(130);
    }
    if !a.json
        && let Some(s) = embed_after_training(&a, &outcome.out)?
    {
        eprintln!(
            "embedded {} node(s) from {} crops in {:.1} s (CLIP {})",
            s.nodes.iter().filter(|n| n.crops > 0).count(),
            s.crops,
            s.seconds,
            s.model
        );
    }
    Ok(())
}
