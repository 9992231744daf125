//! `ExportJob`: nodes as meshes or point clouds for simulators and 3D tools, with an
//! optional MuJoCo or URDF model that places them at the nodes' poses (assist-mesh does
//! the geometry; this is where a scene, a node selection and an output folder meet).
//!
//! The output folder is staged and swapped in whole (`--force` only over assist's own
//! folders). It holds one file per node (`node_ID_LABEL.EXT`), `export.json` (per node:
//! id, label, file, frame, pose in metres, counts, closed or not, volume and mass
//! properties; the scene's up and metres per unit), and `scene.xml` (MJCF) or
//! `scene.urdf` with one `node_ID_LABEL.urdf` per object.

use std::path::PathBuf;
use std::time::Instant;

use assist_core::{DVec3, InstanceId};
use assist_mesh::sim::{self, Body};
use assist_mesh::write::{self, Format, obj_name};
use assist_mesh::{ExtractOptions, MeshFrame, NodeMesh, node_pose};
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::{NeuralScene, Result, Session, SessionError, request};

/// A simulator model to write beside the meshes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimModel {
    Mjcf,
    Urdf,
}

/// Default number of points of a point cloud per node.
pub const DEFAULT_POINTS: usize = 100_000;
/// Default material density for masses in simulator models (kg/m³, water).
pub const DEFAULT_MATERIAL_DENSITY: f64 = 1000.0;

/// What to export and where.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExportJob {
    /// Nodes by id or label; `all` = every object node; `background` (or 0) = the
    /// background's inner box.
    pub nodes: Vec<String>,
    pub format: Format,
    /// Coordinates of the files; `None` = the world, or the nodes' frames with `sim`.
    pub frame: Option<MeshFrame>,
    pub sim: Option<SimModel>,
    #[serde(flatten)]
    pub extract: ExtractOptions,
    /// Points per node for `Format::Points`.
    pub points: usize,
    /// kg/m³ for the simulator models' masses.
    pub material_density: f64,
    pub out: PathBuf,
    pub force: bool,
}

impl Default for ExportJob {
    fn default() -> Self {
        ExportJob {
            nodes: vec!["all".into()],
            format: Format::Obj,
            frame: None,
            sim: None,
            extract: ExtractOptions::default(),
            points: DEFAULT_POINTS,
            material_density: DEFAULT_MATERIAL_DENSITY,
            out: PathBuf::from("export"),
            force: false,
        }
    }
}

/// One node as exported.
#[derive(Debug, Clone, Serialize)]
pub struct ExportedNode {
    pub id: InstanceId,
    pub label: String,
    pub file: String,
    pub vertices: usize,
    pub triangles: usize,
    /// Every edge in exactly two triangles, consistently oriented.
    pub closed: bool,
    /// Enclosed volume in m³ (closed meshes only).
    pub volume_m3: Option<f64>,
    /// Handles of the surface (tunnels through it), closed meshes only; and its pieces.
    pub genus: Option<i64>,
    pub components: usize,
    /// What the node's occupancy grid holds, m³: the volume a surface of the object
    /// should come near (a much smaller one is hollow or full of tunnels).
    pub occupancy_m3: f64,
    /// The level (m along up) of the support the surface was cut at, when one was found.
    pub cut_at_support_m: Option<f64>,
    /// What does not hold about this mesh, in words.
    pub warnings: Vec<String>,
    /// The lowest level of the surface along up and its footprint (world units, along
    /// [`sim::horizontal_axes`]): where a simulator's support goes.
    #[serde(skip)]
    pub world_base: Option<sim::Support>,
    pub seconds: f64,
}

/// A closed mesh enclosing less than this share of its node's occupancy is reported
/// (hollow or undertrained).
pub const MIN_VOLUME_SHARE: f64 = 0.3;
/// A closed mesh enclosing more than this multiple of its node's occupancy is reported:
/// the occupancy grid counts every cell the field draws, so a surface holding much more
/// than that encloses matter the renderer never shows.
pub const MAX_VOLUME_SHARE: f64 = 2.0;

#[derive(Debug, Clone, Serialize)]
pub struct ExportSummary {
    pub out: PathBuf,
    pub nodes: Vec<ExportedNode>,
    /// The simulator model file, when one was written.
    pub model: Option<String>,
}

