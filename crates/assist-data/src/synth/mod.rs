//! `synth`: a built-in generator of multi-object tabletop scenes with perfect ground truth.
//!
//! A small CPU ray tracer renders a textured room, a table and 3–6 primitive objects
//! (boxes, balls, cylinders, cones) with procedural textures and distinct colours under an
//! area light with soft shadows, from inward-facing cameras at varied heights. The output
//! is a dataset in exactly the desk format (see `../shared/data/README.md`): images,
//! instance masks, z-depth, oriented boxes, labels, a train/test split, a `background/`
//! render of the test views with every object removed, and `edits/<name>/` renders of the
//! test views after a translate, a rotate and a delete. Deterministic for a seed.

pub mod scene;
pub mod trace;
pub mod write;

pub use scene::CameraPath;
pub use write::{SynthConfig, SynthSummary, generate};
