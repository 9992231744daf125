//! A node's surface from its field: the density is sampled on a grid over the node's box
//! (cubic cells in world units, `resolution` along the longest side; cells the node's
//! occupancy grid marks empty count as empty, as the renderer skips them). An object's
//! surface is where it is `opacity` opaque seen from outside (the least optical depth
//! over 26 directions, [`crate::hull`]); the background's, the level set `σ = density`.
//! Tunnels narrower than the closing radius are filled (the support under an object
//! sealing its base), what lies under the support is cut away, and the surface is
//! extracted by marching tetrahedra with one empty layer around the box (so it closes
//! where the object meets the box's faces). Each vertex
//! gets the colour the field shows when looked at head-on (along the inward normal, half
//! a cell inside the surface, with the average appearance code).
//!
//! Meshes are built in the node's frame — the box's axes, world units, scale applied —
//! and moved into the world by the node's rotation and translation when asked.

use assist_core::{DVec3, NodeSpace, SceneNode};
use assist_field::contraction::contract_to_unit;
use assist_field::{Field, Samples};
use assist_scene::{NeuralScene, NodeField};
use serde::{Deserialize, Serialize};

use crate::tetra::{Grid, extract};
use crate::{MeshError, NodeMesh};

/// Default grid cells along the longest side of a node's box.
pub const DEFAULT_RESOLUTION: u32 = 128;
/// Largest accepted resolution (a 1024³ grid takes 4 GiB of densities).
pub const MAX_RESOLUTION: u32 = 1024;
/// Default density level of the surface, in the field's units (per box diagonal of
/// canonical distance): twice the level at which the renderer's occupancy grid starts
/// sampling a cell (1% opacity per smallest marching step, 10.24), so the surface lies in
/// cells the renderer draws. Chosen with `assist bench mesh` (BENCHMARKS.md): higher
/// levels leave the seen surface inside the mesh.
pub const DEFAULT_DENSITY: f32 = 20.0;
/// Default triangle budget per node (a collision body for a simulator, detailed enough
/// for a render).
pub const DEFAULT_MAX_TRIANGLES: usize = 50_000;
/// Default smoothing of the density grid, in cells.
pub const DEFAULT_SMOOTH: f32 = 1.0;
/// Default share of the largest part's volume below which a part is dropped.
pub const DEFAULT_MIN_PART: f64 = 0.05;
/// Default radius, in cells, of the closing of the inside region before the surface is
/// taken: pinholes, grooves and tunnels narrower than about twice it (6 mm on a 10 cm
/// object at the default resolution) are where no view constrained the field, not
/// handles of the object (a mug's handle is far wider). Chosen with `assist bench mesh`
/// (BENCHMARKS.md): the true genus of desk's five objects, and the least Chamfer.
pub const DEFAULT_CLOSE: u32 = 4;
/// Default opacity of an object's surface, seen from outside along the best of 26 grid
/// directions (see [`crate::hull`]): where the object stops a tenth of the light. Chosen
/// with `assist bench mesh` (BENCHMARKS.md): deeper levels lie inside the seen surface.
pub const DEFAULT_OPACITY: f32 = 0.1;

/// Which frame a mesh's coordinates are in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MeshFrame {
    /// The scene's world frame: meshes of all nodes overlay the scene as it renders.
    #[default]
    World,
    /// The node's own frame (origin at its box centre, the box's axes, world units):
    /// a simulator places it at the node's pose.
    Node,
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct ExtractOptions {
    /// Grid cells along the longest side of the node's box.
    pub resolution: u32,
    /// Surface level in the field's density units.
    pub density: f32,
    /// Parts (connected pieces of the surface) enclosing less than this share of the
    /// largest part's volume are dropped, and so are cavities inside it; 0 keeps all.
    #[serde(default = "default_min_part")]
    pub min_part: f64,
    /// Standard deviation, in grid cells, of the Gaussian the density grid is smoothed
    /// with before the surface is taken (the finest hash-grid levels carry noise at the
    /// scale of a few cells that no training view resolves); 0 = none.
    #[serde(default = "default_smooth")]
    pub smooth: f32,
    /// Largest number of triangles per node: more are reduced by quadric-error edge
    /// collapse (shape and closedness kept); 0 = no limit.
    #[serde(default = "default_max_triangles")]
    pub max_triangles: usize,
    /// Radius, in cells, of the closing that fills narrow tunnels before the surface is
    /// taken (see [`DEFAULT_CLOSE`]); 0 = none.
    #[serde(default = "default_close")]
    pub close: u32,
    /// Objects' surfaces lie where the node is this opaque seen from outside (the least
    /// optical depth over 26 directions, see [`DEFAULT_OPACITY`]); 0 takes the level set
    /// of the density (`density`) instead, as the background's always is.
    #[serde(default = "default_opacity")]
    pub opacity: f32,
}

