//! open_clip's evaluation transform: resize the shorter side to the model's size
//! (bicubic), crop the centre square, scale to [0, 1] and normalise per channel.

use image::RgbImage;
use image::imageops::{FilterType, crop_imm, resize};

use crate::{ClipError, Result};

/// The shorter side resized to `size` (the longer one truncated, as torchvision does),
/// then the centre `size × size` square (offsets rounded half to even, as Python's round).
pub fn resize_crop(img: &RgbImage, size: u32) -> Result<RgbImage> {
    let (w, h) = img.dimensions();
    if w == 0 || h == 0 || size == 0 {
        return Err(ClipError::Input(format!(
            "cannot fit a {w}×{h} image to {size}×{size}"
        )));
    }
    let (ow, oh) = if w <= h {
        (size, (size as u64 * h as u64 / w as u64) as u32)
    } else {
        ((size as u64 * w as u64 / h as u64) as u32, size)
    };
    let resized = if (ow, oh) == (w, h) {
        img.clone()
    } else {
        resize(img, ow, oh, FilterType::CatmullRom)
    };
    if (ow, oh) == (size, size) {
        return Ok(resized);
    }
    let left = ((ow - size) as f64 / 2.0).round_ties_even() as u32;
    let top = ((oh - size) as f64 / 2.0).round_ties_even() as u32;
    Ok(crop_imm(&resized, left, top, size, size).to_image())
}

/// `img` as the model's input: `3 × size × size` floats, channel-major.
pub fn preprocess(img: &RgbImage, size: usize, mean: [f32; 3], std: [f32; 3]) -> Result<Vec<f32>> {
    let sq = resize_crop(img, size as u32)?;
    let mut out = vec![0f32; 3 * size * size];
    for (x, y, p) in sq.enumerate_pixels() {
        let i = y as usize * size + x as usize;
        for c in 0..3 {
            out[c * size * size + i] = (p.0[c] as f32 / 255.0 - mean[c]) / std[c];
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_image_of_the_model_size_is_only_normalised() {
        let img = RgbImage::from_fn(4, 4, |x, y| image::Rgb([x as u8 * 60, y as u8 * 60, 255]));
        let p = preprocess(&img, 4, [0.5; 3], [0.25; 3]).unwrap();
        assert_eq!(p.len(), 48);
        // red of pixel (x=3, y=1): 180/255
        assert!((p[4 + 3] - (180.0 / 255.0 - 0.5) / 0.25).abs() < 1e-6);
        // blue everywhere 1.0 → 2.0
        assert!(p[32..].iter().all(|v| (*v - 2.0).abs() < 1e-6));
    }

    #[test]
    fn wide_images_keep_their_centre() {
        // 8×4, left half black, right half white, a red column at x = 3..5 in the middle.
        let img = RgbImage::from_fn(8, 4, |x, _| {
            if (3..5).contains(&x) {
                image::Rgb([255, 0, 0])
            } else if x < 4 {
                image::Rgb([0, 0, 0])
            } else {
                image::Rgb([255, 255, 255])
            }
        });
        let c = resize_crop(&img, 4).unwrap();
        assert_eq!(c.dimensions(), (4, 4));
        assert_eq!(c.get_pixel(1, 0).0, [255, 0, 0]);
        assert_eq!(c.get_pixel(2, 3).0, [255, 0, 0]);
        assert_eq!(c.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(c.get_pixel(3, 0).0, [255, 255, 255]);
        assert!(resize_crop(&RgbImage::new(0, 3), 4).is_err());
    }
}
