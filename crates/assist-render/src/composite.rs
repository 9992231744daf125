//! Alpha compositing of depth-sorted samples along one ray, forward and backward.
//!
//! `α_i = 1 − exp(−σ_i δ_i)`, `T_i = exp(−Σ_{k<i} σ_k δ_k)`, `w_i = T_i α_i`;
//! colour `C = Σ w_i c_i + (1 − O) · background`, depth `D = Σ w_i t_i`, opacity
//! `O = Σ w_i` (paper eq. 1–4), and the second moment `Σ w_i t_i²`. Each sample carries its own interval `δ_i`.

/// One sample of a ray: density, colour, position along the ray and interval length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaySample {
    pub sigma: f32,
    pub rgb: [f32; 3],
    pub t: f32,
    pub dt: f32,
}

/// What compositing produces for one ray.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Composite {
    pub rgb: [f32; 3],
    pub depth: f32,
    pub opacity: f32,
    /// Second moment of the weights along the ray, `Σ w_i t_i²` (with `depth` and
    /// `opacity`, the spread of the weight about a depth: `Σ w_i (t_i − d)²`).
    pub depth_sq: f32,
    /// A node alone in a batch: the opacity of its samples at or past the ray's
    /// [`Traced::beyond`](crate::Traced::beyond) depth, `Σ_{t_i ≥ b} w_i` (how opaque it is
    /// behind that point, counting what lies in front of it). 0 without one, and in the
    /// merged composite.
    pub beyond: f32,
    /// A node alone in a batch: the opacity of its samples in front of the ray's
    /// [`Traced::front`](crate::Traced::front) depth, `Σ_{t_i < f} w_i` (what it puts in
    /// front of the surface a depth map sees). 0 without one, and in the merged composite.
    pub front: f32,
}

/// Composites `samples` (sorted by `t`) over `background`; writes each sample's weight
/// `w_i` into `weights` when given.
pub fn composite(
    samples: &[RaySample],
    background: [f32; 3],
    mut weights: Option<&mut [f32]>,
) -> Composite {
    let mut out = Composite::default();
    // T_i as a running product of each sample's exp(−σδ), one exponential per sample.
    let mut trans = 1.0f32;
    for (i, s) in samples.iter().enumerate() {
        let pass = (-(s.sigma * s.dt)).exp();
        let w = trans * (1.0 - pass);
        for c in 0..3 {
            out.rgb[c] += w * s.rgb[c];
        }
        out.depth += w * s.t;
        out.depth_sq += w * s.t * s.t;
        out.opacity += w;
        if let Some(ws) = weights.as_deref_mut() {
            ws[i] = w;
        }
        trans *= pass;
    }
    for c in 0..3 {
        out.rgb[c] += (1.0 - out.opacity) * background[c];
    }
    out
}