impl ExportJob {
    /// Checks the job's values before anything is read or written.
    fn check(&self) -> Result<()> {
        let job = self;
        job.extract
            .validate()
            .map_err(|e| request("export", e.to_string()))?;
        if job.sim.is_some() && job.format != Format::Obj {
            return Err(request(
                "format",
                "a simulator model references OBJ meshes (MuJoCo and URDF loaders read them): use the obj format".into(),
            ));
        }
        // From aerogel to osmium, with room on both sides: what a simulator can step.
        if !(0.1..=100_000.0).contains(&job.material_density) {
            return Err(request(
                "material density",
                format!(
                    "expected a density from 0.1 to 100000 kg/m³ (water 1000, steel 7850), got {}",
                    assist_core::fmt_num(job.material_density)
                ),
            ));
        }
        if job.format == Format::Points && !(1..=100_000_000).contains(&job.points) {
            return Err(request(
                "points",
                format!("{} is outside 1..=100000000", job.points),
            ));
        }
        Ok(())
    }
}

impl Session {
    /// The surface of node `id` in its own frame (box centre, box axes, world units), cut
    /// at the support it rests on.
    pub fn node_mesh(&self, id: InstanceId, opts: &ExtractOptions) -> Result<NodeMesh> {
        let scene = self.scene();
        let index = scene
            .scene
            .nodes
            .iter()
            .position(|n| n.id == id)
            .ok_or_else(|| {
                request(
                    "node",
                    format!("no node {id} (the scene has {})", self.ids()),
                )
            })?;
        let (cut, _) = support_cut(scene, index);
        assist_mesh::extract_node_cut(scene, index, opts, cut)
            .map_err(|e| request("export", e.to_string()))
    }

    /// The node named `name`: an id, `background`, or a label or description found as an
    /// instruction finds objects (candidates listed when it is unclear).
    pub fn node_named(&mut self, name: &str) -> Result<InstanceId> {
        let t = name.trim();
        if t.is_empty() {
            return Err(request(
                "node",
                "expected an id, a label, `all` or `background`, got an empty name".into(),
            ));
        }
        if let Ok(id) = t.parse::<InstanceId>() {
            return self.node(id).map(|n| n.id).ok_or_else(|| {
                request(
                    "node",
                    format!("no node with id {id} (the scene has {})", self.ids()),
                )
            });
        }
        if t.eq_ignore_ascii_case("background") {
            return self
                .nodes()
                .iter()
                .find(|n| n.is_background())
                .map(|n| n.id)
                .ok_or_else(|| request("node", "the scene has no background node".into()));
        }
        let mpu = self.description().meters_per_unit;
        let r = self
            .resolve(&format!("select the {t}"), None)
            .map_err(|e| request("node", format!("{t:?}: {e}")))?;
        r.edits
            .first()
            .map(|e| e.to_action(mpu).instance_id)
            .ok_or_else(|| request("node", format!("{t:?} names no node")))
    }

    /// The ids `names` select (in scene order, each once).
    fn export_ids(&mut self, names: &[String]) -> Result<Vec<InstanceId>> {
        let mut ids = Vec::new();
        for n in names {
            if n.trim().eq_ignore_ascii_case("all") {
                ids.extend(
                    self.nodes()
                        .iter()
                        .filter(|n| !n.is_background())
                        .map(|n| n.id),
                );
            } else {
                ids.push(self.node_named(n)?);
            }
        }
        let order: Vec<InstanceId> = self.nodes().iter().map(|n| n.id).collect();
        ids.sort_by_key(|id| order.iter().position(|o| o == id));
        ids.dedup();
        if ids.is_empty() {
            return Err(request("node", "no object nodes to export".into()));
        }
        Ok(ids)
    }

