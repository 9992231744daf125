//! Objects' shadows on the background: a shadow grid darkens the background around its
//! object in the composited image only (not in the background's own layer), follows the
//! object when it moves and goes with it when it is deleted; and the gradient of the
//! shading with respect to the grid values matches central differences.

mod common;

use std::sync::Arc;

use assist_core::{DVec3, Similarity3};
use assist_field::ShadeGrid;
use assist_render::{
    RayBatch, RenderOptions, RenderScratch, SampleOptions, Traced, render_rays, sample_rays,
    shade_background, shade_backward, shade_backward_add,
};
use assist_scene::NeuralScene;
use common::{constant_field, node, scene};

const GREY: [f32; 3] = [0.5, 0.5, 0.5];

/// A grey floor (top face at z = −0.2) with a red cube (id 1, half size 0.25) standing at
/// x = −0.6, casting a uniform shadow of factor 0.4 over its region (the box grown 3×).
fn shaded() -> NeuralScene {
    let bg = node(
        0,
        "bg",
        2.0,
        Similarity3::from_translation(DVec3::new(0.0, 0.0, -2.2)),
    );
    let cube = node(
        1,
        "red",
        0.25,
        Similarity3::from_translation(DVec3::new(-0.6, 0.0, 0.05)),
    );
    let mut s = scene(
        vec![bg, cube],
        vec![
            ("bg", constant_field(200.0, GREY, false, 1)),
            ("red", constant_field(200.0, [0.9, 0.1, 0.1], false, 2)),
        ],
        0.0,
    );
    let mut g = ShadeGrid::new(6, 3.0);
    g.values.fill(0.4);
    Arc::make_mut(s.fields.get_mut("red").unwrap()).shade = Some(g);
    s
}

/// Red channel of the composite and of the background alone at the floor point (x, y),
/// seen from 20 units above it.
fn floor_at(s: &NeuralScene, x: f64, y: f64) -> (f32, f32) {
    let (c, layer) = floor_rgb(s, x, y);
    (c[0], layer[0])
}

/// The composite's and the background alone's colour at the floor point (x, y), seen
/// from 20 units above it.
fn floor_rgb(s: &NeuralScene, x: f64, y: f64) -> ([f32; 3], [f32; 3]) {
    let mut sc = RenderScratch::default();
    let target = DVec3::new(x, y, -0.2);
    let origin = DVec3::new(0.0, 0.0, 20.0);
    let ray = assist_core::Ray {
        origin,
        dir: (target - origin).normalize(),
    };
    sc.rays.push(&ray, u32::MAX);
    render_rays(s, &RenderOptions::default(), &mut sc);
    (sc.out.rays[0].rgb, sc.out.nodes[0].rgb)
}

#[test]
fn a_shadow_darkens_the_composite_follows_its_object_and_goes_with_it() {
    let s = shaded();
    // Inside the region (0.5 from the cube's centre, 0.75 reach), outside the cube.
    let (c, layer) = floor_at(&s, -0.1, 0.0);
    assert!((c - 0.4 * GREY[0]).abs() < 0.02, "shadowed floor {c}");
    assert!(
        (layer - GREY[0]).abs() < 0.02,
        "the background alone has no shadow: {layer}"
    );
    // Beyond the region: untouched.
    let (c, _) = floor_at(&s, 0.6, 0.0);
    assert!((c - GREY[0]).abs() < 0.02, "floor away from the cube {c}");
    // Moved 1.2 to the right, the cube shades the floor there and no longer where it was.
    let mut moved = s.clone();
    moved.scene.nodes[1].world_from_local =
        Similarity3::from_translation(DVec3::new(0.6, 0.0, 0.05));
    let (c, _) = floor_at(&moved, 0.1, 0.0);
    assert!(
        (c - 0.4 * GREY[0]).abs() < 0.02,
        "shadow at the new place {c}"
    );
    let (c, _) = floor_at(&moved, -1.1, 0.0);
    assert!((c - GREY[0]).abs() < 0.02, "no shadow at the old place {c}");
    // Deleted, the cube leaves no shadow.
    let mut gone = s.clone();
    gone.scene.nodes.truncate(1);
    let (c, _) = floor_at(&gone, -0.1, 0.0);
    assert!((c - GREY[0]).abs() < 0.02, "shadow of a deleted cube {c}");
    // A tinted shadow (the red cube's light on the floor): each channel has its own factor.
    let mut tinted = s.clone();
    {
        let nf = Arc::make_mut(tinted.fields.get_mut("red").unwrap());
        for p in nf.shade.as_mut().unwrap().values.chunks_exact_mut(3) {
            p.copy_from_slice(&[0.8, 0.4, 0.3]);
        }
    }
    let (c, layer) = floor_rgb(&tinted, -0.1, 0.0);
    for (ch, f) in [0.8, 0.4, 0.3].into_iter().enumerate() {
        assert!((c[ch] - f * GREY[ch]).abs() < 0.02, "channel {ch}: {c:?}");
        assert!((layer[ch] - GREY[ch]).abs() < 0.02, "layer {layer:?}");
    }
}

