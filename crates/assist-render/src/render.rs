//! Rendering cameras: rays → per-node samples → one field query per node → compositing.
//! Produces RGB, z-depth, opacity, panoptic ids and, on request, per-node layers; the
//! selected node is highlighted by adding a colour to its samples (paper §III-B).

use assist_core::{Camera, InstanceId};
use assist_field::{FieldBackend, Precision, Tape};

use crate::batch::BatchOutput;
use crate::sample::{NodeSamples, RayBatch, SampleOptions, Traced};
use crate::tables::SceneTables;
use assist_scene::NeuralScene;

#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// Node to highlight and the colour added to its samples.
    pub highlight: Option<(InstanceId, [f32; 3])>,
    pub max_per_node: usize,
    /// Rays traced per batch (bounds memory).
    pub rays_per_batch: usize,
    /// Also produce each node's own colour and opacity.
    pub layers: bool,
    /// Also produce the image of the background alone, as a render of the scene without
    /// its objects shows it ([`RenderedImage::background`]).
    pub background_alone: bool,
    /// Arithmetic of the field queries (default `Bf16`: the packed `tables` where given,
    /// the MLP products of `assist_simd::products`; `ASSIST_PRECISION=f32` for f32).
    pub precision: Precision,
    /// Samples behind the point where their node's transmittance falls below this are
    /// dropped: queried in rounds along the rays where many rays stop early, each ray
    /// stopping after the round that takes it below, else queried whole and cut where the
    /// rounds would have stopped (see [`crate::query_node_pruned`]). Default
    /// [`crate::PRUNE_EPS`]: each dropped sample weighs less than it in any output; 0
    /// keeps every sample.
    pub prune_eps: f32,
    /// Marching steps times this (see [`SampleOptions::step_scale`]): 1, the default, as
    /// trained; 2 is `render --quality draft`.
    pub step_scale: f32,
    /// Packed hash tables of the scene's fields (see [`SceneTables`]), read at
    /// `Precision::Bf16`; `None`: every field is encoded from its f32 parameters.
    pub tables: Option<std::sync::Arc<SceneTables>>,
    /// When set (from another thread), a whole-camera render stops after the batch in
    /// hand; the caller that set it discards the partial image.
    pub cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Where the fields are queried when not on this CPU (a GPU, `--device`): every
    /// node's samples go to it in one call; pruning's density pass is then skipped (the
    /// GPU queries all samples for less than the CPU would spend choosing). `None`: the
    /// CPU.
    pub backend: Option<std::sync::Arc<dyn FieldBackend>>,
    /// Where the camera stands (world): samples without an image's code take the blend
    /// of the codes of the training views taken nearest there ([`assist_field::Field::
    /// novel_code`]). `render_camera` sets it from its camera; `None`: the average code.
    pub eye: Option<[f64; 3]>,
}

impl RenderOptions {
    /// Rays per batch as rendered: with a backend at least [`BACKEND_RAYS_PER_BATCH`]
    /// (each batch costs a GPU a round trip, so fewer and larger ones pay).
    pub fn batch_rays(&self) -> usize {
        match self.backend {
            Some(_) => self.rays_per_batch.max(BACKEND_RAYS_PER_BATCH),
            None => self.rays_per_batch,
        }
        .max(1)
    }

    /// How a render with these options samples its rays (no jitter).
    pub fn sample_options(&self) -> SampleOptions {
        SampleOptions {
            jitter: false,
            seed: 0,
            max_per_node: self.max_per_node,
            step_scale: self.step_scale,
            keep_proposal: false,
        }
    }

    pub(crate) fn cancelled(&self) -> bool {
        self.cancel
            .as_ref()
            .is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed))
    }
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            highlight: None,
            max_per_node: 1024,
            rays_per_batch: 1 << 14,
            layers: false,
            background_alone: false,
            precision: Precision::fastest(),
            prune_eps: crate::prune::PRUNE_EPS,
            step_scale: 1.0,
            tables: None,
            cancel: None,
            backend: None,
            eye: None,
        }
    }
}

