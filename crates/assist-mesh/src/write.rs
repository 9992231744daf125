//! Mesh and point-cloud files: binary PLY (positions, normals, 8-bit colours; faces for a
//! mesh), Wavefront OBJ (vertex colours after the position, as MeshLab, trimesh and
//! Blender read them; normals) and binary glTF 2.0 (GLB: one mesh with POSITION, NORMAL,
//! COLOR_0 and 32-bit indices). Coordinates are written as they are (glTF viewers assume
//! +y up; a scene's up is recorded beside the files).

use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::{MeshError, NodeMesh, PointCloud};

/// The file formats `assist export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    Ply,
    Obj,
    Glb,
    /// A point cloud (PLY vertices with normals and colours, no faces).
    Points,
}

impl Format {
    pub fn extension(self) -> &'static str {
        match self {
            Format::Ply | Format::Points => "ply",
            Format::Obj => "obj",
            Format::Glb => "glb",
        }
    }
    pub fn parse(s: &str) -> Option<Format> {
        match s.to_ascii_lowercase().as_str() {
            "ply" => Some(Format::Ply),
            "obj" => Some(Format::Obj),
            "glb" | "gltf" => Some(Format::Glb),
            "points" | "pointcloud" | "point-cloud" => Some(Format::Points),
            _ => None,
        }
    }
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> MeshError + '_ {
    move |source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn to_u8(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn ply_header(vertices: usize, faces: Option<usize>, comment: &str) -> String {
    let mut h = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {vertices}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n"
    );
    if let Some(f) = faces {
        h += &format!("element face {f}\nproperty list uchar int vertex_indices\n");
    }
    h + "end_header\n"
}

fn ply_vertices(buf: &mut Vec<u8>, p: &[[f64; 3]], n: &[[f32; 3]], c: &[[f32; 3]]) {
    for i in 0..p.len() {
        for v in p[i] {
            buf.extend_from_slice(&(v as f32).to_le_bytes());
        }
        for v in n[i] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend(c[i].map(to_u8));
    }
}

/// A mesh as binary PLY.
pub fn mesh_ply(m: &NodeMesh) -> Vec<u8> {
    let comment = format!("assist node {} {}", m.id, m.label.replace('\n', " "));
    let mut buf = ply_header(m.positions.len(), Some(m.triangles.len()), &comment).into_bytes();
    ply_vertices(&mut buf, &m.positions, &m.normals, &m.colors);
    for t in &m.triangles {
        buf.push(3);
        for v in t {
            buf.extend_from_slice(&(*v as i32).to_le_bytes());
        }
    }
    buf
}

/// A point cloud as binary PLY.
pub fn points_ply(p: &PointCloud, comment: &str) -> Vec<u8> {
    let mut buf = ply_header(p.positions.len(), None, &comment.replace('\n', " ")).into_bytes();
    ply_vertices(&mut buf, &p.positions, &p.normals, &p.colors);
    buf
}

/// A mesh as OBJ text: `v x y z r g b`, `vn`, `f a//a b//b c//c` (1-based).
pub fn mesh_obj(m: &NodeMesh) -> Vec<u8> {
    let mut s = String::with_capacity(m.positions.len() * 80 + m.triangles.len() * 40);
    s += &format!(
        "# assist node {} {}\n# {} vertices, {} triangles\no {}\n",
        m.id,
        m.label.replace('\n', " "),
        m.positions.len(),
        m.triangles.len(),
        obj_name(&m.label, m.id)
    );
    use std::fmt::Write as _;
    for (p, c) in m.positions.iter().zip(&m.colors) {
        let _ = writeln!(
            s,
            "v {} {} {} {:.4} {:.4} {:.4}",
            p[0] as f32, p[1] as f32, p[2] as f32, c[0], c[1], c[2]
        );
    }
    for n in &m.normals {
        let _ = writeln!(s, "vn {:.5} {:.5} {:.5}", n[0], n[1], n[2]);
    }
    for t in &m.triangles {
        let [a, b, c] = t.map(|v| v + 1);
        let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
    }
    s.into_bytes()
}

