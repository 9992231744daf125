//! An object's box from one click: the surface under the click, the support it stands on
//! (the densest layer of the connected surface below it), the part of that surface above
//! the support connected to the click (in the clicked view), then the same region seen
//! from the other views (as deep as it is wide, above the support or, with none seen,
//! above where the clicked view saw the object end), fused in a voxel grid, its
//! component through the click boxed upright (yaw by the smallest footprint).

use std::collections::{HashMap, VecDeque};

use assist_core::{Camera, DMat3, DVec3, Obb};

use crate::{RenderRequest, Result, Session, SessionError, request};

/// How a click becomes a box.
#[derive(Debug, Clone, Copy)]
pub struct ClickOptions {
    /// Render the views this many times smaller.
    pub render_downscale: u32,
    /// Other views fused (spread over those that see the object).
    pub views: usize,
}

/// How many times smaller than the photographs views are rendered to find boxes and
/// masks (the masks are then refined at full size).
pub const RENDER_DOWNSCALE: u32 = 4;

/// Views are rendered no smaller than this on their longer side to find boxes and masks
/// (unless the photograph is smaller): a 128-pixel capture rendered at a quarter is 32
/// pixels across, too coarse for its objects.
pub const MIN_RENDER_SIDE: u32 = 256;

/// `camera`'s size rendered `downscale` times smaller, its longer side kept at
/// [`MIN_RENDER_SIDE`] or more.
pub fn render_size(camera: &Camera, downscale: f64) -> (u32, u32) {
    let (w, h) = (camera.width(), camera.height());
    let most = (w.max(h) as f64 / MIN_RENDER_SIDE as f64).max(1.0);
    let d = downscale.clamp(1.0, most);
    (
        ((w as f64 / d).round() as u32).max(1),
        ((h as f64 / d).round() as u32).max(1),
    )
}

impl Default for ClickOptions {
    fn default() -> Self {
        ClickOptions {
            render_downscale: RENDER_DOWNSCALE,
            views: 16,
        }
    }
}

/// A view rendered to world points: per pixel, the surface point seen (`None` where the
/// view sees nearly nothing or an existing object).
struct Points {
    width: usize,
    height: usize,
    at: Vec<Option<DVec3>>,
    /// World size of a pixel at unit depth.
    footprint: f64,
}

fn render_points(session: &Session, camera: &Camera, downscale: f64) -> Result<(Camera, Points)> {
    let cam = Session::sized(camera, Some(render_size(camera, downscale)))?;
    let frame = session.render(&cam, &RenderRequest::default())?;
    let w = frame.width as usize;
    let at = (0..frame.depth.len())
        .map(|i| {
            (frame.opacity[i] >= 0.5 && frame.panoptic[i] == 0 && frame.depth[i] > 0.0)
                .then(|| {
                    cam.unproject(
                        (i % w) as f64 + 0.5,
                        (i / w) as f64 + 0.5,
                        frame.depth[i] as f64,
                    )
                })
                .flatten()
        })
        .collect();
    Ok((
        cam,
        Points {
            width: w,
            height: frame.height as usize,
            at,
            footprint: 1.0 / cam.intrinsics.fx,
        },
    ))
}

/// Pixels 4-connected to `seed` whose points pass `keep` and lie within a few pixel
/// footprints of their neighbour's (no depth jump between them).
fn grow(pts: &Points, cam: &Camera, seed: usize, keep: impl Fn(DVec3) -> bool) -> Vec<usize> {
    let eye = cam.pose.center();
    let mut seen = vec![false; pts.at.len()];
    let mut out = Vec::new();
    let mut queue = VecDeque::from([seed]);
    seen[seed] = true;
    while let Some(i) = queue.pop_front() {
        let Some(p) = pts.at[i] else { continue };
        if !keep(p) {
            continue;
        }
        out.push(i);
        let (x, y) = (i % pts.width, i / pts.width);
        let reach = 4.0 * pts.footprint * p.distance(eye);
        let mut try_push = |j: usize| {
            if !seen[j]
                && let Some(q) = pts.at[j]
                && q.distance(p) < reach
            {
                seen[j] = true;
                queue.push_back(j);
            }
        };
        if x > 0 {
            try_push(i - 1);
        }
        if x + 1 < pts.width {
            try_push(i + 1);
        }
        if y > 0 {
            try_push(i - pts.width);
        }
        if y + 1 < pts.height {
            try_push(i + pts.width);
        }
    }
    out
}

