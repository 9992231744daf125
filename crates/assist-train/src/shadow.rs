//! Objects' shadows: what each object darkens on the background is learned as the object's
//! own shadow grid ([`assist_field::ShadeGrid`]), so the background learns the surface as it
//! is without the objects, and an edited object takes its shadow along.
//!
//! A shadow and a dark surface look alike in every photograph; what tells them apart is a
//! prior on the background near each object. Around every object (its box grown
//! [`FREE_EXTENT`] times, within the [`SHADE_EXTENT`] where its grid lives) the
//! background's prior colour is filled from the photograph *outside* that region
//! (push–pull, [`crate::prior`]): the surface as it looks just beyond the object's
//! shadow. Pixels an object covers take that fill with the
//! prior's full weight (nothing is seen there in that view); pixels where the
//! photograph sees the region take it with [`FREE_WEIGHT`], enough to set the brightness
//! of the surface under the shadow while the photograph, through the shadow grid, keeps
//! its texture. Where no object's region is, the prior is as before.

use assist_core::geometry::intersect_local_box;
use assist_core::{Aabb, DVec3, SceneNode};
use assist_field::ShadeGrid;
use assist_scene::NeuralScene;
use rayon::prelude::*;

use crate::prior;
use crate::views::{PRIOR_DILATION, View};

/// Lattice points per axis of an object's shadow grid: 5 mm apart around a 10 cm mug.
/// Finer than 40 gives a moved object a sharper contact shadow at a few per cent more time
/// per step (BENCHMARKS.md).
pub const SHADE_RES: usize = 60;

/// Half-width of the shadow region in box units: the object's box grown three times about
/// its centre (a 10 cm mug's shadow may reach 10 cm beyond it).
pub const SHADE_EXTENT: f32 = 3.0;

/// Half-width, in box units, of the region around an object whose background prior is
/// filled from the photograph outside it. The fill must come from beyond the object's
/// shadow, but no farther: the light on a table changes across it, and a fill from far
/// away is a surface lit differently. Measured against renders of the same views with
/// every object removed (desk's `background/`, the built-in scene's): under the objects
/// the fill from outside 3× the box was 4% too dark on desk (RMS error 0.064), from
/// outside 2× 1.3–2% (0.033), from outside 1.5× 2.6% (0.049: the shadow itself leaks
/// in); on the built-in scene 0.043 / 0.038 / 0.030, and where the photograph sees the
/// region 0.025 / 0.022 / 0.036. Between this and [`SHADE_EXTENT`] the shadows are faint
/// (desk: the photograph is within 0.2% of the surface there on average) and the prior
/// is the photograph's.
pub const FREE_EXTENT: f32 = 2.0;

/// Weight of the shadow-free prior on pixels where the photograph sees the background
/// near an object (relative to the prior's weight under objects).
pub const FREE_WEIGHT: f32 = 0.1;

/// Gives every object node of `scene` a shadow grid (casting none yet) if it has none;
/// returns how many were added.
pub fn add_shadow_grids(scene: &mut NeuralScene) -> usize {
    let mut added = 0;
    let keys: Vec<String> = scene
        .scene
        .nodes
        .iter()
        .filter(|n| !n.is_background())
        .map(|n| n.field.clone())
        .collect();
    for key in keys {
        if let Some(nf) = scene.fields.get_mut(&key)
            && nf.shade.is_none()
        {
            std::sync::Arc::make_mut(nf).shade = Some(ShadeGrid::new(SHADE_RES, SHADE_EXTENT));
            added += 1;
        }
    }
    added
}

/// What [`shadow_free_priors`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ShadowPriorStats {
    /// Views with a background prior near an object.
    pub views: usize,
    /// Pixels given the shadow-free prior: under objects / seen.
    pub covered: usize,
    pub seen: usize,
}

/// The shadow regions of `scene`'s casting objects: each node and the region in its frame.
fn regions(scene: &NeuralScene) -> Vec<(&SceneNode, f32)> {
    assist_render::casters(scene)
        .into_iter()
        .map(|c| (c.scene_node, c.grid.extent))
        .collect()
}

