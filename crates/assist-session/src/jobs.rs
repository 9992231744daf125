//! The smaller jobs front ends run on a scene file: measuring it against a dataset
//! ([`EvalJob`]), finding the light its objects' shadows were cast by ([`LightJob`]), and
//! reading a photograph as training sees it ([`photograph`]).

use std::path::PathBuf;

use assist_core::ShadowCast;
use assist_data::{Frame, LoadOptions, Split};
use assist_scene::scene_file;
pub use assist_train::light::MIN_EXPLAINED as LIGHT_MIN_EXPLAINED;
pub use assist_train::{EvalReport, EvaluatedView, LightEstimate};

use crate::{Result, Session, SessionError};

/// The `downscale` a scene was trained with, from its file's `info` (1 when it does not
/// say).
pub fn trained_downscale(info: &serde_json::Value) -> u32 {
    info.pointer("/options/downscale")
        .and_then(|v| v.as_u64())
        .map_or(1, |v| {
            v.clamp(1, assist_data::downscale::MAX_DOWNSCALE as u64) as u32
        })
}

/// Image quality and panoptic accuracy of a trained scene on a dataset's split.
#[derive(Debug, Clone)]
pub struct EvalJob {
    /// The trained scene directory.
    pub scene: PathBuf,
    /// The dataset with the cameras and ground truth.
    pub data: PathBuf,
    /// The split measured (`None`: every frame).
    pub split: Option<Split>,
    /// Every this-many-th frame of the split.
    pub stride: usize,
    /// Images this many times smaller (`None`: as the scene was trained).
    pub downscale: Option<u32>,
    /// Where the fields are queried (a GPU: `--device`; `None`: this CPU).
    pub backend: Option<std::sync::Arc<dyn assist_render::FieldBackend>>,
    /// Fit each view's camera to its photograph before measuring (`None`: as given).
    pub align: Option<assist_train::AlignOptions>,
}

impl EvalJob {
    /// Loads the scene and the dataset and measures; `progress(done, total)` per image.
    pub fn run(&self, progress: impl FnMut(usize, usize)) -> Result<EvalReport> {
        self.run_each(progress, |_| {})
    }

