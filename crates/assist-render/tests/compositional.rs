//! Compositional rendering against hand-computed cases, invariances of node poses, and
//! the batch backward pass against central finite differences.

mod common;
use common::{constant_field, node, scene};

use assist_core::{Camera, DQuat, DVec3, Intrinsics, Pose, Ray, Rng, Similarity3};
use assist_render::{
    BatchOutput, Behind, CompositeGrad, RayBatch, RayOutputs, RenderOptions, SampleOptions, Traced,
    composite_batch, distortion_distance, render_camera, render_rays, sample_rays,
};
use assist_scene::NeuralScene;

fn trace_one(
    s: &NeuralScene,
    ray: Ray,
) -> (assist_render::Composite, Vec<assist_render::Composite>) {
    let mut sc = assist_render::RenderScratch::default();
    sc.rays.push(&ray, u32::MAX);
    render_rays(s, &RenderOptions::default(), &mut sc);
    (sc.out.rays[0], sc.out.nodes.clone())
}

#[test]
fn two_overlapping_boxes_match_the_closed_form() {
    // Unit cubes (diagonal √3) at z = −3 and z = −3.5; the ray from the origin along −z
    // crosses A on [2.5, 3.5] and B on [3.0, 4.0].
    let (sa, sb) = (6.0f32, 3.0f32);
    let (ca, cb) = ([0.9f32, 0.2, 0.1], [0.1f32, 0.8, 0.3]);
    let s = scene(
        vec![
            node(
                1,
                "a",
                0.5,
                Similarity3::from_translation(DVec3::new(0.0, 0.0, -3.0)),
            ),
            node(
                2,
                "b",
                0.5,
                Similarity3::from_translation(DVec3::new(0.0, 0.0, -3.5)),
            ),
        ],
        vec![
            ("a", constant_field(sa, ca, false, 1)),
            ("b", constant_field(sb, cb, false, 2)),
        ],
        0.0,
    );
    let (c, per) = trace_one(&s, Ray::new(DVec3::ZERO, DVec3::new(0.0, 0.0, -1.0)));
    // Densities per world unit.
    let unit = 3f64.sqrt();
    let (da, db) = (sa as f64 / unit, sb as f64 / unit);
    // Segments: A alone 0.5, both 0.5, B alone 0.5.
    let mut t_acc = 1.0f64;
    let mut col = [0.0f64; 3];
    let mut depth = 0.0f64;
    for (t0, a, b) in [(2.5, da, 0.0), (3.0, da, db), (3.5, 0.0, db)] {
        let s_tot: f64 = a + b;
        let l = 0.5;
        let alpha = 1.0 - (-s_tot * l).exp();
        for k in 0..3 {
            col[k] += t_acc * alpha * (a * ca[k] as f64 + b * cb[k] as f64) / s_tot;
        }
        // ∫ T(t) σ t dt over the segment, closed form.
        let e = (-s_tot * l).exp();
        depth += t_acc * (t0 * (1.0 - e) + (1.0 - e * (1.0 + s_tot * l)) / s_tot);
        t_acc *= e;
    }
    let opacity = 1.0 - t_acc;
    col[2] += t_acc; // blue background
    for k in 0..3 {
        assert!(
            (c.rgb[k] as f64 - col[k]).abs() < 5e-3,
            "rgb {:?} vs {:?}",
            c.rgb,
            col
        );
    }
    assert!(
        (c.opacity as f64 - opacity).abs() < 5e-3,
        "{} vs {opacity}",
        c.opacity
    );
    assert!(
        (c.depth as f64 - depth).abs() < 1e-2,
        "{} vs {depth}",
        c.depth
    );
    // Each node alone: opacity 1 − exp(−σ·1).
    assert!((per[0].opacity as f64 - (1.0 - (-da).exp())).abs() < 5e-3);
    assert!((per[1].opacity as f64 - (1.0 - (-db).exp())).abs() < 5e-3);
}

