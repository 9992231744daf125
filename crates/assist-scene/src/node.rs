//! A node's forward model as the renderer uses it: the field, its occupancy grid and the
//! marching step in canonical units; and `NeuralScene`, a scene with its fields.

use std::collections::BTreeMap;
use std::sync::Arc;

use assist_core::{DVec3, NodeSpace, Scene, SceneNode};
use assist_field::{Field, OccupancyGrid, ShadeGrid};

/// Default step growth with distance (instant-NGP's cone angle for large scenes).
pub const DEFAULT_CONE: f32 = 1.0 / 256.0;

/// Default number of marching steps along the canonical box's diagonal.
pub const STEPS_PER_DIAGONAL: f32 = 1024.0;

#[derive(Debug, Clone)]
pub struct NodeField {
    pub field: Field,
    pub occupancy: OccupancyGrid,
    /// Smallest marching step in local distance units.
    pub step: f32,
    /// Length of the box diagonal in local units: density is integrated over canonical
    /// distance measured in box diagonals, so densities have the same scale for a 5 cm
    /// mug and a 5 m room (as a scene normalised to a unit cube would have).
    pub unit: f32,
    /// Step growth with distance from the camera (`dt = max(step, cone · t)`); 0 = fixed.
    pub cone: f32,
    /// The box alone, or the box plus contracted space beyond it.
    pub space: NodeSpace,
    /// Contracted nodes: the step beyond the box, in contracted units (half an occupancy
    /// cell).
    pub contracted_step: f32,
    /// An object's shadow on the background (multiplies the background's colour around
    /// the object; see [`ShadeGrid`]). `None`: the node casts none.
    pub shade: Option<ShadeGrid>,
    /// A contracted node's proposal: its rays' samples are drawn from the proposal
    /// field's weights along the march instead of taken at every step. `None`: every step
    /// (and always for a bounded node).
    pub proposal: Option<assist_field::Proposal>,
    /// The file these weights were read from, if any: a scene saved with the same bytes
    /// links that file instead of writing them again (checked byte for byte, so weights
    /// changed since are written).
    pub origin: Option<std::path::PathBuf>,
}

impl NodeField {
    /// A field for a box with half extents `half_size`: marching step from the diagonal,
    /// occupancy threshold such that a skipped cell has opacity below 1% per smallest step.
    pub fn new(field: Field, occupancy: OccupancyGrid, half_size: DVec3) -> Self {
        Self::with_space(field, occupancy, half_size, NodeSpace::Box)
    }

    /// A field over `space` (for a contracted node, `half_size` is the inner box). The
    /// occupancy grid of a contracted node weighs each cell by how long its steps are.
    pub fn with_space(
        field: Field,
        occupancy: OccupancyGrid,
        half_size: DVec3,
        space: NodeSpace,
    ) -> Self {
        let diag = (half_size * 2.0).length() as f32;
        let step = diag / STEPS_PER_DIAGONAL;
        let mut occupancy = occupancy;
        occupancy.threshold = 0.01 * STEPS_PER_DIAGONAL;
        // Half an occupancy cell of the contracted space ([−2, 2], `res` cells).
        let contracted_step = 2.0 / occupancy.res as f32;
        match space {
            NodeSpace::Box => occupancy.step_factor.clear(),
            NodeSpace::Contracted => {
                let h = half_size.min_element() as f32;
                occupancy.set_step_factor(|p| {
                    assist_field::contraction::cell_step_factor(p, h, step, contracted_step)
                });
            }
        }
        NodeField {
            field,
            occupancy,
            step,
            unit: diag,
            cone: DEFAULT_CONE,
            space,
            contracted_step,
            shade: None,
            proposal: None,
            origin: None,
        }
    }
}

/// A scene and the fields its nodes refer to (replicas share one `Arc`).
#[derive(Debug, Clone)]
pub struct NeuralScene {
    pub scene: Scene,
    pub fields: BTreeMap<String, Arc<NodeField>>,
}

impl NeuralScene {
    /// The field of node `index` (every node's key is checked on load).
    pub fn field_of(&self, index: usize) -> &NodeField {
        &self.fields[&self.scene.nodes[index].field]
    }
}

impl NeuralScene {
    /// Density of node `index`'s field at world points, per world unit of length (so the
    /// opacity of a short world segment `l` at `p` is `1 − exp(−σ·l)`); 0 outside the
    /// node's box (or, for a contracted node, beyond its far shell).
    pub fn density_at_world(&self, index: usize, points: &[DVec3]) -> Vec<f32> {
        self.query_at_world(index, points, None).0
    }

