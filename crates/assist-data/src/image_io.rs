//! Reading images, masks and depth maps, and writing PNGs atomically.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{DataError, Result};

/// A float image, row-major, `channels` interleaved values per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn new(width: u32, height: u32, channels: u32) -> Self {
        ImageF32 {
            width,
            height,
            channels,
            data: vec![0.0; (width * height * channels) as usize],
        }
    }
    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let i = ((y * self.width + x) * self.channels) as usize;
        &self.data[i..i + self.channels as usize]
    }
}

/// Integer ids per pixel (instance masks).
#[derive(Debug, Clone, PartialEq)]
pub struct IdImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u16>,
}

fn decode(path: &Path) -> Result<image::DynamicImage> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| DataError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| DataError::io(path, e))?;
    reader.decode().map_err(|e| DataError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Width and height from the file header, without decoding the pixels.
pub fn image_dimensions(path: &Path) -> Result<(u32, u32)> {
    if !path.exists() {
        return Err(DataError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "file not found"),
        ));
    }
    image::image_dimensions(path).map_err(|e| DataError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn srgb8(v: u8) -> f32 {
    v as f32 * (1.0 / 255.0)
}

/// Reads an RGB image as floats in [0, 1]. If it has alpha, it is composited over
/// `background` and the alpha is returned too (for Blender object masks).
pub fn read_rgb(path: &Path, background: [f32; 3]) -> Result<(ImageF32, Option<Vec<f32>>)> {
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    let mut out = ImageF32::new(w, h, 3);
    if img.color().has_alpha() {
        let rgba = img.to_rgba8();
        let mut alpha = Vec::with_capacity((w * h) as usize);
        for (i, p) in rgba.pixels().enumerate() {
            let a = srgb8(p.0[3]);
            for c in 0..3 {
                out.data[i * 3 + c] = srgb8(p.0[c]) * a + background[c] * (1.0 - a);
            }
            alpha.push(a);
        }
        Ok((out, Some(alpha)))
    } else {
        let rgb = img.to_rgb8();
        for (o, v) in out.data.iter_mut().zip(rgb.as_raw()) {
            *o = srgb8(*v);
        }
        Ok((out, None))
    }
}

/// Reads an instance-id mask (8- or 16-bit grey or palette PNG; 0 = background): the raw
/// values are the ids.
pub fn read_ids(path: &Path) -> Result<IdImage> {
    read_mask_values(path)
}

/// Reads an instance mask and maps its values to ids with `encoding`.
pub fn read_instance_mask(path: &Path, encoding: crate::masks::MaskEncoding) -> Result<IdImage> {
    let mut m = read_mask_values(path)?;
    if encoding != crate::masks::MaskEncoding::Ids {
        for v in &mut m.data {
            *v = encoding.id(*v);
        }
    }
    Ok(m)
}

/// The raw values of a mask: grey (8 or 16 bits, with or without alpha, or RGB whose
/// pixels are grey), or a palette PNG's indices (what XMem, DEVA and DAVIS write).
pub fn read_mask_values(path: &Path) -> Result<IdImage> {
    if let Some(m) = read_palette_indices(path)? {
        return Ok(m);
    }
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    let not_grey = |what: &str| DataError::Image {
        path: path.to_path_buf(),
        message: format!(
            "a {what} mask with coloured pixels: expected grey values (instance ids, or 0/255 for one object) or a palette PNG whose indices are the ids"
        ),
    };
    let data: Vec<u16> = match img {
        image::DynamicImage::ImageLuma8(g) => g.into_raw().into_iter().map(u16::from).collect(),
        image::DynamicImage::ImageLuma16(g) => g.into_raw(),
        image::DynamicImage::ImageLumaA8(g) => g.pixels().map(|p| u16::from(p.0[0])).collect(),
        image::DynamicImage::ImageLumaA16(g) => g.pixels().map(|p| p.0[0]).collect(),
        image::DynamicImage::ImageRgb8(g) => g
            .pixels()
            .map(|p| (p.0[0] == p.0[1] && p.0[1] == p.0[2]).then_some(u16::from(p.0[0])))
            .collect::<Option<_>>()
            .ok_or_else(|| not_grey("RGB"))?,
        image::DynamicImage::ImageRgba8(g) => g
            .pixels()
            .map(|p| (p.0[0] == p.0[1] && p.0[1] == p.0[2]).then_some(u16::from(p.0[0])))
            .collect::<Option<_>>()
            .ok_or_else(|| not_grey("RGBA"))?,
        image::DynamicImage::ImageRgb16(g) => g
            .pixels()
            .map(|p| (p.0[0] == p.0[1] && p.0[1] == p.0[2]).then_some(p.0[0]))
            .collect::<Option<_>>()
            .ok_or_else(|| not_grey("RGB"))?,
        image::DynamicImage::ImageRgba16(g) => g
            .pixels()
            .map(|p| (p.0[0] == p.0[1] && p.0[1] == p.0[2]).then_some(p.0[0]))
            .collect::<Option<_>>()
            .ok_or_else(|| not_grey("RGBA"))?,
        other => {
            return Err(DataError::Image {
                path: path.to_path_buf(),
                message: format!(
                    "expected an 8- or 16-bit grey or palette mask, got {:?}",
                    other.color()
                ),
            });
        }
    };
    Ok(IdImage {
        width: w,
        height: h,
        data,
    })
}

/// A palette PNG's indices (not its colours); `None` for any other file.
fn read_palette_indices(path: &Path) -> Result<Option<IdImage>> {
    let is_png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !is_png {
        return Ok(None);
    }
    let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
    let bad = |e: png::DecodingError| DataError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::IDENTITY);
    let mut reader = dec.read_info().map_err(bad)?;
    if reader.info().color_type != png::ColorType::Indexed {
        return Ok(None);
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| DataError::Image {
            path: path.to_path_buf(),
            message: "image too large".into(),
        })?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    let bits = info.bit_depth as usize;
    let (w, h) = (info.width as usize, info.height as usize);
    let mut data = Vec::with_capacity(w * h);
    for row in buf.chunks(info.line_size).take(h) {
        for x in 0..w {
            let bit = x * bits;
            let byte = row[bit / 8];
            let shift = 8 - bits - (bit % 8);
            data.push(u16::from((byte >> shift) & ((1u16 << bits) - 1) as u8));
        }
    }
    Ok(Some(IdImage {
        width: info.width,
        height: info.height,
        data,
    }))
}

