//! From a dataset to the nodes of a trainable scene: a background node over the scene
//! bounds (unless the dataset is a Blender object on an empty background), and one object
//! node per instance — with the user's box (`--boxes`, used as given), else the dataset's
//! box plus a margin, else a box carved from the instance masks (visual hull) plus a margin.

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{
    Aabb, Backdrop, DVec3, InstanceId, NodeSpace, Obb, Scene, SceneNode, Similarity3,
};
use assist_data::boxes::BoxOverride;
use assist_data::{Dataset, Format};
use assist_field::{Field, FieldConfig, OccupancyGrid};
use assist_scene::{NeuralScene, NodeField};
use rayon::prelude::*;

use crate::error::{Result, TrainError};
use crate::views::View;

#[derive(Debug, Clone)]
pub struct SetupOptions {
    /// Per-image appearance embeddings.
    pub appearance: bool,
    /// Box margin, as a fraction of the box size on each side.
    pub margin: f64,
    pub background_grid: u32,
    pub object_grid: u32,
    pub seed: u64,
    /// Boxes given by the user (override the dataset's and the carved ones; no margin is
    /// added). Each must name an instance of the dataset.
    pub boxes: Vec<BoxOverride>,
    /// The background node's space (auto: contracted unless the training views have
    /// depth, which bounds the scene).
    pub background_space: BackgroundSpace,
    /// The background's finest hash-grid resolution.
    pub grid_resolution: crate::GridResolution,
    /// Objects' colour from the view direction reflected about a predicted normal
    /// ([`FieldConfig::reflect`]).
    pub reflect: bool,
}

/// The space of the background node.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackgroundSpace {
    /// Contracted for captures without depth (real ones: the scene is unbounded), the
    /// scene box for captures whose depth maps bound what is seen.
    #[default]
    Auto,
    Box,
    Contracted,
}

impl BackgroundSpace {
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "auto" => BackgroundSpace::Auto,
            "box" => BackgroundSpace::Box,
            "contracted" => BackgroundSpace::Contracted,
            _ => return None,
        })
    }

    /// The space `ds` gets with this choice.
    pub fn resolve(self, views: &[View]) -> NodeSpace {
        match self {
            BackgroundSpace::Box => NodeSpace::Box,
            BackgroundSpace::Contracted => NodeSpace::Contracted,
            BackgroundSpace::Auto => {
                if !views.is_empty() && views.iter().all(|v| v.depth.is_some()) {
                    NodeSpace::Box
                } else {
                    NodeSpace::Contracted
                }
            }
        }
    }
}

impl Default for SetupOptions {
    fn default() -> Self {
        SetupOptions {
            appearance: false,
            margin: 0.1,
            background_grid: 128,
            object_grid: 64,
            seed: 0,
            boxes: Vec::new(),
            background_space: BackgroundSpace::Auto,
            grid_resolution: Default::default(),
            reflect: false,
        }
    }
}

/// Whether the dataset is one object on an empty background (Blender synthetic).
pub fn is_object_capture(ds: &Dataset) -> bool {
    ds.format == Format::Blender
}

/// Background colour the images are composited over (white for Blender objects).
pub fn background_color(ds: &Dataset) -> [f32; 3] {
    if is_object_capture(ds) {
        [1.0; 3]
    } else {
        [0.0; 3]
    }
}

/// About how many field parameters [`build_scene`] makes for `ds` with `n_images`
/// training views, from its metadata alone (for a free-space check before any image is
/// read): a background and one field per listed instance (at least one).
pub fn scene_param_estimate(ds: &Dataset, n_images: usize, appearance: bool) -> usize {
    let app = |mut c: FieldConfig| {
        if !appearance {
            c.appearance_dim = 0;
        }
        c.param_count()
    };
    let background = if is_object_capture(ds) {
        0
    } else {
        app(FieldConfig::nerfacto(n_images))
    };
    background + ds.instances.len().max(1) * app(FieldConfig::object(n_images))
}

