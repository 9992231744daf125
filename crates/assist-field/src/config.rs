//! Field configuration: hash-grid and MLP sizes, with Nerfacto's defaults and a smaller
//! object-node preset.

use serde::{Deserialize, Serialize};

use crate::error::FieldError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldConfig {
    /// Hash-grid levels L.
    pub levels: usize,
    /// Features per level F.
    pub features_per_level: usize,
    /// log2 of the table size T per level.
    pub log2_table_size: u32,
    /// Resolution of the coarsest level.
    pub base_resolution: u32,
    /// Resolution of the finest level (geometric growth in between).
    pub max_resolution: u32,
    /// Hidden width of the density net (encoding → hidden → 1 + geo).
    pub hidden: usize,
    /// Geometry feature width passed from the density net to the colour net.
    pub geo_features: usize,
    /// Hidden width of the colour net.
    pub color_hidden: usize,
    /// Hidden layers of the colour net (Nerfacto: 2, i.e. three linear layers).
    pub color_layers: usize,
    /// Spherical-harmonics degree of the view encoding (4 → 16 coefficients).
    pub sh_degree: usize,
    /// Per-image appearance embedding width (0 = none).
    pub appearance_dim: usize,
    /// Number of images with an appearance code.
    pub num_images: usize,
    /// Reflected view direction (Ref-NeRF): the density net also predicts a surface
    /// normal, and the colour net sees the view direction mirrored about it instead of
    /// the view direction itself, so a shiny surface's reflections vary with one
    /// direction shared by all its points rather than with position and view together.
    #[serde(default)]
    pub reflect: bool,
}

/// Most images a field keeps appearance codes for.
pub const MAX_IMAGES: usize = 1 << 20;

impl FieldConfig {
    /// Parameters of a field of this configuration (without making one).
    pub fn param_count(&self) -> usize {
        crate::ParamLayout::new(self).total
    }

    /// Nerfacto's field: 16 levels × 2 features, T = 2^19, resolutions 16 → 2048, 64-wide
    /// nets, geometry feature 15, SH degree 4, appearance embedding 32.
    pub fn nerfacto(num_images: usize) -> Self {
        FieldConfig {
            levels: 16,
            features_per_level: 2,
            log2_table_size: 19,
            base_resolution: 16,
            max_resolution: 2048,
            hidden: 64,
            geo_features: 15,
            color_hidden: 64,
            color_layers: 2,
            sh_degree: 4,
            appearance_dim: 32,
            num_images,
            reflect: false,
        }
    }

    /// An object node: the same nets, a smaller table (2^16) and finest resolution 1024
    /// over the object's own box.
    pub fn object(num_images: usize) -> Self {
        FieldConfig {
            log2_table_size: 16,
            max_resolution: 1024,
            ..Self::nerfacto(num_images)
        }
    }

    pub fn validate(&self) -> Result<(), FieldError> {
        let bad = |f: &str, m: String| {
            Err(FieldError::Config {
                field: f.into(),
                message: m,
            })
        };
        if !(1..=32).contains(&self.levels) {
            return bad("levels", format!("expected 1 to 32, got {}", self.levels));
        }
        if ![1, 2, 4, 8].contains(&self.features_per_level) {
            return bad(
                "features_per_level",
                format!("expected 1, 2, 4 or 8, got {}", self.features_per_level),
            );
        }
        if !(8..=24).contains(&self.log2_table_size) {
            return bad(
                "log2_table_size",
                format!("expected 8 to 24, got {}", self.log2_table_size),
            );
        }
        if self.base_resolution < 2
            || self.max_resolution < self.base_resolution
            || self.max_resolution > 1 << 20
        {
            return bad(
                "max_resolution",
                format!(
                    "expected 2 ≤ base ({}) ≤ max ({}) ≤ 2^20",
                    self.base_resolution, self.max_resolution
                ),
            );
        }
        for (name, w) in [("hidden", self.hidden), ("color_hidden", self.color_hidden)] {
            if w == 0 || w > 256 || w % 16 != 0 {
                return bad(
                    name,
                    format!("expected a multiple of 16 from 16 to 256, got {w}"),
                );
            }
        }
        if self.geo_features == 0 || self.geo_features > 64 {
            return bad(
                "geo_features",
                format!("expected 1 to 64, got {}", self.geo_features),
            );
        }
        if self.color_layers == 0 || self.color_layers > 4 {
            return bad(
                "color_layers",
                format!("expected 1 to 4, got {}", self.color_layers),
            );
        }
        if self.sh_degree == 0 || self.sh_degree > 4 {
            return bad(
                "sh_degree",
                format!("expected 1 to 4, got {}", self.sh_degree),
            );
        }
        if self.appearance_dim > 256 {
            return bad(
                "appearance_dim",
                format!("expected 0 to 256, got {}", self.appearance_dim),
            );
        }
        if self.num_images > MAX_IMAGES {
            return bad(
                "num_images",
                format!("expected at most {MAX_IMAGES}, got {}", self.num_images),
            );
        }
        if self.appearance_dim > 0 && self.num_images == 0 {
            return bad(
                "num_images",
                "an appearance embedding needs at least one image".into(),
            );
        }
        Ok(())
    }

    /// Width of the encoding (L · F).
    pub fn encoding_width(&self) -> usize {
        self.levels * self.features_per_level
    }
    /// Rows per chunk of the encoded features: L · F rounded up to 16 (extra rows zero).
    pub fn encoding_rows(&self) -> usize {
        self.encoding_width().div_ceil(16) * 16
    }
    pub fn sh_width(&self) -> usize {
        self.sh_degree * self.sh_degree
    }
    /// Outputs of the density net: raw density, the geometry feature and, with
    /// [`reflect`](Self::reflect), the predicted normal's three components.
    pub fn density_outputs(&self) -> usize {
        1 + self.geo_features + if self.reflect { 3 } else { 0 }
    }
}
