//! Compositing a traced batch: per ray, the samples of all nodes are merged by depth and
//! composited together (colour, depth, opacity; paper eq. 1), and each node's samples are
//! also composited alone (per-node colour, depth and opacity; eqs. 2–4). With a gradient
//! callback, the backward pass writes dL/dσ and dL/dRGB of every sample (and dL/dshade of
//! the background's samples when objects shade them).

use rayon::prelude::*;

use crate::composite::Composite;
use crate::sample::{HiddenStop, NodeSamples, Traced, distortion_distance};

mod backward;
use backward::{backward_merged, node_alone_backward};

/// Outputs of one batch. Per-node arrays are ray-major: `nodes[r * n_nodes + k]`.
#[derive(Debug, Clone, Default)]
pub struct BatchOutput {
    pub n_nodes: usize,
    /// Everything composited together over the background colour (the background's
    /// samples darkened by objects' shadows, [`NodeSamples::shade`]).
    pub rays: Vec<Composite>,
    /// Each node alone (no background colour, and no shadows: the background as it is
    /// without the objects).
    pub nodes: Vec<Composite>,
    /// Each node's share of the composited weight `Σ_{i∈k} T_i α_i` (for panoptic ids).
    pub share: Vec<f32>,
    /// Per ray, the distortion of the composited weights (mip-NeRF 360's inter-interval
    /// term, in world units): `Σ_{i,j} w_i w_j |t_i − t_j|`. Small when the weight sits at
    /// one depth, large for haze spread along the ray.
    pub distortion: Vec<f32>,
    /// Per ray, the part of the composited colour from the samples without shading (every
    /// node's but the shaded background's), before the backdrop: with the shaded samples'
    /// weights ([`NodeSamples::w`]) and `last`, a ray whose shading alone changed gets its
    /// colour again without compositing ([`recolour`]).
    pub unshaded: Vec<[f32; 3]>,
    /// Per ray, its last sample in depth (the backdrop's colour under
    /// [`Behind::LastSample`]): the node's index and the sample's place among that node's
    /// samples of the ray; [`NO_SAMPLE`] for a ray without samples.
    pub last: Vec<(u32, u32)>,
}

/// [`BatchOutput::last`] of a ray without samples.
pub const NO_SAMPLE: (u32, u32) = (u32::MAX, u32::MAX);

impl BatchOutput {
    /// Panoptic choice per ray: the node with the largest share, or `None` when what is
    /// left of the transmittance (`1 − O`, the background colour) outweighs every node.
    pub fn winner(&self, r: usize) -> Option<usize> {
        let nn = self.n_nodes;
        let share = &self.share[r * nn..(r + 1) * nn];
        let mut best = None;
        let mut best_w = 1.0 - self.rays[r].opacity;
        for (k, &w) in share.iter().enumerate() {
            if w > best_w {
                best_w = w;
                best = Some(k);
            }
        }
        best
    }
}

/// What a ray shows past its last sample (see [`assist_core::Backdrop`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Behind {
    Color([f32; 3]),
    LastSample,
}

impl Behind {
    /// The backdrop of `scene`.
    pub fn of(scene: &assist_core::Scene) -> Self {
        match scene.backdrop {
            assist_core::Backdrop::Color => Behind::Color(scene.background_color),
            assist_core::Backdrop::LastSample => Behind::LastSample,
        }
    }
}

/// Gradient of the loss with respect to one composite.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CompositeGrad {
    pub rgb: [f32; 3],
    pub depth: f32,
    pub opacity: f32,
    /// dL/d(Σ w t², [`Composite::depth_sq`]).
    pub depth_sq: f32,
    /// For a node: dL/d(its share of the composited weight, [`BatchOutput::share`]).
    /// Unused in the ray-level gradient.
    pub share: f32,
    /// For the ray: dL/d(its distortion, [`BatchOutput::distortion`]). Unused for a node.
    pub distortion: f32,
    /// For a node: dL/d([`Composite::beyond`]). Unused in the ray-level gradient.
    pub beyond: f32,
    /// For a node: dL/d([`Composite::front`]). Unused in the ray-level gradient.
    pub front: f32,
}