fn default_opacity() -> f32 {
    DEFAULT_OPACITY
}

fn default_close() -> u32 {
    DEFAULT_CLOSE
}

fn default_max_triangles() -> usize {
    DEFAULT_MAX_TRIANGLES
}

fn default_smooth() -> f32 {
    DEFAULT_SMOOTH
}

fn default_min_part() -> f64 {
    DEFAULT_MIN_PART
}

impl Default for ExtractOptions {
    fn default() -> Self {
        ExtractOptions {
            resolution: DEFAULT_RESOLUTION,
            density: DEFAULT_DENSITY,
            min_part: DEFAULT_MIN_PART,
            smooth: DEFAULT_SMOOTH,
            max_triangles: DEFAULT_MAX_TRIANGLES,
            close: DEFAULT_CLOSE,
            opacity: DEFAULT_OPACITY,
        }
    }
}

impl ExtractOptions {
    pub fn validate(&self) -> Result<(), MeshError> {
        if !(2..=MAX_RESOLUTION).contains(&self.resolution) {
            return Err(MeshError::Option {
                name: "resolution",
                message: format!(
                    "{} is outside 2..={MAX_RESOLUTION} (grid cells along the longest side)",
                    self.resolution
                ),
            });
        }
        if self.close > 8 {
            return Err(MeshError::Option {
                name: "close",
                message: format!("{} is outside 0..=8 (grid cells)", self.close),
            });
        }
        if !(0.0..1.0).contains(&self.opacity) {
            return Err(MeshError::Option {
                name: "opacity",
                message: format!(
                    "{} is outside 0..1 (0 = the density's level set; 0.5 = half opaque)",
                    self.opacity
                ),
            });
        }
        if !(0.0..=8.0).contains(&self.smooth) {
            return Err(MeshError::Option {
                name: "smooth",
                message: format!("{} is outside 0..=8 (grid cells)", self.smooth),
            });
        }
        if !(0.0..=1.0).contains(&self.min_part) {
            return Err(MeshError::Option {
                name: "min-part",
                message: format!(
                    "{} is outside 0..=1 (a share of the largest part)",
                    self.min_part
                ),
            });
        }
        if !(self.density.is_finite() && self.density > 0.0) {
            return Err(MeshError::Option {
                name: "density",
                message: format!("{} is not a positive density", self.density),
            });
        }
        Ok(())
    }
}

/// Where a point of the node's local box is in its field's [0, 1]³ (the inner box of a
/// contracted node is the middle half of it).
fn canonical(node: &SceneNode, nf: &NodeField, p_local: DVec3) -> [f32; 3] {
    let h = node.half_size;
    match nf.space {
        NodeSpace::Box => (p_local / (h * 2.0) + 0.5)
            .clamp(DVec3::ZERO, DVec3::ONE)
            .as_vec3()
            .to_array(),
        NodeSpace::Contracted => contract_to_unit((p_local / h).as_vec3().to_array()),
    }
}

/// The grid over a node's box: vertex counts per axis (without the empty layer) and the
/// local position of vertex `i` along each axis.
struct BoxGrid {
    cells: [usize; 3],
    half: DVec3,
}

