#![allow(dead_code)] // each test binary uses a part of these
//! What the GPU tests share: the adapter (or a loud skip), the field configurations
//! tested, and fields with every parameter random.

use assist_core::Rng;
use assist_field::{Field, FieldConfig};
use assist_gpu::{DeviceChoice, Gpu, GpuError};

/// The first adapter of any kind; `None` (a loud skip) without one, unless
/// `ASSIST_REQUIRE_GPU=1` (CI) makes that a failure.
pub fn gpu() -> Option<Gpu> {
    match Gpu::open(DeviceChoice::Gpu) {
        Ok(g) => {
            eprintln!("GPU tests on {}", g.as_ref().expect("gpu").name());
            g
        }
        Err(GpuError::NoAdapter) if std::env::var("ASSIST_REQUIRE_GPU").as_deref() != Ok("1") => {
            eprintln!("SKIPPED: no GPU adapter (install mesa-vulkan-drivers for lavapipe)");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// A field whose every parameter is random at a scale where each part matters: grid
/// entries ±0.5 (so the encoding, not only the biases, drives the outputs), weights
/// He-uniform, biases ±0.1, codes ±0.5.
pub fn random_field(cfg: FieldConfig, seed: u64) -> Field {
    let mut f = Field::new(cfg, seed).expect("config");
    let mut rng = Rng::new(seed + 7);
    let grid = f.layout.grid.param_count();
    for p in &mut f.params[..grid] {
        *p = rng.f32() - 0.5;
    }
    let layers: Vec<_> = f
        .layout
        .density
        .iter()
        .chain(&f.layout.color)
        .copied()
        .collect();
    for l in layers {
        for o in 0..l.out {
            f.params[l.b + o] = (rng.f32() - 0.5) * 0.2;
        }
    }
    for p in &mut f.params[f.layout.appearance..] {
        *p = rng.f32() - 0.5;
    }
    f
}

/// Nerfacto's nets with a small table, and a configuration of other widths.
pub fn configs() -> Vec<(&'static str, FieldConfig)> {
    vec![
        // Nerfacto's nets with a small table (dense and hashed levels both present).
        (
            "nerfacto nets, T = 2^14",
            FieldConfig {
                log2_table_size: 14,
                ..FieldConfig::nerfacto(6)
            },
        ),
        // Other widths: F = 4, one colour hidden layer, SH degree 3, no appearance codes.
        (
            "F 4, 1 colour layer, SH 3, no codes",
            FieldConfig {
                levels: 6,
                features_per_level: 4,
                log2_table_size: 12,
                base_resolution: 4,
                max_resolution: 64,
                hidden: 32,
                geo_features: 7,
                color_hidden: 32,
                color_layers: 1,
                sh_degree: 3,
                appearance_dim: 0,
                num_images: 0,
                reflect: false,
            },
        ),
    ]
}
