//! Per-node samples of a batch of world rays (marched in [`crate::march`]): the samples of
//! one node are stored ray after ray (structure of arrays), ready for one batched field
//! query per node.

use assist_core::Ray;

/// World rays (unit directions) and the appearance code each should use.
#[derive(Debug, Clone, Default)]
pub struct RayBatch {
    pub origin: Vec<[f32; 3]>,
    pub dir: Vec<[f32; 3]>,
    /// Appearance code per ray; `u32::MAX` = a novel view's (the render's blend, else the
    /// average code).
    pub image: Vec<u32>,
    /// Samples closer than this (world distance) are ignored.
    pub near: f32,
}

impl RayBatch {
    pub fn len(&self) -> usize {
        self.origin.len()
    }
    pub fn is_empty(&self) -> bool {
        self.origin.is_empty()
    }
    pub fn clear(&mut self) {
        self.origin.clear();
        self.dir.clear();
        self.image.clear();
    }
    pub fn push(&mut self, ray: &Ray, image: u32) {
        self.origin.push(ray.origin.as_vec3().to_array());
        self.dir.push(ray.dir.as_vec3().to_array());
        self.image.push(image);
    }
}

#[derive(Debug, Clone, Copy)]
pub struct SampleOptions {
    /// Stratified jitter of the first sample (training); off = deterministic (rendering).
    pub jitter: bool,
    pub seed: u64,
    /// At most this many samples per ray and node.
    pub max_per_node: usize,
    /// Every node's marching steps (smallest step, growth with distance, contracted
    /// step) times this: 1 as trained; 2 for a draft render with about half the samples.
    pub step_scale: f32,
    /// Keep the coarse samples of a node whose samples a proposal draws
    /// ([`Traced::proposal`]), for the proposal's training.
    pub keep_proposal: bool,
}

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions {
            jitter: false,
            seed: 0,
            step_scale: 1.0,
            max_per_node: 1024,
            keep_proposal: false,
        }
    }
}

/// The samples of one node for a batch of rays. Ray `r`'s samples are
/// `start[r]..start[r + 1]`, sorted by `t`.
#[derive(Debug, Clone, Default)]
pub struct NodeSamples {
    /// Index of the node in the scene.
    pub node: usize,
    /// Positions in the canonical box scaled to [0, 1]³.
    pub pos: [Vec<f32>; 3],
    /// Unit directions in canonical space.
    pub dir: [Vec<f32>; 3],
    pub image: Vec<u32>,
    /// World distance along the ray (for sorting and depth).
    pub t: Vec<f32>,
    /// Interval length in canonical distance, in box diagonals (density is integrated
    /// over it).
    pub dt: Vec<f32>,
    pub start: Vec<u32>,
    /// Field outputs (filled by the caller's query): σ and interleaved RGB.
    pub sigma: Vec<f32>,
    pub rgb: Vec<f32>,
    /// Gradients with respect to σ and RGB (filled by `composite_batch`).
    pub d_sigma: Vec<f32>,
    pub d_rgb: Vec<f32>,
    /// The background's samples: the light left by objects' shadows, three factors per
    /// sample (`[r, g, b]`, like `rgb`) multiplying its colour in the composited image (not
    /// in the node alone). Empty: 1 everywhere. Filled by [`crate::shade_background`].
    pub shade: Vec<f32>,
    /// Gradient with respect to `shade` (filled by `composite_batch` when `shade` is).
    pub d_shade: Vec<f32>,
    /// Each shaded sample's weight in the composite (filled by `composite_batch` when
    /// `shade` is; see [`crate::batch::recolour`]).
    pub w: Vec<f32>,
}

