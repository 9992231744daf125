//! Image metrics: PSNR, SSIM (11×11 Gaussian window, σ = 1.5, the standard constants),
//! the share of fine detail a render keeps, and panoptic mean IoU accumulated over a split.

use std::collections::BTreeMap;

/// PSNR in dB of `a` against `b` (values in [0, 1]); `mask` selects pixels (one entry per
/// pixel, `channels` values each). Infinite when identical; `None` if no pixel selected.
pub fn psnr(a: &[f32], b: &[f32], channels: usize, mask: Option<&[bool]>) -> Option<f64> {
    let (se, n) = squared_error(a, b, channels, mask);
    (n > 0).then(|| mse_to_psnr(se / n as f64))
}

/// Sum of squared errors and number of values compared.
pub fn squared_error(a: &[f32], b: &[f32], channels: usize, mask: Option<&[bool]>) -> (f64, usize) {
    assert_eq!(a.len(), b.len());
    let mut se = 0.0f64;
    let mut n = 0usize;
    for (p, (x, y)) in a.chunks(channels).zip(b.chunks(channels)).enumerate() {
        if mask.is_some_and(|m| !m[p]) {
            continue;
        }
        for c in 0..channels {
            let d = (x[c] - y[c]) as f64;
            se += d * d;
        }
        n += channels;
    }
    (se, n)
}

/// `render` with each channel mapped through the gain and offset that fit it best to
/// `truth` (least squares over the image), clamped to [0, 1]: the render as a photograph
/// of other exposure and white balance would show it. What stays wrong after this is
/// structure, not exposure. A flat channel keeps only the offset (the truth's mean).
pub fn color_corrected(render: &[f32], truth: &[f32], channels: usize) -> Vec<f32> {
    assert_eq!(render.len(), truth.len());
    let mut out = render.to_vec();
    let n = (render.len() / channels.max(1)) as f64;
    for c in 0..channels {
        let (mut sr, mut st, mut srr, mut srt) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (x, y) in render.chunks(channels).zip(truth.chunks(channels)) {
            let (r, t) = (x[c] as f64, y[c] as f64);
            sr += r;
            st += t;
            srr += r * r;
            srt += r * t;
        }
        let (mr, mt) = (sr / n.max(1.0), st / n.max(1.0));
        let var = srr / n.max(1.0) - mr * mr;
        let cov = srt / n.max(1.0) - mr * mt;
        let gain = if var > 1e-12 { cov / var } else { 0.0 };
        let offset = mt - gain * mr;
        for x in out.chunks_mut(channels) {
            x[c] = ((gain * x[c] as f64 + offset) as f32).clamp(0.0, 1.0);
        }
    }
    out
}

/// The fine detail of an interleaved image: each channel minus its blur by the 5-tap
/// binomial kernel [1 4 6 4 1]/16 along rows and then columns (a Gaussian of σ = 1 pixel;
/// edges repeat their last pixel). What is left is structure one to three pixels across:
/// texture, dots, edges.
pub fn fine_detail(img: &[f32], width: usize, height: usize, channels: usize) -> Vec<f32> {
    assert_eq!(img.len(), width * height * channels);
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let at = |i: usize, d: isize, n: usize| (i as isize + d).clamp(0, n as isize - 1) as usize;
    let mut rows = vec![0.0f32; img.len()];
    for y in 0..height {
        for x in 0..width {
            for c in 0..channels {
                rows[(y * width + x) * channels + c] = (0..5)
                    .map(|k| K[k] * img[(y * width + at(x, k as isize - 2, width)) * channels + c])
                    .sum();
            }
        }
    }
    let mut out = vec![0.0f32; img.len()];
    for y in 0..height {
        for x in 0..width {
            for c in 0..channels {
                let i = (y * width + x) * channels + c;
                let blur: f32 = (0..5)
                    .map(|k| {
                        K[k] * rows[(at(y, k as isize - 2, height) * width + x) * channels + c]
                    })
                    .sum();
                out[i] = img[i] - blur;
            }
        }
    }
    out
}

