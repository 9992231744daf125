//! The generation spec: what varies from sample to sample and how. Read from TOML (or JSON
//! by the `.json` extension); every field has a default but `scenes`, unknown fields are
//! errors, and every value is checked with an error naming its field. `docs/generate.md`
//! is the user's reference; the doc comments here are the same text.

use std::path::{Path, PathBuf};

use assist_core::action::NodeRef;
use assist_data::Output;
use serde::{Deserialize, Serialize};

use crate::{GenError, Result};

/// A whole spec.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spec {
    /// Samples to make (indices 0 to count − 1).
    #[serde(default = "default_count")]
    pub count: u64,
    /// Every sample is a pure function of (spec, seed, index).
    #[serde(default)]
    pub seed: u64,
    /// Base scenes; each sample rearranges one, drawn uniformly.
    pub scenes: Vec<BaseScene>,
    #[serde(default)]
    pub objects: ObjectRule,
    /// Objects to add, from any scene.
    #[serde(default)]
    pub library: Vec<LibraryEntry>,
    #[serde(default)]
    pub placement: Placement,
    #[serde(default)]
    pub cameras: Cameras,
    #[serde(default)]
    pub output: OutputSpec,
}

fn default_count() -> u64 {
    100
}

/// A base scene and the dataset it was trained from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseScene {
    /// A `NAME.assist` folder.
    pub path: PathBuf,
    /// Its training dataset (cameras, the captured region); default: the dataset the
    /// scene records it was trained from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data: Option<PathBuf>,
}

/// What happens to the base scene's own objects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObjectRule {
    /// Chance that an object stays in the sample (else it is deleted).
    pub keep: f64,
    /// Chance that an object that stays is placed anew (else it stays where it is).
    #[serde(rename = "move")]
    pub move_: f64,
}

impl Default for ObjectRule {
    fn default() -> Self {
        ObjectRule {
            keep: 0.85,
            move_: 0.7,
        }
    }
}

/// A library object: a node of any scene, added `min..=max` times per sample (uniformly).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LibraryEntry {
    /// The `.assist` scene holding it.
    pub scene: PathBuf,
    /// Its id or label there.
    pub node: NodeRef,
    #[serde(default)]
    pub min: u32,
    #[serde(default = "one")]
    pub max: u32,
}

fn one() -> u32 {
    1
}

/// Which upward-facing surfaces objects may stand on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Surfaces {
    /// Surfaces at the level the base scene's objects stand on (a table top).
    Objects,
    /// Every upward-facing surface the training views saw (floor included).
    All,
}

/// How placed objects are drawn and checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Placement {
    /// Yaw about the scene's up, degrees: a uniform draw in `[lo, hi]`.
    pub yaw_deg: [f64; 2],
    /// Uniform scale factor range.
    pub scale: [f64; 2],
    /// Smallest distance between two objects' occupied boxes, metres.
    pub gap_m: f64,
    /// Draws per object before it is given up (recorded in the sample).
    pub tries: u32,
    pub surfaces: Surfaces,
    /// Largest height difference of the support under one object, metres.
    pub flatness_m: f64,
    /// With `surfaces = "objects"`: how far a surface may lie from the level of the
    /// objects' bases, metres.
    pub level_m: f64,
}

impl Default for Placement {
    fn default() -> Self {
        Placement {
            yaw_deg: [-180.0, 180.0],
            scale: [1.0, 1.0],
            gap_m: 0.005,
            tries: 60,
            surfaces: Surfaces::Objects,
            flatness_m: 0.01,
            level_m: 0.03,
        }
    }
}

/// Where a sample's cameras come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraFrom {
    /// The training views (jittered).
    Train,
    /// The dataset's test views (jittered).
    Test,
    /// Every view of the dataset (jittered).
    All,
    /// A random point of an orbit around the sample's objects.
    Orbit,
}

/// The cameras of each sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Cameras {
    pub from: CameraFrom,
    /// Views per sample.
    pub views: u32,
    /// Camera position jitter: a uniform draw in a ball of this radius, metres.
    pub jitter_m: f64,
    /// Camera rotation jitter: up to this angle about a random axis, degrees.
    pub jitter_deg: f64,
    /// Aim every camera at this object (id or label) when the sample has it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at: Option<NodeRef>,
    /// Orbit: elevation above the horizon, degrees (uniform in the range).
    pub elevation_deg: [f64; 2],
    /// Orbit: horizontal field of view, degrees.
    pub fov_deg: f64,
    /// Orbit: a view is kept only where the capture stood, within this angle of a
    /// training camera's direction from the orbit's centre (180 = anywhere); its distance
    /// is kept within the training cameras' distances from the centre.
    pub orbit_within_deg: f64,
}

impl Default for Cameras {
    fn default() -> Self {
        Cameras {
            from: CameraFrom::Train,
            views: 1,
            jitter_m: 0.05,
            jitter_deg: 2.0,
            look_at: None,
            elevation_deg: [20.0, 50.0],
            fov_deg: 50.0,
            orbit_within_deg: 20.0,
        }
    }
}

/// Image size and the images written per view (annotations are always written).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputSpec {
    pub width: u32,
    pub height: u32,
    /// Any of rgb, depth, panoptic, semantic, objects, background.
    pub images: Vec<String>,
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            width: 480,
            height: 360,
            images: ["rgb", "depth", "panoptic", "semantic"]
                .map(String::from)
                .to_vec(),
        }
    }
}

