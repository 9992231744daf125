//! A batch's three stages (marching, the field queries, compositing), and a whole camera
//! rendered with its field queries elsewhere (a GPU, `--device gpu`), overlapped with
//! this CPU's work: while one batch's queries run there, the CPU composites the batch
//! before it and marches the one after. The queries' wait leaves
//! the CPU idle otherwise. Every batch goes through the same stages as one rendered
//! alone, so the image is the same bits either way.

use assist_core::Camera;
use assist_scene::NeuralScene;

use crate::alone::BackgroundAlone;
use crate::batch::composite_batch;
use crate::march::sample_rays;
use crate::render::{
    Query, RenderOptions, RenderScratch, RenderStats, RenderedImage, camera_batch, query_fields,
};
use crate::sample::Traced;

/// One batch of a camera's rays in flight: its scratch, its pixels and where its time went.
pub(crate) struct Batch {
    pub(crate) sc: RenderScratch,
    pixels: Vec<usize>,
    /// Each ray's cosine to the camera axis.
    cos: Vec<f32>,
    st: RenderStats,
}

impl Batch {
    pub(crate) fn new(scene: &NeuralScene) -> Self {
        let mut sc = RenderScratch::default();
        sc.rays.near = scene.scene.near as f32;
        Batch {
            sc,
            pixels: Vec::new(),
            cos: Vec::new(),
            st: RenderStats::default(),
        }
    }

    /// Takes the camera's rays from pixel `p` on (see [`camera_batch`]): the next pixel,
    /// or `None` when every pixel is done.
    pub(crate) fn next(
        &mut self,
        camera: &Camera,
        image: u32,
        p: usize,
        opts: &RenderOptions,
    ) -> Option<usize> {
        let end = camera_batch(
            camera,
            image,
            p,
            opts,
            &mut self.sc.rays,
            &mut self.pixels,
            &mut self.cos,
        )?;
        self.st = RenderStats {
            rays: self.sc.rays.len(),
            ..Default::default()
        };
        Some(end)
    }

    /// Writes the composited batch into the image (and the background's image alone).
    pub(crate) fn write(
        &self,
        scene: &NeuralScene,
        img: &mut RenderedImage,
        alone: &mut Option<BackgroundAlone>,
    ) {
        img.write_batch(scene, &self.sc.out, &self.pixels, &self.cos);
        if let Some(a) = alone.as_mut() {
            a.write_batch(scene, &self.sc, &self.pixels);
        }
    }
}

/// Renders `camera` into `img` three batches at a time: batch i queried on the
/// options' backend while batch i − 1 is composited and written, and batch i + 1 marched.
/// The stages' seconds in the result overlap (they add up to more than the frame took).
pub(crate) fn render_overlapped(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
    img: &mut RenderedImage,
    alone: &mut Option<BackgroundAlone>,
) -> RenderStats {
    let mut stats = RenderStats::default();
    let mut spare: Vec<Batch> = Vec::new();
    let mut p = 0usize;
    // The next batch taken and marched (None once every pixel is taken or the render is
    // cancelled).
    let marched = |p: &mut usize, spare: &mut Vec<Batch>| -> Option<Batch> {
        if opts.cancelled() {
            return None;
        }
        let mut b = spare.pop().unwrap_or_else(|| Batch::new(scene));
        *p = b.next(camera, image, *p, opts)?;
        march_stage(scene, opts, &mut b.sc, &mut b.st);
        Some(b)
    };
    let mut to_query = marched(&mut p, &mut spare);
    let mut queried: Option<Batch> = None;
    while to_query.is_some() || queried.is_some() {
        let mut querying = to_query.take();
        let done = queried.take();
        let (next, ()) = rayon::join(
            || {
                if let Some(mut d) = done {
                    composite_stage(scene, &mut d.sc, &mut d.st);
                    d.write(scene, img, alone);
                    stats.add(&d.st);
                    spare.push(d);
                }
                marched(&mut p, &mut spare)
            },
            || {
                if let Some(b) = querying.as_mut() {
                    query_stage(scene, opts, &mut b.sc, &mut b.st);
                }
            },
        );
        queried = querying;
        to_query = next;
    }
    stats
}

/// Samples in a traced batch, every node's.
fn sample_count(t: &Traced) -> usize {
    t.nodes.iter().map(|n| n.len()).sum()
}

/// A batch's first stage: its rays marched through every node.
pub(crate) fn march_stage(
    scene: &NeuralScene,
    opts: &RenderOptions,
    sc: &mut RenderScratch,
    st: &mut RenderStats,
) {
    let t = std::time::Instant::now();
    sample_rays(scene, &sc.rays, &opts.sample_options(), &mut sc.traced);
    st.marched = sample_count(&sc.traced);
    st.sample_s = t.elapsed().as_secs_f64();
}

/// A batch's second stage: the fields queried at its samples (pruned where asked).
pub(crate) fn query_stage(
    scene: &NeuralScene,
    opts: &RenderOptions,
    sc: &mut RenderScratch,
    st: &mut RenderStats,
) {
    let q = Query::Render {
        precision: opts.precision,
        highlight: opts.highlight,
        tables: opts.tables.as_deref(),
        backend: opts.backend.as_deref(),
        eye: opts.eye,
    };
    let t = std::time::Instant::now();
    if opts.prune_eps > 0.0 && opts.backend.is_none() {
        let s = crate::prune::query_pruned(
            scene,
            &mut sc.traced,
            opts.prune_eps,
            &mut sc.prune,
            &mut sc.tapes,
            q,
        );
        st.prune_s = s.density_s;
    } else {
        query_fields(scene, &mut sc.traced, &mut sc.tapes, q);
    }
    st.queried = sample_count(&sc.traced);
    st.query_s = t.elapsed().as_secs_f64() - st.prune_s;
}

/// A batch's last stage: the background shaded and every ray composited.
pub(crate) fn composite_stage(scene: &NeuralScene, sc: &mut RenderScratch, st: &mut RenderStats) {
    let t = std::time::Instant::now();
    crate::shade::shade_background(scene, &sc.rays, &mut sc.traced);
    composite_batch(
        &mut sc.traced,
        crate::batch::Behind::of(&scene.scene),
        &mut sc.out,
        None,
    );
    st.composite_s = t.elapsed().as_secs_f64();
}
