//! Shadow rays and shadows re-cast under the key light: transmittance against the
//! analytic `exp(−σ·L)`, a moved object's re-cast grid against the grid computed directly
//! at its new pose, and the renderer using it.

mod common;

use assist_core::{DVec3, KeyLight, ShadowCast, Similarity3};
use assist_field::{OccupancyGrid, ShadeGrid};
use assist_render::light::{Occluder, light_points, recast};

fn grid(res: u32, sigma: f32) -> OccupancyGrid {
    let mut g = OccupancyGrid::new(res);
    g.density = vec![sigma; (res as usize).pow(3)];
    g
}

fn at(t: DVec3) -> Similarity3 {
    Similarity3::from_translation(t)
}

#[test]
fn transmittance_is_exp_of_density_times_path_length() {
    let occ = grid(16, 2.0);
    let pose = at(DVec3::new(0.3, -0.2, 0.5));
    let o = Occluder {
        occupancy: &occ,
        half_size: DVec3::splat(0.5),
        pose: &pose,
    };
    let c = pose.translation;
    // Straight through the unit box: path length 1.
    let t = o.transmittance(c - DVec3::Z * 2.0, c + DVec3::Z * 3.0);
    assert!((t - (-2.0f32).exp()).abs() < 1e-4, "{t}");
    // Diagonally through two opposite edges: path length √2.
    let t = o.transmittance(
        c + DVec3::new(-2.0, 0.0, -2.0),
        c + DVec3::new(2.0, 0.0, 2.0),
    );
    let want = (-2.0 * 2f32.sqrt()).exp();
    assert!((t - want).abs() < 0.02 * want, "{t} vs {want}");
    // Missing the box, or stopping short of it.
    assert_eq!(
        o.transmittance(
            c + DVec3::new(2.0, 0.0, -2.0),
            c + DVec3::new(2.0, 0.0, 2.0)
        ),
        1.0
    );
    assert_eq!(o.transmittance(c - DVec3::Z * 3.0, c - DVec3::Z * 1.0), 1.0);
    // Starting inside: only the part beyond the point counts.
    let t = o.transmittance(c, c + DVec3::Z * 3.0);
    assert!((t - (-1.0f32).exp()).abs() < 1e-4, "{t}");
    // Empty and opaque boxes.
    let empty = grid(16, 0.0);
    let e = Occluder {
        occupancy: &empty,
        ..o
    };
    assert_eq!(e.transmittance(c - DVec3::Z * 2.0, c + DVec3::Z * 3.0), 1.0);
    let solid = grid(16, 1e6);
    let s = Occluder {
        occupancy: &solid,
        ..o
    };
    assert_eq!(s.transmittance(c - DVec3::Z * 2.0, c + DVec3::Z * 3.0), 0.0);
}

#[test]
fn transmittance_follows_the_pose_rotation_and_scale() {
    // Density only in the box's +x half: a ray along local z through x > 0 is attenuated,
    // through x < 0 not; turned a quarter about z, the dense half is world +y.
    let mut occ = grid(16, 0.0);
    for z in 0..16 {
        for y in 0..16 {
            for x in 8..16 {
                occ.density[x + 16 * (y + 16 * z)] = 3.0;
            }
        }
    }
    let pose = Similarity3 {
        rotation: assist_core::DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        translation: DVec3::ZERO,
        scale: DVec3::splat(2.0),
    };
    let o = Occluder {
        occupancy: &occ,
        half_size: DVec3::splat(0.5),
        pose: &pose,
    };
    let through = |y: f64| o.transmittance(DVec3::new(0.0, y, -5.0), DVec3::new(0.0, y, 5.0));
    // Local path length 1 (the box is 1 local unit tall, 2 world units).
    assert!((through(0.5) - (-3.0f32).exp()).abs() < 1e-4);
    assert_eq!(through(-0.5), 1.0);
}

#[test]
fn light_points_lie_on_the_disc_facing_up() {
    let l = KeyLight {
        position: DVec3::new(1.0, 2.0, 3.0),
        radius: 0.4,
    };
    let pts = light_points(&l, DVec3::Z);
    assert_eq!(pts.len(), assist_render::light::LIGHT_SAMPLES);
    assert_eq!(pts[0], l.position);
    for p in &pts[1..] {
        assert!((p.z - 3.0).abs() < 1e-12);
        assert!(((*p - l.position).length() - 0.4 / 2f64.sqrt()).abs() < 1e-12);
    }
    let point = KeyLight { radius: 0.0, ..l };
    assert_eq!(light_points(&point, DVec3::Z), vec![l.position]);
}

