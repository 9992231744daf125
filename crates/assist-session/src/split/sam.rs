//! Masks sharpened by Segment Anything, with weights the user supplies (`--sam FILE`):
//! in each photograph, every object the geometry found is prompted with its mask's box
//! and its innermost pixel; of SAM's three masks the one that best agrees with the
//! geometric mask replaces it, and only where they agree on the whole (IoU ≥
//! [`SAM_AGREE`]): SAM sees the photograph's edges, the geometry knows which object is
//! meant. Without weights the geometric masks stand alone.

use std::path::{Path, PathBuf};

use assist_data::image_io::ImageF32;
use assist_sam::{Prompt, Sam};

use super::SplitBox;
use crate::{Result, request};

/// A SAM mask replaces the geometric one where their IoU is at least this.
pub const SAM_AGREE: f64 = 0.7;

/// Objects smaller than this many pixels in a view keep their geometric mask.
const MIN_PIXELS: usize = 16;

/// A loaded SAM and what it did.
pub struct SamRefine {
    sam: Sam,
    pub path: PathBuf,
}

/// Per view: objects prompted, and those whose mask SAM replaced.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct SamCount {
    pub prompted: u64,
    pub replaced: u64,
}

impl SamRefine {
    pub fn load(path: &Path) -> Result<Self> {
        let sam = Sam::load(path).map_err(|e| request("sam", e.to_string()))?;
        Ok(SamRefine {
            sam,
            path: path.to_path_buf(),
        })
    }

    /// Refines `ids` (instance ids per pixel of `photo`) for `boxes` in place.
    pub fn refine(
        &self,
        photo: &ImageF32,
        ids: &mut [u16],
        boxes: &[SplitBox],
    ) -> Result<SamCount> {
        let (w, h) = (photo.width as usize, photo.height as usize);
        let mut count = SamCount::default();
        let present: Vec<&SplitBox> = boxes
            .iter()
            .filter(|b| ids.iter().filter(|&&v| v == b.id).count() >= MIN_PIXELS)
            .collect();
        if present.is_empty() {
            return Ok(count);
        }
        let rgb: Vec<f32> = if photo.channels == 3 {
            photo.data.clone()
        } else {
            (0..w * h)
                .flat_map(|i| {
                    let c = photo.channels as usize;
                    [0, 1, 2].map(|k| photo.data[i * c + k.min(c - 1)])
                })
                .collect()
        };
        let emb = self
            .sam
            .embed(&rgb, w, h)
            .map_err(|e| request("sam", e.to_string()))?;
        for b in present {
            let geo: Vec<bool> = ids.iter().map(|&v| v == b.id).collect();
            let prompt = prompt_for(&geo, w, h);
            count.prompted += 1;
            let mut best_iou = 0.0;
            let mask = self
                .sam
                .segment(&emb, &prompt, |m, _| {
                    let v = iou(m, &geo);
                    best_iou = f64::max(best_iou, v);
                    v
                })
                .map_err(|e| request("sam", e.to_string()))?;
            if best_iou < SAM_AGREE {
                continue;
            }
            count.replaced += 1;
            for (v, (&g, &s)) in ids.iter_mut().zip(geo.iter().zip(&mask)) {
                if g && !s {
                    *v = 0;
                } else if s && *v == 0 {
                    *v = b.id;
                }
            }
        }
        Ok(count)
    }
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let (mut i, mut u) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        i += usize::from(x && y);
        u += usize::from(x || y);
    }
    if u == 0 { 0.0 } else { i as f64 / u as f64 }
}

/// A mask's box (grown by a twentieth of its size on each side) and its innermost pixel
/// (farthest from the outside, chamfer distance) as a positive point.
pub fn prompt_for(mask: &[bool], w: usize, h: usize) -> Prompt {
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (i % w, i / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    let mx = (x1.saturating_sub(x0) + 1) as f32 / 20.0;
    let my = (y1.saturating_sub(y0) + 1) as f32 / 20.0;
    let bbox = [
        (x0 as f32 - mx).max(0.0),
        (y0 as f32 - my).max(0.0),
        (x1 as f32 + mx).min(w as f32 - 1.0),
        (y1 as f32 + my).min(h as f32 - 1.0),
    ];
    // Two-pass chamfer distance to the nearest pixel outside the mask.
    let big = u32::MAX / 4;
    let mut d: Vec<u32> = mask.iter().map(|&m| if m { big } else { 0 }).collect();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut v = d[i];
            if x == 0 || y == 0 {
                v = v.min(u32::from(mask[i]) * 3);
            }
            if x > 0 {
                v = v.min(d[i - 1] + 3);
            }
            if y > 0 {
                v = v.min(d[i - w] + 3);
            }
            d[i] = v;
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            let i = y * w + x;
            let mut v = d[i];
            if x + 1 == w || y + 1 == h {
                v = v.min(u32::from(mask[i]) * 3);
            }
            if x + 1 < w {
                v = v.min(d[i + 1] + 3);
            }
            if y + 1 < h {
                v = v.min(d[i + w] + 3);
            }
            d[i] = v;
        }
    }
    let inner = (0..w * h).max_by_key(|&i| d[i]).unwrap_or(0);
    Prompt {
        points: vec![([(inner % w) as f32, (inner / w) as f32], 1)],
        bbox: Some(bbox),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prompt_is_the_masks_box_and_its_innermost_pixel() {
        // A 9 × 5 rectangle at x 2..11, y 4..9 in a 20 × 12 image.
        let (w, h) = (20, 12);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| (2..11).contains(&(i % w)) && (4..9).contains(&(i / w)))
            .collect();
        let p = prompt_for(&mask, w, h);
        let b = p.bbox.unwrap();
        assert!(
            (b[0] - 1.55).abs() < 1e-5 && (b[1] - 3.75).abs() < 1e-5,
            "{b:?}"
        );
        assert!(
            (b[2] - 10.45).abs() < 1e-5 && (b[3] - 8.25).abs() < 1e-5,
            "{b:?}"
        );
        assert_eq!(p.points[0].0[1], 6.0);
        assert!((4.0..=8.0).contains(&p.points[0].0[0]), "{:?}", p.points);
    }
}