    /// Writes the job's nodes (see the module docs); `on_node` is told of each node once
    /// its file is written.
    pub fn export(
        &mut self,
        job: &ExportJob,
        mut on_node: impl FnMut(usize, usize, &ExportedNode),
    ) -> Result<ExportSummary> {
        job.check()?;
        let ids = self.export_ids(&job.nodes)?;
        assist_fs::check_replaceable_as(&job.out, job.force, assist_fs::Kind::Export)
            .map_err(SessionError::Output)?;
        let staging = assist_fs::Staging::begin(&job.out, "exporting meshes")
            .map_err(SessionError::Output)?;
        let frame = job.frame.unwrap_or(if job.sim.is_some() {
            MeshFrame::Node
        } else {
            MeshFrame::World
        });
        let scene = self.scene();
        let mpu = scene.scene.meters_per_unit;
        let mut nodes = Vec::new();
        let mut bodies = Vec::new();
        let mut records = Vec::new();
        let mut bases = Vec::new();
        for (k, &id) in ids.iter().enumerate() {
            let (done, record, body) = export_node(scene, job, frame, staging.dir(), id)?;
            if !body.fixed
                && let Some(b) = done.world_base
            {
                bases.push(b);
            }
            records.push(record);
            bodies.push(body);
            on_node(k, ids.len(), &done);
            nodes.push(done);
        }
        let model_name = job
            .out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        let up = scene.scene.up;
        // What the objects rest on: a slab under each group of objects whose bases lie
        // within 2 mm, grown 2 cm around their footprints.
        let supports = sim::supports(&bases, 0.002 / mpu, 0.02 / mpu);
        let model = match job.sim {
            None => None,
            Some(SimModel::Mjcf) => {
                let text = sim::mjcf(&model_name, &bodies, mpu, up, &supports);
                write_text(&staging, "scene.xml", &text)?;
                Some("scene.xml".to_string())
            }
            Some(SimModel::Urdf) => {
                write_text(
                    &staging,
                    "scene.urdf",
                    &sim::urdf_scene(&model_name, &bodies, mpu),
                )?;
                for b in bodies.iter().filter(|b| !b.fixed) {
                    write_text(
                        &staging,
                        &format!("{}.urdf", b.name),
                        &sim::urdf_object(b, mpu),
                    )?;
                }
                Some("scene.urdf".to_string())
            }
        };
        let index = json!({
            "format": job.format,
            "frame": frame,
            "up": up.to_array(),
            "meters_per_unit": mpu,
            "units": "mesh files in world units (× meters_per_unit = metres); poses and masses in metres and kilograms",
            "resolution": job.extract.resolution,
            "density_level": job.extract.density,
            "material_density_kg_m3": job.material_density,
            "model": model,
            "supports_m": supports
                .iter()
                .map(|s| json!({"level": s.level * mpu, "lo": s.lo.map(|v| v * mpu), "hi": s.hi.map(|v| v * mpu)}))
                .collect::<Vec<_>>(),
            "nodes": records,
        });
        write_text(
            &staging,
            "export.json",
            &serde_json::to_string_pretty(&index).unwrap_or_default(),
        )?;
        staging.commit().map_err(SessionError::Output)?;
        Ok(ExportSummary {
            out: job.out.clone(),
            nodes,
            model,
        })
    }
}

