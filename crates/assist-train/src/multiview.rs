//! The multi-view background prior: what an object hides in one training view is filled
//! from the other training views that see the same background unoccluded.
//!
//! For a target view, every background pixel of every other view (instance id 0, away
//! from object edges, with a depth) is lifted to its 3D point with that view's z-depth
//! and splatted into the target with a footprint of its projected size. A splat landing
//! on a pixel the target's (dilated) object mask covers is a candidate for that pixel when
//! it lies behind the target's own surface there: behind the object on object pixels
//! (visibility — a point in front of the object would have been seen), at or behind the
//! observed background on the dilated border. Among a pixel's candidates the front-most
//! layer is kept (the first background surface behind the object, not one further back
//! showing through), and its colours are blended robustly: the mean of the layer, then
//! the mean again without the candidates further than 2σ + 0.03 from it (specular
//! highlights, mask errors, misregistration). The fill's confidence grows with the number
//! of views that agree, `1 − 0.5^n`; pixels no view sees fall back to push–pull from
//! everything known (observed and filled) with confidence [`FALLBACK_CONFIDENCE`], so
//! that a guess weighs less than an observation in the background losses.
//!
//! The depth used is the dataset's (desk-format captures, depth sensors). Captures
//! without depth keep the push–pull fill.

use assist_core::Camera;
use assist_core::glam::DVec3;
use rayon::prelude::*;

use crate::multiview_cull::{Cones, NEAR, Quick, TILE, Tiles};
use crate::prior;
use crate::views::{PRIOR_DILATION, View};

/// Confidence of a pixel no other view sees (push–pull guess).
pub const FALLBACK_CONFIDENCE: f32 = 0.25;
/// A candidate behind an object's surface must be this much (relative z) behind it.
const BEHIND_TOLERANCE: f32 = 0.02;
/// Candidates within this relative depth of the front-most one form its layer.
const LAYER_TOLERANCE: f32 = 0.04;
/// Largest splat radius in pixels (a source much closer to the surface than the target).
const MAX_SPLAT_RADIUS: i64 = 2;
/// A candidate is kept only up to this fraction behind the background: on object pixels
/// the one the surrounding pixels continue into (their depth filled in by push–pull), on
/// the dilated border the one the pixel sees. The floor another view sees beside the table
/// lies far behind the unseen table under an object, and without the test it filled every
/// object's footprint (desk: black discs where the objects had stood, and a prior depth
/// through the table).
const PAST_SURROUNDINGS_TOLERANCE: f32 = 0.15;

/// What the multi-view fill achieved over all views.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct MultiViewStats {
    /// Pixels under (dilated) objects to fill, over all views.
    pub hole_pixels: usize,
    /// Of those, filled from other views.
    pub filled_pixels: usize,
}

struct Source<'a> {
    view: &'a View,
    /// Camera-frame (OpenGL) point at z-depth 1 of each pixel centre.
    unit: Vec<[f32; 3]>,
    /// Background pixels usable as sources (id 0, away from objects, depth > 0).
    usable: Vec<bool>,
    /// Where the usable pixels' points lie, a tile at a time (to skip the tiles whose
    /// points cannot land on a target's holes).
    tiles: Tiles,
}

/// Pixel `q`'s point in its camera's frame, as [`splat`] lifts it.
#[inline(always)]
fn lifted(unit: &[[f32; 3]], depth: &[f32], q: usize) -> DVec3 {
    let u = unit[q];
    DVec3::new(u[0] as f64, u[1] as f64, u[2] as f64) * depth[q] as f64
}

fn source(view: &View) -> Option<Source<'_>> {
    let ids = view.ids.as_ref()?;
    let depth = view.depth.as_ref()?;
    let (w, h) = (view.width, view.height);
    let objects: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
    let near_object = prior::dilate(&objects, w, h, PRIOR_DILATION);
    let usable: Vec<bool> = (0..w * h)
        .map(|p| !near_object[p] && depth[p] > 0.0)
        .collect();
    let unit = (0..w * h)
        .map(|p| {
            let (i, j) = (p % w, p / w);
            match view
                .camera
                .intrinsics
                .direction_gl(i as f64 + 0.5, j as f64 + 0.5)
            {
                Some(d) if d.z < 0.0 => {
                    let d = d / -d.z;
                    [d.x as f32, d.y as f32, d.z as f32]
                }
                _ => [0.0; 3],
            }
        })
        .collect::<Vec<_>>();
    let tiles = Tiles::of(w, h, &usable, |q| lifted(&unit, depth, q));
    Some(Source {
        view,
        unit,
        usable,
        tiles,
    })
}