/// Replaces the background prior near every casting object of `scene` by the shadow-free
/// fill (see the module's documentation), in every view that has a built-in prior (a
/// prior from the user's files is left as it is). A pixel is near
/// an object when the background point its prior depth gives lies in the object's region;
/// without a prior depth, when its ray crosses the region.
pub fn shadow_free_priors(scene: &NeuralScene, views: &mut [View]) -> ShadowPriorStats {
    let regions = regions(scene);
    if regions.is_empty() {
        return ShadowPriorStats::default();
    }
    let per_view: Vec<ShadowPriorStats> = views
        .par_iter_mut()
        .map(|v| shadow_free_view(&regions, v))
        .collect();
    per_view
        .iter()
        .fold(ShadowPriorStats::default(), |a, s| ShadowPriorStats {
            views: a.views + s.views,
            covered: a.covered + s.covered,
            seen: a.seen + s.seen,
        })
}

/// The pixels an object covers, dilated by [`PRIOR_DILATION`].
fn near_objects(ids: &[u16], w: usize, h: usize) -> Vec<bool> {
    let objects: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
    prior::dilate(&objects, w, h, PRIOR_DILATION)
}

fn in_region(node: &SceneNode, extent: f32, p: DVec3) -> bool {
    let l = node.world_from_local.local_from_world_point(p) / node.half_size;
    l.abs().max_element() <= extent as f64
}

fn shadow_free_view(regions: &[(&SceneNode, f32)], v: &mut View) -> ShadowPriorStats {
    let (Some(ids), Some(inpaint)) = (&v.ids, &v.inpaint) else {
        return ShadowPriorStats::default();
    };
    if v.prior_from_user {
        // The user's inpainting is what they want the background to be: it stays.
        return ShadowPriorStats::default();
    }
    let (w, h) = (v.width, v.height);
    let hole = near_objects(ids, w, h);
    let forward = v.camera.pose.forward();
    // The fill's region: within the shadow region, at most FREE_EXTENT.
    let regions: Vec<(&SceneNode, f32)> = regions
        .iter()
        .map(|&(n, e)| (n, e.min(FREE_EXTENT)))
        .collect();
    let boxes: Vec<Aabb> = regions
        .iter()
        .map(|(n, e)| Aabb::from_half_size(n.half_size * *e as f64))
        .collect();
    let zone: Vec<bool> = (0..w * h)
        .map(|p| {
            let Some(ray) = v.camera.pixel_ray((p % w) as u32, (p / w) as u32) else {
                return false;
            };
            let z = v.inpaint_depth.as_ref().map_or(0.0, |d| d[p]);
            let cos = ray.dir.dot(forward);
            if z > 0.0 && cos > 1e-3 {
                let point = ray.origin + ray.dir * (z as f64 / cos);
                regions.iter().any(|(n, e)| in_region(n, *e, point))
            } else {
                regions.iter().zip(&boxes).any(|((n, _), b)| {
                    intersect_local_box(&ray, &n.world_from_local, b, 0.0, f64::INFINITY).is_some()
                })
            }
        })
        .collect();
    if !zone.iter().any(|&z| z) {
        return ShadowPriorStats::default();
    }
    let mut free = v.rgb.clone();
    let unknown: Vec<bool> = zone.iter().zip(&hole).map(|(&z, &o)| z || o).collect();
    prior::push_pull(&mut free, w, h, 3, &unknown);
    let mut img = inpaint.clone();
    let mut weight = v
        .prior_confidence
        .clone()
        .unwrap_or_else(|| vec![1.0; w * h]);
    let mut s = ShadowPriorStats {
        views: 1,
        ..Default::default()
    };
    for p in 0..w * h {
        if !zone[p] {
            continue;
        }
        img[3 * p..3 * p + 3].copy_from_slice(&free[3 * p..3 * p + 3]);
        if hole[p] {
            // Under an object the fill from other views (as photographed, shadow and all)
            // gives way to the surface as it looks away from the object, fully trusted
            // where nothing else is known.
            weight[p] = weight[p].max(0.5);
            s.covered += 1;
        } else {
            weight[p] *= FREE_WEIGHT;
            s.seen += 1;
        }
    }
    v.inpaint = Some(img);
    v.prior_rgb_weight = Some(weight);
    s
}

/// Weight, in pixels, of the "no shadow" guess each lattice point starts from in
/// [`estimate_shadows`]: a point seen by few pixels stays near 1.
const ESTIMATE_PRIOR: f64 = 1.0;

