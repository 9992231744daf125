//! Contracted nodes (unbounded backgrounds): samples lie where the contraction puts the
//! world points of the ray, in order, reaching far beyond the box with a bounded count;
//! pruning occluded samples changes renders by less than its threshold.

mod common;

use assist_core::{Camera, DQuat, DVec3, Intrinsics, NodeSpace, Pose, Ray, Rng, Similarity3};
use assist_field::contraction::{FAR_RADIUS, contract_to_unit};
use assist_render::{RayBatch, RenderOptions, SampleOptions, Traced, render_camera, sample_rays};
use assist_scene::NeuralScene;
use common::{constant_field, node, scene};

#[test]
fn contracted_samples_are_the_contracted_ray_points() {
    let pose = Similarity3::new(
        DQuat::from_rotation_z(0.4),
        DVec3::new(1.0, -2.0, 0.5),
        DVec3::splat(1.0),
    )
    .unwrap();
    let mut bg = node(0, "bg", 2.0, pose);
    bg.space = NodeSpace::Contracted;
    let s = scene(
        vec![bg.clone()],
        vec![("bg", constant_field(1.0, [0.5; 3], false, 1))],
        1.0 / 256.0,
    );
    let mut rng = Rng::new(9);
    let mut rays = RayBatch::default();
    let mut world = Vec::new();
    for _ in 0..64 {
        let o = pose.transform_point(DVec3::new(
            rng.range(-1.5, 1.5),
            rng.range(-1.5, 1.5),
            rng.range(-1.5, 1.5),
        ));
        let d = DVec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        )
        .normalize();
        let ray = Ray { origin: o, dir: d };
        rays.push(&ray, 0);
        world.push(ray);
    }
    let mut traced = Traced::default();
    sample_rays(
        &s,
        &rays,
        &SampleOptions {
            jitter: true,
            seed: 3,
            max_per_node: 4096,
            step_scale: 1.0,
            keep_proposal: false,
        },
        &mut traced,
    );
    let ns = &traced.nodes[0];
    for (r, ray) in world.iter().enumerate() {
        let range = ns.range(r);
        assert!(range.len() > 10, "ray {r}: {} samples", range.len());
        // Every ray from inside the box goes to the far shell in a bounded number of steps.
        assert!(range.len() < 1500, "ray {r}: {} samples", range.len());
        let mut last_t = -1.0f32;
        let last = range.end - 1;
        for i in range {
            let t = ns.t[i];
            assert!(t > last_t, "ray {r}: t not increasing");
            last_t = t;
            let local = pose.local_from_world_point(ray.at(t as f64)) / bg.half_size;
            let want = contract_to_unit(local.as_vec3().to_array());
            for a in 0..3 {
                let got = ns.pos[a][i];
                assert!(
                    (got - want[a]).abs() < 1e-3,
                    "ray {r} sample at t {t}: {got} vs {}",
                    want[a]
                );
            }
        }
        // The last interval reaches the far end of the march (it stands for everything
        // beyond): the box diagonal is the density unit, and the pose has scale 1.
        let unit = (bg.half_size * 2.0).length();
        let end = ns.t[last] as f64 + ns.dt[last] as f64 * unit;
        let far = (pose.local_from_world_point(ray.at(end)) / bg.half_size)
            .abs()
            .max_element();
        assert!(
            far > FAR_RADIUS as f64 * 0.9,
            "ray {r} ends at radius {far}"
        );
    }
}

/// A contracted background node and an object node in front of part of it.
fn bg_and_object(bg_field: assist_field::Field, obj_field: assist_field::Field) -> NeuralScene {
    let mut bg = node(0, "bg", 1.0, Similarity3::IDENTITY);
    bg.space = NodeSpace::Contracted;
    let obj = node(
        1,
        "obj",
        0.3,
        Similarity3::from_translation(DVec3::new(0.2, 0.0, 0.0)),
    );
    scene(
        vec![bg, obj],
        vec![("bg", bg_field), ("obj", obj_field)],
        1.0 / 256.0,
    )
}

#[test]
fn pruning_changes_renders_by_less_than_its_threshold() {
    // A dense contracted background and a dense object in front of part of it.
    let s = bg_and_object(
        constant_field(40.0, [0.2, 0.6, 0.3], true, 1),
        constant_field(200.0, [0.9, 0.1, 0.1], true, 2),
    );
    let camera = oblique(32, 24);
    let full = render_camera(
        &s,
        &camera,
        u32::MAX,
        &RenderOptions {
            prune_eps: 0.0,
            ..Default::default()
        },
    );
    let eps = 1e-4;
    let pruned = render_camera(
        &s,
        &camera,
        u32::MAX,
        &RenderOptions {
            prune_eps: eps,
            ..Default::default()
        },
    );
    let mut worst = 0.0f32;
    for (a, b) in full.rgb.iter().zip(&pruned.rgb) {
        worst = worst.max((a - b).abs());
    }
    for (a, b) in full.opacity.iter().zip(&pruned.opacity) {
        worst = worst.max((a - b).abs());
    }
    // bf16 products may differ in the last bits between the two runs' batches.
    assert!(worst < 2.0 * eps + 1e-5, "largest change {worst}");
    assert_eq!(full.panoptic, pruned.panoptic);
}

