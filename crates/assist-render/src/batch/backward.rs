//! The backward passes of [`super::composite_batch`]: through the merged composite and
//! through each node composited alone.

use super::{CompositeGrad, NodeView, RayScratch, distortion_distance};
use crate::composite::Composite;

/// Backward through the merged composite:
/// dL/dσ_i = δ_i (T_{i+1} g_i − Σ_{j>i} w_j g_j), g_i = dL/dw_i (which includes the
/// gradient of the share of the sample's node and of the distortion). `totals`: the
/// composite before the backdrop's colour, Σ w and Σ w·s (s: the distortion's distance
/// in `unit`).
#[inline(always)]
pub(super) fn backward_merged(
    views: &mut [NodeView],
    g: &CompositeGrad,
    background: [f32; 3],
    (acc, mut w_before, mut s_before): (Composite, f32, f32),
    unit: f32,
    sc: &RayScratch,
) {
    let s_total = s_before;
    let g_bg = g.opacity
        - (g.rgb[0] * background[0] + g.rgb[1] * background[1] + g.rgb[2] * background[2]);
    // d dist / d w_i = 2 Σ_j w_j |s_i − s_j| = 2 (s_i W_{<i} − S_{<i} + S_{>i} − s_i W_{>i}),
    // with the prefix sums run backwards from the totals (W = O).
    let mut suffix = 0.0f32;
    for q in (0..sc.merged.len()).rev() {
        let (t, k, j) = sc.merged[q];
        let v = &mut views[k as usize];
        let j = j as usize;
        let wq = sc.w[q];
        let s = distortion_distance(t, unit);
        w_before -= wq;
        s_before -= wq * s;
        let g_dist = if g.distortion != 0.0 {
            let w_after = (acc.opacity - w_before - wq).max(0.0);
            let s_after = (s_total - s_before - wq * s).max(0.0);
            2.0 * g.distortion * (s * w_before - s_before + s_after - s * w_after)
        } else {
            0.0
        };
        let sh = v.shade(j);
        let c = &v.rgb[3 * j..3 * j + 3];
        // The gradient on the shaded colour, per channel, and its sum.
        let gcs = [g.rgb[0] * c[0], g.rgb[1] * c[1], g.rgb[2] * c[2]];
        let gi = g_dist
            + sh[0] * gcs[0]
            + sh[1] * gcs[1]
            + sh[2] * gcs[2]
            + g.depth * t
            + g.depth_sq * t * t
            + g_bg
            + sc.node_grads[k as usize].share;
        if sc.hidden[q] {
            // Its effect on the samples in front of it still counts (through `suffix`).
            suffix += sc.w[q] * gi;
            continue;
        }
        v.d_sigma[j] += v.dt[j] * (sc.t_next[q] * gi - suffix);
        suffix += sc.w[q] * gi;
        for ch in 0..3 {
            v.d_rgb[3 * j + ch] += sc.w[q] * sh[ch] * g.rgb[ch];
        }
        if !v.d_shade.is_empty() {
            for ch in 0..3 {
                v.d_shade[3 * j + ch] += sc.w[q] * gcs[ch];
            }
        }
    }
}

/// Backward through one node composited alone, with its gradient `ng` (`sc.w` and
/// `sc.t_next` are reused for its weights).
#[inline(always)]
pub(super) fn node_alone_backward(
    v: &mut NodeView,
    rg: std::ops::Range<usize>,
    (beyond, front): (f32, f32),
    ng: &CompositeGrad,
    sc: &mut RayScratch,
) {
    sc.w.clear();
    sc.t_next.clear();
    let mut trans = 1.0f32;
    for j in rg.clone() {
        let pass = (-(v.sigma[j] * v.dt[j])).exp();
        sc.w.push(trans * (1.0 - pass));
        trans *= pass;
        sc.t_next.push(trans);
    }
    let mut suffix = 0.0f32;
    for (q, j) in rg.enumerate().rev() {
        let c = &v.rgb[3 * j..3 * j + 3];
        let gi = ng.rgb[0] * c[0]
            + ng.rgb[1] * c[1]
            + ng.rgb[2] * c[2]
            + ng.depth * v.t[j]
            + ng.depth_sq * v.t[j] * v.t[j]
            + ng.opacity
            + if v.t[j] >= beyond { ng.beyond } else { 0.0 }
            + if v.t[j] < front { ng.front } else { 0.0 };
        v.d_sigma[j] += v.dt[j] * (sc.t_next[q] * gi - suffix);
        suffix += sc.w[q] * gi;
        for ch in 0..3 {
            v.d_rgb[3 * j + ch] += sc.w[q] * ng.rgb[ch];
        }
    }
}