impl NodeSamples {
    pub fn len(&self) -> usize {
        self.t.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
    pub fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.start[r] as usize..self.start[r + 1] as usize
    }
    /// Sample `j`'s three shading factors (1 without shade).
    #[inline(always)]
    pub fn shade_at(&self, j: usize) -> [f32; 3] {
        shade_factors(&self.shade, j)
    }
    pub fn samples(&self) -> assist_field::Samples<'_> {
        assist_field::Samples {
            pos: [&self.pos[0], &self.pos[1], &self.pos[2]],
            dir: [&self.dir[0], &self.dir[1], &self.dir[2]],
            image: &self.image,
        }
    }
    pub(crate) fn clear(&mut self) {
        for a in 0..3 {
            self.pos[a].clear();
            self.dir[a].clear();
        }
        self.image.clear();
        self.t.clear();
        self.dt.clear();
        self.start.clear();
        self.shade.clear();
        self.w.clear();
    }
    /// The blocks' samples after this one's, the rays' starts ended (each array copied by
    /// a task of its own). A block's `start` holds the block-local start of each of its
    /// rays, with no trailing end.
    pub(crate) fn append_all(&mut self, blocks: &[NodeSamples]) {
        let mut base = self.t.len() as u32;
        for o in blocks {
            self.start.extend(o.start.iter().map(|s| s + base));
            base += o.t.len() as u32;
        }
        self.start.push(base);
        let NodeSamples {
            pos,
            dir,
            image,
            t,
            dt,
            ..
        } = self;
        rayon::scope(|s| {
            s.spawn(|_| concat(image, blocks.iter().map(|b| &b.image[..])));
            s.spawn(|_| concat(t, blocks.iter().map(|b| &b.t[..])));
            s.spawn(|_| concat(dt, blocks.iter().map(|b| &b.dt[..])));
            for (a, dst) in pos.iter_mut().enumerate() {
                s.spawn(move |_| concat(dst, blocks.iter().map(|b| &b.pos[a][..])));
            }
            for (a, dst) in dir.iter_mut().enumerate() {
                s.spawn(move |_| concat(dst, blocks.iter().map(|b| &b.dir[a][..])));
            }
        });
    }
    /// The samples of rays `rays` (in that order) as a batch of `rays.len()` rays: to be
    /// queried (positions, directions, images), or, `with_outputs`, to be composited as
    /// they are (field outputs and shading instead).
    pub(crate) fn gather_rays(&self, rays: &[usize], with_outputs: bool, out: &mut NodeSamples) {
        self.gather(rays.iter().map(|&r| self.range(r)), with_outputs, out);
    }

    /// The samples `ranges` (each a part of one ray's, in that order) as a batch of one
    /// ray per range (see [`Self::gather_rays`]). Each array is copied by a task of its
    /// own.
    pub(crate) fn gather(
        &self,
        ranges: impl Iterator<Item = std::ops::Range<usize>>,
        with_outputs: bool,
        out: &mut NodeSamples,
    ) {
        out.node = self.node;
        out.start.clear();
        out.w.clear();
        let mut ranges: Vec<std::ops::Range<usize>> = ranges.collect();
        let mut n = 0u32;
        for g in &ranges {
            out.start.push(n);
            n += g.len() as u32;
        }
        out.start.push(n);
        // Adjacent ranges (whole rays in order) copy as one.
        ranges.dedup_by(|b, a| {
            let joined = a.end == b.start;
            if joined {
                a.end = b.end;
            }
            joined
        });
        let shaded = with_outputs && !self.shade.is_empty();
        let g = &ranges[..];
        let NodeSamples {
            pos,
            dir,
            image,
            t,
            dt,
            sigma,
            rgb,
            shade,
            ..
        } = out;
        rayon::scope(|s| {
            s.spawn(|_| column(t, &self.t, g, 1, true));
            s.spawn(|_| column(dt, &self.dt, g, 1, true));
            s.spawn(|_| column(sigma, &self.sigma, g, 1, with_outputs));
            s.spawn(|_| column(rgb, &self.rgb, g, 3, with_outputs));
            s.spawn(|_| column(shade, &self.shade, g, 3, shaded));
            s.spawn(|_| column(image, &self.image, g, 1, !with_outputs));
            for (dst, src) in pos.iter_mut().zip(&self.pos) {
                s.spawn(|_| column(dst, src, g, 1, !with_outputs));
            }
            for (dst, src) in dir.iter_mut().zip(&self.dir) {
                s.spawn(|_| column(dst, src, g, 1, !with_outputs));
            }
        });
    }

    /// Sizes the output and gradient buffers to the sample count (zeroed gradients).
    pub fn prepare_outputs(&mut self, with_grad: bool) {
        let n = self.len();
        self.sigma.resize(n, 0.0);
        self.rgb.resize(3 * n, 0.0);
        if with_grad {
            self.d_sigma.clear();
            self.d_sigma.resize(n, 0.0);
            self.d_rgb.clear();
            self.d_rgb.resize(3 * n, 0.0);
        }
    }
}

