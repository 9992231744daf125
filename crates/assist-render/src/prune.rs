//! Dropping the samples that cannot matter. Training: a density-only
//! query of a node's samples (hash grid + density net, no colour net, no tape), then, per
//! ray, every sample after the transmittance has fallen below `eps` is dropped (nerfacc's
//! early stop in training) — the node's own transmittance, or the ray's through every
//! node's samples merged in depth ([`PruneBy`]). The composite transmittance is at most
//! either, so a dropped sample's weight in any output is below `eps`: the change to
//! colour, depth and opacity is below `eps`, and so is its gradient. Behind an opaque wall
//! a background ray keeps a handful of samples instead of hundreds.

use rayon::prelude::*;

use crate::sample::{NodeSamples, Traced};
use assist_scene::NeuralScene;

/// Default transmittance below which samples are dropped.
pub const PRUNE_EPS: f32 = 1e-4;

/// Training leaves nodes with fewer samples than this per ray that reaches them as they
/// are: the density pass costs about half a full query per sample (the hash-grid encoding
/// is most of both), so it can pay only where many samples lie behind surfaces.
pub const PRUNE_MIN_PER_RAY: f32 = 32.0;

/// Reusable buffers.
#[derive(Debug, Default)]
pub struct PruneScratch {
    /// Training's densities per node, and each ray's stop distance ([`PruneBy::Ray`]).
    sigmas: Vec<Vec<f32>>,
    stop: Vec<f32>,
    keep: Vec<u32>,
    kept: Vec<u32>,
    /// Rendering's rounds: each ray's optical depth so far, the rays still open, and the
    /// samples of the round in hand ([`query_node_pruned`]).
    tau: Vec<f32>,
    live: Vec<u32>,
    /// Each live ray's optical depth through the round in hand.
    depth: Vec<f32>,
    /// Per node (by index): query its next batch in rounds, as its last batch dropped
    /// enough to pay for them ([`ROUNDS_PAY`]); otherwise (and first) whole, each ray cut
    /// afterwards where the rounds would have stopped it.
    in_rounds: Vec<bool>,
    round: NodeSamples,
}

impl PruneScratch {
    /// Queries the next batch of each of `nodes` nodes in rounds, as after a batch that
    /// dropped enough for them to pay: for tests and benchmarks of the two ways.
    pub fn query_in_rounds(&mut self, nodes: usize) {
        self.in_rounds = vec![true; nodes];
    }
}

/// Whose transmittance decides what [`prune_occluded`] drops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PruneBy {
    /// Each node's own: a background sample behind an object node is kept (the render's
    /// pruned query, [`query_pruned`], keeps by this rule too, in rounds along the rays).
    Node,
    /// The ray's, through every node's samples merged in depth: a background sample behind
    /// an opaque object node is dropped too. Every node with samples goes through the
    /// density pass once any node is worth pruning.
    Ray,
}