#[test]
fn the_shadow_gradient_matches_central_differences() {
    // Two overlapping casters, so that the product of their factors is exercised.
    let mut s = shaded();
    let second = node(
        2,
        "blue",
        0.3,
        Similarity3::from_translation(DVec3::new(-0.2, 0.1, 0.1)),
    );
    let f = constant_field(200.0, [0.1, 0.1, 0.9], false, 3);
    let mut nf = assist_scene::NodeField::with_space(
        f,
        assist_field::OccupancyGrid::new(16),
        second.half_size,
        second.space,
    );
    let mut rng = assist_core::Rng::new(7);
    let mut g = ShadeGrid::new(4, 3.0);
    for v in &mut g.values {
        *v = 0.3 + 0.7 * rng.f32();
    }
    nf.shade = Some(g);
    s.fields.insert("blue".into(), Arc::new(nf));
    s.scene.nodes.push(second);
    {
        let red = Arc::make_mut(s.fields.get_mut("red").unwrap());
        for v in &mut red.shade.as_mut().unwrap().values {
            *v = 0.3 + 0.7 * rng.f32();
        }
    }
    // Rays from above onto the floor around both objects.
    let mut rays = RayBatch::default();
    for i in 0..64 {
        let o = DVec3::new(
            -1.2 + 1.6 * rng.f64(),
            -0.8 + 1.6 * rng.f64(),
            3.0 + i as f64 * 0.01,
        );
        let d = DVec3::new(0.1 * (rng.f64() - 0.5), 0.1 * (rng.f64() - 0.5), -1.0).normalize();
        rays.push(&assist_core::Ray { origin: o, dir: d }, 0);
    }
    let mut traced = Traced::default();
    sample_rays(&s, &rays, &SampleOptions::default(), &mut traced);
    shade_background(&s, &rays, &mut traced);
    let n = traced.nodes[0].len();
    assert!(n > 0);
    // A weight per sample and colour channel.
    let coef: Vec<f32> = (0..3 * n).map(|_| rng.f32() - 0.5).collect();
    traced.nodes[0].d_shade = coef.clone();
    let grads = shade_backward(&s, &rays, &traced);
    assert_eq!(grads.len(), 2);
    let loss = |s: &NeuralScene| -> f64 {
        let mut t = traced.clone();
        shade_background(s, &rays, &mut t);
        t.nodes[0]
            .shade
            .iter()
            .zip(&coef)
            .map(|(a, b)| (*a * *b) as f64)
            .sum()
    };
    let mut checked = 0;
    for (k, g) in &grads {
        let key = s.scene.nodes[*k].field.clone();
        for (i, &an) in g.iter().enumerate() {
            let h = 1e-2f32;
            let eval = |delta: f32| {
                let mut s2 = s.clone();
                let nf = Arc::make_mut(s2.fields.get_mut(&key).unwrap());
                nf.shade.as_mut().unwrap().values[i] += delta;
                loss(&s2)
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
            assert!(
                (fd - an as f64).abs() < 1e-3 * (1.0 + fd.abs()),
                "node {k} value {i}: analytic {an}, numeric {fd}"
            );
            checked += usize::from(an.abs() > 1e-3);
        }
    }
    assert!(checked > 20, "only {checked} grid values had a gradient");
    // Into kept buffers (a trainer's): the same bits as alone, then added to what they hold.
    let mut kept = Vec::new();
    shade_backward_add(&s, &rays, &traced, &mut kept);
    assert_eq!(kept, grads);
    shade_backward_add(&s, &rays, &traced, &mut kept);
    for ((k, a), (l, b)) in kept.iter().zip(&grads) {
        assert_eq!(k, l);
        let top = b.iter().fold(0.0f32, |m, y| m.max(y.abs()));
        assert!(top > 0.0);
        assert!(
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - 2.0 * y).abs() <= 1e-5 * top)
        );
    }
    // Buffers that do not fit the casters (another scene's) are replaced.
    kept.truncate(1);
    kept[0].1.push(1.0);
    shade_backward_add(&s, &rays, &traced, &mut kept);
    assert_eq!(kept, grads);
}