/// What the gradient callback sees of one ray.
#[derive(Debug, Clone, Copy)]
pub struct RayOutputs<'a> {
    pub ray: usize,
    /// Everything composited together.
    pub composite: &'a Composite,
    /// Each node alone.
    pub nodes: &'a [Composite],
    /// Each node's share of the composited weight.
    pub share: &'a [f32],
    /// The distortion of the composited weights.
    pub distortion: f32,
}

/// Gradient callback: `(outputs of a ray, d_composite, d_per_node)`; `d_per_node[k]` holds
/// the gradients of node k alone and of its share.
pub type GradFn<'a> = dyn Fn(&RayOutputs, &mut CompositeGrad, &mut [CompositeGrad]) + Sync + 'a;

const BLOCK: usize = 64;

/// A block's view of one node: read-only inputs and the writable gradients.
struct NodeView<'a> {
    start: &'a [u32],
    sigma: &'a [f32],
    rgb: &'a [f32],
    t: &'a [f32],
    dt: &'a [f32],
    d_sigma: &'a mut [f32],
    d_rgb: &'a mut [f32],
    /// Per sample, the factors on its colour's channels in the composite (empty: 1).
    shade: &'a [f32],
    d_shade: &'a mut [f32],
    /// Per sample of a shaded node, its weight in the composite (written by the forward
    /// pass; empty for a node without shade).
    w: &'a mut [f32],
}

impl NodeView<'_> {
    #[inline(always)]
    fn shade(&self, j: usize) -> [f32; 3] {
        crate::sample::shade_factors(self.shade, j)
    }
}

