//! The colour-guided filter (He, Sun and Tang, 2010): a soft mask made to follow the
//! photograph's edges. In each window the output is an affine function of the guide's
//! colour fitted to the mask by least squares, so the mask's boundary moves to where
//! the colour changes. Box sums make it O(pixels) whatever the radius; cheap on 2 cores.

use rayon::prelude::*;

/// Mean over the (2r+1)² window around each pixel of `src` (w × h, one channel),
/// clamped at the borders (each mean over the pixels inside the image).
pub fn box_mean(src: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Column means by a running window (stored column-major), then row means of those.
    let mut cols = vec![0f32; w * h];
    cols.par_chunks_mut(h.max(1))
        .enumerate()
        .for_each(|(x, col)| running_mean(|y| src[y * w + x], r, col));
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| running_mean(|x| cols[x * h + y], r, row));
    out
}

/// `out[i]` = the mean of `at(j)` over `|i − j| ≤ r` within `0..out.len()`.
fn running_mean(at: impl Fn(usize) -> f32, r: usize, out: &mut [f32]) {
    let n = out.len();
    let mut acc = 0f64;
    let (mut lo, mut hi) = (0usize, 0usize);
    for (i, o) in out.iter_mut().enumerate() {
        let (a, b) = (i.saturating_sub(r), (i + r + 1).min(n));
        while hi < b {
            acc += at(hi) as f64;
            hi += 1;
        }
        while lo < a {
            acc -= at(lo) as f64;
            lo += 1;
        }
        *o = (acc / (b - a) as f64) as f32;
    }
}

/// `p` (w × h, values in [0, 1]) filtered with the colour guide `rgb` (interleaved, w × h,
/// in [0, 1]): window radius `r` pixels, regulariser `eps` (larger: smoother, less
/// edge-following).
pub fn guided_filter(rgb: &[f32], p: &[f32], w: usize, h: usize, r: usize, eps: f32) -> Vec<f32> {
    let n = w * h;
    let chan = |c: usize| -> Vec<f32> { (0..n).map(|i| rgb[3 * i + c]).collect() };
    let guide = [chan(0), chan(1), chan(2)];
    let mean = |v: &[f32]| box_mean(v, w, h, r);
    let prod = |a: &[f32], b: &[f32]| -> Vec<f32> { a.iter().zip(b).map(|(x, y)| x * y).collect() };
    let mi = [mean(&guide[0]), mean(&guide[1]), mean(&guide[2])];
    let mp = mean(p);
    let mip = [
        mean(&prod(&guide[0], p)),
        mean(&prod(&guide[1], p)),
        mean(&prod(&guide[2], p)),
    ];
    // The guide's covariance per window (rr, rg, rb, gg, gb, bb).
    let pairs = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    let cov: Vec<Vec<f32>> = pairs
        .iter()
        .map(|&(a, b)| {
            let m = mean(&prod(&guide[a], &guide[b]));
            m.iter()
                .enumerate()
                .map(|(i, v)| v - mi[a][i] * mi[b][i])
                .collect()
        })
        .collect();
    // Per window: a = (Σ + eps·I)⁻¹ cov(I, p), b = mean(p) − a·mean(I).
    let mut coef = vec![[0f32; 4]; n];
    coef.par_iter_mut().enumerate().for_each(|(i, out)| {
        let s = [
            [cov[0][i] + eps, cov[1][i], cov[2][i]],
            [cov[1][i], cov[3][i] + eps, cov[4][i]],
            [cov[2][i], cov[4][i], cov[5][i] + eps],
        ];
        let cp = [
            mip[0][i] - mi[0][i] * mp[i],
            mip[1][i] - mi[1][i] * mp[i],
            mip[2][i] - mi[2][i] * mp[i],
        ];
        let a = solve3(s, cp);
        let b = mp[i] - a[0] * mi[0][i] - a[1] * mi[1][i] - a[2] * mi[2][i];
        *out = [a[0], a[1], a[2], b];
    });
    let mc: Vec<Vec<f32>> = (0..4)
        .map(|k| mean(&coef.iter().map(|c| c[k]).collect::<Vec<_>>()))
        .collect();
    (0..n)
        .map(|i| {
            mc[0][i] * guide[0][i] + mc[1][i] * guide[1][i] + mc[2][i] * guide[2][i] + mc[3][i]
        })
        .collect()
}

