//! Where an object ends and the surface it stands on begins: which surfaces a rendered
//! view shows in each box (with their heights above its base), which show around it,
//! which face up, and from all of them, per box, the height below which a surface
//! belongs to the support ([`Support`]).

use assist_core::{Camera, DVec3, Obb};

use crate::Frame;

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

/// Per pixel of `frame`, whether its surface faces up (its normal, from the depth map's
/// neighbours, within [`FLAT`] of `up`): a table or floor, never an object's side.
pub fn facing_up(frame: &Frame, camera: &Camera, up: DVec3) -> Vec<bool> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let cos = FLAT.to_radians().cos();
    camera
        .depth_normals(&frame.depth, w, h, |i| frame.opacity[i] >= 0.5)
        .into_iter()
        .map(|pn| pn.is_some_and(|(_, n)| n.dot(up).abs() >= cos))
        .collect()
}

/// How far from `up` a surface's normal may lean for it to face up, degrees (normals from
/// a rendered depth map are noisy; 30° / 40° / 50° measured in BENCHMARKS.md).
pub const FLAT: f64 = 40.0;

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

    /// Height of `p` above the box's base, when `p` lies around the box: beside it (its
    /// footprint grown [`AROUND`] times, the box's own left out), from a third of its
    /// height below its base to half its height above it.
    fn height_around(&self, b: &Obb, p: DVec3) -> Option<f64> {
        let local = b.rotation.transpose() * (p - b.center);
        let h = self.sign * local[self.axis] + b.half_size[self.axis];
        let side = (0..3).filter(|&k| k != self.axis);
        let inside = side.clone().all(|k| local[k].abs() <= b.half_size[k]);
        let near = side
            .clone()
            .all(|k| local[k].abs() <= AROUND * b.half_size[k]);
        (near && !inside && h >= -self.height / 3.0 && h <= self.height / 2.0).then_some(h)
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

/// How far around a box its support is looked for, in half-sizes from its centre.
pub const AROUND: f64 = 2.0;

/// Per box, the heights above its base of the surfaces seen around it
/// ([`Upright::height_around`]): the support it stands on, where it shows.
pub fn around_boxes(frame: &Frame, camera: &Camera, boxes: &[Obb], up: DVec3) -> Vec<Vec<f32>> {
    let ups: Vec<Upright> = boxes.iter().map(|b| Upright::new(b, up)).collect();
    let mut out = vec![Vec::new(); boxes.len()];
    for (_, p) in surface_points(frame, camera) {
        for (k, b) in boxes.iter().enumerate() {
            if let Some(h) = ups[k].height_around(b, p) {
                out[k].push(h as f32);
            }
        }
    }
    out
}

/// Height of `p` above the base of box `b` seen along `up`, when `p` lies in the box.
pub fn height_in(b: &Obb, up: DVec3, p: DVec3) -> Option<f64> {
    Upright::new(b, up).height_in(b, p)
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
    around: impl Iterator<Item = &'a Vec<Vec<f32>>>,
) -> Vec<Support> {
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
    let around: Vec<Vec<f32>> = {
        let mut a = vec![Vec::new(); boxes.len()];
        for view in around {
            for (k, hs) in view.iter().enumerate() {
                a[k].extend_from_slice(hs);
            }
        }
        a
    };
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
            let level = layer + band * heights[k];
            match support_around(&around[k], heights[k], bin[k]) {
                // The support's noise as seen around the object decides where it ends
                // (never below the band); the object's sides reach down to its layer.
                Some((s, sigma)) => Support {
                    cut: level.max(s + NOISE_SIGMAS * sigma),
                    base: layer,
                },
                None => Support {
                    cut: level,
                    base: level,
                },
            }
        })
        .collect()
}

/// Where a box's support ends, as heights above the box's base: every surface above
/// `cut` belongs to the object; above `base`, a surface that does not face up does too
/// (an object's side reaching down to the table, where the table's own noise would
/// claim a table-coloured ring of floor round it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Support {
    pub cut: f64,
    pub base: f64,
}

/// The support around a box, from the heights seen around it (beside the box, near its
/// base): its densest layer (bins of `bin`), then the median `s` and robust spread
/// `sigma` (1.4826 × the median absolute deviation) of the heights within a sixth of the
/// box's `height` of it. `None` where too few surfaces show around the box, or where they
/// are not one layer at its base ([`SUPPORT_AROUND`] of them near it, in the box's
/// lower or upper sixth): an object on a pole or in clutter has no support to measure.
fn support_around(hs: &[f32], height: f64, bin: f64) -> Option<(f64, f64)> {
    if hs.len() < MIN_AROUND {
        return None;
    }
    let lo = -height / 3.0;
    let n = ((height * 5.0 / 6.0) / bin).ceil().max(1.0) as usize;
    let mut count = vec![0usize; n];
    for &h in hs {
        let j = ((h as f64 - lo) / bin).floor();
        if j >= 0.0 && (j as usize) < n {
            count[j as usize] += 1;
        }
    }
    let (top, _) = count.iter().enumerate().max_by_key(|(_, c)| **c)?;
    let peak = lo + (top as f64 + 0.5) * bin;
    let mut near: Vec<f64> = hs
        .iter()
        .map(|&h| h as f64)
        .filter(|h| (h - peak).abs() <= height / 6.0)
        .collect();
    if near.len() < MIN_AROUND || (near.len() as f64) < SUPPORT_AROUND * hs.len() as f64 {
        return None;
    }
    near.sort_by(f64::total_cmp);
    let s = near[near.len() / 2];
    if s.abs() > height / 6.0 {
        return None;
    }
    let mut dev: Vec<f64> = near.iter().map(|h| (h - s).abs()).collect();
    dev.sort_by(f64::total_cmp);
    Some((s, 1.4826 * dev[dev.len() / 2]))
}