#[test]
fn scaling_a_node_keeps_its_opacity() {
    let f = constant_field(2.0, [0.5, 0.5, 0.5], false, 3);
    let at = DVec3::new(0.0, 0.0, -5.0);
    let ray = Ray::new(DVec3::ZERO, DVec3::new(0.0, 0.0, -1.0));
    let base = scene(
        vec![node(1, "a", 0.5, Similarity3::from_translation(at))],
        vec![("a", f.clone())],
        0.0,
    );
    let (c0, _) = trace_one(&base, ray);
    for scale in [
        DVec3::splat(2.5),
        DVec3::new(1.0, 1.0, 3.0),
        DVec3::new(0.4, 2.0, 0.7),
    ] {
        let pose = Similarity3::new(DQuat::IDENTITY, at, scale).unwrap();
        let s = scene(vec![node(1, "a", 0.5, pose)], vec![("a", f.clone())], 0.0);
        let (c, _) = trace_one(&s, ray);
        assert!(
            (c.opacity - c0.opacity).abs() < 5e-3,
            "scale {scale:?}: {} vs {}",
            c.opacity,
            c0.opacity
        );
        assert!(c0.opacity > 0.3 && c0.opacity < 0.95);
    }
}

#[test]
fn rotating_a_node_rotates_its_view_dependence() {
    let f = constant_field(40.0, [0.0; 3], true, 4);
    let center = DVec3::new(0.3, -0.2, 0.5);
    let intr = Intrinsics::from_fov_x(9, 9, 0.3);
    let eye = center + DVec3::new(3.0, 1.0, 0.5);
    let cam = Camera {
        intrinsics: intr,
        pose: Pose::look_at(eye, center, DVec3::Z).unwrap(),
    };
    let rot = DQuat::from_rotation_z(1.1) * DQuat::from_rotation_x(0.4);
    let eye_r = center + rot * (eye - center);
    let up_r = rot * DVec3::Z;
    let cam_r = Camera {
        intrinsics: intr,
        pose: Pose::look_at(eye_r, center, up_r).unwrap(),
    };
    let plain = scene(
        vec![node(1, "a", 0.5, Similarity3::from_translation(center))],
        vec![("a", f.clone())],
        0.0,
    );
    let pose = Similarity3::new(rot, center, DVec3::ONE).unwrap();
    let rotated = scene(vec![node(1, "a", 0.5, pose)], vec![("a", f)], 0.0);
    let o = RenderOptions::default();
    let a = render_camera(&plain, &cam, u32::MAX, &o);
    let b = render_camera(&rotated, &cam_r, u32::MAX, &o);
    let c = render_camera(&rotated, &cam, u32::MAX, &o);
    let centre = 3 * (4 * 9 + 4);
    let diff = |x: &[f32], y: &[f32]| {
        (0..3)
            .map(|k| (x[centre + k] - y[centre + k]).abs())
            .fold(0.0, f32::max)
    };
    // Rotating node and camera together changes nothing; rotating the node alone changes
    // the colour seen from the same camera (the field is view dependent).
    assert!(diff(&a.rgb, &b.rgb) < 2e-3, "{}", diff(&a.rgb, &b.rgb));
    assert!(diff(&a.rgb, &c.rgb) > 1e-2, "{}", diff(&a.rgb, &c.rgb));
    assert_eq!(a.panoptic[4 * 9 + 4], 1);
}

