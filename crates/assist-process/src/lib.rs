//! `assist process`: from a phone video or a folder of photographs nobody posed to a
//! dataset `assist train` reads as it is. Frames are decoded by the real `ffmpeg` and the
//! sharpest in each window kept ([`frames`]); poses come from the real COLMAP ([`colmap`]:
//! never reimplemented); the model is turned upright, centred and, given one known
//! distance, put in metres ([`align`]); the result is a nerfstudio dataset ([`write`]).
//! Everything is written in a staging folder and swapped into place at the end, so a
//! failure — a missing program, too few frames registered — leaves nothing behind.

pub mod align;
pub mod colmap;
pub mod compare;
pub mod frames;
pub mod tools;
pub mod write;

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

pub use align::ScaleBy;
pub use colmap::{Cameras, Matcher};

/// Default number of frames taken from a video.
pub const DEFAULT_FRAMES: usize = 150;
/// Fewest photographs a capture can be posed from.
pub const MIN_IMAGES: usize = 3;

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(
        "{tool} is not installed (not on PATH): install Debian's {package} package (apt install {package})"
    )]
    MissingTool {
        tool: &'static str,
        package: &'static str,
    },
    #[error("{tool} failed {what}: {message}")]
    Tool {
        tool: &'static str,
        what: String,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    Input { path: PathBuf, message: String },
    #[error("{}: {message}", path.display())]
    Io { path: PathBuf, message: String },
    #[error(
        "COLMAP registered no images: the views share too little (a blank wall, no texture) or the camera never moved; film the scene while walking around it"
    )]
    NoModel,
    #[error(
        "COLMAP registered {registered} of {total} frames, fewer than half; not registered: {missing}. Film slower, with more overlap between frames and more texture in view"
    )]
    TooFewRegistered {
        registered: usize,
        total: usize,
        missing: String,
    },
    #[error("--scale-by: {0}")]
    ScaleBy(String),
    #[error("cancelled; nothing was written")]
    Cancelled,
    #[error(transparent)]
    Fs(#[from] assist_fs::FsError),
}

/// What to process and how.
#[derive(Debug, Clone)]
pub struct ProcessJob {
    /// A video file or a folder of images.
    pub input: PathBuf,
    /// The dataset folder to write.
    pub out: PathBuf,
    /// Frames to keep (a video's, or a larger folder's sharpest per window).
    pub frames: usize,
    /// How to pair images for matching; `None` = sequential for a video or a folder of
    /// more than [`colmap::MAX_EXHAUSTIVE`] images, exhaustive otherwise.
    pub matcher: Option<Matcher>,
    /// One camera for the capture, or one per frame.
    pub cameras: Cameras,
    /// One known distance, for metres.
    pub scale_by: Option<ScaleBy>,
    /// Replace `out` if assist wrote it.
    pub force: bool,
    /// Set to stop: the running program is killed and nothing is written.
    pub cancel: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

/// The stages, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    Frames,
    Features,
    Matching,
    Mapping,
    Writing,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Frames => "frames",
            Stage::Features => "features",
            Stage::Matching => "matching",
            Stage::Mapping => "mapping",
            Stage::Writing => "writing",
        }
    }
}

/// What `process` reports while it runs.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum ProcessEvent {
    /// A stage begins.
    Stage { stage: Stage, detail: String },
    /// Progress within a stage.
    Progress {
        stage: Stage,
        done: usize,
        total: usize,
    },
}