/// One splat into the target: pixel, z-depth, colour, source view.
#[derive(Clone, Copy)]
struct Candidate {
    pixel: u32,
    view: u32,
    z: f32,
    rgb: [f32; 3],
}

/// Splats every usable pixel of `src` into `target`, keeping those that land on `hole`
/// pixels behind the target's surface. Where `cones` hold the holes' directions, the
/// source's tiles outside them are skipped, and where the target's lens has no
/// distortion, the pixels whose quick projection lands far from every hole of `near`
/// (the holes grown by [`NEAR`]): the same candidates either way.
fn splat(
    src: &Source,
    src_index: u32,
    target: &Camera,
    (target_depth, target_ids): (&[f32], &[u16]),
    surroundings: &[f32],
    (hole, near, cones): (&[bool], &[bool], Option<&Cones>),
    out: &mut Vec<Candidate>,
) {
    let v = src.view;
    let depth = v.depth.as_ref().expect("sources have depth");
    let to_world = v.camera.pose.world_from_camera;
    let to_target = target.pose.camera_from_world() * to_world;
    let (tw, th) = (target.width() as i64, target.height() as i64);
    let (fs, ft) = (v.camera.intrinsics.fx, target.intrinsics.fx);
    let keep: Option<Vec<bool>> = cones.map(|c| {
        let sphere = |&(centre, r): &(DVec3, f64)| c.meet(to_target.transform_point3(centre), r);
        src.tiles
            .spheres
            .iter()
            .map(|s| s.as_ref().is_some_and(sphere))
            .collect()
    });
    let quick = cones.and_then(|_| Quick::new(target, &to_target, near));
    // Pixel `q`'s splat (a source pixel that passed the tests below).
    let mut one = |q: usize| {
        let z = depth[q] as f64;
        let p_src = lifted(&src.unit, depth, q);
        let p_t = to_target.transform_point3(p_src);
        let Some((px, zt)) = target.intrinsics.project_gl(p_t) else {
            return;
        };
        // Far outside the image (or not finite: a point on the camera's plane) it splats
        // nothing, and its pixel would not fit the integer arithmetic below.
        const FAR: f64 = 1e9;
        if !(px.x.abs() < FAR && px.y.abs() < FAR) {
            return;
        }
        let (cx, cy) = (px.x.floor() as i64, px.y.floor() as i64);
        // The source pixel's size on the surface, in target pixels.
        let size = (z / fs) * (ft / zt);
        let r = ((size * 0.5).floor() as i64).clamp(0, MAX_SPLAT_RADIUS);
        if cx + r < 0 || cy + r < 0 || cx - r >= tw || cy - r >= th {
            return;
        }
        let zt = zt as f32;
        let rgb = [v.rgb[3 * q], v.rgb[3 * q + 1], v.rgb[3 * q + 2]];
        for y in (cy - r).max(0)..=(cy + r).min(th - 1) {
            for x in (cx - r).max(0)..=(cx + r).min(tw - 1) {
                let p = (y * tw + x) as usize;
                if !hole[p] {
                    continue;
                }
                let d = target_depth[p];
                let visible = if d <= 0.0 {
                    true
                } else if target_ids[p] != 0 {
                    zt > d * (1.0 + BEHIND_TOLERANCE)
                        && (surroundings[p] <= 0.0
                            || zt <= surroundings[p] * (1.0 + PAST_SURROUNDINGS_TOLERANCE))
                } else {
                    // The background this pixel sees, not something behind it.
                    zt > d * (1.0 - BEHIND_TOLERANCE)
                        && zt <= d * (1.0 + PAST_SURROUNDINGS_TOLERANCE)
                };
                if visible {
                    out.push(Candidate {
                        pixel: p as u32,
                        view: src_index,
                        z: zt,
                        rgb,
                    });
                }
            }
        }
    };
    // Row by row, a tile's run of pixels at a time (raster order, as the candidates must
    // come), the tiles that miss every hole skipped whole.
    let (w, across) = (v.width, src.tiles.across);
    for y in 0..v.height {
        let row = (y / TILE) * across;
        for tx in 0..across {
            if keep.as_ref().is_some_and(|k| !k[row + tx]) {
                continue;
            }
            for q in y * w + tx * TILE..y * w + ((tx + 1) * TILE).min(w) {
                if !src.usable[q] {
                    continue;
                }
                if let Some(quick) = &quick {
                    let (u, z) = (src.unit[q], depth[q]);
                    if quick.misses([u[0] * z, u[1] * z, u[2] * z]) {
                        continue;
                    }
                }
                one(q);
            }
        }
    }
}