/// `dst` made the `ranges` of `src` (`k` values per sample) one after another; empty
/// unless `wanted`.
fn column<T: Copy>(
    dst: &mut Vec<T>,
    src: &[T],
    ranges: &[std::ops::Range<usize>],
    k: usize,
    wanted: bool,
) {
    dst.clear();
    if wanted {
        concat(dst, ranges.iter().map(|g| &src[k * g.start..k * g.end]));
    }
}

/// `parts` appended to `dst`, one after another.
fn concat<'a, T: Copy + 'a>(dst: &mut Vec<T>, parts: impl Iterator<Item = &'a [T]> + Clone) {
    dst.reserve(parts.clone().map(|p| p.len()).sum());
    for p in parts {
        dst.extend_from_slice(p);
    }
}

/// Sample `j`'s three factors in `shade` (three per sample; empty: 1 everywhere).
#[inline(always)]
pub(crate) fn shade_factors(shade: &[f32], j: usize) -> [f32; 3] {
    if shade.is_empty() {
        [1.0; 3]
    } else {
        [shade[3 * j], shade[3 * j + 1], shade[3 * j + 2]]
    }
}

/// The samples of every node for one batch.
#[derive(Debug, Clone, Default)]
pub struct Traced {
    pub rays: usize,
    pub nodes: Vec<NodeSamples>,
    /// Per ray, the distance along it from which each node's [`Composite::beyond`]
    /// opacity is measured (empty: none, every `beyond` is 0). Set by the caller; sampling
    /// leaves it alone.
    ///
    /// [`Composite::beyond`]: crate::Composite::beyond
    pub beyond: Vec<f32>,
    /// Per ray, the distance along it before which each node's [`Composite::front`]
    /// opacity is measured (empty: none, every `front` is 0). Set by the caller.
    ///
    /// [`Composite::front`]: crate::Composite::front
    pub front: Vec<f32>,
    /// Training: the background's samples an object hides get no gradient from the
    /// composited image (see [`HiddenStop`]). `None`: every sample gets its full gradient.
    pub hidden_stop: Option<HiddenStop>,
    /// The distortion measures distances along a ray with [`distortion_distance`] in this
    /// unit (training: the scene's extent); 0 = the world distance itself.
    pub distortion_unit: f32,
    /// The coarse samples of the node whose samples a proposal drew, when the sampling
    /// kept them ([`SampleOptions::keep_proposal`]).
    pub proposal: Option<crate::proposal::ProposalRecord>,
}

/// The distance along a ray at which the distortion loss measures the gap between two
/// samples: `t / unit` up to `unit`, then `2 − unit / t` (mip-NeRF 360's normalised
/// distance: bounded, so a contracted background's far samples, at up to a thousand
/// extents, weigh no more than its near ones); `t` itself when `unit` is 0.
#[inline(always)]
pub fn distortion_distance(t: f32, unit: f32) -> f32 {
    if unit <= 0.0 {
        t
    } else if t <= unit {
        t / unit
    } else {
        2.0 - unit / t
    }
}

/// What objects hide of the background learns from the background's own prior, not from
/// the photographs: in the backward pass of the composite, a sample of node `background`
/// whose transmittance through the objects' samples in front of it is below `below` gets
/// no gradient (density, colour, shade) from the composited outputs. Its effect on the
/// samples in front (the transmittance it takes from those behind) is still propagated,
/// and its node-alone composite keeps its full gradient.
///
/// Without it, the photographs also shape the surface under an object, through the
/// object's imperfect opacity (a dark mug interior is matched as well by a darker table,
/// or by none). Off in training by default (`assist_train::TrainOptions::hidden_stop`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HiddenStop {
    pub background: usize,
    pub below: f32,
}

impl Traced {
    pub fn total_samples(&self) -> usize {
        self.nodes.iter().map(|n| n.len()).sum()
    }
}