/// Added to both sides of each channel's ratio in [`estimate_shadows`] (colour in
/// `[0, 1]`): a channel with almost no light in it gives a factor near 1, not noise.
const RATIO_FLOOR: f32 = 0.02;

/// What [`estimate_shadows`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ShadowEstimate {
    /// Grids that were given a first estimate.
    pub grids: usize,
    /// Photograph pixels that went into them.
    pub pixels: usize,
    /// Per estimated grid (by field key), its lattice points the photographs support
    /// well (trilinear weight of at least [`HELD_SUPPORT`] pixels): what training keeps
    /// when the shadows are held (`train --shadows fixed`).
    pub held: std::collections::BTreeMap<String, Vec<bool>>,
}

/// Support, in pixels' trilinear weight summed over the views, from which an estimated
/// lattice point is held (see [`ShadowEstimate::held`]).
pub const HELD_SUPPORT: f64 = 20.0;

/// Gives every shadow grid of `scene` that casts no shadow yet (every factor 1: new, not
/// trained) a first estimate from the photographs: at each background point a training
/// view sees inside an object's region (the point from the prior's depth; pixels near
/// objects left out), the photograph over the shadow-free prior there, channel by channel
/// (see [`shadow_free_priors`], which must run first), clamped to `[MIN_SHADE, 1]` and
/// averaged onto the lattice with its trilinear weights over all views. Where regions
/// overlap, the object nearest the point (the distance to its box) casts the darkening,
/// and the others' grids are given no shadow there: on a crowded table a neighbour's
/// region covers each object's shadow too, and a shadow split between them stays
/// partly behind when one moves.
///
/// The photograph is the surface times the shadow, and training alone finds the two only
/// slowly: the background learns the shadowed photograph first, and only the light
/// shadow-free prior pulls the shadow out of it, so on desk most of each object's
/// shadow stayed on the background and was left behind when the object moved. Starting
/// the grid at this ratio starts the background at the surface itself.
pub fn estimate_shadows(scene: &mut NeuralScene, views: &[View]) -> ShadowEstimate {
    // Every untrained grid.
    let grids: Vec<Lattice> = assist_render::casters(scene)
        .into_iter()
        .filter(|c| c.grid.values.iter().all(|&v| v == 1.0))
        .map(|c| {
            let shape = ShadeGrid {
                res: c.grid.res,
                extent: c.grid.extent,
                values: Vec::new(),
            };
            (c.node, c.scene_node.clone(), shape)
        })
        .collect();
    if grids.is_empty() {
        return ShadowEstimate::default();
    }
    // Per grid, per lattice point: `[Σ w·r_red, Σ w·r_green, Σ w·r_blue, Σ w]`.
    let empty = || -> (Vec<Vec<[f64; 4]>>, usize) {
        (
            grids
                .iter()
                .map(|g| vec![[0.0; 4]; g.2.res.pow(3)])
                .collect(),
            0,
        )
    };
    // Views in parallel, a few at a time, summed in view order: the same bits whatever
    // the threads do.
    let (mut sums, mut pixels) = empty();
    for chunk in views.chunks(rayon::current_num_threads().max(1) * 2) {
        let parts: Vec<(Vec<Vec<[f64; 4]>>, usize)> = chunk
            .par_iter()
            .map(|v| {
                let mut acc = empty();
                estimate_view(&grids, v, &mut acc);
                acc
            })
            .collect();
        for (part, n) in parts {
            for (x, y) in sums.iter_mut().zip(&part) {
                for (p, q) in x.iter_mut().zip(y) {
                    for c in 0..4 {
                        p[c] += q[c];
                    }
                }
            }
            pixels += n;
        }
    }
    // Every object's box, for the ownership of lattice points.
    let objects: Vec<SceneNode> = scene.scene.objects().cloned().collect();
    let mut held = std::collections::BTreeMap::new();
    for ((k, node, lattice), sum) in grids.iter().zip(&sums) {
        let key = scene.scene.nodes[*k].field.clone();
        let foreign = foreign_points(node, lattice, &objects);
        held.insert(
            key.clone(),
            sum.iter()
                .zip(&foreign)
                .map(|(s, &f)| f || s[3] >= HELD_SUPPORT)
                .collect(),
        );
        let nf = std::sync::Arc::make_mut(scene.fields.get_mut(&key).expect("field of node"));
        let grid = nf.shade.as_mut().expect("a caster has a grid");
        for ((v, s), &f) in grid.values.chunks_exact_mut(3).zip(sum).zip(&foreign) {
            for c in 0..3 {
                v[c] = if f {
                    1.0
                } else {
                    ((s[c] + ESTIMATE_PRIOR) / (s[3] + ESTIMATE_PRIOR)) as f32
                };
            }
        }
        grid.clamp();
    }
    ShadowEstimate {
        grids: grids.len(),
        pixels,
        held,
    }
}

