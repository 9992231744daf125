//! Multi-view consistency of a dataset with depth: back-project one view's depth, project
//! it into another view, and compare depth and colour there. Proves that cameras, poses,
//! depth and images agree (used by tests on desk and synth, and usable on any dataset
//! with depth).

use crate::dataset::Dataset;
use crate::error::Result;
use crate::image_io::{ImageF32, read_depth_png, read_rgb};

/// Outcome of reprojecting view `a` into view `b`.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Reprojection {
    /// Pixels of `a` (sampled every `stride`) whose point lands inside `b`.
    pub projected: usize,
    /// Of those, how many agree with `b`'s depth within 1% (the rest are occluded in `b`).
    pub depth_consistent: usize,
    /// Median over depth-consistent pixels of the mean |ΔRGB| (0–1 scale).
    pub median_abs_rgb: f64,
}

impl Reprojection {
    pub fn consistent_fraction(&self) -> f64 {
        self.depth_consistent as f64 / self.projected.max(1) as f64
    }
}

fn bilinear(img: &ImageF32, x: f64, y: f64) -> Option<[f32; 3]> {
    let (fx, fy) = (x - 0.5, y - 0.5);
    if fx < 0.0 || fy < 0.0 || fx >= (img.width - 1) as f64 || fy >= (img.height - 1) as f64 {
        return None;
    }
    let (x0, y0) = (fx.floor() as u32, fy.floor() as u32);
    let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
    let mut out = [0.0; 3];
    for (dx, dy, w) in [
        (0, 0, (1.0 - ax) * (1.0 - ay)),
        (1, 0, ax * (1.0 - ay)),
        (0, 1, (1.0 - ax) * ay),
        (1, 1, ax * ay),
    ] {
        let p = img.pixel(x0 + dx, y0 + dy);
        for c in 0..3 {
            out[c] += w * p[c];
        }
    }
    Some(out)
}

/// Reprojects frame `a` into frame `b` using `a`'s depth (both frames need depth).
/// `camera_b` may override `b`'s camera (e.g. for a negative control).
pub fn reproject(
    ds: &Dataset,
    a: usize,
    b: usize,
    stride: u32,
    camera_b: Option<assist_core::Camera>,
) -> Result<Reprojection> {
    let (fa, fb) = (&ds.frames[a], &ds.frames[b]);
    let missing = |f: &crate::Frame| {
        crate::DataError::field(
            &f.image_path,
            "depth_file_path",
            "this frame has no depth map",
        )
    };
    let (ia, _) = read_rgb(&fa.image_path, [0.0; 3])?;
    let (ib, _) = read_rgb(&fb.image_path, [0.0; 3])?;
    let da = read_depth_png(
        fa.depth_path.as_ref().ok_or_else(|| missing(fa))?,
        fa.depth_scale,
    )?;
    let db = read_depth_png(
        fb.depth_path.as_ref().ok_or_else(|| missing(fb))?,
        fb.depth_scale,
    )?;
    let cam_b = camera_b.unwrap_or(fb.camera);
    let (mut projected, mut consistent) = (0usize, 0usize);
    let mut diffs = Vec::new();
    for j in (0..fa.camera.height()).step_by(stride as usize) {
        for i in (0..fa.camera.width()).step_by(stride as usize) {
            let z = da.data[(j * da.width + i) as usize] as f64;
            if z <= 0.0 {
                continue;
            }
            let Some(p) = fa.camera.unproject(i as f64 + 0.5, j as f64 + 0.5, z) else {
                continue;
            };
            let Some((px, zb)) = cam_b.project(p) else {
                continue;
            };
            let (ui, vi) = (px.x.floor(), px.y.floor());
            if ui < 0.0 || vi < 0.0 || ui >= db.width as f64 || vi >= db.height as f64 {
                continue;
            }
            projected += 1;
            let zb_map = db.data[(vi as u32 * db.width + ui as u32) as usize] as f64;
            if (zb_map - zb).abs() > 0.01 * zb {
                continue;
            }
            let Some(cb) = bilinear(&ib, px.x, px.y) else {
                continue;
            };
            consistent += 1;
            let ca = ia.pixel(i, j);
            diffs.push((0..3).map(|c| (ca[c] - cb[c]).abs() as f64).sum::<f64>() / 3.0);
        }
    }
    diffs.sort_by(f64::total_cmp);
    let median_abs_rgb = if diffs.is_empty() {
        f64::INFINITY
    } else {
        diffs[diffs.len() / 2]
    };
    Ok(Reprojection {
        projected,
        depth_consistent: consistent,
        median_abs_rgb,
    })
}