/// `1 − k·(1 − V)` at every lattice point of a grid of `res` points over `extent` boxes,
/// for the object posed at `pose`.
fn lamp_grid(o: &Occluder, res: usize, extent: f32, k: [f32; 3], lights: &[DVec3]) -> ShadeGrid {
    let mut g = ShadeGrid::new(res, extent);
    let c = |i: usize| (i as f64 / (res - 1) as f64 * 2.0 - 1.0) * extent as f64;
    for z in 0..res {
        for y in 0..res {
            for x in 0..res {
                let b = DVec3::new(c(x), c(y), c(z)) * o.half_size;
                let v = o.visibility(o.pose.transform_point(b), lights);
                let i = x + res * (y + res * z);
                for ch in 0..3 {
                    g.values[3 * i + ch] = 1.0 - k[ch] * (1.0 - v);
                }
            }
        }
    }
    g
}

#[test]
fn a_moved_objects_shadow_is_recast_as_the_lamp_casts_it_there() {
    let occ = grid(16, 1e4);
    let half = DVec3::splat(0.05);
    let then = at(DVec3::new(0.2, -0.1, 0.05));
    let now = Similarity3 {
        rotation: assist_core::DQuat::from_rotation_z(0.7),
        translation: DVec3::new(-0.1, 0.15, 0.05),
        scale: DVec3::ONE,
    };
    let light = KeyLight {
        position: DVec3::new(0.5, -0.5, 1.2),
        radius: 0.15,
    };
    let lights = light_points(&light, DVec3::Z);
    let k = [0.5, 0.4, 0.3];
    let o = |pose| Occluder {
        occupancy: &occ,
        half_size: half,
        pose,
    };
    let learned = lamp_grid(&o(&then), 30, 3.0, k, &lights);
    let want = lamp_grid(&o(&now), 30, 3.0, k, &lights);
    let cast = ShadowCast {
        pose: then,
        strength: k,
    };
    let got = recast(&learned, &occ, half, &now, &cast, &lights);
    let mae = |a: &ShadeGrid, b: &ShadeGrid| {
        a.values
            .iter()
            .zip(&b.values)
            .map(|(x, y)| (x - y).abs() as f64)
            .sum::<f64>()
            / a.values.len() as f64
    };
    let carried = mae(&learned, &want);
    let recast_err = mae(&got, &want);
    assert!(carried > 0.005, "the test must move the shadow: {carried}");
    assert!(
        recast_err < 0.4 * carried,
        "recast {recast_err} vs carried {carried}"
    );
    // Not moved: unchanged.
    let same = recast(&learned, &occ, half, &then, &cast, &lights);
    assert!(mae(&same, &learned) < 1e-6);
}

#[test]
fn casters_use_the_recast_grid_only_for_moved_objects() {
    use assist_scene::NodeField;
    let half = 0.05;
    let then = at(DVec3::new(0.0, 0.0, 0.05));
    let mut n = common::node(1, "obj", half, then);
    n.cast = Some(ShadowCast {
        pose: then,
        strength: [0.5; 3],
    });
    let mut scene = common::scene(
        vec![n],
        vec![("obj", common::constant_field(5.0, [0.5; 3], false, 1))],
        0.0,
    );
    scene.scene.light = Some(KeyLight {
        position: DVec3::new(0.3, 0.0, 1.0),
        radius: 0.0,
    });
    let nf = std::sync::Arc::make_mut(scene.fields.get_mut("obj").unwrap());
    *nf = NodeField {
        occupancy: grid(16, 1e4),
        shade: Some(ShadeGrid::new(20, 3.0)),
        ..nf.clone()
    };
    let learned = |s: &assist_scene::NeuralScene| {
        matches!(
            assist_render::casters(s)[0].grid,
            assist_render::CasterGrid::Learned(_)
        )
    };
    assert!(learned(&scene));
    scene.scene.nodes[0].world_from_local = at(DVec3::new(0.6, 0.0, 0.05));
    let cs = assist_render::casters(&scene);
    assert!(!learned(&scene));
    // Moved past the lamp's foot, its shadow falls on the other side, where none was
    // learned.
    let min = cs[0].grid.values.iter().copied().fold(1.0f32, f32::min);
    assert!(min < 0.9, "{min}");
    // Without a light, or without a cast, the learned grid.
    let mut no_light = scene.clone();
    no_light.scene.light = None;
    assert!(learned(&no_light));
    scene.scene.nodes[0].cast = None;
    assert!(learned(&scene));
}