/// How much of the photographs' fine detail ([`fine_detail`]) renders reproduce, pooled
/// over images: the least-squares gain of the render's detail on the truth's,
/// `Σ r·t / Σ t²`. 1 is as sharp as the photographs and in the same place; a render
/// blurred or smeared between views keeps its detail at a fraction of the truth's
/// amplitude; detail in the wrong place counts as none. Unlike PSNR it says whether what
/// is wrong is softness.
#[derive(Debug, Clone, Copy, Default)]
pub struct DetailAccumulator {
    cross: f64,
    truth: f64,
}

impl DetailAccumulator {
    /// Adds the pixels `mask` selects (all when `None`) of two detail images.
    pub fn add(&mut self, render: &[f32], truth: &[f32], channels: usize, mask: Option<&[bool]>) {
        assert_eq!(render.len(), truth.len());
        for (p, (r, t)) in render
            .chunks(channels)
            .zip(truth.chunks(channels))
            .enumerate()
        {
            if mask.is_some_and(|m| !m[p]) {
                continue;
            }
            for c in 0..channels {
                self.cross += r[c] as f64 * t[c] as f64;
                self.truth += t[c] as f64 * t[c] as f64;
            }
        }
    }

    /// The gain; `None` when the selected truth had no detail at all.
    pub fn gain(&self) -> Option<f64> {
        (self.truth > 1e-12).then(|| self.cross / self.truth)
    }
}

