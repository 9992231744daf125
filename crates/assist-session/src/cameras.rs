//! Cameras to render: a dataset's split (file names kept), a bare `transforms.json`, or
//! an orbit around the scene's objects.

use std::path::{Path, PathBuf};

use assist_core::{Camera, DVec3, Intrinsics, Pose, Scene};
use assist_data::{LoadOptions, Split};
use serde::{Deserialize, Serialize};

use crate::{Result, SessionError, request};

/// A camera with the name its files are written under.
#[derive(Debug, Clone)]
pub struct NamedCamera {
    pub name: String,
    pub camera: Camera,
}

/// Which frames of a dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SplitChoice {
    Train,
    Val,
    Test,
    All,
    /// The test split when the dataset declares its split (split.json, `*_filenames`,
    /// Blender's files), else every frame (e.g. a bare `transforms.json` of cameras).
    #[default]
    Auto,
}

impl SplitChoice {
    pub fn parse(s: &str) -> Option<SplitChoice> {
        Some(match s {
            "all" => SplitChoice::All,
            "auto" => SplitChoice::Auto,
            other => match Split::parse(other)? {
                Split::Train => SplitChoice::Train,
                Split::Val => SplitChoice::Val,
                Split::Test => SplitChoice::Test,
            },
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            SplitChoice::Train => "train",
            SplitChoice::Val => "val",
            SplitChoice::Test => "test",
            SplitChoice::All => "all",
            SplitChoice::Auto => "auto",
        }
    }
}

/// Cameras on a circle around the objects, looking at their centre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Orbit {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
    /// Elevation above the horizon, degrees.
    pub elevation_deg: f64,
    /// Distance from the centre in world units; `None` frames the objects.
    pub radius: Option<f64>,
}

impl Default for Orbit {
    fn default() -> Self {
        Orbit {
            frames: 24,
            width: 480,
            height: 360,
            fov_deg: 50.0,
            elevation_deg: 30.0,
            radius: None,
        }
    }
}

/// Where the cameras of a render come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraSource {
    /// A dataset folder or a `transforms.json`, read by assist-data's readers.
    Dataset {
        path: PathBuf,
        #[serde(default)]
        split: SplitChoice,
        /// Render the cameras this many times smaller.
        #[serde(default = "one")]
        downscale: u32,
    },
    Orbit(Orbit),
}

fn one() -> u32 {
    1
}

impl CameraSource {
    /// A dataset's training cameras, or the default orbit when there is no dataset (what a
    /// viewer opens with).
    pub fn train_or_orbit(data: Option<&Path>) -> Self {
        match data {
            Some(path) => CameraSource::Dataset {
                path: path.to_path_buf(),
                split: SplitChoice::Train,
                downscale: 1,
            },
            None => CameraSource::Orbit(Orbit::default()),
        }
    }

    /// The cameras, for `scene` (an orbit frames its objects).
    pub fn cameras(&self, scene: &Scene) -> Result<Vec<NamedCamera>> {
        match self {
            CameraSource::Orbit(o) => orbit(scene, o),
            CameraSource::Dataset {
                path,
                split,
                downscale,
            } => dataset_cameras(path, *split, *downscale),
        }
    }
}

/// The world box around the scene's objects (or all nodes when it has none).
pub fn objects_box(scene: &Scene) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let has_objects = scene.nodes.iter().any(|n| !n.is_background());
    for n in scene
        .nodes
        .iter()
        .filter(|n| !has_objects || !n.is_background())
    {
        for c in n.world_corners() {
            lo = lo.min(c);
            hi = hi.max(c);
        }
    }
    (lo, hi)
}

/// `o.frames` cameras on a circle around the objects, looking at their centre.
/// The most cameras one orbit may hold (a million frames of cameras alone is gigabytes;
/// a dataset of more views is made in several runs).
pub const MAX_ORBIT_FRAMES: usize = 100_000;

