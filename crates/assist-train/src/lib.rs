//! assist-train: training a compositional scene from posed images and instance masks.
//!
//! `setup` turns a dataset into scene nodes (boxes from the dataset or carved from the
//! masks), `views` loads the training images with their masks and background priors
//! (`prior` within a view, `multiview` from the other views), `trainer` runs the paper's five losses with Adam and checkpoints, and
//! `metrics`/`eval` measure PSNR, SSIM, panoptic mIoU and background quality.

#![forbid(unsafe_code)]

mod align;
mod distil;
mod error;
mod eval;
mod footprint;
mod freespace;
mod layout;
pub mod light;
pub mod losses;
pub mod metrics;
mod multiview;
mod multiview_cull;
mod optimizer;
mod prior;
mod setup;
pub mod shadow;
mod trainer;
mod views;

pub use align::{AlignOptions, AlignReport, Alignment, align_camera};
pub use distil::{ClearReport, DistilOptions, DistilReport, clear, distil};
pub use error::{Result, TrainError};
pub use eval::{
    EvalReport, EvaluatedView, ImageScore, PriorReport, PriorScore, background_dataset, evaluate,
    evaluate_each, evaluate_priors,
};
pub use footprint::{
    GridResolution, MAX_GRID_RESOLUTION, MIN_GRID_RESOLUTION, background_resolution,
    content_depth_percentile, footprint_resolution,
};
pub use freespace::{CarveStats, carve_scene};
pub use layout::{
    CaptureLayout, LayoutChoice, SURROUND_MAX_GAP_DEGREES, WalkAroundDefaults, azimuth_gap,
    background_grid_resolution, capture_layout, default_grid_resolution, describe_layout,
    focus_point, largest_azimuth_gap, mean_up, scene_takes_walk_around_defaults,
    takes_walk_around_defaults,
};
pub use light::{LightEstimate, estimate_light, estimate_light_from};
pub use multiview::MultiViewStats;
pub use optimizer::{CpuOptimizer, NodeOptimizer, OptimizerFactory};
pub use setup::{
    BackgroundSpace, BoxSource, NodeBox, SetupOptions, background_color, build_scene,
    is_object_capture, near_plane, node_boxes, object_field, object_table_log2,
    scene_param_estimate, scene_region, set_anchors,
};
pub use shadow::{
    ShadowEstimate, ShadowPriorStats, add_shadow_grids, estimate_shadows, shadow_free_priors,
};
pub use trainer::{
    EMPTY_MARGIN, KeptHistory, Lambdas, ObjectRays, POSE_LR, PhaseTimes, PoseRefiner, ResumeState,
    StepStats, StopReason, TERMS, TermInfo, Terms, TrainOptions, TrainReport, Trainer,
    default_error_rays, default_lr_end, default_proposal, default_prune_eps, object_ray_draw, term,
    update_depth_affine,
};
pub use views::{PriorKind, View, fill_prior, fill_priors, load_view, load_views};
