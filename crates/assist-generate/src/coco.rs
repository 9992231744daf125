//! COCO's run-length masks and what a view's masks say about each object.

use serde::{Deserialize, Serialize};

/// Run lengths of a binary mask in COCO's order (column-major: down each column, columns
/// left to right), starting with a run of zeros (possibly empty).
pub fn rle_counts(w: usize, h: usize, on: impl Fn(usize) -> bool) -> Vec<u32> {
    let mut counts = Vec::new();
    let mut cur = false;
    let mut run = 0u32;
    for x in 0..w {
        for y in 0..h {
            let v = on(y * w + x);
            if v != cur {
                counts.push(run);
                run = 0;
                cur = v;
            }
            run += 1;
        }
    }
    counts.push(run);
    counts
}

/// COCO's compressed RLE string (`pycocotools`' `rleToString`): each count, as a difference
/// to the count two before it from the third on, in 5-bit groups with a continuation bit,
/// offset by 48 into printable ASCII.
pub fn rle_string(counts: &[u32]) -> String {
    let mut s = String::new();
    for (i, &c) in counts.iter().enumerate() {
        let mut x = c as i64;
        if i > 2 {
            x -= counts[i - 2] as i64;
        }
        loop {
            let mut c = (x & 0x1f) as u8;
            x >>= 5;
            let more = if c & 0x10 != 0 { x != -1 } else { x != 0 };
            if more {
                c |= 0x20;
            }
            s.push((c + 48) as char);
            if !more {
                break;
            }
        }
    }
    s
}

/// Decodes [`rle_string`] (for tests and for reading fragments back).
pub fn rle_decode(s: &str) -> Vec<u32> {
    let b = s.as_bytes();
    let mut counts: Vec<u32> = Vec::new();
    let mut p = 0;
    while p < b.len() {
        let mut x: i64 = 0;
        let mut k = 0;
        loop {
            let c = (b[p] - 48) as i64;
            x |= (c & 0x1f) << (5 * k);
            let more = c & 0x20 != 0;
            p += 1;
            k += 1;
            if !more {
                if c & 0x10 != 0 {
                    x |= -1i64 << (5 * k);
                }
                break;
            }
        }
        let m = counts.len();
        if m > 2 {
            x += counts[m - 2] as i64;
        }
        counts.push(x as u32);
    }
    counts
}

/// A box `[x, y, width, height]` in pixels (COCO's convention).
pub type BBox = [u32; 4];

/// Pixel bounding box of a mask.
pub fn bbox(w: usize, h: usize, on: impl Fn(usize) -> bool) -> Option<BBox> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if on(y * w + x) {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
    }
    (x0 != usize::MAX).then(|| {
        [
            x0 as u32,
            y0 as u32,
            (x1 - x0 + 1) as u32,
            (y1 - y0 + 1) as u32,
        ]
    })
}

/// How COCO instance annotations give masks: outer polygons (what torchvision's detection
/// reference and detectron2 read by default; holes are filled) or compressed RLE (exact).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CocoMasks {
    #[default]
    Polygon,
    Rle,
}