/// The share of the surfaces around a box that must lie in one layer for it to be the
/// box's support: tables and floors put nearly all there, an object on a pole in clutter
/// about half (docs/history.md, session 32).
pub const SUPPORT_AROUND: f64 = 0.8;

/// A support's surface reaches this many robust standard deviations above its median.
pub const NOISE_SIGMAS: f64 = 3.0;

/// Surfaces that must show around a box for its support to be measured there.
const MIN_AROUND: usize = 30;

/// The share of a box's surface points one thin layer must hold to be its support.
pub const SUPPORT_SHARE: f64 = 0.1;

/// Per box, a mask of `n` pixels: 1 where the surface seen in the box lies at or above
/// the box's support level.
pub fn owned(
    seen: &[Vec<(u32, f32)>],
    levels: &[Support],
    flat: &[bool],
    n: usize,
) -> Vec<Vec<f32>> {
    seen.iter()
        .zip(levels)
        .map(|(pts, level)| {
            let mut m = vec![0f32; n];
            for &(i, h) in pts {
                let h = h as f64;
                let up = flat.get(i as usize).copied().unwrap_or(true);
                if h >= level.cut || (h >= level.base && !up) {
                    m[i as usize] = 1.0;
                }
            }
            m
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
            unseen: vec![false; w * h],
            background: Vec::new(),
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
        let around = around_boxes(&frame, &cam, &[b], DVec3::Z);
        let levels = support_levels(&[b], DVec3::Z, 0.04, [seen.clone()].iter(), [around].iter());
        // The table shows 0.07 above the box's base: cut 0.02 above its layer.
        assert!((levels[0].cut - 0.09).abs() < 0.011, "{levels:?}");
        // Seen from straight above, the table and the cube's top face up.
        let flat = facing_up(&frame, &cam, DVec3::Z);
        assert!(flat[5 * w + 5] && flat[20 * w + 20]);
        let m = &owned(&seen, &levels, &flat, w * h)[0];
        for y in 0..h {
            for x in 0..w {
                let p = cam.unproject(x as f64 + 0.5, y as f64 + 0.5, 1.6).unwrap();
                assert_eq!(m[y * w + x] == 1.0, cube(p), "({x}, {y})");
            }
        }
        // A pixel an existing object wins is not owned.
        frame.panoptic[20 * w + 20] = 3;
        let seen = in_boxes(&frame, &cam, &[b], DVec3::Z);
        assert_eq!(owned(&seen, &levels, &flat, w * h)[0][20 * w + 20], 0.0);
    }

    #[test]
    fn a_noisy_table_is_cut_at_its_noise_but_an_objects_sides_reach_down_to_it() {
        // A box 1 unit tall whose base is the table; the table's surface is rendered
        // with noise up to ±0.05 around it and in the box; the object's side (pixels
        // 1000..1100, not facing up) reaches down to the table.
        let b = Obb::new(DVec3::new(0.0, 0.0, 0.5), DVec3::ONE, DMat3::IDENTITY);
        let noise = |i: usize| 0.05 * (((i * 7919) % 101) as f32 / 50.0 - 1.0);
        let mut seen = vec![];
        let mut flat = vec![false; 1200];
        for i in 0..1000 {
            seen.push((i as u32, noise(i).max(0.0)));
            flat[i] = true;
        }
        for i in 1000..1100 {
            seen.push((i as u32, (i - 1000) as f32 / 100.0));
        }
        let around: Vec<f32> = (0..2000).map(noise).collect();
        let seen = vec![seen];
        let levels = support_levels(
            &[b],
            DVec3::Z,
            0.04,
            [seen.clone()].iter(),
            [vec![around.clone()]].iter(),
        );
        // The cut lies above the table's noise (not at 4% of the height), and the side
        // keeps all but its lowest points.
        assert!(levels[0].cut > 0.05 && levels[0].cut < 0.15, "{levels:?}");
        let m = &owned(&seen, &levels, &flat, 1200)[0];
        assert_eq!(m[..1000].iter().sum::<f32>(), 0.0);
        assert!(m[1000..1100].iter().sum::<f32>() >= 95.0);
        // Around a box on a pole in clutter (no one layer at its base), the band above
        // the layer in the box (0.02) decides.
        let clutter: Vec<f32> = (0..2000).map(|i| (i % 50) as f32 / 100.0 - 0.3).collect();
        let levels = support_levels(
            &[b],
            DVec3::Z,
            0.04,
            [seen.clone()].iter(),
            [vec![clutter]].iter(),
        );
        assert_eq!(levels[0].cut, levels[0].base);
        assert!((levels[0].cut - 0.06).abs() < 1e-9, "{levels:?}");
    }
}