pub fn orbit(scene: &Scene, o: &Orbit) -> Result<Vec<NamedCamera>> {
    let bad = |m: String| Err(request("orbit", m));
    if o.frames == 0
        || o.frames > MAX_ORBIT_FRAMES
        || o.width == 0
        || o.height == 0
        || o.width > 16384
        || o.height > 16384
    {
        return bad(format!(
            "expected 1 to {MAX_ORBIT_FRAMES} frames and 1 to 16384 pixels each way, got {} frames of {}×{}",
            o.frames, o.width, o.height
        ));
    }
    if !(1.0..179.0).contains(&o.fov_deg) {
        return bad(format!(
            "field of view: expected degrees between 1 and 179, got {}",
            o.fov_deg
        ));
    }
    if !(-89.0..=89.0).contains(&o.elevation_deg) {
        return bad(format!(
            "elevation: expected degrees between -89 and 89, got {}",
            o.elevation_deg
        ));
    }
    let (lo, hi) = objects_box(scene);
    if !lo.is_finite() || !hi.is_finite() {
        return bad("the scene has no nodes to orbit around".into());
    }
    let centre = (lo + hi) * 0.5;
    let half_diag = ((hi - lo) * 0.5).length().max(1e-6);
    let fov_x = o.fov_deg.to_radians();
    let fov_y = 2.0 * ((0.5 * fov_x).tan() * o.height as f64 / o.width as f64).atan();
    let r = match o.radius {
        Some(r) if !(r.is_finite() && r > 0.0) => {
            return bad(format!("radius: expected a positive distance, got {r}"));
        }
        Some(r) => r,
        None => 1.15 * half_diag / (0.5 * fov_y.min(fov_x)).sin(),
    };
    if !(r.is_finite() && centre.is_finite() && (centre.length() + r) < 1e12) {
        return bad(format!(
            "the scene's objects span {lo:.3?} to {hi:.3?}: no orbit around them fits in finite space (give a radius, or fix the scene's boxes)"
        ));
    }
    let up = scene.up.normalize();
    let a = if up.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    let e1 = (a - up * a.dot(up)).normalize();
    let e2 = up.cross(e1);
    let el = o.elevation_deg.to_radians();
    let intr = Intrinsics::from_fov_x(o.width, o.height, fov_x);
    (0..o.frames)
        .map(|k| {
            let th = std::f64::consts::TAU * k as f64 / o.frames as f64;
            let dir = (e1 * th.cos() + e2 * th.sin()) * el.cos() + up * el.sin();
            let pose = Pose::look_at(centre + dir * r, centre, up)
                .map_err(|e| request("orbit", e.to_string()))?;
            Ok(NamedCamera {
                name: format!("orbit_{k:03}"),
                camera: Camera {
                    intrinsics: intr,
                    pose,
                },
            })
        })
        .collect()
}

/// The cameras of a dataset split, named after their frames.
pub fn dataset_cameras(
    path: &Path,
    split: SplitChoice,
    downscale: u32,
) -> Result<Vec<NamedCamera>> {
    let opts = LoadOptions {
        downscale,
        ..Default::default()
    };
    let ds = assist_data::load(path, &opts).map_err(SessionError::Data)?;
    let want = match split {
        SplitChoice::All => None,
        SplitChoice::Auto if !ds.split_declared => None,
        SplitChoice::Auto | SplitChoice::Test => Some(Split::Test),
        SplitChoice::Train => Some(Split::Train),
        SplitChoice::Val => Some(Split::Val),
    };
    let cams: Vec<NamedCamera> = ds
        .frames
        .iter()
        .filter(|f| want.is_none_or(|s| f.split == s))
        .map(|f| NamedCamera {
            name: f.name.clone(),
            camera: f.camera,
        })
        .collect();
    if cams.is_empty() {
        return Err(request(
            "cameras",
            format!(
                "{}: no frames in split {:?} (it has {} frames in all)",
                path.display(),
                split.name(),
                ds.frames.len()
            ),
        ));
    }
    Ok(cams)
}
