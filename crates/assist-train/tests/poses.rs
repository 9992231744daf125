//! The camera-pose refinement's gradient against central differences: the loss of a batch
//! of rays as a function of a view's translation and rotation, with every sample kept at
//! its distance along its ray (as the analytic gradient holds the sampling fixed), through
//! object boxes and a contracted background.

use std::sync::Arc;

use assist_core::{DMat3, DVec3, NodeSpace, Ray, Rng};
use assist_data::LoadOptions;
use assist_data::synth::{SynthConfig, generate};
use assist_field::Tape;
use assist_field::contraction::contract_to_unit;
use assist_render::{Query, RayBatch, SampleOptions, Traced, query_fields, sample_rays};
use assist_scene::NeuralScene;
use assist_testkit::TempDir;
use assist_train::{
    BackgroundSpace, PoseRefiner, SetupOptions, background_color, build_scene, load_views,
};

/// The samples' field positions when the rays are moved by `(t, rot)` (world translation,
/// rotation of the directions), each sample at its recorded distance.
fn positions(
    scene: &NeuralScene,
    traced: &Traced,
    rays: &RayBatch,
    t: DVec3,
    rot: DMat3,
) -> Vec<[Vec<f32>; 3]> {
    traced
        .nodes
        .iter()
        .map(|ns| {
            let node = &scene.scene.nodes[ns.node];
            let nf = scene.field_of(ns.node);
            let mut out: [Vec<f32>; 3] = Default::default();
            for r in 0..rays.len() {
                let o = DVec3::from(rays.origin[r].map(f64::from)) + t;
                let d = rot * DVec3::from(rays.dir[r].map(f64::from));
                for j in ns.start[r] as usize..ns.start[r + 1] as usize {
                    let x = o + ns.t[j] as f64 * d;
                    let l = node.world_from_local.local_from_world_point(x);
                    let p = if nf.space == NodeSpace::Contracted {
                        contract_to_unit((l / node.half_size).as_vec3().to_array())
                    } else {
                        (l / (node.half_size * 2.0) + 0.5).as_vec3().to_array()
                    };
                    for a in 0..3 {
                        out[a].push(p[a]);
                    }
                }
            }
            out
        })
        .collect()
}

/// `L = Σ a·σ + Σ b·rgb` over every node's samples at `pos` (directions as recorded).
fn loss(
    scene: &NeuralScene,
    traced: &Traced,
    pos: &[[Vec<f32>; 3]],
    w: &[(Vec<f32>, Vec<f32>)],
) -> f64 {
    let mut total = 0.0;
    for ((ns, p), (a, b)) in traced.nodes.iter().zip(pos).zip(w) {
        let n = ns.len();
        if n == 0 {
            continue;
        }
        let s = assist_field::Samples {
            pos: [&p[0], &p[1], &p[2]],
            dir: [&ns.dir[0], &ns.dir[1], &ns.dir[2]],
            image: &ns.image,
        };
        let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
        scene
            .field_of(ns.node)
            .field
            .forward(&s, &mut sig, &mut rgb);
        total += sig
            .iter()
            .zip(a)
            .map(|(x, y)| (*x * *y) as f64)
            .sum::<f64>();
        total += rgb
            .iter()
            .zip(b)
            .map(|(x, y)| (*x * *y) as f64)
            .sum::<f64>();
    }
    total
}

