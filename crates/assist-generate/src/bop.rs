//! The BOP side of a generated run, as the bop_toolkit reads it: per sample (a BOP scene)
//! `rgb/`, `depth/` (six-digit image ids, the same files as `views/`), `mask/` and
//! `mask_visib/` (`IMAGE_GT.png`, 0/255) and `scene_gt_info.json` beside `scene_gt.json`
//! and `scene_camera.json`; per run `models/obj_CLASS.ply` in millimetres, in the frame
//! `cam_R_m2c`/`cam_t_m2c` give (the node's box: centre at the origin, box axes), with
//! `models_info.json` (diameter and 3D box per object).

use std::path::Path;

use serde_json::{Value, json};

use crate::coco;
use crate::sample::{Sample, io, pretty, write};
use crate::{Generator, Result};

/// Writes sample `s`'s BOP image folders and `scene_gt_info.json` into `dir`, whose
/// `views/` holds the rendered images.
pub(crate) fn write_sample(dir: &Path, s: &Sample) -> Result<()> {
    let mut info = serde_json::Map::new();
    for sub in ["rgb", "depth", "mask", "mask_visib"] {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| io(&d, e))?;
    }
    for (k, v) in s.views.iter().enumerate() {
        let name = &v.camera.name;
        // The same bytes as the views' images (a second name, or a copy across devices).
        for (from, to) in [("images", "rgb"), ("depth", "depth")] {
            let src = dir.join("views").join(from).join(format!("{name}.png"));
            let dst = dir.join(to).join(format!("{k:06}.png"));
            if src.is_file() && std::fs::hard_link(&src, &dst).is_err() {
                std::fs::copy(&src, &dst).map_err(|e| io(&dst, e))?;
            }
        }
        let f = &v.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        let gts = s.scene_gt[k.to_string()]
            .as_array()
            .cloned()
            .unwrap_or_default();
        let mut entries = Vec::new();
        for (j, gt) in gts.iter().enumerate() {
            let id = gt["inst_id"].as_u64().unwrap_or(0) as u16;
            let layer = f.layers.iter().find(|l| l.id == id);
            let visib = |q: usize| f.panoptic[q] == id;
            let all = |q: usize| visib(q) || layer.is_some_and(|l| l.opacity[q] >= 0.5);
            for (sub, m) in [
                ("mask", &all as &dyn Fn(usize) -> bool),
                ("mask_visib", &visib),
            ] {
                let px: Vec<u8> = (0..w * h).map(|q| if m(q) { 255 } else { 0 }).collect();
                let file = dir.join(sub).join(format!("{k:06}_{j:06}.png"));
                assist_data::image_io::write_gray8_png(&file, w as u32, h as u32, &px)?;
            }
            let count = |m: &dyn Fn(usize) -> bool| (0..w * h).filter(|&q| m(q)).count() as u64;
            let (n_all, n_visib) = (count(&all), count(&visib));
            let n_valid = count(&|q| all(q) && f.depth[q] > 0.0);
            let bbox = |m: &dyn Fn(usize) -> bool| {
                coco::bbox(w, h, m).map_or(json!([-1, -1, -1, -1]), |b| json!(b))
            };
            entries.push(json!({
                "bbox_obj": bbox(&all),
                "bbox_visib": bbox(&visib),
                "px_count_all": n_all,
                "px_count_valid": n_valid,
                "px_count_visib": n_visib,
                "visib_fract": if n_all > 0 { n_visib as f64 / n_all as f64 } else { 0.0 },
            }));
        }
        info.insert(k.to_string(), Value::Array(entries));
    }
    write(
        &dir.join("scene_gt_info.json"),
        &pretty(&Value::Object(info)),
    )
}

/// The folder of a run's object models (BOP's `models/`).
pub const MODELS: &str = "models";

