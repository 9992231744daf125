//! Objects made after training where nobody drew masks (issue 41): a box around an object
//! in a scene trained as one background node decides, in any view, which pixels the
//! object owns — those whose surface lies in the box above the support it stands on —
//! and a colour-guided filter moves that mask onto the photograph's edges.

pub mod click;
mod folder;
pub mod guided;
mod job;
pub mod sam;
pub mod support;
pub mod targets;

pub use folder::{MaskProgress, MasksWritten, Owned, node_obb};
pub use job::{SPLIT_ITERS, SplitConfig, SplitEvent, SplitJob, SplitOutcome};
pub use support::{Support, around_boxes, facing_up, in_boxes, owned, support_levels};

use assist_core::{Camera, InstanceId, Obb};
use assist_data::image_io::ImageF32;

use crate::{RenderRequest, Result, Session};

/// A new object: its instance id in the masks and its box in world units.
#[derive(Debug, Clone)]
pub struct SplitBox {
    pub id: InstanceId,
    pub label: String,
    pub obb: Obb,
}

/// How masks are derived from boxes.
#[derive(Debug, Clone, Copy)]
pub struct MaskOptions {
    /// Surfaces less than this share of a box's height above its base belong to the
    /// support (the table the object stands on), not the object.
    pub support_band: f64,
    /// The guided filter's window radius as a share of the photograph's larger side (0 =
    /// no refinement), and its regulariser.
    pub refine_radius: f64,
    pub refine_eps: f32,
}

impl Default for MaskOptions {
    fn default() -> Self {
        MaskOptions {
            support_band: 0.04,
            refine_radius: 0.02,
            refine_eps: 1e-3,
        }
    }
}

/// Instance ids per pixel at the photograph's size from soft per-box masks at render
/// size (`rw` × `rh`): each mask resized, refined on `photo`'s edges, and a pixel given
/// the box whose refined mask is largest there when it is above ½.
pub fn refine(
    soft: &[Vec<f32>],
    ids: &[InstanceId],
    (rw, rh): (usize, usize),
    photo: &ImageF32,
    opts: &MaskOptions,
) -> Vec<u16> {
    let (w, h) = (photo.width as usize, photo.height as usize);
    let r = (opts.refine_radius * w.max(h) as f64).round() as usize;
    let mut best = vec![(0.5f32, 0u16); w * h];
    for (m, &id) in soft.iter().zip(ids) {
        let up = guided::resize(m, rw, rh, w, h);
        // Filtered only around the box's pixels: 3r + 1 beyond them every window of the
        // filter's two passes sees no mask, so the output there is 0 (never above ½).
        let Some(roi) = guided::Roi::around_nonzero(&up, w, h, 3 * r + 1) else {
            continue;
        };
        let q = if r > 0 {
            guided::guided_filter(
                &roi.crop(&photo.data, 3),
                &roi.crop(&up, 1),
                roi.w,
                roi.h,
                r,
                opts.refine_eps,
            )
        } else {
            roi.crop(&up, 1)
        };
        for (k, v) in q.into_iter().enumerate() {
            let b = &mut best[roi.index(k)];
            if v > b.0 {
                *b = (v, id);
            }
        }
    }
    best.into_iter().map(|(_, id)| id).collect()
}

/// One view to derive masks for: its camera and, to refine on, its photograph.
pub struct MaskView<'a> {
    pub camera: Camera,
    pub photo: Option<&'a ImageF32>,
}

/// What one rendered view shows in the boxes: its size and, per box, the pixels whose
/// surface lies in it with their heights ([`in_boxes`]).
#[derive(Debug, Clone)]
pub struct BoxView {
    pub width: usize,
    pub height: usize,
    pub seen: Vec<Vec<(u32, f32)>>,
    /// Per box, the heights of the surfaces around it ([`around_boxes`]).
    pub around: Vec<Vec<f32>>,
    /// Per pixel, whether its surface faces up ([`facing_up`]).
    pub flat: Vec<bool>,
    /// The scene's own instance ids at render size (its existing objects).
    pub panoptic: Vec<u16>,
}

impl BoxView {
    /// The instance ids the boxes own in this view, above their support `levels`,
    /// refined on `photo` when given (then at its size).
    pub fn mask(
        &self,
        boxes: &[SplitBox],
        levels: &[Support],
        photo: Option<&ImageF32>,
        opts: &MaskOptions,
    ) -> Vec<u16> {
        let soft = owned(&self.seen, levels, &self.flat, self.width * self.height);
        let ids: Vec<InstanceId> = boxes.iter().map(|b| b.id).collect();
        match photo {
            Some(p) => refine(&soft, &ids, (self.width, self.height), p, opts),
            None => hard(&soft, &ids, self.width * self.height),
        }
    }

    /// `ids` (a mask at `w` × `h`) with the scene's existing objects where no box
    /// claims the pixel (their rendered ids, nearest pixel).
    pub fn with_existing(&self, mut ids: Vec<u16>, w: usize, h: usize) -> Vec<u16> {
        for (i, id) in ids.iter_mut().enumerate() {
            if *id == 0 {
                let x = (i % w) * self.width / w.max(1);
                let y = (i / w) * self.height / h.max(1);
                *id = self.panoptic[y.min(self.height - 1) * self.width + x.min(self.width - 1)];
            }
        }
        ids
    }
}

