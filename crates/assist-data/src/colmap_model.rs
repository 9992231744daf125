//! COLMAP's sparse model records (cameras, images, points) and its camera-model table,
//! shared by the binary and the text reader.

use std::collections::HashMap;

use assist_core::{DVec2, DVec3};

#[derive(Debug, Clone)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: String,
    pub width: u32,
    pub height: u32,
    pub params: Vec<f64>,
}

#[derive(Debug, Clone)]
pub struct ColmapImage {
    pub id: u32,
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// 2D observations: pixel position and the 3D point id (−1 when none).
    pub points2d: Vec<(DVec2, i64)>,
}

#[derive(Debug, Clone)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: DVec3,
    pub rgb: [u8; 3],
    pub error: f64,
}

#[derive(Debug, Clone, Default)]
pub struct ColmapModel {
    pub cameras: HashMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: HashMap<u64, ColmapPoint>,
}

/// (model id, name, number of parameters), as in COLMAP's `camera_models.h`.
pub(crate) const MODELS: &[(i32, &str, usize)] = &[
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

pub(crate) fn model_name(id: i32) -> Option<(&'static str, usize)> {
    MODELS.iter().find(|m| m.0 == id).map(|m| (m.1, m.2))
}
pub(crate) fn model_params(name: &str) -> Option<usize> {
    MODELS.iter().find(|m| m.1 == name).map(|m| m.2)
}