    /// Density (as [`density_at_world`](Self::density_at_world)) and, when `dirs` (unit
    /// world directions, one per point) are given, colour of node `index`'s field at
    /// world points, with the average appearance code; black where the density is 0
    /// (or without `dirs`).
    pub fn query_at_world(
        &self,
        index: usize,
        points: &[DVec3],
        dirs: Option<&[DVec3]>,
    ) -> (Vec<f32>, Vec<[f32; 3]>) {
        let node = &self.scene.nodes[index];
        let nf = self.field_of(index);
        let w = &node.world_from_local;
        let mut inside = Vec::with_capacity(points.len());
        let mut pos: [Vec<f32>; 3] = Default::default();
        let mut dir: [Vec<f32>; 3] = Default::default();
        for (k, p) in points.iter().enumerate() {
            let u = field_position(node, nf.space, *p);
            inside.push(u.is_some());
            if let Some(u) = u {
                let d = dirs
                    .map(|d| w.local_from_world_vector(d[k]).normalize_or_zero())
                    .unwrap_or(DVec3::Z);
                for a in 0..3 {
                    pos[a].push(u[a]);
                    dir[a].push(d[a] as f32);
                }
            }
        }
        let n = pos[0].len();
        let mut sigma = vec![0.0f32; n];
        let mut rgb = vec![0.0f32; if dirs.is_some() { 3 * n } else { 0 }];
        if n > 0 {
            let p = [&pos[0][..], &pos[1][..], &pos[2][..]];
            match dirs {
                Some(_) => {
                    let s = assist_field::Samples {
                        pos: p,
                        dir: [&dir[0], &dir[1], &dir[2]],
                        image: &[],
                    };
                    nf.field.forward(&s, &mut sigma, &mut rgb);
                }
                None => nf.field.density(p, &mut sigma),
            }
        }
        // σ is per box diagonal of local length: per world unit it is σ · local_per_world / unit
        // (the mean scale for a node scaled unevenly).
        let per_world = (3.0 / w.scale.element_sum()) as f32 / nf.unit;
        let mut k = 0;
        let mut out_sigma = Vec::with_capacity(points.len());
        let mut out_rgb = Vec::with_capacity(if dirs.is_some() { points.len() } else { 0 });
        for ok in inside {
            let (s, c) = if ok {
                let c = rgb
                    .get(3 * k..3 * k + 3)
                    .map_or([0.0; 3], |c| [c[0], c[1], c[2]]);
                k += 1;
                (sigma[k - 1] * per_world, c)
            } else {
                (0.0, [0.0; 3])
            };
            out_sigma.push(s);
            if dirs.is_some() {
                out_rgb.push(c);
            }
        }
        (out_sigma, out_rgb)
    }
}

/// The world point at position `u` of the unit cube the field of `node` (laid out as
/// `space`) is queried on: the inverse of [`field_position`].
pub fn world_position(node: &SceneNode, space: NodeSpace, u: [f32; 3]) -> DVec3 {
    let local = match space {
        NodeSpace::Box => (DVec3::from(u.map(f64::from)) - 0.5) * node.half_size * 2.0,
        NodeSpace::Contracted => {
            let c = assist_field::contraction::uncontract_from_unit(u);
            DVec3::from(c.map(f64::from)) * node.half_size
        }
    };
    node.world_from_local.transform_point(local)
}

/// Where world point `p` lies in the field of `node` (laid out as `space`): its position
/// in the unit cube the field is queried on, or `None` outside the node's box (or, for a
/// contracted node, beyond its far shell).
pub fn field_position(node: &SceneNode, space: NodeSpace, p: DVec3) -> Option<[f32; 3]> {
    let l = node.world_from_local.local_from_world_point(p);
    let half = node.half_size;
    match space {
        NodeSpace::Box => {
            let ok = (l.abs() - half).max_element() <= 0.0;
            ok.then(|| (l / (half * 2.0) + 0.5).as_vec3().to_array())
        }
        NodeSpace::Contracted => {
            let c = l / half;
            let far = assist_field::contraction::FAR_RADIUS as f64;
            (c.abs().max_element() < far)
                .then(|| assist_field::contraction::contract_to_unit(c.as_vec3().to_array()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A world point taken into a node's field and back lands where it was, in a box
    /// node (turned, scaled unevenly) and in a contracted one (inside its box and far
    /// beyond it).
    #[test]
    fn world_position_inverts_field_position() {
        let mut node = SceneNode::from_obb(
            1,
            "n",
            "f",
            &assist_core::Obb::new(
                DVec3::new(0.3, -0.2, 0.5),
                DVec3::new(0.4, 0.6, 0.2),
                assist_core::glam::DMat3::from_rotation_z(0.7),
            ),
        );
        node.world_from_local.scale = DVec3::new(1.0, 1.5, 0.8);
        let points = [
            DVec3::new(0.35, -0.15, 0.52),
            DVec3::new(0.2, -0.3, 0.45),
            DVec3::new(3.0, 2.0, -1.0),
        ];
        for (space, n) in [(NodeSpace::Box, 2), (NodeSpace::Contracted, 3)] {
            for p in &points[..n] {
                let u = field_position(&node, space, *p).expect("in the field");
                let back = world_position(&node, space, u);
                assert!(
                    (back - *p).length() < 1e-4 * (1.0 + p.length()),
                    "{space:?}: {p} → {back}"
                );
            }
        }
        assert!(field_position(&node, NodeSpace::Box, points[2]).is_none());
    }
}
