//! `assist generate`: randomized, physically plausible, labelled variations of trained
//! scenes (`docs/generate.md`), any shard of a run, resumable; `assist generate merge DIR`
//! joins the shards' annotations.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_generate::{CocoMasks, Generator, RunEvent, RunOptions, Shard, Spec};
use clap::{Args, Subcommand};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct GenerateArgs {
    #[command(subcommand)]
    pub command: Option<GenerateCommand>,
    /// The spec (TOML, or JSON by extension): base scenes, library, placement, cameras,
    /// outputs (docs/generate.md).
    #[arg(long, conflicts_with = "scene", required_unless_present = "scene")]
    pub spec: Option<PathBuf>,
    /// Without a spec: rearrange this scene's own objects with the default spec.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The output folder (shared by every shard of a run).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Samples in the run (overrides the spec's `count`).
    #[arg(long)]
    pub count: Option<u64>,
    /// Seed of the run (overrides the spec's `seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Make only shard i of n (0-based): samples with index % n == i. Default: from
    /// SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT or JOB_COMPLETION_INDEX/JOB_COMPLETIONS
    /// when set, else every sample.
    #[arg(long, value_name = "i/n")]
    pub shard: Option<String>,
    /// Plan placements and write the actions and poses (OUT/plans/) without rendering.
    #[arg(long)]
    pub dry_run: bool,
    /// Replace an --out that assist generated from another spec.
    #[arg(long)]
    pub force: bool,
    /// Read flags from a TOML file (keys are the long flag names; flags on the command
    /// line win).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Print a JSON summary on stdout (progress stays on stderr).
    #[arg(long)]
    pub json: bool,
    /// Masks of the COCO instances a whole run merges: polygons (outer outlines, holes
    /// filled: what torchvision's and detectron2's loaders read by default) or exact RLE.
    #[arg(long, value_enum, default_value_t = CocoMasksArg::Polygon)]
    pub coco_masks: CocoMasksArg,
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

/// `--coco-masks`.
#[derive(clap::ValueEnum, Debug, Clone, Copy)]
pub enum CocoMasksArg {
    Polygon,
    Rle,
}

impl From<CocoMasksArg> for CocoMasks {
    fn from(a: CocoMasksArg) -> Self {
        match a {
            CocoMasksArg::Polygon => CocoMasks::Polygon,
            CocoMasksArg::Rle => CocoMasks::Rle,
        }
    }
}

#[derive(Subcommand, Debug)]
pub enum GenerateCommand {
    /// Join the samples of every shard into annotations/instances.json,
    /// annotations/panoptic.json and index.json.
    Merge {
        /// The run's output folder.
        dir: PathBuf,
        /// Merge the samples present even if some are missing.
        #[arg(long)]
        partial: bool,
        /// Print a JSON summary of the merged files on stdout.
        #[arg(long)]
        json: bool,
        /// Masks of the COCO instances: polygon or rle.
        #[arg(long, value_enum, default_value_t = CocoMasksArg::Polygon)]
        coco_masks: CocoMasksArg,
    },
    /// List the run's shards that are complete, partial (stopped, or a file missing or
    /// truncated), missing, or another run's, and how to run the others again.
    Status {
        /// The run's output folder.
        dir: PathBuf,
        /// The n of the shards' `--shard i/n` (default: the n their completion records
        /// name; a run without records counts as one shard).
        #[arg(long, value_name = "N")]
        shards: Option<u64>,
        /// Check every file's content by hash, not only its size.
        #[arg(long)]
        hashes: bool,
        /// Print only the shards to run again, as `i,j,…` (for Slurm's `--array=`).
        #[arg(long, conflicts_with = "json")]
        rerun: bool,
        /// Print the status as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
}

struct Prep(bool);

impl assist_generate::Progress for Prep {
    fn preparing(&mut self, what: &str) {
        if self.0 {
            eprintln!("{what} …");
        }
    }
}

fn status(
    dir: &std::path::Path,
    shards: Option<u64>,
    hashes: bool,
    rerun: bool,
    json: bool,
) -> anyhow::Result<()> {
    let st = assist_generate::status(dir, shards, hashes)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&st)?);
        return Ok(());
    }
    if rerun {
        println!("{}", st.to_rerun());
        return Ok(());
    }
    let n = st.shards;
    println!(
        "{}: {} of {} samples made; {} shards{}: {} complete, {} partial, {} missing, {} another run's",
        dir.display(),
        st.samples_done,
        st.count,
        n,
        match st.shards_from {
            "records" => " (from the completion records)",
            "whole run" =>
                " (no completion records: one shard; give --shards N if the run was split)",
            _ => "",
        },
        st.complete.len(),
        st.partial.len(),
        st.missing.len(),
        st.foreign.len()
    );
    for s in &st.incomplete {
        println!(
            "  shard {} {}: {} of {} samples hold{}{}",
            s.shard,
            s.state,
            s.done,
            s.owned,
            if s.problems.is_empty() { "" } else { "; " },
            s.problems.join("; ")
        );
    }
    if st.all_complete {
        println!(
            "every shard is complete: assist generate merge {}",
            dir.display()
        );
    } else {
        let list = st.to_rerun();
        println!(
            "run again: assist generate --spec SPEC --out {} --shard i/{n} for i in {list} (Slurm: sbatch --array={list} …; a rerun remakes only what does not hold)",
            dir.display()
        );
    }
    Ok(())
}