/// A `w × h` camera looking past the object at the background, from inside the box.
fn oblique(w: u32, h: u32) -> Camera {
    Camera {
        intrinsics: Intrinsics::from_fov_x(w, h, 1.0),
        pose: Pose::look_at(
            DVec3::new(0.0, -0.8, 0.1),
            DVec3::new(0.2, 0.0, 0.0),
            DVec3::Z,
        )
        .unwrap(),
    }
}

/// A field whose output depends on where a sample is: random hash-table entries (±1) and
/// nets, its density raised by `ln_sigma` so rays turn opaque.
fn textured_field(seed: u64, ln_sigma: f32) -> assist_field::Field {
    let mut cfg = assist_field::FieldConfig::object(0);
    cfg.appearance_dim = 0;
    cfg.log2_table_size = 12;
    cfg.levels = 4;
    let mut f = assist_field::Field::new(cfg, seed).unwrap();
    let mut rng = Rng::new(seed + 100);
    let grid = f.layout.grid.param_count();
    for p in &mut f.params[..grid] {
        *p = rng.f32() * 2.0 - 1.0;
    }
    let d2 = f.layout.density[1];
    f.params[d2.b] += ln_sigma;
    f
}

/// The samples of `s` along every pixel's ray of a 24 × 18 [`oblique`] view (no jitter).
fn oblique_samples(s: &NeuralScene) -> Traced {
    let camera = oblique(24, 18);
    let mut rays = RayBatch::default();
    for j in 0..camera.height() {
        for i in 0..camera.width() {
            rays.push(&camera.pixel_ray(i, j).unwrap(), u32::MAX);
        }
    }
    rays.near = 0.01;
    let so = SampleOptions {
        jitter: false,
        seed: 0,
        max_per_node: 1024,
        step_scale: 1.0,
        keep_proposal: false,
    };
    let mut traced = Traced::default();
    sample_rays(s, &rays, &so, &mut traced);
    traced
}

/// A render's query at f32.
fn f32_query() -> assist_render::Query<'static> {
    assist_render::Query::Render {
        precision: assist_field::Precision::F32,
        highlight: None,
        tables: None,
        backend: None,
        eye: None,
    }
}

/// Rendering's pruned query, in rounds along the rays: each ray keeps a prefix of its
/// samples holding every sample whose optical depth in front (through its node) is at
/// most `-ln eps`, drops only samples past that (each weighs less than `eps`), and its
/// kept samples' outputs are those of a full query of every sample.
#[test]
fn the_pruned_query_keeps_a_prefix_and_drops_only_what_weighs_nothing() {
    use assist_render::{PruneScratch, query_fields, query_pruned};
    let s = bg_and_object(textured_field(1, 3.0), textured_field(2, 5.0));
    let eps = 1e-4f32;
    let mut traced = oblique_samples(&s);
    let mut full = traced.clone();
    let q = f32_query();
    let (mut sc, mut tapes) = (PruneScratch::default(), Vec::new());
    query_fields(&s, &mut full, &mut tapes, q);
    let rounds = query_pruned(&s, &mut traced, eps, &mut sc, &mut tapes, q);
    assert!(
        rounds.dropped > 0 && rounds.dropped < rounds.queried,
        "{rounds:?}"
    );
    // Equal but for the last bits: the encoding's vector body and its scalar tail (the
    // last samples of a batch) round differently.
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * x.abs().max(y.abs()).max(1.0);
    let limit = -eps.ln();
    for (a, f) in traced.nodes.iter().zip(&full.nodes) {
        assert_eq!(a.sigma.len(), a.len());
        for ray in 0..a.start.len() - 1 {
            let (kept, all) = (a.range(ray), f.range(ray));
            assert!(kept.len() <= all.len(), "ray {ray}");
            assert_eq!(a.t[kept.clone()], f.t[all.start..all.start + kept.len()]);
            for (i, j) in kept.clone().zip(all.clone()) {
                assert!(close(a.sigma[i], f.sigma[j]), "ray {ray}");
                assert!((0..3).all(|c| close(a.rgb[3 * i + c], f.rgb[3 * j + c])));
            }
            // The optical depth in front of each sample: the first dropped one lies past
            // the limit, every kept one before it need not.
            let mut tau = 0.0f32;
            for (n, j) in all.clone().enumerate() {
                if n == kept.len() {
                    assert!(tau > limit, "ray {ray}: dropped at optical depth {tau}");
                    break;
                }
                tau += f.sigma[j] * f.dt[j];
            }
        }
    }
}

