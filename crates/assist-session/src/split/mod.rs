//! Objects made after training where nobody drew masks (issue 41): a box around an object
//! in a scene trained as one background node decides, in any view, which pixels the
//! object owns — those whose surface lies in the box above the support it stands on —
//! and a colour-guided filter moves that mask onto the photograph's edges.

pub mod click;
mod folder;
pub mod guided;
mod job;
pub mod targets;

pub use folder::{MaskProgress, MasksWritten, Owned, node_obb};
pub use job::{SPLIT_ITERS, SplitConfig, SplitEvent, SplitJob, SplitOutcome};

use assist_core::{Camera, DVec3, InstanceId, Obb};
use assist_data::image_io::ImageF32;

use crate::{Frame, RenderRequest, Result, Session};

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

/// The world points of `frame`'s pixels (rendered from `camera`) that see a surface of
/// the background: `(pixel, point)`. Pixels an existing object wins, or that see nearly
/// nothing, are left out.
fn surface_points<'a>(
    frame: &'a Frame,
    camera: &'a Camera,
) -> impl Iterator<Item = (usize, DVec3)> + 'a {
    let w = frame.width as usize;
    (0..frame.depth.len()).filter_map(move |i| {
        if frame.opacity[i] < 0.5 || frame.panoptic[i] != 0 || frame.depth[i] <= 0.0 {
            return None;
        }
        let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
        camera
            .unproject(x, y, frame.depth[i] as f64)
            .map(|p| (i, p))
    })
}

/// A box seen along `up`: its local axis nearest `up`, the sign that points it up, and
/// its height.
#[derive(Debug, Clone, Copy)]
struct Upright {
    axis: usize,
    sign: f64,
    height: f64,
}

impl Upright {
    fn new(b: &Obb, up: DVec3) -> Self {
        let dots = [0, 1, 2].map(|k| b.rotation.col(k).dot(up));
        let axis = (0..3)
            .max_by(|&a, &c| dots[a].abs().total_cmp(&dots[c].abs()))
            .unwrap_or(2);
        Upright {
            axis,
            sign: if dots[axis] < 0.0 { -1.0 } else { 1.0 },
            height: 2.0 * b.half_size[axis],
        }
    }

    /// Height of `p` above the box's base, when `p` lies in the box.
    fn height_in(&self, b: &Obb, p: DVec3) -> Option<f64> {
        let local = b.rotation.transpose() * (p - b.center);
        local
            .abs()
            .cmple(b.half_size)
            .all()
            .then(|| self.sign * local[self.axis] + b.half_size[self.axis])
    }
}

/// Per box, the pixels of `frame` (rendered from `camera`) whose surface lies in the box,
/// with its height above the box's base.
pub fn in_boxes(frame: &Frame, camera: &Camera, boxes: &[Obb], up: DVec3) -> Vec<Vec<(u32, f32)>> {
    let ups: Vec<Upright> = boxes.iter().map(|b| Upright::new(b, up)).collect();
    let mut out = vec![Vec::new(); boxes.len()];
    for (i, p) in surface_points(frame, camera) {
        for (k, b) in boxes.iter().enumerate() {
            if let Some(h) = ups[k].height_in(b, p) {
                out[k].push((i as u32, h as f32));
            }
        }
    }
    out
}

/// Per box, the height above its base below which surfaces belong to the support (the
/// table the object stands on), from the surfaces seen in it over many views: a support
/// shows as one thin layer in the box's lower third holding many of the points (a loose
/// box reaching below the table shows it above the base); the cut is `band` (a share
/// of the box's height) above that layer, or above the base where there is none.
pub fn support_levels<'a>(
    boxes: &[Obb],
    up: DVec3,
    band: f64,
    seen: impl Iterator<Item = &'a Vec<Vec<(u32, f32)>>>,
) -> Vec<f64> {
    let heights: Vec<f64> = boxes.iter().map(|b| Upright::new(b, up).height).collect();
    let bin: Vec<f64> = heights.iter().map(|h| (band * h / 2.0).max(1e-9)).collect();
    let bins: Vec<usize> = heights
        .iter()
        .zip(&bin)
        .map(|(h, b)| ((h / 3.0) / b).ceil().max(1.0) as usize)
        .collect();
    let mut count: Vec<Vec<usize>> = bins.iter().map(|&n| vec![0; n]).collect();
    let mut total = vec![0usize; boxes.len()];
    for view in seen {
        for (k, pts) in view.iter().enumerate() {
            total[k] += pts.len();
            for &(_, h) in pts {
                let j = (h as f64 / bin[k]).floor();
                if j >= 0.0 && (j as usize) < bins[k] {
                    count[k][j as usize] += 1;
                }
            }
        }
    }
    (0..boxes.len())
        .map(|k| {
            let (top, n) = count[k]
                .iter()
                .enumerate()
                .max_by_key(|(_, n)| **n)
                .map(|(j, n)| (j, *n))
                .unwrap_or((0, 0));
            let layer = if n > 0 && n as f64 >= SUPPORT_SHARE * total[k] as f64 {
                (top + 1) as f64 * bin[k]
            } else {
                0.0
            };
            layer + band * heights[k]
        })
        .collect()
}

