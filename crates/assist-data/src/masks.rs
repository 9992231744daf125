//! Instance masks from any tool: a `masks/` folder beside the images (`masks_N/` beside
//! `images_N/`), whatever the dataset's format (COLMAP, LLFF, nerfstudio, Blender), with
//! one mask per image named like it (`frame_001.png` or `.jpg` for `frame_001.jpg`, or
//! COLMAP's `frame_001.jpg.png`).
//!
//! What a mask's values mean is decided over the whole folder:
//! - **instance-valued**: grey (8- or 16-bit) or palette PNGs (XMem, DEVA, Cutie and DAVIS
//!   write palette PNGs; the palette index is the object id) with several distinct
//!   non-zero values: each value is an instance id, 0 the background;
//! - **binary**: masks with one non-zero value (0/255 or 0/1), or any JPEG (whose
//!   compression blurs values): one object, id 1, where the value is at least half the
//!   largest (JPEG) or non-zero (PNG).
//!
//! RGB masks whose pixels are grey (R = G = B) read as grey; colour-coded RGB masks are
//! refused with a message saying what to write instead.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use crate::dataset::Dataset;
use crate::error::{DataError, Result};

/// How the values of an instance mask map to instance ids.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase", tag = "kind")]
pub enum MaskEncoding {
    /// Values are instance ids (0 = background).
    #[default]
    Ids,
    /// One object: id 1 where the value is at least `threshold`.
    Binary { threshold: u16 },
}

impl MaskEncoding {
    /// The instance id of a raw mask value.
    #[inline]
    pub fn id(self, v: u16) -> u16 {
        match self {
            MaskEncoding::Ids => v,
            MaskEncoding::Binary { threshold } => u16::from(v >= threshold),
        }
    }
}

/// What was found in a mask folder (for `dataset info` and training's log).
#[derive(Debug, Clone, Serialize)]
pub struct MaskFolder {
    pub folder: PathBuf,
    pub files: usize,
    pub encoding: MaskEncoding,
    /// Instance ids seen (after the encoding).
    pub ids: Vec<u16>,
}

const EXTS: &[&str] = &["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];

/// The mask folder for an image folder: `masks` for `images` (or any other name),
/// `masks_N` for `images_N`.
fn mask_folder_for(image_dir: &Path) -> Option<PathBuf> {
    let name = image_dir.file_name()?.to_string_lossy().into_owned();
    let suffix = name
        .rsplit_once('_')
        .filter(|(_, n)| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
        .map(|(_, n)| format!("_{n}"))
        .unwrap_or_default();
    Some(image_dir.parent()?.join(format!("masks{suffix}")))
}

/// The mask of `image` in `folder`, by the names tools give them.
fn find_mask(folder: &Path, image: &Path) -> Option<PathBuf> {
    let stem = image.file_stem()?.to_string_lossy().into_owned();
    let file = image.file_name()?.to_string_lossy().into_owned();
    EXTS.iter()
        .map(|e| folder.join(format!("{stem}.{e}")))
        .chain(std::iter::once(folder.join(format!("{file}.png"))))
        .find(|p| p.is_file())
}

fn is_jpeg(p: &Path) -> bool {
    p.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("jpg") || e.eq_ignore_ascii_case("jpeg"))
}

/// The mask folder of an image folder: `masks` (or `masks_N` for `images_N`), else —
/// when the images will be made `downscale` times smaller — `masks_<downscale>`.
fn existing_mask_folder(image_dir: &Path, downscale: u32) -> Option<PathBuf> {
    let d = mask_folder_for(image_dir)?;
    if d.is_dir() {
        return Some(d);
    }
    let reduced = image_dir.parent()?.join(format!("masks_{downscale}"));
    (downscale > 1 && reduced.is_dir()).then_some(reduced)
}

/// `masks_N` folders beside the images that [`attach_mask_folder`] did not use (to tell a
/// user which `--downscale` would use them).
pub fn unused_mask_folders(ds: &Dataset) -> Vec<PathBuf> {
    let Some(parent) = ds
        .frames
        .first()
        .and_then(|f| f.image_path.parent())
        .and_then(Path::parent)
    else {
        return Vec::new();
    };
    let used = ds.mask_folder.as_ref().map(|m| m.folder.clone());
    let mut out: Vec<PathBuf> = std::fs::read_dir(parent)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_dir()
                && p.file_name().is_some_and(|n| {
                    let n = n.to_string_lossy();
                    n == "masks"
                        || n.strip_prefix("masks_")
                            .is_some_and(|k| k.parse::<u32>().is_ok())
                })
                && Some(p) != used.as_ref()
        })
        .collect();
    out.sort();
    out
}

