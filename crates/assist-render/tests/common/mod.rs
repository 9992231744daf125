//! Scenes built by hand for the render tests: constant fields and cube nodes.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{DVec3, Scene, SceneNode, Similarity3};
use assist_field::{Field, FieldConfig, OccupancyGrid};
use assist_render::{NeuralScene, NodeField};

/// A field of constant density (per box diagonal) and colour: every MLP weight zero, the
/// density bias ln σ and the colour bias logit(c). With `view_dependent`, the colour net
/// keeps its random weights, so colour depends on the view direction only.
pub fn constant_field(sigma: f32, rgb: [f32; 3], view_dependent: bool, seed: u64) -> Field {
    let mut cfg = FieldConfig::object(0);
    cfg.appearance_dim = 0;
    cfg.log2_table_size = 12;
    cfg.levels = 4;
    let mut f = Field::new(cfg, seed).unwrap();
    let lay = f.layout.clone();
    let d1 = lay.density[0];
    let d2 = lay.density[1];
    for p in &mut f.params[d1.w..d1.w + d1.out * d1.inp_pad] {
        *p = 0.0;
    }
    for p in &mut f.params[d1.b..d1.b + d1.out] {
        *p = 0.0;
    }
    for p in &mut f.params[d2.w..d2.w + d2.out * d2.inp_pad] {
        *p = 0.0;
    }
    f.params[d2.b] = sigma.ln();
    if !view_dependent {
        for l in &lay.color {
            for p in &mut f.params[l.w..l.w + l.out * l.inp_pad] {
                *p = 0.0;
            }
            for p in &mut f.params[l.b..l.b + l.out] {
                *p = 0.0;
            }
        }
        let last = lay.color.last().unwrap();
        for c in 0..3 {
            f.params[last.b + c] = (rgb[c] / (1.0 - rgb[c])).ln();
        }
    }
    f
}

pub fn node(id: u16, key: &str, half: f64, pose: Similarity3) -> SceneNode {
    SceneNode {
        id,
        label: format!("n{id}"),
        embedding: None,
        field: key.into(),
        half_size: DVec3::splat(half),
        world_from_local: pose,
        space: assist_core::NodeSpace::Box,
    }
}

pub fn scene(nodes: Vec<SceneNode>, fields: Vec<(&str, Field)>, cone: f32) -> NeuralScene {
    let mut map = BTreeMap::new();
    for (k, f) in fields {
        let n = nodes.iter().find(|n| n.field == k).unwrap();
        let mut nf = NodeField::with_space(f, OccupancyGrid::new(16), n.half_size, n.space);
        nf.cone = cone;
        map.insert(k.to_string(), Arc::new(nf));
    }
    NeuralScene {
        scene: Scene {
            nodes,
            up: DVec3::Z,
            meters_per_unit: 1.0,
            background_color: [0.0, 0.0, 1.0],
            backdrop: Default::default(),
            selected: None,
            near: 0.0,
        },
        fields: map,
    }
}