/// Builds the untrained scene for `ds` from its training `views`.
pub fn build_scene(ds: &Dataset, views: &[View], opts: &SetupOptions) -> Result<NeuralScene> {
    let n_images = views.len();
    let app = |mut c: FieldConfig| {
        if !opts.appearance {
            c.appearance_dim = 0;
        }
        c
    };
    let mut nodes = Vec::new();
    let mut fields = BTreeMap::new();
    let region = scene_region(ds, views);
    let space = opts.background_space.resolve(views);
    let mut near = 0.0;
    if !is_object_capture(ds) {
        near = near_plane(ds, views);
        let inner = match space {
            NodeSpace::Box => region,
            NodeSpace::Contracted => unbounded_inner_region(ds, views),
        };
        let c = inner.center();
        let half = inner.size() * 0.5 * 1.05;
        let node = SceneNode {
            id: 0,
            label: "background".into(),
            embedding: None,
            class: None,
            field: "background".into(),
            half_size: half,
            world_from_local: Similarity3::from_translation(c),
            space,
            cast: None,
        };
        let mut config = app(FieldConfig::nerfacto(n_images));
        config.max_resolution = opts.grid_resolution.resolve(ds, views, half, space);
        let field = Field::new(config, opts.seed)?;
        fields.insert(
            "background".to_string(),
            Arc::new(NodeField::with_space(
                field,
                training_grid(opts.background_grid),
                half,
                space,
            )),
        );
        nodes.push(node);
    }
    for nb in node_boxes(ds, views, &region, opts)? {
        let key = format!("object-{}", nb.id);
        let node = SceneNode::from_obb(nb.id, &nb.label, &key, &nb.obb);
        let table = object_table_log2(views, nb.id);
        fields.insert(key, Arc::new(object_field(opts, n_images, &node, table)?));
        nodes.push(node);
    }
    let scene = Scene {
        nodes,
        up: ds.world_up.unwrap_or(DVec3::Z),
        meters_per_unit: ds.meters_per_unit.unwrap_or(1.0),
        background_color: background_color(ds),
        // Captures with an unknown background show their last sample (see `Backdrop`).
        backdrop: if is_object_capture(ds) {
            Backdrop::Color
        } else {
            Backdrop::LastSample
        },
        selected: None,
        near,
        classes: Vec::new(),
        light: None,
        relight: false,
    };
    let mut scene = scene;
    scene.register_classes();
    let mut scene = NeuralScene { scene, fields };
    set_anchors(&mut scene, views);
    Ok(scene)
}

/// Records where each training view's camera stood ([`Field::anchors`], in each node's
/// local frame) in every field with one appearance code per view that has none yet, so
/// that views from elsewhere take the codes of the nearest ones. Fields whose codes are
/// of other photographs (another capture's node) are left as they are.
pub fn set_anchors(scene: &mut NeuralScene, views: &[View]) {
    let NeuralScene { scene, fields } = scene;
    for node in &scene.nodes {
        let Some(nf) = fields.get_mut(&node.field) else {
            continue;
        };
        let f = &nf.field;
        if f.config.appearance_dim == 0
            || f.config.num_images != views.len()
            || !f.anchors.is_empty()
        {
            continue;
        }
        let anchors = views
            .iter()
            .map(|v| {
                let p = node
                    .world_from_local
                    .local_from_world_point(v.camera.pose.center());
                p.as_vec3().to_array()
            })
            .collect();
        Arc::make_mut(nf).field.anchors = anchors;
    }
}

/// A visible convex surface's area over its silhouette's (a sphere's: 4πr² / πr²).
const SURFACE_PER_SILHOUETTE: f64 = 4.0;

/// The hash-table size (log2 entries per level) object `id` needs to hold its surface at
/// the training views' resolution, about one finest-level cell per pixel: its median
/// silhouette over the views that see it, in pixels, times [`SURFACE_PER_SILHOUETTE`],
/// between [`FieldConfig::object`]'s and [`FieldConfig::nerfacto`]'s (a background's).
/// Small objects keep the small table; one that fills half of every view (a walk-around's
/// subject) gets the background's.
pub fn object_table_log2(views: &[View], id: InstanceId) -> u32 {
    let (lo, hi) = (
        FieldConfig::object(0).log2_table_size,
        FieldConfig::nerfacto(0).log2_table_size,
    );
    let mut silhouettes: Vec<usize> = views
        .par_iter()
        .filter_map(|v| {
            let n = v.ids.as_ref()?.iter().filter(|&&i| i == id).count();
            (n > 0).then_some(n)
        })
        .collect();
    if silhouettes.is_empty() {
        return lo;
    }
    silhouettes.sort_unstable();
    let median = silhouettes[silhouettes.len() / 2] as f64;
    let need = (median * SURFACE_PER_SILHOUETTE).log2().ceil();
    (need.max(0.0) as u32).clamp(lo, hi)
}

