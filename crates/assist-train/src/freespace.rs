//! Free-space carving from depth maps: the space between a camera and the surface its
//! depth map sees there is empty, so occupancy-grid cells that rays cross freely are
//! marked empty ([`assist_field::OccupancyGrid::empty`]) before training starts. Without
//! it a depth-supervised background spends its first minutes filling the room with fog
//! (the demo's background marched ~215 samples per ray through 25–30% occupied cells).
//!
//! A cell is carved when at least [`MIN_FREE_RAYS`] rays cross it and no ray ends in it
//! with this node's instance id (a surface the node must keep; for the background also
//! its prior depth behind objects). With dense depth maps the background's cells no ray
//! reaches are carved too: nothing can train them. Rays stop
//! [`SURFACE_MARGIN`] (relative) and one and a half cells short of the surface, so noisy
//! depth and mixed edge pixels never carve a surface. Contracted nodes are not carved
//! (captures with depth get box backgrounds).

use assist_core::{DVec3, NodeSpace, SceneNode};
use assist_scene::NeuralScene;
use rayon::prelude::*;
use std::sync::Arc;

use crate::views::View;

/// Rays that must cross a cell freely before it is carved.
pub const MIN_FREE_RAYS: u16 = 2;
/// Rays stop this fraction of the surface distance short of it.
pub const SURFACE_MARGIN: f64 = 0.03;
/// At most about this many rays are marched through the free space (every k-th pixel in
/// each direction); every pixel's end point is counted.
const MAX_RAYS: usize = 2_000_000;

/// Cells carved per node (field key, carved fraction of its grid).
pub type CarveStats = Vec<(String, f64)>;

/// Carves every box node of `scene` whose grid the depth maps of `views` see (all views
/// need depth). Replicas share a field and are carved once, through their first node.
pub fn carve_scene(scene: &mut NeuralScene, views: &[View]) -> CarveStats {
    if views.is_empty() || views.iter().any(|v| v.depth.is_none()) {
        return Vec::new();
    }
    let mut stats = Vec::new();
    let mut done = std::collections::BTreeSet::new();
    let objects: Vec<SceneNode> = scene.scene.objects().cloned().collect();
    for node in &scene.scene.nodes {
        if node.space != NodeSpace::Box || !done.insert(node.field.clone()) {
            continue;
        }
        let Some(nf) = scene.fields.get_mut(&node.field) else {
            continue;
        };
        let res = nf.occupancy.res;
        let (free, hit) = ray_counts(node, res, views);
        // Only a background with dense depth carves what no ray reaches (see `classify`).
        let reached = if node.is_background() && dense_depth(views) {
            surface_cells(node, res, views)
        } else {
            vec![false; free.len()]
        };
        let (mut empty, kept) = classify(node, views, &free, &hit, &reached);
        if node.is_background() && dense_depth(views) {
            spare_under_objects(node, res, &objects, &free, &mut empty);
        }
        let frac = empty.iter().filter(|&&e| e).count() as f64 / empty.len().max(1) as f64;
        let occ = &mut Arc::make_mut(nf).occupancy;
        occ.set_empty(&empty);
        occ.set_kept(&kept);
        stats.push((node.field.clone(), frac));
    }
    stats
}

/// The cells of `node`'s `res`³ grid the depth maps show to be empty.
#[cfg(test)]
fn free_cells(node: &SceneNode, res: u32, views: &[View]) -> Vec<bool> {
    carve_cells(node, res, views).0
}

/// The empty and kept cells of `node`'s grid (without sparing what objects stand on).
#[cfg(test)]
fn carve_cells(node: &SceneNode, res: u32, views: &[View]) -> (Vec<bool>, Vec<bool>) {
    let (free, hit) = ray_counts(node, res, views);
    classify(node, views, &free, &hit, &surface_cells(node, res, views))
}

