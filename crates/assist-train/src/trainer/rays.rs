//! Drawing a batch of training rays with their targets.

use assist_core::Rng;
use rayon::prelude::*;

use super::Trainer;
use crate::views::View;

/// What each ray is supervised with.
#[derive(Debug, Clone, Copy)]
pub(super) struct Target {
    pub(super) rgb: [f32; 3],
    /// Node index of the object this ray first hits (`u32::MAX`: none).
    pub(super) mask_node: u32,
    /// Whether the view has instance masks (object losses apply).
    pub(super) masked: bool,
    pub(super) inpaint: Option<[f32; 3]>,
    /// Prior depth as distance along the ray, in units of the scene extent.
    pub(super) depth: Option<f32>,
    /// Weight of the prior terms (the prior's confidence at this pixel).
    pub(super) prior_weight: f32,
    /// Weight of the prior's colour term (the confidence, or less near objects' shadows).
    pub(super) rgb_weight: f32,
    /// The dataset's depth as distance along the ray, in units of the scene extent: the
    /// first surface the ray meets (`None`: no depth map, or none at this pixel).
    pub(super) surface: Option<f32>,
    /// The pixel's index in its view.
    pub(super) pixel: u32,
    /// The ray's weight in every term (see [`super::error_map`]; 1 for a uniform draw).
    pub(super) weight: f32,
}

/// A pixel `(view, index)` drawn uniformly over the pixels to train on: one a `mask_path`
/// excludes is drawn again, 16 times at most (`None` then: the ray is left out).
fn draw_pixel(views: &[View], total: u64, rng: &mut Rng) -> Option<(usize, usize)> {
    for _ in 0..16 {
        let mut p = rng.below(total) as usize;
        let mut vi = 0;
        while p >= views[vi].width * views[vi].height {
            p -= views[vi].width * views[vi].height;
            vi += 1;
        }
        if views[vi].valid.as_ref().is_none_or(|ok| ok[p]) {
            return Some((vi, p));
        }
    }
    None
}

impl Trainer {
    pub(super) fn draw_rays(&mut self) {
        let n = self.rays_per_batch;
        let seed = self.opts.seed ^ (self.iteration as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let views = &self.views;
        let total = self.pixel_count as u64;
        let node_of_id = &self.node_of_id;
        let extent = self.extent;
        let objects = &self.object_pixels;
        let object_extra = self.object_rays.extra;
        let poses = self.poses.as_ref();
        let map = &self.error_map;
        let drawn: Vec<Option<(assist_core::Ray, u32, u32, Target)>> = (0..n)
            .into_par_iter()
            .map(|r| {
                let mut rng = Rng::stream(seed, r as u64);
                let (vi, p, weight) = if !objects.is_empty() && rng.f64() < object_extra {
                    let (vi, p) = objects[rng.below(objects.len() as u64) as usize];
                    (vi as usize, p as usize, 1.0)
                } else if map.is_on() {
                    let (vi, p) = if rng.f64() < map.share {
                        map.draw(views, &mut rng)?
                    } else {
                        draw_pixel(views, total, &mut rng)?
                    };
                    (vi, p, map.weight(views, vi, p))
                } else {
                    let (vi, p) = draw_pixel(views, total, &mut rng)?;
                    (vi, p, 1.0)
                };
                let v = &views[vi];
                let (i, j) = ((p % v.width) as u32, (p / v.width) as u32);
                let mut ray = v.camera.pixel_ray(i, j)?;
                if let Some(p) = poses {
                    p.apply(vi, &mut ray);
                }
                let rgb = [v.rgb[3 * p], v.rgb[3 * p + 1], v.rgb[3 * p + 2]];
                let (masked, mask_node) = match &v.ids {
                    Some(ids) => (true, node_of_id.get(&ids[p]).copied().unwrap_or(u32::MAX)),
                    None => (false, u32::MAX),
                };
                let inpaint = v
                    .inpaint
                    .as_ref()
                    .map(|im| [im[3 * p], im[3 * p + 1], im[3 * p + 2]]);
                let cos = ray.dir.dot(v.camera.pose.forward()) as f32;
                let depth = v
                    .inpaint_depth
                    .as_ref()
                    .map(|d| d[p])
                    .filter(|&z| z > 0.0 && cos > 1e-3)
                    .map(|z| z / cos / extent);
                let surface = v
                    .depth
                    .as_ref()
                    .map(|d| d[p])
                    .filter(|&z| z > 0.0 && z.is_finite() && cos > 1e-3)
                    .map(|z| z / cos / extent);
                let prior_weight = v.prior_confidence.as_ref().map_or(1.0, |c| c[p]);
                let rgb_weight = v.prior_rgb_weight.as_ref().map_or(prior_weight, |c| c[p]);
                Some((
                    ray,
                    v.image_index,
                    vi as u32,
                    Target {
                        rgb,
                        mask_node,
                        masked,
                        inpaint,
                        depth,
                        prior_weight,
                        rgb_weight,
                        surface,
                        pixel: p as u32,
                        weight,
                    },
                ))
            })
            .collect();
        self.rays.clear();
        self.rays.near = self.scene.scene.near as f32;
        self.targets.clear();
        self.ray_views.clear();
        for (ray, img, vi, t) in drawn.into_iter().flatten() {
            self.rays.push(&ray, img);
            self.targets.push(t);
            self.ray_views.push(vi);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_a_mask_excludes_are_never_drawn() {
        let view = |valid: Option<Vec<bool>>| View {
            valid,
            ..View::blank(4, 2)
        };
        // View 0: only pixel 5 is valid; view 1: all; view 2: none.
        let mut only5 = vec![false; 8];
        only5[5] = true;
        let views = [view(Some(only5)), view(None), view(Some(vec![false; 8]))];
        let mut rng = Rng::new(2);
        let mut seen = std::collections::BTreeSet::new();
        let mut left_out = 0;
        for _ in 0..4000 {
            match draw_pixel(&views, 24, &mut rng) {
                Some((vi, p)) => {
                    assert!(vi != 2 && (vi != 0 || p == 5), "drew ({vi}, {p})");
                    seen.insert((vi, p));
                }
                None => left_out += 1,
            }
        }
        // Every valid pixel is drawn; a ray is rarely left out (P = (15/24)^16).
        assert_eq!(seen.len(), 9);
        assert!(left_out < 10, "{left_out}");
    }

    #[test]
    fn the_extra_draw_makes_up_the_objects_share_and_no_more() {
        use crate::trainer::object_ray_draw;
        for (least, share) in [(0.33, 0.12), (0.33, 0.0), (0.5, 0.3), (1.0, 0.2)] {
            let o = object_ray_draw(least, share);
            // The draw's share on objects: the extra rays, and the uniform draw's part.
            let on = o.extra + (1.0 - o.extra) * share;
            assert!((on - least).abs() < 1e-12, "{least} {share}: {o:?}");
        }
        // Objects that already fill the share (a walk-around's) take nothing extra.
        assert_eq!(object_ray_draw(0.33, 0.47).extra, 0.0);
        assert_eq!(object_ray_draw(0.33, 0.33).extra, 0.0);
        assert_eq!(object_ray_draw(0.0, 0.1).extra, 0.0);
        assert_eq!(object_ray_draw(0.5, 1.0).extra, 0.0);
    }
}