/// A new, untrained field for object `node` (its seed from the node's id) with 2^`table`
/// hash-table entries per level ([`object_table_log2`]), as training gives every object
/// of a dataset.
pub fn object_field(
    opts: &SetupOptions,
    n_images: usize,
    node: &SceneNode,
    table: u32,
) -> Result<NodeField> {
    let mut c = FieldConfig::object(n_images);
    c.log2_table_size = table;
    c.reflect = opts.reflect;
    if !opts.appearance {
        c.appearance_dim = 0;
    }
    let field = Field::new(c, opts.seed + node.id as u64)?;
    Ok(NodeField::new(
        field,
        training_grid(opts.object_grid),
        node.half_size,
    ))
}

/// Refresh samples each occupancy cell takes before training may empty it (see
/// [`OccupancyGrid::start_warmup`]).
pub const OCCUPANCY_WARMUP: u8 = 4;

/// A new node's occupancy grid: every cell occupied until its warm-up is over.
fn training_grid(res: u32) -> OccupancyGrid {
    let mut g = OccupancyGrid::new(res);
    g.start_warmup(OCCUPANCY_WARMUP);
    g
}

/// Where an object box comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BoxSource {
    /// `--boxes`, used as given.
    User,
    /// The dataset's `bbox`, plus the margin.
    Dataset,
    /// Carved from the instance masks (visual hull), plus the margin.
    Carved,
}

/// The box of one object node.
#[derive(Debug, Clone)]
pub struct NodeBox {
    pub id: InstanceId,
    pub label: String,
    pub obb: Obb,
    pub source: BoxSource,
}

/// The region the background node covers: the dataset's bounds united with what the
/// training depth maps see.
pub fn scene_region(ds: &Dataset, views: &[View]) -> Aabb {
    match depth_bounds(views) {
        Some(b) => b.union(&Aabb::new(ds.bounds.min, ds.bounds.max)),
        None => Aabb::new(ds.bounds.min, ds.bounds.max),
    }
}

/// The inner region of a contracted background (kept linearly; everything beyond it is
/// contracted): the camera centres united with where most of the content is — the 5th to
/// 95th percentile of the sparse points, else the views' frustums between the near bound
/// and the geometric mean of the near and far bounds (LLFF), else a cube around the point
/// the cameras look at reaching the median camera distance.
pub fn unbounded_inner_region(ds: &Dataset, views: &[View]) -> Aabb {
    let mut cams = Aabb::empty();
    for v in views {
        cams.extend(v.camera.pose.center());
    }
    let content = if ds.points.len() >= 20 {
        assist_data::dataset::percentile_aabb(&ds.points, 50)
    } else if let Some((near, far)) = ds.depth_range {
        let mid = (near * far).sqrt();
        let mut b = Aabb::empty();
        for v in views {
            let c = &v.camera;
            let (w, h) = (c.width() as f64, c.height() as f64);
            for (u, t) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h), (w / 2.0, h / 2.0)] {
                for z in [near, mid] {
                    if let Some(p) = c.unproject(u, t, z) {
                        b.extend(p);
                    }
                }
            }
        }
        b
    } else {
        carve_region(views, &cams)
    };
    let mut b = cams.union(&content);
    // A degenerate box (one camera, points on a plane) gets some thickness.
    let s = b.size().max_element().max(1e-6);
    let pad = (DVec3::splat(0.05 * s) - b.size() * 0.5).max(DVec3::ZERO);
    b = Aabb::new(b.min - pad, b.max + pad);
    b
}

/// Near plane of a scene (not of an object capture): half the distance to the closest
/// content any view sees — the 1st percentile of the depth maps' depths, else of the
/// sparse points' depths in the views that see them, else the LLFF near bound; 0 when
/// unknown. Keeps each view from painting its own haze
/// right in front of its camera.
pub fn near_plane(ds: &Dataset, views: &[View]) -> f64 {
    if let Some(z) = crate::content_depth_percentile(&ds.points, views, 1) {
        return 0.5 * z;
    }
    match ds.depth_range {
        Some((near, _)) if near > 0.0 => 0.5 * near,
        _ => 0.0,
    }
}