#[test]
fn batch_backward_matches_finite_differences() {
    // Two random fields in overlapping boxes; a loss linear in every composite output (the
    // ray's colour, depth, opacity and distortion, each node's colour, depth, opacity and
    // share) with random coefficients; dL/dσ and dL/drgb of every sample against central
    // differences. The distortion's coefficient is scaled up so that its term is not lost
    // in the tolerance.
    let mut fields = Vec::new();
    for (k, seed) in [("a", 5u64), ("b", 6)] {
        let mut f = constant_field(1.0, [0.5; 3], true, seed);
        // Random density too: restore random first-layer weights of the density net.
        let mut rng = Rng::new(seed);
        let d1 = f.layout.density[0];
        for p in &mut f.params[d1.w..d1.w + d1.out * d1.inp_pad] {
            *p = (rng.f32() - 0.5) * 0.5;
        }
        let d2 = f.layout.density[1];
        for p in &mut f.params[d2.w..d2.w + d2.out * d2.inp_pad] {
            *p = (rng.f32() - 0.5) * 0.5;
        }
        fields.push((k, f));
    }
    let s = scene(
        vec![
            node(
                0,
                "a",
                1.0,
                Similarity3::from_translation(DVec3::new(0.0, 0.0, -3.0)),
            ),
            node(
                3,
                "b",
                0.4,
                Similarity3::new(
                    DQuat::from_rotation_y(0.5),
                    DVec3::new(0.1, 0.0, -2.8),
                    DVec3::new(1.0, 1.5, 0.8),
                )
                .unwrap(),
            ),
        ],
        fields,
        1.0 / 64.0,
    );
    let mut rays = RayBatch::default();
    let mut rng = Rng::new(9);
    for _ in 0..6 {
        let d = DVec3::new(rng.range(-0.1, 0.1), rng.range(-0.1, 0.1), -1.0).normalize();
        rays.push(&Ray::new(DVec3::ZERO, d), u32::MAX);
    }
    let mut traced = Traced::default();
    let so = SampleOptions {
        jitter: true,
        seed: 1,
        max_per_node: 40,
        step_scale: 1.0,
        keep_proposal: false,
    };
    sample_rays(&s, &rays, &so, &mut traced);
    assert!(traced.nodes.iter().all(|n| n.len() > 10));
    // Each node's opacity beyond a depth inside both boxes.
    traced.beyond = (0..traced.rays).map(|r| 2.75 + 0.04 * r as f32).collect();
    // And in front of another.
    traced.front = (0..traced.rays).map(|r| 2.85 - 0.03 * r as f32).collect();
    let mut tapes = Vec::new();
    let q = assist_render::Query::Render {
        precision: assist_field::Precision::F32,
        highlight: None,
        tables: None,
        backend: None,
        eye: None,
    };
    assist_render::query_fields(&s, &mut traced, &mut tapes, q);
    let bg = s.scene.background_color;
    const DIST: f32 = 20.0;
    // The distortion against its definition, Σ_{i,j} w_i w_j |s_i − s_j| over the merged
    // samples, in world distance (unit 0) and in the normalised distance with its unit
    // inside the boxes (samples on both sides of it).
    for unit in [0.0, 2.9] {
        let mut out = BatchOutput::default();
        let mut t2 = traced.clone();
        t2.distortion_unit = unit;
        composite_batch(&mut t2, Behind::Color(bg), &mut out, None);
        let mut beyond_seen = Vec::new();
        let mut front_seen = Vec::new();
        for r in 0..traced.rays {
            let mut merged: Vec<assist_render::RaySample> = Vec::new();
            for ns in &traced.nodes {
                for j in ns.range(r) {
                    merged.push(assist_render::RaySample {
                        sigma: ns.sigma[j],
                        rgb: [ns.rgb[3 * j], ns.rgb[3 * j + 1], ns.rgb[3 * j + 2]],
                        t: ns.t[j],
                        dt: ns.dt[j],
                    });
                }
            }
            merged.sort_by(|a, b| a.t.total_cmp(&b.t));
            let mut w = vec![0.0; merged.len()];
            assist_render::composite(&merged, bg, Some(&mut w));
            let mut d = 0.0f64;
            for i in 0..w.len() {
                for j in 0..w.len() {
                    let s = |q: usize| distortion_distance(merged[q].t, unit);
                    d += (w[i] * w[j] * (s(i) - s(j)).abs()) as f64;
                }
            }
            assert!(
                (out.distortion[r] as f64 - d).abs() < 1e-4 * (1.0 + d),
                "ray {r}: distortion {} against {d}",
                out.distortion[r]
            );
            assert!(d > 1e-3, "ray {r}: distortion {d} too small to test");
            // Each node's opacity beyond `traced.beyond[r]`, from its own weights.
            for (k, ns) in traced.nodes.iter().enumerate() {
                let alone: Vec<assist_render::RaySample> = ns
                    .range(r)
                    .map(|j| assist_render::RaySample {
                        sigma: ns.sigma[j],
                        rgb: [ns.rgb[3 * j], ns.rgb[3 * j + 1], ns.rgb[3 * j + 2]],
                        t: ns.t[j],
                        dt: ns.dt[j],
                    })
                    .collect();
                let mut w = vec![0.0; alone.len()];
                let c = assist_render::composite(&alone, [0.0; 3], Some(&mut w));
                let b: f32 = (0..w.len())
                    .filter(|&j| alone[j].t >= traced.beyond[r])
                    .map(|j| w[j])
                    .sum();
                let got = out.nodes[r * 2 + k].beyond;
                assert!(
                    (got - b).abs() < 1e-5,
                    "ray {r} node {k}: beyond {got} against {b}"
                );
                beyond_seen.push((b, c.opacity));
                let f: f32 = (0..w.len())
                    .filter(|&j| alone[j].t < traced.front[r])
                    .map(|j| w[j])
                    .sum();
                let got = out.nodes[r * 2 + k].front;
                assert!(
                    (got - f).abs() < 1e-5,
                    "ray {r} node {k}: front {got} against {f}"
                );
                front_seen.push((f, c.opacity));
            }
            assert_eq!(out.rays[r].beyond, 0.0, "the merged composite has none");
            assert_eq!(out.rays[r].front, 0.0, "the merged composite has none");
        }
        assert!(
            front_seen.iter().any(|&(f, o)| f > 0.05 && f < o - 0.05),
            "no ray has part of a node's weight on each side of its front: {front_seen:?}"
        );
        assert!(
            beyond_seen.iter().any(|&(b, o)| b > 0.05 && b < o - 0.05),
            "no ray has part of a node's weight on each side of its depth: {beyond_seen:?}"
        );
    }
    // The gradients below with the normalised distance (world distance is unit 0: the
    // same code with s = t).
    traced.distortion_unit = 2.9;
    let coef: Vec<f32> = (0..6 * 32).map(|_| rng.f32() - 0.5).collect();
    let loss = |out: &BatchOutput| -> f64 {
        let mut l = 0.0f64;
        for r in 0..out.rays.len() {
            let c = &out.rays[r];
            let q = &coef[r * 32..];
            l += (q[0] * c.rgb[0]
                + q[1] * c.rgb[1]
                + q[2] * c.rgb[2]
                + q[3] * c.depth
                + q[4] * c.opacity
                + q[18] * c.depth_sq
                + DIST * q[17] * out.distortion[r]) as f64;
            for k in 0..2 {
                let p = &out.nodes[r * 2 + k];
                let a = &q[5 + 5 * k..];
                l += (a[0] * p.rgb[0]
                    + a[1] * p.rgb[1]
                    + a[2] * p.rgb[2]
                    + a[3] * p.depth
                    + a[4] * p.opacity
                    + q[19 + k] * p.depth_sq
                    + q[21 + k] * p.beyond
                    + q[23 + k] * p.front
                    + q[15 + k] * out.share[r * 2 + k]) as f64;
            }
        }
        l
    };
    let grad = |o: &RayOutputs, g: &mut CompositeGrad, gn: &mut [CompositeGrad]| {
        let q = &coef[o.ray * 32..];
        *g = CompositeGrad {
            rgb: [q[0], q[1], q[2]],
            depth: q[3],
            opacity: q[4],
            depth_sq: q[18],
            share: 0.0,
            distortion: DIST * q[17],
            beyond: 0.0,
            front: 0.0,
        };
        for k in 0..2 {
            let p = &q[5 + 5 * k..];
            gn[k] = CompositeGrad {
                rgb: [p[0], p[1], p[2]],
                depth: p[3],
                opacity: p[4],
                depth_sq: q[19 + k],
                share: q[15 + k],
                distortion: 0.0,
                beyond: q[21 + k],
                front: q[23 + k],
            };
        }
    };
    // Node 0's samples are shaded in the composite (as objects' shadows shade the
    // background's): the shade's gradient is checked with the others.
    traced.nodes[0].shade = (0..3 * traced.nodes[0].len())
        .map(|_| 0.3 + 0.7 * rng.f32())
        .collect();
    // Over a background colour, and showing the last sample past the transmittance.
    let mut failures = Vec::new();
    for behind in [Behind::Color(bg), Behind::LastSample] {
        let mut out = BatchOutput::default();
        for ns in traced.nodes.iter_mut() {
            ns.prepare_outputs(true);
        }
        composite_batch(&mut traced, behind, &mut out, Some(&grad));
        let h = 1e-3f32;
        for k in 0..2 {
            for i in 0..traced.nodes[k].len() {
                // σ, the colour's channels, and (node 0) the shade's channels.
                for which in 0..if k == 0 { 7 } else { 4 } {
                    let analytic = match which {
                        0 => traced.nodes[k].d_sigma[i],
                        4..=6 => traced.nodes[k].d_shade[3 * i + which - 4],
                        _ => traced.nodes[k].d_rgb[3 * i + which - 1],
                    };
                    let eval = |delta: f32| {
                        let mut t = traced.clone();
                        match which {
                            0 => t.nodes[k].sigma[i] += delta,
                            4..=6 => t.nodes[k].shade[3 * i + which - 4] += delta,
                            _ => t.nodes[k].rgb[3 * i + which - 1] += delta,
                        }
                        let mut o = BatchOutput::default();
                        composite_batch(&mut t, behind, &mut o, None);
                        loss(&o)
                    };
                    let fd = ((eval(h) - eval(-h)) / (2.0 * h as f64)) as f32;
                    if (fd - analytic).abs() > 2e-3 * (1.0 + fd.abs()) {
                        failures.push(format!(
                            "{behind:?} node {k} sample {i} input {which}: fd {fd} analytic {analytic}"
                        ));
                    }
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