impl BoxGrid {
    fn new(node: &SceneNode, resolution: u32) -> Self {
        let world = node.half_size * node.world_from_local.scale * 2.0;
        let cell = world.max_element() / resolution as f64;
        let cells = world
            .to_array()
            .map(|l| ((l / cell).ceil() as usize).max(2));
        BoxGrid {
            cells,
            half: node.half_size,
        }
    }
    /// Local position of (possibly fractional) grid coordinates counted from the empty
    /// layer (grid index 1 is the box's lower face).
    fn local(&self, g: [f32; 3]) -> DVec3 {
        DVec3::from_array([0, 1, 2].map(|a| {
            -self.half[a] + 2.0 * self.half[a] * (g[a] as f64 - 1.0) / self.cells[a] as f64
        }))
    }
    fn dims(&self) -> [usize; 3] {
        self.cells.map(|c| c + 3)
    }
}

/// The surface of node `index` of `scene` in the node's frame (see the module docs).
pub fn extract_node(
    scene: &NeuralScene,
    index: usize,
    opts: &ExtractOptions,
) -> Result<NodeMesh, MeshError> {
    extract_node_cut(scene, index, opts, None)
}

/// [`extract_node`], with nothing kept on the lower side of the plane `n·p = d` (`n`, `d`
/// in the node's frame, world units, scale applied): the support an object rests on,
/// so that its base is flat on it rather than reaching into it.
pub fn extract_node_cut(
    scene: &NeuralScene,
    index: usize,
    opts: &ExtractOptions,
    cut: Option<(DVec3, f64)>,
) -> Result<NodeMesh, MeshError> {
    opts.validate()?;
    let node = &scene.scene.nodes[index];
    let nf = scene.field_of(index);
    let grid = BoxGrid::new(node, opts.resolution);
    let dims = grid.dims();
    // Densities at the vertices inside the box (one empty layer around them).
    let mut pos: [Vec<f32>; 3] = Default::default();
    let mut at = Vec::new();
    for k in 1..dims[2] - 1 {
        for j in 1..dims[1] - 1 {
            for i in 1..dims[0] - 1 {
                let u = canonical(node, nf, grid.local([i as f32, j as f32, k as f32]));
                if nf.occupancy.is_occupied(u) {
                    for a in 0..3 {
                        pos[a].push(u[a]);
                    }
                    at.push(i + dims[0] * (j + dims[1] * k));
                }
            }
        }
    }
    let mut sigma = vec![0.0f32; at.len()];
    if !at.is_empty() {
        nf.field.density([&pos[0], &pos[1], &pos[2]], &mut sigma);
    }
    let mut density = vec![0.0f32; dims.iter().product()];
    for (&v, &s) in at.iter().zip(&sigma) {
        density[v] = s;
    }
    if opts.smooth > 0.0 {
        gaussian_blur(&mut density, dims, opts.smooth);
    }
    let border = |v: usize| {
        let c = [v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1])];
        (0..3).any(|a| c[a] == 0 || c[a] == dims[a] - 1)
    };
    // What lies under the support the object is cut at.
    let scale = node.world_from_local.scale;
    let below: Option<Vec<bool>> = cut.map(|(n, d)| {
        (0..density.len())
            .map(|v| {
                let g = [v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1])];
                n.dot(grid.local(g.map(|c| c as f32)) * scale) < d
            })
            .collect()
    });
    let cell = (node.half_size * scale * 2.0).max_element() / opts.resolution as f64;
    let opacity_surface = opts.opacity > 0.0 && nf.space == NodeSpace::Box && !node.is_background();
    // Log of the value the surface is a level set of; the empty layer stays empty,
    // whatever the blur spread into it.
    let (mut values, level) = if opacity_surface {
        for (v, s) in density.iter_mut().enumerate() {
            if border(v) {
                *s = 0.0;
            }
        }
        // Optical depth of one cell along each axis: world cell / scale = local length,
        // over the box diagonal in local units.
        let per_cell = [0, 1, 2].map(|a| (cell / scale[a]) as f32 / nf.unit);
        let tau = crate::hull::least_depth(&density, below.as_deref(), dims, per_cell);
        let values = tau.iter().map(|t| t.ln()).collect::<Vec<f32>>();
        (values, (-(1.0 - opts.opacity).ln()).ln())
    } else {
        let values = density
            .iter()
            .enumerate()
            .map(|(v, &s)| {
                if border(v) || s <= 0.0 {
                    f32::NEG_INFINITY
                } else {
                    s.ln()
                }
            })
            .collect();
        (values, opts.density.ln())
    };
    close_and_cut(
        &mut values,
        level,
        dims,
        opts.close as usize,
        below.as_deref(),
    );
    let surface = extract(
        &Grid {
            dims,
            values: &values,
        },
        level,
    );
    let positions: Vec<[f64; 3]> = surface
        .positions
        .iter()
        .map(|g| (grid.local(*g) * scale).to_array())
        .collect();
    let normals = vertex_normals(&positions, &surface.triangles);
    let colors = colors_at(node, nf, &positions, &normals, cell * 0.5);
    let mut mesh = NodeMesh {
        id: node.id,
        label: node.label.clone(),
        frame: MeshFrame::Node,
        positions,
        normals,
        colors,
        triangles: surface.triangles,
    };
    if opts.min_part > 0.0 {
        mesh.keep_main_parts(opts.min_part);
    }
    if opts.max_triangles > 0 {
        mesh.decimate(opts.max_triangles);
    }
    Ok(mesh)
}