/// The object nodes' boxes: one per declared instance, else per id the masks contain.
/// A user box that names no instance is an error.
pub fn node_boxes(
    ds: &Dataset,
    views: &[View],
    region: &Aabb,
    opts: &SetupOptions,
) -> Result<Vec<NodeBox>> {
    let mut ids: Vec<(InstanceId, String, Option<Obb>)> = ds
        .instances
        .iter()
        .map(|i| (i.id, i.label.clone(), i.bbox))
        .collect();
    if ids.is_empty() {
        let mut seen = std::collections::BTreeSet::new();
        for v in views {
            if let Some(m) = &v.ids {
                seen.extend(m.iter().copied().filter(|&i| i != 0));
            }
        }
        let name = ds
            .root
            .file_name()
            .map(|n| n.to_string_lossy().trim_end_matches("_400").to_string())
            .unwrap_or_else(|| "object".into());
        for id in seen {
            let label = if id == 1 && is_object_capture(ds) {
                name.clone()
            } else {
                format!("object {id}")
            };
            ids.push((id, label, None));
        }
    }
    let mut used = vec![false; opts.boxes.len()];
    let mut out = Vec::with_capacity(ids.len());
    for (id, label, bbox) in ids {
        let mut user: Option<&BoxOverride> = None;
        for (u, b) in opts.boxes.iter().enumerate() {
            if b.matches(id, &label)? {
                if let Some(prev) = user {
                    return Err(TrainError::Other(format!(
                        "{}: {} and {} both give a box for instance {id} ({label:?})",
                        b.file.display(),
                        prev.entry,
                        b.entry
                    )));
                }
                used[u] = true;
                user = Some(b);
            }
        }
        let user = user.map(|b| b.bbox);
        let grow = |b: Obb| Obb {
            half_size: b.half_size * (1.0 + 2.0 * opts.margin),
            ..b
        };
        let (obb, source) = match (user, bbox) {
            (Some(b), _) => (b, BoxSource::User),
            (None, Some(b)) => (grow(b), BoxSource::Dataset),
            (None, None) => {
                let carved = carve_box(views, id, &carve_region(views, region)).ok_or_else(|| {
                    TrainError::Other(format!(
                        "instance {id} ({label}): no box in the dataset and none could be carved from the masks (is it visible in the training images? `--boxes` can give one)"
                    ))
                })?;
                let b = Obb {
                    center: carved.center(),
                    half_size: carved.size() * 0.5,
                    rotation: assist_core::DMat3::IDENTITY,
                };
                (grow(b), BoxSource::Carved)
            }
        };
        out.push(NodeBox {
            id,
            label,
            obb,
            source,
        });
    }
    if let Some(u) = used.iter().position(|&u| !u) {
        let b = &opts.boxes[u];
        let known: Vec<String> = out
            .iter()
            .map(|n| format!("{} {:?}", n.id, n.label))
            .collect();
        return Err(TrainError::Other(format!(
            "{}: {}: names no instance of {} (its instances: {})",
            b.file.display(),
            b.entry,
            ds.root.display(),
            if known.is_empty() {
                "none".to_string()
            } else {
                known.join(", ")
            }
        )));
    }
    Ok(out)
}

/// Bounds of what the training depth maps see (0.2nd–99.8th percentile per axis of the
/// back-projected pixels, every 4th pixel in each direction); `None` without depth.
pub fn depth_bounds(views: &[View]) -> Option<Aabb> {
    let pts: Vec<DVec3> = views
        .par_iter()
        .flat_map_iter(|v| {
            let d = v.depth.as_ref();
            (0..v.height)
                .step_by(4)
                .flat_map(move |j| (0..v.width).step_by(4).map(move |i| (i, j)))
                .filter_map(move |(i, j)| {
                    let z = *d?.get(j * v.width + i)?;
                    (z > 0.0)
                        .then(|| v.camera.unproject(i as f64 + 0.5, j as f64 + 0.5, z as f64))?
                })
        })
        .collect();
    if pts.len() < 100 {
        return None;
    }
    let mut b = assist_data::dataset::percentile_aabb(&pts, 2);
    for v in views {
        b.extend(v.camera.pose.center());
    }
    Some(b)
}