/// The cells of a `res`³ grid the depth maps show to be empty, and those where at least
/// [`MIN_FREE_RAYS`] rays end on this node's surface (kept occupied in training, whatever
/// a random point in them says), from the ray counts of [`ray_counts`] and the cells the
/// depth maps' surfaces pass through ([`surface_cells`]).
fn classify(
    node: &SceneNode,
    views: &[View],
    free: &[u16],
    hit: &[u16],
    reached: &[bool],
) -> (Vec<bool>, Vec<bool>) {
    // With dense depth maps, a background cell no ray reaches (behind every surface, or
    // outside every view) can never be trained: its initial haze would only float in front
    // of a novel view (the demo's test views had fog 0.1–0.7 m from the camera). A cell a
    // seen surface passes through is reached, even where no pixel's end point fell in it.
    let unobserved_too = node.is_background() && dense_depth(views);
    let empty = free
        .iter()
        .zip(hit)
        .zip(reached)
        .map(|((&f, &h), &s)| h == 0 && (f >= MIN_FREE_RAYS || (unobserved_too && f == 0 && !s)))
        .collect();
    let kept = hit.iter().map(|&h| h >= MIN_FREE_RAYS).collect();
    (empty, kept)
}

/// Gives back the background cells inside an object's box (grown by one background
/// cell) that were carved only for being unobserved: what an object stands on is hidden
/// by it in every view, and carved it renders as a hole once the object moves (desk's
/// table under the mug rendered black where the mug had stood). Their colour and depth
/// then come from the background prior. Cells rays cross freely stay carved.
fn spare_under_objects(
    node: &SceneNode,
    res: u32,
    objects: &[SceneNode],
    free: &[u16],
    empty: &mut [bool],
) {
    let r = res as usize;
    let size = node.half_size * 2.0;
    let cell_world = (node.world_from_local.scale * (size / res as f64)).max_element();
    for (c, e) in empty.iter_mut().enumerate() {
        if !*e || free[c] > 0 {
            continue;
        }
        let i = DVec3::new((c % r) as f64, ((c / r) % r) as f64, (c / (r * r)) as f64);
        let local = ((i + 0.5) / res as f64 - 0.5) * size;
        let p = node.world_from_local.transform_point(local);
        let inside = objects.iter().any(|o| {
            let l = o.world_from_local.local_from_world_point(p);
            let grow = cell_world / o.world_from_local.scale.min_element();
            (l.abs() - o.half_size).max_element() <= grow
        });
        if inside {
            *e = false;
        }
    }
}

/// Per cell of `node`'s `res`³ grid: how many rays cross it freely, and how many end in it
/// on this node's surface.
pub fn ray_counts(node: &SceneNode, res: u32, views: &[View]) -> (Vec<u16>, Vec<u16>) {
    ray_counts_marching(node, res, views, MAX_RAYS)
}

/// [`ray_counts`], marching at most about `max_rays` rays.
fn ray_counts_marching(
    node: &SceneNode,
    res: u32,
    views: &[View],
    max_rays: usize,
) -> (Vec<u16>, Vec<u16>) {
    let r = res as usize;
    let n = r * r * r;
    let pixels: usize = views.iter().map(|v| v.width * v.height).sum();
    let stride = ((pixels as f64 / max_rays.max(1) as f64).sqrt().ceil() as usize).max(1);
    let size = node.half_size * 2.0;
    // One pair of counters per thread's share of the views (a 128³ grid is 4 MB each).
    let share = views.len().div_ceil(rayon::current_num_threads().max(1));
    let (free, hit) = views
        .par_chunks(share.max(1))
        .map(|chunk| {
            let (mut free, mut hit) = (vec![0u16; n], vec![0u16; n]);
            for v in chunk {
                cast_view(node, v, res, size, stride, &mut free, &mut hit);
            }
            (free, hit)
        })
        .reduce(
            || (vec![0u16; n], vec![0u16; n]),
            |(mut fa, mut ha), (fb, hb)| {
                for (a, b) in fa.iter_mut().zip(&fb) {
                    *a = a.saturating_add(*b);
                }
                for (a, b) in ha.iter_mut().zip(&hb) {
                    *a = a.saturating_add(*b);
                }
                (fa, ha)
            },
        );
    (free, hit)
}

