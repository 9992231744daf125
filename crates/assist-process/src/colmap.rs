//! Poses by the real COLMAP (never reimplemented): SIFT features on the CPU, one OPENCV
//! camera for the whole capture (a phone's lens, distortion included) or one
//! SIMPLE_RADIAL camera per frame ([`Cameras`]), sequential
//! matching for a video's frames or exhaustive matching for a set of photographs, then
//! the incremental mapper. Of the models the mapper writes, the one that registers the
//! most images is kept.

use std::path::{Path, PathBuf};
use std::process::Command;

use assist_data::colmap::ColmapModel;

use std::sync::atomic::AtomicBool;

use crate::tools::{COLMAP, Runner};
use crate::{ProcessError, ProcessEvent, Stage};

/// How images are paired for matching.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Matcher {
    /// Each image with its neighbours in capture order (a video).
    Sequential,
    /// Every pair (a few hundred photographs at most).
    Exhaustive,
}

/// How many cameras COLMAP solves for (`process --cameras`; the same names in Python).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum Cameras {
    /// One OPENCV camera (focal lengths, centre, radial and tangential distortion) shared
    /// by every frame: one lens at one zoom.
    #[default]
    Shared,
    /// One SIMPLE_RADIAL camera (one focal length, centre, one radial term) per frame:
    /// for frames whose focal length changes (a phone refocusing as it moves, photographs
    /// from several cameras or zooms). More unknowns, so each needs more matches.
    PerFrame,
}

impl Cameras {
    /// COLMAP's `--ImageReader.single_camera` and `--ImageReader.camera_model`.
    fn reader_args(self) -> [&'static str; 4] {
        let (single, model) = match self {
            Cameras::Shared => ("1", "OPENCV"),
            Cameras::PerFrame => ("0", "SIMPLE_RADIAL"),
        };
        [
            "--ImageReader.single_camera",
            single,
            "--ImageReader.camera_model",
            model,
        ]
    }
}

/// Photographs above which `auto` matches sequentially even for a folder: exhaustive
/// matching grows with the square of the count.
pub const MAX_EXHAUSTIVE: usize = 200;

/// Runs COLMAP on the images of `images` (all one size) in the workspace `work`, logging
/// to `work/colmap.log`; returns the largest model and the folder it was read from.
pub fn reconstruct(
    images: &Path,
    work: &Path,
    matcher: Matcher,
    cameras: Cameras,
    count: usize,
    cancel: &AtomicBool,
    on_event: &mut dyn FnMut(&ProcessEvent),
) -> Result<(ColmapModel, PathBuf), ProcessError> {
    let colmap = COLMAP.find()?;
    let runner = Runner {
        log: work.join("colmap.log"),
        cancel,
    };
    let db = work.join("database.db");
    let colmap_cmd = || {
        let mut c = Command::new(&colmap);
        // COLMAP links Qt even for its command line; no display is needed or wanted.
        c.env("QT_QPA_PLATFORM", "offscreen");
        // Its solver's glog lines go to the captured stderr (`colmap.log`), not to log
        // files left in the system's temporary folder.
        c.env("GLOG_logtostderr", "1");
        c
    };
    step(
        on_event,
        Stage::Features,
        "SIFT features (COLMAP, CPU)",
        "extracting features",
        colmap_cmd()
            .arg("feature_extractor")
            .arg("--database_path")
            .arg(&db)
            .arg("--image_path")
            .arg(images)
            .args(cameras.reader_args())
            .args(["--SiftExtraction.use_gpu", "0"]),
        &runner,
        count,
    )?;
    let (name, extra): (&str, &[&str]) = match matcher {
        Matcher::Sequential => (
            "sequential_matcher",
            &["--SequentialMatching.overlap", "10"],
        ),
        Matcher::Exhaustive => ("exhaustive_matcher", &[]),
    };
    step(
        on_event,
        Stage::Matching,
        &format!("{name} (COLMAP, CPU)"),
        "matching features",
        colmap_cmd()
            .arg(name)
            .arg("--database_path")
            .arg(&db)
            .args(["--SiftMatching.use_gpu", "0"])
            .args(extra),
        &runner,
        count,
    )?;
    let sparse = work.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| ProcessError::Io {
        path: sparse.clone(),
        message: e.to_string(),
    })?;
    let mapper = |out: &Path, relaxed: &[&str]| {
        let mut c = colmap_cmd();
        c.arg("mapper")
            .arg("--database_path")
            .arg(&db)
            .arg("--image_path")
            .arg(images)
            .arg("--output_path")
            .arg(out)
            .args(relaxed);
        c
    };
    let first = step(
        on_event,
        Stage::Mapping,
        "incremental mapper (COLMAP)",
        "mapping",
        &mut mapper(&sparse, &[]),
        &runner,
        count,
    )
    .and_then(|_| largest_model(&sparse));
    match first {
        Err(ProcessError::Cancelled) => return Err(ProcessError::Cancelled),
        Ok(found) if found.0.images.len() as f64 >= RETRY_BELOW * count as f64 => {
            return Ok(found);
        }
        _ => {}
    }
    // COLMAP's defaults want 100 inlier matches for the first pair and 30 to register
    // an image; plain, smooth surfaces and frames without a focal length in their EXIF
    // (every video frame) may offer fewer, leaving no model, or the capture broken into
    // several models at frames it could not register. One retry with lower thresholds (in its own folder); the model registering more is
    // kept, and the registration check decides whether it is enough.
    let relaxed = work.join("sparse-relaxed");
    std::fs::create_dir_all(&relaxed).map_err(|e| ProcessError::Io {
        path: relaxed.clone(),
        message: e.to_string(),
    })?;
    step(
        on_event,
        Stage::Mapping,
        "under 90% of the frames posed under COLMAP's defaults; mapping again with relaxed thresholds (few matches: a plain scene, or no focal length known)",
        "mapping",
        &mut mapper(&relaxed, &RELAXED),
        &runner,
        count,
    )?;
    let second = largest_model(&relaxed)?;
    Ok(match first {
        Ok(found) if found.0.images.len() >= second.0.images.len() => found,
        _ => second,
    })
}

