//! LLFF: `poses_bounds.npy` (N × 17: a 3 × 5 matrix `[R | t | hwf]` per image with the
//! rotation's columns as (down, right, backwards), then near and far bounds) and images
//! in `images/` or `images_N/` (downscaled N times; the factor is read from the folder name
//! and checked against the image size).

use std::path::{Path, PathBuf};

use assist_core::{Camera, DMat3, DVec3, Intrinsics, Pose};

use crate::dataset::{Dataset, Format, Frame, compute_bounds, holdout_split};
use crate::error::{DataError, Result};
use crate::image_io::image_dimensions;
use crate::npy::read_npy;

const IMAGE_EXTS: &[&str] = &["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];

/// Image folders `images` (factor 1) and `images_N`, sorted by factor.
fn image_folders(dir: &Path) -> Vec<(u32, PathBuf)> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if !e.path().is_dir() {
                continue;
            }
            if name == "images" {
                out.push((1, e.path()));
            } else if let Some(n) = name
                .strip_prefix("images_")
                .and_then(|s| s.parse::<u32>().ok())
                && n > 0
            {
                out.push((n, e.path()));
            }
        }
    }
    out.sort();
    out
}

pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| DataError::io(dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension()
                .map(|e| IMAGE_EXTS.contains(&e.to_string_lossy().as_ref()))
                .unwrap_or(false)
        })
        .collect();
    v.sort();
    Ok(v)
}

pub fn load(dir: &Path, factor: Option<u32>) -> Result<Dataset> {
    let npy = dir.join("poses_bounds.npy");
    let arr = read_npy(&npy)?;
    if arr.shape.len() != 2 || arr.shape[1] != 17 {
        return Err(DataError::field(
            &npy,
            "shape",
            format!("expected (N, 17), got {:?}", arr.shape),
        ));
    }
    let n = arr.shape[0];
    let folders = image_folders(dir);
    let (factor, img_dir) = match factor {
        Some(f) => folders
            .iter()
            .find(|(k, _)| *k == f)
            .cloned()
            .ok_or_else(|| DataError::NotADataset {
                path: dir.into(),
                message: format!(
                    "no image folder for factor {f} (expected {})",
                    if f == 1 {
                        "images/".into()
                    } else {
                        format!("images_{f}/")
                    }
                ),
            })?,
        None => folders
            .first()
            .cloned()
            .ok_or_else(|| DataError::NotADataset {
                path: dir.into(),
                message: "poses_bounds.npy found but no images/ or images_N/ folder".into(),
            })?,
    };
    let images = list_images(&img_dir)?;
    if images.len() != n {
        return Err(DataError::field(
            &npy,
            "shape[0]",
            format!(
                "{n} poses, but {} has {} images; expected one image per pose",
                img_dir.display(),
                images.len()
            ),
        ));
    }
    let mut frames = Vec::with_capacity(n);
    let mut near = f64::INFINITY;
    let mut far = 0.0f64;
    for (i, img) in images.iter().enumerate() {
        let row = &arr.data[i * 17..(i + 1) * 17];
        let field = format!("row {i}");
        assist_core::error::check_finite(&field, row).map_err(|e| DataError::core(&npy, e))?;
        // Row-major 3×5: m[r][c] = row[r*5 + c].
        let col = |c: usize| DVec3::new(row[c], row[5 + c], row[10 + c]);
        let (h, w, f) = (row[4], row[9], row[14]);
        // (down, right, back) → OpenGL (right, up, back).
        let r = DMat3::from_cols(col(1), -col(0), col(2));
        let pose = Pose::from_rotation_translation(r, col(3), &format!("{field} pose"))
            .map_err(|e| DataError::core(&npy, e))?;
        let (iw, ih) = image_dimensions(img)?;
        let (ew, eh) = (
            (w / factor as f64).round() as u32,
            (h / factor as f64).round() as u32,
        );
        if (iw, ih) != (ew, eh) {
            return Err(DataError::ImageSize {
                path: img.clone(),
                field: format!("{} row {i} hwf {h}x{w} / factor {factor}", npy.display()),
                got_w: iw,
                got_h: ih,
                want_w: ew,
                want_h: eh,
            });
        }
        if f <= 0.0 {
            return Err(DataError::field(
                &npy,
                format!("{field} focal"),
                format!("expected a positive focal length, got {f}"),
            ));
        }
        let s = iw as f64 / w;
        let intr = Intrinsics {
            width: iw,
            height: ih,
            fx: f * s,
            fy: f * s,
            cx: iw as f64 / 2.0,
            cy: ih as f64 / 2.0,
            distortion: assist_core::Distortion::None,
        };
        near = near.min(row[15]);
        far = far.max(row[16]);
        let camera = Camera {
            intrinsics: intr,
            pose,
        };
        frames.push(Frame::new(img.clone(), camera, "PINHOLE", holdout_split(i)));
    }
    let depth_range = (near.is_finite() && far > 0.0).then_some((near, far));
    let (bounds, normalization) = compute_bounds(&frames, &[], &[], depth_range);
    let world_up = crate::dataset::cameras_up(&frames);
    Ok(Dataset {
        format: Format::Llff,
        root: dir.to_path_buf(),
        frames,
        instances: vec![],
        world_up,
        meters_per_unit: None,
        points: vec![],
        depth_range,
        split_declared: false,
        rendered: false,
        split_source: format!(
            "every 8th image held out for test (images from {})",
            img_dir.file_name().unwrap_or_default().to_string_lossy()
        ),
        bounds,
        normalization,
        mask_folder: None,
        prior_folder: None,
    })
}