pub fn mse_to_psnr(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// Mean SSIM over all pixels and channels of two interleaved images (values in [0, 1]),
/// with an 11×11 Gaussian window (σ 1.5), K1 = 0.01, K2 = 0.03, data range 1, computed
/// over the valid region (no padding), as in the reference implementation.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize, channels: usize) -> f64 {
    const R: usize = 5;
    let g: Vec<f64> = {
        let w: Vec<f64> = (0..2 * R + 1)
            .map(|i| {
                let x = i as f64 - R as f64;
                (-(x * x) / (2.0 * 1.5 * 1.5)).exp()
            })
            .collect();
        let s: f64 = w.iter().sum();
        w.into_iter().map(|v| v / s).collect()
    };
    if width < 2 * R + 1 || height < 2 * R + 1 {
        return f64::NAN;
    }
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let (ow, oh) = (width - 2 * R, height - 2 * R);
    let mut total = 0.0;
    for c in 0..channels {
        let get = |img: &[f32], x: usize, y: usize| img[(y * width + x) * channels + c] as f64;
        // Separable filtering of x, y, x², y², xy: horizontal then vertical.
        let mut h = vec![[0.0f64; 5]; ow * height];
        for y in 0..height {
            for x in 0..ow {
                let mut s = [0.0; 5];
                for k in 0..2 * R + 1 {
                    let (p, q) = (get(a, x + k, y), get(b, x + k, y));
                    let w = g[k];
                    s[0] += w * p;
                    s[1] += w * q;
                    s[2] += w * p * p;
                    s[3] += w * q * q;
                    s[4] += w * p * q;
                }
                h[y * ow + x] = s;
            }
        }
        for y in 0..oh {
            for x in 0..ow {
                let mut s = [0.0; 5];
                for k in 0..2 * R + 1 {
                    let v = h[(y + k) * ow + x];
                    for i in 0..5 {
                        s[i] += g[k] * v[i];
                    }
                }
                let (mx, my) = (s[0], s[1]);
                let vx = s[2] - mx * mx;
                let vy = s[3] - my * my;
                let cxy = s[4] - mx * my;
                total += ((2.0 * mx * my + c1) * (2.0 * cxy + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
    }
    total / (ow * oh * channels) as f64
}

/// Intersection and union counts per class, accumulated over images.
#[derive(Debug, Clone, Default)]
pub struct IouAccumulator {
    pub classes: BTreeMap<u16, (u64, u64)>,
}

impl IouAccumulator {
    pub fn add(&mut self, predicted: &[u16], truth: &[u16]) {
        assert_eq!(predicted.len(), truth.len());
        let mut inter: BTreeMap<u16, u64> = BTreeMap::new();
        let mut count_p: BTreeMap<u16, u64> = BTreeMap::new();
        let mut count_t: BTreeMap<u16, u64> = BTreeMap::new();
        for (&p, &t) in predicted.iter().zip(truth) {
            *count_p.entry(p).or_default() += 1;
            *count_t.entry(t).or_default() += 1;
            if p == t {
                *inter.entry(p).or_default() += 1;
            }
        }
        let keys: std::collections::BTreeSet<u16> =
            count_p.keys().chain(count_t.keys()).copied().collect();
        for k in keys {
            let i = inter.get(&k).copied().unwrap_or(0);
            let u =
                count_p.get(&k).copied().unwrap_or(0) + count_t.get(&k).copied().unwrap_or(0) - i;
            let e = self.classes.entry(k).or_default();
            e.0 += i;
            e.1 += u;
        }
    }
    /// IoU per class that appears in the truth or the prediction.
    pub fn per_class(&self) -> BTreeMap<u16, f64> {
        self.classes
            .iter()
            .filter(|(_, (_, u))| *u > 0)
            .map(|(&k, &(i, u))| (k, i as f64 / u as f64))
            .collect()
    }
    pub fn mean(&self) -> Option<f64> {
        let pc = self.per_class();
        (!pc.is_empty()).then(|| pc.values().sum::<f64>() / pc.len() as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_known_error() {
        // Every value off by 0.1: MSE 0.01 → 20 dB.
        let a = vec![0.5f32; 30];
        let b = vec![0.6f32; 30];
        assert!((psnr(&a, &b, 3, None).unwrap() - 20.0).abs() < 1e-4);
        assert_eq!(psnr(&a, &a, 3, None).unwrap(), f64::INFINITY);
        let mask = vec![false; 10];
        assert!(psnr(&a, &b, 3, Some(&mask)).is_none());
    }

    #[test]
    fn ssim_identical_is_one_and_constant_shift_is_known() {
        let (w, h) = (24, 20);
        let a: Vec<f32> = (0..w * h)
            .map(|i| ((i * 37 % 101) as f32) / 100.0)
            .collect();
        assert!((ssim(&a, &a, w, h, 1) - 1.0).abs() < 1e-12);
        // Constant images x = 0.2, y = 0.4: variances 0, so SSIM = (2·0.08 + c1)/(0.2 + c1).
        let x = vec![0.2f32; w * h];
        let y = vec![0.4f32; w * h];
        let c1 = 1e-4;
        let expect = (2.0 * 0.2 * 0.4 + c1) / (0.04 + 0.16 + c1);
        assert!((ssim(&x, &y, w, h, 1) - expect).abs() < 1e-6);
        // Noise lowers it.
        let n: Vec<f32> = a
            .iter()
            .enumerate()
            .map(|(i, v)| v + if i % 2 == 0 { 0.1 } else { -0.1 })
            .collect();
        let s = ssim(&a, &n, w, h, 1);
        assert!(s < 0.95 && s > 0.0, "{s}");
    }

    #[test]
    fn color_correction_removes_gain_and_offset_only() {
        // Two channels; the render is the truth under another gain and offset per channel
        // (within [0, 1], so the clamp does not bite): corrected, it is the truth again.
        let truth: Vec<f32> = (0..200)
            .map(|i| 0.1 + 0.8 * ((i * 37 % 97) as f32) / 96.0)
            .collect();
        let render: Vec<f32> = truth
            .chunks(2)
            .flat_map(|p| [0.5 * p[0] + 0.2, 0.9 * p[1] - 0.05])
            .collect();
        let c = color_corrected(&render, &truth, 2);
        let (se, n) = squared_error(&c, &truth, 2, None);
        assert!(se / (n as f64) < 1e-10, "{}", se / n as f64);
        let (se0, _) = squared_error(&render, &truth, 2, None);
        assert!(se0 / (n as f64) > 1e-3);
        // Structure stays: a render with the pixels shuffled is corrected to no better than
        // its channel means (a gain of ~0), far from the truth.
        let shuffled: Vec<f32> = (0..100)
            .flat_map(|i| {
                let j = (i * 61) % 100;
                [render[2 * j], render[2 * j + 1]]
            })
            .collect();
        let c = color_corrected(&shuffled, &truth, 2);
        let (se, _) = squared_error(&c, &truth, 2, None);
        let var: f64 = truth
            .iter()
            .map(|&t| (t as f64 - truth.iter().map(|&v| v as f64).sum::<f64>() / 200.0).powi(2))
            .sum::<f64>();
        assert!(se > 0.5 * var, "{se} {var}");
        // A flat render takes the truth's mean; the truth itself is left as it is.
        let flat = color_corrected(&[0.3; 6], &[0.1, 0.2, 0.3, 0.5, 0.6, 0.7], 3);
        assert_eq!(flat, [0.3, 0.4, 0.5, 0.3, 0.4, 0.5]);
        let same = color_corrected(&truth, &truth, 2);
        let (se, _) = squared_error(&same, &truth, 2, None);
        assert!(se < 1e-10);
    }

    #[test]
    fn fine_detail_is_hand_computed_and_its_gain_measures_softness() {
        // A flat image has none; a single bright pixel in a 5×5 image keeps 1 − (6/16)².
        assert!(
            fine_detail(&[0.4; 12], 2, 2, 3)
                .iter()
                .all(|v| v.abs() < 1e-7)
        );
        let mut dot = vec![0.0f32; 25];
        dot[12] = 1.0;
        let d = fine_detail(&dot, 5, 5, 1);
        assert!((d[12] - (1.0 - 36.0 / 256.0)).abs() < 1e-6, "{}", d[12]);
        assert!((d[11] + 24.0 / 256.0).abs() < 1e-6 && (d[0] + 1.0 / 256.0).abs() < 1e-6);
        // Edges repeat: a pixel at the corner blurred with its copies.
        let mut corner = vec![0.0f32; 25];
        corner[0] = 1.0;
        let c = fine_detail(&corner, 5, 5, 1);
        assert!(
            (c[0] - (1.0 - (11.0f32 / 16.0).powi(2))).abs() < 1e-6,
            "{}",
            c[0]
        );

        let (w, h) = (32, 24);
        let truth: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i as u32).wrapping_mul(2_654_435_761) >> 16) as f32 / 65535.0)
            .collect();
        let gain = |render: &[f32]| {
            let mut acc = DetailAccumulator::default();
            acc.add(
                &fine_detail(render, w, h, 3),
                &fine_detail(&truth, w, h, 3),
                3,
                None,
            );
            acc.gain().unwrap()
        };
        assert!((gain(&truth) - 1.0).abs() < 1e-9);
        // Contrast halved and shifted: exactly half the detail (the blur is linear and
        // removes constants).
        let half: Vec<f32> = truth.iter().map(|v| 0.5 * v + 0.2).collect();
        assert!((gain(&half) - 0.5).abs() < 1e-6, "{}", gain(&half));
        // Blurred renders keep less; a flat one none; detail elsewhere none either.
        let blurred: Vec<f32> = truth
            .iter()
            .zip(fine_detail(&truth, w, h, 3))
            .map(|(t, d)| t - d)
            .collect();
        let g = gain(&blurred);
        assert!(g > -0.1 && g < 0.5, "{g}");
        assert!(gain(&vec![0.5; truth.len()]).abs() < 1e-9);
        let shifted: Vec<f32> = (0..truth.len())
            .map(|i| truth[(i + 3 * 5) % truth.len()])
            .collect();
        assert!(gain(&shifted).abs() < 0.2, "{}", gain(&shifted));
        // A mask selects pixels; nothing selected, or no detail in the truth, is no figure.
        let none = vec![false; w * h];
        let mut acc = DetailAccumulator::default();
        acc.add(&truth, &truth, 3, Some(&none));
        assert!(acc.gain().is_none());
    }

    #[test]
    fn miou_counts() {
        let mut acc = IouAccumulator::default();
        // truth: 0 0 1 1; predicted: 0 1 1 1 → class0 1/2, class1 2/3.
        acc.add(&[0, 1, 1, 1], &[0, 0, 1, 1]);
        let pc = acc.per_class();
        assert!((pc[&0] - 0.5).abs() < 1e-12 && (pc[&1] - 2.0 / 3.0).abs() < 1e-12);
        assert!((acc.mean().unwrap() - (0.5 + 2.0 / 3.0) / 2.0).abs() < 1e-12);
    }
}