/// A node's batch queried whole (the first, or after one that dropped too little for
/// rounds to pay) has each ray cut afterwards where its rounds would have stopped it: the
/// same samples, the same bits as the rounds.
#[test]
fn a_whole_query_cut_afterwards_keeps_what_the_rounds_keep() {
    use assist_render::{PruneScratch, SceneTables, query_pruned};
    let s = bg_and_object(textured_field(1, 3.0), textured_field(2, 5.0));
    let tables = SceneTables::of(&s);
    let q = assist_render::Query::Render {
        precision: assist_field::Precision::Bf16,
        highlight: None,
        tables: Some(&tables),
        backend: None,
        eye: None,
    };
    let eps = 1e-4f32;
    let traced = oblique_samples(&s);
    let all: usize = traced.nodes.iter().map(|n| n.len()).sum();
    let (mut rounds, mut whole) = (traced.clone(), traced.clone());
    let mut sc = PruneScratch::default();
    sc.query_in_rounds(traced.nodes.len());
    let r = query_pruned(&s, &mut rounds, eps, &mut sc, &mut Vec::new(), q);
    let mut sc = PruneScratch::default();
    let w = query_pruned(&s, &mut whole, eps, &mut sc, &mut Vec::new(), q);
    assert!(r.dropped > 0 && r.queried < all, "{r:?}");
    assert_eq!((w.queried, w.dropped), (all, r.dropped), "{w:?} {r:?}");
    for (a, b) in rounds.nodes.iter().zip(&whole.nodes) {
        assert_eq!(a.start, b.start);
        assert_eq!(a.t, b.t);
        assert_eq!(a.dt, b.dt);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.sigma), bits(&b.sigma));
        assert_eq!(bits(&a.rgb), bits(&b.rgb));
    }
}

/// Training's pruning by the ray's transmittance: a sample is dropped exactly when the
/// optical depth before it, through every node's samples merged in depth, exceeds
/// `-ln eps` (checked against a brute-force merge of the densities); the background
/// behind the opaque object loses samples the node's own transmittance keeps; and with
/// one node it drops what the node's own rule drops.
#[test]
fn pruning_by_the_ray_drops_what_lies_behind_any_node() {
    use assist_render::{PruneBy, PruneScratch, prune_occluded, query_fields};
    let eps = 1e-4f32;
    let limit = -eps.ln();
    let s = bg_and_object(textured_field(1, 1.0), textured_field(2, 6.0));
    let all = oblique_samples(&s);
    let q = f32_query();
    let prune = |scene: &NeuralScene, traced: &Traced, by: PruneBy| {
        let mut t = traced.clone();
        let (mut sc, mut tapes) = (PruneScratch::default(), Vec::new());
        let st = prune_occluded(scene, &mut t, eps, by, &mut sc, &mut tapes);
        (t, st)
    };
    let (by_node, sn) = prune(&s, &all, PruneBy::Node);
    let (by_ray, sr) = prune(&s, &all, PruneBy::Ray);
    assert!(sr.dropped > sn.dropped, "{sr:?} {sn:?}");
    // The reference: every sample's densities, merged per ray in depth.
    let mut full = all.clone();
    query_fields(&s, &mut full, &mut Vec::new(), q);
    let rays_n = full.nodes[0].start.len() - 1;
    let (mut checked, mut behind_object) = (0, 0);
    for r in 0..rays_n {
        let mut merged: Vec<(f32, f32, usize)> = Vec::new();
        for (k, ns) in full.nodes.iter().enumerate() {
            let (a, b) = (ns.start[r] as usize, ns.start[r + 1] as usize);
            merged.extend((a..b).map(|i| (ns.t[i], ns.sigma[i] * ns.dt[i], k)));
        }
        merged.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut tau = 0.0f32;
        for &(t, d, k) in &merged {
            let (ns, pn) = (&by_ray.nodes[k], &by_node.nodes[k]);
            let kept = ns.t[ns.start[r] as usize..ns.start[r + 1] as usize].contains(&t);
            // (Densities from the render's query and the density pass differ in their last
            // bits: samples within a hair of the limit are not judged.)
            if (tau - limit).abs() > 1e-3 * limit {
                assert_eq!(kept, tau <= limit, "ray {r} node {k} t {t}: depth {tau}");
                checked += 1;
                let own = pn.t[pn.start[r] as usize..pn.start[r + 1] as usize].contains(&t);
                if k == 0 && own && !kept {
                    behind_object += 1;
                }
            }
            tau += d;
        }
    }
    assert!(
        checked > 1000 && behind_object > 0,
        "{checked} {behind_object}"
    );
    // One node: the ray's transmittance is the node's own.
    let mut bg_only = s.clone();
    bg_only.scene.nodes.truncate(1);
    let one = oblique_samples(&bg_only);
    let (a, sa) = prune(&bg_only, &one, PruneBy::Node);
    let (b, sb) = prune(&bg_only, &one, PruneBy::Ray);
    assert!(sa.dropped > 0);
    assert_eq!((sa.queried, sa.dropped), (sb.queried, sb.dropped));
    assert_eq!(a.nodes[0].start, b.nodes[0].start);
    assert_eq!(a.nodes[0].t, b.nodes[0].t);
}

