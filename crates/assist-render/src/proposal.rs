//! Drawing a ray's samples from a proposal field's weights (mip-NeRF 360, Nerfacto), and
//! the interlevel loss that trains the proposal to bound the field's weights.
//!
//! A ray's coarse intervals are its march's steps (each `[t, t + dt]`, sorted; the march
//! skips empty cells, so there may be gaps between them). Resampling works in the
//! coordinate `u` that runs along the coarse intervals only (their lengths laid end to
//! end, the gaps left out): the fine intervals are cut at levels of the weights'
//! cumulative distribution over `u`, so a fine interval's length never counts a gap the
//! march found empty.

use assist_field::Step;

/// Weight added to every coarse interval before the fine ones are drawn (Nerfacto's
/// histogram padding), so no interval the proposal thinks empty is never sampled again.
pub const HISTOGRAM_PADDING: f32 = 0.01;

/// A ray's fine interval in the coarse intervals' coordinate `u` (see the module's
/// comment): `[u0, u1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Span {
    pub u0: f32,
    pub u1: f32,
}

/// A training batch's coarse samples of the node whose samples a proposal drew, kept for
/// the interlevel loss ([`interlevel`]). Ray `r`'s coarse samples are
/// `start[r]..start[r + 1]`; the node's samples (as drawn, before anything is dropped)
/// have one span each, in the same order.
#[derive(Debug, Clone, Default)]
pub struct ProposalRecord {
    pub node: usize,
    /// Positions in [0, 1]³.
    pub pos: [Vec<f32>; 3],
    /// The march's steps (parameter and length along the ray in the node's box units).
    pub steps: Vec<Step>,
    /// The intervals in box diagonals (what density is integrated over).
    pub delta: Vec<f32>,
    /// The proposal's densities when the samples were drawn.
    pub sigma: Vec<f32>,
    pub start: Vec<u32>,
    pub spans: Vec<Span>,
}

impl ProposalRecord {
    /// The blocks' records one after another (each block's `start` holds its rays'
    /// block-local starts and its end).
    pub(crate) fn append_all(&mut self, blocks: &[ProposalRecord]) {
        for a in 0..3 {
            self.pos[a].clear();
        }
        self.steps.clear();
        self.delta.clear();
        self.sigma.clear();
        self.spans.clear();
        self.start.clear();
        self.start.push(0);
        for b in blocks.iter().filter(|b| !b.start.is_empty()) {
            let base = self.steps.len() as u32;
            self.start.extend(b.start[1..].iter().map(|s| s + base));
            for a in 0..3 {
                self.pos[a].extend_from_slice(&b.pos[a]);
            }
            self.steps.extend_from_slice(&b.steps);
            self.delta.extend_from_slice(&b.delta);
            self.sigma.extend_from_slice(&b.sigma);
            self.spans.extend_from_slice(&b.spans);
        }
    }

    /// Ray `r`'s coarse samples.
    pub fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.start[r] as usize..self.start[r + 1] as usize
    }
}

/// The weights `wᵢ = Tᵢ (1 − e^{−σᵢ δᵢ})` of one ray's samples (`Tᵢ` the transmittance
/// before sample `i`), into `w`; returns the transmittance left after the last.
pub fn weights(sigma: &[f32], delta: &[f32], w: &mut [f32]) -> f32 {
    let mut acc = 0.0f32;
    let mut t_before = 1.0f32;
    for i in 0..sigma.len() {
        acc += sigma[i] * delta[i];
        let t_after = (-acc).exp();
        w[i] = t_before - t_after;
        t_before = t_after;
    }
    t_before
}

/// The gradient of a loss with respect to each `σᵢ`, given its gradient `g` with respect
/// to each weight of [`weights`]: `∂L/∂σₖ = δₖ (gₖ Tₖ₊₁ − Σ_{i>k} gᵢ wᵢ)`, into `d_sigma`.
pub fn weights_backward(sigma: &[f32], delta: &[f32], g: &[f32], d_sigma: &mut [f32]) {
    let n = sigma.len();
    // Forward again for the transmittances after each sample and the weights.
    let mut after = vec![0.0f32; n];
    let mut w = vec![0.0f32; n];
    let mut acc = 0.0f32;
    let mut t_before = 1.0f32;
    for i in 0..n {
        acc += sigma[i] * delta[i];
        after[i] = (-acc).exp();
        w[i] = t_before - after[i];
        t_before = after[i];
    }
    let mut behind = 0.0f32;
    for k in (0..n).rev() {
        d_sigma[k] = delta[k] * (g[k] * after[k] - behind);
        behind += g[k] * w[k];
    }
}

