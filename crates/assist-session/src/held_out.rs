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
    /// The views were rendered and compared at 1/`scale` of the training images' size
    /// (views over [`HELD_OUT_MAX_PIXELS`] are; 1: at their size). `assist eval`
    /// measures at full size.
    pub scale: u32,
    /// The first view, ground truth left and render right (periodic evaluations).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preview: Option<PathBuf>,
}

/// Largest view the held-out checks during training render, in pixels: a larger one is
/// averaged down by the smallest whole factor that brings it under this, so checking a
/// phone capture's views costs a fraction of the training, not more than it.
pub const HELD_OUT_MAX_PIXELS: usize = 250_000;

/// One held-out view as measured: its camera and photograph at the measured size.
struct Shown {
    camera: assist_core::Camera,
    width: usize,
    height: usize,
    rgb: Vec<f32>,
}

/// The smallest whole factor that brings `w × h` pixels under [`HELD_OUT_MAX_PIXELS`].
fn shrink_factor(w: usize, h: usize) -> usize {
    let mut k = 1;
    while (w / k) * (h / k) > HELD_OUT_MAX_PIXELS && w / k > 1 && h / k > 1 {
        k += 1;
    }
    k
}

impl Shown {
    /// A `width × height` photograph at 1/`k` of its size: each pixel the mean of a k×k block (a right or bottom
    /// remainder of fewer than k pixels is left out), the camera's intrinsics to match.
    fn of(
        camera: assist_core::Camera,
        width: usize,
        height: usize,
        rgb: Vec<f32>,
        k: usize,
    ) -> Shown {
        if k == 1 {
            return Shown {
                camera,
                width,
                height,
                rgb,
            };
        }
        let (w, h) = (width / k, height / k);
        let rgb = assist_data::downscale::reduce_mean(&rgb, width, height, 3, k);
        let mut camera = camera;
        camera.intrinsics = camera.intrinsics.downscaled(k as f64, w as u32, h as u32);
        Shown {
            camera,
            width: w,
            height: h,
            rgb,
        }
    }
}

/// The held-out views of a run, loaded once.
pub(crate) struct HeldOutSet {
    split: Split,
    scale: u32,
    views: Vec<Shown>,
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
            let mut scale = 1;
            for i in 0..k {
                let f = frames[i * frames.len() / k];
                let v = assist_train::load_view(f, u32::MAX, bg)?;
                let s = shrink_factor(v.width, v.height);
                scale = scale.max(s);
                views.push(Shown::of(f.camera, v.width, v.height, v.rgb, s));
            }
            return Ok(Some(HeldOutSet {
                split,
                scale: scale as u32,
                views,
            }));
        }
        Ok(None)
    }

    /// [`Self::measure`] of a run's fields after step `s`, pulled from its optimizers
    /// first (a GPU's keep them between steps).
    pub(crate) fn measure_during(
        &self,
        t: &mut assist_train::Trainer,
        s: &assist_train::StepStats,
        preview: &std::path::Path,
    ) -> Result<HeldOut> {
        t.pull()?;
        self.measure(&t.scene, s.iteration, s.elapsed, Some(preview))
    }

    /// Renders the views with `scene` (the nearest training views' codes) and scores them; with
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
        for v in &self.views {
            let img = assist_render::render_camera(scene, &v.camera, u32::MAX, &opts);
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
        if let (Some(path), Some(rgb), Some(v)) = (preview, &first, self.views.first()) {
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
            scale: self.scale,
            preview: written,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{Camera, DVec3, Intrinsics, Pose};

    #[test]
    fn large_views_are_measured_smaller_with_their_cameras_to_match() {
        assert_eq!(shrink_factor(400, 400), 1);
        assert_eq!(shrink_factor(640, 480), 2);
        assert_eq!(shrink_factor(1080, 1920), 3);
        assert_eq!(shrink_factor(4000, 1), 1);
        let camera = Camera {
            intrinsics: Intrinsics::from_fov_x(7, 5, 1.0),
            pose: Pose::look_at(DVec3::new(0.0, -2.0, 0.5), DVec3::ZERO, DVec3::Z).unwrap(),
        };
        let (w, h) = (7, 5);
        let rgb: Vec<f32> = (0..3 * w * h).map(|i| i as f32).collect();
        let s = Shown::of(camera, w, h, rgb, 2);
        assert_eq!((s.width, s.height), (3, 2));
        // Pixel (1, 1): the mean of source pixels x 2–3, y 2–3, channel 0.
        let src = |x: usize, y: usize| (3 * (y * w + x)) as f32;
        let want = (src(2, 2) + src(3, 2) + src(2, 3) + src(3, 3)) / 4.0;
        assert_eq!(s.rgb[3 * (s.width + 1)], want);
        // Its ray passes through the middle of that block of the full-size camera.
        let small = s.camera.pixel_ray(1, 1).unwrap();
        let full = camera.ray(3.0, 3.0).unwrap();
        assert!(small.dir.distance(full.dir) < 1e-12, "{small:?} {full:?}");
    }
}
