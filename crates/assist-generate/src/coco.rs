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

    #[test]
    fn boxes_are_inclusive_pixel_extents() {
        let m = [0, 0, 0, 0, 0, 1, 1, 0, 0, 1, 0, 0];
        assert_eq!(bbox(4, 3, |q| m[q] == 1), Some([1, 1, 2, 2]));
        assert_eq!(bbox(4, 3, |_| false), None);
    }
}
