//! Scenes built by hand for tests: nodes with constant fields (a density and a colour
//! everywhere in their box), so that a render is known without training.

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{DVec3, NodeSpace, Scene, SceneNode, Similarity3};
use assist_field::{Field, OccupancyGrid};
use assist_scene::{NeuralScene, NodeField};

/// A cube node `half` wide each way at `at`, its field keyed `f{id}`.
pub fn node(id: u16, label: &str, half: f64, at: DVec3) -> SceneNode {
    SceneNode {
        id,
        label: label.into(),
        embedding: None,
        class: None,
        field: format!("f{id}"),
        half_size: DVec3::splat(half),
        world_from_local: Similarity3::from_translation(at),
        space: NodeSpace::Box,
        cast: None,
    }
}

/// A field of constant density `sigma` and colour `rgb`.
pub fn constant(sigma: f32, rgb: [f32; 3], seed: u64) -> Field {
    Field::constant(sigma, rgb, false, seed).expect("a valid constant field")
}

/// A metric, z-up scene of `nodes`, each with the field of the same index (16³ occupancy
/// grids, everything occupied), on a black backdrop.
pub fn scene_of(nodes: Vec<SceneNode>, fields: Vec<Field>) -> NeuralScene {
    assert_eq!(nodes.len(), fields.len(), "one field per node");
    let mut map = BTreeMap::new();
    for (n, f) in nodes.iter().zip(fields) {
        let nf = NodeField::new(f, OccupancyGrid::new(16), n.half_size);
        map.insert(n.field.clone(), Arc::new(nf));
    }
    NeuralScene {
        scene: Scene::with_nodes(nodes, DVec3::Z),
        fields: map,
    }
}

/// A grey room-sized background (density 3) with a red box (1) and a green box (2),
/// `half` wide each way, on the floor 0.3 apart.
pub fn two_boxes(half: f64) -> NeuralScene {
    scene_of(
        vec![
            node(0, "background", 1.5, DVec3::ZERO),
            node(1, "red box", half, DVec3::new(-0.15, 0.0, 0.05)),
            node(2, "green box", half, DVec3::new(0.15, 0.0, 0.05)),
        ],
        vec![
            constant(3.0, [0.5, 0.5, 0.5], 1),
            constant(3000.0, [0.9, 0.1, 0.1], 2),
            constant(3000.0, [0.1, 0.8, 0.2], 3),
        ],
    )
}