/// The packed (bf16) hash tables a render reads at `Precision::Bf16`: a frame within the
/// rounding of bf16 of the f32 one; pruning on them as without them; and tables of a
/// field changed since they were packed (a training step's `Arc::make_mut`) never read.
#[test]
fn packed_tables_render_close_to_f32_and_are_never_stale() {
    use assist_field::Precision;
    use assist_render::SceneTables;
    use std::sync::Arc;
    let s = bg_and_object(textured_field(1, 3.0), textured_field(2, 5.0));
    let camera = oblique(32, 24);
    let tables = Arc::new(SceneTables::of(&s));
    assert!(tables.covers(&s));
    assert!(tables.bytes() > 0);
    let at = |scene: &NeuralScene, precision, tables: Option<&Arc<SceneTables>>, eps| {
        render_camera(
            scene,
            &camera,
            u32::MAX,
            &RenderOptions {
                precision,
                tables: tables.cloned(),
                prune_eps: eps,
                ..Default::default()
            },
        )
    };
    let diff = |a: &[f32], b: &[f32]| {
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        let mean = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.len() as f32;
        (worst, mean)
    };
    let exact = at(&s, Precision::F32, Some(&tables), 0.0);
    let packed = at(&s, Precision::Bf16, Some(&tables), 0.0);
    let (worst, mean) = diff(&exact.rgb, &packed.rgb);
    eprintln!("packed tables against f32: largest colour change {worst}, mean {mean}");
    assert!(worst > 0.0, "the packed tables were not read");
    assert!(worst < 0.02 && mean < 2e-3, "{worst} {mean}");
    assert_eq!(exact.panoptic, packed.panoptic);
    // Without tables given, Bf16 reads the f32 parameters (its products are f32 here
    // unless the CPU has AVX-512 BF16 or AVX2).
    if !assist_simd::reduced_products() {
        assert_eq!(at(&s, Precision::Bf16, None, 0.0).rgb, exact.rgb);
    }
    // Pruning's rounds query the samples in other batches than the unpruned render, which
    // can round their reduced-precision products differently; allowed up to the
    // f32-against-reduced change above.
    let rounding = if assist_simd::reduced_products() {
        worst
    } else {
        0.0
    };
    let pruned = at(&s, Precision::Bf16, Some(&tables), 1e-4);
    let (worst, _) = diff(&packed.rgb, &pruned.rgb);
    assert!(
        worst < 2e-4 + 1e-5 + rounding,
        "pruning on packed tables changed {worst} (products' rounding {rounding})"
    );

    // The object's field changed after packing: its tables are not found (it is read in
    // f32), the background's still are; a refresh packs the new field alone.
    let mut changed = s.clone();
    let obj = Arc::make_mut(changed.fields.get_mut("obj").unwrap());
    let grid = obj.field.layout.grid.param_count();
    for p in &mut obj.field.params[..grid] {
        *p = -*p;
    }
    assert!(!tables.covers(&changed));
    assert!(tables.get(&changed, 1).is_none() && tables.get(&changed, 0).is_some());
    let stale = at(&changed, Precision::Bf16, Some(&tables), 0.0);
    let truth = at(&changed, Precision::F32, None, 0.0);
    let (now, _) = diff(&stale.rgb, &truth.rgb);
    let (before, _) = diff(&exact.rgb, &truth.rgb);
    assert!(
        now < 2e-3 && before > 1e-2,
        "stale tables read? {now} vs {before}"
    );
    let mut fresh = (*tables).clone();
    assert_eq!(fresh.refresh(&changed), 1);
    assert!(fresh.covers(&changed));
}