/// Attaches the masks of a `masks/` folder to the frames that have no instance mask yet,
/// and decides their encoding (`downscale`: the factor the images will be reduced by, so
/// that `masks_N/` serves full-size images trained N times smaller). `Ok(None)` when there
/// is no such folder. A folder that lacks the mask of some image is an error naming both.
pub fn attach_mask_folder(ds: &mut Dataset, downscale: u32) -> Result<Option<MaskFolder>> {
    let mut folder: Option<PathBuf> = None;
    for f in &ds.frames {
        if f.instance_mask_path.is_some() {
            continue;
        }
        if let Some(d) = f
            .image_path
            .parent()
            .and_then(|d| existing_mask_folder(d, downscale))
        {
            folder = Some(d);
            break;
        }
    }
    let Some(folder) = folder else {
        return Ok(None);
    };
    let frames: Vec<usize> = (0..ds.frames.len())
        .filter(|&k| {
            let f = &ds.frames[k];
            f.instance_mask_path.is_none()
                && f.image_path
                    .parent()
                    .and_then(|d| existing_mask_folder(d, downscale))
                    .as_deref()
                    == Some(folder.as_path())
        })
        .collect();
    attach(ds, folder, &frames, false).map(Some)
}

/// Replaces every frame's instance mask with the one in `folder` (masks made elsewhere,
/// e.g. by `assist dataset masks`); the dataset's own instances are dropped, and those of
/// `folder/instances.json` (ids, labels, boxes, as `assist dataset boxes --json` writes
/// them) declared when it exists.
pub fn attach_given_masks(ds: &mut Dataset, folder: &Path) -> Result<MaskFolder> {
    if !folder.is_dir() {
        return Err(DataError::field(
            folder,
            "masks",
            "expected a folder of instance masks, one per image named like it",
        ));
    }
    for f in &mut ds.frames {
        f.instance_mask_path = None;
    }
    ds.instances.clear();
    let listed = folder.join(INSTANCES_FILE);
    if listed.is_file() {
        for b in crate::boxes::read_boxes(&listed)? {
            let id = b.id.ok_or_else(|| {
                DataError::field(&listed, &b.entry, "expected an \"id\" for each instance")
            })?;
            ds.instances.push(crate::dataset::InstanceInfo {
                id,
                label: b.label.clone().unwrap_or_else(|| format!("object {id}")),
                bbox: Some(b.bbox),
            });
        }
    }
    let frames: Vec<usize> = (0..ds.frames.len()).collect();
    let declared = !ds.instances.is_empty();
    attach(ds, folder.to_path_buf(), &frames, declared)
}

/// The file in a masks folder that names its instances.
pub const INSTANCES_FILE: &str = "instances.json";

