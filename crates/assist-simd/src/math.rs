//! Elementwise functions written to vectorise: plain branch-free arithmetic that the
//! compiler turns into SIMD inside loops compiled for a dispatched level (where the
//! standard library's `exp` stays a scalar call per element).

/// `e^x` to within 2 ulp over the normal range (Cephes' single-precision polynomial after
/// reduction by ln 2). Inputs are clamped to [−87, 88] (results from 1.6e−38 to 1.7e38,
/// never 0 or infinity); NaN stays NaN.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 in two parts, so that n·C1 is exact.
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    let xc = x.clamp(-87.0, 88.0);
    let n = (xc * LOG2E + 0.5).floor();
    let r = xc - n * C1 - n * C2;
    let p = 1.987_569_1e-4f32;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5;
    let p = p * r * r + r + 1.0;
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    let y = p * scale;
    if x.is_nan() { x } else { y }
}

/// The logistic function `1 / (1 + e^−x)` through [`exp`].
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_std_within_two_ulp() {
        let mut worst = 0f64;
        let mut at = 0f32;
        let mut x = -87.0f32;
        while x <= 88.0 {
            let (got, want) = (exp(x) as f64, (x as f64).exp());
            let rel = ((got - want) / want).abs();
            if rel > worst {
                worst = rel;
                at = x;
            }
            x += 0.000_37;
        }
        // f32 has 2^-23 ≈ 1.19e-7 relative spacing.
        assert!(worst < 2.5e-7, "worst relative error {worst:e} at x = {at}");
        assert_eq!(exp(0.0), 1.0);
        assert!(exp(f32::NAN).is_nan());
        assert!(exp(-1000.0) > 0.0 && exp(1000.0).is_finite());
        assert!(exp(f32::NEG_INFINITY) > 0.0 && exp(f32::INFINITY).is_finite());
    }

    #[test]
    fn sigmoid_values() {
        assert_eq!(sigmoid(0.0), 0.5);
        for &x in &[-30.0f32, -3.0, -0.1, 0.7, 5.0, 40.0] {
            let want = 1.0 / (1.0 + (-(x as f64)).exp());
            assert!((sigmoid(x) as f64 - want).abs() < 1e-7, "sigmoid({x})");
        }
        assert!(sigmoid(-200.0) >= 0.0 && sigmoid(200.0) <= 1.0);
    }

    /// Inside a loop compiled for the dispatched level the function gives the same bits as
    /// called alone (no fast-math reassociation).
    #[test]
    fn vectorised_loop_equals_scalar_calls() {
        let xs: Vec<f32> = (0..1000).map(|i| (i as f32 - 500.0) * 0.173).collect();
        let mut v = xs.clone();
        crate::dispatch::simd(|| v.iter_mut().for_each(|x| *x = exp(*x)));
        for (x, y) in xs.iter().zip(&v) {
            assert_eq!(exp(*x).to_bits(), y.to_bits(), "x = {x}");
        }
    }
}
