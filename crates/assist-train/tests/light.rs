//! The key light found from shadow grids a known lamp cast, and none from darkening no
//! lamp explains.

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{DVec3, KeyLight, Scene, SceneNode, Similarity3};
use assist_field::{Field, OccupancyGrid, ShadeGrid};
use assist_render::light::{Occluder, light_points};
use assist_scene::{NeuralScene, NodeField};

const RES: usize = 30;
const EXTENT: f32 = 3.0;

/// Cubes of half size 0.05 standing on the plane z = 0 at `xy`, opaque, with shadow grids
/// `shade(occluder, lattice world point)` at the lattice points within one spacing of the
/// plane (what photographs see) and 1 elsewhere.
fn scene(xy: &[(f64, f64)], shade: impl Fn(&Occluder, DVec3, usize) -> [f32; 3]) -> NeuralScene {
    let half = DVec3::splat(0.05);
    let mut occ = OccupancyGrid::new(16);
    occ.density = vec![1e4; 16 * 16 * 16];
    let mut nodes = Vec::new();
    let mut fields = BTreeMap::new();
    for (i, &(x, y)) in xy.iter().enumerate() {
        let key = format!("object-{}", i + 1);
        let pose = Similarity3::from_translation(DVec3::new(x, y, 0.05));
        let o = Occluder {
            occupancy: &occ,
            half_size: half,
            pose: &pose,
        };
        let mut g = ShadeGrid::new(RES, EXTENT);
        let c = |i: usize| (i as f64 / (RES - 1) as f64 * 2.0 - 1.0) * EXTENT as f64;
        let spacing = 2.0 * EXTENT as f64 * 0.05 / (RES - 1) as f64;
        for z in 0..RES {
            for y in 0..RES {
                for x in 0..RES {
                    let p = pose.transform_point(DVec3::new(c(x), c(y), c(z)) * half);
                    if p.z.abs() > spacing {
                        continue;
                    }
                    let k = x + RES * (y + RES * z);
                    g.values[3 * k..3 * k + 3].copy_from_slice(&shade(&o, p, k));
                }
            }
        }
        let field = Field::constant(5.0, [0.5; 3], false, 1).unwrap();
        let mut nf = NodeField::new(field, occ.clone(), half);
        nf.shade = Some(g);
        fields.insert(key.clone(), Arc::new(nf));
        nodes.push(SceneNode {
            id: i as u16 + 1,
            label: key.clone(),
            embedding: None,
            class: None,
            field: key,
            half_size: half,
            world_from_local: pose,
            space: Default::default(),
            cast: None,
        });
    }
    let mut s = Scene::with_nodes(nodes, DVec3::Z);
    s.light = None;
    NeuralScene { scene: s, fields }
}

/// A tiny deterministic "photograph noise" in (0, 1).
fn noise(k: usize) -> f32 {
    let h = (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
    h as f32 / (1u64 << 24) as f32
}

#[test]
fn the_lamp_that_cast_the_shadows_is_found() {
    let lamp = KeyLight {
        position: DVec3::new(0.6, -0.4, 1.5),
        radius: 0.2,
    };
    let lights = light_points(&lamp, DVec3::Z);
    let k = [0.6, 0.5, 0.4];
    let xy = [(0.0, 0.0), (-0.3, 0.2), (0.2, 0.25), (-0.2, -0.25)];
    let mut scene = scene(&xy, |o, p, i| {
        let v = o.visibility(p, &lights);
        k.map(|k| 1.0 - k * (1.0 - v) - 0.003 * noise(i))
    });
    let e = assist_train::estimate_light(&mut scene);
    let l = e.light.expect("a light");
    assert!(e.explained > 0.8, "{e:?}");
    assert_eq!(scene.scene.light, Some(l));
    // Seen from the objects, the lamp is where it was (its distance matters less).
    let centre = DVec3::ZERO;
    let (want, got) = (lamp.position - centre, l.position - centre);
    let angle = want.angle_between(got).to_degrees();
    assert!(angle < 6.0, "direction off by {angle}°: {l:?}");
    let ratio = got.length() / want.length();
    assert!((0.6..1.6).contains(&ratio), "distance ratio {ratio}: {l:?}");
    // Every object's strength per channel, and its cast where it stands.
    assert_eq!(e.strength.len(), xy.len());
    for n in &scene.scene.nodes {
        let c = n.cast.as_ref().expect("a cast");
        assert_eq!(c.pose, n.world_from_local);
        for ch in 0..3 {
            assert!((c.strength[ch] - k[ch]).abs() < 0.12, "{:?}", c.strength);
        }
        assert!(c.strength[0] > c.strength[2]);
    }
}

#[test]
fn darkening_no_lamp_explains_gives_no_light() {
    let xy = [(0.0, 0.0), (-0.3, 0.2), (0.2, 0.25)];
    // Speckle: dark points here and there, no shadow shape.
    let mut scene = scene(&xy, |_, _, i| [1.0 - 0.3 * noise(i * 7 + 3); 3]);
    let e = assist_train::estimate_light(&mut scene);
    assert!(e.light.is_none(), "{e:?}");
    assert!(e.explained < assist_train::light::MIN_EXPLAINED);
    assert!(scene.scene.light.is_none());
    assert!(scene.scene.nodes.iter().all(|n| n.cast.is_none()));
}

#[test]
fn scenes_without_shadow_grids_are_left_alone() {
    let mut s = scene(&[(0.0, 0.0)], |_, _, _| [1.0; 3]);
    for f in s.fields.values_mut() {
        Arc::make_mut(f).shade = None;
    }
    let e = assist_train::estimate_light(&mut s);
    assert_eq!(e.points, 0);
    assert!(e.light.is_none());
}
