//! The photographs a capture is posed from: a folder's images as they are, or frames of a
//! video decoded by `ffmpeg` — three candidates per frame wanted, evenly in time, of
//! which the sharpest in each window is kept (motion blur ruins features and training
//! alike). A folder with more images than wanted is thinned the same way.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::tools::{self, FFMPEG, FFPROBE, Runner};
use crate::{ProcessError, ProcessEvent, Stage};

/// Image files of a folder (JPEG or PNG, by extension), by name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>, ProcessError> {
    let entries = std::fs::read_dir(dir).map_err(|e| ProcessError::Io {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut images: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_image(p))
        .collect();
    images.sort();
    Ok(images)
}

pub fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "jpg" | "jpeg" | "png"))
}

/// Sharpness of an image: the variance of the Laplacian of its grey levels (0–255), at
/// most 640 pixels on the longer side (blur shows at every scale; the full size only
/// costs time).
pub fn sharpness(path: &Path) -> Result<f64, ProcessError> {
    let img = image::open(path).map_err(|e| ProcessError::Input {
        path: path.to_path_buf(),
        message: format!("not an image this build can read: {e}"),
    })?;
    let grey = if img.width().max(img.height()) > 640 {
        img.resize(640, 640, image::imageops::FilterType::Triangle)
            .to_luma8()
    } else {
        img.to_luma8()
    };
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    if w < 3 || h < 3 {
        return Ok(0.0);
    }
    let px = grey.as_raw();
    let at = |x: usize, y: usize| f64::from(px[x + w * y]);
    let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let l = at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y);
            sum += l;
            sum2 += l * l;
            n += 1.0;
        }
    }
    let mean = sum / n;
    Ok(sum2 / n - mean * mean)
}

/// Of `scores` (in capture order), the index of the highest in each of `target`
/// consecutive, equal windows (all of them when there are no more than `target`).
pub fn sharpest_per_window(scores: &[f64], target: usize) -> Vec<usize> {
    let n = scores.len();
    if n <= target {
        return (0..n).collect();
    }
    (0..target)
        .map(|w| {
            let (lo, hi) = (
                w * n / target,
                ((w + 1) * n / target).max(w * n / target + 1),
            );
            (lo..hi)
                .max_by(|&a, &b| scores[a].total_cmp(&scores[b]).then(b.cmp(&a)))
                .unwrap_or(lo)
        })
        .collect()
}

/// How long a video lasts (seconds) and how many frames it has, by `ffprobe`.
fn probe(video: &Path) -> Result<(f64, Option<u64>), ProcessError> {
    let ffprobe = FFPROBE.find()?;
    let text = tools::output(
        FFPROBE,
        "reading the video's length",
        Command::new(ffprobe)
            .args(["-v", "error", "-select_streams", "v:0", "-count_packets"])
            .args(["-show_entries", "stream=nb_read_packets:format=duration"])
            .args(["-of", "json"])
            .arg(video),
    )
    .map_err(|e| ProcessError::Input {
        path: video.to_path_buf(),
        message: format!("not a video ffmpeg can read ({e})"),
    })?;
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    let frames = v["streams"][0]["nb_read_packets"]
        .as_str()
        .and_then(|s| s.parse::<u64>().ok());
    let duration = v["format"]["duration"]
        .as_str()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|d| d.is_finite() && *d > 0.0);
    match (duration, frames) {
        (Some(d), f) if f != Some(0) => Ok((d, f)),
        _ => Err(ProcessError::Input {
            path: video.to_path_buf(),
            message: "has no video stream with frames (ffprobe found none)".into(),
        }),
    }
}

/// Decodes candidates for `target` frames of `video` into `dir` (JPEG, ffmpeg's quality
/// 2, `%06d.jpg`): three per wanted frame evenly in time, or every frame of a shorter
/// video. Returns them in order.
pub fn video_candidates(
    video: &Path,
    dir: &Path,
    target: usize,
    runner: &Runner,
    on_event: &mut dyn FnMut(&ProcessEvent),
) -> Result<Vec<PathBuf>, ProcessError> {
    let ffmpeg = FFMPEG.find()?;
    let (duration, frames) = probe(video)?;
    let want = 3 * target as u64;
    let mut cmd = Command::new(ffmpeg);
    cmd.args(["-nostdin", "-hide_banner", "-loglevel", "error", "-i"])
        .arg(video);
    if frames.is_none_or(|f| f > want) {
        cmd.args(["-vf", &format!("fps={:.6}", want as f64 / duration)]);
    } else {
        // Every frame, as they come (no duplicated or dropped frames).
        cmd.args(["-fps_mode", "passthrough"]);
    }
    cmd.args(["-q:v", "2"]).arg(dir.join("%06d.jpg"));
    on_event(&ProcessEvent::Stage {
        stage: Stage::Frames,
        detail: format!(
            "decoding {} candidate frames of a {duration:.1} s video with ffmpeg",
            frames.map_or(want, |f| f.min(want))
        ),
    });
    runner.run(FFMPEG, "decoding the video's frames", &mut cmd, |_| {})?;
    list_images(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sharpest_of_each_window_is_kept() {
        let scores = [1.0, 5.0, 2.0, 9.0, 3.0, 3.0, 0.5, 0.4, 0.6];
        assert_eq!(sharpest_per_window(&scores, 3), vec![1, 3, 8]);
        // Ties go to the earlier frame; fewer frames than wanted keeps them all.
        assert_eq!(sharpest_per_window(&[2.0, 2.0], 1), vec![0]);
        assert_eq!(sharpest_per_window(&[1.0, 2.0], 5), vec![0, 1]);
        // Uneven windows still give one frame each, in order.
        let picked = sharpest_per_window(&[0.0; 10], 4);
        assert_eq!(picked.len(), 4);
        assert!(picked.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn blur_lowers_the_sharpness() {
        let dir = assist_testkit::TempDir::new("sharpness");
        let sharp = image::GrayImage::from_fn(64, 48, |x, y| {
            image::Luma([if (x / 4 + y / 4) % 2 == 0 { 255 } else { 0 }])
        });
        let blurred = image::imageops::blur(&sharp, 2.0);
        let (a, b) = (dir.path().join("a.png"), dir.path().join("b.png"));
        sharp.save(&a).unwrap();
        blurred.save(&b).unwrap();
        let (sa, sb) = (sharpness(&a).unwrap(), sharpness(&b).unwrap());
        assert!(sa > 10.0 * sb, "{sa} vs {sb}");
        // A flat image has none.
        let flat = dir.path().join("c.png");
        image::GrayImage::from_pixel(16, 16, image::Luma([90]))
            .save(&flat)
            .unwrap();
        assert_eq!(sharpness(&flat).unwrap(), 0.0);
    }
}