/// Drops the samples behind the point where the transmittance falls below `eps` (by
/// `by`: the node's own, or the ray's through all nodes), in the nodes with at least
/// [`PRUNE_MIN_PER_RAY`] samples per ray reaching them (with [`PruneBy::Ray`], in every
/// node once one has). Returns how many samples went through the density pass and how
/// many of them were dropped. Training's pass: each queried node's encoding of the
/// samples it keeps is left in its tape (`tapes`, one per node of `traced`), so the
/// forward pass that follows does not encode them again.
pub fn prune_occluded(
    scene: &NeuralScene,
    traced: &mut Traced,
    eps: f32,
    by: PruneBy,
    sc: &mut PruneScratch,
    tapes: &mut Vec<assist_field::Tape>,
) -> PruneStats {
    let mut stats = PruneStats::default();
    let nodes = traced.nodes.len();
    tapes.resize_with(nodes, Default::default);
    let worth: Vec<bool> = traced.nodes.iter().map(worth_pruning).collect();
    let query: Vec<bool> = match by {
        PruneBy::Node => worth,
        PruneBy::Ray if worth.contains(&true) => {
            traced.nodes.iter().map(|n| !n.is_empty()).collect()
        }
        PruneBy::Ray => return stats,
    };
    sc.sigmas.resize_with(nodes, Vec::new);
    for (k, (ns, tape)) in traced.nodes.iter().zip(tapes.iter_mut()).enumerate() {
        sc.sigmas[k].clear();
        if !query[k] {
            continue;
        }
        let n = ns.len();
        stats.queried += n;
        sc.sigmas[k].resize(n, 0.0);
        let nf = scene.field_of(ns.node);
        nf.field.density_encoded(
            [&ns.pos[0], &ns.pos[1], &ns.pos[2]],
            &mut sc.sigmas[k],
            tape,
        );
    }
    if by == PruneBy::Ray {
        stop_distances(&traced.nodes, &sc.sigmas, eps, &mut sc.stop);
    }
    for (k, (ns, tape)) in traced.nodes.iter_mut().zip(tapes.iter_mut()).enumerate() {
        if !query[k] {
            continue;
        }
        let n = ns.len();
        let total = match by {
            PruneBy::Node => keep_counts(ns, &sc.sigmas[k], eps, &mut sc.keep),
            PruneBy::Ray => keep_before(ns, &sc.stop, &mut sc.keep),
        };
        if total < n {
            kept_indices(ns, &sc.keep, &mut sc.kept);
            compact(ns, &sc.keep);
            let nf = scene.field_of(ns.node);
            nf.field
                .keep_encoded(tape, &sc.kept, [&ns.pos[0], &ns.pos[1], &ns.pos[2]]);
            stats.dropped += n - total;
        }
    }
    stats
}

/// Per ray, the distance of the first sample (of any node, the queried nodes' samples
/// merged in depth) before which the optical depth exceeds `-ln eps`: from there on every
/// sample's weight in the composite is below `eps`. Infinite where the ray never gets
/// there. `sigmas[k]` holds node `k`'s densities, or nothing where it was not queried.
fn stop_distances(nodes: &[NodeSamples], sigmas: &[Vec<f32>], eps: f32, stop: &mut Vec<f32>) {
    let limit = -eps.ln();
    let rays = nodes.first().map_or(0, |ns| ns.start.len() - 1);
    stop.clear();
    stop.resize(rays, f32::INFINITY);
    stop.par_iter_mut()
        .enumerate()
        .for_each_init(Vec::new, |buf: &mut Vec<(f32, f32)>, (r, s)| {
            buf.clear();
            for (ns, sigma) in nodes.iter().zip(sigmas) {
                if sigma.len() == ns.len() {
                    let (a, b) = (ns.start[r] as usize, ns.start[r + 1] as usize);
                    buf.extend((a..b).map(|i| (ns.t[i], sigma[i] * ns.dt[i])));
                }
            }
            // One node's samples are in order already (the sort then only checks).
            buf.sort_by(|x, y| x.0.total_cmp(&y.0));
            let mut tau = 0.0f32;
            for &(t, d) in buf.iter() {
                if tau > limit {
                    *s = t;
                    break;
                }
                tau += d;
            }
        });
}

/// Per ray of `ns`, how many leading samples lie before the ray's stop distance `stop`.
/// Returns the total kept.
fn keep_before(ns: &NodeSamples, stop: &[f32], keep: &mut Vec<u32>) -> usize {
    let rays = ns.start.len() - 1;
    keep.resize(rays, 0);
    keep.par_iter_mut().enumerate().for_each(|(r, k)| {
        let (a, b) = (ns.start[r] as usize, ns.start[r + 1] as usize);
        *k = ns.t[a..b].partition_point(|&t| t < stop[r]) as u32;
    });
    keep.iter().map(|&k| k as usize).sum()
}

/// The indices of the samples `keep` keeps (the first `keep[r]` of each ray `r`), in order.
fn kept_indices(ns: &NodeSamples, keep: &[u32], kept: &mut Vec<u32>) {
    kept.clear();
    for (r, &k) in keep.iter().enumerate() {
        let a = ns.start[r];
        kept.extend(a..a + k);
    }
}

