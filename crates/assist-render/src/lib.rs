//! assist-render: compositional volume rendering of scene nodes.
//!
//! This crate holds the compositing of samples along a ray (paper eq. 1–4) with its
//! backward pass; per-node sampling, depth-sorted merging of nodes, panoptic output and
//! highlight build on it.

pub mod composite;

pub use composite::{Composite, RaySample, composite, composite_backward};
