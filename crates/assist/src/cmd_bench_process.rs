//! `assist bench process`: `assist process` on a dataset's own photographs, its poses
//! stripped, against the poses the dataset gives — registration, camera-centre error
//! after the best similarity (as a share of the scene's extent), and time per stage.
//! With `--runs 2` or more it also measures COLMAP against itself: each later run's
//! cameras against the first's, which bounds how closely any one run can be expected to
//! match another reconstruction of the same photographs.

use std::path::{Path, PathBuf};

use anyhow::Context;
use assist_session::process::{ProcessJob, ProcessSummary, compare};

#[derive(clap::Args, Debug)]
pub struct ProcessBenchArgs {
    /// A posed dataset whose images sit in one folder (LLFF, COLMAP, nerfstudio).
    pub data: PathBuf,
    /// Where to write the processed dataset (default: a temporary folder, removed); with
    /// --runs N, run k > 1 goes to OUT-k.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// How COLMAP pairs images (as `assist process --matcher`).
    #[arg(long, value_enum, default_value_t = crate::cmd_process::MatcherArg::Auto)]
    pub matcher: crate::cmd_process::MatcherArg,
    /// One camera or one per frame (as `assist process --cameras`).
    #[arg(long, value_enum, default_value_t)]
    pub cameras: assist_session::process::Cameras,
    /// Frames to keep (as `assist process --frames`).
    #[arg(long, default_value_t = assist_session::process::DEFAULT_FRAMES)]
    pub frames: usize,
    /// Process the photographs this many times: from the second on, each run's cameras
    /// are also compared with the first's (COLMAP's repeatability on this capture).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=10))]
    pub runs: u32,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: ProcessBenchArgs) -> anyhow::Result<()> {
    let given = assist_data::load(&a.data, &Default::default())
        .with_context(|| format!("loading dataset {}", a.data.display()))?;
    let folder = given
        .frames
        .first()
        .and_then(|f| f.image_path.parent())
        .context("the dataset has no frames")?
        .to_path_buf();
    if given
        .frames
        .iter()
        .any(|f| f.image_path.parent() != Some(&folder))
    {
        anyhow::bail!("{}: the images are not all in one folder", a.data.display());
    }
    let tmp = std::env::temp_dir().join(format!("assist-bench-process-{}", std::process::id()));
    if a.out.is_none() {
        std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    }
    let outs: Vec<PathBuf> = (1..=a.runs)
        .map(|k| {
            let base = a.out.clone().unwrap_or_else(|| tmp.join("run"));
            if k == 1 {
                base
            } else {
                let mut name = base.file_name().unwrap_or_default().to_owned();
                name.push(format!("-{k}"));
                base.with_file_name(name)
            }
        })
        .collect();
    let result = outs
        .iter()
        .map(|out| one_run(&a, &folder, out, &given))
        .collect::<anyhow::Result<Vec<_>>>()
        .and_then(|runs| {
            let between = repeatability(&outs)?;
            Ok((runs, between))
        });
    if a.out.is_none() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    let (runs, between) = result?;
    let rows: Vec<serde_json::Value> = runs
        .iter()
        .map(|(summary, report, seconds)| {
            serde_json::json!({
                "seconds": seconds,
                "registered": summary.registered, "frames": summary.frames,
                "registered_share": summary.registered as f64 / summary.frames as f64,
                "stages": summary.seconds, "poses": report,
            })
        })
        .collect();
    if a.json {
        let mut out = rows[0].clone();
        out["data"] = serde_json::json!(a.data);
        out["images"] = serde_json::json!(folder);
        if a.runs > 1 {
            out["runs"] = serde_json::json!(rows);
            out["between_runs"] = serde_json::json!(between);
        }
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    for (k, (summary, report, seconds)) in runs.iter().enumerate() {
        eprintln!(
            "{}{}: {} of {} frames registered ({:.0}%) in {seconds:.0} s; camera centres after a similarity: mean {:.3}, max {:.3} ({:.2}% / {:.2}% of the scene's extent {:.2})",
            a.data.display(),
            if a.runs > 1 {
                format!(" run {}", k + 1)
            } else {
                String::new()
            },
            summary.registered,
            summary.frames,
            100.0 * summary.registered as f64 / summary.frames as f64,
            report.mean_error,
            report.max_error,
            100.0 * report.mean_share,
            100.0 * report.max_share,
            report.extent
        );
    }
    for (k, r) in between.iter().enumerate() {
        eprintln!(
            "run {} against run 1 (COLMAP against itself): {} frames in both; camera centres mean {:.2}% / max {:.2}% of run 1's extent",
            k + 2,
            r.matched,
            100.0 * r.mean_share,
            100.0 * r.max_share
        );
    }
    Ok(())
}

/// One `process` of the photographs into `out`, compared with the given poses.
fn one_run(
    a: &ProcessBenchArgs,
    folder: &Path,
    out: &Path,
    given: &assist_data::Dataset,
) -> anyhow::Result<(ProcessSummary, compare::PoseReport, f64)> {
    let job = ProcessJob {
        input: folder.to_path_buf(),
        out: out.to_path_buf(),
        frames: a.frames.max(given.frames.len()),
        matcher: a.matcher.matcher(),
        cameras: a.cameras,
        scale_by: None,
        force: a.out.is_some(),
        cancel: Default::default(),
    };
    let t0 = std::time::Instant::now();
    let summary = job.run(&mut |e| {
        if !a.json
            && let assist_session::process::ProcessEvent::Stage { stage, detail } = e
        {
            eprintln!("{}: {detail}", stage.name());
        }
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    let processed = load_processed(out)?;
    let report = compare::compare_poses(&processed, given)
        .context("fewer than 3 frames matched, or their centres are degenerate")?;
    Ok((summary, report, seconds))
}

fn load_processed(out: &Path) -> anyhow::Result<assist_data::Dataset> {
    assist_data::load(out, &Default::default())
        .with_context(|| format!("loading the processed dataset {}", out.display()))
}

/// Each later run's cameras against the first run's (its extent the unit).
fn repeatability(outs: &[PathBuf]) -> anyhow::Result<Vec<compare::PoseReport>> {
    let Some((first, rest)) = outs.split_first() else {
        return Ok(Vec::new());
    };
    if rest.is_empty() {
        return Ok(Vec::new());
    }
    let first = load_processed(first)?;
    rest.iter()
        .map(|o| {
            compare::compare_poses(&load_processed(o)?, &first)
                .context("two runs share fewer than 3 frames, or their centres are degenerate")
        })
        .collect()
}
