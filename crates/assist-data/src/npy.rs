//! Minimal NumPy `.npy` reading (little-endian f4/f8, C order) and writing (f32), for LLFF's
//! `poses_bounds.npy` and float depth outputs.

use std::path::Path;

use crate::error::{DataError, Result};

/// A 2-D (or 1-D, 3-D…) array of f64 with its shape.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    parse_npy(path, &bytes)
}

pub fn parse_npy(path: &Path, b: &[u8]) -> Result<NpyArray> {
    let bad = |m: String| DataError::field(path, "npy header", m);
    if b.len() < 10 || &b[..6] != b"\x93NUMPY" {
        return Err(bad("not a NumPy .npy file (magic bytes missing)".into()));
    }
    let major = b[6];
    let (hlen, hstart) = match major {
        1 => (u16::from_le_bytes([b[8], b[9]]) as usize, 10),
        2 | 3 => {
            if b.len() < 12 {
                return Err(DataError::Truncated {
                    path: path.into(),
                    message: "header length".into(),
                });
            }
            (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
        }
        v => return Err(bad(format!("unsupported .npy version {v}"))),
    };
    if b.len() < hstart + hlen {
        return Err(DataError::Truncated {
            path: path.into(),
            message: "the header is cut short".into(),
        });
    }
    let header = std::str::from_utf8(&b[hstart..hstart + hlen])
        .map_err(|_| bad("header is not text".into()))?;
    let descr = dict_value(header, "descr").ok_or_else(|| bad("no 'descr' in header".into()))?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let fortran = dict_value(header, "fortran_order")
        .map(|v| v.starts_with("True"))
        .unwrap_or(false);
    if fortran {
        return Err(bad(
            "Fortran-ordered arrays are not supported; expected C order".into(),
        ));
    }
    let shape_txt =
        dict_value(header, "shape").ok_or_else(|| bad("no 'shape' in header".into()))?;
    let shape: Vec<usize> = shape_txt
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| bad(format!("bad shape {shape_txt}")))
        })
        .collect::<Result<_>>()?;
    let count: usize = shape.iter().product();
    let body = &b[hstart + hlen..];
    let width = match descr {
        "<f8" | "f8" => 8,
        "<f4" | "f4" => 4,
        d => {
            return Err(bad(format!(
                "dtype {d}: expected little-endian float32 or float64 ('<f4' or '<f8')"
            )));
        }
    };
    if body.len() < count * width {
        return Err(DataError::Truncated {
            path: path.into(),
            message: format!(
                "shape {shape:?} needs {} bytes of data, the file has {}",
                count * width,
                body.len()
            ),
        });
    }
    let data = if width == 8 {
        body.chunks_exact(8)
            .take(count)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    } else {
        body.chunks_exact(4)
            .take(count)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
            .collect()
    };
    Ok(NpyArray { shape, data })
}

/// The text after `'key':` up to the next top-level comma (shape tuples kept whole).
fn dict_value<'h>(header: &'h str, key: &str) -> Option<&'h str> {
    let k1 = format!("'{key}':");
    let start = header.find(&k1)? + k1.len();
    let rest = header[start..].trim_start();
    if rest.starts_with('(') {
        let end = rest.find(')')?;
        return Some(&rest[..=end]);
    }
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    Some(rest[..end].trim())
}

/// Encodes a float32 array as `.npy` bytes (version 1.0, C order).
pub fn encode_npy_f32(shape: &[usize], data: &[f32]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_txt = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_txt}, }}");
    let total = 10 + header.len() + 1;
    let pad = (64 - total % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_f32() {
        let data: Vec<f32> = (0..12).map(|i| i as f32 * 0.5).collect();
        let bytes = encode_npy_f32(&[3, 4], &data);
        // The data starts on a 64-byte boundary, as NumPy writes it.
        assert_eq!((bytes.len() - 48) % 64, 0);
        let a = parse_npy(Path::new("x.npy"), &bytes).unwrap();
        assert_eq!(a.shape, vec![3, 4]);
        assert_eq!(a.data, data.iter().map(|&v| v as f64).collect::<Vec<_>>());
    }

    #[test]
    fn truncated_is_an_error() {
        let bytes = encode_npy_f32(&[3, 4], &[0.0; 12]);
        let e = parse_npy(Path::new("x.npy"), &bytes[..bytes.len() - 5])
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.npy") && e.contains("truncated"), "{e}");
    }
}
