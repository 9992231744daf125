//! Dropping the samples that cannot matter before the expensive passes: a density-only
//! query of a node's samples (hash grid + density net, no colour net, no tape), then, per
//! ray, every sample after the node's own transmittance has fallen below `eps` is dropped
//! (nerfacc's early stop in training). The composite transmittance is at most the node's
//! own, so a dropped sample's weight in any output is below `eps`: the change to colour,
//! depth and opacity is below `eps`, and so is its gradient. Behind an opaque wall a
//! background ray keeps a handful of samples instead of hundreds.

use rayon::prelude::*;

use crate::sample::{NodeSamples, Traced};
use assist_scene::NeuralScene;

/// Default transmittance below which samples are dropped.
pub const PRUNE_EPS: f32 = 1e-4;

/// Nodes with fewer samples than this per ray that reaches them are left as they are: the
/// density pass costs about half a full query per sample (the hash-grid encoding is most
/// of both), so it can pay only where many samples lie behind surfaces.
pub const PRUNE_MIN_PER_RAY: f32 = 32.0;

/// Reusable buffers.
#[derive(Debug, Default)]
pub struct PruneScratch {
    sigma: Vec<f32>,
    enc: Vec<f32>,
    keep: Vec<u32>,
}

/// Drops, in every node of `traced` with at least [`PRUNE_MIN_PER_RAY`] samples per ray
/// reaching it, the samples behind the point where the node's own transmittance falls
/// below `eps`. Returns how many samples went through the density pass and how many of
/// them were dropped.
pub fn prune_occluded(
    scene: &NeuralScene,
    traced: &mut Traced,
    eps: f32,
    sc: &mut PruneScratch,
) -> PruneStats {
    let mut stats = PruneStats::default();
    for ns in traced.nodes.iter_mut() {
        if ns.is_empty() {
            continue;
        }
        let n = ns.len();
        let reached = ns.start.windows(2).filter(|w| w[1] > w[0]).count().max(1);
        if (n as f32) < PRUNE_MIN_PER_RAY * reached as f32 {
            continue;
        }
        stats.queried += n;
        let nf = scene.field_of(ns.node);
        sc.sigma.resize(n, 0.0);
        nf.field.density_with(
            [&ns.pos[0], &ns.pos[1], &ns.pos[2]],
            &mut sc.sigma[..n],
            &mut sc.enc,
        );
        let limit = -eps.ln();
        // Per ray: the number of leading samples to keep.
        let rays = ns.start.len() - 1;
        sc.keep.resize(rays, 0);
        let (start, dt, sigma) = (&ns.start, &ns.dt, &sc.sigma);
        sc.keep.par_iter_mut().enumerate().for_each(|(r, k)| {
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
        let total: usize = sc.keep.iter().map(|&k| k as usize).sum();
        if total < n {
            compact(ns, &sc.keep);
            stats.dropped += n - total;
        }
    }
    stats
}

/// What [`prune_occluded`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PruneStats {
    /// Samples that went through the density pass.
    pub queried: usize,
    /// Of those, the samples dropped.
    pub dropped: usize,
}

/// Keeps the first `keep[r]` samples of each ray `r`.
fn compact(ns: &mut NodeSamples, keep: &[u32]) {
    let mut w = 0usize;
    let rays = keep.len();
    for r in 0..rays {
        let a = ns.start[r] as usize;
        let k = keep[r] as usize;
        ns.start[r] = w as u32;
        if w != a {
            for axis in 0..3 {
                ns.pos[axis].copy_within(a..a + k, w);
                ns.dir[axis].copy_within(a..a + k, w);
            }
            ns.image.copy_within(a..a + k, w);
            ns.t.copy_within(a..a + k, w);
            ns.dt.copy_within(a..a + k, w);
        }
        w += k;
    }
    ns.start[rays] = w as u32;
    for axis in 0..3 {
        ns.pos[axis].truncate(w);
        ns.dir[axis].truncate(w);
    }
    ns.image.truncate(w);
    ns.t.truncate(w);
    ns.dt.truncate(w);
}
