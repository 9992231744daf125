//! Re-rendering one camera while one node moves (a viewer's drag): the other nodes'
//! samples and field outputs along every ray do not change, so they are kept, and so is
//! the last image. Each update samples the moving node again, and only the rays that cross
//! its box before or after the move are queried and composited again; every other pixel
//! keeps its value. The result is the same image [`render_camera`] gives (tested bit for
//! bit).

use std::sync::Arc;

use rayon::prelude::*;

use assist_core::{Camera, InstanceId, SceneNode};
use assist_field::{LitCells, Precision, Tape};
use assist_scene::NeuralScene;

use crate::batch::{BatchOutput, Behind, composite_batch};
use crate::march::{sample_rays, sample_rays_node};
use crate::prune::{PruneScratch, query_node_pruned, query_pruned};
use crate::render::{
    Query, RenderOptions, RenderedImage, camera_batch, query_fields, query_node, render_camera,
};
use crate::sample::{NodeSamples, RayBatch, SampleOptions, Traced};

/// What a cached frame depends on besides the moving node's pose.
#[derive(Debug, Clone, PartialEq)]
struct Key {
    camera: Camera,
    image: u32,
    moving: usize,
    highlight: Option<(InstanceId, [f32; 3])>,
    precision: Precision,
    max_per_node: usize,
    prune_eps: f32,
    step_scale: f32,
    /// The packed tables read, by identity (their contents follow from `fields`).
    tables: Option<usize>,
    rays_per_batch: usize,
    layers: bool,
    near: f64,
    /// What the shading and the backdrop read from the scene besides its nodes: the key
    /// light (re-cast shadows), whether it relights moved objects, the up it faces, the
    /// backdrop.
    light: Option<assist_core::KeyLight>,
    relight: bool,
    up: assist_core::DVec3,
    behind: Behind,
    /// Every node but the moving one.
    others: Vec<SceneNode>,
    /// Every field, by identity.
    fields: Vec<(String, usize)>,
}

struct Batch {
    rays: RayBatch,
    pixels: Vec<usize>,
    cos: Vec<f32>,
    traced: Traced,
    /// Per ray, what [`crate::batch::recolour`] needs besides the samples: the colour of
    /// the unshaded samples and the last sample ([`BatchOutput::unshaded`], `last`).
    unshaded: Vec<[f32; 3]>,
    last: Vec<(u32, u32)>,
    /// What re-shading the background after a move keeps between updates.
    kept: crate::reshade::Kept,
}

/// The kept samples of one camera's frame (about 60 bytes per sample: a 480×360 frame of
/// a trained room holds tens of megabytes).
#[derive(Default)]
pub struct DragCache {
    key: Option<Key>,
    batches: Vec<Batch>,
    /// The last image rendered with this cache.
    image: Option<RenderedImage>,
    /// The moving node as the last render saw it, and the cells of its shadow grid that
    /// shaded nothing there.
    moved: Option<SceneNode>,
    moved_lit: Option<LitCells>,
    /// Per caster of the scene ([`crate::shade::casters`]), the cells of its grid that
    /// shade nothing; `None` for the moving node (its grid changes as it moves).
    lits: Vec<Option<LitCells>>,
    work: Work,
}

/// Work buffers of an update.
#[derive(Default)]
struct Work {
    tape: Tape,
    out: BatchOutput,
    /// The moving node's new samples.
    fresh: NodeSamples,
    /// The rays composited again (the node crosses them, before or after) and their
    /// samples.
    affected: Vec<usize>,
    sub: Traced,
    /// The rays whose shading alone changed: coloured again without compositing.
    recoloured: Vec<usize>,
    /// Per ray, whether its shading changed.
    shade_changed: Vec<bool>,
    pixels: Vec<usize>,
    cos: Vec<f32>,
    prune: PruneScratch,
}

impl DragCache {
    /// Whether the next render of the same camera and scene (but the moving node) will
    /// reuse the kept samples.
    pub fn is_warm(&self) -> bool {
        self.key.is_some()
    }

    /// Drops what is kept.
    pub fn clear(&mut self) {
        self.key = None;
        self.batches.clear();
        self.image = None;
        self.moved = None;
        self.moved_lit = None;
        self.lits.clear();
    }
}

/// How a render with `opts` samples (no jitter) and queries its fields.
fn sampling_and_query(opts: &RenderOptions) -> (SampleOptions, Query<'_>) {
    let so = opts.sample_options();
    let q = Query::Render {
        precision: opts.precision,
        highlight: opts.highlight,
        tables: opts.tables.as_deref(),
        backend: opts.backend.as_deref(),
        eye: opts.eye,
    };
    (so, q)
}

