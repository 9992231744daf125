//! Objects' shadows: what each object darkens on the background is learned as the object's
//! own shadow grid ([`assist_field::ShadeGrid`]), so the background learns the surface as it
//! is without the objects, and an edited object takes its shadow along.
//!
//! A shadow and a dark surface look alike in every photograph; what tells them apart is a
//! prior on the background near each object. Around every object (its box grown
//! [`SHADE_EXTENT`] times, where its grid lives) the background's prior colour is filled
//! from the photograph *outside* that region (push–pull, [`crate::prior`]): the surface
//! as it looks away from the object. Pixels an object covers take that fill with the
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

/// Lattice points per axis of an object's shadow grid.
pub const SHADE_RES: usize = 40;

/// Half-width of the shadow region in box units: the object's box grown three times about
/// its centre (a 10 cm mug's shadow may reach 10 cm beyond it).
pub const SHADE_EXTENT: f32 = 3.0;

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
    let objects: Vec<bool> = ids.iter().map(|&i| i != 0).collect();
    let hole = prior::dilate(&objects, w, h, PRIOR_DILATION);
    let forward = v.camera.pose.forward();
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
        }
    }

    /// A floor (z = 0) seen from above, bright on the left half (x < 0) and dark on the
    /// right, with a cube of half size 0.1 at (0.5, 0, 0.1) covering the pixels around it.
    fn setup() -> (NeuralScene, View) {
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
            scene: Scene {
                nodes,
                up: DVec3::Z,
                meters_per_unit: 1.0,
                background_color: [0.0; 3],
                backdrop: Default::default(),
                selected: None,
                near: 0.0,
                classes: Vec::new(),
            },
            fields,
        };
        let (w, h) = (64usize, 48usize);
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
            let c = if on_cube {
                0.9
            } else if x.x < 0.0 {
                0.8
            } else {
                0.3
            };
            rgb[3 * p..3 * p + 3].fill(c);
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
        let (mut scene, mut view) = setup();
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
        // Seen within the region (0.25 from the centre; the region reaches 0.3): the fill,
        // lightly weighted.
        let p = at(0.5, 0.25);
        assert!((inpaint[3 * p] - 0.3).abs() < 0.05);
        assert!((weight[p] - FREE_WEIGHT).abs() < 1e-6);
        // Away from it: the photograph, fully weighted.
        for (x, y, c) in [(-0.5, 0.0, 0.8), (0.5, 0.45, 0.3)] {
            let p = at(x, y);
            assert_eq!((inpaint[3 * p], weight[p]), (c, 1.0), "at ({x}, {y})");
        }
    }
}
