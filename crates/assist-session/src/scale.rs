//! The scene's unit after training. A capture processed without `--scale-by` is in
//! COLMAP's arbitrary unit, read as metres by every length assist takes or writes (edits,
//! the generator's gaps, depth in millimetres, masses); an object whose real height the
//! user knows sets metres per unit instead.

use assist_core::{DVec3, InstanceId};

use crate::{Result, Session, request};

/// A connected part of the occupied cells smaller than this share of the largest is left
/// out of an object's extent (haze the field left around it).
pub const MAIN_PART_SHARE: f64 = 0.1;

/// The cells of an `r`³ grid (x fastest) for which `occupied` holds, in the parts
/// (26-connected) of at least [`MAIN_PART_SHARE`] of the largest part's size.
fn main_parts(r: usize, occupied: impl Fn(usize) -> bool) -> Vec<usize> {
    let n = r * r * r;
    let mut part = vec![u32::MAX; n];
    let mut sizes: Vec<usize> = Vec::new();
    let mut stack = Vec::new();
    for seed in (0..n).filter(|&c| occupied(c)) {
        if part[seed] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        let mut size = 0;
        part[seed] = id;
        stack.push(seed);
        while let Some(c) = stack.pop() {
            size += 1;
            let (x, y, z) = (c % r, (c / r) % r, c / (r * r));
            for dz in -1i64..=1 {
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let (u, v, w) = (x as i64 + dx, y as i64 + dy, z as i64 + dz);
                        let inside = |a: i64| (0..r as i64).contains(&a);
                        if !(inside(u) && inside(v) && inside(w)) {
                            continue;
                        }
                        let d = u as usize + r * (v as usize + r * w as usize);
                        if part[d] == u32::MAX && occupied(d) {
                            part[d] = id;
                            stack.push(d);
                        }
                    }
                }
            }
        }
        sizes.push(size);
    }
    let largest = sizes.iter().copied().max().unwrap_or(0);
    (0..n)
        .filter(|&c| {
            part[c] != u32::MAX
                && sizes[part[c] as usize] as f64 >= MAIN_PART_SHARE * largest as f64
        })
        .collect()
}

impl Session {
    /// The height along the scene's up of what node `id`'s field occupies (its occupancy
    /// grid's occupied cells, corner to corner: the largest connected part and any other
    /// at least [`MAIN_PART_SHARE`] its size, so that a wisp of haze apart from the object
    /// does not count), in world units; its box's height when nothing is occupied.
    pub fn occupied_height(&self, id: InstanceId) -> Result<f64> {
        let node = self
            .node(id)
            .ok_or_else(|| request("node", format!("no node with id {id} ({})", self.ids())))?;
        if node.is_background() {
            return Err(request(
                "node",
                format!("node {id} is the background: name an object"),
            ));
        }
        let up = self.description().up.normalize();
        let pose = node.world_from_local;
        let world = |u: DVec3| {
            let local = (u - 0.5) * (node.half_size * 2.0);
            pose.translation + pose.rotation * (local * pose.scale)
        };
        let g = &self.scene().fields[&node.field].occupancy;
        let r = g.res as usize;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for c in main_parts(r, |c| g.is_occupied_cell(c)) {
            let v = DVec3::new((c % r) as f64, ((c / r) % r) as f64, (c / (r * r)) as f64);
            for corner in 0..8 {
                let d = DVec3::new(
                    (corner & 1) as f64,
                    ((corner >> 1) & 1) as f64,
                    ((corner >> 2) & 1) as f64,
                );
                let h = world((v + d) / r as f64).dot(up);
                lo = lo.min(h);
                hi = hi.max(h);
            }
        }
        if hi > lo {
            return Ok(hi - lo);
        }
        let corners = (0..8).map(|k| {
            world(DVec3::new(
                (k & 1) as f64,
                ((k >> 1) & 1) as f64,
                ((k >> 2) & 1) as f64,
            ))
            .dot(up)
        });
        let (lo, hi) = corners.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), h| {
            (a.min(h), b.max(h))
        });
        Ok(hi - lo)
    }

    /// Sets metres per world unit, one undo step noting `why`.
    pub fn set_meters_per_unit(&mut self, mpu: f64, why: &str) -> Result<()> {
        Ok(self.editor.set_meters_per_unit(mpu, why)?)
    }

    /// Sets metres per unit as `target` says (one undo step) and reports it.
    pub fn scale_to(&mut self, target: &ScaleTarget) -> Result<Scaled> {
        let before = self.description().meters_per_unit;
        let (mpu, why, object) = match target {
            ScaleTarget::Height { node, meters } => {
                if !(meters.is_finite() && *meters > 0.0) {
                    return Err(request(
                        "height",
                        format!("expected a positive number of metres, got {meters}"),
                    ));
                }
                let id = self.node_named(node)?;
                let units = self.occupied_height(id)?;
                let label = self.node(id).map(|n| n.label.clone()).unwrap_or_default();
                let why = format!("scale: {label:?} is {meters} m tall ({units:.4} units)");
                let object = ScaledObject {
                    id,
                    label,
                    height_units: units,
                    height_m: *meters,
                };
                (meters / units, why, Some(object))
            }
            ScaleTarget::MetersPerUnit(m) => (*m, format!("scale: {m} m per unit"), None),
        };
        self.set_meters_per_unit(mpu, &why)?;
        Ok(Scaled {
            meters_per_unit: mpu,
            before,
            object,
        })
    }
}

