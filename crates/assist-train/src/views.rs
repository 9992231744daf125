//! Training views held in memory: colour, instance ids (from instance masks or from the
//! alpha of Blender images), dataset depth, and the background prior (user-supplied
//! inpainted colour/depth, or the built-in fill).

use assist_core::Camera;
use assist_data::image_io::{read_depth_png, read_instance_mask, read_rgb};
use assist_data::{Dataset, Frame, Split};
use rayon::prelude::*;

use crate::error::{Result, TrainError};
use crate::prior;

/// Which built-in fill produces the background prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum PriorKind {
    /// No background prior (λ1 = λ2 = 0 unless the user supplies files).
    None,
    PushPull,
    Exemplar,
    /// From the other views that see the background (needs depth; push–pull elsewhere).
    #[default]
    MultiView,
}

impl PriorKind {
    pub const NAMES: &'static str = "multi-view, push-pull, exemplar or none";

    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "none" => PriorKind::None,
            "push-pull" => PriorKind::PushPull,
            "exemplar" => PriorKind::Exemplar,
            "multi-view" => PriorKind::MultiView,
            _ => return None,
        })
    }
}

#[derive(Debug, Clone)]
pub struct View {
    pub name: String,
    pub camera: Camera,
    /// Index of the view among the training images (appearance code).
    pub image_index: u32,
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<f32>,
    pub ids: Option<Vec<u16>>,
    /// Pixels to train on (nerfstudio's `mask_path`: 0 = ignore the pixel); `None` = all.
    pub valid: Option<Vec<bool>>,
    /// Dataset depth (z, world units; 0 = none).
    pub depth: Option<Vec<f32>>,
    /// Background prior: colour with objects removed.
    pub inpaint: Option<Vec<f32>>,
    /// Background prior: z-depth with objects removed (0 = none).
    pub inpaint_depth: Option<Vec<f32>>,
    /// Weight of the background prior per pixel (0..1; `None` = 1 everywhere).
    pub prior_confidence: Option<Vec<f32>>,
    /// Weight of the prior's colour per pixel where it differs from `prior_confidence`
    /// (near objects that cast shadows: see [`crate::shadow`]); `None` = the confidence.
    pub prior_rgb_weight: Option<Vec<f32>>,
    /// The prior colour came from the user's files (`inpaint_path`, `--prior-dir`): it is
    /// used as given, never replaced by a built-in fill.
    pub prior_from_user: bool,
}

#[cfg(test)]
impl View {
    /// A black `width × height` view seen from +z, with nothing but its colour (tests).
    pub(crate) fn blank(width: usize, height: usize) -> View {
        View {
            name: "v".into(),
            camera: Camera {
                intrinsics: assist_core::Intrinsics::from_fov_x(width as u32, height as u32, 1.0),
                pose: assist_core::Pose::look_at(
                    assist_core::DVec3::Z,
                    assist_core::DVec3::ZERO,
                    assist_core::DVec3::Y,
                )
                .unwrap(),
            },
            image_index: 0,
            width,
            height,
            rgb: vec![0.0; width * height * 3],
            ids: None,
            valid: None,
            depth: None,
            inpaint: None,
            inpaint_depth: None,
            prior_confidence: None,
            prior_rgb_weight: None,
            prior_from_user: false,
        }
    }
}

/// Pixels covered by objects, dilated by this many pixels, are filled by the prior.
pub const PRIOR_DILATION: usize = 3;

