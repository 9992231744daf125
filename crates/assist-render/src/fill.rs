//! Filling what no training view saw. Under a last-sample backdrop (a captured room, whose
//! background is unknown) a ray that meets no sample of any node has nothing to show: the
//! part of the room it looks at (the top of a wall, a floor beyond the captured area) was
//! in no photograph, so free-space carving emptied it and the field holds nothing there.
//! Such pixels used to render black, with depth 0. They are now filled with the nearest
//! seen pixels' colour and depth, a pull–push over an image pyramid: each coarser level
//! averages the seen pixels below it, and each unseen pixel takes the bilinear value of the
//! level above. A 3D fill would need a surface to continue, and the field has none there;
//! the image-space continuation is what a viewer expects to see (the wall goes on), costs a
//! few operations per pixel, and is the same in a full render and a drag update.

/// Fills the `target` pixels of `values` (`channels` interleaved values per pixel, a
/// `width`×`height` image) from the `source` pixels, by pull–push. Pixels that are neither
/// keep their values; with no source pixel at all, nothing changes.
pub fn pull_push(
    width: usize,
    height: usize,
    channels: usize,
    values: &mut [f32],
    source: &[bool],
    target: &[bool],
) {
    let n = width * height;
    assert!(values.len() == n * channels && source.len() == n && target.len() == n);
    if !target.iter().any(|&t| t) || !source.iter().any(|&s| s) {
        return;
    }
    // Level 0: the image with weight 1 at the sources; each coarser level halves the
    // size, a pixel's value the weighted mean of its (up to four) children and its weight
    // their summed weight, at most 1. Stops once a level has no pixel left unweighted.
    let mut levels = vec![Level {
        width,
        height,
        values: values.to_vec(),
        weight: source.iter().map(|&s| if s { 1.0 } else { 0.0 }).collect(),
    }];
    while levels
        .last()
        .is_some_and(|l| l.weight.iter().any(|&w| w < 1.0))
        && levels.last().is_some_and(|l| l.width > 1 || l.height > 1)
    {
        let next = levels.last().expect("one level at least").pull(channels);
        levels.push(next);
    }
    // Push: from the coarsest level down, each pixel that is not fully weighted blends in
    // the bilinear value of the level above (already complete).
    for l in (0..levels.len() - 1).rev() {
        let (fine, coarse) = levels.split_at_mut(l + 1);
        fine[l].push(&coarse[0], channels);
    }
    let filled = &levels[0].values;
    for q in (0..n).filter(|&q| target[q] && !source[q]) {
        values[q * channels..(q + 1) * channels]
            .copy_from_slice(&filled[q * channels..(q + 1) * channels]);
    }
}

/// One level of the pyramid: values and their weights in [0, 1].
struct Level {
    width: usize,
    height: usize,
    values: Vec<f32>,
    weight: Vec<f32>,
}