/// The height of the support under the click: the middle of the fullest layer (bins of
/// `bin`) of the connected surface's heights below the clicked point's, when that layer
/// holds at least `share` of them (a floor or table top seen around the object; an
/// object's own side spreads evenly over its layers).
fn support_height(heights: &[f64], clicked: f64, bin: f64, share: f64) -> Option<f64> {
    let mut count: HashMap<i64, usize> = HashMap::new();
    let mut total = 0usize;
    for &h in heights.iter().filter(|&&h| h < clicked - 2.0 * bin) {
        *count.entry((h / bin).floor() as i64).or_default() += 1;
        total += 1;
    }
    count
        .into_iter()
        .max_by_key(|&(k, n)| (n, -k))
        .filter(|&(_, n)| n as f64 >= share * total as f64)
        .map(|(k, _)| (k as f64 + 0.5) * bin)
}

/// The share of the surface below a click its support's layer must hold. Below it the
/// support is taken as unseen (a reflective or untextured floor the field put elsewhere)
/// and the object's base is its lowest point.
pub const SUPPORT_SHARE: f64 = 0.1;

/// The box of the object under pixel `(u, v)` of `camera` (pixels of the camera's own
/// size), fused over `others` (the capture's views).
pub fn box_at_click(
    session: &Session,
    camera: &Camera,
    (u, v): (f64, f64),
    others: &[Camera],
    opts: &ClickOptions,
) -> Result<Obb> {
    let up = session.description().up.normalize();
    // The clicked view at twice the others' resolution (its layers are thinner), and no
    // finer than that for a camera larger than the capture's (a viewer's window): the
    // layers of a blurry scene must stay thicker than its noise.
    let mut widths: Vec<u32> = others.iter().map(|c| c.width()).collect();
    widths.sort_unstable();
    let capture = widths
        .get(widths.len() / 2)
        .copied()
        .unwrap_or(camera.width());
    let larger = (camera.width() as f64 / capture.max(1) as f64).max(1.0);
    let fine = (opts.render_downscale / 2).max(1) as f64 * larger;
    let (cam, pts) = render_points(session, camera, fine)?;
    let (x, y) = (
        (u * pts.width as f64 / camera.width() as f64).floor(),
        (v * pts.height as f64 / camera.height() as f64).floor(),
    );
    if x < 0.0 || y < 0.0 || x >= pts.width as f64 || y >= pts.height as f64 {
        return Err(request(
            "click",
            format!(
                "({u}, {v}) is outside the view ({}×{} pixels)",
                camera.width(),
                camera.height()
            ),
        ));
    }
    let seed = y as usize * pts.width + x as usize;
    let Some(p0) = pts.at[seed] else {
        return Err(nothing_there(u, v, "the view sees nothing solid there"));
    };
    let eye = cam.pose.center();
    // Layers two pixels thick at the click's distance; the object starts two layers
    // above its support's middle.
    let bin = 2.0 * pts.footprint * p0.distance(eye);
    let surface = grow(&pts, &cam, seed, |_| true);
    let heights: Vec<f64> = surface
        .iter()
        .filter_map(|&i| pts.at[i])
        .map(|p| p.dot(up))
        .collect();
    let h0 = p0.dot(up);
    // On the connected surface's fullest layer (a table top, a floor): what objects
    // stand on, not an object.
    if support_height(&heights, f64::INFINITY, bin, 0.0).is_some_and(|d| (h0 - d).abs() < bin) {
        return Err(nothing_there(
            u,
            v,
            "the click is on the surface objects stand on: click an object",
        ));
    }
    let support = support_height(&heights, h0, bin, SUPPORT_SHARE);
    if heights.iter().all(|&h| h >= h0 - 2.0 * bin) {
        return Err(nothing_there(
            u,
            v,
            "nothing below the clicked surface: click an object standing on something",
        ));
    }
    let floor = support.map_or(f64::NEG_INFINITY, |s| s + 2.0 * bin);
    if h0 <= floor {
        return Err(nothing_there(
            u,
            v,
            "the click is on the surface objects stand on: click an object",
        ));
    }
    let region = grow(&pts, &cam, seed, |p| p.dot(up) > floor);
    let foot = foot_seen(&pts, cam.pose.center(), &region);
    let first: Vec<DVec3> = region.iter().filter_map(|&i| pts.at[i]).collect();
    let obb = upright_box(&first, up, support);
    // An object is much smaller than the surface it stands on; a region as wide is that
    // surface (its field not quite flat) or a wall. The surface is all the view sees at
    // the support's height, connected to the click or not: a floor seen at a grazing
    // angle breaks into pieces the growth does not cross. With no support seen, it is
    // all the view sees.
    let surface_points: Vec<DVec3> = pts
        .at
        .iter()
        .flatten()
        .filter(|p| support.is_none_or(|s| (p.dot(up) - s).abs() <= 2.0 * bin))
        .copied()
        .chain(surface.iter().filter_map(|&i| pts.at[i]))
        .collect();
    let wide = |b: &Obb| b.size().x.max(b.size().y);
    if wide(&obb) > MAX_SHARE_OF_SURFACE * wide(&upright_box(&surface_points, up, support)) {
        return Err(nothing_there(
            u,
            v,
            "the region there is about as wide as the surface under it (the surface itself, not an object on it)",
        ));
    }
    // Voxels a few points across at the click's distance, finer for large objects; sized
    // once, from the clicked view's region (voxels growing with the box would bridge
    // the fog around a noisy object).
    let cell = (obb.size().max_element() / 24.0).max(2.0 * bin);
    let floor = fused_floor(floor, support, foot, &obb, cell);
    let clicked = Clicked {
        first: &first,
        p0,
        up,
        floor,
        support,
    };
    let obb = fuse(session, others, opts, &clicked, obb, cell)?;
    // A margin of two voxels around the sides and over the top (and under the base when
    // no support was seen): the masks decide what in the box is the object; a box cut at
    // its trimmed edge would lose them.
    let margin = 2.0 * cell;
    let axis_up = obb.rotation.col(2);
    let (lift, below) = match support {
        Some(_) => (margin / 2.0, 0.0),
        None => (0.0, margin / 2.0),
    };
    Ok(Obb {
        center: obb.center + axis_up * lift,
        half_size: obb.half_size + DVec3::new(margin, margin, margin / 2.0 + below),
        ..obb
    })
}