/// Loads one frame: colour over `background`, ids, depth. Files `pixel_factor` times
/// larger than the camera (`--downscale`) are reduced: colour by block means, ids and
/// depth by block centres.
pub fn load_view(frame: &Frame, image_index: u32, background: [f32; 3]) -> Result<View> {
    use assist_data::downscale::{reduce_mean, reduce_pick};
    let k = frame.pixel_factor.max(1) as usize;
    let (w, h) = (
        frame.camera.width() as usize,
        frame.camera.height() as usize,
    );
    let check = |path: &std::path::Path, what: &str, gw: u32, gh: u32| -> Result<()> {
        if (gw as usize / k, gh as usize / k) == (w, h) {
            return Ok(());
        }
        let want = if k == 1 {
            format!("{w}×{h}")
        } else {
            format!("{}×{} (the camera's {w}×{h}, {k} times)", w * k, h * k)
        };
        Err(TrainError::Input {
            path: path.to_path_buf(),
            message: format!("{what} is {gw}×{gh}, expected {want}"),
        })
    };
    let colour = |data: Vec<f32>, gw: u32, gh: u32, ch: usize| {
        if k == 1 {
            data
        } else {
            reduce_mean(&data, gw as usize, gh as usize, ch, k)
        }
    };
    let (img, alpha) = read_rgb(&frame.image_path, background)?;
    check(&frame.image_path, "image", img.width, img.height)?;
    let (iw, ih) = (img.width, img.height);
    let rgb = colour(img.data, iw, ih, 3);
    let alpha = alpha.map(|a| colour(a, iw, ih, 1));
    let ids = if let Some(p) = &frame.instance_mask_path {
        let m = read_instance_mask(p, frame.mask_encoding)?;
        check(p, "instance mask", m.width, m.height)?;
        Some(if k == 1 {
            m.data
        } else {
            reduce_pick(&m.data, m.width as usize, m.height as usize, k)
        })
    } else if frame.alpha_is_mask {
        alpha.map(|a| a.iter().map(|&v| u16::from(v > 0.5)).collect())
    } else {
        None
    };
    let valid = match &frame.mask_path {
        Some(p) => {
            let m = assist_data::image_io::read_mask_values(p)?;
            check(p, "mask", m.width, m.height)?;
            let v: Vec<bool> = m.data.iter().map(|&v| v != 0).collect();
            Some(if k == 1 {
                v
            } else {
                reduce_pick(&v, m.width as usize, m.height as usize, k)
            })
        }
        None => None,
    };
    let depth_map = |d: Vec<f32>, gw: u32, gh: u32| {
        if k == 1 {
            d
        } else {
            reduce_pick(&d, gw as usize, gh as usize, k)
        }
    };
    let depth = match &frame.depth_path {
        Some(p) => {
            let d = read_depth_png(p, frame.depth_scale)?;
            check(p, "depth", d.width, d.height)?;
            Some(depth_map(d.data, d.width, d.height))
        }
        None => None,
    };
    let inpaint = match &frame.inpaint_path {
        Some(p) => {
            let (im, _) = read_rgb(p, background)?;
            check(p, "inpainted image", im.width, im.height)?;
            Some(colour(im.data, im.width, im.height, 3))
        }
        None => None,
    };
    let inpaint_depth = match &frame.inpaint_depth_path {
        Some(p) => {
            let (d, gw, gh) = if p.extension().is_some_and(|e| e == "npy") {
                let a = assist_data::npy::read_npy(p)?;
                let shape = a.shape.clone();
                let d: Vec<f32> = a.data.iter().map(|&v| v as f32).collect();
                match shape.as_slice() {
                    [gh, gw] | [gh, gw, 1] => (d, *gw as u32, *gh as u32),
                    _ => {
                        return Err(TrainError::Input {
                            path: p.clone(),
                            message: format!(
                                "inpainted depth has shape {shape:?}, expected (height, width)"
                            ),
                        });
                    }
                }
            } else {
                let d = read_depth_png(p, frame.depth_scale)?;
                (d.data, d.width, d.height)
            };
            check(p, "inpainted depth", gw, gh)?;
            Some(depth_map(d, gw, gh))
        }
        None => None,
    };
    Ok(View {
        name: frame.name.clone(),
        camera: frame.camera,
        image_index,
        width: w,
        height: h,
        rgb,
        ids,
        valid,
        depth,
        prior_from_user: inpaint.is_some(),
        inpaint,
        inpaint_depth,
        prior_confidence: None,
        prior_rgb_weight: None,
    })
}

/// Fills the background prior of a view whose user did not supply one.
pub fn fill_prior(v: &mut View, kind: PriorKind) {
    let Some(ids) = &v.ids else { return };
    if kind == PriorKind::None || !ids.iter().any(|&i| i != 0) {
        return;
    }
    let (w, h) = (v.width, v.height);
    let objects: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
    let hole = prior::dilate(&objects, w, h, PRIOR_DILATION);
    if v.inpaint.is_none() {
        let mut img = v.rgb.clone();
        match kind {
            PriorKind::PushPull | PriorKind::MultiView => {
                prior::push_pull(&mut img, w, h, 3, &hole)
            }
            PriorKind::Exemplar => prior::exemplar_fill(&mut img, w, h, 3, &hole, 7, 24),
            PriorKind::None => {}
        }
        v.inpaint = Some(img);
    }
    if v.inpaint_depth.is_none()
        && let Some(d) = &v.depth
    {
        let mut dd = d.clone();
        let hole_d: Vec<bool> = hole.iter().zip(d).map(|(&m, &z)| m || z <= 0.0).collect();
        prior::push_pull(&mut dd, w, h, 1, &hole_d);
        v.inpaint_depth = Some(dd);
    }
}

/// Fills the background prior of every view that has none: from the other views first
/// with [`PriorKind::MultiView`] (where views have depth), then, with `guess`, with the
/// single-view fill. Without `guess`, what no other view filled keeps no prior: where the
/// other views see what objects hide (a walk-around), a guess from one image contradicts
/// them.
pub fn fill_priors(
    views: &mut [View],
    kind: PriorKind,
    guess: bool,
) -> Option<crate::multiview::MultiViewStats> {
    let stats = (kind == PriorKind::MultiView).then(|| crate::multiview::fill_multiview(views));
    if guess {
        views.par_iter_mut().for_each(|v| fill_prior(v, kind));
    }
    stats
}

/// Loads the frames of `split` (in dataset order), in parallel.
pub fn load_views(ds: &Dataset, split: Split, background: [f32; 3]) -> Result<Vec<View>> {
    let frames: Vec<&Frame> = ds.frames_in(split).collect();
    frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| load_view(f, i as u32, background))
        .collect()
}