impl Generator {
    /// Writes `out/models/`: one mesh per class (object id = class id), from the first
    /// node of that class in the base scenes or the library, in millimetres in the
    /// node's box frame, and `models_info.json`. Classes whose field has no surface get
    /// no model and are listed in `models_info.json`'s `"missing"` file beside it.
    pub(crate) fn write_models(&self, out: &Path) -> Result<()> {
        let target = out.join(MODELS);
        if target.join("models_info.json").is_file() {
            return Ok(());
        }
        let staging = assist_fs::Staging::begin(&target, "writing the object models")?;
        let mut info = serde_json::Map::new();
        let mut missing = Vec::new();
        for (class, name) in self.classes.iter().enumerate().skip(1) {
            let Some(mesh) = self.class_mesh(name) else {
                missing.push(name.clone());
                continue;
            };
            let (lo, hi) = mesh.positions.iter().fold(
                ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
                |(lo, hi), p| {
                    (
                        [0, 1, 2].map(|a| lo[a].min(p[a])),
                        [0, 1, 2].map(|a| hi[a].max(p[a])),
                    )
                },
            );
            info.insert(
                class.to_string(),
                json!({
                    "diameter": diameter(&mesh.positions),
                    "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                    "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2],
                }),
            );
            let file = staging.dir().join(format!("obj_{class:06}.ply"));
            write(&file, &assist_session::mesh_ply(&mesh))?;
        }
        write(
            &staging.dir().join("models_info.json"),
            &pretty(&Value::Object(info)),
        )?;
        if !missing.is_empty() {
            write(
                &staging.dir().join("missing.json"),
                &pretty(&json!(missing)),
            )?;
        }
        staging.commit()?;
        Ok(())
    }

    /// The mesh of the first node of class `name` (base scenes, then the library), in
    /// millimetres in its box frame; `None` when its field has no surface.
    fn class_mesh(&self, name: &str) -> Option<assist_session::NodeMesh> {
        // Pose-error models need the shape, not export detail: 96 cells along the box's
        // longest side and at most 20,000 triangles (about half the time of the default).
        let opts = assist_session::ExtractOptions {
            resolution: 96,
            max_triangles: 20_000,
            ..Default::default()
        };
        for b in &self.bases {
            let scene = b.session.description();
            let mpu = scene.meters_per_unit;
            let found = scene
                .nodes
                .iter()
                .find(|n| !n.is_background() && n.class_name() == name)
                .map(|n| n.id);
            let mesh = match found {
                Some(id) => b.session.node_mesh(id, &opts).ok().map(|m| (m, mpu)),
                None => b
                    .library
                    .iter()
                    .find(|l| l.node.class_name() == name)
                    .and_then(|l| {
                        let other = assist_session::Session::open(Path::new(&l.scene)).ok()?;
                        let mpu = other.description().meters_per_unit;
                        other.node_mesh(l.id, &opts).ok().map(|m| (m, mpu))
                    }),
            };
            if let Some((mut m, mpu)) = mesh.filter(|(m, _)| m.triangles.len() >= 4) {
                for p in &mut m.positions {
                    *p = p.map(|v| v * mpu * 1000.0);
                }
                return Some(m);
            }
            if found.is_some() {
                return None;
            }
        }
        None
    }
}

/// The largest distance between two of `p`, exactly: a lower bound from the points
/// extreme along 26 directions, then only the points that could beat it (their farthest
/// corner of the bounding box is farther) are compared pairwise; a farthest pair has both
/// ends among them.
fn diameter(p: &[[f64; 3]]) -> f64 {
    let d2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>();
    let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut best = 0.0f64;
    for x in -1i32..=1 {
        for y in -1i32..=1 {
            for z in -1i32..=1 {
                let d = [x as f64, y as f64, z as f64];
                let (lo, hi) =
                    p.iter()
                        .fold((None::<&[f64; 3]>, None::<&[f64; 3]>), |(lo, hi), q| {
                            (
                                Some(lo.map_or(q, |l| if dot(q, &d) < dot(l, &d) { q } else { l })),
                                Some(hi.map_or(q, |h| if dot(q, &d) > dot(h, &d) { q } else { h })),
                            )
                        });
                if let (Some(a), Some(b)) = (lo, hi) {
                    best = best.max(d2(a, b));
                }
            }
        }
    }
    let (lo, hi) = p.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), q| {
            (
                [0, 1, 2].map(|a| lo[a].min(q[a])),
                [0, 1, 2].map(|a| hi[a].max(q[a])),
            )
        },
    );
    let far = |q: &[f64; 3]| {
        (0..3)
            .map(|a| (q[a] - lo[a]).abs().max((hi[a] - q[a]).abs()).powi(2))
            .sum::<f64>()
    };
    let rest: Vec<&[f64; 3]> = p.iter().filter(|q| far(q) > best).collect();
    for (i, a) in rest.iter().enumerate() {
        for b in &rest[i + 1..] {
            best = best.max(d2(a, b));
        }
    }
    best.sqrt()
}

#[cfg(test)]
mod tests {
    use super::diameter;

    #[test]
    fn the_diameter_is_the_farthest_pair() {
        let mut rng = assist_core::Rng::new(3);
        for n in [1usize, 2, 5, 50, 400] {
            let p: Vec<[f64; 3]> = (0..n)
                .map(|_| [rng.f64() * 3.0, rng.f64(), rng.f64() * 0.5 - 2.0])
                .collect();
            let mut want = 0.0f64;
            for a in &p {
                for b in &p {
                    want = want.max((0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt());
                }
            }
            assert!(
                (diameter(&p) - want).abs() < 1e-12,
                "{n}: {} vs {want}",
                diameter(&p)
            );
        }
    }
}