/// The height the other views' points must lie above to join the object: `floor` over a
/// support; with none seen but the object's foot seen (`foot`), a voxel below where the
/// clicked view saw the object end (`first`, its box): what the other views show lower
/// down is the floor around it, or the mirror image a shiny floor puts under it, as
/// consistent across views as the object and so fused with it otherwise. With the foot
/// hidden, the other views find where the object ends.
fn fused_floor(floor: f64, support: Option<f64>, foot: bool, first: &Obb, cell: f64) -> f64 {
    match support {
        None if foot => first.center.dot(first.rotation.col(2)) - first.half_size.z - cell,
        _ => floor,
    }
}

/// Whether the view sees where the object in `region` (pixels of `pts`) ends below:
/// under most of the region's lower edge it sees something no nearer than the region
/// (the floor, or what a shiny floor mirrors). Something nearer there, an existing
/// object, nothing, or the image's edge hides the foot.
fn foot_seen(pts: &Points, eye: DVec3, region: &[usize]) -> bool {
    let inside: std::collections::HashSet<usize> = region.iter().copied().collect();
    let (mut seen, mut edge) = (0usize, 0usize);
    for &i in region {
        let below = i + pts.width;
        if inside.contains(&below) {
            continue;
        }
        edge += 1;
        let (Some(p), Some(q)) = (pts.at[i], pts.at.get(below).copied().flatten()) else {
            continue;
        };
        // Nearer by more than a few pixels' footprint (grow's reach) hides it.
        let (d, e) = (p.distance(eye), q.distance(eye));
        if e > d - 4.0 * pts.footprint * d {
            seen += 1;
        }
    }
    2 * seen > edge
}

/// What the clicked view found: its region's points, the clicked point, the scene's up,
/// the height objects start above (−∞ without a support) and the support's height.
struct Clicked<'a> {
    first: &'a [DVec3],
    p0: DVec3,
    up: DVec3,
    floor: f64,
    support: Option<f64>,
}