/// The boxes' [`Obb`]s.
pub fn obbs(boxes: &[SplitBox]) -> Vec<Obb> {
    boxes.iter().map(|b| b.obb).collect()
}

impl Session {
    /// Renders `camera` at `render_size` (its own when `None`) and finds what it shows in
    /// each box.
    pub fn boxes_in_view(
        &self,
        camera: &Camera,
        boxes: &[SplitBox],
        render_size: Option<(u32, u32)>,
    ) -> Result<BoxView> {
        let cam = Self::sized(camera, render_size)?;
        let frame = self.render(&cam, &RenderRequest::default())?;
        Ok(BoxView {
            width: frame.width as usize,
            height: frame.height as usize,
            seen: in_boxes(&frame, &cam, &obbs(boxes), self.description().up),
            around: around_boxes(&frame, &cam, &obbs(boxes), self.description().up),
            flat: facing_up(&frame, &cam, self.description().up),
            panoptic: frame.panoptic.clone(),
        })
    }

    /// The instance ids the boxes own in each view: every view rendered at
    /// `render_size`, the support under each box found over all of them, each mask
    /// refined on its photograph when given. `on_view` is told as each view is rendered.
    pub fn box_masks(
        &self,
        views: &[MaskView],
        boxes: &[SplitBox],
        render_size: Option<(u32, u32)>,
        opts: &MaskOptions,
        mut on_view: impl FnMut(usize),
    ) -> Result<Vec<Vec<u16>>> {
        let mut seen = Vec::with_capacity(views.len());
        for (k, v) in views.iter().enumerate() {
            seen.push(self.boxes_in_view(&v.camera, boxes, render_size)?);
            on_view(k);
        }
        let levels = self.support_levels(boxes, &seen, opts);
        Ok(views
            .iter()
            .zip(&seen)
            .map(|(v, s)| s.mask(boxes, &levels, v.photo, opts))
            .collect())
    }

    /// The pixels of `camera`'s view (rendered at `render_size`) that the box `obb` would
    /// own, unrefined, with the support found in this view alone: (width, height, mask).
    pub fn box_mask_in_view(
        &self,
        camera: &Camera,
        obb: &Obb,
        render_size: Option<(u32, u32)>,
    ) -> Result<(usize, usize, Vec<bool>)> {
        let b = [SplitBox {
            id: 1,
            label: String::new(),
            obb: *obb,
        }];
        let view = self.boxes_in_view(camera, &b, render_size)?;
        let levels = self.support_levels(&b, std::slice::from_ref(&view), &MaskOptions::default());
        let ids = view.mask(&b, &levels, None, &MaskOptions::default());
        Ok((
            view.width,
            view.height,
            ids.iter().map(|&v| v == 1).collect(),
        ))
    }

    /// [`support_levels`] of `boxes` over the views `seen`, along the scene's up.
    pub fn support_levels(
        &self,
        boxes: &[SplitBox],
        seen: &[BoxView],
        opts: &MaskOptions,
    ) -> Vec<Support> {
        support_levels(
            &obbs(boxes),
            self.description().up,
            opts.support_band,
            seen.iter().map(|v| &v.seen),
            seen.iter().map(|v| &v.around),
        )
    }
}

/// Instance ids from unrefined masks (a later box wins where boxes overlap).
fn hard(soft: &[Vec<f32>], ids: &[InstanceId], n: usize) -> Vec<u16> {
    let mut out = vec![0u16; n];
    for (m, &id) in soft.iter().zip(ids) {
        for (o, &v) in out.iter_mut().zip(m) {
            if v > 0.5 {
                *o = id;
            }
        }
    }
    out
}

/// Intersection over union per instance id over many views' (derived, truth) masks,
/// each summed over the views: `(id, iou)` for each id in `ids`.
pub fn iou_per_id(pairs: &[(Vec<u16>, Vec<u16>)], ids: &[InstanceId]) -> Vec<(InstanceId, f64)> {
    ids.iter()
        .map(|&id| {
            let (mut inter, mut union) = (0u64, 0u64);
            for (a, b) in pairs {
                for (x, y) in a.iter().zip(b) {
                    let (p, q) = (*x == id, *y == id);
                    inter += u64::from(p && q);
                    union += u64::from(p || q);
                }
            }
            (
                id,
                if union == 0 {
                    1.0
                } else {
                    inter as f64 / union as f64
                },
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_sums_over_views() {
        let pairs = vec![
            (vec![1, 1, 0, 2], vec![1, 0, 0, 2]),
            (vec![0, 1], vec![1, 1]),
        ];
        let got = iou_per_id(&pairs, &[1, 2]);
        assert_eq!(got[0], (1, 2.0 / 4.0));
        assert_eq!(got[1], (2, 1.0));
    }
}