/// One node's file, its `export.json` record and its simulator body.
fn export_node(
    scene: &NeuralScene,
    job: &ExportJob,
    frame: MeshFrame,
    dir: &std::path::Path,
    id: InstanceId,
) -> Result<(ExportedNode, serde_json::Value, Body)> {
    let mpu = scene.scene.meters_per_unit;
    let t0 = Instant::now();
    let index = scene
        .scene
        .nodes
        .iter()
        .position(|n| n.id == id)
        .unwrap_or(0);
    let node = &scene.scene.nodes[index];
    let (cut, support) = support_cut(scene, index);
    let mesh = assist_mesh::extract_node_cut(scene, index, &job.extract, cut)
        .map_err(|e| request("export", e.to_string()))?;
    // An empty surface is no export: MuJoCo refuses a mesh under 4 vertices, and a file
    // with nothing in it would pass for a result.
    if mesh.positions.len() < 4 || mesh.triangles.is_empty() {
        let level = if job.extract.opacity > 0.0 && !node.is_background() {
            format!("opacity {}", job.extract.opacity)
        } else {
            format!("density level {}", job.extract.density)
        };
        let flag = if job.extract.opacity > 0.0 && !node.is_background() {
            "--opacity"
        } else {
            "--density"
        };
        return Err(request(
            "export",
            format!(
                "node {id} {:?} has no surface at {level} ({} vertices): the field is nearly empty there; train it longer or lower {flag}",
                node.label,
                mesh.positions.len()
            ),
        ));
    }
    let pose = node_pose(scene, id).unwrap_or_default();
    let mesh = match frame {
        MeshFrame::World => mesh.to_world(&pose),
        MeshFrame::Node => mesh,
    };
    let name = obj_name(&node.label, id);
    let file = format!("{name}.{}", job.format.extension());
    let bytes = match job.format {
        Format::Ply => write::mesh_ply(&mesh),
        Format::Obj => write::mesh_obj(&mesh),
        Format::Glb => write::mesh_glb(&mesh),
        Format::Points => write::points_ply(
            &mesh.sample_points(job.points, u64::from(id)),
            &format!("assist node {id} {} (points)", node.label),
        ),
    };
    write::write_file(&dir.join(&file), &bytes).map_err(|e| request("export", e.to_string()))?;
    let closed = mesh.is_closed() && !mesh.triangles.is_empty();
    // Mass properties in the node frame, in metres.
    let mass = closed.then(|| {
        let in_node = match frame {
            MeshFrame::Node => mesh.positions.clone(),
            MeshFrame::World => {
                let inv = pose.inverse().unwrap_or_default();
                mesh.positions
                    .iter()
                    .map(|p| inv.transform_point(DVec3::from_array(*p)).to_array())
                    .collect()
            }
        };
        let metres: Vec<[f64; 3]> = in_node.iter().map(|p| p.map(|v| v * mpu)).collect();
        assist_mesh::mass_properties(&metres, &mesh.triangles, job.material_density)
    });
    let topology = mesh.topology();
    let occupancy_m3 = {
        let box_m3 = (node.half_size * node.world_from_local.scale * 2.0 * mpu).element_product();
        scene.field_of(index).occupancy.occupied_fraction() * box_m3
    };
    let warnings = mesh_warnings(
        topology.genus,
        mass.map(|m| m.volume).filter(|_| !node.is_background()),
        occupancy_m3,
    );
    let done = ExportedNode {
        id,
        label: node.label.clone(),
        file: file.clone(),
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        closed,
        volume_m3: mass.map(|m| m.volume),
        genus: topology.genus,
        components: topology.components,
        occupancy_m3,
        cut_at_support_m: support.map(|l| l * mpu),
        warnings,
        world_base: world_base(&mesh, frame, &pose, scene.scene.up),
        seconds: t0.elapsed().as_secs_f64(),
    };
    let rotation = if frame == MeshFrame::Node {
        pose.rotation
    } else {
        Default::default()
    };
    let fixed = node.is_background();
    // A pad under a flat base, in the frame the mesh is written in (`assist_mesh::pad`).
    let pad = (!fixed)
        .then(|| assist_mesh::pad::exported_pad(&mesh.positions, rotation, scene.scene.up, mpu))
        .flatten();
    let record = json!({
        "id": id,
        "label": node.label,
        "class": node.class_name(),
        "file": file,
        "frame": frame,
        "position_m": (pose.translation * mpu).to_array(),
        "rotation_xyzw": pose.rotation.to_array(),
        "vertices": done.vertices,
        "triangles": done.triangles,
        "closed": closed,
        "genus": done.genus,
        "components": done.components,
        "euler_characteristic": topology.euler,
        "occupancy_m3": occupancy_m3,
        "cut_at_support_m": done.cut_at_support_m,
        "warnings": done.warnings,
        "mass_properties": mass,
        "base_pad": pad.map(|p| p.json_m(mpu)),
        "bounds": mesh.bounds(),
    });
    let body = Body {
        name,
        mesh_file: file,
        translation: if frame == MeshFrame::Node {
            pose.translation
        } else {
            DVec3::ZERO
        },
        rotation,
        mass,
        rgb: mean_color(&mesh),
        fixed,
        pad,
    };
    Ok((done, record, body))
}

