//! Held-out views measured during and after training: their PSNR and SSIM, and a preview
//! image of the first beside its render.

use std::path::PathBuf;

use assist_data::{Dataset, Split};
use assist_scene::NeuralScene;
use assist_train::background_color;
use serde::Serialize;

use crate::{Result, SessionError};

/// Where periodic held-out evaluations leave their preview: beside the scene,
/// `NAME.preview.png` for `NAME.assist`.
pub fn preview_path(out: &std::path::Path) -> PathBuf {
    out.with_extension("preview.png")
}

/// How the scene does on views it did not train on.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOut {
    pub iteration: usize,
    /// Training seconds when measured.
    pub elapsed: f64,
    /// The split the views come from (test, else val).
    pub split: String,
    pub views: usize,
    /// Mean of per-view PSNR (dB) and SSIM.
    pub psnr: f64,
    pub ssim: f64,
    /// Seconds the measurement took (counted in the run's time).
    pub seconds: f64,
    /// The first view, ground truth left and render right (periodic evaluations).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preview: Option<PathBuf>,
}

/// The held-out views of a run, loaded once.
pub(crate) struct HeldOutSet {
    split: Split,
    views: Vec<(assist_core::Camera, assist_train::View)>,
}

impl HeldOutSet {
    /// Up to `n` views of the test split (else val), evenly spread; `None` without one.
    pub(crate) fn load(ds: &Dataset, n: usize) -> Result<Option<HeldOutSet>> {
        if n == 0 {
            return Ok(None);
        }
        let bg = background_color(ds);
        for split in [Split::Test, Split::Val] {
            let frames: Vec<_> = ds.frames_in(split).collect();
            if frames.is_empty() {
                continue;
            }
            let k = n.min(frames.len());
            let mut views = Vec::with_capacity(k);
            for i in 0..k {
                let f = frames[i * frames.len() / k];
                let v = assist_train::load_view(f, u32::MAX, bg)?;
                views.push((f.camera, v));
            }
            return Ok(Some(HeldOutSet { split, views }));
        }
        Ok(None)
    }

    /// Renders the views with `scene` (the average appearance) and scores them; with
    /// `preview`, writes the first view beside its render there.
    pub(crate) fn measure(
        &self,
        scene: &NeuralScene,
        iteration: usize,
        elapsed: f64,
        preview: Option<&std::path::Path>,
    ) -> Result<HeldOut> {
        use assist_train::metrics::{psnr, ssim};
        let t0 = std::time::Instant::now();
        let opts = assist_render::RenderOptions::default();
        let (mut p, mut q) = (0.0, 0.0);
        let mut first = None;
        for (cam, v) in &self.views {
            let img = assist_render::render_camera(scene, cam, u32::MAX, &opts);
            let rgb: Vec<f32> = img.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect();
            p += psnr(&rgb, &v.rgb, 3, None)
                .unwrap_or(f64::INFINITY)
                .min(100.0);
            q += ssim(&rgb, &v.rgb, v.width, v.height, 3);
            if first.is_none() {
                first = Some(rgb);
            }
        }
        let n = self.views.len().max(1) as f64;
        let mut written = None;
        if let (Some(path), Some(rgb), Some((_, v))) = (preview, &first, self.views.first()) {
            let (w, h) = (v.width, v.height);
            let mut side = vec![0u8; 2 * w * h * 3];
            let to8 = |x: f32| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        let i = 3 * (y * w + x) + c;
                        side[3 * (y * 2 * w + x) + c] = to8(v.rgb[i]);
                        side[3 * (y * 2 * w + w + x) + c] = to8(rgb[i]);
                    }
                }
            }
            assist_data::image_io::write_rgb8_png(path, 2 * w as u32, h as u32, &side)
                .map_err(SessionError::Data)?;
            written = Some(path.to_path_buf());
        }
        Ok(HeldOut {
            iteration,
            elapsed,
            split: self.split.name().to_string(),
            views: self.views.len(),
            psnr: p / n,
            ssim: q / n,
            seconds: t0.elapsed().as_secs_f64(),
            preview: written,
        })
    }
}