fn key(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
    moving: usize,
) -> Key {
    Key {
        camera: *camera,
        image,
        moving,
        highlight: opts.highlight,
        precision: opts.precision,
        max_per_node: opts.max_per_node,
        prune_eps: opts.prune_eps,
        step_scale: opts.step_scale,
        tables: opts
            .tables
            .as_ref()
            .map(|t| std::sync::Arc::as_ptr(t) as usize),
        rays_per_batch: opts.batch_rays(),
        layers: opts.layers,
        near: scene.scene.near,
        light: scene.scene.light,
        relight: scene.scene.relight,
        up: scene.scene.up,
        behind: Behind::of(&scene.scene),
        others: scene
            .scene
            .nodes
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != moving)
            .map(|(_, n)| n.clone())
            .collect(),
        fields: scene
            .fields
            .iter()
            .map(|(k, f)| (k.clone(), Arc::as_ptr(f) as usize))
            .collect(),
    }
}

/// Renders `camera` as [`render_camera`] does. When the last render with `cache` was of the
/// same camera and options, and only node `moving` has changed since, only that node is
/// sampled and queried again.
pub fn render_camera_moving(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
    moving: InstanceId,
    cache: &mut DragCache,
) -> RenderedImage {
    let opts = &*crate::appearance::seen_from(opts, camera, image);
    let Some(k) = scene.scene.nodes.iter().position(|n| n.id == moving) else {
        cache.clear();
        return render_camera(scene, camera, image, opts);
    };
    let (so, q) = sampling_and_query(opts);
    let behind = Behind::of(&scene.scene);
    let key = key(scene, camera, image, opts, k);
    if cache.key.as_ref() == Some(&key)
        && let Some(mut img) = cache.image.take()
    {
        let c = &mut *cache;
        // A node that casts a shadow moves it: the background's shade is computed again
        // and every ray whose shade changed is composited again too.
        let bg = scene
            .field_of(k)
            .shade
            .as_ref()
            .and_then(|_| scene.scene.nodes.iter().position(|n| n.is_background()));
        let before = c.moved.take();
        let casters = bg.map(|_| crate::shade::casters(scene)).unwrap_or_default();
        let now_lit = crate::shade::lit_cells_of(&casters, k);
        let before_lit = c.moved_lit.take();
        // The other casters are as the kept frame saw them (the key holds them).
        if c.lits.len() != casters.len() {
            c.lits = casters
                .iter()
                .map(|cs| (cs.node != k).then(|| cs.grid.lit_cells()))
                .collect();
        }
        let lits: Option<Vec<&LitCells>> = now_lit.as_ref().and_then(|now| {
            (casters.iter().zip(&c.lits))
                .map(|(cs, l)| if cs.node == k { Some(now) } else { l.as_ref() })
                .collect()
        });
        let w = &mut c.work;
        for b in c.batches.iter_mut() {
            sample_rays_node(scene, k, &b.rays, &so, &mut w.fresh);
            // Only the samples in the moved node's shadow region, before or after, can
            // change their shading; without the node as it was, all are shaded again.
            w.shade_changed.clear();
            w.shade_changed.resize(b.rays.len(), false);
            let mut old_shade = None;
            if let Some(bi) = bg {
                let done = match (&before, &before_lit, &lits) {
                    (Some(n), Some(was), Some(lits)) => crate::reshade::reshade_moved(
                        scene,
                        &b.rays,
                        &mut b.traced,
                        (&casters, lits),
                        k,
                        (n, was),
                        &mut b.kept,
                        &mut w.shade_changed,
                    ),
                    _ => false,
                };
                if !done {
                    b.kept.forget_shaded();
                    let was = std::mem::take(&mut b.traced.nodes[bi].shade);
                    crate::shade::shade_background(scene, &b.rays, &mut b.traced);
                    old_shade = Some(was);
                }
            }
            let old = &b.traced.nodes[k];
            let bg_ns = bg.map(|bi| &b.traced.nodes[bi]);
            let shade_changed = |r: usize| {
                w.shade_changed[r]
                    || old_shade.as_ref().is_some_and(|was| {
                        bg_ns.is_some_and(|ns| {
                            // The ray's three factors per sample, before and after (a
                            // missing side counts as changed).
                            let g = ns.range(r);
                            let s = 3 * g.start..3 * g.end;
                            was.get(s.clone()) != ns.shade.get(s)
                        })
                    })
            };
            // A ray the node crosses, before or after, is composited again; one whose
            // shading alone changed needs only its colour again, from the weights kept.
            w.affected.clear();
            w.recoloured.clear();
            for r in 0..b.rays.len() {
                if !old.range(r).is_empty() || !w.fresh.range(r).is_empty() {
                    w.affected.push(r);
                } else if shade_changed(r) {
                    w.recoloured.push(r);
                }
            }
            recolour_rays(scene, b, behind, w, &mut img);
            if !w.affected.is_empty() {
                composite_again(scene, (k, bg), b, w, (opts, q, behind), &mut img);
            }
            std::mem::swap(&mut b.traced.nodes[k], &mut w.fresh);
        }
        cache.moved = Some(scene.scene.nodes[k].clone());
        cache.moved_lit = now_lit;
        cache.image = Some(img.clone());
        img.fill_unseen();
        return img;
    }
    cache.clear();
    let mut img = render_and_keep(scene, camera, image, opts, cache);
    cache.key = Some(key);
    cache.moved = Some(scene.scene.nodes[k].clone());
    cache.moved_lit = crate::shade::lit_cells_of(&crate::shade::casters(scene), k);
    cache.image = Some(img.clone());
    img.fill_unseen();
    img
}