/// Where to carve: the scene region united with a cube around the point the cameras look
/// at (least-squares intersection of their optical axes) reaching the median camera
/// distance — for object captures whose cameras all sit on one side of the object.
pub fn carve_region(views: &[View], region: &Aabb) -> Aabb {
    let Some(focus) = crate::focus_point(views) else {
        return *region;
    };
    let mut dist: Vec<f64> = views
        .iter()
        .map(|v| (v.camera.pose.center() - focus).length())
        .collect();
    dist.sort_by(f64::total_cmp);
    let r = dist[dist.len() / 2];
    region.union(&Aabb::new(focus - DVec3::splat(r), focus + DVec3::splat(r)))
}

/// Visual hull of instance `id`: voxels seen by at least a quarter of the masked views that
/// project inside the mask in every view that sees them (allowing 5% disagreeing views for
/// mask noise). Carved twice: over `region` (96³), then again (64³) over what the first
/// pass kept, grown by two of its voxels — so the box is as fine as a few millimetres for a
/// small object in a room-sized region. Returns the bounding box of the kept voxels, grown
/// by one (fine) voxel.
pub fn carve_box(views: &[View], id: InstanceId, region: &Aabb) -> Option<Aabb> {
    let coarse = carve_pass(views, id, region, 96)?;
    let voxel = region.size() / 96.0;
    let refined = Aabb::new(coarse.min - voxel, coarse.max + voxel);
    carve_pass(views, id, &refined, 64).or(Some(coarse))
}

fn carve_pass(views: &[View], id: InstanceId, region: &Aabb, g: usize) -> Option<Aabb> {
    let size = region.size();
    let voxel = size / g as f64;
    // A voxel must be seen by a quarter of the masked views: regions only a few cameras see
    // (e.g. right in front of one camera) are not constrained enough to be kept.
    let masked = views.iter().filter(|v| v.ids.is_some()).count();
    let min_seen = (masked / 4).max(2);
    let kept: Vec<DVec3> = (0..g * g * g)
        .into_par_iter()
        .filter_map(|c| {
            let p = region.min
                + DVec3::new(
                    (c % g) as f64 + 0.5,
                    ((c / g) % g) as f64 + 0.5,
                    (c / (g * g)) as f64 + 0.5,
                ) * voxel;
            let (mut inside, mut outside) = (0usize, 0usize);
            for v in views {
                let Some(ids) = &v.ids else { continue };
                let Some((px, _)) = v.camera.project(p) else {
                    continue;
                };
                if px.x < 0.0 || px.y < 0.0 || px.x >= v.width as f64 || px.y >= v.height as f64 {
                    continue;
                }
                if ids[px.y as usize * v.width + px.x as usize] == id {
                    inside += 1;
                } else {
                    outside += 1;
                }
            }
            let seen = inside + outside;
            (seen >= min_seen && outside * 20 <= seen).then_some(p)
        })
        .collect();
    if kept.is_empty() {
        return None;
    }
    let mut b = Aabb::empty();
    for p in kept {
        b.extend(p - voxel);
        b.extend(p + voxel);
    }
    Some(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 512×512 view whose first `n` pixels belong to instance 7.
    fn seen(n: usize) -> View {
        let mut v = View::blank(512, 512);
        let mut ids = vec![0u16; 512 * 512];
        ids[..n].fill(7);
        v.ids = Some(ids);
        v
    }

    #[test]
    fn an_objects_table_holds_its_surface_between_the_object_and_background_sizes() {
        // Small on screen (a desk mug): the object default.
        assert_eq!(object_table_log2(&[seen(3000), seen(4000)], 7), 16);
        // Median silhouette 40,000 px: 160,000 surface cells need 2^18.
        let views = [seen(10), seen(40_000), seen(50_000), View::blank(512, 512)];
        assert_eq!(object_table_log2(&views, 7), 18);
        // Half of every view (a walk-around's subject): capped at the background's.
        assert_eq!(
            object_table_log2(&[seen(131_072), seen(140_000), seen(200_000)], 7),
            19
        );
        // Seen nowhere, or another id: the default.
        assert_eq!(object_table_log2(&[], 7), 16);
        assert_eq!(object_table_log2(&[seen(131_072)], 3), 16);
    }
}
