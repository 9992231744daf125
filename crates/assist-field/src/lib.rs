//! assist-field: the neural radiance field of a scene node, on CPU.
//!
//! A multiresolution hash grid (instant-NGP) feeding Nerfacto's tiny MLPs, with
//! hand-written forward and backward passes over batches of samples in structure-of-arrays
//! and chunk-blocked layouts, an Adam kernel over the flat parameter vector, an occupancy
//! grid with empty-space-skipping ray marching, and safetensors serialisation.
//!
//! Speed: level-major encoding (one level's table in cache at a time), backward split per
//! level (no atomics), MLP products through `assist-simd`'s runtime-dispatched GEMM, rayon
//! across cores, buffers reused across steps. The CPU implementation is the reference
//! behind the `Field` API; a second implementation (a GPU) plugs in as a [`FieldBackend`].

#![forbid(unsafe_code)]

mod adam;
mod backend;
mod config;
mod constant;
pub mod contraction;
mod error;
mod field;
pub mod hashgrid;
pub mod io;
mod mlp;
mod occupancy;
pub mod proposal;
mod sh;
pub mod shade;

pub use adam::Adam;
pub use backend::{FieldBackend, FieldQuery};
pub use config::FieldConfig;
pub use error::FieldError;
pub use field::{Field, PackedTables, ParamLayout, PhaseTimes, Precision, Samples, Tape};
pub use mlp::Linear;
pub use occupancy::{ConeRay, ContractedRay, Marching, OccupancyGrid, Step};
pub use proposal::{Proposal, ProposalConfig, ProposalField, ProposalTape};
pub use shade::{LitCells, ShadeGrid};
