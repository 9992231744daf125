//! Background priors made elsewhere (`--prior-dir DIR`, the paper's path): per frame, an
//! image of the view with its objects inpainted by any external model, and optionally
//! that model's depth of the emptied view.
//!
//! Layout: `DIR/<image stem>.png` (or `.jpg`, `.jpeg`, or `<image file name>.png`) at
//! the size of the dataset's images, and `DIR/depth/<image stem>.npy` (float32, height ×
//! width, any scale: it is fitted up to scale and shift) or `.png` (16-bit, scaled by the
//! dataset's depth unit). With `--downscale N`, a `DIR_N/` beside `DIR` holding the same
//! names at the reduced size is used when it exists, as for `images_N/`. The prior
//! replaces a frame's `inpaint_path` / `inpaint_depth_path` from `transforms.json`.
//!
//! Training frames without a prior image keep the built-in fill; a folder that matches no
//! training frame, or a depth without its image, is an error naming the folder.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::dataset::{Dataset, Split};
use crate::error::{DataError, Result};

const IMAGE_EXTS: &[&str] = &["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];
const DEPTH_EXTS: &[&str] = &["npy", "png", "PNG"];

/// What a prior folder supplied.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PriorFolder {
    pub folder: PathBuf,
    /// Training frames with a prior image.
    pub images: usize,
    /// Of those, frames with a prior depth.
    pub depths: usize,
    /// Training frames in the dataset.
    pub train_frames: usize,
    /// Names of training frames without a prior image (they keep the built-in fill).
    pub missing: Vec<String>,
}

fn find(folder: &Path, image: &Path, exts: &[&str], whole_name: bool) -> Option<PathBuf> {
    let stem = image.file_stem()?.to_string_lossy().into_owned();
    let file = image.file_name()?.to_string_lossy().into_owned();
    exts.iter()
        .map(|e| folder.join(format!("{stem}.{e}")))
        .chain(whole_name.then(|| folder.join(format!("{file}.png"))))
        .find(|p| p.is_file())
}

/// Attaches the priors in `folder` to the frames of `ds` (every split: a held-out frame's
/// prior is not used in training, but keeps its paths for inspection).
pub fn attach_prior_folder(ds: &mut Dataset, folder: &Path) -> Result<PriorFolder> {
    if !folder.is_dir() {
        return Err(DataError::field(
            folder,
            "prior-dir",
            "not a folder: expected a folder of inpainted images named after the dataset's images",
        ));
    }
    let depth_dir = folder.join("depth");
    let mut out = PriorFolder {
        folder: folder.to_path_buf(),
        images: 0,
        depths: 0,
        train_frames: 0,
        missing: Vec::new(),
    };
    for f in ds.frames.iter_mut() {
        let train = f.split == Split::Train;
        out.train_frames += usize::from(train);
        let image = find(folder, &f.image_path, IMAGE_EXTS, true);
        let depth = find(&depth_dir, &f.image_path, DEPTH_EXTS, false);
        match (image, depth) {
            (Some(i), d) => {
                out.images += usize::from(train);
                out.depths += usize::from(train && d.is_some());
                f.inpaint_path = Some(i);
                if d.is_some() {
                    f.inpaint_depth_path = d;
                }
            }
            (None, Some(d)) => {
                return Err(DataError::field(
                    &d,
                    "prior-dir",
                    format!(
                        "a prior depth without its image: expected {} too",
                        folder.join(format!("{}.png", f.name)).display()
                    ),
                ));
            }
            (None, None) => {
                if train {
                    out.missing.push(f.name.clone());
                }
            }
        }
    }
    if out.images == 0 {
        let example = ds
            .frames
            .iter()
            .find(|f| f.split == Split::Train)
            .map(|f| format!("{}.png", f.name))
            .unwrap_or_default();
        return Err(DataError::field(
            folder,
            "prior-dir",
            format!(
                "no inpainted image here matches a training image (expected names such as {example}, one per training image)"
            ),
        ));
    }
    Ok(out)
}
