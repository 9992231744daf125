//! Training views held in memory: colour, instance ids (from instance masks or from the
//! alpha of Blender images), dataset depth, and the background prior (user-supplied
//! inpainted colour/depth, or the built-in fill).

use assist_core::Camera;
use assist_data::image_io::{read_depth_png, read_ids, read_rgb};
use assist_data::{Dataset, Frame, Split};
use rayon::prelude::*;

use crate::error::{Result, TrainError};
use crate::prior;

/// Which built-in fill produces the background prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PriorKind {
    /// No background prior (λ1 = λ2 = 0 unless the user supplies files).
    None,
    PushPull,
    Exemplar,
}

impl PriorKind {
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "none" => PriorKind::None,
            "push-pull" => PriorKind::PushPull,
            "exemplar" => PriorKind::Exemplar,
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
    /// Dataset depth (z, world units; 0 = none).
    pub depth: Option<Vec<f32>>,
    /// Background prior: colour with objects removed.
    pub inpaint: Option<Vec<f32>>,
    /// Background prior: z-depth with objects removed (0 = none).
    pub inpaint_depth: Option<Vec<f32>>,
}

/// Pixels covered by objects, dilated by this many pixels, are filled by the prior.
pub const PRIOR_DILATION: usize = 3;

/// Loads one frame: colour over `background`, ids, depth.
pub fn load_view(frame: &Frame, image_index: u32, background: [f32; 3]) -> Result<View> {
    let (img, alpha) = read_rgb(&frame.image_path, background)?;
    let (w, h) = (img.width as usize, img.height as usize);
    if (w as u32, h as u32) != (frame.camera.width(), frame.camera.height()) {
        return Err(TrainError::Input {
            path: frame.image_path.clone(),
            message: format!(
                "image is {w}×{h} but its camera says {}×{}",
                frame.camera.width(),
                frame.camera.height()
            ),
        });
    }
    let ids = if let Some(p) = &frame.instance_mask_path {
        let m = read_ids(p)?;
        if (m.width as usize, m.height as usize) != (w, h) {
            return Err(TrainError::Input {
                path: p.clone(),
                message: format!(
                    "instance mask is {}×{} but its image {} is {w}×{h}",
                    m.width,
                    m.height,
                    frame.image_path.display()
                ),
            });
        }
        Some(m.data)
    } else if frame.alpha_is_mask {
        alpha.map(|a| a.iter().map(|&v| u16::from(v > 0.5)).collect())
    } else {
        None
    };
    let depth = match &frame.depth_path {
        Some(p) => {
            let d = read_depth_png(p, frame.depth_scale)?;
            if (d.width as usize, d.height as usize) != (w, h) {
                return Err(TrainError::Input {
                    path: p.clone(),
                    message: format!("depth is {}×{} but the image is {w}×{h}", d.width, d.height),
                });
            }
            Some(d.data)
        }
        None => None,
    };
    let inpaint = match &frame.inpaint_path {
        Some(p) => {
            let (im, _) = read_rgb(p, background)?;
            if (im.width as usize, im.height as usize) != (w, h) {
                return Err(TrainError::Input {
                    path: p.clone(),
                    message: format!(
                        "inpainted image is {}×{}, expected {w}×{h}",
                        im.width, im.height
                    ),
                });
            }
            Some(im.data)
        }
        None => None,
    };
    let inpaint_depth = match &frame.inpaint_depth_path {
        Some(p) => {
            let d = if p.extension().is_some_and(|e| e == "npy") {
                let a = assist_data::npy::read_npy(p)?;
                a.data.iter().map(|&v| v as f32).collect::<Vec<f32>>()
            } else {
                read_depth_png(p, frame.depth_scale)?.data
            };
            if d.len() != w * h {
                return Err(TrainError::Input {
                    path: p.clone(),
                    message: format!("inpainted depth has {} values, expected {w}×{h}", d.len()),
                });
            }
            Some(d)
        }
        None => None,
    };
    Ok(View {
        name: frame.name.clone(),
        camera: frame.camera,
        image_index,
        width: w,
        height: h,
        rgb: img.data,
        ids,
        depth,
        inpaint,
        inpaint_depth,
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
            PriorKind::PushPull => prior::push_pull(&mut img, w, h, 3, &hole),
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

/// Loads the frames of `split` (in dataset order), in parallel.
pub fn load_views(ds: &Dataset, split: Split, background: [f32; 3]) -> Result<Vec<View>> {
    let frames: Vec<&Frame> = ds.frames_in(split).collect();
    frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| load_view(f, i as u32, background))
        .collect()
}
