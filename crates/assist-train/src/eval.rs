//! Evaluation of a trained scene on a dataset split: PSNR, SSIM, panoptic mIoU against
//! instance masks, and — where the dataset has `background/` ground truth — background
//! PSNR over all pixels and over the pixels that objects cover.

use std::path::Path;

use assist_data::{Dataset, Split};
use assist_render::{RenderOptions, render_camera};
use assist_scene::NeuralScene;
use serde::Serialize;

use crate::error::Result;
use crate::metrics::{
    DetailAccumulator, IouAccumulator, color_corrected, fine_detail, mse_to_psnr, squared_error,
    ssim,
};
use crate::views::load_view;

#[derive(Debug, Clone, Serialize)]
pub struct ImageScore {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
    /// PSNR after the render's best gain and offset per channel ([`color_corrected`]).
    pub color_corrected_psnr: f64,
    /// The camera's fit to the photograph, when poses are aligned before measuring.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment: Option<crate::AlignReport>,
}

#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub split: String,
    pub images: usize,
    /// Mean of per-image PSNR.
    pub psnr: f64,
    pub ssim: f64,
    /// Mean of per-image PSNR after each render's best gain and offset per channel (what
    /// the views' exposure and white balance alone cost: the gap to `psnr`).
    pub color_corrected_psnr: f64,
    /// How much of the photographs' fine detail (structure 1–3 pixels across) the renders
    /// reproduce, every image pooled ([`DetailAccumulator`]): 1 as sharp as they are, 0.5
    /// at half its contrast; `None` (left out of the JSON, as every figure that does not
    /// apply) for photographs without detail.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detail: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub panoptic_miou: Option<f64>,
    /// IoU of each instance id (0 = background) whose mean is `panoptic_miou`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub panoptic_iou: Option<std::collections::BTreeMap<u16, f64>>,
    /// PSNR of the composited image over the pixels the dataset's masks give to objects,
    /// and over all others (every measured image's pixels pooled): where a capture's error
    /// is, on the object or around it, whatever nodes the scene was trained with.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub object_pixels_psnr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub other_pixels_psnr: Option<f64>,
    /// [`EvalReport::detail`] over the same two sets of pixels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub object_pixels_detail: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub other_pixels_detail: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub background_psnr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub background_occluded_psnr: Option<f64>,
    /// Median of |rendered − true| / true z-depth of the background node alone, over the
    /// pixels where the `background/` ground truth has depth (a pixel the background
    /// leaves empty counts as error 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub background_depth_error: Option<f64>,
    pub per_image: Vec<ImageScore>,
    pub seconds: f64,
}

/// One measured view, as [`evaluate_each`] hands it over: the photograph (interleaved RGB
/// at the render's size), the render and its score.
pub struct EvaluatedView<'a> {
    pub truth: &'a [f32],
    pub render: &'a assist_render::RenderedImage,
    pub score: &'a ImageScore,
}

/// Evaluates `scene` on the frames of `split` (every `stride`-th one; `None` = all frames,
/// e.g. for a folder of edit renders).
pub fn evaluate(
    scene: &NeuralScene,
    ds: &Dataset,
    split: Option<Split>,
    stride: usize,
    progress: impl FnMut(usize, usize),
) -> Result<EvalReport> {
    let opts = RenderOptions::default();
    evaluate_each(scene, ds, split, stride, &opts, None, progress, |_| {})
}