/// The fewest rays per batch when a backend queries the fields ([`RenderOptions::batch_rays`]).
pub const BACKEND_RAYS_PER_BATCH: usize = 1 << 16;

/// The default highlight colour (added to the selected node's samples).
pub const HIGHLIGHT: [f32; 3] = [0.0, 0.45, 0.25];

/// One node rendered alone.
#[derive(Debug, Clone)]
pub struct NodeLayer {
    pub id: InstanceId,
    pub rgb: Vec<f32>,
    pub opacity: Vec<f32>,
}

#[derive(Debug, Clone)]
pub struct RenderedImage {
    pub width: u32,
    pub height: u32,
    /// Interleaved RGB in [0, 1].
    pub rgb: Vec<f32>,
    /// Z-depth along the camera axis in world units (`D/O`; 0 where nothing is hit).
    pub depth: Vec<f32>,
    pub opacity: Vec<f32>,
    /// Instance id of the node with the largest composited weight; 0 = background.
    pub panoptic: Vec<u16>,
    pub layers: Vec<NodeLayer>,
    /// Pixels whose ray met no sample of any node under a last-sample backdrop: what no
    /// training view saw (e.g. the top of a wall). [`RenderedImage::fill_unseen`] gives
    /// them the colour and depth of the nearest seen pixels; their opacity stays 0.
    pub unseen: Vec<bool>,
    /// Interleaved RGB of the background alone (empty unless asked for): the same bits as
    /// rendering the scene with its objects removed, from the samples this render queried
    /// ([`RenderOptions::background_alone`]).
    pub background: Vec<f32>,
}

impl RenderedImage {
    /// An image of `camera`'s size with every output zero (layers for each node when asked).
    pub fn empty(scene: &NeuralScene, camera: &Camera, layers: bool) -> Self {
        let (w, h) = (camera.width(), camera.height());
        let n = (w * h) as usize;
        RenderedImage {
            width: w,
            height: h,
            rgb: vec![0.0; 3 * n],
            depth: vec![0.0; n],
            opacity: vec![0.0; n],
            panoptic: vec![0; n],
            unseen: vec![false; n],
            background: Vec::new(),
            layers: if layers {
                scene
                    .scene
                    .nodes
                    .iter()
                    .map(|nd| NodeLayer {
                        id: nd.id,
                        rgb: vec![0.0; 3 * n],
                        opacity: vec![0.0; n],
                    })
                    .collect()
            } else {
                Vec::new()
            },
        }
    }

    /// Writes a batch's composited rays into pixels `pixels` (`cos`: each ray's cosine to
    /// the camera axis, turning distance into z-depth).
    pub fn write_batch(
        &mut self,
        scene: &NeuralScene,
        out: &BatchOutput,
        pixels: &[usize],
        cos: &[f32],
    ) {
        let nn = scene.scene.nodes.len();
        let last_sample = scene.scene.backdrop == assist_core::Backdrop::LastSample;
        for (r, &q) in pixels.iter().enumerate() {
            let c = out.rays[r];
            self.opacity[q] = c.opacity;
            self.set_rgb(last_sample, q, c.rgb);
            self.depth[q] = if c.opacity > 1e-3 {
                c.depth / c.opacity * cos[r]
            } else {
                0.0
            };
            self.panoptic[q] = out.winner(r).map(|k| scene.scene.nodes[k].id).unwrap_or(0);
            for (k, layer) in self.layers.iter_mut().enumerate() {
                let a = out.nodes[r * nn + k];
                layer.rgb[3 * q..3 * q + 3].copy_from_slice(&a.rgb);
                layer.opacity[q] = a.opacity;
            }
        }
    }
}

impl RenderedImage {
    /// Pixel `q`'s colour, its opacity already set.
    fn set_rgb(&mut self, last_sample: bool, q: usize, rgb: [f32; 3]) {
        // No sample at all: nothing weighted and no last sample's colour behind.
        self.unseen[q] = last_sample && self.opacity[q] == 0.0 && rgb == [0.0; 3];
        self.rgb[3 * q..3 * q + 3].copy_from_slice(&rgb);
    }