/// Rounds until the box holds still: the other views' points in the box grown by half
/// (and as deep as wide), the component through the click kept (voxels of `cell`), the
/// box fitted again. A noisy field breaks the clicked view's region into pieces; each
/// round reaches further along the object. Views are rendered once and reused.
fn fuse(
    session: &Session,
    others: &[Camera],
    opts: &ClickOptions,
    c: &Clicked,
    obb: Obb,
    cell: f64,
) -> Result<Obb> {
    fuse_rounds(others, opts.views, c, obb, cell, |k| {
        let pts = render_points(session, &others[k], opts.render_downscale as f64)?.1;
        Ok(pts.at.into_iter().flatten().collect())
    })
}

/// [`fuse`]'s rounds, with `seen(k)` the surface points view `k` of `others` shows (asked
/// once per view).
fn fuse_rounds(
    others: &[Camera],
    views: usize,
    c: &Clicked,
    mut obb: Obb,
    cell: f64,
    mut seen: impl FnMut(usize) -> Result<Vec<DVec3>>,
) -> Result<Obb> {
    let mut rendered: HashMap<usize, Vec<DVec3>> = HashMap::new();
    for _ in 0..MAX_ROUNDS {
        // Grown by half, and as deep as it is wide: the clicked view saw the object's
        // front only, and its back may lie as far behind as the front is wide (a can's
        // half-cylinder seen from one side).
        let across = obb.half_size.x.max(obb.half_size.y);
        let grown = Obb {
            half_size: DVec3::new(across, across, obb.half_size.z) * 1.5,
            ..obb
        };
        // Points tagged with the view that saw them: the clicked view is 0.
        let mut cloud: Vec<(DVec3, usize)> = c.first.iter().map(|p| (*p, 0)).collect();
        let chosen = spread(others, obb.center, views);
        for &k in &chosen {
            let pts = match rendered.entry(k) {
                std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::hash_map::Entry::Vacant(e) => e.insert(seen(k)?),
            };
            cloud.extend(
                pts.iter()
                    .filter(|q| grown.contains(**q, 0.0) && q.dot(c.up) > c.floor)
                    .map(|q| (*q, k + 1)),
            );
        }
        let min_views = MIN_VOXEL_VIEWS.min(chosen.len() + 1);
        let kept = component_through(&cloud, c.p0, cell, min_views);
        let next = upright_box(&kept, c.up, c.support);
        let moved = (next.center - obb.center).abs().max_element()
            + (next.half_size - obb.half_size).abs().max_element();
        obb = next;
        if moved < cell {
            break;
        }
    }
    Ok(obb)
}

/// The most rounds of fusing other views into a click's box.
pub const MAX_ROUNDS: usize = 5;

fn nothing_there(u: f64, v: f64, why: &str) -> SessionError {
    request("click", format!("no object at ({u}, {v}): {why}"))
}

/// The widest an object may be, as a share of the surface it stands on (in the clicked
/// view).
pub const MAX_SHARE_OF_SURFACE: f64 = 0.5;

/// Up to `n` of `cams` (their indices) that look at `target` from in front, spread over
/// the directions they see it from (farthest-point order, starting anywhere).
fn spread(cams: &[Camera], target: DVec3, n: usize) -> Vec<usize> {
    let seeing: Vec<(usize, DVec3)> = cams
        .iter()
        .enumerate()
        .filter(|(_, c)| {
            c.project(target).is_some_and(|(px, z)| {
                z > 0.0
                    && px.x >= 0.0
                    && px.y >= 0.0
                    && px.x < c.width() as f64
                    && px.y < c.height() as f64
            })
        })
        .map(|(k, c)| (k, (c.pose.center() - target).normalize()))
        .collect();
    let mut chosen: Vec<usize> = Vec::new();
    let mut best = vec![f64::INFINITY; seeing.len()];
    let mut next = 0;
    while chosen.len() < n.min(seeing.len()) {
        chosen.push(next);
        for (k, (_, d)) in seeing.iter().enumerate() {
            best[k] = best[k].min(d.distance(seeing[next].1));
        }
        next = (0..seeing.len())
            .max_by(|&a, &b| best[a].total_cmp(&best[b]))
            .unwrap_or(0);
        if best[next] == 0.0 {
            break;
        }
    }
    chosen.into_iter().map(|k| seeing[k].0).collect()
}