/// Whether every view has depth at (nearly) every pixel: depth sensors leave holes on
/// dark, shiny or distant surfaces, and a surface seen only through holes has no hit.
fn dense_depth(views: &[View]) -> bool {
    views.iter().all(|v| {
        v.depth.as_ref().is_some_and(|d| {
            let missing = d.iter().filter(|&&z| z <= 0.0).count();
            missing * 1000 <= d.len()
        })
    })
}

/// Adjacent pixels whose surface depths differ by at most this fraction are taken to see
/// one surface between them (more is a depth edge, or a surface too oblique to bridge).
const SURFACE_GAP: f64 = 0.1;

/// The cells of `node`'s `res`³ grid that the depth maps' surfaces pass through: each pair
/// of adjacent pixels that see this node's surface (its prior depth behind objects, for the
/// background) at nearly one depth spans a piece of it, and so does each quad of four such
/// pixels (a bilinear patch), sampled at half a cell. At a
/// distance or at a grazing angle a pixel covers several cells, and its end point marks
/// only one: a wall seen by a few views far away had cells between the end points that
/// counted as never seen and were carved (the demo's wall rendered speckled with holes).
pub fn surface_cells(node: &SceneNode, res: u32, views: &[View]) -> Vec<bool> {
    let n = (res as usize).pow(3);
    views
        .par_iter()
        .fold(
            || vec![false; n],
            |mut reached, v| {
                mark_surface(node, v, res, &mut reached);
                reached
            },
        )
        .reduce(
            || vec![false; n],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x |= y;
                }
                a
            },
        )
}

/// [`surface_cells`] for one view.
fn mark_surface(node: &SceneNode, v: &View, res: u32, reached: &mut [bool]) {
    let Some(depth) = v.depth.as_ref() else {
        return;
    };
    let size = node.half_size * 2.0;
    let step = 0.5 * (size / res as f64).min_element();
    let forward = v.camera.pose.forward();
    // Each pixel's surface point in the node's local frame, with its z-depth.
    let points: Vec<Option<(DVec3, f64)>> = (0..v.width * v.height)
        .map(|p| {
            let z = surface_depth(node, v, depth, p)?;
            let ray = v
                .camera
                .pixel_ray((p % v.width) as u32, (p / v.width) as u32)?;
            let cos = ray.dir.dot(forward);
            (cos > 1e-6).then(|| {
                let w = ray.origin + ray.dir * (z / cos);
                (node.world_from_local.local_from_world_point(w), z)
            })
        })
        .collect();
    let at = |i: usize, j: usize| {
        (i < v.width && j < v.height)
            .then(|| points[j * v.width + i])
            .flatten()
    };
    let one_surface = |zs: &[f64]| {
        let (lo, hi) = zs
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &z| (l.min(z), h.max(z)));
        hi - lo <= SURFACE_GAP * lo
    };
    let mut mark = |p: DVec3| {
        if let Some(c) = cell_of(p, size, res) {
            reached[c] = true;
        }
    };
    for j in 0..v.height {
        for i in 0..v.width {
            let Some((a, za)) = at(i, j) else {
                continue;
            };
            let (b, c, d) = (at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            // The four pixels' quad as a bilinear patch where they see one surface;
            // else the edges to the right and below that do.
            if let (Some((b, zb)), Some((c, zc)), Some((d, zd))) = (b, c, d)
                && one_surface(&[za, zb, zc, zd])
            {
                let nu = (b - a).length().max((d - c).length()) / step;
                let nv = (c - a).length().max((d - b).length()) / step;
                let (nu, nv) = (nu.ceil().max(1.0) as usize, nv.ceil().max(1.0) as usize);
                for kv in 0..=nv {
                    let fv = kv as f64 / nv as f64;
                    let (l, r) = (a + (c - a) * fv, b + (d - b) * fv);
                    for ku in 0..=nu {
                        mark(l + (r - l) * (ku as f64 / nu as f64));
                    }
                }
                continue;
            }
            for (b, zb) in [b, c].into_iter().flatten() {
                if !one_surface(&[za, zb]) {
                    continue;
                }
                let steps = ((b - a).length() / step).ceil().max(1.0) as usize;
                for k in 0..=steps {
                    mark(a + (b - a) * (k as f64 / steps as f64));
                }
            }
        }
    }
}

