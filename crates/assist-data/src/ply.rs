//! The vertex positions of a PLY point cloud (nerfstudio's `sparse_pc.ply`, which
//! `ns-process-data` and `assist process` write): ASCII or binary little-endian, any
//! scalar property types, positions from the `x`, `y`, `z` properties of the `vertex`
//! element (other elements must come after it).

use std::path::Path;

use assist_core::DVec3;

use crate::error::{DataError, Result};

fn size_of(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

fn value(t: &str, b: &[u8]) -> f64 {
    match t {
        "char" | "int8" => f64::from(b[0] as i8),
        "uchar" | "uint8" => f64::from(b[0]),
        "short" | "int16" => f64::from(i16::from_le_bytes([b[0], b[1]])),
        "ushort" | "uint16" => f64::from(u16::from_le_bytes([b[0], b[1]])),
        "int" | "int32" => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        "uint" | "uint32" => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        "float" | "float32" => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        _ => f64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])),
    }
}

/// The positions of the `vertex` element of the PLY file at `path`.
pub fn read_points(path: &Path) -> Result<Vec<DVec3>> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let bad = |m: String| DataError::field(path, "header", m);
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| bad("no `end_header` line: not a PLY file".into()))?;
    let header = String::from_utf8_lossy(&bytes[..end]);
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(bad("does not start with `ply`".into()));
    }
    let (mut format, mut count, mut props) = (None, None, Vec::new());
    let mut in_vertex = false;
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, n] => {
                if count.is_some() && !in_vertex {
                    continue;
                }
                in_vertex = *name == "vertex";
                if in_vertex {
                    count = Some(
                        n.parse::<usize>()
                            .map_err(|_| bad(format!("bad count {n:?}")))?,
                    );
                } else if count.is_none() {
                    return Err(bad(format!("element {name:?} comes before `vertex`")));
                }
            }
            ["property", "list", ..] if in_vertex => {
                return Err(bad("a list property in `vertex` is not supported".into()));
            }
            ["property", t, name] if in_vertex => {
                let size = size_of(t).ok_or_else(|| bad(format!("unknown property type {t:?}")))?;
                props.push((t.to_string(), name.to_string(), size));
            }
            _ => {}
        }
    }
    let count = count.ok_or_else(|| bad("no `vertex` element".into()))?;
    let axis = |n: &str| {
        props
            .iter()
            .position(|p| p.1 == n)
            .ok_or_else(|| bad(format!("the vertex element has no `{n}` property")))
    };
    let xyz = [axis("x")?, axis("y")?, axis("z")?];
    let body = &bytes[end + 11..];
    let mut points = Vec::with_capacity(count);
    match format.as_deref() {
        Some("ascii") => {
            let text = String::from_utf8_lossy(body);
            for (k, line) in text.lines().take(count).enumerate() {
                let v: Vec<f64> = line
                    .split_whitespace()
                    .map(|s| s.parse::<f64>())
                    .collect::<std::result::Result<_, _>>()
                    .map_err(|_| {
                        DataError::field(path, format!("vertex {k}"), "expected numbers")
                    })?;
                if v.len() < props.len() {
                    return Err(DataError::field(
                        path,
                        format!("vertex {k}"),
                        "too few values",
                    ));
                }
                points.push(DVec3::new(v[xyz[0]], v[xyz[1]], v[xyz[2]]));
            }
        }
        Some("binary_little_endian") => {
            let stride: usize = props.iter().map(|p| p.2).sum();
            let offsets: Vec<usize> = props
                .iter()
                .scan(0, |o, p| {
                    let at = *o;
                    *o += p.2;
                    Some(at)
                })
                .collect();
            for r in body.chunks_exact(stride).take(count) {
                let get = |i: usize| value(&props[i].0, &r[offsets[i]..]);
                points.push(DVec3::new(get(xyz[0]), get(xyz[1]), get(xyz[2])));
            }
        }
        other => {
            return Err(bad(format!(
                "format {other:?}: expected ascii or binary_little_endian"
            )));
        }
    }
    if points.len() != count {
        return Err(DataError::field(
            path,
            "vertex",
            format!(
                "the header declares {count} vertices, the file holds {}",
                points.len()
            ),
        ));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_points_read_back() {
        let dir = std::env::temp_dir().join(format!("assist-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ascii = dir.join("a.ply");
        std::fs::write(
            &ascii,
            "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nend_header\n1 2 3 255\n-4 5.5 6 0\n",
        )
        .unwrap();
        let p = read_points(&ascii).unwrap();
        assert_eq!(
            p,
            vec![DVec3::new(1.0, 2.0, 3.0), DVec3::new(-4.0, 5.5, 6.0)]
        );
        let bin = dir.join("b.ply");
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty uchar red\nproperty double x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        b.push(7);
        b.extend(0.25f64.to_le_bytes());
        b.extend((-1.5f32).to_le_bytes());
        b.extend(2.0f32.to_le_bytes());
        std::fs::write(&bin, b).unwrap();
        assert_eq!(
            read_points(&bin).unwrap(),
            vec![DVec3::new(0.25, -1.5, 2.0)]
        );
        // Truncated: named.
        std::fs::write(&ascii, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").unwrap();
        assert!(
            read_points(&ascii)
                .unwrap_err()
                .to_string()
                .contains("declares 3")
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
