//! Pictures for people: instance ids as distinct colours, depth as grey, integer
//! enlargement, captions, and contact sheets that tile views side by side.

use crate::image_io::ImageF32;

/// Distinct colours for instance ids (0 = black): hues a golden-ratio step apart.
pub fn id_color(id: u16) -> [f32; 3] {
    if id == 0 {
        return [0.0; 3];
    }
    let h = (id as f32 * 0.618_034).fract();
    hsv(h, 0.75, 0.95)
}

fn hsv(h: f32, s: f32, v: f32) -> [f32; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    match i as i32 % 6 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// Instance ids as an RGB picture (see [`id_color`]).
pub fn ids_image(w: u32, h: u32, ids: &[u16]) -> ImageF32 {
    let mut out = ImageF32::new(w, h, 3);
    for (k, &v) in ids.iter().enumerate() {
        out.data[k * 3..k * 3 + 3].copy_from_slice(&id_color(v));
    }
    out
}

/// Depth as grey: near is white, far dark (square-root scale between the nearest and the
/// farthest valid depth), no depth (0) black.
pub fn depth_image(w: u32, h: u32, depth: &[f32]) -> ImageF32 {
    let valid = depth.iter().copied().filter(|&v| v > 0.0);
    let (lo, hi) = valid.fold((f32::INFINITY, 0.0f32), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let mut out = ImageF32::new(w, h, 3);
    for (k, &v) in depth.iter().enumerate() {
        let t = if v > 0.0 {
            1.0 - ((v - lo) / (hi - lo).max(1e-6)).sqrt()
        } else {
            0.0
        };
        out.data[k * 3..k * 3 + 3].copy_from_slice(&[t, t, t]);
    }
    out
}

/// Nearest-neighbour enlargement of an RGB image by an integer factor.
pub fn upscale(img: &ImageF32, f: u32) -> ImageF32 {
    let mut out = ImageF32::new(img.width * f, img.height * f, 3);
    for y in 0..out.height {
        for x in 0..out.width {
            let src = img.pixel(x / f, y / f);
            let k = ((y * out.width + x) * 3) as usize;
            out.data[k..k + 3].copy_from_slice(&src[..3]);
        }
    }
    out
}

/// Pixel height of the band [`captioned`] adds above an image at text scale `scale`.
pub fn caption_height(scale: u32) -> u32 {
    (8 + 4) * scale.max(1)
}

/// `img` with a dark band above it holding `text` in white (an 8×8 bitmap font enlarged
/// `scale` times; printable ASCII, anything else drawn as `?`; text past the right edge is
/// cut).
pub fn captioned(img: &ImageF32, text: &str, scale: u32) -> ImageF32 {
    let s = scale.max(1);
    let band = caption_height(s);
    let mut out = ImageF32::new(img.width, img.height + band, 3);
    for px in out.data[..(band * img.width * 3) as usize].chunks_mut(3) {
        px.copy_from_slice(&[0.12, 0.12, 0.12]);
    }
    for y in 0..img.height {
        for x in 0..img.width {
            let src = img.pixel(x, y);
            let k = (((band + y) * img.width + x) * 3) as usize;
            out.data[k..k + 3].copy_from_slice(&src[..3]);
        }
    }
    let (x0, y0) = (2 * s, 2 * s);
    for (n, ch) in text.chars().enumerate() {
        let ch = if ch.is_ascii() && !ch.is_ascii_control() {
            ch
        } else {
            '?'
        };
        let glyph = font8x8::legacy::BASIC_LEGACY[ch as usize];
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8u32 {
                if bits >> col & 1 == 0 {
                    continue;
                }
                for dy in 0..s {
                    for dx in 0..s {
                        let x = x0 + (n as u32 * 8 + col) * s + dx;
                        let y = y0 + row as u32 * s + dy;
                        if x < out.width && y < band {
                            let k = ((y * out.width + x) * 3) as usize;
                            out.data[k..k + 3].copy_from_slice(&[1.0; 3]);
                        }
                    }
                }
            }
        }
    }
    out
}

/// Tiles RGB images into rows of `cols` on white, 2 pixels apart; each cell is as large as
/// the largest image. An empty list gives an empty image.
pub fn contact_sheet(images: &[ImageF32], cols: usize) -> ImageF32 {
    let cols = cols.max(1);
    let w = images.iter().map(|i| i.width).max().unwrap_or(0);
    let h = images.iter().map(|i| i.height).max().unwrap_or(0);
    let rows = images.len().div_ceil(cols);
    let gap = 2;
    let used = cols.min(images.len()) as u32;
    let mut out = ImageF32::new(used * (w + gap), rows as u32 * (h + gap), 3);
    out.data.fill(1.0);
    for (n, img) in images.iter().enumerate() {
        let (ox, oy) = ((n % cols) as u32 * (w + gap), (n / cols) as u32 * (h + gap));
        for y in 0..img.height {
            for x in 0..img.width {
                let src = img.pixel(x, y);
                let k = (((oy + y) * out.width + ox + x) * 3) as usize;
                out.data[k..k + 3].copy_from_slice(&src[..3]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_caption_is_white_text_on_a_band_above_the_image() {
        let mut img = ImageF32::new(40, 10, 3);
        img.data.fill(0.5);
        let c = captioned(&img, "Hi", 1);
        assert_eq!((c.width, c.height), (40, 10 + caption_height(1)));
        // The image is below the band, unchanged.
        assert!((0..10).all(|y| (0..40).all(|x| c.pixel(x, y + 12)[0] == 0.5)));
        // 'H' has two vertical strokes: two runs of columns lit from top to bottom.
        let lit = |x: u32| (2..10).filter(|&y| c.pixel(x, y)[0] == 1.0).count();
        let full: Vec<bool> = (2..10).map(|x| lit(x) >= 6).collect();
        let strokes = (0..full.len())
            .filter(|&i| full[i] && (i == 0 || !full[i - 1]))
            .count();
        assert_eq!(
            strokes,
            2,
            "columns lit: {:?}",
            (2..10).map(lit).collect::<Vec<_>>()
        );
        // Nothing is drawn past the two glyphs.
        assert!((20..40).all(|x| (0..12).all(|y| c.pixel(x, y)[0] < 0.2)));
        // An unprintable character still takes its place, as '?'.
        let q = captioned(&img, "\u{1F600}", 1);
        assert!((2..10).any(|x| (2..10).any(|y| q.pixel(x, y)[0] == 1.0)));
    }

    #[test]
    fn ids_get_distinct_colours_and_background_is_black() {
        assert_eq!(id_color(0), [0.0; 3]);
        let cs: Vec<[f32; 3]> = (1..=20).map(id_color).collect();
        for (i, a) in cs.iter().enumerate() {
            for b in &cs[i + 1..] {
                let d: f32 = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum();
                assert!(d > 0.05, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn depth_is_white_near_dark_far_black_missing() {
        let img = depth_image(3, 1, &[1.0, 5.0, 0.0]);
        assert_eq!(&img.data[0..3], &[1.0; 3]);
        assert_eq!(&img.data[3..6], &[0.0; 3]);
        assert_eq!(&img.data[6..9], &[0.0; 3]);
    }

    #[test]
    fn sheet_places_images_in_rows() {
        let mut a = ImageF32::new(2, 1, 3);
        a.data.fill(0.25);
        let sheet = contact_sheet(&[a.clone(), a.clone(), a], 2);
        assert_eq!((sheet.width, sheet.height), (8, 6));
        assert_eq!(sheet.pixel(0, 0), &[0.25; 3]);
        assert_eq!(sheet.pixel(2, 0), &[1.0; 3]);
        assert_eq!(sheet.pixel(4, 0), &[0.25; 3]);
        assert_eq!(sheet.pixel(0, 3), &[0.25; 3]);
        assert_eq!(sheet.pixel(4, 3), &[1.0; 3]);
        let up = upscale(&ImageF32::new(1, 1, 3), 3);
        assert_eq!((up.width, up.height), (3, 3));
    }
}