/// The points of `cloud` (each with the view that saw it) in the 26-connected voxel
/// component (voxels of `cell`) holding the voxel nearest `seed`; voxels of fewer than
/// [`MIN_VOXEL_POINTS`] points, or seen by fewer than `min_views` views, neither count
/// nor connect: a surface is where the views agree, fog is where one view alone puts it.
fn component_through(
    cloud: &[(DVec3, usize)],
    seed: DVec3,
    cell: f64,
    min_views: usize,
) -> Vec<DVec3> {
    let key = |p: DVec3| (p / cell).floor().as_i64vec3().to_array();
    let mut voxels: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, (p, _)) in cloud.iter().enumerate() {
        voxels.entry(key(*p)).or_default().push(i);
    }
    voxels.retain(|_, v| {
        let mut views: Vec<usize> = v.iter().map(|&i| cloud[i].1).collect();
        views.sort_unstable();
        views.dedup();
        v.len() >= MIN_VOXEL_POINTS && views.len() >= min_views
    });
    let Some(start) = voxels
        .keys()
        .min_by(|a, b| {
            let d = |k: &[i64; 3]| {
                (DVec3::new(k[0] as f64, k[1] as f64, k[2] as f64) + 0.5) * cell - seed
            };
            d(a).length_squared().total_cmp(&d(b).length_squared())
        })
        .copied()
    else {
        return Vec::new();
    };
    let mut seen: HashMap<[i64; 3], ()> = HashMap::from([(start, ())]);
    let mut queue = VecDeque::from([start]);
    let mut out = Vec::new();
    while let Some(k) = queue.pop_front() {
        out.extend(voxels[&k].iter().map(|&i| cloud[i].0));
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let n = [k[0] + dx, k[1] + dy, k[2] + dz];
                    if voxels.contains_key(&n) && seen.insert(n, ()).is_none() {
                        queue.push_back(n);
                    }
                }
            }
        }
    }
    out
}

/// Points a voxel needs to be part of an object.
pub const MIN_VOXEL_POINTS: usize = 3;

/// Views that must see a surface in a voxel for it to be part of an object (fewer when
/// fewer views are fused).
pub const MIN_VOXEL_VIEWS: usize = 3;

/// The share of the points left out at each end of each axis when boxing them (stray
/// points do not stretch the box).
pub const TRIM: f64 = 0.005;