    /// Pixel `q`'s colour again (its opacity as it was), as [`Self::write_batch`] writes it.
    pub(crate) fn set_colour(&mut self, scene: &NeuralScene, q: usize, rgb: [f32; 3]) {
        let last_sample = scene.scene.backdrop == assist_core::Backdrop::LastSample;
        self.set_rgb(last_sample, q, rgb);
    }

    /// Fills the [`unseen`](Self::unseen) pixels' colour and depth from the seen pixels
    /// around them (see [`crate::fill`]); a no-op when every pixel was seen.
    pub fn fill_unseen(&mut self) {
        if !self.unseen.iter().any(|&u| u) {
            return;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let seen: Vec<bool> = self.unseen.iter().map(|u| !u).collect();
        crate::fill::pull_push(w, h, 3, &mut self.rgb, &seen, &self.unseen);
        // Depth from the seen pixels that have one (a nearly transparent ray has none).
        let with_depth: Vec<bool> = self.depth.iter().map(|&d| d > 0.0).collect();
        crate::fill::pull_push(w, h, 1, &mut self.depth, &with_depth, &self.unseen);
    }
}

/// How fields are queried.
#[derive(Debug, Clone, Copy)]
pub enum Query<'a> {
    /// For an image: at `precision`, adding `highlight`'s colour to that node's samples;
    /// at `Precision::Bf16`, encoding from `tables` where they hold the node's field.
    Render {
        precision: Precision,
        highlight: Option<(InstanceId, [f32; 3])>,
        tables: Option<&'a SceneTables>,
        /// Queries the fields there rather than on this CPU (see [`RenderOptions::backend`]).
        backend: Option<&'a dyn FieldBackend>,
        /// The camera's centre, for novel views' codes (see [`RenderOptions::eye`]).
        eye: Option<[f64; 3]>,
    },
    /// For a training step: in f32, keeping each node's tape for the backward pass and
    /// leaving room for the gradients.
    Train,
    /// As `Train`, for a camera no photograph was taken from (fitting a held-out view):
    /// its samples take the novel view's code seen from `eye`, as its render does.
    Fit { eye: Option<[f64; 3]> },
}

/// Queries every node's field at its samples: the one query path of rendering and
/// training. `tapes` are reusable scratch buffers, one per node.
pub fn query_fields(scene: &NeuralScene, traced: &mut Traced, tapes: &mut Vec<Tape>, q: Query) {
    tapes.resize_with(traced.nodes.len(), Tape::default);
    if let Query::Render {
        backend: Some(b),
        highlight,
        eye,
        ..
    } = q
        && query_all_on(b, scene, traced, eye)
    {
        for ns in &mut traced.nodes {
            crate::relight::relight_node(scene, ns.node, &ns.pos, &mut ns.rgb);
            add_highlight(scene, ns.node, &mut ns.rgb, highlight);
        }
        return;
    }
    for (ns, tape) in traced.nodes.iter_mut().zip(tapes.iter_mut()) {
        query_node(scene, ns, tape, q);
    }
}

/// Every node's samples queried on `backend` in one call (so a GPU waits once per batch,
/// not once per node); false when it failed (the caller then queries on this CPU).
fn query_all_on(
    backend: &dyn FieldBackend,
    scene: &NeuralScene,
    traced: &mut Traced,
    eye: Option<[f64; 3]>,
) -> bool {
    let mut outs: Vec<(Vec<f32>, Vec<f32>)> = traced
        .nodes
        .iter_mut()
        .map(|ns| {
            ns.prepare_outputs(false);
            (std::mem::take(&mut ns.sigma), std::mem::take(&mut ns.rgb))
        })
        .collect();
    let codes: Vec<Option<Vec<f32>>> = traced
        .nodes
        .iter()
        .map(|ns| crate::appearance::novel_code(scene, ns.node, eye))
        .collect();
    let mut queries: Vec<assist_field::FieldQuery> = traced
        .nodes
        .iter()
        .zip(outs.iter_mut())
        .zip(&codes)
        .filter(|((ns, _), _)| !ns.is_empty())
        .map(|((ns, (sigma, rgb)), code)| assist_field::FieldQuery {
            field: &scene.field_of(ns.node).field,
            samples: ns.samples(),
            novel: code.as_deref(),
            sigma,
            rgb,
        })
        .collect();
    let ok = backend.forward_all(&mut queries).is_ok();
    drop(queries);
    for (ns, (sigma, rgb)) in traced.nodes.iter_mut().zip(outs) {
        ns.sigma = sigma;
        ns.rgb = rgb;
    }
    ok
}