/// The share of a box's surface points one thin layer must hold to be its support.
pub const SUPPORT_SHARE: f64 = 0.1;

/// Per box, a mask of `n` pixels: 1 where the surface seen in the box lies at or above
/// the box's support level.
pub fn owned(seen: &[Vec<(u32, f32)>], levels: &[f64], n: usize) -> Vec<Vec<f32>> {
    seen.iter()
        .zip(levels)
        .map(|(pts, &level)| {
            let mut m = vec![0f32; n];
            for &(i, h) in pts {
                if h as f64 >= level {
                    m[i as usize] = 1.0;
                }
            }
            m
        })
        .collect()
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
        let q = if r > 0 {
            guided::guided_filter(&photo.data, &up, w, h, r, opts.refine_eps)
        } else {
            up
        };
        for (b, v) in best.iter_mut().zip(q) {
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
    /// The scene's own instance ids at render size (its existing objects).
    pub panoptic: Vec<u16>,
}

impl BoxView {
    /// The instance ids the boxes own in this view, above their support `levels`,
    /// refined on `photo` when given (then at its size).
    pub fn mask(
        &self,
        boxes: &[SplitBox],
        levels: &[f64],
        photo: Option<&ImageF32>,
        opts: &MaskOptions,
    ) -> Vec<u16> {
        let soft = owned(&self.seen, levels, self.width * self.height);
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
    ) -> Vec<f64> {
        support_levels(
            &obbs(boxes),
            self.description().up,
            opts.support_band,
            seen.iter().map(|v| &v.seen),
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
    use assist_core::{DMat3, Intrinsics, Pose};

    /// A camera 2 units above the origin looking straight down (+y of the image is −y
    /// of the world), 40 × 40 pixels.
    fn down_camera() -> Camera {
        let pose = Pose::look_at(DVec3::new(0.0, 0.0, 2.0), DVec3::ZERO, DVec3::Y).unwrap();
        Camera {
            intrinsics: Intrinsics::from_fov_x(40, 40, 60f64.to_radians()),
            pose,
        }
    }

    #[test]
    fn a_box_owns_what_stands_in_it_but_not_the_table_under_it() {
        // Depth: the table (z = 0) everywhere, a 0.4-unit cube standing on it at the
        // centre (its top at z = 0.4, 1.6 from the camera).
        let cam = down_camera();
        let (w, h) = (40usize, 40usize);
        let mut frame = Frame {
            width: 40,
            height: 40,
            rgb: vec![0.5; 3 * w * h],
            depth: vec![2.0; w * h],
            opacity: vec![1.0; w * h],
            panoptic: vec![0; w * h],
            layers: Vec::new(),
        };
        let cube = |p: DVec3| p.x.abs() < 0.2 && p.y.abs() < 0.2;
        for y in 0..h {
            for x in 0..w {
                let p = cam.unproject(x as f64 + 0.5, y as f64 + 0.5, 1.6).unwrap();
                if cube(p) {
                    frame.depth[y * w + x] = 1.6;
                }
            }
        }
        // A loose box: wider than the cube and reaching below the table top.
        let b = Obb::new(
            DVec3::new(0.0, 0.0, 0.18),
            DVec3::new(0.7, 0.7, 0.5),
            DMat3::IDENTITY,
        );
        let seen = in_boxes(&frame, &cam, &[b], DVec3::Z);
        let levels = support_levels(&[b], DVec3::Z, 0.04, [seen.clone()].iter());
        // The table shows 0.07 above the box's base: cut 0.02 above its layer.
        assert!((levels[0] - 0.09).abs() < 0.011, "{levels:?}");
        let m = &owned(&seen, &levels, w * h)[0];
        for y in 0..h {
            for x in 0..w {
                let p = cam.unproject(x as f64 + 0.5, y as f64 + 0.5, 1.6).unwrap();
                assert_eq!(m[y * w + x] == 1.0, cube(p), "({x}, {y})");
            }
        }
        // A pixel an existing object wins is not owned.
        frame.panoptic[20 * w + 20] = 3;
        let seen = in_boxes(&frame, &cam, &[b], DVec3::Z);
        assert_eq!(owned(&seen, &levels, w * h)[0][20 * w + 20], 0.0);
    }

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
