//! assist-mesh: what a scene node is as geometry, for simulators and 3D tools.
//!
//! [`extract_node`] turns a node's radiance field into a closed, coloured triangle mesh
//! (marching tetrahedra on its density, [`tetra`]); [`NodeMesh::sample_points`] gives a
//! point cloud on it; [`write`] saves meshes as PLY, OBJ or GLB and point clouds as PLY;
//! [`mass_properties`] gives volume, centre of mass and inertia of a closed mesh; [`sim`]
//! writes a MuJoCo MJCF or a URDF model that places the meshes at the nodes' poses;
//! [`chamfer`] measures a mesh against points (e.g. ground-truth depth back-projected).

#![forbid(unsafe_code)]

pub mod chamfer;
mod close;
mod decimate;
mod extract;
mod hull;
mod mass;
pub mod pad;
mod parts;
pub use parts::Topology;
pub mod sim;
pub mod tetra;
pub mod write;

use assist_core::{DVec3, InstanceId, Rng, Similarity3};
use assist_scene::NeuralScene;

pub use extract::{
    DEFAULT_CLOSE, DEFAULT_DENSITY, DEFAULT_MAX_TRIANGLES, DEFAULT_MIN_PART, DEFAULT_OPACITY,
    DEFAULT_RESOLUTION, DEFAULT_SMOOTH, ExtractOptions, MAX_RESOLUTION, MeshFrame, extract_node,
    extract_node_cut,
};
pub use mass::{MassProperties, mass_properties};

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// An extraction or export option out of range.
    #[error("{name}: {message}")]
    Option { name: &'static str, message: String },
    #[error("writing {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
}

/// One node's surface: positions in world units (in the node's frame or the world's, as
/// `frame` says), unit normals, colours in [0, 1] and outward-wound triangles.
#[derive(Debug, Clone)]
pub struct NodeMesh {
    pub id: InstanceId,
    pub label: String,
    pub frame: MeshFrame,
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Points on a surface with their normals and colours.
#[derive(Debug, Clone, Default)]
pub struct PointCloud {
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
}

/// The rigid part of a node's pose (rotation and translation; the scale is in the node
/// frame's coordinates already).
pub fn node_pose(scene: &NeuralScene, id: InstanceId) -> Option<Similarity3> {
    let n = scene.scene.node(id)?;
    let p = &n.world_from_local;
    Some(Similarity3::from_rotation_translation(
        p.rotation_matrix(),
        p.translation,
    ))
}

impl NodeMesh {
    /// The mesh in the world frame (`pose`: the node's rotation and translation, as
    /// [`node_pose`] gives it). A mesh already in the world is returned as it is.
    pub fn to_world(mut self, pose: &Similarity3) -> NodeMesh {
        if self.frame == MeshFrame::World {
            return self;
        }
        for p in &mut self.positions {
            *p = pose.transform_point(DVec3::from_array(*p)).to_array();
        }
        for n in &mut self.normals {
            let v = pose.rotation * DVec3::from_array(n.map(f64::from));
            *n = v.as_vec3().to_array();
        }
        self.frame = MeshFrame::World;
        self
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.triangles.iter().map(|t| self.triangle_area(t)).sum()
    }

    fn triangle_area(&self, t: &[u32; 3]) -> f64 {
        let [a, b, c] = t.map(|i| DVec3::from_array(self.positions[i as usize]));
        (b - a).cross(c - a).length() * 0.5
    }

    /// Axis-aligned bounds of the positions (`None` for an empty mesh).
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| {
            (
                [0, 1, 2].map(|a| lo[a].min(p[a])),
                [0, 1, 2].map(|a| hi[a].max(p[a])),
            )
        }))
    }

    /// `count` points spread uniformly over the surface by area (deterministic for a
    /// seed), each with its triangle's normal and the colour interpolated from its
    /// vertices.
    pub fn sample_points(&self, count: usize, seed: u64) -> PointCloud {
        let mut out = PointCloud::default();
        if self.triangles.is_empty() || count == 0 {
            return out;
        }
        let mut cum = Vec::with_capacity(self.triangles.len());
        let mut total = 0.0;
        for t in &self.triangles {
            total += self.triangle_area(t);
            cum.push(total);
        }
        let mut rng = Rng::new(seed);
        for _ in 0..count {
            let x = rng.f64() * total;
            let k = cum
                .partition_point(|&c| c < x)
                .min(self.triangles.len() - 1);
            let t = self.triangles[k];
            let (mut r1, mut r2) = (rng.f64(), rng.f64());
            if r1 + r2 > 1.0 {
                (r1, r2) = (1.0 - r1, 1.0 - r2);
            }
            let w = [1.0 - r1 - r2, r1, r2];
            let [a, b, c] = t.map(|i| DVec3::from_array(self.positions[i as usize]));
            let p = a * w[0] + b * w[1] + c * w[2];
            let n = (b - a).cross(c - a).normalize_or_zero();
            let col = [0, 1, 2].map(|ch| {
                (0..3)
                    .map(|v| w[v] as f32 * self.colors[t[v] as usize][ch])
                    .sum::<f32>()
            });
            out.positions.push(p.to_array());
            out.normals.push(n.as_vec3().to_array());
            out.colors.push(col);
        }
        out
    }

    /// Volume, centre of mass and inertia (about the centre) for a uniform `density`,
    /// in the mesh's units.
    pub fn mass_properties(&self, density: f64) -> MassProperties {
        mass_properties(&self.positions, &self.triangles, density)
    }

    /// Whether every edge is shared by exactly two triangles, once in each direction
    /// (closed and consistently oriented).
    pub fn is_closed(&self) -> bool {
        let mut directed = std::collections::HashMap::new();
        for t in &self.triangles {
            for e in 0..3 {
                *directed.entry((t[e], t[(e + 1) % 3])).or_insert(0u32) += 1;
            }
        }
        directed
            .iter()
            .all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
    }
}
