//! Into and out of the model's frame: the photograph resized so its longer side is the
//! encoder's input, normalised with SAM's pixel statistics and zero-padded to a square;
//! masks scaled back with PyTorch's bilinear rule (`align_corners=False`) in the
//! reference's two steps (to the padded input, cropped, then to the photograph).

use candle_core::{Device, Tensor};

use crate::{Result, SamError};

/// SAM's pixel mean and standard deviation (0–255 scale).
const MEAN: [f32; 3] = [123.675, 116.28, 103.53];
const STD: [f32; 3] = [58.395, 57.12, 57.375];

/// Bilinear resampling of a `sw` × `sh` single-channel image to `dw` × `dh`, reading
/// source coordinates `(d + ½)·scale − ½` (clamped at 0), as PyTorch does.
fn bilinear(
    src: &[f32],
    sw: usize,
    sh: usize,
    (scale_x, scale_y): (f64, f64),
    dw: usize,
    dh: usize,
) -> Vec<f32> {
    let axis = |d: usize, scale: f64, n: usize| {
        let s = ((d as f64 + 0.5) * scale - 0.5).max(0.0);
        let i0 = (s.floor() as usize).min(n - 1);
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, (s - i0 as f64) as f32)
    };
    let xs: Vec<_> = (0..dw).map(|x| axis(x, scale_x, sw)).collect();
    let mut out = vec![0f32; dw * dh];
    for y in 0..dh {
        let (y0, y1, ly) = axis(y, scale_y, sh);
        for (x, &(x0, x1, lx)) in xs.iter().enumerate() {
            let top = src[y0 * sw + x0] * (1.0 - lx) + src[y0 * sw + x1] * lx;
            let bottom = src[y1 * sw + x0] * (1.0 - lx) + src[y1 * sw + x1] * lx;
            out[y * dw + x] = top * (1.0 - ly) + bottom * ly;
        }
    }
    out
}

/// The encoder's input `[1, 3, size, size]` for an RGB image (`rgb` in [0, 1], row-major),
/// and its size once resized (longer side `size`).
pub fn preprocess(
    rgb: &[f32],
    width: usize,
    height: usize,
    size: usize,
) -> Result<(Tensor, (usize, usize))> {
    if width == 0 || height == 0 || rgb.len() != 3 * width * height {
        return Err(SamError::Input(format!(
            "an RGB image of {width} × {height} needs {} values, got {}",
            3 * width * height,
            rgb.len()
        )));
    }
    let s = size as f64 / width.max(height) as f64;
    let (rw, rh) = (
        ((width as f64 * s).round() as usize).clamp(1, size),
        ((height as f64 * s).round() as usize).clamp(1, size),
    );
    let mut data = vec![0f32; 3 * size * size];
    for c in 0..3 {
        let plane: Vec<f32> = (0..width * height)
            .map(|i| rgb[3 * i + c] * 255.0)
            .collect();
        // Shrinking: average over the source footprint first (a box pre-filter), so a
        // 4000-pixel photograph does not alias.
        let (plane, pw, ph) = box_shrink(&plane, width, height, rw, rh);
        let r = bilinear(
            &plane,
            pw,
            ph,
            (pw as f64 / rw as f64, ph as f64 / rh as f64),
            rw,
            rh,
        );
        for y in 0..rh {
            for x in 0..rw {
                data[c * size * size + y * size + x] = (r[y * rw + x] - MEAN[c]) / STD[c];
            }
        }
    }
    Ok((
        Tensor::from_vec(data, (1, 3, size, size), &Device::Cpu)?,
        (rw, rh),
    ))
}

/// Averages `k` × `k` blocks while the image stays at least twice the target size.
fn box_shrink(p: &[f32], w: usize, h: usize, tw: usize, th: usize) -> (Vec<f32>, usize, usize) {
    let k = (w / (2 * tw)).min(h / (2 * th)).max(1);
    if k == 1 {
        return (p.to_vec(), w, h);
    }
    let (nw, nh) = (w / k, h / k);
    let mut out = vec![0f32; nw * nh];
    for y in 0..nh {
        for x in 0..nw {
            let mut s = 0.0;
            for dy in 0..k {
                for dx in 0..k {
                    s += p[(y * k + dy) * w + x * k + dx];
                }
            }
            out[y * nw + x] = s / (k * k) as f32;
        }
    }
    (out, nw, nh)
}

/// A low-resolution mask (`side` × `side` logits) at the photograph's size: scaled to
/// the padded input (`input` square), cropped to the resized image, scaled to `original`.
pub fn mask_to_size(
    logits: &[f32],
    side: usize,
    input: usize,
    (rw, rh): (usize, usize),
    (ow, oh): (usize, usize),
) -> Vec<f32> {
    let scale = side as f64 / input as f64;
    let padded = bilinear(logits, side, side, (scale, scale), rw, rh);
    bilinear(
        &padded,
        rw,
        rh,
        (rw as f64 / ow as f64, rh as f64 / oh as f64),
        ow,
        oh,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_follows_pytorch_on_a_hand_computed_case() {
        // 2 × 1 → 4 × 1 (scale ½): sources −0.25 (→0), 0.25, 0.75, 1.25 (→ index 1).
        let out = bilinear(&[0.0, 4.0], 2, 1, (0.5, 1.0), 4, 1);
        assert_eq!(out, vec![0.0, 1.0, 3.0, 4.0]);
    }

    #[test]
    fn a_wide_image_is_resized_to_the_longer_side_and_padded_with_zeros() {
        let rgb = vec![0.5f32; 3 * 40 * 20];
        let (t, (rw, rh)) = preprocess(&rgb, 40, 20, 16).unwrap();
        assert_eq!((rw, rh), (16, 8));
        let v = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let red = (127.5 - MEAN[0]) / STD[0];
        assert!((v[0] - red).abs() < 1e-5);
        assert_eq!(v[8 * 16], 0.0); // below the image: padding
        assert!(preprocess(&rgb, 40, 21, 16).is_err());
    }
}
