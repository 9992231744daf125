//! Renders a synth scene and writes it in the desk format, atomically (into a temporary
//! folder beside the output, renamed into place at the end).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use assist_core::{Camera, DVec3, Rng};
use rayon::prelude::*;
use serde_json::{Value, json};

use super::scene::{CameraPath, Object, Scene, build_scene, cameras};
use super::trace::render_view;
use crate::error::{DataError, Result};
use crate::image_io::write_atomic;
use crate::writer::{DatasetWriter, IdImages, Instance, Output, ViewImages, WriterConfig};

#[derive(Debug, Clone)]
pub struct SynthConfig {
    pub seed: u64,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub objects: usize,
    /// Colour samples per pixel (anti-aliasing).
    pub spp: u32,
    /// Light samples per colour sample (soft shadows).
    pub shadow_samples: u32,
    /// Where the cameras stand.
    pub path: CameraPath,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            seed: 0,
            views: 60,
            width: 128,
            height: 96,
            objects: 5,
            spp: 4,
            shadow_samples: 4,
            path: CameraPath::Spiral,
        }
    }
}

impl SynthConfig {
    pub fn validate(&self) -> Result<()> {
        let bad = |f: &str, m: String| Err(DataError::field("synth", f, m));
        if !(3..=6).contains(&self.objects) {
            return bad(
                "--objects",
                format!("expected 3 to 6 objects, got {}", self.objects),
            );
        }
        if self.views < 6 {
            return bad(
                "--views",
                format!(
                    "expected at least 6 views (one in six is a test view), got {}",
                    self.views
                ),
            );
        }
        if self.views > 10_000 {
            return bad(
                "--views",
                format!("expected at most 10000 views, got {}", self.views),
            );
        }
        if !(16..=4096).contains(&self.width) || !(16..=4096).contains(&self.height) {
            return bad(
                "--width/--height",
                format!(
                    "expected 16 to 4096 pixels, got {}x{}",
                    self.width, self.height
                ),
            );
        }
        if self.spp == 0 || self.spp > 256 || self.shadow_samples == 0 || self.shadow_samples > 256
        {
            return bad("--spp", "expected 1 to 256 samples".into());
        }
        Ok(())
    }
}

/// What was written.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SynthSummary {
    pub out: PathBuf,
    pub views: usize,
    pub train: usize,
    pub test: usize,
    pub objects: Vec<(u16, String)>,
    pub edits: Vec<String>,
    pub images_written: usize,
}

/// Test views are the frames with `i % 6 == 3`, as in desk.
pub fn is_test(i: usize) -> bool {
    i % 6 == 3
}

/// The writer of one of synth's datasets (the scene, the background alone, an edit): the
/// desk format, 8-bit instance images, with the scene's objects and their boxes.
fn writer(dir: &Path, cfg: &SynthConfig, objects: Option<&[Object]>) -> Result<DatasetWriter> {
    let mut outputs = vec![Output::Rgb, Output::Depth];
    if objects.is_some() {
        outputs.push(Output::Panoptic);
    }
    let extra = json!({
        "meters_per_unit": 1.0,
        "table_top_z": super::scene::TABLE_Z,
        "renderer": format!("assist synth (seed {}, {} spp, {} light samples)", cfg.seed, cfg.spp, cfg.shadow_samples),
    });
    let instances = objects
        .unwrap_or_default()
        .iter()
        .map(|o| Instance {
            id: o.id,
            label: o.label.clone(),
            class: None,
            bbox: Some(o.obb()),
        })
        .collect();
    let cfg = WriterConfig {
        outputs,
        instances,
        id_images: IdImages::Instances8,
        extra: extra.as_object().cloned().unwrap_or_default(),
        ..WriterConfig::default()
    };
    DatasetWriter::create_in(dir, cfg)
}

struct Job {
    writer: usize,
    scene_idx: usize,
    view: usize,
}

fn edit_name(op: &str, label: &str) -> String {
    let slug: String = label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect();
    format!("{op}_{slug}")
}