/// A rectangle of an image (`x0..x0 + w`, `y0..y0 + h` of an image `stride` wide): what
/// a mask's filtering needs to see.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roi {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
    stride: usize,
}

impl Roi {
    /// The pixels of `p` (w × h) above 0, grown by `margin` on every side and clipped to
    /// the image; `None` when every pixel is 0.
    pub fn around_nonzero(p: &[f32], w: usize, h: usize, margin: usize) -> Option<Roi> {
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for (y, row) in p.chunks_exact(w.max(1)).enumerate().take(h) {
            let Some(first) = row.iter().position(|&v| v > 0.0) else {
                continue;
            };
            let last = row.iter().rposition(|&v| v > 0.0).unwrap_or(first);
            (x0, x1) = (x0.min(first), x1.max(last));
            (y0, y1) = (y0.min(y), y);
        }
        (x0 != usize::MAX).then(|| {
            let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
            let (x1, y1) = ((x1 + margin).min(w - 1), (y1 + margin).min(h - 1));
            Roi {
                x0,
                y0,
                w: x1 + 1 - x0,
                h: y1 + 1 - y0,
                stride: w,
            }
        })
    }

    /// The rectangle's pixels of an image with `channels` values per pixel (interleaved).
    pub fn crop(&self, img: &[f32], channels: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.w * self.h * channels);
        for y in self.y0..self.y0 + self.h {
            let at = (y * self.stride + self.x0) * channels;
            out.extend_from_slice(&img[at..at + self.w * channels]);
        }
        out
    }

    /// The whole image's index of the rectangle's pixel `k` (row-major in the rectangle).
    pub fn index(&self, k: usize) -> usize {
        (self.y0 + k / self.w) * self.stride + self.x0 + k % self.w
    }
}

