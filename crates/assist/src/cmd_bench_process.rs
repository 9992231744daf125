//! `assist bench process`: `assist process` on a dataset's own photographs, its poses
//! stripped, against the poses the dataset gives — registration, camera-centre error
//! after the best similarity (as a share of the scene's extent), and time per stage.

use std::path::PathBuf;

use anyhow::Context;
use assist_session::process::{ProcessJob, compare};

#[derive(clap::Args, Debug)]
pub struct ProcessBenchArgs {
    /// A posed dataset whose images sit in one folder (LLFF, COLMAP, nerfstudio).
    pub data: PathBuf,
    /// Where to write the processed dataset (default: a temporary folder, removed).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// How COLMAP pairs images (as `assist process --matcher`).
    #[arg(long, value_enum, default_value_t = crate::cmd_process::MatcherArg::Auto)]
    pub matcher: crate::cmd_process::MatcherArg,
    /// One camera or one per frame (as `assist process --cameras`).
    #[arg(long, value_enum, default_value_t = crate::cmd_process::CamerasArg::Shared)]
    pub cameras: crate::cmd_process::CamerasArg,
    /// Frames to keep (as `assist process --frames`).
    #[arg(long, default_value_t = assist_session::process::DEFAULT_FRAMES)]
    pub frames: usize,
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
    let out = a.out.clone().unwrap_or_else(|| tmp.clone());
    let job = ProcessJob {
        input: folder.clone(),
        out: out.clone(),
        frames: a.frames.max(given.frames.len()),
        matcher: a.matcher.matcher(),
        cameras: a.cameras.into(),
        scale_by: None,
        force: a.out.is_some(),
        cancel: Default::default(),
    };
    let t0 = std::time::Instant::now();
    let done = job.run(&mut |e| {
        if !a.json
            && let assist_session::process::ProcessEvent::Stage { stage, detail } = e
        {
            eprintln!("{}: {detail}", stage.name());
        }
    });
    let seconds = t0.elapsed().as_secs_f64();
    let result = done.map_err(anyhow::Error::from).and_then(|summary| {
        let processed = assist_data::load(&out, &Default::default())
            .with_context(|| format!("loading the processed dataset {}", out.display()))?;
        let report = compare::compare_poses(&processed, &given)
            .context("fewer than 3 frames matched, or their centres are degenerate")?;
        Ok((summary, report))
    });
    if a.out.is_none() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    let (summary, report) = result?;
    let row = serde_json::json!({
        "data": a.data, "images": folder, "seconds": seconds,
        "registered": summary.registered, "frames": summary.frames,
        "registered_share": summary.registered as f64 / summary.frames as f64,
        "stages": summary.seconds, "poses": report,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&row)?);
    } else {
        eprintln!(
            "{}: {} of {} frames registered ({:.0}%) in {seconds:.0} s; camera centres after a similarity: mean {:.3}, max {:.3} ({:.2}% / {:.2}% of the scene's extent {:.2})",
            a.data.display(),
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
    Ok(())
}