/// Adds the highlight's colour to node `node`'s samples when it is the one highlighted.
fn add_highlight(
    scene: &NeuralScene,
    node: usize,
    rgb: &mut [f32],
    highlight: Option<(InstanceId, [f32; 3])>,
) {
    if let Some((id, add)) = highlight
        && scene.scene.nodes[node].id == id
    {
        for px in rgb.chunks_exact_mut(3) {
            for c in 0..3 {
                px[c] = (px[c] + add[c]).min(1.0);
            }
        }
    }
}

/// Queries one node's samples (see [`query_fields`]).
pub fn query_node(scene: &NeuralScene, ns: &mut NodeSamples, tape: &mut Tape, q: Query) {
    ns.prepare_outputs(matches!(q, Query::Train | Query::Fit { .. }));
    if ns.is_empty() {
        return;
    }
    let nf = scene.field_of(ns.node);
    // The outputs are moved out while the samples are borrowed.
    let mut sigma = std::mem::take(&mut ns.sigma);
    let mut rgb = std::mem::take(&mut ns.rgb);
    match q {
        Query::Train | Query::Fit { .. } => {
            let eye = if let Query::Fit { eye } = q {
                eye
            } else {
                None
            };
            let code = crate::appearance::novel_code(scene, ns.node, eye);
            let s = ns.samples();
            (nf.field).forward_train_novel(&s, code.as_deref(), tape, &mut sigma, &mut rgb)
        }
        Query::Render {
            precision,
            highlight,
            backend,
            eye,
            ..
        } => {
            let tables = crate::tables::for_node(scene, ns.node, &q);
            let code = crate::appearance::novel_code(scene, ns.node, eye);
            // A backend that fails falls back to this CPU (it keeps its error to report).
            let elsewhere = backend.is_some_and(|b| {
                b.forward_all(&mut [assist_field::FieldQuery {
                    field: &nf.field,
                    samples: ns.samples(),
                    novel: code.as_deref(),
                    sigma: &mut sigma,
                    rgb: &mut rgb,
                }])
                .is_ok()
            });
            if !elsewhere {
                let s = ns.samples();
                nf.field.forward_at(
                    precision,
                    tables,
                    code.as_deref(),
                    &s,
                    tape,
                    &mut sigma,
                    &mut rgb,
                );
            }
            crate::relight::relight_node(scene, ns.node, &ns.pos, &mut rgb);
            add_highlight(scene, ns.node, &mut rgb, highlight);
        }
    }
    ns.sigma = sigma;
    ns.rgb = rgb;
}

/// Reusable buffers for rendering.
#[derive(Default)]
pub struct RenderScratch {
    pub rays: RayBatch,
    pub traced: Traced,
    pub tapes: Vec<Tape>,
    pub out: BatchOutput,
    pub prune: crate::prune::PruneScratch,
}

/// Where a render's time went and how many samples it queried (`assist bench render`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderStats {
    pub rays: usize,
    /// Samples marched (every node, before pruning).
    pub marched: usize,
    /// Samples whose fields were queried in full (after pruning).
    pub queried: usize,
    /// Seconds: marching, pruning's choosing and moving of samples between its rounds,
    /// the field queries, shading and compositing.
    pub sample_s: f64,
    pub prune_s: f64,
    pub query_s: f64,
    pub composite_s: f64,
    /// Seconds from start to end of a whole camera's render: the stages' sum, except
    /// where they overlap (the fields queried on a GPU, [`crate::overlap`]).
    pub wall_s: f64,
}