/// Per-pixel blend of the candidates: front layer, robust mean, number of views.
struct Fill {
    rgb: Vec<[f32; 3]>,
    z: Vec<f32>,
    views: Vec<u32>,
}

fn blend(cands: &[Candidate], n: usize) -> Fill {
    let mut zmin = vec![f32::INFINITY; n];
    for c in cands {
        let p = c.pixel as usize;
        zmin[p] = zmin[p].min(c.z);
    }
    let in_layer = |c: &Candidate| c.z <= zmin[c.pixel as usize] * (1.0 + LAYER_TOLERANCE);
    // First pass: mean and variance of the layer.
    let mut sum = vec![[0.0f32; 4]; n];
    let mut sq = vec![0.0f32; n];
    for c in cands.iter().filter(|c| in_layer(c)) {
        let p = c.pixel as usize;
        for k in 0..3 {
            sum[p][k] += c.rgb[k];
            sq[p] += c.rgb[k] * c.rgb[k];
        }
        sum[p][3] += 1.0;
    }
    let mean: Vec<[f32; 3]> = sum
        .iter()
        .map(|s| {
            let m = s[3].max(1.0);
            [s[0] / m, s[1] / m, s[2] / m]
        })
        .collect();
    let limit: Vec<f32> = (0..n)
        .map(|p| {
            let m = sum[p][3].max(1.0);
            let mean_sq = mean[p].iter().map(|v| v * v).sum::<f32>();
            let var = (sq[p] / m - mean_sq).max(0.0) / 3.0;
            2.0 * var.sqrt() + 0.03
        })
        .collect();
    // Second pass: the mean of the candidates near the first mean.
    let mut acc = vec![[0.0f32; 5]; n];
    let mut last_view = vec![u32::MAX; n];
    let mut views = vec![0u32; n];
    for c in cands.iter().filter(|c| in_layer(c)) {
        let p = c.pixel as usize;
        let far = (0..3).any(|k| (c.rgb[k] - mean[p][k]).abs() > limit[p]);
        if far {
            continue;
        }
        for k in 0..3 {
            acc[p][k] += c.rgb[k];
        }
        acc[p][3] += c.z;
        acc[p][4] += 1.0;
        // Candidates arrive grouped by source view.
        if last_view[p] != c.view {
            last_view[p] = c.view;
            views[p] += 1;
        }
    }
    let rgb = acc
        .iter()
        .map(|a| {
            let m = a[4].max(1.0);
            [a[0] / m, a[1] / m, a[2] / m]
        })
        .collect();
    let z = acc.iter().map(|a| a[3] / a[4].max(1.0)).collect();
    Fill { rgb, z, views }
}

/// One view's prior: colour, depth, confidence, pixels to fill and pixels filled.
struct Filled {
    rgb: Vec<f32>,
    depth: Vec<f32>,
    confidence: Vec<f32>,
    holes: usize,
    filled: usize,
}

/// Fills the background prior (colour, depth, confidence) of every view with instance
/// masks and depth from the other views; views without both are left alone (the caller
/// fills them with push–pull). Views that already carry a user-supplied prior colour are
/// left alone too.
pub fn fill_multiview(views: &mut [View]) -> MultiViewStats {
    fill_multiview_culled(views, true)
}