/// Says what a rerun of a complete shard did: nothing made (a whole run merged if it had
/// not been).
fn complete_already(
    a: &GenerateArgs,
    out: &std::path::Path,
    shard: Shard,
    done: assist_generate::shards::CompleteRerun,
) -> anyhow::Result<()> {
    eprintln!(
        "shard {}/{} of {} is complete ({} samples; its record {}): nothing to do",
        shard.index,
        shard.count,
        out.display(),
        done.owned,
        assist_generate::shards::record_path(out, shard).display()
    );
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "out": out,
                "shard": format!("{}/{}", shard.index, shard.count),
                "made": 0,
                "skipped": done.owned,
                "complete": true,
                "merged": done.merged,
            }))?
        );
    }
    Ok(())
}

pub fn run(a: GenerateArgs) -> anyhow::Result<()> {
    if let Some(GenerateCommand::Status {
        dir,
        shards,
        hashes,
        rerun,
        json,
    }) = &a.command
    {
        return status(dir, *shards, *hashes, *rerun, *json);
    }
    if let Some(GenerateCommand::Merge {
        dir,
        partial,
        json,
        coco_masks,
    }) = a.command
    {
        let m = assist_generate::merge(&dir, partial, coco_masks.into())?;
        if json {
            println!("{}", serde_json::to_string_pretty(&m)?);
        }
        eprintln!(
            "merged {} samples ({} images, {} annotations) in {}{}",
            m.samples,
            m.images,
            m.annotations,
            dir.display(),
            if m.missing.is_empty() {
                String::new()
            } else {
                format!("; {} missing", m.missing.len())
            }
        );
        return Ok(());
    }
    let Some(out) = a.out.clone() else {
        bail!("--out: expected the output folder");
    };
    // Before any work: the output is generated samples or nothing yet, never a scene or
    // a dataset (the run's own scenes included).
    assist_fs::check_kind(&out, assist_fs::Kind::Generated)?;
    if a.force {
        assist_fs::check_only_ours(&out, assist_generate::GENERATED)?;
    }
    let mut spec = match (&a.spec, &a.scene) {
        (Some(p), _) => Spec::load(p)?,
        (None, Some(s)) => Spec::for_scene(s),
        (None, None) => bail!("expected --spec SPEC or --scene SCENE.assist"),
    };
    if let Some(c) = a.count {
        spec.count = c;
    }
    if let Some(s) = a.seed {
        spec.seed = s;
    }
    spec.check(a.spec.as_deref().unwrap_or(std::path::Path::new("--scene")))?;
    let shard = match &a.shard {
        Some(s) => Shard::parse(s).map_err(|m| anyhow::anyhow!("--shard: {m}"))?,
        None => Shard::from_env(|k| std::env::var(k).ok())
            .map_err(|m| anyhow::anyhow!("shard from the environment: {m}"))?
            .unwrap_or(Shard::ALL),
    };
    // A shard that is complete has nothing to do: say so without loading a scene.
    if !a.dry_run
        && !a.force
        && let Some(done) =
            assist_generate::shards::rerun_if_complete(&out, &spec, shard, a.coco_masks.into())?
    {
        return complete_already(&a, &out, shard, done);
    }
    let tty = std::io::stderr().is_terminal();
    let device = a.device.open()?;
    let generator = Generator::prepare_on(spec, device.field_backend(), &mut Prep(true))
        .context("preparing the run")?;
    let bar = crate::progress::bar(tty, "generate");
    let opts = RunOptions {
        out: out.clone(),
        shard,
        dry_run: a.dry_run,
        force: a.force,
        coco_masks: a.coco_masks.into(),
    };
    let summary = generator.run(&opts, |e| match e {
        RunEvent::Start { owned, done } => {
            bar.set_length(*owned);
            bar.set_position(*done);
            if *done > 0 {
                eprintln!("{done} of {owned} samples of this shard are already made; continuing");
            }
        }
        RunEvent::Sample {
            report,
            finished,
            left,
            elapsed,
        } => {
            bar.inc(1);
            let rate = *finished as f64 / elapsed.max(1e-9);
            if !tty {
                eprintln!(
                    "sample {}: {} objects, {} draws ({} rejected){} · {:.2} samples/s, ETA {:.0} s",
                    report.index,
                    report.objects,
                    report.draws,
                    report.rejected,
                    if report.gave_up.is_empty() {
                        String::new()
                    } else {
                        format!(", gave up on {}", report.gave_up.len())
                    },
                    rate,
                    *left as f64 / rate.max(1e-9)
                );
            }
        }
    })?;
    bar.finish_and_clear();
    device.report();
    eprintln!(
        "{} {} samples into {} (shard {}; {} already there) in {:.1} s, {:.2} samples/s; {} of {} placement draws rejected, {} objects given up",
        if a.dry_run { "planned" } else { "made" },
        summary.made,
        out.display(),
        summary.shard,
        summary.skipped,
        summary.seconds,
        summary.samples_per_second,
        summary.rejected,
        summary.draws,
        summary.gave_up
    );
    if let Some(m) = &summary.merged {
        eprintln!(
            "wrote annotations/instances.json and annotations/panoptic.json ({} images, {} annotations) and index.json",
            m.images, m.annotations
        );
    } else if !a.dry_run {
        eprintln!(
            "when every shard is done: assist generate merge {}",
            out.display()
        );
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}
