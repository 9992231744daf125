//! COLMAP sparse models, binary (`cameras.bin`, `images.bin`, `points3D.bin`) and text
//! (`*.txt`), with the camera models COLMAP writes for such data: SIMPLE_PINHOLE, PINHOLE,
//! SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE (and FULL_OPENCV when its rational terms
//! are zero). Images are found beside the model (`images/` next to `sparse/`).

use std::path::{Path, PathBuf};

use assist_core::{Camera, DVec3, Distortion, Intrinsics, Pose};

use crate::colmap_model::MODELS;
use crate::dataset::{Dataset, Format, Frame, compute_bounds, holdout_split};
use crate::error::{DataError, Result};

pub use crate::colmap_model::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};

const SUPPORTED: &str = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE, FULL_OPENCV (k4..k6 = 0)";

/// Converts a COLMAP camera into intrinsics.
pub fn intrinsics(cam: &ColmapCamera, file: &Path) -> Result<Intrinsics> {
    let p = &cam.params;
    let field = format!("camera {}", cam.id);
    let bad = |m: String| DataError::field(file, format!("{field}.params"), m);
    let want = MODELS.iter().find(|m| m.1 == cam.model).map(|m| m.2);
    if let Some(n) = want
        && p.len() != n
    {
        return Err(bad(format!(
            "{} takes {n} parameters, got {}",
            cam.model,
            p.len()
        )));
    }
    let none = Distortion::None;
    let (fx, fy, cx, cy, distortion) = match cam.model.as_str() {
        "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], none),
        "PINHOLE" => (p[0], p[1], p[2], p[3], none),
        "SIMPLE_RADIAL" => (
            p[0],
            p[0],
            p[1],
            p[2],
            Distortion::OpenCv {
                k1: p[3],
                k2: 0.0,
                k3: 0.0,
                p1: 0.0,
                p2: 0.0,
            },
        ),
        "RADIAL" => (
            p[0],
            p[0],
            p[1],
            p[2],
            Distortion::OpenCv {
                k1: p[3],
                k2: p[4],
                k3: 0.0,
                p1: 0.0,
                p2: 0.0,
            },
        ),
        "OPENCV" => (
            p[0],
            p[1],
            p[2],
            p[3],
            Distortion::OpenCv {
                k1: p[4],
                k2: p[5],
                k3: 0.0,
                p1: p[6],
                p2: p[7],
            },
        ),
        "OPENCV_FISHEYE" => (
            p[0],
            p[1],
            p[2],
            p[3],
            Distortion::Fisheye {
                k1: p[4],
                k2: p[5],
                k3: p[6],
                k4: p[7],
            },
        ),
        "FULL_OPENCV" => {
            if p[9] != 0.0 || p[10] != 0.0 || p[11] != 0.0 {
                return Err(bad("FULL_OPENCV with rational terms k4..k6 ≠ 0 is not supported; expected k4 = k5 = k6 = 0".into()));
            }
            (
                p[0],
                p[1],
                p[2],
                p[3],
                Distortion::OpenCv {
                    k1: p[4],
                    k2: p[5],
                    k3: p[8],
                    p1: p[6],
                    p2: p[7],
                },
            )
        }
        other => {
            return Err(DataError::field(
                file,
                format!("{field}.model"),
                format!("camera model {other} is not supported; expected one of {SUPPORTED}"),
            ));
        }
    };
    let distortion = if distortion.is_none() {
        Distortion::None
    } else {
        distortion
    };
    let intr = Intrinsics {
        width: cam.width,
        height: cam.height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    };
    intr.validate(&field)
        .map_err(|e| DataError::core(file, e))?;
    Ok(intr)
}

/// Reads the model in `dir`, binary or text.
pub fn read_model(dir: &Path, binary: bool) -> Result<ColmapModel> {
    if binary {
        crate::colmap_bin::read(dir)
    } else {
        crate::colmap_text::read(dir)
    }
}

/// Where the images of a model in `model_dir` are: `images/` in the model's folder, its
/// parent (`sparse/`) or grandparent (`scene/` of `scene/sparse/0`).
pub fn find_image_dir(model_dir: &Path) -> Option<PathBuf> {
    let mut d = Some(model_dir);
    for _ in 0..3 {
        let dir = d?;
        let cand = dir.join("images");
        if cand.is_dir() {
            return Some(cand);
        }
        d = dir.parent();
    }
    None
}

pub fn load_dataset(model_dir: &Path, format: Format) -> Result<Dataset> {
    let binary = format == Format::ColmapBinary;
    let model = read_model(model_dir, binary)?;
    let ext = if binary { "bin" } else { "txt" };
    let cam_file = model_dir.join(format!("cameras.{ext}"));
    let img_file = model_dir.join(format!("images.{ext}"));
    let image_dir = find_image_dir(model_dir).ok_or_else(|| DataError::NotADataset {
        path: model_dir.into(),
        message: "COLMAP model found, but no images/ folder beside it (looked in the model folder and its two parents)".into(),
    })?;
    let mut images = model.images.clone();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut frames = Vec::with_capacity(images.len());
    for (i, im) in images.iter().enumerate() {
        let cam = model.cameras.get(&im.camera_id).ok_or_else(|| {
            DataError::field(
                &img_file,
                format!("image {} ({}).camera_id", im.id, im.name),
                format!("camera {} is not in {}", im.camera_id, cam_file.display()),
            )
        })?;
        let intrinsics = intrinsics(cam, &cam_file)?;
        let pose = Pose::from_colmap(im.qvec, im.tvec, &format!("image {} ({})", im.id, im.name))
            .map_err(|e| DataError::core(&img_file, e))?;
        let image_path = image_dir.join(&im.name);
        frames.push(Frame {
            // The frame is named after the image as COLMAP names it (the resolved file may
            // differ, e.g. a downscaled folder).
            name: crate::dataset::file_stem(Path::new(&im.name)),
            ..Frame::new(
                image_path,
                Camera { intrinsics, pose },
                &cam.model,
                holdout_split(i),
            )
        });
    }
    let mut points: Vec<DVec3> = model.points.values().map(|p| p.xyz).collect();
    points.sort_by(|a, b| {
        a.x.total_cmp(&b.x)
            .then(a.y.total_cmp(&b.y))
            .then(a.z.total_cmp(&b.z))
    });
    let (bounds, normalization) = compute_bounds(&frames, &points, &[], None);
    let world_up = crate::dataset::cameras_up(&frames);
    Ok(Dataset {
        format,
        root: model_dir.to_path_buf(),
        frames,
        instances: vec![],
        world_up,
        meters_per_unit: None,
        points,
        depth_range: None,
        split_declared: false,
        rendered: false,
        split_source: "every 8th image (sorted by name) held out for test".into(),
        bounds,
        normalization,
        mask_folder: None,
        prior_folder: None,
    })
}