impl OutputSpec {
    pub fn outputs(&self) -> std::result::Result<Vec<Output>, String> {
        let mut v = Vec::new();
        for w in &self.images {
            v.push(Output::parse(w)?);
        }
        // Annotations need the instance ids.
        if !v.contains(&Output::Panoptic) {
            v.push(Output::Panoptic);
        }
        v.sort();
        v.dedup();
        Ok(v)
    }
}

impl Spec {
    /// The default spec for one scene: its own objects rearranged (the documented
    /// defaults).
    pub fn for_scene(scene: &Path) -> Spec {
        Spec {
            count: default_count(),
            seed: 0,
            scenes: vec![BaseScene {
                path: scene.to_path_buf(),
                data: None,
            }],
            objects: ObjectRule::default(),
            library: Vec::new(),
            placement: Placement::default(),
            cameras: Cameras::default(),
            output: OutputSpec::default(),
        }
    }

    /// Reads a spec file (TOML, or JSON by extension); relative paths in it are taken
    /// relative to the file's folder.
    pub fn load(path: &Path) -> Result<Spec> {
        let text = assist_fs::read_text(path).map_err(|e| GenError::Spec {
            path: path.into(),
            field: "file".into(),
            message: e.to_string(),
        })?;
        let bad = |message: String| GenError::Spec {
            path: path.into(),
            field: "spec".into(),
            message,
        };
        let mut spec: Spec = if path.extension().is_some_and(|e| e == "json") {
            serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?
        } else {
            toml::from_str(&text).map_err(|e| bad(e.to_string().trim_end().to_string()))?
        };
        let base = path.parent().unwrap_or(Path::new("."));
        let rel = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        for s in &mut spec.scenes {
            rel(&mut s.path);
            if let Some(d) = &mut s.data {
                rel(d);
            }
        }
        for l in &mut spec.library {
            rel(&mut l.scene);
        }
        spec.check(path)?;
        Ok(spec)
    }

    /// Checks every value; `path` names the spec in errors.
    pub fn check(&self, path: &Path) -> Result<()> {
        let err = |field: &str, message: String| {
            Err(GenError::Spec {
                path: path.into(),
                field: field.into(),
                message,
            })
        };
        if self.count == 0 || self.count > 100_000_000 {
            return err(
                "count",
                format!("expected 1 to 100000000 samples, got {}", self.count),
            );
        }
        if self.scenes.is_empty() {
            return err("scenes", "expected at least one base scene".into());
        }
        let prob = |field: &str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                err(field, format!("expected a probability in [0, 1], got {v}"))
            }
        };
        prob("objects.keep", self.objects.keep)?;
        prob("objects.move", self.objects.move_)?;
        for (k, l) in self.library.iter().enumerate() {
            if l.min > l.max {
                return err(
                    &format!("library[{k}].min"),
                    format!("min {} is above max {}", l.min, l.max),
                );
            }
            if l.max > 64 {
                return err(
                    &format!("library[{k}].max"),
                    format!("expected at most 64 copies per sample, got {}", l.max),
                );
            }
        }
        let p = &self.placement;
        let range = |field: &str, r: [f64; 2], lo: f64, hi: f64| {
            if r.iter().all(|v| v.is_finite() && (lo..=hi).contains(v)) && r[0] <= r[1] {
                Ok(())
            } else {
                err(
                    field,
                    format!("expected [low, high] with {lo} ≤ low ≤ high ≤ {hi}, got {r:?}"),
                )
            }
        };
        range("placement.yaw_deg", p.yaw_deg, -360.0, 360.0)?;
        range("placement.scale", p.scale, 0.05, 20.0)?;
        let nonneg = |field: &str, v: f64, hi: f64| {
            if v.is_finite() && (0.0..=hi).contains(&v) {
                Ok(())
            } else {
                err(field, format!("expected a value in [0, {hi}], got {v}"))
            }
        };
        nonneg("placement.gap_m", p.gap_m, 10.0)?;
        nonneg("placement.flatness_m", p.flatness_m, 10.0)?;
        nonneg("placement.level_m", p.level_m, 100.0)?;
        if p.tries == 0 || p.tries > 100_000 {
            return err(
                "placement.tries",
                format!("expected 1 to 100000 draws, got {}", p.tries),
            );
        }
        let c = &self.cameras;
        if c.views == 0 || c.views > 1000 {
            return err(
                "cameras.views",
                format!("expected 1 to 1000 views per sample, got {}", c.views),
            );
        }
        nonneg("cameras.jitter_m", c.jitter_m, 100.0)?;
        nonneg("cameras.jitter_deg", c.jitter_deg, 180.0)?;
        range("cameras.elevation_deg", c.elevation_deg, -89.0, 89.0)?;
        if !(c.orbit_within_deg > 0.0 && c.orbit_within_deg <= 180.0) {
            return err(
                "cameras.orbit_within_deg",
                format!(
                    "expected degrees above 0 and at most 180, got {}",
                    c.orbit_within_deg
                ),
            );
        }
        if !(1.0..179.0).contains(&c.fov_deg) {
            return err(
                "cameras.fov_deg",
                format!("expected degrees between 1 and 179, got {}", c.fov_deg),
            );
        }
        let o = &self.output;
        if !(1..=16384).contains(&o.width) || !(1..=16384).contains(&o.height) {
            return err(
                "output.width/height",
                format!(
                    "expected 1 to 16384 pixels each way, got {}×{}",
                    o.width, o.height
                ),
            );
        }
        if let Err(m) = o.outputs() {
            return err("output.images", m);
        }
        Ok(())
    }
}