/// Closes the inside region (`values` above `level`; cells just filled get a value a
/// little above the level, so the surface passes around them), the cells under the
/// support sealing the base, then empties those cells.
fn close_and_cut(
    values: &mut [f32],
    level: f32,
    dims: [usize; 3],
    radius: usize,
    below: Option<&[bool]>,
) {
    let inside: Vec<bool> = values.iter().map(|&v| v > level).collect();
    let closed = crate::close::close(&inside, below, dims, radius);
    for (v, (c, i)) in closed.iter().zip(&inside).enumerate() {
        if *c && !i {
            values[v] = level + 0.25;
        }
    }
    if let Some(below) = below {
        for (x, b) in values.iter_mut().zip(below) {
            if *b {
                *x = f32::NEG_INFINITY;
            }
        }
    }
}

/// Separable Gaussian blur (standard deviation `sigma` cells, truncated at 3σ, values
/// beyond the grid taken as 0) of a grid with x fastest.
fn gaussian_blur(values: &mut [f32], dims: [usize; 3], sigma: f32) {
    let r = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let stride = [1, dims[0], dims[0] * dims[1]];
    let mut line = Vec::new();
    for axis in 0..3 {
        let n = dims[axis];
        let (o1, o2) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        for b in 0..dims[o2] {
            for a in 0..dims[o1] {
                let base = a * stride[o1] + b * stride[o2];
                line.clear();
                line.extend((0..n).map(|i| values[base + i * stride[axis]]));
                for i in 0..n {
                    let mut acc = 0.0;
                    for (k, w) in kernel.iter().enumerate() {
                        let j = i as isize + k as isize - r;
                        if j >= 0 && (j as usize) < n {
                            acc += w * line[j as usize];
                        }
                    }
                    values[base + i * stride[axis]] = acc;
                }
            }
        }
    }
}

/// Area-weighted vertex normals (unit; zero for a vertex of degenerate triangles only).
pub(crate) fn vertex_normals(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| DVec3::from_array(positions[i as usize]));
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.iter()
        .map(|n| n.normalize_or_zero().as_vec3().to_array())
        .collect()
}