/// Colours again the rays of `b` whose shading alone changed (`w.recoloured`), from the
/// weights the last composite kept; a ray that cannot be (its weights not kept) joins
/// `w.affected`, to be composited again.
fn recolour_rays(
    scene: &NeuralScene,
    b: &Batch,
    behind: Behind,
    w: &mut Work,
    img: &mut RenderedImage,
) {
    if w.recoloured.is_empty() {
        return;
    }
    let colours: Vec<Option<[f32; 3]>> = w
        .recoloured
        .par_iter()
        .map(|&r| {
            let kept = (b.unshaded[r], b.last[r], img.opacity[b.pixels[r]]);
            crate::batch::recolour(&b.traced, r, behind, kept)
        })
        .collect();
    for (&r, rgb) in w.recoloured.iter().zip(colours) {
        match rgb {
            Some(rgb) => img.set_colour(scene, b.pixels[r], rgb),
            None => w.affected.push(r),
        }
    }
    w.affected.sort_unstable();
}

/// Composites again the rays `w.affected` of `b`: node `k`'s new samples (`w.fresh`)
/// queried, every other node's samples as kept; writes them into `img` and keeps what
/// a later update recolours them from (`bg`: the shaded background's index).
fn composite_again(
    scene: &NeuralScene,
    (k, bg): (usize, Option<usize>),
    b: &mut Batch,
    w: &mut Work,
    (opts, q, behind): (&RenderOptions, Query, Behind),
    img: &mut RenderedImage,
) {
    w.sub.rays = w.affected.len();
    w.sub
        .nodes
        .resize_with(b.traced.nodes.len(), NodeSamples::default);
    for (j, ns) in b.traced.nodes.iter().enumerate() {
        if j == k {
            w.fresh.gather_rays(&w.affected, false, &mut w.sub.nodes[j]);
            // Pruning (each ray by the node's own density) keeps for these rays what a
            // full render keeps.
            let sub = &mut w.sub.nodes[j];
            if opts.prune_eps > 0.0 {
                query_node_pruned(scene, sub, opts.prune_eps, &mut w.prune, &mut w.tape, q);
            } else {
                query_node(scene, sub, &mut w.tape, q);
            }
        } else {
            ns.gather_rays(&w.affected, true, &mut w.sub.nodes[j]);
        }
    }
    composite_batch(&mut w.sub, behind, &mut w.out, None);
    w.pixels.clear();
    w.cos.clear();
    for &r in &w.affected {
        w.pixels.push(b.pixels[r]);
        w.cos.push(b.cos[r]);
    }
    img.write_batch(scene, &w.out, &w.pixels, &w.cos);
    // What a later update recolours these rays from.
    for (i, &r) in w.affected.iter().enumerate() {
        b.unshaded[r] = w.out.unshaded[i];
        b.last[r] = w.out.last[i];
    }
    if let Some(bi) = bg {
        let (sub, ns) = (&w.sub.nodes[bi], &mut b.traced.nodes[bi]);
        if sub.w.len() == sub.len() && ns.w.len() == ns.len() {
            for (i, &r) in w.affected.iter().enumerate() {
                let (from, to) = (sub.range(i), ns.range(r));
                ns.w[to].copy_from_slice(&sub.w[from]);
            }
        } else {
            ns.w.clear();
        }
    }
}

/// A whole render of `camera` whose batches (samples and field outputs) `cache` keeps.
fn render_and_keep(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
    cache: &mut DragCache,
) -> RenderedImage {
    let (so, q) = sampling_and_query(opts);
    let behind = Behind::of(&scene.scene);
    let mut img = RenderedImage::empty(scene, camera, opts.layers);
    let mut tapes = Vec::new();
    let mut p = 0usize;
    loop {
        let mut b = Batch {
            rays: RayBatch {
                near: scene.scene.near as f32,
                ..RayBatch::default()
            },
            pixels: Vec::new(),
            cos: Vec::new(),
            traced: Traced::default(),
            unshaded: Vec::new(),
            last: Vec::new(),
            kept: Default::default(),
        };
        let Some(end) = camera_batch(
            camera,
            image,
            p,
            opts,
            &mut b.rays,
            &mut b.pixels,
            &mut b.cos,
        ) else {
            break;
        };
        sample_rays(scene, &b.rays, &so, &mut b.traced);
        if opts.prune_eps > 0.0 {
            query_pruned(
                scene,
                &mut b.traced,
                opts.prune_eps,
                &mut cache.work.prune,
                &mut tapes,
                q,
            );
        } else {
            query_fields(scene, &mut b.traced, &mut tapes, q);
        }
        crate::shade::shade_background(scene, &b.rays, &mut b.traced);
        let out = &mut cache.work.out;
        composite_batch(&mut b.traced, behind, out, None);
        img.write_batch(scene, out, &b.pixels, &b.cos);
        b.unshaded = std::mem::take(&mut out.unshaded);
        b.last = std::mem::take(&mut out.last);
        cache.batches.push(b);
        p = end;
    }
    img
}