/// The smallest upright box (yaw in 2° steps) around `pts` (all but [`TRIM`] at each end
/// of each axis), its base on the support (or at its lowest points when none was seen).
fn upright_box(pts: &[DVec3], up: DVec3, support: Option<f64>) -> Obb {
    let [a, b] = assist_mesh::sim::horizontal_axes(up);
    let mut best: Option<(f64, Obb)> = None;
    let range = |mut v: Vec<f64>| -> (f64, f64) {
        v.sort_by(f64::total_cmp);
        let cut = ((v.len() as f64 * TRIM) as usize).min(v.len().saturating_sub(1) / 2);
        (v[cut], v[v.len() - 1 - cut])
    };
    if pts.is_empty() {
        return Obb::new(DVec3::ZERO, DVec3::splat(1e-6), DMat3::IDENTITY);
    }
    for step in 0..45 {
        let yaw = (step as f64 * 2.0).to_radians();
        let (x, y) = (a * yaw.cos() + b * yaw.sin(), b * yaw.cos() - a * yaw.sin());
        let (x0, x1) = range(pts.iter().map(|p| p.dot(x)).collect());
        let (y0, y1) = range(pts.iter().map(|p| p.dot(y)).collect());
        let (z0, z1) = range(pts.iter().map(|p| p.dot(up)).collect());
        let lo = DVec3::new(x0, y0, support.unwrap_or(z0));
        let hi = DVec3::new(x1, y1, z1);
        let area = (hi.x - lo.x) * (hi.y - lo.y);
        if best.as_ref().is_none_or(|(b, _)| area < *b) {
            let r = DMat3::from_cols(x, y, up);
            let c = (lo + hi) / 2.0;
            best = Some((area, Obb::new(r * c, (hi - lo).max(DVec3::splat(1e-6)), r)));
        }
    }
    best.map(|(_, b)| b)
        .unwrap_or_else(|| Obb::new(DVec3::ZERO, DVec3::splat(1e-6), DMat3::IDENTITY))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_support_is_the_fullest_layer_below_the_click() {
        // A table at 0.75 (many points), a box top at 0.9, the click at 0.85.
        let mut h = vec![0.75; 500];
        h.extend(vec![0.9; 200]);
        h.extend((0..100).map(|k| 0.75 + 0.15 * k as f64 / 100.0));
        let s = support_height(&h, 0.85, 0.005, SUPPORT_SHARE).unwrap();
        assert!((s - 0.7525).abs() < 0.0026, "{s}");
        assert_eq!(support_height(&[0.9, 0.95], 0.85, 0.005, 0.0), None);
        // An object's side alone (no floor seen under it): no layer stands out.
        let side: Vec<f64> = (0..1000).map(|k| 0.5 + 0.3 * k as f64 / 1000.0).collect();
        assert_eq!(support_height(&side, 0.85, 0.005, SUPPORT_SHARE), None);
        assert!(support_height(&side, 0.85, 0.005, 0.0).is_some());
    }

    /// A can (radius 0.4, 2.3 tall) on a mirror-like floor, as the field renders it: each
    /// view shows the can's side facing it and, below the floor, the can's mirror image.
    /// The clicked view sees the front half; no support is seen.
    #[test]
    fn a_click_fuses_the_objects_back_and_not_its_mirror_image() {
        let (r, tall) = (0.4, 2.3);
        let cams: Vec<Camera> = (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 8.0 + 0.2;
                let eye = DVec3::new(5.0 * a.cos(), 5.0 * a.sin(), 2.0);
                let pose = assist_core::Pose::look_at(eye, DVec3::new(0.0, 0.0, 1.0), DVec3::Z);
                Camera {
                    intrinsics: assist_core::Intrinsics::from_fov_x(64, 48, 1.0),
                    pose: pose.unwrap(),
                }
            })
            .collect();
        // The can's side (and its mirror image) as seen from `eye`, points 0.03 apart.
        let side = |eye: DVec3, mirror: bool| -> Vec<DVec3> {
            let mut out = Vec::new();
            for i in 0..84 {
                let a = i as f64 * std::f64::consts::TAU / 84.0;
                let n = DVec3::new(a.cos(), a.sin(), 0.0);
                for j in 1..77 {
                    let z = j as f64 * 0.03;
                    let p = n * r + DVec3::Z * if mirror { -z } else { z };
                    if n.dot(eye - p) > 0.0 {
                        out.push(p);
                    }
                }
            }
            out
        };
        let click_eye = DVec3::new(5.0, 0.0, 2.0);
        let first = side(click_eye, false);
        let p0 = DVec3::new(r, 0.0, 1.5);
        let obb = upright_box(&first, DVec3::Z, None);
        let cell = obb.size().max_element() / 24.0;
        let fused = |floor: f64| {
            let c = Clicked {
                first: &first,
                p0,
                up: DVec3::Z,
                floor,
                support: None,
            };
            fuse_rounds(&cams, 16, &c, obb, cell, |k| {
                let eye = cams[k].pose.center();
                Ok([side(eye, false), side(eye, true)].concat())
            })
            .unwrap()
        };
        let b = fused(fused_floor(f64::NEG_INFINITY, None, true, &obb, cell));
        let (s, base) = (b.size(), b.center.z - b.half_size.z);
        assert!(s.x > 0.75 && s.y > 0.75, "the can's back is in: {s}");
        assert!(s.x < 0.9 && s.y < 0.9, "{s}");
        assert!(base > -cell, "the mirror image is not: base at {base}");
        assert!((s.z - tall).abs() < 0.1, "{s}");
        // Without the cut the mirror image joins the can.
        let b = fused(f64::NEG_INFINITY);
        assert!(b.center.z - b.half_size.z < -1.0, "{b:?}");
    }

    /// A region 3 pixels wide (rows 1–3 of a 5 × 6 view, 10 units away) and what the view
    /// sees under it.
    #[test]
    fn the_foot_is_seen_unless_something_nearer_hides_it() {
        let view = |under: Option<f64>, rows: usize| {
            let (w, h) = (5usize, 6usize);
            let mut at = vec![Some(DVec3::new(30.0, 0.0, 0.0)); w * h];
            let mut region = Vec::new();
            for y in 1..1 + rows {
                for x in 1..4 {
                    at[y * w + x] = Some(DVec3::new(10.0, 0.0, 0.0));
                    region.push(y * w + x);
                }
            }
            if 1 + rows < h {
                for x in 1..4 {
                    at[(1 + rows) * w + x] = under.map(|d| DVec3::new(d, 0.0, 0.0));
                }
            }
            let pts = Points {
                width: w,
                height: h,
                at,
                footprint: 0.01,
            };
            foot_seen(&pts, DVec3::ZERO, &region)
        };
        assert!(view(Some(12.0), 3), "the floor behind its base");
        assert!(
            view(Some(9.8), 3),
            "the floor at its base, within the reach"
        );
        assert!(!view(Some(5.0), 3), "an object in front of it");
        assert!(!view(None, 3), "an existing object or nothing");
        assert!(!view(Some(12.0), 5), "cut by the image's edge");
    }

    #[test]
    fn voxel_components_split_what_is_apart() {
        // Two dense runs of points 0.4 apart, and a lone point between them.
        // Two dense runs of points 0.4 apart, seen by views 0–3, and a lone point between
        // them; then a dense run between them seen by one view only (fog).
        let mut cloud: Vec<(DVec3, usize)> = (0..40)
            .map(|k| (DVec3::new(k as f64 * 0.0025, 0.0, 0.0), k % 4))
            .collect();
        cloud.extend((0..40).map(|k| (DVec3::new(0.5 + k as f64 * 0.0025, 0.0, 0.0), k % 4)));
        cloud.push((DVec3::new(0.3, 0.0, 0.0), 1));
        let got = component_through(&cloud, DVec3::new(0.02, 0.0, 0.0), 0.015, 3);
        assert_eq!(got.len(), 40);
        assert!(got.iter().all(|p| p.x < 0.2));
        cloud.extend((0..200).map(|k| (DVec3::new(0.1 + k as f64 * 0.002, 0.0, 0.0), 2)));
        let bridged = component_through(&cloud, DVec3::new(0.02, 0.0, 0.0), 0.015, 1);
        assert!(
            bridged.iter().any(|p| p.x > 0.45),
            "one view's fog bridges the gap"
        );
        let got = component_through(&cloud, DVec3::new(0.02, 0.0, 0.0), 0.015, 3);
        assert!(got.iter().all(|p| p.x < 0.2), "unless views must agree");
    }

    #[test]
    fn the_upright_box_finds_a_turned_footprint() {
        // Corners of a 0.2 × 0.1 rectangle turned by 30°, from height 0.1 to 0.3.
        let yaw = 30f64.to_radians();
        let (x, y) = (
            DVec3::new(yaw.cos(), yaw.sin(), 0.0),
            DVec3::new(-yaw.sin(), yaw.cos(), 0.0),
        );
        let mut pts = Vec::new();
        for (i, j, z) in [
            (-1.0, -1.0, 0.1),
            (1.0, -1.0, 0.3),
            (1.0, 1.0, 0.2),
            (-1.0, 1.0, 0.3),
        ] {
            pts.push(x * 0.1 * i + y * 0.05 * j + DVec3::new(1.0, 2.0, z));
        }
        let b = upright_box(&pts, DVec3::Z, Some(0.0));
        let s = b.size();
        let (long, short) = (s.x.max(s.y), s.x.min(s.y));
        assert!(
            (long - 0.2).abs() < 1e-6 && (short - 0.1).abs() < 1e-6,
            "{s}"
        );
        assert!((s.z - 0.3).abs() < 1e-9, "from the support up: {s}");
        assert!(
            (b.center - DVec3::new(1.0, 2.0, 0.15)).length() < 1e-6,
            "{}",
            b.center
        );
        let free = upright_box(&pts, DVec3::Z, None);
        assert!(
            (free.size().z - 0.2).abs() < 1e-9,
            "from the lowest point: {s}"
        );
    }
}
