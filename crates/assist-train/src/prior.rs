//! The built-in background prior: fill the pixels under (dilated) object masks from the
//! surrounding background, for colour and for depth. The paper uses LaMa and Omnidata,
//! which cannot be downloaded here; users who run them can reference their outputs per
//! frame instead (`inpaint_path`, `inpaint_depth_path`).
//!
//! Two classical fills are offered and compared on the desk benchmark's background ground
//! truth (`assist bench prior`, figures in BENCHMARKS.md): a multi-scale push–pull fill
//! (smooth, fast) and push–pull followed by exemplar patch synthesis (texture from the
//! unmasked pixels; copied texture that lands in the wrong place costs more than a smooth
//! guess).

/// Dilates a boolean mask by `r` pixels (square structuring element).
pub fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut tmp = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if mask[y * w + x] {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    tmp[y * w + xx] = true;
                }
            }
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if tmp[y * w + x] {
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    out[yy * w + x] = true;
                }
            }
        }
    }
    out
}

/// Push–pull fill: `hole` pixels of `img` (`c` channels) are replaced by a smooth
/// interpolation of the known pixels, built from a pyramid of known-weighted averages.
pub fn push_pull(img: &mut [f32], w: usize, h: usize, c: usize, hole: &[bool]) {
    let weights: Vec<f32> = hole.iter().map(|&m| if m { 0.0 } else { 1.0 }).collect();
    let filled = pull(img, &weights, w, h, c);
    for p in 0..w * h {
        if hole[p] {
            img[p * c..(p + 1) * c].copy_from_slice(&filled[p * c..(p + 1) * c]);
        }
    }
}

/// Recursive pull (2×2 weighted averages down) and push (bilinear up where unknown).
fn pull(img: &[f32], wt: &[f32], w: usize, h: usize, c: usize) -> Vec<f32> {
    let mut out = img.to_vec();
    if w <= 1 && h <= 1 {
        return out;
    }
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut small = vec![0.0f32; w2 * h2 * c];
    let mut swt = vec![0.0f32; w2 * h2];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let q = (y / 2) * w2 + x / 2;
            swt[q] += wt[p];
            for k in 0..c {
                small[q * c + k] += wt[p] * img[p * c + k];
            }
        }
    }
    for q in 0..w2 * h2 {
        if swt[q] > 0.0 {
            for k in 0..c {
                small[q * c + k] /= swt[q];
            }
        }
    }
    let swt_n: Vec<f32> = swt.iter().map(|&v| v.min(1.0)).collect();
    let coarse = pull(&small, &swt_n, w2, h2, c);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if wt[p] >= 1.0 {
                continue;
            }
            // Bilinear sample of the coarse level at this pixel's centre.
            let fx = ((x as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (w2 - 1) as f32);
            let fy = ((y as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (h2 - 1) as f32);
            let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w2 - 1), (y0 + 1).min(h2 - 1));
            let (ax, ay) = (fx - x0 as f32, fy - y0 as f32);
            let a = wt[p];
            for k in 0..c {
                let v = coarse[(y0 * w2 + x0) * c + k] * (1.0 - ax) * (1.0 - ay)
                    + coarse[(y0 * w2 + x1) * c + k] * ax * (1.0 - ay)
                    + coarse[(y1 * w2 + x0) * c + k] * (1.0 - ax) * ay
                    + coarse[(y1 * w2 + x1) * c + k] * ax * ay;
                out[p * c + k] = a * img[p * c + k] + (1.0 - a) * v;
            }
        }
    }
    out
}