/// Colours of the field at node-frame points, looked at along `-normal` from `inset`
/// inside the surface (average appearance code).
pub(crate) fn colors_at(
    node: &SceneNode,
    nf: &NodeField,
    points: &[[f64; 3]],
    normals: &[[f32; 3]],
    inset: f64,
) -> Vec<[f32; 3]> {
    let scale = node.world_from_local.scale;
    let mut pos: [Vec<f32>; 3] = Default::default();
    let mut dir: [Vec<f32>; 3] = Default::default();
    for (q, n) in points.iter().zip(normals) {
        let n = DVec3::from_array(n.map(f64::from));
        let local = (DVec3::from_array(*q) - n * inset) / scale;
        let u = canonical(node, nf, local);
        // A direction of the node frame in local units is divided by the scale.
        let d = (-n / scale).normalize_or(DVec3::NEG_Z).as_vec3().to_array();
        for a in 0..3 {
            pos[a].push(u[a]);
            dir[a].push(d[a]);
        }
    }
    query_colors(&nf.field, &pos, &dir)
}

fn query_colors(field: &Field, pos: &[Vec<f32>; 3], dir: &[Vec<f32>; 3]) -> Vec<[f32; 3]> {
    let n = pos[0].len();
    let mut sigma = vec![0.0f32; n];
    let mut rgb = vec![0.0f32; 3 * n];
    if n > 0 {
        let s = Samples {
            pos: [&pos[0], &pos[1], &pos[2]],
            dir: [&dir[0], &dir[1], &dir[2]],
            image: &[],
        };
        field.forward(&s, &mut sigma, &mut rgb);
    }
    rgb.chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]].map(|v| v.clamp(0.0, 1.0)))
        .collect()
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::sync::Arc;

    use assist_core::{DMat3, DQuat, DVec3, Obb, Scene, SceneNode, Similarity3};
    use assist_field::{Field, OccupancyGrid};
    use assist_scene::{NeuralScene, NodeField};

    use super::*;
    use crate::node_pose;

    /// One object node, a box of half size `half` posed by `pose`, of constant density
    /// `sigma` and colour, with an occupancy grid of 8³ whose cells `occupied` keeps.
    fn scene(
        half: DVec3,
        pose: Similarity3,
        sigma: f32,
        occupied: impl Fn([usize; 3]) -> bool,
    ) -> NeuralScene {
        let mut node = SceneNode::from_obb(
            7,
            "green box",
            "box",
            &Obb::new(DVec3::ZERO, half * 2.0, DMat3::IDENTITY),
        );
        node.world_from_local = pose;
        let field = Field::constant(sigma, [0.2, 0.7, 0.4], false, 1).unwrap();
        let mut occ = OccupancyGrid::new(8);
        let empty: Vec<bool> = (0..512)
            .map(|c| !occupied([c % 8, c / 8 % 8, c / 64]))
            .collect();
        occ.set_empty(&empty);
        let mut fields = BTreeMap::new();
        fields.insert(
            "box".to_string(),
            Arc::new(NodeField::new(field, occ, half)),
        );
        NeuralScene {
            scene: Scene::with_nodes(vec![node], DVec3::Z),
            fields,
        }
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|i| (a[i] - b[i]).abs() <= tol)
    }

    #[test]
    fn a_dense_box_gives_its_own_closed_box_scaled_and_posed() {
        let half = DVec3::new(0.1, 0.2, 0.05);
        let pose = Similarity3::new(
            DQuat::from_rotation_z(0.5),
            DVec3::new(1.0, -2.0, 0.3),
            DVec3::new(2.0, 2.0, 2.0),
        )
        .unwrap();
        let s = scene(half, pose, 1000.0, |_| true);
        let opts = ExtractOptions {
            resolution: 40,
            density: 69.3,
            min_part: 0.05,
            smooth: 0.0,
            max_triangles: 0,
            close: 0,
            opacity: 0.0,
        };
        let m = extract_node(&s, 0, &opts).unwrap();
        assert!(m.is_closed());
        // In the node frame: the box scaled (half sizes 0.2, 0.4, 0.1), within a
        // thousandth of a cell (the empty layer cuts at the face).
        let (lo, hi) = m.bounds().unwrap();
        let cell = 0.8 / 40.0;
        assert!(close(hi, [0.2, 0.4, 0.1], cell * 0.01), "{hi:?}");
        assert!(close(lo, [-0.2, -0.4, -0.1], cell * 0.01), "{lo:?}");
        let mp = m.mass_properties(1.0);
        assert!((mp.volume - 0.4 * 0.8 * 0.2).abs() < 1e-3, "{}", mp.volume);
        // Colours of the constant field.
        for c in &m.colors {
            assert!(close(c.map(f64::from), [0.2, 0.7, 0.4], 1e-3), "{c:?}");
        }
        // In the world: the centre at the translation, the box's x axis turned 0.5 rad.
        let w = m.clone().to_world(&node_pose(&s, 7).unwrap());
        let c = w.mass_properties(1.0).center;
        assert!(close(c, [1.0, -2.0, 0.3], 1e-6), "{c:?}");
        let far = w
            .positions
            .iter()
            .map(|p| DVec3::from_array(*p) - DVec3::new(1.0, -2.0, 0.3))
            .max_by(|a, b| {
                a.dot(DVec3::new(0.5f64.cos(), 0.5f64.sin(), 0.0))
                    .total_cmp(&b.dot(DVec3::new(0.5f64.cos(), 0.5f64.sin(), 0.0)))
            })
            .unwrap();
        assert!((far.dot(DVec3::new(0.5f64.cos(), 0.5f64.sin(), 0.0)) - 0.2).abs() < 1e-3);
        // Normals point out of the box.
        for (p, n) in w.positions.iter().zip(&w.normals) {
            let out = DVec3::from_array(*p) - DVec3::new(1.0, -2.0, 0.3);
            assert!(out.dot(DVec3::from_array(n.map(f64::from))) > 0.0);
        }
    }

    #[test]
    fn empty_cells_leave_no_surface_and_faint_matter_is_solid_by_its_opacity() {
        let half = DVec3::splat(0.5);
        // Only the lower half (z cells 0..4) occupied: the mesh stops at z = 0.
        let s = scene(half, Similarity3::IDENTITY, 1000.0, |c| c[2] < 4);
        let m = extract_node(
            &s,
            0,
            &ExtractOptions {
                resolution: 32,
                density: 69.3,
                min_part: 0.05,
                smooth: 0.0,
                max_triangles: 0,
                close: 0,
                opacity: 0.0,
            },
        )
        .unwrap();
        assert!(m.is_closed());
        let (lo, hi) = m.bounds().unwrap();
        assert!(hi[2] < 0.0 && hi[2] > -1.0 / 32.0 - 1e-9, "{hi:?}");
        assert!((lo[2] + 0.5).abs() < 1e-3);
        // A density below the level: nothing.
        let thin = scene(half, Similarity3::IDENTITY, 10.0, |_| true);
        let level_set = ExtractOptions {
            opacity: 0.0,
            ..Default::default()
        };
        let m = extract_node(&thin, 0, &level_set).unwrap();
        assert!(m.triangles.is_empty());
        // Seen by its opacity, the same faint matter is a solid: 10 per diagonal adds
        // 0.0451 of optical depth per cell (1/128 of a unit box, √3 its diagonal; half
        // of that at the face, by the trapezoid from the empty layer), so depths are
        // 0.0226, 0.0677, 0.1128 at the face and the next two vertices: 10% opacity
        // (depth 0.1054) lies 1 + (ln 0.1054 − ln 0.0677) / (ln 0.1128 − ln 0.0677) =
        // 1.866 cells in from each face.
        let unsmoothed = ExtractOptions {
            smooth: 0.0,
            ..Default::default()
        };
        let m = extract_node(&thin, 0, &unsmoothed).unwrap();
        assert!(m.is_closed());
        let (lo, hi) = m.bounds().unwrap();
        let inset = 0.5 - 1.866 / 128.0;
        for a in 0..3 {
            assert!((hi[a] - inset).abs() < 1e-4, "{hi:?}");
            assert!((lo[a] + inset).abs() < 1e-4, "{lo:?}");
        }
        // Options out of range are refused by name.
        let e = extract_node(
            &thin,
            0,
            &ExtractOptions {
                resolution: 1,
                density: 1.0,
                min_part: 0.0,
                smooth: 0.0,
                max_triangles: 0,
                close: 0,
                opacity: 0.0,
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("resolution"));
    }
}
