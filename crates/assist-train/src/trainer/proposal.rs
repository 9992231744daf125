//! Training a background's proposal field beside it: each step's coarse samples (kept by
//! the sampling) and the field's weights along the same rays give the interlevel loss
//! (`assist_render::proposal::interlevel`), whose gradient reaches only the proposal.

use std::sync::Arc;

use assist_field::{Adam, Proposal, ProposalConfig, ProposalField};
use assist_render::proposal::{interlevel, weights, weights_backward};
use rayon::prelude::*;

use super::Trainer;

/// The most coarse samples a step trains the proposal on: a step's first rays up to this
/// many (early in training a ray's coarse march holds several times the samples drawn
/// from it, and the proposal's training would cost as much as the field's).
const PROPOSAL_BATCH: usize = 1 << 16;

/// How many of a step's first rays (drawn at random) the proposal trains on: as many as
/// hold at most `budget` coarse samples in all (their samples are a prefix of the record's,
/// `start` its per-ray offsets, one more than the rays), and at least one.
fn rays_within(start: &[u32], budget: usize) -> usize {
    start
        .partition_point(|&s| s as usize <= budget)
        .saturating_sub(1)
        .clamp(1, start.len().saturating_sub(1).max(1))
}

/// The proposal's optimiser and buffers.
#[derive(Debug, Default)]
pub(crate) struct ProposalTraining {
    adam: Option<Adam>,
    tape: assist_field::ProposalTape,
    grad: Vec<f32>,
    d_sigma: Vec<f32>,
}

impl Trainer {
    /// Gives the background a proposal drawing `samples` per ray, when it is unbounded
    /// (contracted): a fresh one, or its own kept with the new count. 0 leaves the scene
    /// as it is (a proposal it has goes on training).
    pub(super) fn attach_proposal(&mut self, samples: usize) {
        let Some(b) = self.background else { return };
        if samples == 0 {
            return;
        }
        let key = self.scene.scene.nodes[b].field.clone();
        let nf = Arc::make_mut(self.scene.fields.get_mut(&key).expect("field of node"));
        if nf.space != assist_core::NodeSpace::Contracted {
            return;
        }
        let field = match nf.proposal.take() {
            Some(p) => p.field,
            None => ProposalField::new(ProposalConfig::default(), self.opts.seed ^ 0x7072_6f70)
                .expect("the default proposal's sizes are valid"),
        };
        nf.proposal = Some(Proposal { field, samples });
    }

    /// One step of the proposal's training on the batch just queried (when its samples
    /// came from a proposal), on its first rays up to [`PROPOSAL_BATCH`] coarse samples:
    /// returns the interlevel loss (mean per ray trained on).
    pub(super) fn train_proposal(&mut self, lr: f32) -> Option<f64> {
        let rec = self.traced.proposal.as_ref()?;
        let ns = &self.traced.nodes[rec.node];
        let key = &self.scene.scene.nodes[rec.node].field;
        let all = self.traced.rays;
        if all == 0
            || ns.start.len() != all + 1
            || rec.spans.len() != ns.len()
            || rec.start.len() != all + 1
        {
            return None;
        }
        let rays = rays_within(&rec.start, PROPOSAL_BATCH);
        let coarse = rec.start[rays] as usize;
        let t = &mut self.proposal;
        t.d_sigma.clear();
        t.d_sigma.resize(coarse, 0.0);
        // Rays in parallel, each writing its own coarse samples' gradient.
        let mut parts: Vec<(std::ops::Range<usize>, &mut [f32])> = Vec::with_capacity(rays);
        let mut rest = &mut t.d_sigma[..];
        for r in 0..rays {
            let c = rec.range(r);
            let (head, tail) = rest.split_at_mut(c.len());
            parts.push((r..r + 1, head));
            rest = tail;
        }
        // Each ray's loss collected in order and summed in order (rayon's `sum` associates
        // by how the work was split, so the reported loss moved from run to run).
        let per_ray: Vec<f64> = parts
            .into_par_iter()
            .map_init(
                || (Vec::new(), Vec::new(), Vec::new()),
                |(w_f, w_c, g_c), (r, d)| {
                    let r = r.start;
                    let (c, f) = (rec.range(r), ns.range(r));
                    if c.is_empty() || f.is_empty() {
                        return 0.0;
                    }
                    w_f.resize(f.len(), 0.0);
                    weights(&ns.sigma[f.clone()], &ns.dt[f.clone()], w_f);
                    w_c.resize(c.len(), 0.0);
                    weights(&rec.sigma[c.clone()], &rec.delta[c.clone()], w_c);
                    g_c.clear();
                    g_c.resize(c.len(), 0.0);
                    let l = interlevel(&rec.steps[c.clone()], w_c, &rec.spans[f], w_f, g_c);
                    weights_backward(&rec.sigma[c.clone()], &rec.delta[c], g_c, d);
                    l as f64
                },
            )
            .collect();
        let loss: f64 = per_ray.iter().sum();
        let scale = 1.0 / rays.max(1) as f32;
        t.d_sigma.iter_mut().for_each(|d| *d *= scale);
        let nf = Arc::make_mut(self.scene.fields.get_mut(key).expect("field of node"));
        let p = &mut nf.proposal.as_mut()?.field;
        let pos = [
            &rec.pos[0][..coarse],
            &rec.pos[1][..coarse],
            &rec.pos[2][..coarse],
        ];
        p.forward_train(pos, &mut t.tape);
        t.grad.clear();
        t.grad.resize(p.params.len(), 0.0);
        p.backward(pos, &t.tape, &t.d_sigma, &mut t.grad);
        let adam = t.adam.get_or_insert_with(|| {
            let mut a = Adam::new(p.params.len());
            a.sparse_range = 0..p.mlp_start();
            a
        });
        if adam.m.len() != p.params.len() {
            return None;
        }
        adam.update(lr, &mut p.params, &mut t.grad);
        Some(loss / rays.max(1) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::rays_within;

    /// Rays of 10, 15 and 15 coarse samples: the budget takes whole rays from the first,
    /// never none, never more than there are.
    #[test]
    fn the_proposal_trains_on_the_first_rays_within_its_budget() {
        let start = [0, 10, 25, 40];
        assert_eq!(rays_within(&start, 25), 2);
        assert_eq!(rays_within(&start, 24), 1);
        assert_eq!(rays_within(&start, 40), 3);
        assert_eq!(rays_within(&start, 1 << 20), 3);
        // The first ray alone is over the budget: it is trained on all the same.
        assert_eq!(rays_within(&start, 5), 1);
        assert_eq!(rays_within(&[0, 7], 3), 1);
        // The training step's own budget on a step whose rays hold 119 coarse samples.
        let many: Vec<u32> = (0..=4096).map(|r| r * 119).collect();
        let r = rays_within(&many, super::PROPOSAL_BATCH);
        assert!(
            many[r] as usize <= super::PROPOSAL_BATCH
                && many[r + 1] as usize > super::PROPOSAL_BATCH
        );
    }
}