/// Exemplar fill after push–pull: hole pixels are synthesised onion-peel order (from the
/// border inwards), each copying the centre of the best-matching fully known `patch`×`patch`
/// patch, compared on the already known/filled pixels of its neighbourhood. Candidate
/// patches are searched within `search` pixels.
pub fn exemplar_fill(
    img: &mut [f32],
    w: usize,
    h: usize,
    c: usize,
    hole: &[bool],
    patch: usize,
    search: usize,
) {
    push_pull(img, w, h, c, hole);
    let r = (patch / 2) as isize;
    let mut known: Vec<bool> = hole.iter().map(|&m| !m).collect();
    // Candidate centres: patches entirely outside the hole.
    let src_ok: Vec<bool> = {
        let d = dilate(hole, w, h, patch / 2);
        (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                !d[p]
                    && x >= r as usize
                    && y >= r as usize
                    && x + (r as usize) < w
                    && y + (r as usize) < h
            })
            .collect()
    };
    let mut remaining: Vec<usize> = (0..w * h).filter(|&p| hole[p]).collect();
    while !remaining.is_empty() {
        // Front: hole pixels with a known 4-neighbour.
        let front: Vec<usize> = remaining
            .iter()
            .copied()
            .filter(|&p| {
                let (x, y) = (p % w, p / w);
                (x > 0 && known[p - 1])
                    || (x + 1 < w && known[p + 1])
                    || (y > 0 && known[p - w])
                    || (y + 1 < h && known[p + w])
            })
            .collect();
        let front = if front.is_empty() {
            remaining.clone()
        } else {
            front
        };
        let updates: Vec<(usize, Vec<f32>)> = {
            use rayon::prelude::*;
            front
                .par_iter()
                .map(|&p| {
                    let (px, py) = ((p % w) as isize, (p / w) as isize);
                    let mut best = (f32::INFINITY, p);
                    let s = search as isize;
                    let mut sy = (py - s).max(r);
                    while sy < (py + s).min(h as isize - r) {
                        let mut sx = (px - s).max(r);
                        while sx < (px + s).min(w as isize - r) {
                            let q = sy as usize * w + sx as usize;
                            if src_ok[q] {
                                let mut d = 0.0f32;
                                let mut n = 0;
                                for dy in -r..=r {
                                    for dx in -r..=r {
                                        let (tx, ty) = (px + dx, py + dy);
                                        if tx < 0 || ty < 0 || tx >= w as isize || ty >= h as isize
                                        {
                                            continue;
                                        }
                                        let tp = ty as usize * w + tx as usize;
                                        if !known[tp] {
                                            continue;
                                        }
                                        let sp = (sy + dy) as usize * w + (sx + dx) as usize;
                                        for k in 0..c {
                                            let e = img[tp * c + k] - img[sp * c + k];
                                            d += e * e;
                                        }
                                        n += 1;
                                    }
                                }
                                if n > 0 {
                                    let d = d / n as f32;
                                    if d < best.0 {
                                        best = (d, q);
                                    }
                                }
                            }
                            sx += 1;
                        }
                        sy += 1;
                    }
                    (p, img[best.1 * c..(best.1 + 1) * c].to_vec())
                })
                .collect()
        };
        for (p, v) in updates {
            img[p * c..(p + 1) * c].copy_from_slice(&v);
            known[p] = true;
        }
        remaining.retain(|&p| !known[p]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_pull_reproduces_a_linear_ramp() {
        let (w, h) = (64, 48);
        let mut img: Vec<f32> = (0..w * h).map(|p| (p % w) as f32 / w as f32).collect();
        let truth = img.clone();
        let hole: Vec<bool> = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                (20..30).contains(&x) && (10..30).contains(&y)
            })
            .collect();
        for p in 0..w * h {
            if hole[p] {
                img[p] = 5.0;
            }
        }
        push_pull(&mut img, w, h, 1, &hole);
        let err = img
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err < 0.08, "max error {err}");
        // Known pixels are untouched.
        for p in 0..w * h {
            if !hole[p] {
                assert_eq!(img[p], truth[p]);
            }
        }
    }

    #[test]
    fn exemplar_fill_continues_stripes() {
        // Vertical stripes of period 4; a hole in the middle is filled with stripes.
        let (w, h) = (48, 40);
        let truth: Vec<f32> = (0..w * h)
            .map(|p| if (p % w) % 4 < 2 { 1.0 } else { 0.0 })
            .collect();
        let hole: Vec<bool> = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                (18..28).contains(&x) && (14..26).contains(&y)
            })
            .collect();
        let mut a = truth.clone();
        let mut b = truth.clone();
        push_pull(&mut a, w, h, 1, &hole);
        exemplar_fill(&mut b, w, h, 1, &hole, 7, 24);
        let err = |img: &[f32]| -> f32 {
            (0..w * h)
                .filter(|&p| hole[p])
                .map(|p| (img[p] - truth[p]).powi(2))
                .sum::<f32>()
        };
        assert!(
            err(&b) < 0.25 * err(&a),
            "exemplar {} push-pull {}",
            err(&b),
            err(&a)
        );
    }
}