/// What sets a scene's unit: an object's real height along the scene's up, or metres per
/// unit given directly.
#[derive(Debug, Clone, PartialEq)]
pub enum ScaleTarget {
    Height { node: String, meters: f64 },
    MetersPerUnit(f64),
}

/// `assist scene scale`'s choice of target (clap derives its flags from it).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ScaleFlags {
    /// The object whose real height is known: an id or a name ("beer can").
    #[arg(long, requires = "height", conflicts_with = "meters_per_unit")]
    pub object: Option<String>,
    /// Its real height along the scene's up, with the unit: 16cm, 0.16m, 160mm. Its
    /// height in the scene is what its field occupies.
    #[arg(long, requires = "object")]
    pub height: Option<String>,
    /// Or metres per unit given directly.
    #[arg(long, required_unless_present = "object")]
    pub meters_per_unit: Option<f64>,
}

impl ScaleFlags {
    pub fn target(&self) -> Result<ScaleTarget> {
        match (&self.object, &self.height, self.meters_per_unit) {
            (Some(node), Some(h), None) => Ok(ScaleTarget::Height {
                node: node.clone(),
                meters: assist_process::align::parse_distance(h)
                    .map_err(|e| request("height", e))?,
            }),
            (None, None, Some(m)) => Ok(ScaleTarget::MetersPerUnit(m)),
            _ => Err(request(
                "scale",
                "give --object and --height, or --meters-per-unit alone".into(),
            )),
        }
    }
}

/// What [`Session::scale_to`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Scaled {
    pub meters_per_unit: f64,
    pub before: f64,
    pub object: Option<ScaledObject>,
}

/// The object a scale was measured on.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ScaledObject {
    pub id: InstanceId,
    pub label: String,
    pub height_units: f64,
    pub height_m: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_objects_height_sets_the_unit_as_one_undo_step() {
        let scene = assist_testkit::scenes::two_boxes(0.08);
        let mut s = Session::new(scene);
        let id = s
            .nodes()
            .iter()
            .find(|n| !n.is_background())
            .map(|n| n.id)
            .unwrap();
        let h = s.occupied_height(id).unwrap();
        let box_h = {
            let n = s.node(id).unwrap();
            2.0 * n.half_size.z * n.world_from_local.scale.z
        };
        assert!(h > 0.0 && h <= box_h + 1e-9, "{h} vs the box's {box_h}");
        s.set_meters_per_unit(0.16 / h, "scale: the box is 16 cm tall")
            .unwrap();
        assert!((s.description().meters_per_unit * h - 0.16).abs() < 1e-12);
        assert!(s.undo());
        assert_eq!(s.description().meters_per_unit, 1.0);
        assert!(s.set_meters_per_unit(f64::NAN, "x").is_err());
        assert!(s.set_meters_per_unit(0.0, "x").is_err());
        let bg = s.nodes().iter().find(|n| n.is_background()).unwrap().id;
        assert!(s.occupied_height(bg).is_err());
    }

    /// A stray occupied cell apart from the object does not count in its height; a part
    /// of it the size of the object does.
    #[test]
    fn haze_apart_from_the_object_is_not_its_height() {
        let scene = assist_testkit::scenes::two_boxes(0.08);
        let node = scene
            .scene
            .nodes
            .iter()
            .find(|n| !n.is_background())
            .unwrap()
            .clone();
        let (id, key) = (node.id, node.field.clone());
        let grid = |cells: &[[usize; 3]]| {
            let mut g = assist_field::OccupancyGrid::new(16);
            let mut empty = vec![true; g.cells()];
            for &[x, y, z] in cells {
                empty[x + 16 * (y + 16 * z)] = false;
            }
            g.set_empty(&empty);
            g
        };
        // The object: a 4 × 4 × 4 block at the bottom; haze: one cell near the top.
        let block: Vec<[usize; 3]> = (0..64)
            .map(|i| [6 + i % 4, 6 + i / 4 % 4, 1 + i / 16])
            .collect();
        let mut with_haze = block.clone();
        with_haze.push([2, 2, 14]);
        let mut two = block.clone();
        two.extend(block.iter().map(|&[x, y, z]| [x, y, z + 10]));
        let height = |cells: &[[usize; 3]]| {
            let mut sc = scene.clone();
            std::sync::Arc::make_mut(sc.fields.get_mut(&key).unwrap()).occupancy = grid(cells);
            Session::new(sc).occupied_height(id).unwrap()
        };
        let box_h = 2.0 * node.half_size.z * node.world_from_local.scale.z;
        let cells_h = |k: f64| k / 16.0 * box_h;
        assert!((height(&block) - cells_h(4.0)).abs() < 1e-9);
        assert!((height(&with_haze) - cells_h(4.0)).abs() < 1e-9);
        assert!((height(&two) - cells_h(14.0)).abs() < 1e-9);
    }
}