impl Level {
    /// The next coarser level: each pixel the weighted mean of its children.
    fn pull(&self, ch: usize) -> Level {
        let (w, h) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut values = vec![0.0; w * h * ch];
        let mut weight = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let mut sum = 0.0f32;
                for (cx, cy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (fx, fy) = (2 * x + cx, 2 * y + cy);
                    if fx >= self.width || fy >= self.height {
                        continue;
                    }
                    let q = fy * self.width + fx;
                    let wq = self.weight[q];
                    if wq > 0.0 {
                        sum += wq;
                        for c in 0..ch {
                            values[p * ch + c] += wq * self.values[q * ch + c];
                        }
                    }
                }
                if sum > 0.0 {
                    for c in 0..ch {
                        values[p * ch + c] /= sum;
                    }
                }
                weight[p] = sum.min(1.0);
            }
        }
        Level {
            width: w,
            height: h,
            values,
            weight,
        }
    }

    /// Blends the bilinear value of `coarse` (complete) into every pixel whose weight is
    /// below 1, in proportion to what is missing; the level is complete afterwards.
    fn push(&mut self, coarse: &Level, ch: usize) {
        let clamp = |v: f32, n: usize| v.clamp(0.0, (n - 1) as f32);
        for y in 0..self.height {
            for x in 0..self.width {
                let p = y * self.width + x;
                let wp = self.weight[p];
                if wp >= 1.0 {
                    continue;
                }
                // The pixel's centre in the coarse level's pixel coordinates.
                let u = clamp((x as f32 + 0.5) / 2.0 - 0.5, coarse.width);
                let v = clamp((y as f32 + 0.5) / 2.0 - 0.5, coarse.height);
                let (x0, y0) = (u.floor() as usize, v.floor() as usize);
                let (x1, y1) = (
                    (x0 + 1).min(coarse.width - 1),
                    (y0 + 1).min(coarse.height - 1),
                );
                let (fx, fy) = (u - x0 as f32, v - y0 as f32);
                for c in 0..ch {
                    let at =
                        |xx: usize, yy: usize| coarse.values[(yy * coarse.width + xx) * ch + c];
                    let up = (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy)
                        + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy;
                    let i = p * ch + c;
                    self.values[i] = wp * self.values[i] + (1.0 - wp) * up;
                }
                self.weight[p] = 1.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sources keep their values exactly; every target is filled with a value within the
    /// sources' range; other pixels are untouched.
    #[test]
    fn sources_kept_targets_filled_within_range() {
        let (w, h) = (13, 7);
        let mut rng = assist_core::Rng::new(3);
        let mut vals: Vec<f32> = (0..w * h * 2).map(|_| rng.f32()).collect();
        let source: Vec<bool> = (0..w * h).map(|q| q % 5 != 0 && q % 7 != 3).collect();
        let target: Vec<bool> = (0..w * h).map(|q| q % 5 == 0).collect();
        let before = vals.clone();
        let range = |c: usize| {
            let it = (0..w * h).filter(|&q| source[q]).map(|q| before[2 * q + c]);
            (
                it.clone().fold(f32::MAX, f32::min),
                it.fold(f32::MIN, f32::max),
            )
        };
        pull_push(w, h, 2, &mut vals, &source, &target);
        for q in 0..w * h {
            for c in 0..2 {
                let (v, b) = (vals[2 * q + c], before[2 * q + c]);
                if source[q] || !target[q] {
                    assert_eq!(v, b, "pixel {q} changed");
                } else {
                    let (lo, hi) = range(c);
                    assert!(
                        v >= lo - 1e-6 && v <= hi + 1e-6,
                        "pixel {q}: {v} outside {lo}..{hi}"
                    );
                    assert_ne!(v, b, "pixel {q} not filled");
                }
            }
        }
    }

    /// A hole in a constant image is filled with that constant; a hole in a horizontal
    /// ramp is filled near the ramp's value there (the fill continues what surrounds it).
    #[test]
    fn holes_continue_their_surroundings() {
        let (w, h) = (32, 16);
        let hole = |x: usize, y: usize| (10..14).contains(&x) && (5..9).contains(&y);
        let source: Vec<bool> = (0..w * h).map(|q| !hole(q % w, q / w)).collect();
        let target: Vec<bool> = source.iter().map(|s| !s).collect();
        let mut flat: Vec<f32> = source.iter().map(|&s| if s { 0.25 } else { 0.0 }).collect();
        pull_push(w, h, 1, &mut flat, &source, &target);
        assert!(flat.iter().all(|&v| (v - 0.25).abs() < 1e-6), "{flat:?}");
        let mut ramp: Vec<f32> = (0..w * h)
            .map(|q| {
                if source[q] {
                    (q % w) as f32 / w as f32
                } else {
                    0.0
                }
            })
            .collect();
        pull_push(w, h, 1, &mut ramp, &source, &target);
        for q in (0..w * h).filter(|&q| target[q]) {
            let want = (q % w) as f32 / w as f32;
            assert!(
                (ramp[q] - want).abs() < 0.08,
                "pixel {q}: {} against {want}",
                ramp[q]
            );
        }
    }

    /// Nothing to fill from, or nothing to fill: the values are left as they are.
    #[test]
    fn no_source_or_no_target_changes_nothing() {
        let mut v = vec![0.5f32; 12];
        pull_push(4, 3, 1, &mut v, &[false; 12], &[true; 12]);
        assert_eq!(v, vec![0.5; 12]);
        pull_push(4, 3, 1, &mut v, &[true; 12], &[false; 12]);
        assert_eq!(v, vec![0.5; 12]);
    }
}