/// The three edits: translate one object to a free spot, rotate another about its box
/// centre, delete a third.
fn make_edits(scene: &Scene, rng: &mut Rng) -> Vec<(String, Value, Scene)> {
    let n = scene.objects.len();
    let mut order: Vec<usize> = (0..n).collect();
    rng.shuffle(&mut order);
    // Rotate a box (a rotation is visible on it); translate and delete two others.
    if let Some(k) = order
        .iter()
        .position(|&i| matches!(scene.objects[i].shape, super::scene::Shape::Box { .. }))
    {
        order.swap(1, k);
    }
    let mut out = Vec::new();
    // Translate.
    let a = &scene.objects[order[0]];
    let rad = a.shape.footprint_radius();
    let mut offset = DVec3::ZERO;
    for _ in 0..2000 {
        let ang = rng.range(0.0, std::f64::consts::TAU);
        let len = rng.range(0.08, 0.2);
        let cand = DVec3::new(len * ang.cos(), len * ang.sin(), 0.0);
        let nb = a.base + cand;
        let on_table = nb.x.abs() < 0.6 && nb.y.abs() < 0.38;
        let free =
            scene.objects.iter().filter(|o| o.id != a.id).all(|o| {
                (o.base - nb).truncate().length() > rad + o.shape.footprint_radius() + 0.02
            });
        if on_table && free {
            offset = (cand * 1000.0).round() / 1000.0;
            break;
        }
    }
    if offset != DVec3::ZERO {
        let mut s = scene.clone();
        s.objects[order[0]].base += offset;
        out.push((edit_name("translate", &a.label), json!({"instance_id": a.id, "operation": "translate", "config": {"offset": offset.to_array()}}), s));
    }
    // Rotate (about world +Z through the box centre; the base centre is on that axis).
    let b = &scene.objects[order[1 % n]];
    let degrees = [45.0, 60.0, 90.0, -45.0, -60.0, -90.0][rng.below(6) as usize];
    let mut s = scene.clone();
    s.objects[order[1 % n]].yaw += f64::to_radians(degrees);
    out.push((edit_name("rotate", &b.label), json!({"instance_id": b.id, "operation": "rotate", "config": {"axis": "z", "degrees": degrees, "center": b.obb().center.to_array()}}), s));
    // Delete.
    let c = &scene.objects[order[2 % n]];
    out.push((
        edit_name("delete", &c.label),
        json!({"instance_id": c.id, "operation": "delete", "config": {}}),
        scene.without(c.id),
    ));
    out
}

/// Generates the scene and writes the dataset to `out`. Refuses to replace an existing
/// non-empty folder unless `force`. `progress(done, total)` is called as views finish.
pub fn generate(
    cfg: &SynthConfig,
    out: &Path,
    force: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<SynthSummary> {
    cfg.validate()?;
    assist_fs::check_replaceable_as(out, force, assist_fs::Kind::Dataset)?;
    let mut rng = Rng::new(cfg.seed);
    let scene = build_scene(&mut rng, cfg.objects);
    let cams = cameras(&mut rng, cfg.views, cfg.width, cfg.height, cfg.path);
    let edits = make_edits(&scene, &mut rng);
    // Written whole beside `out` and swapped into place.
    let staging = assist_fs::Staging::begin(out, "synth")?;
    write_all(cfg, staging.dir(), &scene, &cams, &edits, progress)?;
    staging.commit()?;
    let test = (0..cfg.views).filter(|&i| is_test(i)).count();
    Ok(SynthSummary {
        out: out.to_path_buf(),
        views: cfg.views,
        train: cfg.views - test,
        test,
        objects: scene
            .objects
            .iter()
            .map(|o| (o.id, o.label.clone()))
            .collect(),
        edits: edits.iter().map(|e| e.0.clone()).collect(),
        images_written: cfg.views + test * (1 + edits.len()),
    })
}

fn write_all(
    cfg: &SynthConfig,
    dir: &Path,
    scene: &Scene,
    cams: &[Camera],
    edits: &[(String, Value, Scene)],
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<()> {
    let tests: Vec<usize> = (0..cams.len()).filter(|&i| is_test(i)).collect();
    let bg = scene.without_objects();
    let mut scenes = vec![scene.clone(), bg];
    let mut writers = vec![
        writer(dir, cfg, Some(&scene.objects))?,
        writer(&dir.join("background"), cfg, None)?,
    ];
    let mut jobs: Vec<Job> = (0..cams.len())
        .map(|v| Job {
            writer: 0,
            scene_idx: 0,
            view: v,
        })
        .collect();
    jobs.extend(tests.iter().map(|&v| Job {
        writer: 1,
        scene_idx: 1,
        view: v,
    }));
    for (name, edit, s) in edits {
        let ed = dir.join("edits").join(name);
        writers.push(writer(&ed, cfg, Some(&s.objects))?);
        write_atomic(
            &ed.join("edit.json"),
            serde_json::to_string_pretty(edit).unwrap().as_bytes(),
        )?;
        scenes.push(s.clone());
        let (w, idx) = (writers.len() - 1, scenes.len() - 1);
        jobs.extend(tests.iter().map(|&v| Job {
            writer: w,
            scene_idx: idx,
            view: v,
        }));
    }
    let done = AtomicUsize::new(0);
    let total = jobs.len();
    progress(0, total);
    jobs.par_iter().try_for_each(|job| -> Result<()> {
        let cam = &cams[job.view];
        // The same noise seed per view in every variant, so unchanged pixels stay identical.
        let r = render_view(
            &scenes[job.scene_idx],
            cam,
            cfg.seed
                .wrapping_mul(0x100_0001)
                .wrapping_add(job.view as u64),
            cfg.spp,
            cfg.shadow_samples,
        );
        let view = ViewImages {
            width: cam.width(),
            height: cam.height(),
            rgb: &r.rgb,
            depth: &r.depth,
            panoptic: &r.ids,
            ..Default::default()
        };
        writers[job.writer].write(job.view, &format!("r_{:03}", job.view), cam, &view)?;
        progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        Ok(())
    })?;
    for w in writers {
        w.finish()?;
    }
    let split = json!({"train": (0..cams.len()).filter(|&i| !is_test(i)).collect::<Vec<_>>(), "test": tests});
    write_atomic(
        &dir.join("split.json"),
        serde_json::to_string_pretty(&split).unwrap().as_bytes(),
    )
}