/// The share of the frames below which the mapper runs again with [`RELAXED`]
/// thresholds (a capture is expected to register whole).
pub const RETRY_BELOW: f64 = 0.9;

/// The mapper's thresholds for a second try: 25 inliers (not 100) and 8° (not 16°) for
/// the first pair, 15 inliers (not 30) to register an image.
const RELAXED: [&str; 6] = [
    "--Mapper.init_min_num_inliers",
    "25",
    "--Mapper.init_min_tri_angle",
    "8",
    "--Mapper.abs_pose_min_num_inliers",
    "15",
];

/// One COLMAP command as a stage: announced, run, its log lines turned into progress.
fn step(
    on_event: &mut dyn FnMut(&ProcessEvent),
    stage: Stage,
    detail: &str,
    what: &str,
    cmd: &mut Command,
    runner: &Runner,
    count: usize,
) -> Result<(), ProcessError> {
    on_event(&ProcessEvent::Stage {
        stage,
        detail: detail.to_string(),
    });
    runner.run(COLMAP, what, cmd, |line| {
        if let Some((done, total)) = parse_progress(stage, line, count) {
            on_event(&ProcessEvent::Progress { stage, done, total });
        }
    })
}

/// The model under `sparse/` (`0/`, `1/` …) that registers the most images.
fn largest_model(sparse: &Path) -> Result<(ColmapModel, PathBuf), ProcessError> {
    let mut best: Option<(ColmapModel, PathBuf)> = None;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(sparse)
        .map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    dirs.sort();
    for dir in dirs.into_iter().filter(|d| d.join("images.bin").is_file()) {
        let model =
            assist_data::colmap::read_model(&dir, true).map_err(|e| ProcessError::Tool {
                tool: COLMAP.name,
                what: "mapping".into(),
                message: format!("wrote a model assist cannot read: {e}"),
            })?;
        if best
            .as_ref()
            .is_none_or(|(b, _)| model.images.len() > b.images.len())
        {
            best = Some((model, dir));
        }
    }
    best.ok_or(ProcessError::NoModel)
}

/// Progress in COLMAP's log lines: "Processed file [i/n]" (features), "Matching block
/// [i/n, …]" or "Matching image [i/n]" (matching), "Registering image #id (k)" (mapping,
/// `k` images registered of `count`).
fn parse_progress(stage: Stage, line: &str, count: usize) -> Option<(usize, usize)> {
    let bracket = |key: &str| -> Option<(usize, usize)> {
        let rest = &line[line.find(key)? + key.len()..];
        let inner = rest.strip_prefix('[')?;
        let end = inner.find([']', ','])?;
        let (a, b) = inner[..end].split_once('/')?;
        Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
    };
    match stage {
        Stage::Features => bracket("Processed file "),
        Stage::Matching => bracket("Matching block ").or_else(|| bracket("Matching image ")),
        Stage::Mapping => {
            let rest = &line[line.find("Registering image #")?..];
            let k = rest[rest.find('(')? + 1..rest.find(')')?]
                .trim()
                .parse()
                .ok()?;
            Some((k, count))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The flag's names (clap) and the JSON/Python names (serde) are the same words.
    #[test]
    fn camera_modes_read_the_same_on_the_command_line_and_in_json() {
        use clap::ValueEnum;
        for c in Cameras::value_variants() {
            let name = c.to_possible_value().unwrap().get_name().to_string();
            let back: Cameras =
                serde_json::from_value(serde_json::Value::from(name.clone())).unwrap();
            assert_eq!(back, *c, "{name}");
        }
        assert!(serde_json::from_value::<Cameras>(serde_json::Value::from("per-image")).is_err());
    }

    #[test]
    fn colmap_log_lines_give_progress() {
        let p = |s, l| parse_progress(s, l, 20);
        assert_eq!(
            p(
                Stage::Features,
                "I1126 18:40:01.1 feature_extraction.cc:292] Processed file [3/20]"
            ),
            Some((3, 20))
        );
        assert_eq!(
            p(Stage::Matching, "Matching block [1/4, 2/4] in 0.5s"),
            Some((1, 4))
        );
        assert_eq!(p(Stage::Matching, "Matching image [7/150]"), Some((7, 150)));
        assert_eq!(
            p(Stage::Mapping, "Registering image #12 (5)"),
            Some((5, 20))
        );
        assert_eq!(p(Stage::Mapping, "Retriangulation"), None);
        assert_eq!(p(Stage::Features, "Processed file [x/20]"), None);
    }
}
