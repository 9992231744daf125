//! Scenes built by hand for the render tests: constant fields and cube nodes.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{DVec3, Scene, SceneNode, Similarity3};
use assist_field::{Field, OccupancyGrid};
use assist_scene::{NeuralScene, NodeField};

/// A field of constant density and colour ([`Field::constant`]).
pub fn constant_field(sigma: f32, rgb: [f32; 3], view_dependent: bool, seed: u64) -> Field {
    Field::constant(sigma, rgb, view_dependent, seed).unwrap()
}

pub fn node(id: u16, key: &str, half: f64, pose: Similarity3) -> SceneNode {
    SceneNode {
        id,
        label: format!("n{id}"),
        embedding: None,
        class: None,
        field: key.into(),
        half_size: DVec3::splat(half),
        world_from_local: pose,
        space: assist_core::NodeSpace::Box,
        cast: None,
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
            background_color: [0.0, 0.0, 1.0],
            ..Scene::with_nodes(nodes, DVec3::Z)
        },
        fields: map,
    }
}