#[test]
fn the_pose_gradient_matches_central_differences() {
    let tmp = TempDir::new("pose-grad");
    let data = tmp.join("synth");
    let cfg = SynthConfig {
        views: 6,
        width: 32,
        height: 24,
        ..SynthConfig::default()
    };
    generate(&cfg, &data, false, &|_, _| {}).unwrap();
    let ds = assist_data::load(&data, &LoadOptions::default()).unwrap();
    let views = load_views(&ds, assist_data::Split::Train, background_color(&ds)).unwrap();
    let setup = SetupOptions {
        background_space: BackgroundSpace::Contracted,
        appearance: false,
        ..SetupOptions::default()
    };
    let mut scene = build_scene(&ds, &views, &setup).unwrap();
    assert!(
        scene
            .scene
            .nodes
            .iter()
            .any(|n| n.space == NodeSpace::Contracted)
            && scene.scene.nodes.len() > 1,
        "a contracted background and objects"
    );
    // Tables far from their tiny initial values, so that position matters to the output.
    let mut rng = Rng::new(17);
    for nf in scene.fields.values_mut() {
        let nf = Arc::make_mut(nf);
        // Coarse levels only (finer ones zero): a central difference then rarely
        // straddles a cell face, where the trilinear encoding has a kink.
        let grid = nf.field.layout.grid.clone();
        let f = grid.features;
        for lv in &grid.levels {
            let v = if lv.res <= 24 { 1.0 } else { 0.0 };
            for p in &mut nf.field.params[lv.offset * f..(lv.offset + lv.size as usize) * f] {
                *p = v * (rng.f32() - 0.5);
            }
        }
    }
    // Rays of the first view through every fourth pixel.
    let v = &views[0];
    let mut rays = RayBatch::default();
    for p in (0..v.width * v.height).step_by(4) {
        let ray: Ray = v
            .camera
            .pixel_ray((p % v.width) as u32, (p / v.width) as u32)
            .unwrap();
        rays.push(&ray, u32::MAX);
    }
    rays.near = scene.scene.near as f32;
    let so = SampleOptions {
        jitter: false,
        seed: 1,
        max_per_node: 1024,
        step_scale: 1.0,
        keep_proposal: false,
    };
    let mut traced = Traced::default();
    sample_rays(&scene, &rays, &so, &mut traced);
    let mut tapes: Vec<Tape> = Vec::new();
    query_fields(&scene, &mut traced, &mut tapes, Query::Train);
    let mut weights = Vec::new();
    for (ns, tape) in traced.nodes.iter_mut().zip(tapes.iter_mut()) {
        let n = ns.len();
        // Colour only: the density's scale (up to e^15) would drown a central difference
        // in f32 rounding; the colour depends on position through the same encoding.
        let a: Vec<f32> = vec![0.0; n];
        let b: Vec<f32> = (0..3 * n).map(|_| rng.f32() - 0.5).collect();
        if n > 0 {
            let field = &scene.field_of(ns.node).field;
            let mut grad = vec![0.0f32; field.param_count()];
            field.backward(&ns.samples(), tape, &a, &b, &mut grad);
        }
        weights.push((a, b));
    }
    assert!(traced.nodes.iter().filter(|ns| !ns.is_empty()).count() >= 2);
    // The positions rebuilt from the rays are the sampled ones.
    let here = positions(&scene, &traced, &rays, DVec3::ZERO, DMat3::IDENTITY);
    for (ns, p) in traced.nodes.iter().zip(&here) {
        for a in 0..3 {
            for (x, y) in ns.pos[a].iter().zip(&p[a]) {
                assert!(
                    (x - y).abs() < 1e-4,
                    "node {} axis {a}: sampled {x}, rebuilt {y}",
                    ns.node
                );
            }
        }
    }
    let extent = 2.0f32;
    let mut poses = PoseRefiner::new(1, extent);
    let view_of_ray = vec![0u32; rays.len()];
    poses.accumulate(&scene, &traced, &tapes, &rays, &view_of_ray);
    let g = poses.gradient().to_vec();
    // A unit of translation parameter moves the centre by this much (see `correction`).
    poses.params[0] = 1.0;
    let unit = poses.correction(0).0.length();
    let f = |t: DVec3, w: DVec3| {
        let rot = if w.length() > 0.0 {
            DMat3::from_axis_angle(w.normalize(), w.length())
        } else {
            DMat3::IDENTITY
        };
        loss(
            &scene,
            &traced,
            &positions(&scene, &traced, &rays, t, rot),
            &weights,
        )
    };
    let mut report = Vec::new();
    let mut ok = true;
    let mut pairs = Vec::new();
    for a in 0..6 {
        let mut e = DVec3::ZERO;
        let (num, h) = if a < 3 {
            let h = 1e-5;
            e[a] = h * unit;
            ((f(e, DVec3::ZERO) - f(-e, DVec3::ZERO)) / (2.0 * h), h)
        } else {
            let h = 1e-5;
            e[a - 3] = h;
            ((f(DVec3::ZERO, e) - f(DVec3::ZERO, -e)) / (2.0 * h), h)
        };
        let ana = g[a] as f64;
        report.push(format!(
            "param {a}: analytic {ana:.5} central {num:.5} (h {h})"
        ));
        // Thousands of piecewise-trilinear samples: a few straddle a cell face or a ReLU
        // kink within ±h, so single components agree to tens of percent only (measured:
        // five of six within 8%, one 25%); a wrong sign, scale, frame or transpose is
        // far outside this.
        ok &= (ana - num).abs() <= 0.35 * num.abs().max(ana.abs()) + 1e-3;
        ok &= ana.abs() > 1e-3;
        pairs.push((ana, num));
    }
    let dot: f64 = pairs.iter().map(|(x, y)| x * y).sum();
    let (na, nn) = (
        pairs.iter().map(|(x, _)| x * x).sum::<f64>().sqrt(),
        pairs.iter().map(|(_, y)| y * y).sum::<f64>().sqrt(),
    );
    let cos = dot / (na * nn);
    report.push(format!("cosine {cos:.4}"));
    ok &= cos > 0.97;
    eprintln!("{}", report.join("\n"));
    assert!(ok, "{}", report.join("\n"));
}
