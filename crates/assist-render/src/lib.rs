//! assist-render: compositional volume rendering of scene nodes (paper eqs. 1–4).
//!
//! A batch of world rays is sampled per node (`sample`): each ray is moved into the node's
//! canonical box, clipped to it and marched through the node's occupancy grid; density is
//! integrated over canonical distance, so a node's opacity does not change when it is moved,
//! rotated or scaled. Each node's field is queried once per batch, the samples of all nodes
//! are merged by depth and composited (`batch`), with per-node colour, depth and opacity
//! and a backward pass into every sample; objects' shadow grids darken the background's
//! samples in the composite (`shade`). `render` turns cameras into images (RGB, z-depth,
//! opacity, panoptic ids, per-node layers, selection highlight). Scenes themselves — nodes
//! with their fields, scene files, the editor — are assist-scene's.

#![forbid(unsafe_code)]

mod alone;
mod appearance;
mod batch;
mod composite;
mod drag;
pub mod fill;
pub mod light;
mod march;
mod overlap;
pub mod proposal;
mod prune;
pub mod relight;
mod render;
mod reshade;
mod sample;
mod shade;
mod tables;

pub use assist_field::{FieldBackend, Precision};
pub use batch::{BatchOutput, Behind, CompositeGrad, GradFn, RayOutputs, composite_batch};
pub use composite::{Composite, RaySample, composite, composite_backward};
pub use drag::{DragCache, render_camera_moving};
pub use march::{sample_rays, sample_rays_node};
pub use prune::{
    PRUNE_EPS, PRUNE_MIN_PER_RAY, PruneBy, PruneScratch, PruneStats, prune_occluded,
    query_node_pruned, query_pruned,
};
pub use render::{
    HIGHLIGHT, NodeLayer, Query, RenderOptions, RenderScratch, RenderStats, RenderedImage,
    query_fields, query_node, render_camera, render_camera_timed, render_rays, render_rays_timed,
};
pub use sample::{HiddenStop, NodeSamples, RayBatch, SampleOptions, Traced, distortion_distance};
pub use shade::{
    Caster, CasterGrid, casters, casts_shadows, shade_background, shade_backward,
    shade_backward_add,
};
pub use tables::SceneTables;