/// Backward of [`composite`]: given dL/dC, dL/dD and dL/dO, writes dL/dσ_i and dL/dc_i.
pub fn composite_backward(
    samples: &[RaySample],
    background: [f32; 3],
    d_rgb: [f32; 3],
    d_depth: f32,
    d_opacity: f32,
    d_sigma: &mut [f32],
    d_color: &mut [[f32; 3]],
) {
    let n = samples.len();
    // g_i = dL/dw_i (the background term makes every w_i also reduce the background).
    let g_bg = d_opacity
        - (d_rgb[0] * background[0] + d_rgb[1] * background[1] + d_rgb[2] * background[2]);
    // Forward pass again for T_i and w_i (cheap; avoids storing).
    let mut w = vec![0f32; n];
    let mut t_next = vec![0f32; n];
    let mut trans = 1.0f32;
    for (i, s) in samples.iter().enumerate() {
        let pass = (-(s.sigma * s.dt)).exp();
        w[i] = trans * (1.0 - pass);
        trans *= pass;
        t_next[i] = trans;
    }
    // dL/dσ_i = δ_i (T_{i+1} g_i − Σ_{j>i} w_j g_j), suffix sums from the back.
    let mut suffix = 0.0f32;
    for i in (0..n).rev() {
        let s = &samples[i];
        let g =
            d_rgb[0] * s.rgb[0] + d_rgb[1] * s.rgb[1] + d_rgb[2] * s.rgb[2] + d_depth * s.t + g_bg;
        d_sigma[i] = s.dt * (t_next[i] * g - suffix);
        suffix += w[i] * g;
        for c in 0..3 {
            d_color[i][c] = w[i] * d_rgb[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_two_samples() {
        // σδ = ln 2 for both: α = 1/2 each; T = 1, 1/2; w = 1/2, 1/4.
        let ln2 = std::f32::consts::LN_2;
        let s = [
            RaySample {
                sigma: ln2,
                rgb: [1.0, 0.0, 0.0],
                t: 1.0,
                dt: 1.0,
            },
            RaySample {
                sigma: 2.0 * ln2,
                rgb: [0.0, 1.0, 0.0],
                t: 2.0,
                dt: 0.5,
            },
        ];
        let mut w = [0.0; 2];
        let c = composite(&s, [0.0, 0.0, 1.0], Some(&mut w));
        assert!((w[0] - 0.5).abs() < 1e-6 && (w[1] - 0.25).abs() < 1e-6);
        assert!((c.opacity - 0.75).abs() < 1e-6);
        assert!((c.depth - (0.5 + 0.5)).abs() < 1e-6);
        assert!(
            (c.rgb[0] - 0.5).abs() < 1e-6
                && (c.rgb[1] - 0.25).abs() < 1e-6
                && (c.rgb[2] - 0.25).abs() < 1e-6
        );
    }

    /// Backward against central differences for every σ_i and colour channel, collecting
    /// all failures.
    #[test]
    fn backward_matches_central_differences() {
        let mut rng = assist_core::Rng::new(9);
        let mut failures = Vec::new();
        for trial in 0..20 {
            let n = 1 + trial % 9;
            let mut t = 0.5f32;
            let samples: Vec<RaySample> = (0..n)
                .map(|_| {
                    let dt = 0.05 + rng.f32() * 0.3;
                    t += dt;
                    RaySample {
                        sigma: rng.f32() * 4.0,
                        rgb: [rng.f32(), rng.f32(), rng.f32()],
                        t,
                        dt,
                    }
                })
                .collect();
            let bg = [rng.f32(), rng.f32(), rng.f32()];
            let (dc, dd, dopa) = (
                [rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5],
                rng.f32() - 0.5,
                rng.f32() - 0.5,
            );
            let loss = |s: &[RaySample]| {
                let c = composite(s, bg, None);
                (dc[0] * c.rgb[0]
                    + dc[1] * c.rgb[1]
                    + dc[2] * c.rgb[2]
                    + dd * c.depth
                    + dopa * c.opacity) as f64
            };
            let mut ds = vec![0.0; n];
            let mut dcol = vec![[0.0; 3]; n];
            composite_backward(&samples, bg, dc, dd, dopa, &mut ds, &mut dcol);
            let eps = 1e-3;
            for i in 0..n {
                let mut p = samples.clone();
                p[i].sigma += eps;
                let mut m = samples.clone();
                m[i].sigma -= eps;
                let num = (loss(&p) - loss(&m)) / (2.0 * eps as f64);
                if (num - ds[i] as f64).abs() > 1e-3 * num.abs().max(1.0) {
                    failures.push(format!(
                        "trial {trial} dσ[{i}]: analytic {} numeric {num}",
                        ds[i]
                    ));
                }
                for c in 0..3 {
                    let mut p = samples.clone();
                    p[i].rgb[c] += eps;
                    let mut m = samples.clone();
                    m[i].rgb[c] -= eps;
                    let num = (loss(&p) - loss(&m)) / (2.0 * eps as f64);
                    if (num - dcol[i][c] as f64).abs() > 1e-3 * num.abs().max(1.0) {
                        failures.push(format!(
                            "trial {trial} drgb[{i}][{c}]: analytic {} numeric {num}",
                            dcol[i][c]
                        ));
                    }
                }
            }
        }
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }
}
