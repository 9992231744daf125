//! The per-ray loss terms of training, each returning its value and its gradient with
//! respect to the composited quantities it reads, so that the value the log shows and the
//! gradient training follows come from one definition (checked against central
//! differences below). Weights (λ) and the batch mean are applied by the caller.

/// Colour error `mean_c (pred_c − target_c)²` and its gradient.
pub fn rgb(pred: [f32; 3], target: [f32; 3]) -> (f32, [f32; 3]) {
    let e = [0, 1, 2].map(|c| pred[c] - target[c]);
    (
        e.iter().map(|v| v * v).sum::<f32>() / 3.0,
        e.map(|v| 2.0 * v / 3.0),
    )
}

/// Colour error of one node alone against a target colour, in premultiplied form:
/// `mean_c (C_c − O·target_c)²`, where `C = Σ w c` is the node's composited colour and `O =
/// Σ w` its opacity. Returns the value and the gradients with respect to `C` and `O`.
///
/// The paper compares `C` with the target directly. While a node is still partly
/// transparent (`O < 1`, early in training or at its silhouette), that comparison can only
/// be met by raising every colour, and Adam keeps pushing colours that have reached the
/// top of the sigmoid until their logits are so large that the gradient underflows: the
/// node is white for the rest of the run (the demo's and beer's box backgrounds rendered in
/// grey, their colour nets saturated at 1). Scaling the target by the node's own opacity
/// asks the same of an opaque node and nothing impossible of a transparent one; the
/// opacity is supervised by its own terms.
pub fn premultiplied_rgb(color: [f32; 3], opacity: f32, target: [f32; 3]) -> (f32, [f32; 3], f32) {
    let e = [0, 1, 2].map(|c| color[c] - opacity * target[c]);
    let value = e.iter().map(|v| v * v).sum::<f32>() / 3.0;
    let d_color = e.map(|v| 2.0 * v / 3.0);
    let d_opacity = -(0..3).map(|c| 2.0 * e[c] * target[c]).sum::<f32>() / 3.0;
    (value, d_color, d_opacity)
}

/// Squared error of an opacity against a mask value (0 or 1): `(O − m)²`.
pub fn opacity(o: f32, m: f32) -> (f32, f32) {
    let e = o - m;
    (e * e, 2.0 * e)
}

/// The object-share term `(1 − W)²` of a node's share `W` of the composited weight.
pub fn share(w: f32) -> (f32, f32) {
    let e = 1.0 - w;
    (e * e, -2.0 * e)
}

/// Depth of known scale: the expected squared depth error under the node's weights,
/// `Σ w_i (t_i/E − d)² + (1 − O) d²` = `S/E² − 2 d D/E + d²`, for its composited depth
/// `D = Σ w t`, second moment `S = Σ w t²` and opacity `O`, the scene extent `E` and the
/// target `d` (units of `E`); weight the node does not place counts as placed at the
/// camera. Returns the value and the gradients with respect to `D` and `S`.
///
/// Zero only when all the weight sits at the target depth. The squared error of `D`
/// alone (the paper's `L_bg_depth`) is also met by a partly transparent node whose weight
/// sits at the far end of the ray in the right proportion, or by haze spread evenly
/// around the target — a node can then paint each training view on the walls of its box
/// and match its depth maps, which then fails on every view it did not train on.
pub fn depth_moment(depth: f32, depth_sq: f32, extent: f32, target: f32) -> (f32, f32, f32) {
    let (x, x2) = (depth / extent, depth_sq / (extent * extent));
    let value = x2 - 2.0 * target * x + target * target;
    (value, -2.0 * target / extent, 1.0 / (extent * extent))
}

