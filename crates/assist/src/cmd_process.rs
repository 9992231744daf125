//! `assist process`: a video or a folder of photographs → a posed dataset (see
//! `assist_session::process`). Each stage is announced with a progress bar; `--json`
//! prints the summary.

use std::io::IsTerminal;
use std::path::PathBuf;

use assist_session::process::{
    Cameras, DEFAULT_FRAMES, Matcher, ProcessEvent, ProcessJob, ScaleBy, Stage,
};
use clap::{Args, ValueEnum};

#[derive(Args, Debug)]
pub struct ProcessArgs {
    /// A video file (any format ffmpeg reads) or a folder of photographs (JPEG, PNG).
    pub input: PathBuf,
    /// The dataset folder to write (staged, swapped in whole; see --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Frames to keep: a video's (the sharpest in each of this many windows), or a
    /// larger folder's, thinned the same way.
    #[arg(long, default_value_t = DEFAULT_FRAMES)]
    pub frames: usize,
    /// How COLMAP pairs images: auto = sequential for a video or more than 200
    /// photographs, exhaustive otherwise.
    #[arg(long, value_enum, default_value_t = MatcherArg::Auto)]
    pub matcher: MatcherArg,
    /// How many cameras COLMAP solves for.
    #[arg(long, value_enum, default_value_t)]
    pub cameras: Cameras,
    /// One known distance, for metres: "FRAME:x,y FRAME:x,y DISTANCE" — two pixels (a
    /// frame's index in name order or its file name, then the pixel) showing the ends of
    /// a distance, e.g. "3:410,220 17:388,610 0.30m" (m, cm or mm). Without it the unit
    /// is COLMAP's, arbitrary.
    #[arg(long)]
    pub scale_by: Option<ScaleBy>,
    /// Replace --out if assist wrote it (a folder assist did not write is never replaced).
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout (frames, registered, unit, seconds per stage).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MatcherArg {
    Auto,
    Sequential,
    Exhaustive,
}

impl MatcherArg {
    pub fn matcher(self) -> Option<Matcher> {
        match self {
            MatcherArg::Auto => None,
            MatcherArg::Sequential => Some(Matcher::Sequential),
            MatcherArg::Exhaustive => Some(Matcher::Exhaustive),
        }
    }
}

pub fn run(a: ProcessArgs) -> anyhow::Result<()> {
    let job = ProcessJob {
        input: a.input.clone(),
        out: a.out.clone(),
        frames: a.frames,
        matcher: a.matcher.matcher(),
        cameras: a.cameras,
        scale_by: a.scale_by.clone(),
        force: a.force,
        cancel: Default::default(),
    };
    let tty = std::io::stderr().is_terminal();
    let mut bar = crate::progress::bar(false, "");
    let mut current: Option<Stage> = None;
    let done = job.run(&mut |e| match e {
        ProcessEvent::Stage { stage, detail } => {
            bar.finish_and_clear();
            bar = crate::progress::bar(tty, stage.name());
            current = Some(*stage);
            if !a.json || !tty {
                eprintln!("{}: {detail}", stage.name());
            }
        }
        ProcessEvent::Progress { stage, done, total } => {
            if current == Some(*stage) {
                bar.set_length(*total as u64);
                bar.set_position(*done as u64);
            }
        }
    })?;
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&done)?);
        return Ok(());
    }
    let secs: f64 = done.seconds.iter().map(|s| s.1).sum();
    eprintln!(
        "wrote {}: {} of {} frames posed ({}×{}), {} sparse points, in {:.0} s",
        done.out.display(),
        done.registered,
        done.frames,
        done.width,
        done.height,
        done.points,
        secs
    );
    if !done.not_registered.is_empty() {
        eprintln!(
            "warning: COLMAP did not register {} frame(s), left out: {}",
            done.not_registered.len(),
            done.not_registered.join(", ")
        );
    }
    for w in &done.warnings {
        eprintln!("warning: {w}");
    }
    match done.meters_per_unit {
        Some(_) => eprintln!("unit: metres (from --scale-by)"),
        None => eprintln!(
            "unit: COLMAP's, arbitrary (give --scale-by with one known distance for metres)"
        ),
    }
    eprintln!(
        "next: assist train {} --out SCENE.assist",
        done.out.display()
    );
    Ok(())
}