/// The z-depth of `node`'s surface at pixel `p`: the depth map's where the pixel sees the
/// node, and for the background the prior's depth where an object hides it.
fn surface_depth(node: &SceneNode, v: &View, depth: &[f32], p: usize) -> Option<f64> {
    let z = depth[p] as f64;
    if z <= 0.0 {
        return None;
    }
    let id = v.ids.as_ref().map_or(0, |ids| ids[p]);
    if id == node.id {
        return Some(z);
    }
    let zb = v.inpaint_depth.as_ref().map(|b| b[p] as f64)?;
    (node.is_background() && zb > z).then_some(zb)
}

/// The cell of a `res`³ grid over a box of `size` (centred on the origin) holding local
/// point `p`; `None` outside the box.
fn cell_of(p: DVec3, size: DVec3, res: u32) -> Option<usize> {
    let r = res as usize;
    let u = p / size + 0.5;
    if u.min_element() < 0.0 || u.max_element() >= 1.0 {
        return None;
    }
    let i = (u * res as f64).as_uvec3();
    let [x, y, z] = [i.x as usize, i.y as usize, i.z as usize].map(|a| a.min(r - 1));
    Some(x + r * (y + r * z))
}

fn cast_view(
    node: &SceneNode,
    v: &View,
    res: u32,
    size: DVec3,
    stride: usize,
    free: &mut [u16],
    hit: &mut [u16],
) {
    let Some(depth) = v.depth.as_ref() else {
        return;
    };
    let half = node.half_size;
    let cell = size / res as f64;
    let step = 0.5 * cell.min_element();
    let margin = 1.5 * cell.max_element();
    let forward = v.camera.pose.forward();
    let to_cell = |p: DVec3| cell_of(p, size, res);
    // Every pixel's end point counts (a surface seen at the edge of one or two views would
    // otherwise have no hit between the cast rays, and with dense depth be carved as never
    // seen: desk's wall near the top of the views rendered as holes); the space in front
    // of the surfaces is marched along every `stride`-th ray in each direction.
    for j in 0..v.height {
        for i in 0..v.width {
            let cast = j % stride == 0 && i % stride == 0;
            let p = j * v.width + i;
            let z = depth[p] as f64;
            if z <= 0.0 {
                continue;
            }
            let Some(ray) = v.camera.pixel_ray(i as u32, j as u32) else {
                continue;
            };
            let cos = ray.dir.dot(forward);
            if cos <= 1e-6 {
                continue;
            }
            let t_surface = z / cos;
            // The ray in the node's local frame (local units).
            let o = node.world_from_local.local_from_world_point(ray.origin);
            let d = node.world_from_local.local_from_world_vector(ray.dir);
            let per_world = d.length();
            let t_end_local = t_surface * per_world;
            let d = d / per_world;
            // This node's surface (behind an object, the background's prior depth there).
            if let Some(zs) = surface_depth(node, v, depth, p)
                && let Some(c) = to_cell(o + d * (zs / cos * per_world))
            {
                hit[c] = hit[c].saturating_add(1);
            }
            if !cast {
                continue;
            }
            let stop = t_end_local * (1.0 - SURFACE_MARGIN) - margin;
            let aabb = assist_core::Aabb::from_half_size(half);
            let Some((t0, t1)) = aabb.intersect(o, d, 0.0, stop.max(0.0)) else {
                continue;
            };
            let mut t = t0 + 0.5 * step;
            let mut last = usize::MAX;
            while t < t1 {
                if let Some(c) = to_cell(o + d * t)
                    && c != last
                {
                    free[c] = free[c].saturating_add(1);
                    last = c;
                }
                t += step;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{Camera, Intrinsics, Pose, Similarity3};

    /// Views of the ground plane z = 0 from a ring of cameras, with exact depth.
    fn plane_views() -> Vec<View> {
        (0..8)
            .map(|k| {
                let a = k as f64 / 8.0 * std::f64::consts::TAU;
                let eye = DVec3::new(0.8 * a.cos(), 0.8 * a.sin(), 0.7);
                let camera = Camera {
                    intrinsics: Intrinsics {
                        width: 40,
                        height: 30,
                        fx: 35.0,
                        fy: 35.0,
                        cx: 20.0,
                        cy: 15.0,
                        distortion: Default::default(),
                    },
                    pose: Pose::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
                };
                let depth = (0..1200)
                    .map(|p| {
                        let ray = camera.pixel_ray((p % 40) as u32, (p / 40) as u32).unwrap();
                        if ray.dir.z >= 0.0 {
                            return 0.0;
                        }
                        let t = -ray.origin.z / ray.dir.z;
                        camera.z_depth(ray.dir, t) as f32
                    })
                    .collect();
                View {
                    name: String::new(),
                    camera,
                    image_index: 0,
                    width: 40,
                    height: 30,
                    rgb: vec![0.0; 3600],
                    ids: None,
                    valid: None,
                    depth: Some(depth),
                    inpaint: None,
                    inpaint_depth: None,
                    prior_confidence: None,
                    prior_rgb_weight: None,
                    prior_from_user: false,
                }
            })
            .collect()
    }

    /// A background box from z = -0.2 to 0.8 over the plane's seen part (off-centre: the
    /// local frame is not the world frame).
    fn plane_box() -> SceneNode {
        SceneNode {
            id: 0,
            label: "background".into(),
            embedding: None,
            class: None,
            field: "background".into(),
            half_size: DVec3::new(0.5, 0.5, 0.5),
            world_from_local: Similarity3::from_translation(DVec3::new(0.0, 0.0, 0.3)),
            space: NodeSpace::Box,
            cast: None,
        }
    }

    #[test]
    fn unobserved_cells_inside_an_object_box_are_spared_but_free_ones_stay_carved() {
        let node = plane_box();
        let res = 10u32;
        let r = res as usize;
        // An object of half size 0.1 centred at (0.2, 0.2, 0.1) in the world; the
        // background's box spans [-0.5, 0.5]² × [-0.2, 0.8] (cells of 0.1).
        let mut object = plane_box();
        object.id = 1;
        object.half_size = DVec3::splat(0.1);
        object.world_from_local = Similarity3::from_translation(DVec3::new(0.2, 0.2, 0.1));
        let mut empty = vec![true; r * r * r];
        let mut free = vec![0u16; r * r * r];
        let cell = |x: usize, y: usize, z: usize| x + r * (y + r * z);
        // Cell (7, 7, 3) (centre (0.25, 0.25, 0.15)) is inside the box but rays cross it.
        free[cell(7, 7, 3)] = 3;
        spare_under_objects(&node, res, std::slice::from_ref(&object), &free, &mut empty);
        // Centre (0.25, 0.25, 0.05): inside; (0.35, 0.35, 0.05): within one cell of it;
        // (−0.25, −0.25, 0.05) and (0.25, 0.25, 0.45): away from it.
        assert!(!empty[cell(7, 7, 2)], "the cell under the object is spared");
        assert!(!empty[cell(8, 8, 2)], "one cell beyond the box is spared");
        assert!(empty[cell(7, 7, 3)], "a cell rays cross stays carved");
        assert!(
            empty[cell(2, 2, 2)] && empty[cell(7, 7, 6)],
            "cells away stay carved"
        );
    }

    #[test]
    fn the_space_above_a_seen_plane_is_carved_and_the_plane_kept() {
        let views = plane_views();
        let node = plane_box();
        let res = 20u32;
        let r = res as usize;
        let cell_z = |k: usize| -0.2 + (k as f64 + 0.5) / r as f64;
        let count = |empty: &[bool], lo: f64, hi: f64| {
            let (mut n, mut carved) = (0, 0);
            for z in (0..r).filter(|&z| (lo..hi).contains(&cell_z(z))) {
                for y in 5..15 {
                    for x in 5..15 {
                        n += 1;
                        carved += usize::from(empty[x + r * (y + r * z)]);
                    }
                }
            }
            (carved, n)
        };
        // Dense depth: above the plane carved, the plane's cells (z in [0, 0.05)) kept,
        // and below it (never reached) carved too.
        let empty = free_cells(&node, res, &views);
        let (plane, _) = count(&empty, 0.0, 0.05);
        assert_eq!(plane, 0, "cells on the plane were carved");
        let (above, n) = count(&empty, 0.1, 0.4);
        assert!(
            above * 10 >= n * 9,
            "{above} of {n} cells above the plane carved"
        );
        let (below, n) = count(&empty, -0.2, -0.06);
        assert_eq!(below, n, "cells below the plane are never reached");
        // The plane's cells are the kept ones (held occupied in training), and only they.
        let (_, kept) = carve_cells(&node, res, &views);
        let (on, n_on) = count(&kept, 0.0, 0.05);
        assert!(on * 10 >= n_on * 9, "{on} of {n_on} plane cells kept");
        assert_eq!(count(&kept, 0.1, 0.4).0, 0, "cells above the plane kept");
        // Depth with holes: what no ray reaches is kept.
        let mut holed = views.clone();
        for v in &mut holed {
            v.depth.as_mut().unwrap()[..4].fill(0.0);
        }
        let empty = free_cells(&node, res, &holed);
        assert_eq!(count(&empty, 0.0, 0.05).0, 0);
        assert_eq!(count(&empty, -0.2, -0.06).0, 0);
        let (above, n) = count(&empty, 0.1, 0.4);
        assert!(
            above * 10 >= n * 9,
            "{above} of {n} cells above the plane carved"
        );
    }

    /// On a grid finer than the pixels' footprint the end points miss some of the
    /// plane's cells; the surface between adjacent pixels keeps every one of them from
    /// being carved as never seen (and without it some would be).
    #[test]
    fn a_surface_between_sparse_end_points_is_not_carved_as_unseen() {
        let views = plane_views();
        let node = plane_box();
        let res = 160u32;
        let r = res as usize;
        let (free, hit) = ray_counts(&node, res, &views);
        let reached = surface_cells(&node, res, &views);
        // The plane z = 0 lies on the boundary of layers 31 and 32 (local z = −0.3).
        let holes = |empty: &[bool]| {
            let mut n = 0;
            for y in 60..100 {
                for x in 60..100 {
                    let c = |z: usize| x + r * (y + r * z);
                    n += usize::from(empty[c(31)] && empty[c(32)]);
                }
            }
            n
        };
        let (empty, _) = classify(&node, &views, &free, &hit, &reached);
        let (hits_only, _) = classify(&node, &views, &free, &hit, &vec![false; r * r * r]);
        assert_eq!(holes(&empty), 0, "the plane has holes");
        assert!(holes(&hits_only) > 100, "{}", holes(&hits_only));
        // The surface pass marks the plane, not the space above it.
        let above = (60..100)
            .flat_map(|y| (60..100).map(move |x| (x, y)))
            .filter(|&(x, y)| reached[x + r * (y + r * 40)])
            .count();
        assert_eq!(above, 0);
    }

    /// Every pixel's end point is a hit, however few rays are marched: a surface seen
    /// between the marched rays (at the edge of one or two views) is not carved.
    #[test]
    fn every_pixel_counts_its_hit_whatever_the_marching_stride() {
        let views = plane_views();
        let node = plane_box();
        let (free_all, hit_all) = ray_counts_marching(&node, 40, &views, usize::MAX);
        // 9,600 pixels, about 600 marched: every 4th in each direction.
        let (free_few, hit_few) = ray_counts_marching(&node, 40, &views, 600);
        let total = |v: &[u16]| v.iter().map(|&c| c as u64).sum::<u64>();
        assert_eq!(hit_few, hit_all);
        assert!(total(&hit_all) > 5000, "{}", total(&hit_all));
        assert!(
            total(&free_few) * 8 < total(&free_all),
            "free-space marching is strided: {} against {}",
            total(&free_few),
            total(&free_all)
        );
    }
}
