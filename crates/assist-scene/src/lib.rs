//! assist-scene: a scene as data, apart from rendering and training.
//!
//! A [`NeuralScene`] is a [`assist_core::Scene`] (nodes, boxes, labels) with each node's
//! [`NodeField`] (its radiance field, occupancy grid and marching step) in memory; replicas
//! share one `Arc<NodeField>`. [`scene_file`] saves and loads `NAME.assist/` directories
//! atomically, with the undo history. The [`Editor`] applies actions (validated by
//! assist-core, once) with their weights — importing the fields of nodes added from other
//! scenes — and keeps the undo/redo history. A viewer or a generator holds a scene through
//! this crate without the trainer.

#![forbid(unsafe_code)]

mod editor;
mod node;
pub mod scene_file;

pub use editor::{EditError, Editor, SceneFiles};
pub use node::{
    DEFAULT_CONE, NeuralScene, NodeField, STEPS_PER_DIAGONAL, field_position, world_position,
};
pub use scene_file::SceneFileError;