/// `s⁻¹ v` for a symmetric positive definite 3×3 `s` (Cramer's rule; `s` is regularised,
/// so its determinant is positive).
fn solve3(s: [[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    let det = |m: [[f32; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(s);
    if d.abs() < 1e-20 {
        return [0.0; 3];
    }
    let mut out = [0f32; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut m = s;
        for r in 0..3 {
            m[r][k] = v[r];
        }
        *o = det(m) / d;
    }
    out
}

/// Bilinear resampling of a one-channel `src` (sw × sh) to dw × dh, pixel centres aligned.
pub fn resize(src: &[f32], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<f32> {
    if (sw, sh) == (dw, dh) {
        return src.to_vec();
    }
    let (fx, fy) = (sw as f32 / dw as f32, sh as f32 / dh as f32);
    let mut out = vec![0f32; dw * dh];
    out.par_chunks_mut(dw.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let sy = ((y as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
            let (y0, ty) = (sy.floor() as usize, sy.fract());
            let y1 = (y0 + 1).min(sh - 1);
            for (x, o) in row.iter_mut().enumerate() {
                let sx = ((x as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
                let (x0, tx) = (sx.floor() as usize, sx.fract());
                let x1 = (x0 + 1).min(sw - 1);
                let top = src[y0 * sw + x0] * (1.0 - tx) + src[y0 * sw + x1] * tx;
                let bot = src[y1 * sw + x0] * (1.0 - tx) + src[y1 * sw + x1] * tx;
                *o = top * (1.0 - ty) + bot * ty;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mean_matches_a_direct_sum() {
        let (w, h, r) = (13, 9, 2);
        let src: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32).collect();
        let got = box_mean(&src, w, h, r);
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut c) = (0.0, 0.0);
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        s += src[yy * w + xx];
                        c += 1.0;
                    }
                }
                assert!((got[y * w + x] - s / c).abs() < 1e-4, "({x}, {y})");
            }
        }
    }

    #[test]
    fn a_blurred_shifted_mask_snaps_to_the_colour_edge() {
        // The guide: red left of x = 20, green right of it (same brightness). The mask
        // (as upsampled from a coarse render) ramps from 1 at x = 16 to 0 at x = 26, its
        // ½ at 21. Filtered, it steps down at the colour edge, across which it was smooth.
        let (w, h) = (40, 12);
        let mut rgb = vec![0f32; 3 * w * h];
        let mut p = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                rgb[3 * i + if x < 20 { 0 } else { 1 }] = 0.6;
                p[i] = (1.0 - (x as f32 - 16.0) / 10.0).clamp(0.0, 1.0);
            }
        }
        let q = guided_filter(&rgb, &p, w, h, 4, 1e-3);
        for y in 0..h {
            let row = &q[y * w..(y + 1) * w];
            assert!(row[19] - row[20] > 0.3, "no step at the edge: {row:?}");
            for (x, &v) in row.iter().enumerate() {
                assert_eq!(v > 0.5, x < 20, "({x}, {y}): {v}");
                if !(12..=29).contains(&x) {
                    assert!(!(0.1..=0.9).contains(&v), "({x}, {y}): {v}");
                }
            }
        }
    }

    #[test]
    fn filtering_a_crop_around_the_mask_matches_the_whole_image() {
        // A textured guide and a blob of mask in the middle of a larger image: filtered
        // in the rectangle 3r + 1 around the blob, as on the whole image (the rest 0).
        let (w, h, r) = (90, 70, 5);
        let mut rgb = vec![0f32; 3 * w * h];
        let mut p = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                for c in 0..3 {
                    rgb[3 * i + c] = (((x * 7 + y * 13 + c * 5) % 17) as f32) / 17.0;
                }
                let d = ((x as f32 - 40.0).powi(2) + (y as f32 - 30.0).powi(2)).sqrt();
                p[i] = (1.0 - (d - 6.0) / 4.0).clamp(0.0, 1.0);
            }
        }
        let full = guided_filter(&rgb, &p, w, h, r, 1e-3);
        let roi = Roi::around_nonzero(&p, w, h, 3 * r + 1).unwrap();
        assert!(
            roi.w < w && roi.h < h && roi.x0 > 0 && roi.y0 > 0,
            "{roi:?}"
        );
        let q = guided_filter(&roi.crop(&rgb, 3), &roi.crop(&p, 1), roi.w, roi.h, r, 1e-3);
        let mut inside = vec![false; w * h];
        for (k, v) in q.iter().enumerate() {
            let i = roi.index(k);
            inside[i] = true;
            assert!(
                (v - full[i]).abs() < 1e-5,
                "pixel {i}: {v} against {}",
                full[i]
            );
        }
        for (i, v) in full.iter().enumerate() {
            if !inside[i] {
                assert!(v.abs() < 1e-5, "pixel {i} outside the crop: {v}");
            }
        }
        assert!(full.iter().any(|&v| v > 0.5));
        assert_eq!(Roi::around_nonzero(&vec![0.0; w * h], w, h, 3), None);
        // A margin past the borders is clipped to the image.
        let all = Roi::around_nonzero(&p, w, h, 1000).unwrap();
        assert_eq!((all.x0, all.y0, all.w, all.h), (0, 0, w, h));
    }

    #[test]
    fn resize_keeps_constants_and_ramps() {
        let src: Vec<f32> = (0..4 * 3).map(|i| (i % 4) as f32).collect();
        let up = resize(&src, 4, 3, 8, 6);
        // Pixel centre 2.5 of 8 maps to 0.75 of 4 (between the values 0 and 1).
        assert!((up[2] - 0.75).abs() < 1e-6, "{}", up[2]);
        assert!(up.iter().all(|v| (0.0..=3.0).contains(v)));
        assert_eq!(resize(&src, 4, 3, 4, 3), src);
    }
}
