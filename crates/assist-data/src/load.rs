//! Format detection and loading: picks the reader for a path, then attaches a masks
//! folder and applies `--downscale`.

use std::path::{Path, PathBuf};

use crate::dataset::{Dataset, Format, LoadOptions};
use crate::error::{DataError, Result};

/// Detects the format at `path`: a `transforms.json` (nerfstudio), `transforms_train.json`
/// (Blender), a COLMAP model with `images.bin`/`images.txt` (in `sparse/0`, `sparse` or the
/// folder itself), or `poses_bounds.npy` (LLFF). A file path selects by its name.
pub fn detect_format(path: &Path) -> Result<(Format, PathBuf)> {
    if !path.exists() {
        return Err(DataError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or directory"),
        ));
    }
    if path.is_file() {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        return match name.as_str() {
            n if n.starts_with("transforms_") && n.ends_with(".json") => Ok((Format::Blender, dir)),
            n if n.ends_with(".json") => Ok((Format::Nerfstudio, path.to_path_buf())),
            "poses_bounds.npy" => Ok((Format::Llff, dir)),
            "images.bin" | "cameras.bin" | "points3D.bin" => Ok((Format::ColmapBinary, dir)),
            "images.txt" | "cameras.txt" | "points3D.txt" => Ok((Format::ColmapText, dir)),
            _ => Err(DataError::NotADataset {
                path: path.into(),
                message: "not a dataset file: expected transforms.json, transforms_train.json, poses_bounds.npy or a COLMAP model file".into(),
            }),
        };
    }
    if path.join("transforms.json").is_file() {
        return Ok((Format::Nerfstudio, path.join("transforms.json")));
    }
    if path.join("transforms_train.json").is_file() || path.join("transforms_test.json").is_file() {
        return Ok((Format::Blender, path.to_path_buf()));
    }
    for model in [
        path.join("sparse/0"),
        path.join("sparse"),
        path.to_path_buf(),
    ] {
        if model.join("images.bin").is_file() {
            return Ok((Format::ColmapBinary, model));
        }
        if model.join("images.txt").is_file() {
            return Ok((Format::ColmapText, model));
        }
    }
    if path.join("poses_bounds.npy").is_file() {
        return Ok((Format::Llff, path.to_path_buf()));
    }
    Err(DataError::NotADataset {
        path: path.into(),
        message: "no dataset found here: expected transforms.json (nerfstudio), transforms_train.json (Blender), \
                  a COLMAP model (sparse/0/images.bin or images.txt) or poses_bounds.npy (LLFF)"
            .into(),
    })
}

/// Loads the dataset at `path` (a folder or a dataset file).
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let (detected, target) = detect_format(path)?;
    let format = opts.format.unwrap_or(detected);
    let target = if format == detected {
        target
    } else {
        path.to_path_buf()
    };
    let mut ds = match format {
        Format::Nerfstudio => crate::nerfstudio::load(&target)?,
        Format::Blender => crate::blender::load(&target)?,
        Format::ColmapBinary | Format::ColmapText => crate::colmap::load_dataset(&target, format)?,
        Format::Llff => crate::llff::load(&target, opts.llff_factor)?,
    };
    ds.root = path.to_path_buf();
    if ds.frames.is_empty() {
        return Err(DataError::NotADataset {
            path: path.into(),
            message: "the dataset has no frames".into(),
        });
    }
    // Every reader's cameras meet the same limits (a Blender `camera_angle_x` ≥ π gives a
    // focal length of zero or less; a declared size must not overflow a buffer).
    for f in &ds.frames {
        let i = &f.camera.intrinsics;
        i.validate(&format!("frame {:?}", f.name))
            .map_err(|e| DataError::core(&f.image_path, e))?;
        let m = f.camera.pose.world_from_camera;
        let finite = m
            .matrix3
            .to_cols_array()
            .iter()
            .chain(&m.translation.to_array())
            .all(|v| v.is_finite());
        if !finite {
            return Err(DataError::field(
                &f.image_path,
                format!("frame {:?}.transform_matrix", f.name),
                "expected finite numbers",
            ));
        }
    }
    ds.mask_folder = match &opts.masks {
        Some(dir) => Some(crate::masks::attach_given_masks(&mut ds, dir)?),
        None => crate::masks::attach_mask_folder(&mut ds, opts.downscale.max(1))?,
    };
    if let Some(dir) = &opts.prior_dir {
        ds.prior_folder = Some(crate::priors::attach_prior_folder(&mut ds, dir)?);
    }
    crate::downscale::apply(&mut ds, opts.downscale.max(1))?;
    Ok(ds)
}