/// Rendering's pruned query of every node ([`query_node_pruned`]).
pub fn query_pruned(
    scene: &NeuralScene,
    traced: &mut Traced,
    eps: f32,
    sc: &mut PruneScratch,
    tapes: &mut Vec<assist_field::Tape>,
    q: crate::render::Query,
) -> PruneStats {
    let mut stats = PruneStats::default();
    tapes.resize_with(traced.nodes.len(), Default::default);
    for (ns, tape) in traced.nodes.iter_mut().zip(tapes.iter_mut()) {
        let s = query_node_pruned(scene, ns, eps, sc, tape, q);
        stats.queried += s.queried;
        stats.dropped += s.dropped;
        stats.density_s += s.density_s;
    }
    stats
}

/// Rendering's pruned query of one node, in rounds along the rays: each round queries
/// the next [`ROUND`] samples of every ray whose node's own transmittance is still above
/// `eps`, so a ray that has met its surface gets no further query, density or colour.
/// What a ray keeps is the prefix of its samples up to the round in which its
/// transmittance fell below `eps` — every sample before that point, and a few after it —
/// and depends on that ray alone (a drag's re-rendered rays match a full render's). The
/// rounds' copying pays only where many rays stop early: a node's first batch, and any
/// after a batch that dropped less than [`ROUNDS_PAY`] of its samples, is queried whole
/// and each ray cut afterwards to what its rounds would keep (the same samples and bits;
/// `sc` carries the choice from batch to batch).
pub fn query_node_pruned(
    scene: &NeuralScene,
    ns: &mut NodeSamples,
    eps: f32,
    sc: &mut PruneScratch,
    tape: &mut assist_field::Tape,
    q: crate::render::Query,
) -> PruneStats {
    let mut stats = PruneStats::default();
    let elsewhere = matches!(
        q,
        crate::render::Query::Render {
            backend: Some(_),
            ..
        }
    );
    if ns.is_empty() || elsewhere {
        // A backend (a GPU) queries every sample: no rounds here.
        stats.queried = ns.len();
        crate::render::query_node(scene, ns, tape, q);
        return stats;
    }
    let t0 = std::time::Instant::now();
    let n = ns.len();
    let limit = -eps.ln();
    if sc.in_rounds.len() <= ns.node {
        sc.in_rounds.resize(ns.node + 1, false);
    }
    // Either way, every kept sample's outputs end in place and `sc.keep` holds how many
    // leading samples each ray keeps.
    let rounds = sc.in_rounds[ns.node];
    let queried_s = if rounds {
        query_in_rounds(scene, ns, limit, sc, tape, q)
    } else {
        // Every sample in one query, then each ray cut where its rounds would have
        // stopped it: the same samples and bits as the rounds, without their copying.
        let tq = std::time::Instant::now();
        crate::render::query_node(scene, ns, tape, q);
        let queried_s = tq.elapsed().as_secs_f64();
        rounds_keep(ns, limit, &mut sc.keep);
        queried_s
    };
    let total: usize = sc.keep.iter().map(|&k| k as usize).sum();
    stats.queried = if rounds { total } else { n };
    if total < n {
        compact_with_outputs(ns, &sc.keep);
        stats.dropped = n - total;
    }
    sc.in_rounds[ns.node] = stats.dropped >= (ROUNDS_PAY * n as f64) as usize;
    stats.density_s = t0.elapsed().as_secs_f64() - queried_s;
    stats
}