/// The distance, in world units, from world point `p` to `node`'s box (0 inside it).
fn box_distance(node: &SceneNode, p: DVec3) -> f64 {
    let local = node.world_from_local.local_from_world_point(p);
    let out = (local.abs() - node.half_size).max(DVec3::ZERO);
    (out * node.world_from_local.scale).length()
}

/// Per lattice point of `node`'s grid (shaped like `lattice`): whether another of
/// `objects` is nearer to it than `node` (by the distance to each box). What lies nearer
/// another object is that object's to darken — its contact shadow, the table under it —
/// and is no part of this one's shadow: a point there that no photograph settles would
/// otherwise learn the neighbour's shadow, and carry it along when this object moves.
fn foreign_points(node: &SceneNode, lattice: &ShadeGrid, objects: &[SceneNode]) -> Vec<bool> {
    let (r, e) = (lattice.res, lattice.extent as f64);
    let step = if r > 1 { 2.0 * e / (r - 1) as f64 } else { 0.0 };
    (0..r * r * r)
        .map(|i| {
            let c = DVec3::new(
                (i % r) as f64 * step - e,
                (i / r % r) as f64 * step - e,
                (i / (r * r)) as f64 * step - e,
            );
            let p = node.world_from_local.transform_point(c * node.half_size);
            let own = box_distance(node, p);
            objects
                .iter()
                .filter(|o| o.id != node.id)
                .any(|o| box_distance(o, p) < own)
        })
        .collect()
}

/// A grid to estimate: its node's index, the node, and the grid's shape (no values; it
/// only finds lattice corners).
type Lattice = (usize, SceneNode, ShadeGrid);