/// The lowest level of `mesh` along `up` and its footprint, in the world (see
/// [`ExportedNode::world_base`]).
fn world_base(
    mesh: &NodeMesh,
    frame: MeshFrame,
    pose: &assist_core::Similarity3,
    up: DVec3,
) -> Option<sim::Support> {
    let up = up.normalize();
    let [e1, e2] = sim::horizontal_axes(up);
    let mut b = sim::Support {
        level: f64::INFINITY,
        lo: [f64::INFINITY; 2],
        hi: [f64::NEG_INFINITY; 2],
    };
    for p in &mesh.positions {
        let p = DVec3::from_array(*p);
        let w = match frame {
            MeshFrame::World => p,
            MeshFrame::Node => pose.transform_point(p),
        };
        b.level = b.level.min(w.dot(up));
        for (a, e) in [e1, e2].iter().enumerate() {
            b.lo[a] = b.lo[a].min(w.dot(*e));
            b.hi[a] = b.hi[a].max(w.dot(*e));
        }
    }
    b.level.is_finite().then_some(b)
}

/// What does not hold about a node's mesh, in words: tunnels through it, and a volume
/// (`None` for the background or an open mesh) far from what its occupancy holds.
fn mesh_warnings(genus: Option<i64>, volume_m3: Option<f64>, occupancy_m3: f64) -> Vec<String> {
    let mut warnings = Vec::new();
    if let Some(g) = genus.filter(|g| *g > 0) {
        warnings.push(format!(
            "genus {g}: the surface has {g} tunnel(s) through it"
        ));
    }
    if let Some(v) = volume_m3 {
        let share = 100.0 * v / occupancy_m3.max(1e-12);
        if v < MIN_VOLUME_SHARE * occupancy_m3 {
            warnings.push(format!(
                "it encloses {:.0} cm³, {share:.0}% of the {:.0} cm³ its occupancy holds: the surface may be hollow or undertrained",
                v * 1e6,
                occupancy_m3 * 1e6
            ));
        } else if v > MAX_VOLUME_SHARE * occupancy_m3 {
            warnings.push(format!(
                "it encloses {:.0} cm³, {share:.0}% of the {:.0} cm³ its occupancy holds: the surface holds matter the renderer does not show",
                v * 1e6,
                occupancy_m3 * 1e6
            ));
        }
    }
    warnings
}

/// The plane (node frame) an object's surface is cut at: the level of the background's
/// surface under it (see [`assist_core::placement::support_height`]), so that its base is
/// flat on the table rather than reaching into it; with the level (world units along
/// up). `None` for the background, where no flat support is found, or where the level
/// found lies too far above the box's base to be what carries it.
fn support_cut(scene: &NeuralScene, index: usize) -> (Option<(DVec3, f64)>, Option<f64>) {
    let node = &scene.scene.nodes[index];
    let Some(bg) = scene.scene.nodes.iter().position(|n| n.is_background()) else {
        return (None, None);
    };
    if node.is_background() {
        return (None, None);
    }
    let up = scene.scene.up.normalize();
    let mut density = |pts: &[DVec3]| scene.density_at_world(bg, pts);
    let Some(level) =
        assist_core::placement::support_height(node, up, scene.scene.meters_per_unit, &mut density)
    else {
        return (None, None);
    };
    // A support is under the object: it may trim its base (a mesh reaches a centimetre or
    // so into the table), never more than 3 cm or a third of the box's height — a level
    // higher up is something else (a neighbour's residue in the background, a shelf).
    let heights = node.world_corners().map(|c| c.dot(up));
    let (low, high) = heights
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &z| {
            (l.min(z), h.max(z))
        });
    let reach = (0.03 / scene.scene.meters_per_unit).min((high - low) / 3.0);
    if level > low + reach {
        return (None, None);
    }
    let w = &node.world_from_local;
    let n = w.rotation.inverse() * up;
    (Some((n, level - up.dot(w.translation))), Some(level))
}

fn write_text(staging: &assist_fs::Staging, name: &str, text: &str) -> Result<()> {
    write::write_file(&staging.dir().join(name), text.as_bytes())
        .map_err(|e| request("export", e.to_string()))
}

fn mean_color(m: &NodeMesh) -> [f32; 3] {
    if m.colors.is_empty() {
        return [0.7; 3];
    }
    let n = m.colors.len() as f32;
    [0, 1, 2].map(|c| m.colors.iter().map(|v| v[c]).sum::<f32>() / n)
}