/// [`evaluate`], handing each view to `on_view` once it is measured (a contact sheet);
/// with `align`, each view's camera is first fitted to its photograph
/// ([`crate::align_camera`]) and measured from there.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_each(
    scene: &NeuralScene,
    ds: &Dataset,
    split: Option<Split>,
    stride: usize,
    opts: &RenderOptions,
    align: Option<&crate::AlignOptions>,
    mut progress: impl FnMut(usize, usize),
    mut on_view: impl FnMut(EvaluatedView<'_>),
) -> Result<EvalReport> {
    let t0 = std::time::Instant::now();
    let split_name = split.map_or("all", |s| s.name());
    let frames: Vec<_> = ds
        .frames
        .iter()
        .filter(|f| split.is_none_or(|s| f.split == s))
        .step_by(stride.max(1))
        .collect();
    if frames.is_empty() {
        return Err(crate::error::TrainError::Input {
            path: ds.root.clone(),
            message: format!("the dataset has no frames in split {split_name:?}"),
        });
    }
    let mut bg_truth = background_dataset(&ds.root)?;
    // The truth is read at the size of the frames measured (a dataset read with
    // `--downscale`).
    if let Some(bt) = &mut bg_truth
        && let Some((f, b)) = frames
            .iter()
            .find_map(|f| bt.frames.iter().find(|b| b.name == f.name).map(|b| (f, b)))
    {
        let factor = (b.camera.width() as f64 / f.camera.width().max(1) as f64).round() as u32;
        if factor > 1 {
            assist_data::downscale::apply(bt, factor)?;
        }
    }
    let bg_scene = scene
        .scene
        .nodes
        .iter()
        .position(|n| n.is_background())
        .map(|k| {
            let mut s = scene.clone();
            s.scene.nodes = vec![scene.scene.nodes[k].clone()];
            s
        });
    let mut per_image = Vec::new();
    let mut pooled = Pooled::default();
    for (i, f) in frames.iter().enumerate() {
        progress(i, frames.len());
        let v = load_view(f, u32::MAX, scene.scene.background_color)?;
        let fitted =
            align.map(|a| crate::align_camera(scene, &f.camera, &v.rgb, v.valid.as_deref(), a));
        let camera = fitted.as_ref().map_or(&f.camera, |a| &a.camera);
        let img = render_camera(scene, camera, u32::MAX, opts);
        let rgb: Vec<f32> = img.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let (se, n) = squared_error(&rgb, &v.rgb, 3, None);
        let (cse, cn) = squared_error(&color_corrected(&rgb, &v.rgb, 3), &v.rgb, 3, None);
        per_image.push(ImageScore {
            name: f.name.clone(),
            psnr: mse_to_psnr(se / n as f64),
            ssim: ssim(&rgb, &v.rgb, v.width, v.height, 3),
            color_corrected_psnr: mse_to_psnr(cse / cn as f64),
            alignment: fitted.as_ref().map(|a| a.report),
        });
        on_view(EvaluatedView {
            truth: &v.rgb,
            render: &img,
            score: per_image.last().expect("pushed above"),
        });
        pooled.add_view(&rgb, &img.panoptic, &v);
        if let (Some(bt), Some(bs)) = (&bg_truth, &bg_scene)
            && let Some(bf) = bt.frames.iter().find(|b| b.name == f.name)
        {
            let truth = load_view(bf, u32::MAX, scene.scene.background_color)?;
            let b = render_camera(bs, camera, u32::MAX, opts);
            pooled.add_background(&b, &truth, v.ids.as_deref());
        }
    }
    progress(frames.len(), frames.len());
    let m = per_image.len().max(1) as f64;
    let mut p = pooled;
    Ok(EvalReport {
        split: split_name.into(),
        images: per_image.len(),
        psnr: per_image.iter().map(|s| s.psnr).sum::<f64>() / m,
        ssim: per_image.iter().map(|s| s.ssim).sum::<f64>() / m,
        color_corrected_psnr: per_image
            .iter()
            .map(|s| s.color_corrected_psnr)
            .sum::<f64>()
            / m,
        detail: p.detail.gain(),
        panoptic_miou: if p.any_ids { p.iou.mean() } else { None },
        panoptic_iou: p.any_ids.then(|| p.iou.per_class()),
        object_pixels_psnr: pooled_psnr(p.split_se[0]),
        other_pixels_psnr: pooled_psnr(p.split_se[1]),
        object_pixels_detail: p.split_detail[0].gain(),
        other_pixels_detail: p.split_detail[1].gain(),
        background_psnr: pooled_psnr(p.bg),
        background_occluded_psnr: pooled_psnr(p.occluded),
        background_depth_error: median(&mut p.depth_err),
        per_image,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The figures pooled over every view measured: panoptic IoU, squared error and fine
/// detail on the masks' object pixels and the others, and the background node's against
/// the `background/` ground truth.
#[derive(Default)]
struct Pooled {
    iou: IouAccumulator,
    any_ids: bool,
    /// Squared error and channel count on object pixels [0] and the others [1].
    split_se: [(f64, usize); 2],
    detail: DetailAccumulator,
    split_detail: [DetailAccumulator; 2],
    /// The background alone: everywhere, and where objects hide it.
    bg: (f64, usize),
    occluded: (f64, usize),
    depth_err: Vec<f32>,
}

impl Pooled {
    /// One view's render (`rgb` clamped, `panoptic` ids) against its photograph `v`.
    fn add_view(&mut self, rgb: &[f32], panoptic: &[u16], v: &crate::views::View) {
        let (rd, td) = (
            fine_detail(rgb, v.width, v.height, 3),
            fine_detail(&v.rgb, v.width, v.height, 3),
        );
        self.detail.add(&rd, &td, 3, None);
        if let Some(ids) = &v.ids {
            self.any_ids = true;
            self.iou.add(panoptic, ids);
            let on_object: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
            let others: Vec<bool> = on_object.iter().map(|&o| !o).collect();
            for (k, mask) in [&on_object, &others].into_iter().enumerate() {
                let (se, n) = squared_error(rgb, &v.rgb, 3, Some(mask));
                self.split_se[k].0 += se;
                self.split_se[k].1 += n;
                self.split_detail[k].add(&rd, &td, 3, Some(mask));
            }
        }
    }

    /// The background node's render `b` of a view against the ground truth `truth` of
    /// the background alone; `ids`, the view's instance masks, say where objects hide it.
    fn add_background(
        &mut self,
        b: &assist_render::RenderedImage,
        truth: &crate::views::View,
        ids: Option<&[u16]>,
    ) {
        let brgb: Vec<f32> = b.rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let (se, n) = squared_error(&brgb, &truth.rgb, 3, None);
        self.bg.0 += se;
        self.bg.1 += n;
        if let Some(td) = &truth.depth {
            self.depth_err.extend(
                td.iter()
                    .zip(&b.depth)
                    .filter(|(t, _)| **t > 0.0)
                    .map(|(&t, &d)| if d > 0.0 { ((d - t) / t).abs() } else { 1.0 }),
            );
        }
        if let Some(ids) = ids {
            let mask: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
            let (se, n) = squared_error(&brgb, &truth.rgb, 3, Some(&mask));
            self.occluded.0 += se;
            self.occluded.1 += n;
        }
    }
}

/// PSNR of a pooled squared error and channel count; `None` when nothing was counted.
fn pooled_psnr((se, n): (f64, usize)) -> Option<f64> {
    (n > 0).then(|| mse_to_psnr(se / n as f64))
}

/// The median of `v` (reordered); `None` when empty.
fn median(v: &mut [f32]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m as f64)
}

/// The `background/` ground truth beside a dataset (desk format), when present.
pub fn background_dataset(root: &Path) -> Result<Option<Dataset>> {
    let dir = if root.is_dir() {
        root.to_path_buf()
    } else {
        root.parent().unwrap_or(Path::new(".")).to_path_buf()
    };
    let b = dir.join("background");
    if !b.join("transforms.json").exists() {
        return Ok(None);
    }
    Ok(Some(assist_data::load(&b, &Default::default())?))
}

/// How well one built-in prior fills the background behind objects.
#[derive(Debug, Clone, Serialize)]
pub struct PriorScore {
    pub prior: crate::views::PriorKind,
    /// PSNR of the filled colour against the `background/` ground truth over the pixels
    /// objects cover (all views pooled), the figure comparable with a trained scene's
    /// `background_occluded_psnr`.
    pub occluded_psnr: f64,
    /// Mean seconds to fill one view.
    pub seconds_per_view: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct PriorReport {
    pub views: usize,
    pub occluded_pixels: usize,
    pub scores: Vec<PriorScore>,
}

/// Measures the built-in background priors on the views of `split` that have instance
/// masks and a `background/` ground-truth view (desk format): the views are filled as
/// training fills its views (the multi-view fill draws on the views of the same split),
/// then compared with the truth under their objects.
pub fn evaluate_priors(
    ds: &Dataset,
    split: Option<Split>,
    kinds: &[crate::views::PriorKind],
    mut progress: impl FnMut(usize, usize),
) -> Result<PriorReport> {
    let Some(truth) = background_dataset(&ds.root)? else {
        return Err(crate::error::TrainError::Input {
            path: ds.root.join("background"),
            message: "no background/transforms.json: the prior needs background ground truth"
                .into(),
        });
    };
    let pairs: Vec<_> = ds
        .frames
        .iter()
        .filter(|f| split.is_none_or(|s| f.split == s) && f.instance_mask_path.is_some())
        .filter_map(|f| {
            truth
                .frames
                .iter()
                .find(|b| b.name == f.name)
                .map(|b| (f, b))
        })
        .collect();
    if pairs.is_empty() {
        return Err(crate::error::TrainError::Input {
            path: ds.root.clone(),
            message: "no view has both an instance mask and a background/ view of the same name"
                .into(),
        });
    }
    // The views to fill, with their truths; the multi-view fill draws on all of them.
    let mut set = Vec::new();
    let mut truths = Vec::new();
    for (i, (f, b)) in pairs.iter().enumerate() {
        progress(i, 2 * pairs.len());
        let v = load_view(f, u32::MAX, [0.0; 3])?;
        let t = load_view(b, u32::MAX, [0.0; 3])?;
        if t.rgb.len() != v.rgb.len() {
            return Err(crate::error::TrainError::Input {
                path: b.image_path.clone(),
                message: format!(
                    "background view is {}×{} but {} is {}×{}",
                    t.width,
                    t.height,
                    f.image_path.display(),
                    v.width,
                    v.height
                ),
            });
        }
        if v.ids.is_none() {
            continue;
        }
        set.push(v);
        truths.push(t);
    }
    let mut se = vec![0.0f64; kinds.len()];
    let mut secs = vec![0.0f64; kinds.len()];
    let mut pixels = 0usize;
    for (k, &kind) in kinds.iter().enumerate() {
        progress(pairs.len() + k * pairs.len() / kinds.len(), 2 * pairs.len());
        let mut filled = set.clone();
        for v in &mut filled {
            v.inpaint = None;
            v.inpaint_depth = None;
            v.prior_confidence = None;
        }
        let t0 = std::time::Instant::now();
        crate::views::fill_priors(&mut filled, kind, true);
        secs[k] += t0.elapsed().as_secs_f64();
        for (v, t) in filled.iter().zip(&truths) {
            let mask: Vec<bool> = v
                .ids
                .as_ref()
                .expect("views with masks")
                .iter()
                .map(|&i| i != 0)
                .collect();
            let img = v.inpaint.as_ref().unwrap_or(&v.rgb);
            let (e, n) = squared_error(img, &t.rgb, 3, Some(&mask));
            se[k] += e;
            if k == 0 {
                pixels += n / 3;
            }
        }
    }
    progress(2 * pairs.len(), 2 * pairs.len());
    let scores = kinds
        .iter()
        .enumerate()
        .map(|(k, &prior)| PriorScore {
            prior,
            occluded_psnr: mse_to_psnr(se[k] / (3 * pixels.max(1)) as f64),
            seconds_per_view: secs[k] / pairs.len() as f64,
        })
        .collect();
    Ok(PriorReport {
        views: pairs.len(),
        occluded_pixels: pixels,
        scores,
    })
}