/// The outer boundaries of a `w`×`h` mask as COCO polygons: per 4-connected region, its
/// outline along pixel edges (`[x0, y0, x1, y1, …]`, vertices at pixel corners, only where
/// the outline turns). pycocotools rasterises such a polygon back to exactly the region's
/// pixels, holes filled. Regions touching only at a corner get one polygon each.
pub fn polygons(w: usize, h: usize, on: impl Fn(usize) -> bool) -> Vec<Vec<f64>> {
    // Screen axes (y down): east, south, west, north. An edge runs between pixel corners
    // with its pixel on the right, so outer outlines run clockwise on screen and holes
    // the other way. Edge id: corner * 4 + direction.
    const DIRS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
    let fg = |x: i64, y: i64| {
        x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h && on(y as usize * w + x as usize)
    };
    let stride = w as i64 + 1;
    let id = |x: i64, y: i64, d: usize| ((y * stride + x) as usize) * 4 + d;
    let mut edge = vec![false; 4 * (w + 1) * (h + 1)];
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            if fg(x, y) {
                edge[id(x, y, 0)] |= !fg(x, y - 1);
                edge[id(x + 1, y, 1)] |= !fg(x + 1, y);
                edge[id(x + 1, y + 1, 2)] |= !fg(x, y + 1);
                edge[id(x, y + 1, 3)] |= !fg(x - 1, y);
            }
        }
    }
    let mut used = vec![false; edge.len()];
    let mut loops = Vec::new();
    for start in 0..edge.len() {
        if !edge[start] || used[start] {
            continue;
        }
        // Follow the outline: at each corner turn right if an edge does (two pixels
        // meeting diagonally: the right turn stays with this pixel), else go on, else
        // turn left. Each edge is followed once.
        let (c, d0) = (start / 4, start % 4);
        let (mut x, mut y, mut d) = (c as i64 % stride, c as i64 / stride, d0);
        let mut pts = Vec::new();
        let mut area2 = 0i64;
        loop {
            used[id(x, y, d)] = true;
            let (nx, ny) = (x + DIRS[d].0, y + DIRS[d].1);
            area2 += x * ny - nx * y;
            (x, y) = (nx, ny);
            let next = [(d + 1) % 4, d, (d + 3) % 4]
                .into_iter()
                .find(|&e| edge[id(x, y, e)])
                .expect("an outline is closed");
            if id(x, y, next) == start {
                break;
            }
            let e = next;
            if e != d {
                pts.extend([x as f64, y as f64]);
            }
            d = e;
        }
        // Back at the start corner: a vertex when the outline turns there.
        if d != d0 {
            pts.splice(0..0, [x as f64, y as f64]);
        }
        if area2 > 0 && pts.len() >= 6 {
            loops.push(pts);
        }
    }
    loops
}