/// Forward (and, with `grad`, backward) compositing of every ray of `traced`; the node
/// outputs (`sigma`, `rgb`) must be filled; with `grad`, `d_sigma`/`d_rgb` must be sized
/// and zeroed (`NodeSamples::prepare_outputs(true)`).
pub fn composite_batch(
    traced: &mut Traced,
    background: Behind,
    out: &mut BatchOutput,
    grad: Option<&GradFn>,
) {
    let n = traced.rays;
    let nn = traced.nodes.len();
    let beyond = &traced.beyond;
    let front = &traced.front;
    let unit = traced.distortion_unit;
    let hidden = traced
        .hidden_stop
        .filter(|h| h.background < nn && grad.is_some());
    out.n_nodes = nn;
    out.rays.clear();
    out.rays.resize(n, Composite::default());
    out.nodes.clear();
    out.nodes.resize(n * nn, Composite::default());
    out.share.clear();
    out.share.resize(n * nn, 0.0);
    out.distortion.clear();
    out.distortion.resize(n, 0.0);
    out.unshaded.clear();
    out.unshaded.resize(n, [0.0; 3]);
    out.last.clear();
    out.last.resize(n, NO_SAMPLE);
    if nn == 0 {
        // No node (a scene whose every node is hidden): every ray sees nothing.
        return;
    }
    let n_blocks = n.div_ceil(BLOCK);
    // Split every node's arrays at block boundaries (ray-major storage makes each block's
    // samples contiguous), then regroup per block.
    let mut per_block: Vec<Vec<NodeView>> = (0..n_blocks).map(|_| Vec::with_capacity(nn)).collect();
    for ns in traced.nodes.iter_mut() {
        let NodeSamples {
            start,
            sigma,
            rgb,
            t,
            dt,
            d_sigma,
            d_rgb,
            shade,
            d_shade,
            w,
            ..
        } = ns;
        let with_grad = grad.is_some();
        let shaded = !shade.is_empty();
        w.clear();
        if shaded {
            w.resize(t.len(), 0.0);
        }
        let mut ws: &mut [f32] = w.as_mut_slice();
        if with_grad && shaded {
            d_shade.clear();
            d_shade.resize(shade.len(), 0.0);
        }
        let mut dsh: &mut [f32] = if with_grad && shaded {
            d_shade.as_mut_slice()
        } else {
            &mut []
        };
        let mut ds: &mut [f32] = if with_grad {
            d_sigma.as_mut_slice()
        } else {
            &mut []
        };
        let mut dc: &mut [f32] = if with_grad {
            d_rgb.as_mut_slice()
        } else {
            &mut []
        };
        for (b, views) in per_block.iter_mut().enumerate() {
            let r0 = b * BLOCK;
            let r1 = ((b + 1) * BLOCK).min(n);
            let (s0, s1) = (start[r0] as usize, start[r1] as usize);
            let len = s1 - s0;
            let (a, rest) = std::mem::take(&mut ds).split_at_mut(if with_grad { len } else { 0 });
            ds = rest;
            let (c, rest) =
                std::mem::take(&mut dc).split_at_mut(if with_grad { 3 * len } else { 0 });
            dc = rest;
            let (e, rest) = std::mem::take(&mut dsh).split_at_mut(if with_grad && shaded {
                3 * len
            } else {
                0
            });
            dsh = rest;
            let (wv, rest) = std::mem::take(&mut ws).split_at_mut(if shaded { len } else { 0 });
            ws = rest;
            views.push(NodeView {
                start: &start[r0..=r1],
                sigma: &sigma[s0..s1],
                rgb: &rgb[3 * s0..3 * s1],
                t: &t[s0..s1],
                dt: &dt[s0..s1],
                d_sigma: a,
                d_rgb: c,
                shade: if shaded { &shade[3 * s0..3 * s1] } else { &[] },
                d_shade: e,
                w: wv,
            });
        }
    }
    per_block
        .into_par_iter()
        .zip(out.rays.par_chunks_mut(BLOCK))
        .zip(out.nodes.par_chunks_mut(BLOCK * nn))
        .zip(out.share.par_chunks_mut(BLOCK * nn))
        .zip(out.distortion.par_chunks_mut(BLOCK))
        .zip(out.unshaded.par_chunks_mut(BLOCK))
        .zip(out.last.par_chunks_mut(BLOCK))
        .enumerate()
        .for_each_init(
            RayScratch::default,
            |scratch, (b, ((((((mut views, rays), nodes), share), dist), unshaded), last))| {
                for (i, ray_out) in rays.iter_mut().enumerate() {
                    let r = b * BLOCK + i;
                    composite_ray(
                        r,
                        i,
                        (
                            beyond.get(r).copied().unwrap_or(f32::INFINITY),
                            front.get(r).copied().unwrap_or(f32::NEG_INFINITY),
                            unit,
                        ),
                        &mut views,
                        background,
                        hidden,
                        RayOut {
                            composite: ray_out,
                            nodes: &mut nodes[i * nn..(i + 1) * nn],
                            share: &mut share[i * nn..(i + 1) * nn],
                            distortion: &mut dist[i],
                            unshaded: &mut unshaded[i],
                            last: &mut last[i],
                        },
                        grad,
                        scratch,
                    );
                }
            },
        );
}

/// Where one ray's outputs go.
struct RayOut<'a> {
    composite: &'a mut Composite,
    nodes: &'a mut [Composite],
    share: &'a mut [f32],
    distortion: &'a mut f32,
    unshaded: &'a mut [f32; 3],
    last: &'a mut (u32, u32),
}

#[derive(Default)]
struct RayScratch {
    merged: Vec<(f32, u32, u32)>,
    w: Vec<f32>,
    t_next: Vec<f32>,
    /// Per merged sample: whether it is a background sample objects hide (`HiddenStop`).
    hidden: Vec<bool>,
    node_grads: Vec<CompositeGrad>,
}