/// A name made of letters, digits and `_` (for OBJ objects, glTF nodes and simulator
/// bodies).
pub fn obj_name(label: &str, id: u16) -> String {
    let clean: String = label
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let clean = clean.trim_matches('_');
    if clean.is_empty() {
        format!("node_{id}")
    } else {
        format!("node_{id}_{clean}")
    }
}

/// A mesh as binary glTF 2.0 (GLB).
pub fn mesh_glb(m: &NodeMesh) -> Vec<u8> {
    let nv = m.positions.len();
    let mut bin = Vec::with_capacity(nv * 36 + m.triangles.len() * 12);
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &m.positions {
        for a in 0..3 {
            let v = p[a] as f32;
            lo[a] = lo[a].min(v);
            hi[a] = hi[a].max(v);
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let normals_at = bin.len();
    for n in &m.normals {
        for v in n {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let colors_at = bin.len();
    for c in &m.colors {
        for v in c {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let indices_at = bin.len();
    for t in &m.triangles {
        for v in t {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let view = |offset: usize, length: usize, target: u32| json!({"buffer": 0, "byteOffset": offset, "byteLength": length, "target": target});
    let (lo, hi) = if nv == 0 {
        ([0.0; 3], [0.0; 3])
    } else {
        (lo, hi)
    };
    let name = obj_name(&m.label, m.id);
    let doc = json!({
        "asset": {"version": "2.0", "generator": "assist"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "COLOR_0": 2},
            "indices": 3,
            "mode": 4
        }]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            view(0, normals_at, 34962),
            view(normals_at, colors_at - normals_at, 34962),
            view(colors_at, indices_at - colors_at, 34962),
            view(indices_at, bin.len() - indices_at, 34963),
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": nv, "type": "VEC3", "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": nv, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": nv, "type": "VEC3"},
            {"bufferView": 3, "componentType": 5125, "count": m.triangles.len() * 3, "type": "SCALAR"}
        ],
    });
    let mut js = serde_json::to_vec(&doc).unwrap_or_default();
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Writes `bytes` to `path` (created or replaced).
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), MeshError> {
    let mut f = std::fs::File::create(path).map_err(io(path))?;
    f.write_all(bytes).map_err(io(path))?;
    f.sync_all().map_err(io(path))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MeshFrame;

    fn tetrahedron() -> NodeMesh {
        NodeMesh {
            id: 3,
            label: "red mug".into(),
            frame: MeshFrame::World,
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            colors: vec![
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.5, 0.5, 0.5],
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn ply_sizes_add_up() {
        let m = tetrahedron();
        let b = mesh_ply(&m);
        let head = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(b.len() - head, 4 * (24 + 3) + 4 * 13);
        assert!(String::from_utf8_lossy(&b[..head]).contains("element face 4"));
    }

    #[test]
    fn obj_has_coloured_vertices_and_one_based_faces() {
        let s = String::from_utf8(mesh_obj(&tetrahedron())).unwrap();
        assert!(s.contains("v 1 0 0 0.0000 1.0000 0.0000"), "{s}");
        assert!(s.contains("f 1//1 3//3 2//2"));
        assert!(s.contains("o node_3_red_mug"));
    }

    #[test]
    fn glb_chunks_are_aligned_and_the_json_parses() {
        let b = mesh_glb(&tetrahedron());
        assert_eq!(&b[..4], b"glTF");
        let total = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
        assert_eq!(total, b.len());
        let jl = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
        assert_eq!(jl % 4, 0);
        let doc: serde_json::Value = serde_json::from_slice(&b[20..20 + jl]).unwrap();
        assert_eq!(doc["accessors"][3]["count"], 12);
        let bl = u32::from_le_bytes(b[20 + jl..24 + jl].try_into().unwrap()) as usize;
        assert_eq!(
            bl,
            doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize
        );
        assert_eq!(20 + jl + 8 + bl, b.len());
    }
}