/// [`fill_multiview`], skipping the source tiles that cannot reach a hole when `cull`.
pub(crate) fn fill_multiview_culled(views: &mut [View], cull: bool) -> MultiViewStats {
    let sources: Vec<Option<Source>> = views.par_iter().map(source).collect();
    let results: Vec<Option<Filled>> = (0..views.len())
        .into_par_iter()
        .map(|t| {
            let v = &views[t];
            sources[t].as_ref()?;
            if v.inpaint.is_some() {
                return None;
            }
            let ids = v.ids.as_ref()?;
            let depth = v.depth.as_ref()?;
            let (w, h) = (v.width, v.height);
            let objects: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
            if !objects.iter().any(|&o| o) {
                return None;
            }
            let hole = prior::dilate(&objects, w, h, PRIOR_DILATION);
            // The depth of the background around the hole, continued across it.
            let mut surroundings = depth.clone();
            let unknown: Vec<bool> = (0..w * h).map(|p| hole[p] || depth[p] <= 0.0).collect();
            prior::push_pull(&mut surroundings, w, h, 1, &unknown);
            let cones = match cull {
                true => Cones::of(&v.camera, &hole, w, h),
                false => None,
            };
            let near = prior::dilate(&hole, w, h, NEAR);
            let mut cands = Vec::new();
            for (s, src) in sources.iter().enumerate() {
                if s == t {
                    continue;
                }
                if let Some(src) = src {
                    splat(
                        src,
                        s as u32,
                        &v.camera,
                        (depth, ids),
                        &surroundings,
                        (&hole, &near, cones.as_ref()),
                        &mut cands,
                    );
                }
            }
            let fill = blend(&cands, w * h);
            let mut rgb = v.rgb.clone();
            let mut dd = depth.clone();
            let mut conf = vec![1.0f32; w * h];
            let mut rest_rgb = vec![false; w * h];
            let mut rest_d = vec![false; w * h];
            let (mut holes, mut filled) = (0, 0);
            for p in 0..w * h {
                if !hole[p] {
                    rest_d[p] = dd[p] <= 0.0;
                    continue;
                }
                holes += 1;
                if fill.views[p] > 0 {
                    filled += 1;
                    rgb[3 * p..3 * p + 3].copy_from_slice(&fill.rgb[p]);
                    dd[p] = fill.z[p];
                    conf[p] = 1.0 - 0.5f32.powi(fill.views[p] as i32);
                } else {
                    rest_rgb[p] = true;
                    rest_d[p] = true;
                    conf[p] = FALLBACK_CONFIDENCE;
                }
            }
            prior::push_pull(&mut rgb, w, h, 3, &rest_rgb);
            prior::push_pull(&mut dd, w, h, 1, &rest_d);
            Some(Filled {
                rgb,
                depth: dd,
                confidence: conf,
                holes,
                filled,
            })
        })
        .collect();
    let mut stats = MultiViewStats::default();
    for (v, r) in views.iter_mut().zip(results) {
        if let Some(f) = r {
            v.inpaint = Some(f.rgb);
            if v.inpaint_depth.is_none() {
                v.inpaint_depth = Some(f.depth);
            }
            v.prior_confidence = Some(f.confidence);
            stats.hole_pixels += f.holes;
            stats.filled_pixels += f.filled;
        }
    }
    stats
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use assist_core::{Intrinsics, Pose};

    const CENTRE: DVec3 = DVec3::new(0.0, 0.0, 0.12);
    const RADIUS: f64 = 0.1;

    fn plane_colour(p: DVec3) -> [f32; 3] {
        let f = |v: f64| (0.5 + 0.45 * (v * 9.0).sin()) as f32;
        [f(p.x), f(p.y), f(p.x + p.y)]
    }

    /// Ray-cast view of a textured ground plane with a magenta sphere on it; with
    /// `object` false the sphere is absent (the background truth).
    fn render(camera: &Camera, object: bool) -> View {
        render_on(camera, object, None)
    }

    /// Depth of the floor below a table of half-size `table` (the plane is the table top).
    const FLOOR: f64 = -0.75;

    /// [`render`], the plane being a square table of half-size `table` (when given) above
    /// a dark floor.
    pub(crate) fn render_on(camera: &Camera, object: bool, table: Option<f64>) -> View {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let mut rgb = vec![0.0; 3 * w * h];
        let mut ids = vec![0u16; w * h];
        let mut depth = vec![0.0f32; w * h];
        for p in 0..w * h {
            let ray = camera.pixel_ray((p % w) as u32, (p / w) as u32).unwrap();
            let mut best = f64::INFINITY;
            if ray.dir.z < 0.0 {
                best = -ray.origin.z / ray.dir.z;
                let hit = ray.origin + ray.dir * best;
                let c = match table {
                    Some(s) if hit.x.abs() > s || hit.y.abs() > s => {
                        best = (FLOOR - ray.origin.z) / ray.dir.z;
                        [0.05, 0.05, 0.08]
                    }
                    _ => plane_colour(hit),
                };
                rgb[3 * p..3 * p + 3].copy_from_slice(&c);
            }
            if object {
                let oc = ray.origin - CENTRE;
                let b = oc.dot(ray.dir);
                let disc = b * b - (oc.length_squared() - RADIUS * RADIUS);
                if disc > 0.0 {
                    let t = -b - disc.sqrt();
                    if t > 0.0 && t < best {
                        best = t;
                        rgb[3 * p..3 * p + 3].copy_from_slice(&[1.0, 0.0, 1.0]);
                        ids[p] = 1;
                    }
                }
            }
            if best.is_finite() {
                depth[p] = camera.z_depth(ray.dir, best) as f32;
            }
        }
        View {
            name: String::new(),
            camera: *camera,
            image_index: 0,
            width: w,
            height: h,
            rgb,
            ids: Some(ids),
            valid: None,
            depth: Some(depth),
            inpaint: None,
            inpaint_depth: None,
            prior_confidence: None,
            prior_rgb_weight: None,
            prior_from_user: false,
        }
    }

    pub(crate) fn cameras(n: usize) -> Vec<Camera> {
        (0..n)
            .map(|k| {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                let eye = DVec3::new(0.9 * a.cos(), 0.9 * a.sin(), 0.6);
                Camera {
                    intrinsics: Intrinsics {
                        width: 80,
                        height: 60,
                        fx: 70.0,
                        fy: 70.0,
                        cx: 40.0,
                        cy: 30.0,
                        distortion: Default::default(),
                    },
                    pose: Pose::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap(),
                }
            })
            .collect()
    }

    #[test]
    fn what_a_sphere_hides_is_filled_from_the_views_that_see_it() {
        let cams = cameras(12);
        let mut views: Vec<View> = cams.iter().map(|c| render(c, true)).collect();
        let truth: Vec<View> = cams.iter().map(|c| render(c, false)).collect();
        let stats = fill_multiview(&mut views);
        assert!(stats.hole_pixels > 0);
        let (mut err, mut n, mut fallback) = (0.0f64, 0usize, 0usize);
        for (v, t) in views.iter().zip(&truth) {
            let conf = v.prior_confidence.as_ref().unwrap();
            let fill = v.inpaint.as_ref().unwrap();
            let depth = v.inpaint_depth.as_ref().unwrap();
            for p in 0..v.width * v.height {
                if v.ids.as_ref().unwrap()[p] == 0 {
                    continue;
                }
                if conf[p] <= FALLBACK_CONFIDENCE {
                    fallback += 1;
                    continue;
                }
                n += 1;
                for k in 0..3 {
                    err += (fill[3 * p + k] - t.rgb[3 * p + k]).abs() as f64;
                }
                let dz = t.depth.as_ref().unwrap()[p];
                assert!(
                    (depth[p] - dz).abs() < 0.03 * dz,
                    "depth {} against {dz}",
                    depth[p]
                );
            }
        }
        let mean = err / (3 * n.max(1)) as f64;
        // Most of what the sphere hides is seen by another view; its contact patch is not.
        assert!(n > 3 * fallback, "filled {n}, fallback {fallback}");
        assert!(fallback > 0);
        assert!(mean < 0.03, "mean colour error {mean} over {n} pixels");
    }

    #[test]
    fn the_floor_seen_beside_a_table_never_fills_what_an_object_stands_on() {
        let cams = cameras(12);
        let table = Some(0.45);
        let mut views: Vec<View> = cams.iter().map(|c| render_on(c, true, table)).collect();
        let truth: Vec<View> = cams.iter().map(|c| render_on(c, false, table)).collect();
        // The floor is in view beside the table, so it is a source for the fill.
        let floor_seen = truth
            .iter()
            .flat_map(|t| t.rgb.chunks(3))
            .filter(|c| c[2] == 0.08)
            .count();
        assert!(floor_seen > 1000, "{floor_seen}");
        fill_multiview(&mut views);
        let (mut on_table, mut wrong) = (0, 0);
        for (v, t) in views.iter().zip(&truth) {
            let depth = v.inpaint_depth.as_ref().unwrap();
            let fill = v.inpaint.as_ref().unwrap();
            for p in 0..v.width * v.height {
                if v.ids.as_ref().unwrap()[p] == 0 || t.rgb[3 * p + 2] == 0.08 {
                    continue;
                }
                // The table is behind the object here.
                on_table += 1;
                let dz = t.depth.as_ref().unwrap()[p];
                let floor = [0.05, 0.05, 0.08];
                let dark = (0..3).all(|k| (fill[3 * p + k] - floor[k]).abs() < 0.03);
                if (depth[p] - dz).abs() > 0.1 * dz || dark {
                    wrong += 1;
                }
            }
        }
        assert!(on_table > 500, "{on_table}");
        assert_eq!(
            wrong, 0,
            "{wrong} of {on_table} pixels filled from past the table"
        );
    }
}