/// One ray: merge, composite, and optionally backward.
#[allow(clippy::too_many_arguments)]
fn composite_ray(
    r: usize,
    i: usize,
    (beyond, front, unit): (f32, f32, f32),
    views: &mut [NodeView],
    behind: Behind,
    hidden: Option<HiddenStop>,
    o: RayOut,
    grad: Option<&GradFn>,
    sc: &mut RayScratch,
) {
    let RayOut {
        composite: out,
        nodes: node_out,
        share,
        distortion,
        unshaded,
        last: last_out,
    } = o;
    merge_samples(i, views, sc);
    let m = sc.merged.len();
    let (mut acc, parts) = forward_merged(views, hidden, share, sc);
    *unshaded = parts[0];
    // The backdrop: a colour, or the colour of the last sample (black without samples).
    let last = sc.merged.last().map(|&(_, k, j)| (k as usize, j as usize));
    if let Some((k, j)) = last {
        *last_out = (k as u32, (j - ray_range(&views[k], i).start) as u32);
    }
    let background = match (behind, last) {
        (Behind::Color(c), _) => c,
        (Behind::LastSample, Some((k, j))) => {
            backdrop_colour(&views[k].rgb[3 * j..3 * j + 3], views[k].shade(j))
        }
        (Behind::LastSample, None) => [0.0; 3],
    };
    acc.rgb = with_backdrop(acc.rgb, acc.opacity, background);
    *out = acc;
    // Distortion Σ_{i,j} w_i w_j |s_i − s_j| = 2 Σ_i w_i (s_i W_{<i} − S_{<i}) over the
    // depth-sorted samples (s: `distortion_distance`, monotone in t; W, S: prefix sums of
    // w and w·s).
    let (mut w_before, mut s_before, mut dist) = (0.0f32, 0.0f32, 0.0f32);
    for (q, &(t, _, _)) in sc.merged.iter().enumerate() {
        let t = distortion_distance(t, unit);
        let w = sc.w[q];
        dist += 2.0 * w * (t * w_before - s_before);
        w_before += w;
        s_before += w * t;
    }
    *distortion = dist;
    for (k, v) in views.iter().enumerate() {
        node_out[k] = node_alone(v, ray_range(v, i), beyond, front);
    }
    let Some(grad) = grad else { return };
    let mut g = CompositeGrad::default();
    sc.node_grads.clear();
    sc.node_grads.resize(views.len(), CompositeGrad::default());
    let outputs = RayOutputs {
        ray: r,
        composite: out,
        nodes: node_out,
        share: &*share,
        distortion: dist,
    };
    grad(&outputs, &mut g, &mut sc.node_grads);
    // The last sample's colour also shows through what is left of the transmittance.
    let last_hidden = m > 0 && sc.hidden[m - 1];
    if let (Behind::LastSample, Some((k, j)), false) = (behind, last, last_hidden) {
        let rest = 1.0 - acc.opacity;
        let v = &mut views[k];
        let sh = v.shade(j);
        for ch in 0..3 {
            v.d_rgb[3 * j + ch] += rest * sh[ch] * g.rgb[ch];
        }
        if !v.d_shade.is_empty() {
            for ch in 0..3 {
                v.d_shade[3 * j + ch] += rest * g.rgb[ch] * v.rgb[3 * j + ch];
            }
        }
    }
    let totals = (acc, w_before, s_before);
    backward_merged(views, &g, background, totals, unit, sc);
    // Backward through each node alone (no background colour).
    for (k, v) in views.iter_mut().enumerate() {
        let ng = CompositeGrad {
            share: 0.0,
            ..sc.node_grads[k]
        };
        if ng != CompositeGrad::default() {
            node_alone_backward(v, ray_range(v, i), (beyond, front), &ng, sc);
        }
    }
}

/// Block-local range of ray `i`'s samples in a node's view.
#[inline(always)]
fn ray_range(v: &NodeView, i: usize) -> std::ops::Range<usize> {
    let b0 = v.start[0] as usize;
    (v.start[i] as usize - b0)..(v.start[i + 1] as usize - b0)
}