/// Reads a 16-bit depth PNG; values times `scale` (0 stays 0 = no depth).
pub fn read_depth_png(path: &Path, scale: f64) -> Result<ImageF32> {
    let img = decode(path)?;
    let (w, h) = (img.width(), img.height());
    let raw: Vec<u16> = match img {
        image::DynamicImage::ImageLuma16(g) => g.into_raw(),
        image::DynamicImage::ImageLuma8(g) => g.into_raw().into_iter().map(u16::from).collect(),
        other => {
            return Err(DataError::Image {
                path: path.to_path_buf(),
                message: format!(
                    "expected a single-channel 16-bit depth PNG, got {:?}",
                    other.color()
                ),
            });
        }
    };
    Ok(ImageF32 {
        width: w,
        height: h,
        channels: 1,
        data: raw.into_iter().map(|v| (v as f64 * scale) as f32).collect(),
    })
}

/// Decodes fully (catching truncation) and returns the size.
pub fn decoded_size(path: &Path) -> Result<(u32, u32)> {
    let img = decode(path)?;
    Ok((img.width(), img.height()))
}

/// Writes bytes to `path` atomically: a temporary file beside it, then a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_path(path);
    let res = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(DataError::io(path, e));
    }
    Ok(())
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

fn encode_png(
    w: u32,
    h: u32,
    data: &[u8],
    color: image::ExtendedColorType,
) -> Result<Vec<u8>, image::ImageError> {
    use image::ImageEncoder;
    let mut buf = Vec::new();
    image::codecs::png::PngEncoder::new(&mut buf).write_image(data, w, h, color)?;
    Ok(buf)
}

fn png_err(path: &Path, e: image::ImageError) -> DataError {
    DataError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// 8-bit RGB (3 channels) or RGBA (4 channels) PNG from floats in [0, 1] (clamped, rounded).
pub fn write_rgb_png(path: &Path, img: &ImageF32) -> Result<()> {
    assert!(
        img.channels == 3 || img.channels == 4,
        "write_rgb_png takes 3- or 4-channel images"
    );
    let bytes: Vec<u8> = img
        .data
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let png = encode_png(
        img.width,
        img.height,
        &bytes,
        if img.channels == 4 {
            image::ExtendedColorType::Rgba8
        } else {
            image::ExtendedColorType::Rgb8
        },
    )
    .map_err(|e| png_err(path, e))?;
    write_atomic(path, &png)
}

/// 8-bit grey PNG.
/// Writes 8-bit RGB bytes (3 per pixel) as a PNG, atomically.
pub fn write_rgb8_png(path: &Path, w: u32, h: u32, data: &[u8]) -> Result<()> {
    let png =
        encode_png(w, h, data, image::ExtendedColorType::Rgb8).map_err(|e| png_err(path, e))?;
    write_atomic(path, &png)
}

pub fn write_gray8_png(path: &Path, w: u32, h: u32, data: &[u8]) -> Result<()> {
    let png = encode_png(w, h, data, image::ExtendedColorType::L8).map_err(|e| png_err(path, e))?;
    write_atomic(path, &png)
}

/// 16-bit grey PNG (the encoder takes native-endian samples and stores them big-endian).
pub fn write_gray16_png(path: &Path, w: u32, h: u32, data: &[u16]) -> Result<()> {
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let png =
        encode_png(w, h, &bytes, image::ExtendedColorType::L16).map_err(|e| png_err(path, e))?;
    write_atomic(path, &png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trips() {
        let dir = std::env::temp_dir().join(format!("assist-imgio-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ids: Vec<u16> = (0..12).map(|i| i * 1000).collect();
        let p = dir.join("ids.png");
        write_gray16_png(&p, 4, 3, &ids).unwrap();
        assert_eq!(read_ids(&p).unwrap().data, ids);
        let d = read_depth_png(&p, 0.001).unwrap();
        assert!((d.data[5] - 5.0).abs() < 1e-6);
        let mut img = ImageF32::new(2, 2, 3);
        img.data[0] = 1.0;
        img.data[4] = 0.5;
        let p = dir.join("rgb.png");
        write_rgb_png(&p, &img).unwrap();
        let (back, alpha) = read_rgb(&p, [0.0; 3]).unwrap();
        assert!(alpha.is_none());
        assert_eq!(back.data[0], 1.0);
        assert!((back.data[4] - 128.0 / 255.0).abs() < 1e-6);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