/// [`query_node_pruned`]'s rounds: the outputs of every sample queried put in place in
/// `ns` (the rest left as they were), each ray's count of them in `sc.keep`. Returns the
/// seconds spent in the queries themselves.
fn query_in_rounds(
    scene: &NeuralScene,
    ns: &mut NodeSamples,
    limit: f32,
    sc: &mut PruneScratch,
    tape: &mut assist_field::Tape,
    q: crate::render::Query,
) -> f64 {
    let n = ns.len();
    let rays = ns.start.len() - 1;
    sc.keep.clear();
    sc.keep.resize(rays, 0);
    sc.tau.clear();
    sc.tau.resize(rays, 0.0);
    sc.live.clear();
    sc.live
        .extend((0..rays as u32).filter(|&r| ns.start[r as usize + 1] > ns.start[r as usize]));
    // The outputs, by the samples' places before compaction.
    // (Not cleared: every sample kept is written, and the rest are compacted away.)
    let mut sigma = std::mem::take(&mut ns.sigma);
    let mut rgb = std::mem::take(&mut ns.rgb);
    sigma.resize(n, 0.0);
    rgb.resize(3 * n, 0.0);
    let mut sub = std::mem::take(&mut sc.round);
    let mut queried_s = 0.0;
    while !sc.live.is_empty() {
        // The round's samples of every live ray, ray after ray.
        let (keep, start) = (&sc.keep, &ns.start);
        let round_of = |&r: &u32| {
            let a = start[r as usize] as usize + keep[r as usize] as usize;
            a..(a + ROUND).min(start[r as usize + 1] as usize)
        };
        ns.gather(sc.live.iter().map(round_of), false, &mut sub);
        let tq = std::time::Instant::now();
        crate::render::query_node(scene, &mut sub, tape, q);
        queried_s += tq.elapsed().as_secs_f64();
        // Each live ray's outputs into place (the two arrays and the round's optical
        // depths each a task of their own) and its optical depth so far; a ray past the
        // limit, or out of samples, is done.
        let (live, keep) = (&sc.live, &sc.keep);
        let place =
            |k: usize| ns.start[live[k] as usize] as usize + keep[live[k] as usize] as usize;
        let mut depth = std::mem::take(&mut sc.depth);
        rayon::scope(|s| {
            s.spawn(|_| {
                for k in 0..live.len() {
                    let (i0, i1) = (sub.start[k] as usize, sub.start[k + 1] as usize);
                    sigma[place(k)..place(k) + i1 - i0].copy_from_slice(&sub.sigma[i0..i1]);
                }
            });
            s.spawn(|_| {
                for k in 0..live.len() {
                    let (i0, i1) = (sub.start[k] as usize, sub.start[k + 1] as usize);
                    let a = 3 * place(k);
                    rgb[a..a + 3 * (i1 - i0)].copy_from_slice(&sub.rgb[3 * i0..3 * i1]);
                }
            });
            s.spawn(|_| {
                depth.clear();
                depth.extend((0..live.len()).map(|k| {
                    (sub.start[k] as usize..sub.start[k + 1] as usize)
                        .map(|i| sub.sigma[i] * sub.dt[i])
                        .sum::<f32>()
                }));
            });
        });
        let mut still = 0;
        for k in 0..sc.live.len() {
            let r = sc.live[k] as usize;
            sc.tau[r] += depth[k];
            sc.keep[r] += sub.start[k + 1] - sub.start[k];
            if sc.tau[r] <= limit && sc.keep[r] < ns.start[r + 1] - ns.start[r] {
                sc.live[still] = r as u32;
                still += 1;
            }
        }
        sc.depth = depth;
        sc.live.truncate(still);
    }
    sc.round = sub;
    ns.sigma = sigma;
    ns.rgb = rgb;
    queried_s
}

/// The share of a node's samples a batch must drop for rounds to pay for their copying
/// on its next batch; below it, the next batch is queried whole and cut afterwards
/// ([`rounds_keep`]).
const ROUNDS_PAY: f64 = 0.2;

/// Per ray of `ns` (every sample's outputs in place), how many leading samples the rounds
/// of [`query_node_pruned`] keep: whole rounds, until the one after which the optical
/// depth exceeds `limit`, each round's summed as the rounds sum it (so the same bits
/// decide).
fn rounds_keep(ns: &NodeSamples, limit: f32, keep: &mut Vec<u32>) {
    let rays = ns.start.len() - 1;
    keep.resize(rays, 0);
    let (start, sigma, dt) = (&ns.start, &ns.sigma, &ns.dt);
    keep.par_iter_mut().enumerate().for_each(|(r, k)| {
        let (a, len) = (start[r] as usize, (start[r + 1] - start[r]) as usize);
        let (mut kept, mut tau) = (0usize, 0.0f32);
        while kept < len {
            let end = (kept + ROUND).min(len);
            tau += (a + kept..a + end).map(|i| sigma[i] * dt[i]).sum::<f32>();
            kept = end;
            // As the rounds judge it (a NaN depth stops the ray there too).
            let open = tau <= limit;
            if !open {
                break;
            }
        }
        *k = kept as u32;
    });
}