    /// [`run`](Self::run), handing each measured view to `on_view`.
    pub fn run_each(
        &self,
        progress: impl FnMut(usize, usize),
        on_view: impl FnMut(assist_train::EvaluatedView<'_>),
    ) -> Result<EvalReport> {
        let (scene, info) = scene_file::load(&self.scene)?;
        let opts = LoadOptions {
            downscale: self.downscale.unwrap_or_else(|| trained_downscale(&info)),
            ..Default::default()
        };
        let ds = assist_data::load(&self.data, &opts).map_err(SessionError::Data)?;
        Ok(assist_train::evaluate_each(
            &scene,
            &ds,
            self.split,
            self.stride.max(1),
            &assist_render::RenderOptions {
                backend: self.backend.clone(),
                ..Default::default()
            },
            self.align.as_ref(),
            progress,
            on_view,
        )?)
    }
}

impl Session {
    /// The scene as it is in memory, measured on `ds`'s `split` (`None`: every frame).
    pub fn evaluate(
        &self,
        ds: &assist_data::Dataset,
        split: Option<Split>,
        stride: usize,
        progress: impl FnMut(usize, usize),
    ) -> Result<EvalReport> {
        Ok(assist_train::evaluate(
            self.scene(),
            ds,
            split,
            stride.max(1),
            progress,
        )?)
    }
}

/// Finds the lamp that casts a scene's learned shadows and writes the scene with it
/// (training does this at its end; this is for scenes trained before, or to look again).
#[derive(Debug, Clone)]
pub struct LightJob {
    pub scene: PathBuf,
    /// Where the scene with its light is written (may be `scene` itself, with `force`).
    pub out: PathBuf,
    pub force: bool,
    /// Whether objects moved from where they were photographed are shaded by the light
    /// where they stand now ([`assist_core::Scene::relight`]); `None` keeps the scene's.
    pub relight: Option<bool>,
}

impl LightJob {
    pub fn run(&self) -> Result<LightEstimate> {
        let (mut scene, mut history, meta) = scene_file::load_with_history(&self.scene)?;
        // Where each object's shadow was learned: where it stood before the first edit (a
        // replica where its original stood; a node from another scene is left out).
        let first = history.undo.first().map(|s| s.scene.clone());
        let e = assist_train::estimate_light_from(&mut scene, |n| match (&n.cast, &first) {
            (Some(c), _) => Some(c.pose),
            (None, None) => Some(n.world_from_local),
            (None, Some(first)) => first
                .nodes
                .iter()
                .find(|o| o.field == n.field)
                .map(|o| o.world_from_local),
        });
        // The scenes the history holds get the same light, so an undo keeps it.
        let casts: Vec<(u16, String, Option<ShadowCast>)> = scene
            .scene
            .nodes
            .iter()
            .map(|n| (n.id, n.field.clone(), n.cast.clone()))
            .collect();
        if let Some(r) = self.relight {
            scene.scene.relight = r;
        }
        for step in history.undo.iter_mut().chain(history.redo.iter_mut()) {
            step.scene.light = scene.scene.light;
            step.scene.relight = scene.scene.relight;
            for n in &mut step.scene.nodes {
                n.cast = casts
                    .iter()
                    .find(|(id, f, _)| *id == n.id && *f == n.field)
                    .and_then(|(_, _, c)| c.clone());
            }
        }
        scene_file::save_with_history(&self.out, &scene, &history, meta, self.force)?;
        Ok(e)
    }
}

/// A photograph as training and evaluation see it: its stored (sRGB) values in [0, 1], row-major,
/// transparent pixels over `backdrop`.
#[derive(Debug, Clone)]
pub struct Photograph {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<f32>,
}

/// Reads `frame`'s image (at the dataset's downscale) over `backdrop`.
pub fn photograph(frame: &Frame, backdrop: [f32; 3]) -> Result<Photograph> {
    let v = assist_train::load_view(frame, u32::MAX, backdrop)?;
    Ok(Photograph {
        width: v.width,
        height: v.height,
        rgb: v.rgb,
    })
}

/// The dataset a scene was trained on, from its file's `info`. A relative path (scenes
/// trained before paths were recorded whole) is read against the folder that holds the
/// scene, never the working directory; the dataset found there must have the fingerprint
/// recorded at training. `Ok(None)` when the scene records no dataset.
pub fn recorded_dataset(
    scene: &std::path::Path,
    info: &serde_json::Value,
) -> Result<Option<PathBuf>> {
    let Some(d) = info.get("dataset").and_then(|v| v.as_str()) else {
        return Ok(None);
    };
    let recorded = PathBuf::from(d);
    let path = if recorded.is_absolute() {
        recorded
    } else {
        let dir = if scene.is_dir() {
            scene
        } else {
            scene.parent().unwrap_or(std::path::Path::new("."))
        };
        dir.parent()
            .unwrap_or(std::path::Path::new("."))
            .join(recorded)
    };
    let missing = || {
        crate::request(
            "dataset",
            format!(
                "{} was trained on {d} ({}), which is not there; give the dataset (--data)",
                scene.display(),
                path.display()
            ),
        )
    };
    if !path.exists() {
        return Err(missing());
    }
    if let Some(want) = info.get("dataset_fingerprint").and_then(|v| v.as_str()) {
        let opts = LoadOptions {
            downscale: trained_downscale(info),
            ..Default::default()
        };
        let ds = assist_data::load(&path, &opts).map_err(SessionError::Data)?;
        let got = ds.fingerprint();
        if got != want {
            return Err(crate::request(
                "dataset",
                format!(
                    "{} is not the dataset {} was trained on (fingerprint {got}, recorded {want}: other frames or poses); give the dataset (--data)",
                    path.display(),
                    scene.display()
                ),
            ));
        }
    }
    Ok(Some(path))
}

/// The box training would give each object of the dataset at `path` (from its instance
/// masks or boxes, or from `user`'s boxes, which win), in its world frame.
pub fn dataset_boxes(
    path: &std::path::Path,
    user: Vec<assist_data::boxes::BoxOverride>,
) -> Result<Vec<assist_train::NodeBox>> {
    use assist_data::Split;
    use assist_train::{SetupOptions, background_color, node_boxes, scene_region};
    let ds = assist_data::load(path, &LoadOptions::default()).map_err(SessionError::Data)?;
    if ds.count(Split::Train) == 0 {
        return Err(crate::request(
            "dataset",
            format!("{}: the dataset has no training frames", path.display()),
        ));
    }
    let views = assist_train::load_views(&ds, Split::Train, background_color(&ds))?;
    let opts = SetupOptions {
        boxes: user,
        ..Default::default()
    };
    Ok(node_boxes(&ds, &views, &scene_region(&ds, &views), &opts)?)
}