impl RenderStats {
    /// Adds `o`'s counts and seconds to these.
    pub fn add(&mut self, o: &RenderStats) {
        self.rays += o.rays;
        self.marched += o.marched;
        self.queried += o.queried;
        self.sample_s += o.sample_s;
        self.prune_s += o.prune_s;
        self.query_s += o.query_s;
        self.composite_s += o.composite_s;
        self.wall_s += o.wall_s;
    }
}

/// Renders a batch of rays (inference).
pub fn render_rays(scene: &NeuralScene, opts: &RenderOptions, sc: &mut RenderScratch) {
    render_rays_timed(scene, opts, sc);
}

/// [`render_rays`], saying where the time went.
pub fn render_rays_timed(
    scene: &NeuralScene,
    opts: &RenderOptions,
    sc: &mut RenderScratch,
) -> RenderStats {
    let mut st = RenderStats {
        rays: sc.rays.len(),
        ..Default::default()
    };
    crate::overlap::march_stage(scene, opts, sc, &mut st);
    crate::overlap::query_stage(scene, opts, sc, &mut st);
    crate::overlap::composite_stage(scene, sc, &mut st);
    st
}

/// Renders a whole camera; `image` selects the appearance code (`u32::MAX` = average).
pub fn render_camera(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
) -> RenderedImage {
    render_camera_timed(scene, camera, image, opts).0
}

/// [`render_camera`], saying where the time went.
pub fn render_camera_timed(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
) -> (RenderedImage, RenderStats) {
    let start = std::time::Instant::now();
    let opts = &*crate::appearance::seen_from(opts, camera, image);
    let mut stats = RenderStats::default();
    let mut img = RenderedImage::empty(scene, camera, opts.layers);
    let pixels_n = img.opacity.len();
    // The background's image alone comes from this render's samples; a scene without a
    // background node (or with it highlighted) renders its image alone apart.
    let mut alone = match opts.background_alone {
        true => crate::alone::BackgroundAlone::of(scene, pixels_n).filter(|a| {
            // A highlighted background is not the background alone.
            opts.highlight.map(|(id, _)| id) != Some(scene.scene.nodes[a.node].id)
        }),
        false => None,
    };
    if opts.backend.is_some() {
        // The queries run elsewhere: this CPU marches and composites the batches beside them.
        stats = crate::overlap::render_overlapped(scene, camera, image, opts, &mut img, &mut alone);
    } else {
        let mut b = crate::overlap::Batch::new(scene);
        let mut p = 0usize;
        while !opts.cancelled()
            && let Some(end) = b.next(camera, image, p, opts)
        {
            stats.add(&render_rays_timed(scene, opts, &mut b.sc));
            b.write(scene, &mut img, &mut alone);
            p = end;
        }
    }
    img.fill_unseen();
    if let Some(a) = alone {
        img.background = a.finish(img.width, img.height);
    } else if opts.background_alone && !opts.cancelled() {
        img.background = crate::alone::render_apart(scene, camera, image, opts);
    }
    stats.wall_s = start.elapsed().as_secs_f64();
    (img, stats)
}

/// Fills `rays` with the camera rays of pixels `p..` (at most `opts.rays_per_batch`),
/// recording each ray's pixel and its cosine to the camera axis; returns the next pixel,
/// or `None` when every pixel is done.
pub(crate) fn camera_batch(
    camera: &Camera,
    image: u32,
    p: usize,
    opts: &RenderOptions,
    rays: &mut RayBatch,
    pixels: &mut Vec<usize>,
    cos: &mut Vec<f32>,
) -> Option<usize> {
    let w = camera.width();
    let n = (w * camera.height()) as usize;
    if p >= n {
        return None;
    }
    let forward = camera.pose.forward();
    let end = (p + opts.batch_rays()).min(n);
    rays.clear();
    cos.clear();
    pixels.clear();
    for q in p..end {
        let (i, j) = ((q as u32) % w, (q as u32) / w);
        if let Some(ray) = camera.pixel_ray(i, j) {
            cos.push(ray.dir.dot(forward) as f32);
            rays.push(&ray, image);
            pixels.push(q);
        }
    }
    Some(end)
}