/// Samples per ray in each round of a pruned query: short, so that a ray stops soon after
/// its surface even where rays carry only a few samples (bounded rooms, objects).
const ROUND: usize = 4;

/// Whether node samples `ns` have enough samples per ray reaching the node for the
/// density pass to pay ([`PRUNE_MIN_PER_RAY`]).
fn worth_pruning(ns: &NodeSamples) -> bool {
    if ns.is_empty() {
        return false;
    }
    let reached = ns.start.windows(2).filter(|w| w[1] > w[0]).count().max(1);
    ns.len() as f32 >= PRUNE_MIN_PER_RAY * reached as f32
}

/// Per ray of `ns`, how many leading samples to keep: those before the node's own
/// transmittance (from densities `sigma`) falls below `eps`. Returns the total kept.
fn keep_counts(ns: &NodeSamples, sigma: &[f32], eps: f32, keep: &mut Vec<u32>) -> usize {
    let limit = -eps.ln();
    let rays = ns.start.len() - 1;
    keep.resize(rays, 0);
    let (start, dt) = (&ns.start, &ns.dt);
    keep.par_iter_mut().enumerate().for_each(|(r, k)| {
        let (a, b) = (start[r] as usize, start[r + 1] as usize);
        let mut tau = 0.0f32;
        let mut m = b - a;
        for i in a..b {
            if tau > limit {
                m = i - a;
                break;
            }
            tau += sigma[i] * dt[i];
        }
        *k = m as u32;
    });
    keep.iter().map(|&k| k as usize).sum()
}

/// What [`prune_occluded`] or [`query_pruned`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PruneStats {
    /// Training: the samples that went through the density pass. Rendering: the samples
    /// queried (those kept).
    pub queried: usize,
    /// The samples dropped.
    pub dropped: usize,
    /// Rendering: seconds spent choosing and moving samples, outside the queries
    /// ([`query_pruned`]).
    pub density_s: f64,
}

/// [`compact`], the samples' field outputs (`sigma`, `rgb`) moved with them.
fn compact_with_outputs(ns: &mut NodeSamples, keep: &[u32]) {
    let (start, sigma, rgb) = (&ns.start, &mut ns.sigma, &mut ns.rgb);
    rayon::join(
        || keep_prefixes(sigma, start, keep, 1),
        || keep_prefixes(rgb, start, keep, 3),
    );
    compact(ns, keep);
}

/// Keeps the first `keep[r]` samples of each ray `r` (each array a task of its own).
fn compact(ns: &mut NodeSamples, keep: &[u32]) {
    let NodeSamples {
        pos,
        dir,
        image,
        t,
        dt,
        start,
        ..
    } = ns;
    let st = &start[..];
    rayon::scope(|s| {
        s.spawn(|_| keep_prefixes(image, st, keep, 1));
        s.spawn(|_| keep_prefixes(t, st, keep, 1));
        s.spawn(|_| keep_prefixes(dt, st, keep, 1));
        for a in pos.iter_mut().chain(dir.iter_mut()) {
            s.spawn(|_| keep_prefixes(a, st, keep, 1));
        }
    });
    let mut w = 0u32;
    for (r, &k) in keep.iter().enumerate() {
        start[r] = w;
        w += k;
    }
    start[keep.len()] = w;
}

/// `v` (`k` values per sample, rays by `start`) cut to the first `keep[r]` samples of each
/// ray `r`, in place.
fn keep_prefixes<T: Copy>(v: &mut Vec<T>, start: &[u32], keep: &[u32], k: usize) {
    let mut w = 0usize;
    for (r, &m) in keep.iter().enumerate() {
        let (a, m) = (k * start[r] as usize, k * m as usize);
        if w != a {
            v.copy_within(a..a + m, w);
        }
        w += m;
    }
    v.truncate(w);
}
