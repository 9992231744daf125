//! Re-rendering one camera while one node moves (a viewer's drag): the other nodes'
//! samples and field outputs along every ray do not change, so they are kept; each update
//! re-samples and re-queries the moving node alone and composites again. The result is
//! the same image [`render_camera`] gives (tested bit for bit).

use std::sync::Arc;

use assist_core::{Camera, InstanceId, SceneNode};
use assist_field::{Precision, Tape};
use assist_scene::NeuralScene;

use crate::batch::{BatchOutput, Behind, composite_batch};
use crate::render::{
    Query, RenderOptions, RenderedImage, camera_batch, query_fields, query_node, render_camera,
};
use crate::sample::{RayBatch, SampleOptions, Traced, sample_rays, sample_rays_node};

/// What a cached frame depends on besides the moving node's pose.
#[derive(Debug, Clone, PartialEq)]
struct Key {
    camera: Camera,
    image: u32,
    moving: usize,
    highlight: Option<(InstanceId, [f32; 3])>,
    precision: Precision,
    max_per_node: usize,
    rays_per_batch: usize,
    layers: bool,
    near: f64,
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
}

/// The kept samples of one camera's frame (about 60 bytes per sample: a 480×360 frame of
/// a trained room holds tens of megabytes).
#[derive(Default)]
pub struct DragCache {
    key: Option<Key>,
    batches: Vec<Batch>,
    tape: Tape,
    out: BatchOutput,
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
    }
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
        rays_per_batch: opts.rays_per_batch,
        layers: opts.layers,
        near: scene.scene.near,
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
    let Some(k) = scene.scene.nodes.iter().position(|n| n.id == moving) else {
        cache.clear();
        return render_camera(scene, camera, image, opts);
    };
    if opts.prune_eps > 0.0 {
        // Pruning depends on every node's density along the ray: nothing can be kept.
        cache.clear();
        return render_camera(scene, camera, image, opts);
    }
    let so = SampleOptions {
        jitter: false,
        seed: 0,
        max_per_node: opts.max_per_node,
    };
    let q = Query::Render {
        precision: opts.precision,
        highlight: opts.highlight,
    };
    let behind = Behind::of(&scene.scene);
    let key = key(scene, camera, image, opts, k);
    let mut img = RenderedImage::empty(scene, camera, opts.layers);
    if cache.key.as_ref() == Some(&key) {
        for b in cache.batches.iter_mut() {
            sample_rays_node(scene, k, &b.rays, &so, &mut b.traced.nodes[k]);
            query_node(scene, &mut b.traced.nodes[k], &mut cache.tape, q);
            composite_batch(&mut b.traced, behind, &mut cache.out, None);
            img.write_batch(scene, &cache.out, &b.pixels, &b.cos);
        }
        return img;
    }
    cache.clear();
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
        query_fields(scene, &mut b.traced, &mut tapes, q);
        composite_batch(&mut b.traced, behind, &mut cache.out, None);
        img.write_batch(scene, &cache.out, &b.pixels, &b.cos);
        cache.batches.push(b);
        p = end;
    }
    cache.key = Some(key);
    img
}