/// Adds one view's ratios into `acc` (per grid: `[Σ w·r, Σ w]` per lattice point; the
/// number of pixels used).
fn estimate_view(grids: &[Lattice], v: &View, acc: &mut (Vec<Vec<[f64; 4]>>, usize)) {
    use assist_field::shade::MIN_SHADE;
    let (Some(ids), Some(prior), Some(depth)) = (&v.ids, &v.inpaint, &v.inpaint_depth) else {
        return;
    };
    if v.prior_from_user {
        return;
    }
    let (w, h) = (v.width, v.height);
    let near = near_objects(ids, w, h);
    let forward = v.camera.pose.forward();
    let mut inside = Vec::with_capacity(grids.len());
    for p in 0..w * h {
        if near[p] || depth[p] <= 0.0 || v.valid.as_ref().is_some_and(|m| !m[p]) {
            continue;
        }
        let Some(ray) = v.camera.pixel_ray((p % w) as u32, (p / w) as u32) else {
            continue;
        };
        let cos = ray.dir.dot(forward);
        if cos <= 1e-3 {
            continue;
        }
        let point = ray.origin + ray.dir * (depth[p] as f64 / cos);
        // Every region the point lies in, with the point's distance to that object's box
        // (world units).
        inside.clear();
        for (g, (_, node, lattice)) in grids.iter().enumerate() {
            let l = node.world_from_local.local_from_world_point(point) / node.half_size;
            if let Some(c) = lattice.corners(l.as_vec3().to_array()) {
                inside.push((g, c, box_distance(node, point)));
            }
        }
        let Some(nearest) = inside
            .iter()
            .min_by(|a, b| a.2.total_cmp(&b.2))
            .map(|n| n.0)
        else {
            continue;
        };
        // Per channel: the light reflected by the object tints what it darkens.
        // (A dark channel's ratio is softened by RATIO_FLOOR rather than left to noise.)
        let (seen, free) = (&v.rgb[3 * p..3 * p + 3], &prior[3 * p..3 * p + 3]);
        if free.iter().sum::<f32>() < 1e-3 {
            continue;
        }
        let ratio: [f64; 3] = std::array::from_fn(|c| {
            ((seen[c] + RATIO_FLOOR) / (free[c] + RATIO_FLOOR)).clamp(MIN_SHADE, 1.0) as f64
        });
        for (g, c, _) in &inside {
            // The nearest object casts it; the others are told they do not.
            let r = if *g == nearest { ratio } else { [1.0; 3] };
            let sum = &mut acc.0[*g];
            for i in 0..8 {
                let wt = c.weight[i] as f64;
                let s = &mut sum[c.index[i] as usize];
                for ch in 0..3 {
                    s[ch] += wt * r[ch];
                }
                s[3] += wt;
            }
        }
        acc.1 += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{Camera, Intrinsics, NodeSpace, Pose, Scene, Similarity3};
    use assist_scene::NodeField;
    use std::collections::BTreeMap;
    use std::sync::Arc;

    fn node(id: u16, key: &str, half: f64, at: DVec3) -> SceneNode {
        SceneNode {
            id,
            label: key.into(),
            embedding: None,
            class: None,
            field: key.into(),
            half_size: DVec3::splat(half),
            world_from_local: Similarity3::from_translation(at),
            space: NodeSpace::Box,
            cast: None,
        }
    }

    /// A floor (z = 0) seen from above in `w × h` pixels, bright on the left half (x < 0)
    /// and dark on the right, with a cube of half size 0.1 at (0.5, 0, 0.1) covering the
    /// pixels around it, and the floor at `0.61 < x < 0.69, |y| < 0.1` (beside
    /// the cube, within its prior's fill region) darkened by `shadow` in red and by
    /// `0.8 · shadow` in green and blue (a shadow tinted by the cube's light) when
    /// `shadow < 1`.
    fn setup_sized(w: usize, h: usize, shadow: f32) -> (NeuralScene, View) {
        let nodes = vec![
            node(0, "background", 2.0, DVec3::ZERO),
            node(1, "cube", 0.1, DVec3::new(0.5, 0.0, 0.1)),
        ];
        let mut fields = BTreeMap::new();
        for n in &nodes {
            let f = assist_field::Field::constant(1.0, [0.5; 3], false, 1).unwrap();
            let nf = NodeField::new(f, assist_field::OccupancyGrid::new(8), n.half_size);
            fields.insert(n.field.clone(), Arc::new(nf));
        }
        let scene = NeuralScene {
            scene: Scene::with_nodes(nodes, DVec3::Z),
            fields,
        };
        let camera = Camera {
            intrinsics: Intrinsics::from_fov_x(w as u32, h as u32, 1.2),
            pose: Pose::look_at(DVec3::new(0.0, -0.01, 2.0), DVec3::ZERO, DVec3::Y).unwrap(),
        };
        let (mut rgb, mut ids, mut depth) =
            (vec![0.0; 3 * w * h], vec![0u16; w * h], vec![0.0; w * h]);
        for p in 0..w * h {
            let ray = camera.pixel_ray((p % w) as u32, (p / w) as u32).unwrap();
            let t = -ray.origin.z / ray.dir.z;
            let x = ray.origin + ray.dir * t;
            depth[p] = camera.z_depth(ray.dir, t) as f32;
            let on_cube = (x.x - 0.5).abs() < 0.1 && x.y.abs() < 0.1;
            ids[p] = u16::from(on_cube);
            let tint = if shadow < 1.0 { 0.8 } else { 1.0 };
            let c = if on_cube {
                [0.9; 3]
            } else if x.x < 0.0 {
                [0.8; 3]
            } else if x.x > 0.61 && x.x < 0.69 && x.y.abs() < 0.1 {
                [0.3 * shadow, 0.3 * shadow * tint, 0.3 * shadow * tint]
            } else {
                [0.3; 3]
            };
            rgb[3 * p..3 * p + 3].copy_from_slice(&c);
        }
        let view = View {
            name: "v".into(),
            camera,
            image_index: 0,
            width: w,
            height: h,
            rgb: rgb.clone(),
            ids: Some(ids),
            valid: None,
            depth: Some(depth.clone()),
            inpaint: Some(rgb),
            inpaint_depth: Some(depth),
            prior_confidence: None,
            prior_rgb_weight: None,
            prior_from_user: false,
        };
        (scene, view)
    }

    #[test]
    fn the_prior_near_a_casting_object_is_filled_from_outside_its_region() {
        let (mut scene, mut view) = setup_sized(160, 120, 1.0);
        // A prior the user supplied is never replaced.
        let mut user = view.clone();
        user.prior_from_user = true;
        // Without shadow grids nothing changes.
        let mut views = vec![view.clone()];
        assert_eq!(
            shadow_free_priors(&scene, &mut views),
            ShadowPriorStats::default()
        );
        assert!(views[0].prior_rgb_weight.is_none());
        assert_eq!(add_shadow_grids(&mut scene), 1);
        assert_eq!(add_shadow_grids(&mut scene), 0, "added once");
        let given = user.inpaint.clone();
        let st = shadow_free_priors(&scene, std::slice::from_mut(&mut user));
        assert_eq!(st, ShadowPriorStats::default());
        assert_eq!(user.inpaint, given);
        let st = shadow_free_priors(&scene, std::slice::from_mut(&mut view));
        assert!(st.views == 1 && st.covered > 0 && st.seen > 0, "{st:?}");
        let weight = view.prior_rgb_weight.as_ref().unwrap();
        let inpaint = view.inpaint.as_ref().unwrap();
        let (w, cam) = (view.width, view.camera);
        let at = |x: f64, y: f64| {
            let (px, _) = cam.project(DVec3::new(x, y, 0.0)).unwrap();
            px.y as usize * w + px.x as usize
        };
        // Under the cube: the dark floor around the region, fully weighted (the cube's own
        // colour, 0.9, and the bright left half are not what it is filled with).
        let p = at(0.5, 0.0);
        assert!((inpaint[3 * p] - 0.3).abs() < 0.05, "{}", inpaint[3 * p]);
        assert_eq!(weight[p], 1.0);
        // Seen within the fill's region (0.18 from the centre; it reaches 0.2): the fill,
        // lightly weighted.
        let p = at(0.5, 0.18);
        assert!((inpaint[3 * p] - 0.3).abs() < 0.05);
        assert!((weight[p] - FREE_WEIGHT).abs() < 1e-6);
        // Beyond it (in the shadow grid's region, which reaches 0.3, or outside that too):
        // the photograph, fully weighted.
        for (x, y, c) in [(-0.5, 0.0, 0.8), (0.5, 0.25, 0.3), (0.5, 0.45, 0.3)] {
            let p = at(x, y);
            assert_eq!((inpaint[3 * p], weight[p]), (c, 1.0), "at ({x}, {y})");
        }
    }

    #[test]
    fn a_new_grid_starts_from_the_photographs_darkening() {
        // (Enough pixels per lattice point that the estimate's one-pixel prior towards no
        // shadow is small: ~15 each on the 60³ lattice.)
        let (mut scene, view) = setup_sized(1280, 960, 0.5);
        let mut views = vec![view];
        // Without grids, nothing to estimate.
        assert_eq!(
            estimate_shadows(&mut scene, &views),
            ShadowEstimate::default()
        );
        add_shadow_grids(&mut scene);
        shadow_free_priors(&scene, &mut views);
        let st = estimate_shadows(&mut scene, &views);
        assert_eq!(st.grids, 1);
        assert!(st.pixels > 1000, "{st:?}");
        let node = scene.scene.nodes[1].clone();
        let grid = scene.field_of(1).shade.clone().unwrap();
        let at = |x: f64, y: f64| {
            let l = node
                .world_from_local
                .local_from_world_point(DVec3::new(x, y, 0.0))
                / node.half_size;
            grid.value(l.as_vec3().to_array())
        };
        // In the shadow: half as bright as the floor around it in red, 0.4 in green and
        // blue (each channel's ratio, softened by RATIO_FLOOR).
        for (x, y) in [(0.63, 0.0), (0.65, 0.05), (0.67, -0.05)] {
            let s = at(x, y);
            assert!(
                (s[0] - 0.5).abs() < 0.1 && (s[1] - 0.4).abs() < 0.1 && (s[2] - 0.4).abs() < 0.1,
                "shade {s:?} at ({x}, {y})"
            );
            assert!(s[0] - s[1] > 0.05, "tinted: {s:?}");
        }
        // Seen, unshadowed, inside the region: no shadow.
        for (x, y) in [(0.5, 0.22), (0.3, -0.2), (0.75, 0.2)] {
            let s = at(x, y);
            assert!(s.iter().all(|&v| v > 0.9), "shade {s:?} at ({x}, {y})");
        }
        // Under the cube nothing is seen: no shadow is guessed there.
        assert!(at(0.5, 0.0).iter().all(|&v| v > 0.95));
        // A grid that has been trained is left as it is.
        let before = grid.values.clone();
        assert_eq!(
            estimate_shadows(&mut scene, &views),
            ShadowEstimate::default()
        );
        assert_eq!(scene.field_of(1).shade.as_ref().unwrap().values, before);
        // No shadow in the photographs: none estimated.
        let (mut scene, view) = setup_sized(640, 480, 1.0);
        let mut views = vec![view];
        add_shadow_grids(&mut scene);
        shadow_free_priors(&scene, &mut views);
        estimate_shadows(&mut scene, &views);
        let g = scene.field_of(1).shade.as_ref().unwrap();
        let low = g.values.iter().copied().fold(1.0f32, f32::min);
        assert!(low > 0.85, "lowest factor {low} with no shadow");
    }

    /// Adds a second object, "other", of half size 0.1 at (0.5, 0.3, 0.1): beside the
    /// cube, its region covering the cube's shadow too (nothing of it is photographed).
    fn add_other(scene: &mut NeuralScene) {
        let other = node(2, "other", 0.1, DVec3::new(0.5, 0.3, 0.1));
        let f = assist_field::Field::constant(1.0, [0.5; 3], false, 1).unwrap();
        let nf = NodeField::new(f, assist_field::OccupancyGrid::new(8), other.half_size);
        scene.fields.insert(other.field.clone(), Arc::new(nf));
        scene.scene.nodes.push(other);
    }

    #[test]
    fn where_regions_overlap_the_nearest_object_casts_the_shadow() {
        let (mut scene, view) = setup_sized(1280, 960, 0.5);
        add_other(&mut scene);
        let mut views = vec![view];
        add_shadow_grids(&mut scene);
        shadow_free_priors(&scene, &mut views);
        assert_eq!(estimate_shadows(&mut scene, &views).grids, 2);
        let shade = |k: usize, x: f64, y: f64| {
            let n = &scene.scene.nodes[k];
            let l = n
                .world_from_local
                .local_from_world_point(DVec3::new(x, y, 0.0))
                / n.half_size;
            scene
                .field_of(k)
                .shade
                .as_ref()
                .unwrap()
                .value(l.as_vec3().to_array())
        };
        // (0.65, 0.05) is 0.05 from the cube's box and 0.16 from the other's.
        let (mine, theirs) = (shade(1, 0.65, 0.05), shade(2, 0.65, 0.05));
        assert!((mine[0] - 0.5).abs() < 0.1, "the cube's factors {mine:?}");
        assert!(
            theirs.iter().all(|&v| v > 0.9),
            "the other object's factors {theirs:?}"
        );
    }

    #[test]
    fn what_lies_nearer_another_object_is_held_shadow_free() {
        let (mut scene, view) = setup_sized(320, 240, 0.5);
        add_other(&mut scene);
        let mut views = vec![view];
        add_shadow_grids(&mut scene);
        shadow_free_priors(&scene, &mut views);
        let st = estimate_shadows(&mut scene, &views);
        let (cube, other) = (&scene.scene.nodes[1], &scene.scene.nodes[2]);
        let grid = scene.field_of(2).shade.as_ref().unwrap();
        let held = &st.held["other"];
        let r = grid.res;
        let e = grid.extent as f64;
        let step = 2.0 * e / (r - 1) as f64;
        let (mut foreign, mut own_free) = (0, 0);
        for i in 0..r * r * r {
            let c = DVec3::new(
                (i % r) as f64 * step - e,
                (i / r % r) as f64 * step - e,
                (i / (r * r)) as f64 * step - e,
            );
            let p = other.world_from_local.transform_point(c * other.half_size);
            if box_distance(cube, p) < box_distance(other, p) {
                // The cube's: held, casting nothing — even under the cube, where no
                // photograph sees the floor.
                assert!(held[i], "point {i} at {p} is the cube's");
                assert_eq!(grid.values[3 * i..3 * i + 3], [1.0; 3]);
                foreign += 1;
            } else if !held[i] {
                own_free += 1;
            }
        }
        assert!(foreign > 1000, "{foreign} points nearer the cube");
        // Its own unseen points (under itself) still train.
        assert!(own_free > 1000, "{own_free} free points of its own");
    }
}