/// One object in one view: what is seen of it, and what would be without occluders.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewObject {
    pub id: u16,
    pub class: u16,
    /// Pixels where it is the instance shown.
    pub visible_pixels: u64,
    /// Pixels it covers alone (its own opacity ≥ 0.5), occluders ignored, within the image.
    pub amodal_pixels: u64,
    /// visible / amodal (0 when it covers nothing).
    pub visibility: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bbox_visible: Option<BBox>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bbox_amodal: Option<BBox>,
    /// COCO compressed RLE of the visible mask (absent when nothing is visible).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rle: Option<String>,
    /// The visible mask's outer outlines as COCO polygons (see [`polygons`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub polygons: Vec<Vec<f64>>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_are_column_major_and_start_with_zeros() {
        // 3×2 image, row-major:  1 0 0 / 1 1 0  → columns: (1,1), (0,1), (0,0)
        let m = [1, 0, 0, 1, 1, 0];
        let c = rle_counts(3, 2, |q| m[q] == 1);
        assert_eq!(c, vec![0, 2, 1, 1, 2]);
        let all0 = rle_counts(2, 2, |_| false);
        assert_eq!(all0, vec![4]);
    }

    #[test]
    fn compressed_strings_round_trip_and_match_pycocotools() {
        // pycocotools' `encode` of the 2×3 mask [[1, 0, 0], [1, 1, 0]].
        assert_eq!(rle_string(&[0, 2, 1, 1, 2]), "021O1");
        for counts in [
            vec![0u32, 2, 1, 1, 2],
            vec![5, 100000, 3, 70, 1, 1, 1, 2_000_000],
            vec![172800],
            vec![10, 1, 40, 1, 35, 200, 3],
        ] {
            let s = rle_string(&counts);
            assert!(s.bytes().all(|b| (48..48 + 64).contains(&b)), "{s}");
            assert_eq!(rle_decode(&s), counts, "{s}");
        }
    }

    /// Pixels whose centres lie inside any of `polys` (even-odd per polygon, then union).
    fn raster(w: usize, h: usize, polys: &[Vec<f64>]) -> Vec<bool> {
        let mut m = vec![false; w * h];
        for p in polys {
            let pts: Vec<(f64, f64)> = p.chunks(2).map(|c| (c[0], c[1])).collect();
            for y in 0..h {
                for x in 0..w {
                    let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                    let mut inside = false;
                    for i in 0..pts.len() {
                        let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
                        if (a.1 > py) != (b.1 > py)
                            && px < a.0 + (py - a.1) / (b.1 - a.1) * (b.0 - a.0)
                        {
                            inside = !inside;
                        }
                    }
                    m[y * w + x] |= inside;
                }
            }
        }
        m
    }

    /// `m` with every background pixel not reachable from the border set (holes filled).
    fn filled(w: usize, h: usize, m: &[bool]) -> Vec<bool> {
        let mut outside = vec![false; w * h];
        let mut stack: Vec<usize> = (0..w * h)
            .filter(|&q| !m[q] && (q % w == 0 || q % w == w - 1 || q / w == 0 || q / w == h - 1))
            .collect();
        while let Some(q) = stack.pop() {
            if outside[q] || m[q] {
                continue;
            }
            outside[q] = true;
            // 8-connected: regions meeting at a corner are apart, so the background
            // between them is one.
            let (x, y) = (q % w, q / w);
            for (dx, dy) in [
                (-1i64, -1i64),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h {
                    stack.push(ny as usize * w + nx as usize);
                }
            }
        }
        outside.iter().map(|o| !o).collect()
    }

    #[test]
    fn polygons_outline_pixels_exactly_with_holes_filled() {
        // One pixel: its four corners, clockwise on screen.
        assert_eq!(
            polygons(3, 3, |q| q == 4),
            vec![vec![1.0, 1.0, 2.0, 1.0, 2.0, 2.0, 1.0, 2.0]]
        );
        // An L: six vertices, only where the outline turns.
        let l = [1, 1, 1, 1, 0, 0, 1, 0, 0];
        let p = polygons(3, 3, |q| l[q] == 1);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].len(), 12, "{p:?}");
        // Pixels meeting at a corner: one polygon each.
        let d = [1, 0, 0, 1];
        assert_eq!(polygons(2, 2, |q| d[q] == 1).len(), 2);
        // A ring: the outer outline only.
        let ring: Vec<bool> = (0..25)
            .map(|q| {
                let (x, y) = (q % 5, q / 5);
                (1..4).contains(&x) && (1..4).contains(&y) && q != 12
            })
            .collect();
        let p = polygons(5, 5, |q| ring[q]);
        assert_eq!(p, vec![vec![1.0, 1.0, 4.0, 1.0, 4.0, 4.0, 1.0, 4.0]]);
        assert!(polygons(4, 4, |_| false).is_empty());
        // Random blobs of every density: the polygons rasterise to the mask, holes filled.
        let mut rng = assist_core::Rng::new(7);
        for case in 0..200 {
            let (w, h) = (1 + rng.below(12) as usize, 1 + rng.below(12) as usize);
            let p = rng.f64();
            let m: Vec<bool> = (0..w * h).map(|_| rng.f64() < p).collect();
            let polys = polygons(w, h, |q| m[q]);
            assert_eq!(
                raster(w, h, &polys),
                filled(w, h, &m),
                "case {case}: {w}×{h} {m:?} → {polys:?}"
            );
        }
    }

    #[test]
    fn boxes_are_inclusive_pixel_extents() {
        let m = [0, 0, 0, 0, 0, 1, 1, 0, 0, 1, 0, 0];
        assert_eq!(bbox(4, 3, |q| m[q] == 1), Some([1, 1, 2, 2]));
        assert_eq!(bbox(4, 3, |_| false), None);
    }
}
