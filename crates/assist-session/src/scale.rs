//! The scene's unit after training. A capture processed without `--scale-by` is in
//! COLMAP's arbitrary unit, read as metres by every length assist takes or writes (edits,
//! the generator's gaps, depth in millimetres, masses); an object whose real height the
//! user knows sets metres per unit instead.

use assist_core::{DVec3, InstanceId};

use crate::{Result, Session, request};

impl Session {
    /// The height along the scene's up of what node `id`'s field occupies (its occupancy
    /// grid's occupied cells, corner to corner), in world units; its box's height when
    /// nothing is occupied.
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
        for c in (0..r * r * r).filter(|&c| g.is_occupied_cell(c)) {
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
}