/// Draws `n` fine intervals of one ray from its coarse `steps` and their weights `w`
/// (padded by [`HISTOGRAM_PADDING`]): `n + 1` cuts at the levels `(k + ξₖ) / (n + 1)` of
/// the weights' distribution over `u` (`jitter` gives each `ξₖ` from a stream; none:
/// every level `k / n`, so the fine intervals cover the coarse ones end to end). Appends
/// the fine samples to `out` as steps (each at its interval's start, as a march's, with the
/// interval's length) and their spans to `spans`. Nothing when `steps` is empty.
pub fn resample(
    steps: &[Step],
    w: &[f32],
    n: usize,
    mut jitter: Option<&mut assist_core::Rng>,
    out: &mut Vec<Step>,
    spans: &mut Vec<Span>,
) {
    if steps.is_empty() || n == 0 {
        return;
    }
    let pad: f32 = HISTOGRAM_PADDING;
    let total: f32 = w.iter().map(|&x| x.max(0.0) + pad).sum();
    // Walks the bins (and their starts in u) as the levels rise.
    let mut bin = 0usize;
    let mut cdf_before = 0.0f32;
    let mut u_before = 0.0f32;
    let mut cut = |level: f32| -> f32 {
        let target = level.clamp(0.0, 1.0) * total;
        loop {
            let mass = w[bin].max(0.0) + pad;
            if cdf_before + mass >= target || bin + 1 == steps.len() {
                let f = ((target - cdf_before) / mass).clamp(0.0, 1.0);
                return u_before + f * steps[bin].dt;
            }
            cdf_before += mass;
            u_before += steps[bin].dt;
            bin += 1;
        }
    };
    let mut u = Vec::with_capacity(n + 1);
    for k in 0..=n {
        let level = match jitter.as_deref_mut() {
            Some(rng) => (k as f32 + rng.f32()) / (n + 1) as f32,
            None => k as f32 / n as f32,
        };
        u.push(cut(level));
    }
    // u back to t, along the coarse intervals.
    let mut bin = 0usize;
    let mut u_start = 0.0f32;
    let mut to_t = |x: f32| -> f32 {
        while bin + 1 < steps.len() && x > u_start + steps[bin].dt {
            u_start += steps[bin].dt;
            bin += 1;
        }
        steps[bin].t + (x - u_start).clamp(0.0, steps[bin].dt)
    };
    for k in 0..n {
        let (u0, u1) = (u[k], u[k + 1].max(u[k]));
        out.push(Step {
            t: to_t(u0),
            dt: u1 - u0,
        });
        spans.push(Span { u0, u1 });
    }
}