/// Ray `i`'s samples of every node, merged by depth into `sc.merged` as (t, node, index).
#[inline(always)]
fn merge_samples(i: usize, views: &[NodeView], sc: &mut RayScratch) {
    sc.merged.clear();
    for (k, v) in views.iter().enumerate() {
        for j in ray_range(v, i) {
            sc.merged.push((v.t[j], k as u32, j as u32));
        }
    }
    if views.len() > 1 {
        sc.merged.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }
}

/// The forward composite over the merged samples, before the backdrop: each sample's
/// weight and the transmittance after it (kept in `sc` for the backward), each node's
/// share of the weight, and which background samples objects hide.
#[inline(always)]
fn forward_merged(
    views: &mut [NodeView],
    hidden: Option<HiddenStop>,
    share: &mut [f32],
    sc: &mut RayScratch,
) -> (Composite, [[f32; 3]; 2]) {
    let m = sc.merged.len();
    sc.w.clear();
    sc.w.resize(m, 0.0);
    sc.t_next.clear();
    sc.t_next.resize(m, 0.0);
    sc.hidden.clear();
    sc.hidden.resize(m, false);
    let mut acc = Composite::default();
    // The colour of the samples without and with shading, apart.
    let mut parts = [[0.0f32; 3]; 2];
    // Transmittance in front of the sample, a running product of each sample's
    // `exp(−σδ)` (one exponential per sample).
    let mut trans = 1.0f32;
    // Transmittance through the objects' samples alone (for `HiddenStop`).
    let mut trans_obj = 1.0f32;
    for (q, &(t, k, j)) in sc.merged.iter().enumerate() {
        let v = &mut views[k as usize];
        let j = j as usize;
        let pass = (-(v.sigma[j] * v.dt[j])).exp();
        let w = trans * (1.0 - pass);
        trans *= pass;
        if let Some(h) = hidden {
            if k as usize == h.background {
                sc.hidden[q] = trans_obj < h.below;
            } else {
                trans_obj *= pass;
            }
        }
        sc.w[q] = w;
        sc.t_next[q] = trans;
        let shaded = !v.shade.is_empty();
        add_weighted(
            &mut parts[shaded as usize],
            w,
            v.shade(j),
            &v.rgb[3 * j..3 * j + 3],
        );
        if shaded {
            v.w[j] = w;
        }
        acc.depth += w * t;
        acc.depth_sq += w * t * t;
        acc.opacity += w;
        share[k as usize] += w;
    }
    acc.rgb = join_parts(parts[0], parts[1]);
    (acc, parts)
}

/// Adds a sample's colour `rgb`, shaded by `sh`, at weight `w` to `acc` (the one formula
/// of the composite and of [`recolour`], so that both give the same bits).
#[inline(always)]
fn add_weighted(acc: &mut [f32; 3], w: f32, sh: [f32; 3], rgb: &[f32]) {
    for c in 0..3 {
        acc[c] += w * sh[c] * rgb[c];
    }
}

/// The composited colour from its unshaded and shaded parts.
#[inline(always)]
fn join_parts(unshaded: [f32; 3], shaded: [f32; 3]) -> [f32; 3] {
    [
        unshaded[0] + shaded[0],
        unshaded[1] + shaded[1],
        unshaded[2] + shaded[2],
    ]
}

/// The last sample's colour as the backdrop shows it.
#[inline(always)]
pub(crate) fn backdrop_colour(rgb: &[f32], sh: [f32; 3]) -> [f32; 3] {
    [rgb[0] * sh[0], rgb[1] * sh[1], rgb[2] * sh[2]]
}

/// `rgb` with the backdrop behind what is left of the transmittance.
#[inline(always)]
pub(crate) fn with_backdrop(mut rgb: [f32; 3], opacity: f32, background: [f32; 3]) -> [f32; 3] {
    for c in 0..3 {
        rgb[c] += (1.0 - opacity) * background[c];
    }
    rgb
}

