//! A masks folder any tool reads: one 8-bit PNG per image of a dataset, named like it
//! (0 = background, else the instance id), `instances.json` (ids, labels, world boxes)
//! and `masks.json` (how they were made). `assist train DATA --masks DIR` trains its
//! objects; `assist scene split` writes one for its fine-tune.

use std::path::Path;

use assist_core::{InstanceId, Obb, SceneNode};
use assist_data::{Dataset, image_io};
use serde_json::json;

use super::click::render_size;
use super::sam::{SamCount, SamRefine};
use super::{MaskOptions, SplitBox};
use crate::{Result, Session, SessionError, request};

/// Where writing a masks folder stands.
#[derive(Debug, Clone, Copy)]
pub enum MaskProgress {
    /// Views rendered (the support under each box comes from all of them).
    Rendering { done: usize, total: usize },
    /// Masks refined on their photographs and written.
    Refining { done: usize, total: usize },
}

/// What a masks folder holds.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MasksWritten {
    pub images: usize,
    /// Per new object, the height above its box's base below which surfaces are its
    /// support (world units).
    pub support_levels: Vec<f64>,
    /// Per new object, the height above its box's base where its support's layer ends
    /// (the object's sides reach down to it).
    pub support_bases: Vec<f64>,
    pub objects: Vec<Owned>,
    pub seconds: f64,
    /// With a SAM checkpoint: the object masks it was asked for and those it replaced.
    pub sam: Option<SamCount>,
}

/// A new object and the pixels it owns over all images.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Owned {
    pub id: InstanceId,
    pub label: String,
    pub pixels: u64,
}

/// A node's box in world units.
pub fn node_obb(n: &SceneNode) -> Obb {
    let w = &n.world_from_local;
    Obb::new(
        w.transform_point(assist_core::DVec3::ZERO),
        n.half_size * 2.0 * w.scale,
        w.rotation_matrix(),
    )
}

fn io_error(path: &Path, e: impl std::fmt::Display) -> SessionError {
    request("masks", format!("writing {}: {e}", path.display()))
}

