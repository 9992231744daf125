//! Training and evaluating at a lower resolution (`--downscale N`), as nerfstudio's
//! dataparsers do: each frame's camera becomes N times smaller (`width / N` pixels,
//! rounded down, intrinsics divided by N, so a small pixel covers exactly N × N large
//! ones). Its files are taken from an `<folder>_N/` beside their folder when one holds the
//! same file name at that size (COLMAP's and nerfstudio's `images_2/`, `images_4/` …, and
//! `masks_N/`), else read at full size and reduced in memory: colour by the mean of each
//! N × N block, masks and depth by the block's centre pixel (no mixed ids or depths).

use std::path::{Path, PathBuf};

use crate::dataset::{Dataset, Frame};
use crate::error::{DataError, Result};
use crate::image_io::image_dimensions;

/// Largest accepted factor.
pub const MAX_DOWNSCALE: u32 = 64;

/// Applies `factor` to every frame of `ds` (1 leaves it as it is).
pub fn apply(ds: &mut Dataset, factor: u32) -> Result<()> {
    if factor == 1 {
        return Ok(());
    }
    if factor == 0 || factor > MAX_DOWNSCALE {
        return Err(DataError::field(
            &ds.root,
            "downscale",
            format!("expected a factor from 1 to {MAX_DOWNSCALE}, got {factor}"),
        ));
    }
    for f in &mut ds.frames {
        downscale_frame(f, factor)?;
    }
    Ok(())
}

/// `dir/name` → `dir_N/name`, when that file exists.
fn sibling(path: &Path, factor: u32) -> Option<PathBuf> {
    let dir = path.parent()?;
    let folder = dir.file_name()?.to_string_lossy();
    let p = dir
        .parent()?
        .join(format!("{folder}_{factor}"))
        .join(path.file_name()?);
    p.is_file().then_some(p)
}

fn downscale_frame(f: &mut Frame, factor: u32) -> Result<()> {
    let intr = f.camera.intrinsics;
    let (w, h) = (intr.width / factor, intr.height / factor);
    if w == 0 || h == 0 {
        return Err(DataError::field(
            &f.image_path,
            "downscale",
            format!(
                "a {}×{} image cannot be made {factor} times smaller",
                intr.width, intr.height
            ),
        ));
    }
    f.camera.intrinsics = intr.downscaled(factor as f64, w, h);
    // Pre-reduced files are used only when every file of the frame has one at the right
    // size; otherwise all are reduced in memory (one factor per frame).
    let mut paths: Vec<&mut PathBuf> = vec![&mut f.image_path];
    paths.extend(f.mask_path.as_mut());
    paths.extend(f.instance_mask_path.as_mut());
    paths.extend(f.depth_path.as_mut());
    paths.extend(f.inpaint_path.as_mut());
    paths.extend(f.inpaint_depth_path.as_mut());
    // `.npy` depth has no image header; it is checked when read.
    let fits = |s: &Path| {
        s.extension().is_some_and(|e| e == "npy") || image_dimensions(s).is_ok_and(|d| d == (w, h))
    };
    let found: Vec<Option<PathBuf>> = paths
        .iter()
        .map(|p| {
            sibling(p, factor)
                .filter(|s| fits(s))
                // Already reduced (a `masks_N/` given to full-size images).
                .or_else(|| {
                    (p.parent()
                        .is_some_and(|d| d.ends_with(format!("masks_{factor}")))
                        && fits(p))
                    .then(|| p.to_path_buf())
                })
        })
        .collect();
    if found.iter().all(Option::is_some) {
        for (p, s) in paths.into_iter().zip(found) {
            *p = s.expect("checked");
        }
        return Ok(());
    }
    // Mixed sizes cannot be read with one factor: a reduced mask needs reduced images.
    if let Some(p) = paths
        .iter()
        .zip(&found)
        .find_map(|(p, s)| (s.as_deref() == Some(p.as_path())).then(|| p.to_path_buf()))
    {
        let missing = paths
            .iter()
            .zip(&found)
            .find(|(_, s)| s.is_none())
            .map(|(q, _)| q.display().to_string())
            .unwrap_or_default();
        return Err(DataError::field(
            &p,
            "downscale",
            format!(
                "this mask is already {factor} times smaller, but {missing} has no {w}×{h} copy in a _{factor} folder beside it; put the reduced images there too"
            ),
        ));
    }
    f.pixel_factor = factor;
    Ok(())
}

/// Mean of each `factor × factor` block of a `w × h` image with `channels` interleaved
/// values (the last partial row and column of blocks are dropped).
pub fn reduce_mean(data: &[f32], w: usize, h: usize, channels: usize, factor: usize) -> Vec<f32> {
    let (ow, oh) = (w / factor, h / factor);
    let mut out = vec![0.0f32; ow * oh * channels];
    let inv = 1.0 / (factor * factor) as f32;
    for j in 0..oh {
        for i in 0..ow {
            let o = (j * ow + i) * channels;
            for y in j * factor..(j + 1) * factor {
                for x in i * factor..(i + 1) * factor {
                    let s = (y * w + x) * channels;
                    for c in 0..channels {
                        out[o + c] += data[s + c];
                    }
                }
            }
            for c in 0..channels {
                out[o + c] *= inv;
            }
        }
    }
    out
}

/// The centre pixel of each `factor × factor` block (for ids and depth, which must not be
/// mixed).
pub fn reduce_pick<T: Copy>(data: &[T], w: usize, h: usize, factor: usize) -> Vec<T> {
    let (ow, oh) = (w / factor, h / factor);
    let c = factor / 2;
    let mut out = Vec::with_capacity(ow * oh);
    for j in 0..oh {
        for i in 0..ow {
            out.push(data[(j * factor + c) * w + i * factor + c]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_averaged_and_picked() {
        // 5×4 image, factor 2 → 2×2 (the last column is dropped).
        let data: Vec<f32> = (0..20).map(|v| v as f32).collect();
        let m = reduce_mean(&data, 5, 4, 1, 2);
        assert_eq!(m, vec![3.0, 5.0, 13.0, 15.0]);
        let p = reduce_pick(&data, 5, 4, 2);
        assert_eq!(p, vec![6.0, 8.0, 16.0, 18.0]);
        // Interleaved channels stay apart.
        let rgb: Vec<f32> = (0..16).flat_map(|v| [v as f32, 1.0, -1.0]).collect();
        let m = reduce_mean(&rgb, 4, 4, 3, 4);
        assert_eq!(m, vec![7.5, 1.0, -1.0]);
    }
}
