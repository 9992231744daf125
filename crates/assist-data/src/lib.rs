//! assist-data: datasets in, datasets out.
//!
//! Readers for nerfstudio `transforms.json` (with our instance extension), Blender
//! synthetic, COLMAP (binary and text) and LLFF produce one [`Dataset`] type; the format
//! is detected from the path. [`validate`] checks that every referenced file exists and
//! decodes at the declared size. [`synth`] generates multi-object tabletop scenes with a
//! small CPU ray tracer, written in the desk format with perfect ground truth.
//!
//! Parsing is two-stage: raw JSON/binary records are read with their field paths, then
//! validated into typed values; every error names the file and the field.

#![forbid(unsafe_code)]

pub mod blender;
pub mod boxes;
pub mod colmap;
pub mod colmap_bin;
mod colmap_model;
pub mod colmap_text;
pub mod consistency;
pub mod dataset;
pub mod downscale;
pub mod error;
pub mod image_io;
pub mod json;
pub mod llff;
mod load;
pub mod masks;
pub mod nerfstudio;
pub mod npy;
pub mod ply;
pub mod priors;
pub mod synth;
pub mod validate;
pub mod visual;
pub mod writer;

pub use dataset::{
    Dataset, Format, Frame, InstanceInfo, LoadOptions, Normalization, SceneBounds, Split,
};
pub use error::{DataError, Result};
pub use image_io::{IdImage, ImageF32};
pub use load::{detect_format, load};
pub use writer::{DatasetWriter, IdImages, Instance, Layer, Output, ViewImages, WriterConfig};