/// The composited colour of ray `r` of `traced` when only the shading of its shaded
/// node's samples changed since [`composite_batch`] gave it `unshaded`, `last` and
/// `opacity` (and the shaded node's weights, [`NodeSamples::w`]): the same bits as
/// compositing the ray again. `None` when more than one node is shaded.
pub fn recolour(
    traced: &Traced,
    r: usize,
    behind: Behind,
    (unshaded, last, opacity): ([f32; 3], (u32, u32), f32),
) -> Option<[f32; 3]> {
    let mut shaded_nodes = traced.nodes.iter().filter(|ns| !ns.shade.is_empty());
    let mut shaded = [0.0f32; 3];
    if let Some(ns) = shaded_nodes.next() {
        if shaded_nodes.next().is_some() || ns.w.len() != ns.len() {
            return None;
        }
        for j in ns.range(r) {
            add_weighted(
                &mut shaded,
                ns.w[j],
                ns.shade_at(j),
                &ns.rgb[3 * j..3 * j + 3],
            );
        }
    }
    let background = match behind {
        Behind::Color(c) => c,
        Behind::LastSample if last == NO_SAMPLE => [0.0; 3],
        Behind::LastSample => {
            let ns = traced.nodes.get(last.0 as usize)?;
            let j = ns.range(r).start + last.1 as usize;
            backdrop_colour(ns.rgb.get(3 * j..3 * j + 3)?, ns.shade_at(j))
        }
    };
    Some(with_backdrop(
        join_parts(unshaded, shaded),
        opacity,
        background,
    ))
}