/// What `process` made.
#[derive(Debug, Clone, Serialize)]
pub struct ProcessSummary {
    pub out: PathBuf,
    /// `video` or `images`.
    pub input_kind: &'static str,
    /// Frames given to COLMAP, and how many it registered.
    pub frames: usize,
    pub registered: usize,
    /// Names of the frames COLMAP did not register (left out of the dataset).
    pub not_registered: Vec<String>,
    pub matcher: Matcher,
    pub cameras: Cameras,
    pub points: usize,
    /// Metres per unit, when `--scale-by` gave one; `None`: COLMAP's arbitrary unit.
    pub meters_per_unit: Option<f64>,
    pub width: u32,
    pub height: u32,
    /// Seconds per stage, in order.
    pub seconds: Vec<(Stage, f64)>,
    /// What the user should know about the result (e.g. a `--scale-by` pixel near a
    /// frame's border).
    pub warnings: Vec<String>,
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> ProcessError + '_ {
    move |e| ProcessError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl ProcessJob {
    /// Runs the job (see the crate docs), reporting through `on_event`.
    pub fn run(
        &self,
        on_event: &mut dyn FnMut(&ProcessEvent),
    ) -> Result<ProcessSummary, ProcessError> {
        let input_kind = if self.input.is_dir() {
            "images"
        } else if self.input.is_file() {
            "video"
        } else {
            return Err(ProcessError::Input {
                path: self.input.clone(),
                message: "no such file or folder (give a video or a folder of images)".into(),
            });
        };
        if self.frames < MIN_IMAGES {
            return Err(ProcessError::Input {
                path: self.input.clone(),
                message: format!("--frames {} is under {MIN_IMAGES}", self.frames),
            });
        }
        // The programs are checked before anything is written.
        if input_kind == "video" {
            tools::FFMPEG.find()?;
            tools::FFPROBE.find()?;
        }
        tools::COLMAP.find()?;
        assist_fs::check_replaceable_as(&self.out, self.force, assist_fs::Kind::Dataset)?;
        assist_fs::check_not_input(&self.out, &[self.input.as_path()])?;
        let staging = assist_fs::Staging::begin(&self.out, "process")?;
        let dir = staging.dir().to_path_buf();
        let work = dir.join("colmap");
        let images = dir.join("images");
        for d in [&work, &images] {
            std::fs::create_dir_all(d).map_err(io(d))?;
        }
        let mut seconds = Vec::new();
        let t0 = Instant::now();
        let names = self.gather(input_kind, &dir, on_event)?;
        check_sizes(&images, &names, &self.input, input_kind == "images")?;
        seconds.push((Stage::Frames, t0.elapsed().as_secs_f64()));
        let matcher = self.matcher.unwrap_or(
            if input_kind == "video" || names.len() > colmap::MAX_EXHAUSTIVE {
                Matcher::Sequential
            } else {
                Matcher::Exhaustive
            },
        );
        let t1 = Instant::now();
        let (model, model_dir) = colmap::reconstruct(
            &images,
            &work,
            matcher,
            self.cameras,
            names.len(),
            &self.cancel,
            on_event,
        )?;
        seconds.push((Stage::Mapping, t1.elapsed().as_secs_f64()));
        let registered: std::collections::BTreeSet<&str> =
            model.images.iter().map(|i| i.name.as_str()).collect();
        let not_registered: Vec<String> = names
            .iter()
            .filter(|n| !registered.contains(n.as_str()))
            .cloned()
            .collect();
        if registered.len() * 2 < names.len() {
            let mut missing = not_registered[..not_registered.len().min(20)].join(", ");
            if not_registered.len() > 20 {
                missing.push_str(&format!(" and {} more", not_registered.len() - 20));
            }
            return Err(ProcessError::TooFewRegistered {
                registered: registered.len(),
                total: names.len(),
                missing,
            });
        }
        let t2 = Instant::now();
        on_event(&ProcessEvent::Stage {
            stage: Stage::Writing,
            detail: "transforms.json, split.json, sparse points, images_2/4/8".into(),
        });
        let aligned = align::align(&model, self.scale_by.as_ref(), &model_dir)?;
        let camera = model.cameras.values().next().ok_or(ProcessError::NoModel)?;
        write::dataset_files(&dir, &model, &aligned)?;
        // Frames COLMAP could not pose are not part of the dataset.
        for n in &not_registered {
            let p = images.join(n);
            std::fs::remove_file(&p).map_err(io(&p))?;
        }
        let kept: Vec<String> = aligned.frames.iter().map(|f| f.name.clone()).collect();
        write::downscaled_copies(&dir, &kept)?;
        // The sparse model and COLMAP's log stay (under colmap/); the feature database,
        // large and only COLMAP's, does not.
        let db = work.join("database.db");
        std::fs::remove_file(&db).map_err(io(&db))?;
        seconds.push((Stage::Writing, t2.elapsed().as_secs_f64()));
        let summary = ProcessSummary {
            out: self.out.clone(),
            input_kind,
            frames: names.len(),
            registered: registered.len(),
            not_registered,
            matcher,
            cameras: self.cameras,
            points: aligned.points.len(),
            meters_per_unit: aligned.meters_per_unit,
            width: camera.width,
            height: camera.height,
            seconds,
            warnings: aligned.warnings.clone(),
        };
        let record = serde_json::json!({
            "input": self.input,
            "summary": &summary,
            "colmap_model": model_dir.strip_prefix(&dir).unwrap_or(&model_dir),
            "unit": match aligned.meters_per_unit {
                Some(_) => "metres (from --scale-by)",
                None => "COLMAP's arbitrary unit: give --scale-by for metres, or later `assist scene scale` with an object's height",
            },
            "scale_by": self.scale_by.as_ref().zip(aligned.known).map(|(by, [a, b])| serde_json::json!({
                "a": { "frame": by.a.0, "pixel": by.a.1, "point": a.to_array() },
                "b": { "frame": by.b.0, "pixel": by.b.1, "point": b.to_array() },
                "meters": by.meters,
            })),
        });
        let path = dir.join("process.json");
        std::fs::write(
            &path,
            serde_json::to_string_pretty(&record).unwrap_or_default(),
        )
        .map_err(io(&path))?;
        staging.commit()?;
        Ok(summary)
    }

    /// Puts the frames into `dir/images/` (a video's sharpest, or the folder's images,
    /// thinned to `frames` if more); returns their names in capture order.
    fn gather(
        &self,
        kind: &str,
        dir: &Path,
        on_event: &mut dyn FnMut(&ProcessEvent),
    ) -> Result<Vec<String>, ProcessError> {
        let images = dir.join("images");
        let candidates = if kind == "video" {
            let cand = dir.join("candidates");
            std::fs::create_dir_all(&cand).map_err(io(&cand))?;
            let runner = tools::Runner {
                log: dir.join("colmap").join("ffmpeg.log"),
                cancel: &self.cancel,
            };
            frames::video_candidates(&self.input, &cand, self.frames, &runner, on_event)?
        } else {
            on_event(&ProcessEvent::Stage {
                stage: Stage::Frames,
                detail: format!("photographs in {}", self.input.display()),
            });
            frames::list_images(&self.input)?
        };
        if candidates.len() < MIN_IMAGES {
            return Err(ProcessError::Input {
                path: self.input.clone(),
                message: format!(
                    "{} image(s); poses need at least {MIN_IMAGES} photographs of the scene from different places",
                    candidates.len()
                ),
            });
        }
        let picked = if candidates.len() > self.frames {
            let mut scores = Vec::with_capacity(candidates.len());
            for (k, c) in candidates.iter().enumerate() {
                if self.cancel.load(std::sync::atomic::Ordering::SeqCst) {
                    return Err(ProcessError::Cancelled);
                }
                scores.push(frames::sharpness(c)?);
                on_event(&ProcessEvent::Progress {
                    stage: Stage::Frames,
                    done: k + 1,
                    total: candidates.len(),
                });
            }
            frames::sharpest_per_window(&scores, self.frames)
        } else {
            (0..candidates.len()).collect()
        };
        let mut names = Vec::new();
        for (k, &i) in picked.iter().enumerate() {
            let src = &candidates[i];
            let name = if kind == "video" {
                format!("frame_{:05}.jpg", k + 1)
            } else {
                src.file_name()
                    .and_then(|n| n.to_str())
                    .ok_or_else(|| ProcessError::Input {
                        path: src.clone(),
                        message: "the file name is not UTF-8".into(),
                    })?
                    .to_string()
            };
            let dst = images.join(&name);
            if kind == "video" {
                std::fs::rename(src, &dst).map_err(io(src))?;
            } else {
                std::fs::copy(src, &dst).map_err(io(src))?;
            }
            names.push(name);
        }
        if kind == "video" {
            let cand = dir.join("candidates");
            std::fs::remove_dir_all(&cand).map_err(io(&cand))?;
        }
        Ok(names)
    }
}

/// Every image must have the first one's size (one camera for the capture); errors name
/// the user's file when the images came from a folder.
fn check_sizes(
    images: &Path,
    names: &[String],
    input: &Path,
    from_folder: bool,
) -> Result<(), ProcessError> {
    let mut first: Option<(u32, u32)> = None;
    for n in names {
        let p = images.join(n);
        let size = image::image_dimensions(&p).map_err(|e| ProcessError::Input {
            path: p.clone(),
            message: format!("not an image this build can read: {e}"),
        })?;
        match first {
            None => first = Some(size),
            Some(f) if f != size => {
                return Err(ProcessError::Input {
                    path: if from_folder {
                        input.join(n)
                    } else {
                        PathBuf::from(n)
                    },
                    message: format!(
                        "is {}×{}, the first image {}×{}: one capture is one camera, all its images one size",
                        size.0, size.1, f.0, f.1
                    ),
                });
            }
            _ => {}
        }
    }
    Ok(())
}