/// Sets the instance masks of `frames` from `folder` (each must have one) and decides
/// their encoding from the values all of them use (`ids`: the values are ids, as a
/// folder that declares its instances says, even with one object).
fn attach(ds: &mut Dataset, folder: PathBuf, frames: &[usize], ids: bool) -> Result<MaskFolder> {
    let mut paths = Vec::new();
    for &k in frames {
        let f = &mut ds.frames[k];
        let Some(m) = find_mask(&folder, &f.image_path) else {
            let stem = crate::dataset::file_stem(&f.image_path);
            return Err(DataError::field(
                &folder,
                "masks",
                format!(
                    "no mask for image {} (expected {stem}.png, {stem}.jpg or {}.png in this folder; every image needs one, all zero where no object is visible)",
                    f.image_path.display(),
                    f.image_path
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                ),
            ));
        };
        f.instance_mask_path = Some(m.clone());
        paths.push(m);
    }
    // Decide the encoding from the values all masks use.
    let seen: Vec<Vec<bool>> = paths
        .par_iter()
        .map(|p| -> Result<Vec<bool>> {
            let m = crate::image_io::read_mask_values(p)?;
            let mut s = vec![false; 65536];
            for &v in &m.data {
                s[v as usize] = true;
            }
            Ok(s)
        })
        .collect::<Result<_>>()?;
    let mut any = vec![false; 65536];
    for s in &seen {
        for (a, &b) in any.iter_mut().zip(s) {
            *a |= b;
        }
    }
    let values: Vec<u16> = (1..65536usize)
        .filter(|&v| any[v])
        .map(|v| v as u16)
        .collect();
    let encoding = if ids {
        MaskEncoding::Ids
    } else if paths.iter().any(|p| is_jpeg(p)) {
        MaskEncoding::Binary {
            threshold: values.last().map_or(128, |&m| m.div_ceil(2).max(1)),
        }
    } else if values.len() == 1 {
        MaskEncoding::Binary {
            threshold: values[0],
        }
    } else {
        MaskEncoding::Ids
    };
    for f in ds.frames.iter_mut() {
        if f.instance_mask_path
            .as_ref()
            .is_some_and(|p| p.parent() == Some(folder.as_path()))
        {
            f.mask_encoding = encoding;
        }
    }
    let mut ids: Vec<u16> = values.iter().map(|&v| encoding.id(v)).collect();
    ids.retain(|&i| i != 0);
    ids.dedup();
    Ok(MaskFolder {
        folder,
        files: paths.len(),
        encoding,
        ids,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_folders_follow_image_folders() {
        let m = |s: &str| mask_folder_for(Path::new(s)).unwrap();
        assert_eq!(m("/d/images"), PathBuf::from("/d/masks"));
        assert_eq!(m("/d/images_4"), PathBuf::from("/d/masks_4"));
        assert_eq!(m("/d/rgb"), PathBuf::from("/d/masks"));
        assert_eq!(m("/d/my_images"), PathBuf::from("/d/masks"));
    }

    #[test]
    fn palette_masks_read_as_indices() {
        // A 4-bit palette PNG whose palette colours are not the indices.
        let dir = std::env::temp_dir().join(format!("assist-palette-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.png");
        let (w, h) = (5u32, 3u32);
        let idx: Vec<u8> = (0..w * h).map(|i| (i % 4) as u8).collect();
        let mut packed = Vec::new();
        for row in idx.chunks(w as usize) {
            let mut line = vec![0u8; (w as usize).div_ceil(2)];
            for (x, &v) in row.iter().enumerate() {
                line[x / 2] |= v << (4 * (1 - x % 2));
            }
            packed.extend(line);
        }
        {
            let file = std::fs::File::create(&path).unwrap();
            let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
            enc.set_color(png::ColorType::Indexed);
            enc.set_depth(png::BitDepth::Four);
            enc.set_palette(vec![0, 0, 0, 128, 0, 0, 0, 128, 0, 128, 128, 0]);
            let mut wr = enc.write_header().unwrap();
            wr.write_image_data(&packed).unwrap();
        }
        let m = crate::image_io::read_mask_values(&path).unwrap();
        assert_eq!((m.width, m.height), (w, h));
        assert_eq!(m.data, idx.iter().map(|&v| v as u16).collect::<Vec<_>>());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn encodings_map_values_to_ids() {
        assert_eq!(MaskEncoding::Ids.id(7), 7);
        let b = MaskEncoding::Binary { threshold: 128 };
        assert_eq!((b.id(0), b.id(127), b.id(128), b.id(255)), (0, 0, 1, 1));
    }
}