/// Depth prior under a learnable affine map: `(a·D/E + b − d)²` for a node's composited
/// depth `D` (world units), the scene extent `E` and the prior `d` (units of `E`). Returns
/// the value, the gradient with respect to `D`, and with respect to `(a, b)`.
pub fn affine_depth(depth: f32, extent: f32, ab: [f32; 2], target: f32) -> (f32, f32, [f32; 2]) {
    let x = depth / extent;
    let e = ab[0] * x + ab[1] - target;
    (e * e, 2.0 * e * ab[0] / extent, [2.0 * e * x, 2.0 * e])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central difference of `f` at `x` along coordinate `i`.
    fn fd<const N: usize>(f: impl Fn([f64; N]) -> f64, x: [f64; N], i: usize) -> f64 {
        let h = 1e-2; // the terms are quadratic: central differences are exact up to rounding
        let (mut a, mut b) = (x, x);
        a[i] += h;
        b[i] -= h;
        (f(a) - f(b)) / (2.0 * h)
    }

    fn close(a: f32, b: f64) {
        assert!(
            (a as f64 - b).abs() <= 2e-3 * (1.0 + b.abs()),
            "analytic {a}, numeric {b}"
        );
    }

    fn f32s<const N: usize>(x: [f64; N]) -> [f32; N] {
        x.map(|v| v as f32)
    }

    #[test]
    fn colour_terms_match_central_differences() {
        let t = [0.2, 0.7, 0.5];
        let x = [0.4, 0.1, 0.9];
        let (_, g) = rgb(f32s(x), f32s(t));
        for i in 0..3 {
            close(g[i], fd(|x| rgb(f32s(x), f32s(t)).0 as f64, x, i));
        }
        // (C, O) as one vector of four.
        let x = [0.3, 0.25, 0.1, 0.6];
        let f = |x: [f64; 4]| {
            premultiplied_rgb([x[0], x[1], x[2]].map(|v| v as f32), x[3] as f32, f32s(t)).0 as f64
        };
        let (_, gc, go) = premultiplied_rgb([0.3, 0.25, 0.1], 0.6, f32s(t));
        for i in 0..3 {
            close(gc[i], fd(f, x, i));
        }
        close(go, fd(f, x, 3));
    }

    #[test]
    fn a_transparent_node_is_not_asked_to_brighten() {
        // Colour equal to opacity × target: no error, and no push on the colour.
        let (v, g, _) = premultiplied_rgb([0.1, 0.2, 0.05], 0.25, [0.4, 0.8, 0.2]);
        assert!(v < 1e-12 && g.iter().all(|g| g.abs() < 1e-6));
        // The plain colour error would push it towards the target.
        let (_, g) = rgb([0.1, 0.2, 0.05], [0.4, 0.8, 0.2]);
        assert!(g.iter().all(|&g| g < 0.0));
    }

    #[test]
    fn opacity_share_and_depth_terms_match_central_differences() {
        let (_, g) = opacity(0.3, 1.0);
        close(
            g,
            fd(|x: [f64; 1]| opacity(x[0] as f32, 1.0).0 as f64, [0.3], 0),
        );
        let (_, g) = share(0.7);
        close(g, fd(|x: [f64; 1]| share(x[0] as f32).0 as f64, [0.7], 0));
        // (D, a, b)
        let x = [2.5, 0.9, 0.05];
        let f =
            |x: [f64; 3]| affine_depth(x[0] as f32, 4.0, [x[1] as f32, x[2] as f32], 0.5).0 as f64;
        let (_, gd, gab) = affine_depth(2.5, 4.0, [0.9, 0.05], 0.5);
        close(gd, fd(f, x, 0));
        close(gab[0], fd(f, x, 1));
        close(gab[1], fd(f, x, 2));
        // (D, S)
        let x = [1.2, 2.0];
        let f = |x: [f64; 2]| depth_moment(x[0] as f32, x[1] as f32, 4.0, 0.3).0 as f64;
        let (_, gd, gs) = depth_moment(1.2, 2.0, 4.0, 0.3);
        close(gd, fd(f, x, 0));
        close(gs, fd(f, x, 1));
    }

    /// Weights `w` at depths `t` (extent 1): the depth-moment value.
    fn moment(w: &[f32], t: &[f32], target: f32) -> f32 {
        let d: f32 = w.iter().zip(t).map(|(w, t)| w * t).sum();
        let s: f32 = w.iter().zip(t).map(|(w, t)| w * t * t).sum();
        depth_moment(d, s, 1.0, target).0
    }

    #[test]
    fn the_depth_moment_is_zero_only_with_the_weight_at_the_target() {
        assert!(moment(&[1.0], &[0.4], 0.4).abs() < 1e-6);
        // The right expected depth from a partly transparent far end, or from haze spread
        // around the target, is not enough.
        let far = moment(&[0.4], &[1.0], 0.4);
        let haze = moment(&[0.5, 0.5], &[0.2, 0.6], 0.4);
        assert!(far > 0.05 && haze > 0.01, "far {far}, haze {haze}");
        // Nothing hit costs the target's square.
        assert!((moment(&[], &[], 0.4) - 0.16).abs() < 1e-6);
    }
}
