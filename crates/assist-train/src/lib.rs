//! assist-train: training a compositional scene from posed images and instance masks.
//!
//! `setup` turns a dataset into scene nodes (boxes from the dataset or carved from the
//! masks), `views` loads the training images with their masks and background priors
//! (`prior` within a view, `multiview` from the other views), `trainer` runs the paper's five losses with Adam and checkpoints, and
//! `metrics`/`eval` measure PSNR, SSIM, panoptic mIoU and background quality.

#![forbid(unsafe_code)]

pub mod error;
pub mod eval;
pub mod freespace;
pub mod losses;
pub mod metrics;
pub mod multiview;
pub mod optimizer;
pub mod prior;
pub mod setup;
pub mod trainer;
pub mod views;

pub use error::{Result, TrainError};
pub use optimizer::{CpuOptimizer, NodeOptimizer};
pub use trainer::{TrainOptions, TrainReport, Trainer};
pub use views::{PriorKind, View};