impl Session {
    /// Writes the masks of `boxes` for every frame of `ds` into the folder `dir` (which
    /// exists; the caller stages it), rendering at `render_downscale` and refining on
    /// each photograph. With `keep_existing`, pixels no box claims keep the scene's own
    /// objects (rendered), and `instances.json` lists those too.
    pub fn write_masks(
        &self,
        ds: &Dataset,
        boxes: &[SplitBox],
        dir: &Path,
        render_downscale: u32,
        keep_existing: bool,
        sam: Option<&SamRefine>,
        mut on: impl FnMut(MaskProgress),
    ) -> Result<MasksWritten> {
        let started = std::time::Instant::now();
        let opts = MaskOptions::default();
        let n = ds.frames.len();
        let size = |c: &assist_core::Camera| Some(render_size(c, render_downscale as f64));
        let mut seen = Vec::with_capacity(n);
        for (k, f) in ds.frames.iter().enumerate() {
            seen.push(self.boxes_in_view(&f.camera, boxes, size(&f.camera))?);
            on(MaskProgress::Rendering {
                done: k + 1,
                total: n,
            });
        }
        let levels = self.support_levels(boxes, &seen, &opts);
        // One view's mask, refined and written: its pixels per box, and SAM's count.
        let one = |f: &assist_data::Frame, view: &super::BoxView| -> Result<(Vec<u64>, SamCount)> {
            // Photographs are read one at a time, as each mask is refined.
            let photo = image_io::read_rgb(&f.image_path, [0.0; 3])
                .map_err(SessionError::Data)?
                .0;
            let mut ids = view.mask(boxes, &levels, Some(&photo), &opts);
            let count = match sam {
                Some(sam) => sam.refine(&photo, &mut ids, boxes)?,
                None => SamCount::default(),
            };
            let owned = boxes
                .iter()
                .map(|b| ids.iter().filter(|&&v| v == b.id).count() as u64)
                .collect();
            if keep_existing {
                ids = view.with_existing(ids, photo.width as usize, photo.height as usize);
            }
            let path = dir.join(format!(
                "{}.png",
                assist_data::dataset::file_stem(&f.image_path)
            ));
            let bytes: Vec<u8> = ids.iter().map(|&v| v.min(255) as u8).collect();
            image_io::write_gray8_png(&path, photo.width, photo.height, &bytes)
                .map_err(SessionError::Data)?;
            Ok((owned, count))
        };
        let mut owned = vec![0u64; boxes.len()];
        let mut sam_count = SamCount::default();
        let mut add = |(o, c): (Vec<u64>, SamCount)| {
            for (a, b) in owned.iter_mut().zip(o) {
                *a += b;
            }
            sam_count.prompted += c.prompted;
            sam_count.replaced += c.replaced;
        };
        let refining = |done| MaskProgress::Refining { done, total: n };
        if sam.is_some() {
            // SAM's encoder keeps both cores busy on one photograph.
            for (k, (f, view)) in ds.frames.iter().zip(&seen).enumerate() {
                add(one(f, view)?);
                on(refining(k + 1));
            }
        } else {
            // A view's refinement is mostly serial: the views share the cores, a few at a
            // time so that progress is told as they finish.
            use rayon::prelude::*;
            let chunk = 2 * rayon::current_num_threads();
            let mut done = 0;
            for (frames, views) in ds.frames.chunks(chunk).zip(seen.chunks(chunk)) {
                let made: Vec<_> = frames
                    .par_iter()
                    .zip(views)
                    .map(|(f, view)| one(f, view))
                    .collect();
                for r in made {
                    add(r?);
                    done += 1;
                    on(refining(done));
                }
            }
        }
        let mut listed: Vec<(InstanceId, String, Obb)> = Vec::new();
        if keep_existing {
            for node in self.description().objects() {
                listed.push((node.id, node.label.clone(), node_obb(node)));
            }
        }
        listed.extend(boxes.iter().map(|b| (b.id, b.label.clone(), b.obb)));
        let instances: Vec<_> = listed
            .iter()
            .map(|(id, label, obb)| {
                let r = obb.rotation;
                json!({
                    "id": id,
                    "label": label,
                    "bbox": {
                        "center": obb.center.to_array(),
                        "size": obb.size().to_array(),
                        "rotation": (0..3).map(|i| (0..3).map(|j| r.col(j)[i]).collect::<Vec<_>>()).collect::<Vec<_>>(),
                    },
                })
            })
            .collect();
        let written = MasksWritten {
            images: n,
            support_levels: levels.iter().map(|l| l.cut).collect(),
            support_bases: levels.iter().map(|l| l.base).collect(),
            objects: boxes
                .iter()
                .zip(&owned)
                .map(|(b, &pixels)| Owned {
                    id: b.id,
                    label: b.label.clone(),
                    pixels,
                })
                .collect(),
            seconds: started.elapsed().as_secs_f64(),
            sam: sam.map(|_| sam_count),
        };
        let path = dir.join(assist_data::masks::INSTANCES_FILE);
        let text = serde_json::to_string_pretty(&json!({ "instances": instances }))
            .map_err(|e| io_error(&path, e))?;
        std::fs::write(&path, text).map_err(|e| io_error(&path, e))?;
        let path = dir.join("masks.json");
        let mut record = serde_json::to_value(&written).map_err(|e| io_error(&path, e))?;
        record["data"] = json!(ds.root);
        record["render_downscale"] = json!(render_downscale);
        if let Some(sam) = sam {
            record["sam_checkpoint"] = json!(sam.path);
        }
        let text = serde_json::to_string_pretty(&record).map_err(|e| io_error(&path, e))?;
        std::fs::write(&path, text).map_err(|e| io_error(&path, e))?;
        Ok(written)
    }
}
