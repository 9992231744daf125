//! The one `Dataset` type every reader produces, splits, and scene bounds with the
//! normalisation that maps outputs back to the dataset's own units. (Format detection and
//! loading, which call the readers, are in `load.rs`.)

use std::path::{Path, PathBuf};

use assist_core::{Aabb, Camera, DMat3, DVec3, InstanceId, Obb};
use serde::Serialize;

use crate::error::{DataError, Result};

/// Which reader produced a dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    Nerfstudio,
    Blender,
    ColmapBinary,
    ColmapText,
    Llff,
}

impl Format {
    pub fn name(&self) -> &'static str {
        match self {
            Format::Nerfstudio => "nerfstudio",
            Format::Blender => "blender",
            Format::ColmapBinary => "colmap-binary",
            Format::ColmapText => "colmap-text",
            Format::Llff => "llff",
        }
    }
    pub fn parse(s: &str) -> Option<Format> {
        Some(match s {
            "nerfstudio" => Format::Nerfstudio,
            "blender" => Format::Blender,
            "colmap" | "colmap-binary" => Format::ColmapBinary,
            "colmap-text" => Format::ColmapText,
            "llff" => Format::Llff,
            _ => return None,
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub fn name(&self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
    pub fn parse(s: &str) -> Option<Split> {
        Some(match s {
            "train" => Split::Train,
            "val" | "validation" => Split::Val,
            "test" => Split::Test,
            _ => return None,
        })
    }
}

/// One posed image and what comes with it.
#[derive(Debug, Clone, Serialize)]
pub struct Frame {
    /// File stem of the image (used to name outputs rendered for this camera).
    pub name: String,
    pub image_path: PathBuf,
    pub camera: Camera,
    /// The camera model as the source names it (`OPENCV`, `SIMPLE_RADIAL`, …).
    pub camera_model: String,
    pub split: Split,
    /// Binary mask of pixels to use (nerfstudio `mask_path`).
    pub mask_path: Option<PathBuf>,
    /// The image's alpha is the object mask (Blender synthetic).
    pub alpha_is_mask: bool,
    /// Instance ids per pixel, 0 = background.
    pub instance_mask_path: Option<PathBuf>,
    /// How the instance mask's values map to ids (a binary mask is one object).
    pub mask_encoding: crate::masks::MaskEncoding,
    /// Z-depth PNG; raw value × `depth_scale` = depth in scene units.
    pub depth_path: Option<PathBuf>,
    pub depth_scale: f64,
    /// User-supplied background prior: the image with objects inpainted (nerfstudio
    /// extension `inpaint_path`).
    pub inpaint_path: Option<PathBuf>,
    /// User-supplied background depth prior (`inpaint_depth_path`, 16-bit PNG scaled by
    /// `depth_unit_scale_factor`, or float32 `.npy`), up to scale and shift.
    pub inpaint_depth_path: Option<PathBuf>,
    /// The frame's files are this many times the camera's size (`--downscale` without
    /// pre-reduced folders): readers reduce them ([`crate::downscale`]). 1 = as is.
    pub pixel_factor: u32,
}

impl Frame {
    /// A frame named after its image's file stem, with no masks, depth or priors.
    pub fn new(image_path: PathBuf, camera: Camera, camera_model: &str, split: Split) -> Self {
        Frame {
            name: file_stem(&image_path),
            image_path,
            camera,
            camera_model: camera_model.to_string(),
            split,
            mask_path: None,
            alpha_is_mask: false,
            instance_mask_path: None,
            mask_encoding: crate::masks::MaskEncoding::Ids,
            depth_path: None,
            depth_scale: 1.0,
            inpaint_path: None,
            inpaint_depth_path: None,
            pixel_factor: 1,
        }
    }
}

/// An object instance declared by the dataset.
#[derive(Debug, Clone, Serialize)]
pub struct InstanceInfo {
    pub id: InstanceId,
    pub label: String,
    /// Oriented box in world coordinates, when the dataset gives one.
    pub bbox: Option<Obb>,
}

/// Axis-aligned region of interest and where it came from.
#[derive(Debug, Clone, Serialize)]
pub struct SceneBounds {
    pub min: DVec3,
    pub max: DVec3,
    pub source: String,
}

/// `p_normalized = (p − center) · scale`; the inverse maps outputs back to dataset units.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Normalization {
    pub center: DVec3,
    pub scale: f64,
}

impl Normalization {
    pub fn to_normalized(&self, p: DVec3) -> DVec3 {
        (p - self.center) * self.scale
    }
    pub fn to_dataset(&self, p: DVec3) -> DVec3 {
        p / self.scale + self.center
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Dataset {
    pub format: Format,
    /// The path the dataset was loaded from.
    pub root: PathBuf,
    pub frames: Vec<Frame>,
    pub instances: Vec<InstanceInfo>,
    /// The world's up (against gravity): as the dataset states it, or, for formats that
    /// state none (LLFF, COLMAP), the cameras' up ([`cameras_up`]).
    pub world_up: Option<DVec3>,
    /// Metres per world unit, when the dataset says (or implies) its scale.
    pub meters_per_unit: Option<f64>,
    /// Sparse 3D points (COLMAP), in world units.
    pub points: Vec<DVec3>,
    /// Near/far depth range (LLFF bounds), when known.
    pub depth_range: Option<(f64, f64)>,
    /// How the train/test split was decided.
    pub split_source: String,
    /// Whether the dataset declares its split (split.json, `*_filenames`, Blender's files)
    /// rather than following a hold-out rule (every 8th frame for test).
    pub split_declared: bool,
    /// Whether the images were rendered rather than photographed: a Blender dataset, or a
    /// `transforms.json` that names its `renderer` (as desk's does, and every dataset
    /// assist writes). Rendered views agree in exposure and white balance, so they need no
    /// per-image appearance codes; photographs (COLMAP, LLFF, `assist process`,
    /// nerfstudio's own captures) do.
    pub rendered: bool,
    pub bounds: SceneBounds,
    pub normalization: Normalization,
    /// Instance masks found in a `masks/` folder beside the images ([`crate::masks`]).
    pub mask_folder: Option<crate::masks::MaskFolder>,
    /// Background priors from `LoadOptions::prior_dir` ([`crate::priors`]).
    pub prior_folder: Option<crate::priors::PriorFolder>,
}

/// Options for loading.
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Force a format instead of detecting it.
    pub format: Option<Format>,
    /// LLFF downscale factor (`images_N`); default: the smallest available.
    pub llff_factor: Option<u32>,
    /// Make every camera this many times smaller (see [`crate::downscale`]); 1 = as the
    /// dataset is (0, the `Default`, means 1 here; the CLI refuses 0).
    pub downscale: u32,
    /// A folder of background priors made elsewhere ([`crate::priors`]).
    pub prior_dir: Option<std::path::PathBuf>,
    /// Instance masks made elsewhere, replacing the dataset's own
    /// ([`crate::masks::attach_given_masks`]).
    pub masks: Option<std::path::PathBuf>,
}

impl Dataset {
    /// The dataset as if nobody had labelled it (`train --no-objects`): no instances, no
    /// instance masks, no masks folder.
    pub fn unlabel(&mut self) {
        self.instances.clear();
        self.mask_folder = None;
        for f in &mut self.frames {
            f.instance_mask_path = None;
        }
    }

    /// A stable digest of what a scene is trained from: the format, and each frame's name,
    /// split and pose (to 1e-5 world units). It does not depend on the image size, so
    /// `--downscale` keeps it; a different capture (or a reordered split) changes it.
    pub fn fingerprint(&self) -> String {
        // FNV-1a, 64 bits: stable across builds and platforms (std's hasher is not).
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                h ^= b as u64;
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        eat(format!("{:?}", self.format).as_bytes());
        for f in &self.frames {
            eat(f.name.as_bytes());
            eat(&[0, f.split as u8]);
            for v in f.camera.pose.to_matrix().to_cols_array() {
                eat(&((v * 1e5).round() as i64).to_le_bytes());
            }
        }
        format!("{h:016x}")
    }

    pub fn frames_in(&self, split: Split) -> impl Iterator<Item = &Frame> {
        self.frames.iter().filter(move |f| f.split == split)
    }
    pub fn count(&self, split: Split) -> usize {
        self.frames_in(split).count()
    }
    pub fn instance(&self, id: InstanceId) -> Option<&InstanceInfo> {
        self.instances.iter().find(|i| i.id == id)
    }
}

/// Up for a capture that states none (LLFF and COLMAP frames are COLMAP's, whose axes are
/// arbitrary, often +Y down, so +Z is no guess at all): perpendicular to the cameras'
/// right axes, since people hold cameras level, on the side of their mean up
/// ([`assist_core::cameras_up`]; the mean up alone leans by the pitch of a capture that
/// looks down from one side). `None` when the cameras are turned every which way.
pub fn cameras_up(frames: &[Frame]) -> Option<DVec3> {
    assist_core::cameras_up(frames.iter().map(|f| {
        let r = f.camera.pose.rotation();
        (r.x_axis, r.y_axis)
    }))
}

/// The file stem of `p` (the name outputs rendered for a frame are given).
pub fn file_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Splits for datasets that do not declare one: every 8th frame (0, 8, 16, …) is held out
/// for testing, the LLFF/Mip-NeRF convention.
pub const HOLDOUT_EVERY: usize = 8;
pub fn holdout_split(i: usize) -> Split {
    if i.is_multiple_of(HOLDOUT_EVERY) {
        Split::Test
    } else {
        Split::Train
    }
}

/// The box spanning the `per_mille`-th to the `(1000 − per_mille)`-th per-mille of
/// `points` on each axis (robust to stray points). `points` must not be empty.
pub fn percentile_aabb(points: &[DVec3], per_mille: usize) -> Aabb {
    let n = points.len();
    let mut lo = DVec3::ZERO;
    let mut hi = DVec3::ZERO;
    for a in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        lo[a] = v[n * per_mille / 1000];
        hi[a] = v[(n * (1000 - per_mille) / 1000).min(n - 1)];
    }
    Aabb::new(lo, hi)
}

/// Bounds from content (points, boxes or a depth range) united with the camera centres,
/// and the normalisation that maps them into [−1, 1]³.
pub fn compute_bounds(
    frames: &[Frame],
    points: &[DVec3],
    instances: &[InstanceInfo],
    depth_range: Option<(f64, f64)>,
) -> (SceneBounds, Normalization) {
    let mut aabb = Aabb::empty();
    let mut sources = Vec::new();
    if !points.is_empty() {
        // Robust: 1st–99th percentile per axis, so stray points do not blow up the box.
        aabb = aabb.union(&percentile_aabb(points, 10));
        sources.push("sparse points (1st-99th percentile)");
    }
    let boxes: Vec<&Obb> = instances.iter().filter_map(|i| i.bbox.as_ref()).collect();
    if !boxes.is_empty() {
        for b in boxes {
            aabb = aabb.union(&b.world_aabb());
        }
        sources.push("instance boxes");
    }
    if let Some((near, far)) = depth_range {
        for f in frames {
            let c = &f.camera;
            for (u, v) in [
                (0.0, 0.0),
                (c.width() as f64, 0.0),
                (0.0, c.height() as f64),
                (c.width() as f64, c.height() as f64),
            ] {
                for z in [near, far] {
                    if let Some(p) = c.unproject(u, v, z) {
                        aabb.extend(p);
                    }
                }
            }
        }
        sources.push("near/far frustums");
    }
    for f in frames {
        aabb.extend(f.camera.pose.center());
    }
    sources.push("camera centres");
    if aabb.is_empty() {
        aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
    }
    let extent = aabb.size().max_element().max(1e-9);
    let bounds = SceneBounds {
        min: aabb.min,
        max: aabb.max,
        source: sources.join(" + "),
    };
    let norm = Normalization {
        center: aabb.center(),
        scale: 2.0 / extent,
    };
    (bounds, norm)
}

/// Parses a row-major world-from-box rotation, checking it is a rotation.
pub fn checked_rotation(m: DMat3, file: &Path, field: &str) -> Result<DMat3> {
    let err = (m.transpose() * m - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    if err > 1e-3 || m.determinant() < 0.0 {
        return Err(DataError::field(
            file,
            field,
            format!(
                "expected a rotation matrix (orthonormal, determinant +1); max |RᵀR − I| = {err:.2e}, det = {:.3}",
                m.determinant()
            ),
        ));
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{DQuat, Intrinsics, Pose};

    fn frame(eye: DVec3, target: DVec3, up: DVec3) -> Frame {
        let camera = Camera {
            intrinsics: Intrinsics::from_fov_x(4, 3, 1.0),
            pose: Pose::look_at(eye, target, up).unwrap(),
        };
        Frame::new(PathBuf::from("x.png"), camera, "PINHOLE", Split::Train)
    }

    /// Upright cameras walking around an object and looking down at it, in a world turned
    /// every which way: their up is the world's up turned the same way.
    #[test]
    fn the_mean_up_of_a_walk_around_is_up_in_any_frame() {
        let turn = DQuat::from_euler(assist_core::glam::EulerRot::XYZ, 1.1, -0.4, 2.3);
        let frames: Vec<Frame> = (0..12)
            .map(|k| {
                let a = k as f64 / 12.0 * std::f64::consts::TAU;
                let eye = DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 1.5);
                frame(turn * eye, DVec3::ZERO, turn * DVec3::Z)
            })
            .collect();
        let up = cameras_up(&frames).unwrap();
        assert!((up - turn * DVec3::Z).length() < 1e-9, "{up}");
        // Cameras rolled a quarter turn each in turn: no mean worth the name.
        let rolled: Vec<Frame> = [DVec3::Z, DVec3::X, -DVec3::Z, -DVec3::X]
            .iter()
            .map(|u| frame(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, *u))
            .collect();
        assert_eq!(cameras_up(&rolled), None);
    }
}