/// A node's samples of one ray composited alone (no backdrop, no shading), with the
/// weight beyond `beyond` and in front of `front`.
#[inline(always)]
fn node_alone(v: &NodeView, range: std::ops::Range<usize>, beyond: f32, front: f32) -> Composite {
    let mut a = Composite::default();
    let mut trans = 1.0f32;
    for j in range {
        let pass = (-(v.sigma[j] * v.dt[j])).exp();
        let w = trans * (1.0 - pass);
        trans *= pass;
        for c in 0..3 {
            a.rgb[c] += w * v.rgb[3 * j + c];
        }
        a.depth += w * v.t[j];
        a.depth_sq += w * v.t[j] * v.t[j];
        a.opacity += w;
        if v.t[j] >= beyond {
            a.beyond += w;
        }
        if v.t[j] < front {
            a.front += w;
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One ray's samples of node `k`, with their gradients sized and zeroed.
    fn node(k: usize, t: &[f32], sigma: &[f32]) -> NodeSamples {
        let n = t.len();
        NodeSamples {
            node: k,
            start: vec![0, n as u32],
            t: t.to_vec(),
            dt: vec![0.1; n],
            sigma: sigma.to_vec(),
            rgb: (0..3 * n).map(|i| 0.2 + 0.1 * i as f32).collect(),
            d_sigma: vec![0.0; n],
            d_rgb: vec![0.0; 3 * n],
            ..Default::default()
        }
    }

    /// Gradients of every sample (σ then RGB, per node) for a loss on the composite
    /// (`merged`) and on the background alone, with or without the stop.
    fn grads(stop: Option<HiddenStop>, merged: bool) -> Vec<Vec<f32>> {
        // Background samples in front of the object, behind it, and further behind.
        let mut traced = Traced {
            rays: 1,
            nodes: vec![
                node(0, &[1.0, 2.0, 3.0], &[2.0, 5.0, 5.0]),
                node(1, &[1.5], &[40.0]),
            ],
            beyond: Vec::new(),
            front: Vec::new(),
            hidden_stop: stop,
            distortion_unit: 0.0,
            proposal: None,
        };
        let grad = |_: &RayOutputs, g: &mut CompositeGrad, gn: &mut [CompositeGrad]| {
            if merged {
                g.rgb = [1.0, -0.5, 0.3];
                g.distortion = 0.2;
                g.opacity = 0.1;
            }
            gn[0].rgb = [0.4, 0.2, -0.3];
            gn[0].depth = 0.05;
        };
        let mut out = BatchOutput::default();
        composite_batch(&mut traced, Behind::LastSample, &mut out, Some(&grad));
        traced
            .nodes
            .iter()
            .map(|n| n.d_sigma.iter().chain(&n.d_rgb).copied().collect())
            .collect()
    }

    #[test]
    fn a_ray_whose_shading_alone_changed_is_recoloured_to_the_same_bits() {
        // Two rays: the background (shaded) behind and in front of an object, thin
        // enough that the last sample's colour shows behind; and a ray without samples.
        let mut bg = node(0, &[1.0, 2.0, 3.0], &[0.5, 1.0, 2.0]);
        bg.start = vec![0, 3, 3];
        bg.shade = vec![0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.95, 0.85, 0.75];
        let mut obj = node(1, &[1.5], &[3.0]);
        obj.start = vec![0, 1, 1];
        for behind in [Behind::LastSample, Behind::Color([0.3, 0.2, 0.1])] {
            let mut traced = Traced {
                rays: 2,
                nodes: vec![bg.clone(), obj.clone()],
                beyond: Vec::new(),
                front: Vec::new(),
                hidden_stop: None,
                distortion_unit: 0.0,
                proposal: None,
            };
            let mut out = BatchOutput::default();
            composite_batch(&mut traced, behind, &mut out, None);
            let kept: Vec<_> = (0..2)
                .map(|r| (out.unshaded[r], out.last[r], out.rays[r].opacity))
                .collect();
            assert!(out.rays[0].opacity < 0.99, "the backdrop shows");
            assert_eq!(out.last[0], (0, 2));
            assert_eq!(out.last[1], NO_SAMPLE);
            // New shading, then the whole composite again.
            traced.nodes[0].shade = vec![0.5, 0.6, 0.7, 0.2, 0.3, 0.4, 0.1, 0.2, 0.3];
            let mut again = BatchOutput::default();
            composite_batch(&mut traced, behind, &mut again, None);
            assert_ne!(again.rays[0].rgb, out.rays[0].rgb);
            for (r, &k) in kept.iter().enumerate() {
                assert_eq!(
                    recolour(&traced, r, behind, k),
                    Some(again.rays[r].rgb),
                    "ray {r}, {behind:?}"
                );
            }
        }
    }

    #[test]
    fn what_objects_hide_of_the_background_learns_only_from_its_own_terms() {
        let stop = Some(HiddenStop {
            background: 0,
            below: 0.5,
        });
        let full = grads(None, true);
        let stopped = grads(stop, true);
        let alone = grads(None, false);
        // The sample in front of the object keeps its gradient; those behind it (the
        // object's transmittance is e^−4) keep only the background-alone terms'.
        let (bg, bg_full, bg_alone) = (&stopped[0], &full[0], &alone[0]);
        for (i, v) in [0usize, 3, 4, 5].into_iter().map(|i| (i, bg[i])) {
            assert_eq!(v, bg_full[i], "visible sample, gradient {i}");
        }
        for i in [1usize, 2, 6, 7, 8, 9, 10, 11] {
            assert_eq!(bg[i], bg_alone[i], "hidden sample, gradient {i}");
            assert_ne!(bg_full[i], bg_alone[i], "gradient {i} has a composite part");
        }
        // The object's gradient is the true one: the hidden samples' effect on it counts.
        assert_eq!(stopped[1], full[1]);
        // A stop below the object's transmittance changes nothing.
        let loose = grads(
            Some(HiddenStop {
                background: 0,
                below: 0.01,
            }),
            true,
        );
        assert_eq!(loose, full);
    }
}
