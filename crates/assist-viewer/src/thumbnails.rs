//! Thumbnails of the dataset's photographs for the page's camera list: each camera's own
//! training image, box-filtered to [`THUMB_WIDTH`] pixels wide and sent as a JPEG data URL
//! in the hello message (a few kilobytes each; read once when the viewer starts). A camera
//! whose photograph cannot be read gets none, and the list shows its name alone.

use std::path::Path;

use assist_data::{LoadOptions, Split, image_io};
use base64::Engine;

use crate::worker::encode_jpeg;

/// Width of a thumbnail, in pixels.
pub const THUMB_WIDTH: u32 = 96;

/// One data URL (or `None`) per camera name, from the training frames of the dataset at
/// `data`.
pub fn thumbnails(data: &Path, names: &[String]) -> Vec<Option<String>> {
    let Ok(ds) = assist_data::load(data, &LoadOptions::default()) else {
        return vec![None; names.len()];
    };
    names
        .iter()
        .map(|name| {
            let frame = ds
                .frames
                .iter()
                .find(|f| f.split == Split::Train && &f.name == name)?;
            let (img, _) = image_io::read_rgb(&frame.image_path, [1.0; 3]).ok()?;
            let (w, h, rgb) = shrink(&img.data, img.width, img.height, img.channels);
            let jpeg = encode_jpeg(&rgb, w, h);
            Some(format!(
                "data:image/jpeg;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(jpeg)
            ))
        })
        .collect()
}

/// A box-filtered copy [`THUMB_WIDTH`] wide (RGB of the first three channels).
fn shrink(data: &[f32], w: u32, h: u32, channels: u32) -> (u32, u32, Vec<f32>) {
    let tw = THUMB_WIDTH.min(w).max(1);
    let th = ((h as u64 * tw as u64 / w.max(1) as u64) as u32).max(1);
    let mut out = vec![0.0f32; (tw * th * 3) as usize];
    for ty in 0..th {
        let (y0, y1) = (ty * h / th, ((ty + 1) * h / th).max(ty * h / th + 1));
        for tx in 0..tw {
            let (x0, x1) = (tx * w / tw, ((tx + 1) * w / tw).max(tx * w / tw + 1));
            let mut acc = [0.0f32; 3];
            for y in y0..y1.min(h) {
                for x in x0..x1.min(w) {
                    let p = ((y * w + x) * channels) as usize;
                    for c in 0..3 {
                        acc[c] += data[p + c.min(channels as usize - 1)];
                    }
                }
            }
            let n = ((y1.min(h) - y0) * (x1.min(w) - x0)).max(1) as f32;
            let q = ((ty * tw + tx) * 3) as usize;
            for c in 0..3 {
                out[q + c] = acc[c] / n;
            }
        }
    }
    (tw, th, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_training_camera_gets_its_photograph_small() {
        let tmp = assist_testkit::TempDir::new("thumbs");
        let data = tmp.path().join("cap");
        let cfg = assist_data::synth::SynthConfig {
            views: 8,
            width: 160,
            height: 120,
            objects: 3,
            spp: 1,
            shadow_samples: 1,
            ..Default::default()
        };
        assist_data::synth::generate(&cfg, &data, false, &|_, _| {}).unwrap();
        let ds = assist_data::load(&data, &LoadOptions::default()).unwrap();
        let mut names: Vec<String> = ds.frames_in(Split::Train).map(|f| f.name.clone()).collect();
        names.push("no such view".into());
        let t = thumbnails(&data, &names);
        assert_eq!(t.len(), names.len());
        assert!(t.last().unwrap().is_none());
        for url in &t[..t.len() - 1] {
            let b64 = url
                .as_deref()
                .unwrap()
                .strip_prefix("data:image/jpeg;base64,")
                .unwrap();
            let jpeg = base64::engine::general_purpose::STANDARD
                .decode(b64)
                .unwrap();
            let img = image::load_from_memory(&jpeg).unwrap();
            assert_eq!((img.width(), img.height()), (96, 72));
        }
        // The box filter keeps a flat colour.
        let (w, h, rgb) = shrink(&vec![0.25; 4 * 10 * 3], 4, 10, 3);
        assert_eq!((w, h), (4, 10));
        assert!(rgb.iter().all(|v| (v - 0.25).abs() < 1e-6));
        let (w, h, rgb) = shrink(&vec![0.5; 400 * 300 * 4], 400, 300, 4);
        assert_eq!((w, h), (96, 72));
        assert!(rgb.iter().all(|v| (v - 0.5).abs() < 1e-6));
    }
}