/// The interlevel loss of one ray (mip-NeRF 360, eq. 13): each fine interval's weight
/// `w_f` (held fixed) beyond the sum of the coarse weights over the coarse intervals it
/// overlaps, `Σ max(0, w_f − bound)² / (w_f + ε)`. The coarse intervals are `steps` (their
/// spans in `u` laid end to end), with weights `w_c`; adds the loss's gradient with
/// respect to each coarse weight into `g_c` and returns the loss.
pub fn interlevel(
    steps: &[Step],
    w_c: &[f32],
    spans: &[Span],
    w_f: &[f32],
    g_c: &mut [f32],
) -> f32 {
    const EPS: f32 = 1e-7;
    let mut loss = 0.0f32;
    // The coarse intervals' starts in u.
    let mut starts = Vec::with_capacity(steps.len() + 1);
    let mut u = 0.0f32;
    for s in steps {
        starts.push(u);
        u += s.dt;
    }
    starts.push(u);
    let mut first = 0usize;
    for (span, &wf) in spans.iter().zip(w_f) {
        // The coarse intervals overlapping [u0, u1]: those starting before u1 and ending
        // after u0 (a point span takes the interval it lies in).
        while first + 1 < steps.len() && starts[first + 1] <= span.u0 {
            first += 1;
        }
        let mut last = first;
        while last + 1 < steps.len() && starts[last + 1] < span.u1 {
            last += 1;
        }
        let bound: f32 = w_c[first..=last].iter().sum();
        let excess = wf - bound;
        if excess > 0.0 {
            loss += excess * excess / (wf + EPS);
            let g = -2.0 * excess / (wf + EPS);
            g_c[first..=last].iter_mut().for_each(|x| *x += g);
        }
    }
    loss
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::Rng;

    fn coarse(rng: &mut Rng, n: usize) -> Vec<Step> {
        let mut t = 0.2;
        (0..n)
            .map(|_| {
                // Gaps here and there, as an occupancy grid's skipping leaves them.
                if rng.f32() < 0.2 {
                    t += rng.f32();
                }
                let s = Step {
                    t,
                    dt: 0.05 + 0.2 * rng.f32(),
                };
                t += s.dt;
                s
            })
            .collect()
    }

    #[test]
    fn weights_and_their_gradient_match_central_differences() {
        let mut rng = Rng::new(1);
        let n = 12;
        let sigma: Vec<f32> = (0..n).map(|_| 3.0 * rng.f32()).collect();
        let delta: Vec<f32> = (0..n).map(|_| 0.05 + 0.3 * rng.f32()).collect();
        let g: Vec<f32> = (0..n).map(|_| rng.f32() * 2.0 - 1.0).collect();
        let mut w = vec![0.0; n];
        let left = weights(&sigma, &delta, &mut w);
        // By hand for the first two: 1 − e^{−σδ}, then e^{−σ₀δ₀}(1 − e^{−σ₁δ₁}).
        let a0 = 1.0 - (-sigma[0] * delta[0]).exp();
        let a1 = 1.0 - (-sigma[1] * delta[1]).exp();
        assert!((w[0] - a0).abs() < 1e-6 && (w[1] - (1.0 - a0) * a1).abs() < 1e-6);
        assert!((w.iter().sum::<f32>() + left - 1.0).abs() < 1e-5);
        let mut d = vec![0.0; n];
        weights_backward(&sigma, &delta, &g, &mut d);
        let loss = |s: &[f32]| {
            let mut w = vec![0.0; n];
            weights(s, &delta, &mut w);
            w.iter()
                .zip(&g)
                .map(|(a, b)| (*a as f64) * (*b as f64))
                .sum::<f64>()
        };
        for k in 0..n {
            let h = 1e-3;
            let mut s = sigma.clone();
            s[k] += h;
            let up = loss(&s);
            s[k] -= 2.0 * h;
            let numeric = (up - loss(&s)) / (2.0 * h as f64);
            assert!(
                (numeric - d[k] as f64).abs() < 1e-3,
                "σ{k}: {} vs {numeric}",
                d[k]
            );
        }
    }

    /// Fine samples lie inside the coarse intervals, sorted, their lengths summing to the
    /// coarse intervals' (deterministic cuts), crowded where the weight is.
    #[test]
    fn fine_samples_follow_the_weights_inside_the_coarse_intervals() {
        let mut rng = Rng::new(2);
        let steps = coarse(&mut rng, 40);
        let mut w = vec![0.0f32; 40];
        w[25] = 0.9;
        w[26] = 0.05;
        for jitter in [false, true] {
            let mut j = Rng::new(7);
            let (mut out, mut spans) = (Vec::new(), Vec::new());
            resample(
                &steps,
                &w,
                32,
                jitter.then_some(&mut j),
                &mut out,
                &mut spans,
            );
            assert_eq!(out.len(), 32);
            let total: f32 = steps.iter().map(|s| s.dt).sum();
            let fine: f32 = out.iter().map(|s| s.dt).sum();
            if !jitter {
                assert!((fine - total).abs() < 1e-4 * total, "{fine} vs {total}");
            }
            for (k, s) in out.iter().enumerate() {
                assert!(
                    steps.iter().any(|c| s.t >= c.t && s.t <= c.t + c.dt),
                    "{s:?}"
                );
                if k > 0 {
                    assert!(s.t >= out[k - 1].t && spans[k].u0 >= spans[k - 1].u0);
                }
            }
            let peak = steps[25];
            let inside = out
                .iter()
                .filter(|s| s.t >= peak.t && s.t <= peak.t + peak.dt)
                .count();
            // 0.9 of the weight against 40 × 0.01 of padding: about two thirds.
            assert!((17..=25).contains(&inside), "{inside} of 32 in the peak");
        }
    }

    #[test]
    fn interlevel_loss_is_zero_when_bounded_and_its_gradient_matches() {
        let mut rng = Rng::new(3);
        let steps = coarse(&mut rng, 20);
        let w_c: Vec<f32> = (0..20).map(|_| 0.05 * rng.f32()).collect();
        let (mut out, mut spans) = (Vec::new(), Vec::new());
        resample(
            &steps,
            &w_c,
            24,
            Some(&mut Rng::new(5)),
            &mut out,
            &mut spans,
        );
        // Fine weights under their bound give no loss; a fine weight above it does.
        let mut g = vec![0.0; 20];
        let small = vec![1e-4f32; 24];
        assert_eq!(interlevel(&steps, &w_c, &spans, &small, &mut g), 0.0);
        assert!(g.iter().all(|&x| x == 0.0));
        let w_f: Vec<f32> = (0..24).map(|_| 0.1 * rng.f32()).collect();
        let loss = interlevel(&steps, &w_c, &spans, &w_f, &mut g);
        assert!(loss > 0.0);
        for i in 0..20 {
            let h = 1e-4;
            let mut w = w_c.clone();
            w[i] += h;
            let up = interlevel(&steps, &w, &spans, &w_f, &mut [0.0; 20]) as f64;
            w[i] -= 2.0 * h;
            let down = interlevel(&steps, &w, &spans, &w_f, &mut [0.0; 20]) as f64;
            let numeric = (up - down) / (2.0 * h as f64);
            assert!(
                (numeric - g[i] as f64).abs() < 2e-2 * numeric.abs().max(1.0),
                "w{i}: {} vs {numeric}",
                g[i]
            );
        }
        // A fine interval's bound is the coarse weight over exactly the intervals it
        // overlaps: one fine span inside coarse interval 3 is bounded by w_c[3] alone.
        let u3: f32 = steps[..3].iter().map(|s| s.dt).sum();
        let one = [Span {
            u0: u3 + 0.1 * steps[3].dt,
            u1: u3 + 0.2 * steps[3].dt,
        }];
        let mut g = vec![0.0; 20];
        let l = interlevel(&steps, &w_c, &one, &[w_c[3] + 0.1], &mut g);
        assert!((l - 0.01 / (w_c[3] + 0.1)).abs() < 1e-5, "{l}");
        assert!(g.iter().enumerate().all(|(i, &x)| (x != 0.0) == (i == 3)));
    }
}
