//! `assist bench mesh SCENE --data DATA`: exported meshes against ground truth. For each
//! object node that is an instance of the dataset, the ground truth is every pixel of its
//! instance masks with depth, back-projected into the world (the surfaces the cameras saw);
//! the node's mesh (world frame) is sampled uniformly, and both directions of the Chamfer
//! distance are reported: truth → mesh (how far the seen surface is from the mesh) and
//! mesh → truth (how much of the mesh lies away from any seen surface — undersides no
//! camera saw count here too). Each `--resolution` × `--density` pair is one row.

use std::time::Instant;

use anyhow::Context;
use assist_core::{DVec3, Rng};
use assist_data::{LoadOptions, image_io};
use assist_mesh::chamfer::distances;
use assist_mesh::{ExtractOptions, extract_node, node_pose};
use clap::Args;
use serde_json::{Value, json};

#[derive(Args, Debug)]
pub struct MeshBenchArgs {
    /// Trained scene directory.
    pub scene: std::path::PathBuf,
    /// Dataset with instance masks and depth maps (desk format).
    #[arg(long)]
    pub data: std::path::PathBuf,
    /// Grid resolutions to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_RESOLUTION])]
    pub resolution: Vec<u32>,
    /// Surface opacities to measure (comma-separated; 0 = the density's level set).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_OPACITY])]
    pub opacity: Vec<f32>,
    /// Surface density levels to measure with opacity 0 (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_DENSITY])]
    pub density: Vec<f32>,
    /// Shares of the largest part below which parts are dropped (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_MIN_PART])]
    pub min_part: Vec<f64>,
    /// Density smoothing in grid cells (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_SMOOTH])]
    pub smooth: Vec<f32>,
    /// Closing radii in grid cells (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_CLOSE])]
    pub close: Vec<u32>,
    /// Triangle budgets per node (comma-separated; 0 = no limit).
    #[arg(long, value_delimiter = ',', default_values_t = [assist_mesh::DEFAULT_MAX_TRIANGLES])]
    pub triangles: Vec<usize>,
    /// Points sampled per set (ground truth and mesh) for the distances.
    #[arg(long, default_value_t = 100_000)]
    pub points: usize,
    /// Distance (metres) for the "within" shares.
    #[arg(long, default_value_t = 0.005)]
    pub within: f64,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Every masked pixel of instance `id` with depth, back-projected (at most `max` points,
/// drawn at random).
fn truth_points(ds: &assist_data::Dataset, id: u16, max: usize) -> anyhow::Result<Vec<DVec3>> {
    let mut pts = Vec::new();
    for f in &ds.frames {
        let (Some(mp), Some(dp)) = (&f.instance_mask_path, &f.depth_path) else {
            continue;
        };
        let mask = image_io::read_instance_mask(mp, f.mask_encoding)?;
        let depth = image_io::read_depth_png(dp, f.depth_scale)?;
        if (mask.width, mask.height) != (depth.width, depth.height) {
            anyhow::bail!("{}: mask and depth sizes differ", mp.display());
        }
        for y in 0..mask.height {
            for x in 0..mask.width {
                let i = (y * mask.width + x) as usize;
                let z = depth.data[i] as f64;
                if mask.data[i] == id
                    && z > 0.0
                    && let Some(p) = f.camera.unproject(x as f64 + 0.5, y as f64 + 0.5, z)
                {
                    pts.push(p);
                }
            }
        }
    }
    if pts.len() > max {
        let mut rng = Rng::new(u64::from(id));
        rng.shuffle(&mut pts);
        pts.truncate(max);
    }
    Ok(pts)
}

pub fn run(a: MeshBenchArgs) -> anyhow::Result<()> {
    let (scene, _) = assist_scene::scene_file::load(&a.scene)
        .with_context(|| format!("loading scene {}", a.scene.display()))?;
    let ds = assist_data::load(&a.data, &LoadOptions::default())
        .with_context(|| format!("loading dataset {}", a.data.display()))?;
    let mpu = scene.scene.meters_per_unit;
    let mut truth = Vec::new();
    for (index, n) in scene.scene.nodes.iter().enumerate() {
        if n.is_background() || ds.instance(n.id).is_none() {
            continue;
        }
        let t = truth_points(&ds, n.id, a.points)?;
        if t.is_empty() {
            continue;
        }
        truth.push((index, n.id, n.label.clone(), t));
    }
    if truth.is_empty() {
        anyhow::bail!(
            "{}: no object node has instance masks with depth in the dataset",
            a.data.display()
        );
    }
    let mut rows = Vec::new();
    for &resolution in &a.resolution {
        let mut grid = Vec::new();
        for &o in &a.opacity {
            // The density level only matters for the density's own level set.
            let levels = if o > 0.0 {
                &[assist_mesh::DEFAULT_DENSITY][..]
            } else {
                &a.density[..]
            };
            for &d in levels {
                for &m in &a.min_part {
                    for &s in &a.smooth {
                        for &c in &a.close {
                            for &t in &a.triangles {
                                grid.push((o, d, m, s, c, t));
                            }
                        }
                    }
                }
            }
        }
        for (opacity, density, min_part, smooth, close, max_triangles) in grid {
            let opts = ExtractOptions {
                resolution,
                density,
                min_part,
                smooth,
                max_triangles,
                close,
                opacity,
            };
            let mut nodes = Vec::new();
            for (index, id, label, gt) in &truth {
                let t0 = Instant::now();
                let mesh = extract_node(&scene, *index, &opts)?
                    .to_world(&node_pose(&scene, *id).unwrap_or_default());
                let seconds = t0.elapsed().as_secs_f64();
                let closed = mesh.is_closed();
                let genus = mesh.topology().genus;
                let samples: Vec<DVec3> = mesh
                    .sample_points(a.points, 1)
                    .positions
                    .iter()
                    .map(|p| DVec3::from_array(*p) * mpu)
                    .collect();
                let gt_m: Vec<DVec3> = gt.iter().map(|p| *p * mpu).collect();
                let (to_mesh, to_truth) = if samples.is_empty() {
                    (None, None)
                } else {
                    (
                        Some(distances(&gt_m, &samples, a.within)),
                        Some(distances(&samples, &gt_m, a.within)),
                    )
                };
                nodes.push(json!({
                    "id": id, "label": label, "seconds": seconds,
                    "triangles": mesh.triangles.len(), "closed": closed, "genus": genus,
                    "truth_to_mesh": to_mesh, "mesh_to_truth": to_truth,
                    "truth_points": gt.len(),
                }));
            }
            let mean = |key: &str, what: &str| {
                let v: Vec<f64> = nodes.iter().filter_map(|n| n[key][what].as_f64()).collect();
                v.iter().sum::<f64>() / v.len().max(1) as f64
            };
            let row = json!({
                "resolution": resolution, "opacity": opacity, "density": density, "min_part": min_part, "smooth": smooth, "close": close, "max_triangles": max_triangles,
                "truth_to_mesh_mean_mm": mean("truth_to_mesh", "mean") * 1e3,
                "mesh_to_truth_mean_mm": mean("mesh_to_truth", "mean") * 1e3,
                "chamfer_mm": (mean("truth_to_mesh", "mean") + mean("mesh_to_truth", "mean")) * 1e3 / 2.0,
                "seconds_per_node": nodes.iter().filter_map(|n| n["seconds"].as_f64()).sum::<f64>() / nodes.len() as f64,
                "nodes": nodes,
            });
            if !a.json {
                eprintln!(
                    "resolution {resolution:>4}  opacity {opacity:.2}  density {density:>7.1}  min part {min_part:.2}  smooth {smooth:.1}  close {close}  budget {max_triangles}  truth→mesh {:.2} mm  mesh→truth {:.2} mm  Chamfer {:.2} mm  {:.2} s/node",
                    row["truth_to_mesh_mean_mm"].as_f64().unwrap_or(f64::NAN),
                    row["mesh_to_truth_mean_mm"].as_f64().unwrap_or(f64::NAN),
                    row["chamfer_mm"].as_f64().unwrap_or(f64::NAN),
                    row["seconds_per_node"].as_f64().unwrap_or(f64::NAN),
                );
                for n in row["nodes"].as_array().into_iter().flatten() {
                    eprintln!(
                        "    {:>2} {:<42} truth→mesh mean {:.2} / median {:.2} mm ({:.0}% within {} mm), mesh→truth mean {:.2} mm, {} triangles{}{}",
                        n["id"],
                        n["label"].as_str().unwrap_or(""),
                        n["truth_to_mesh"]["mean"].as_f64().unwrap_or(f64::NAN) * 1e3,
                        n["truth_to_mesh"]["median"].as_f64().unwrap_or(f64::NAN) * 1e3,
                        n["truth_to_mesh"]["within_share"]
                            .as_f64()
                            .unwrap_or(f64::NAN)
                            * 100.0,
                        a.within * 1e3,
                        n["mesh_to_truth"]["mean"].as_f64().unwrap_or(f64::NAN) * 1e3,
                        n["triangles"],
                        if n["closed"] == true {
                            ", closed"
                        } else {
                            ", open"
                        },
                        n["genus"]
                            .as_u64()
                            .map(|g| format!(", genus {g}"))
                            .unwrap_or_default(),
                    );
                }
            }
            rows.push(row);
        }
    }
    if a.json {
        let v: Value = json!({"scene": a.scene, "data": a.data, "rows": rows});
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(())
}
