//! One sample: draw the rearrangement, express it as actions, apply them through a forked
//! session, draw the cameras, render, annotate, and write the sample's folder atomically.

use std::path::Path;

use assist_core::action::NodeRef;
use assist_core::{
    Action, Camera, DAffine3, DMat3, DQuat, DVec3, Distortion, Intrinsics, Pose, Rng, Similarity3,
};
use assist_data::{DatasetWriter, WriterConfig};
use assist_session::{Frame, NamedCamera, RenderRequest, Session};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use crate::coco::{self, ViewObject};
use crate::place::Posed;
use crate::plan::Plan;
use crate::spec::CameraFrom;
use crate::{Base, GenError, Generator, Result};

/// Something a sample did not get.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaveUp {
    /// What was to be placed: `"move 3 \"red mug\""` or `"add library[0] \"duck\""`.
    pub what: String,
    pub tries: u32,
    /// The rejections, by reason.
    pub reasons: Vec<(String, u32)>,
    /// What became of it: `"stays"`, `"deleted"` or `"not added"`.
    pub outcome: String,
}

/// A sample in memory (see [`Generator::sample`]).
pub struct Sample {
    pub index: u64,
    /// Its edits of the base scene.
    pub actions: Vec<Action>,
    /// `sample.json`: objects, deletions, give-ups, draws, per-view annotations.
    pub record: Value,
    /// BOP `scene_camera.json` and `scene_gt.json`.
    pub scene_camera: Value,
    pub scene_gt: Value,
    /// How its views are written: the scene's units, up and objects, the generator's
    /// classes and outputs.
    pub writer: WriterConfig,
    /// Empty when not rendered.
    pub views: Vec<View>,
    pub report: SampleReport,
}

/// One rendered view of a sample.
pub struct View {
    pub camera: NamedCamera,
    /// RGB, z-depth (scene units), opacity, instance ids, each object's own layer.
    pub frame: Frame,
    /// Semantic class per pixel (the generator's classes).
    pub semantic: Vec<u16>,
    /// 255 where the pixel shows background no training view observed.
    pub unobserved: Vec<u8>,
    /// The COCO panoptic PNG's RGB bytes.
    pub coco_panoptic: Vec<u8>,
    /// The background alone, RGB (when the spec asks for it).
    pub background: Option<Vec<f32>>,
}

/// What a finished sample reports.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SampleReport {
    pub index: u64,
    pub objects: usize,
    pub draws: u32,
    pub rejected: u32,
    pub gave_up: Vec<GaveUp>,
    pub views: usize,
}

impl Generator {
    /// Draws the sample's cameras (after its placement, from the same stream).
    pub(crate) fn cameras(&self, plan: &mut Plan, session: &Session) -> Result<Vec<NamedCamera>> {
        let c = &self.spec.cameras;
        let o = &self.spec.output;
        let base = &self.bases[plan.base];
        let scene = session.description();
        let up = scene.up.normalize();
        let mpu = scene.meters_per_unit;
        let rng = &mut plan.rng;
        let target = c.look_at.as_ref().and_then(|r| {
            scene
                .nodes
                .iter()
                .find(|n| {
                    !n.is_background()
                        && match r {
                            NodeRef::Id(i) => n.id == *i,
                            NodeRef::Label(l) => n.label == *l,
                        }
                })
                .map(|n| n.world_from_local.translation)
        });
        let bad = |m: String| GenError::Sample {
            index: plan.index,
            message: format!("cameras: {m}"),
        };
        let mut out = Vec::new();
        for v in 0..c.views {
            let camera = if c.from == CameraFrom::Orbit {
                let (lo, hi) = assist_session::objects_box(scene);
                let centre = target.unwrap_or((lo + hi) * 0.5);
                let half = ((hi - lo) * 0.5).length().max(1e-6);
                let intr = Intrinsics::from_fov_x(o.width, o.height, c.fov_deg.to_radians());
                let fov_y = 2.0
                    * ((0.5 * c.fov_deg.to_radians()).tan() * o.height as f64 / o.width as f64)
                        .atan();
                let frame_r = 1.15 * half / (0.5 * fov_y.min(c.fov_deg.to_radians())).sin();
                let f = crate::surface::UpFrame::new(up);
                let dir = orbit_direction(rng, c, &f, up, centre, &base.cameras).map_err(bad)?;
                // Where the capture stood: no nearer or farther than its cameras.
                let (near, far) = base
                    .cameras
                    .iter()
                    .map(|n| (n.camera.pose.center() - centre).length())
                    .fold((f64::INFINITY, 0.0f64), |(a, b), d| (a.min(d), b.max(d)));
                let r = if near <= far {
                    frame_r.clamp(near, far)
                } else {
                    frame_r
                };
                let pose =
                    Pose::look_at(centre + dir * r, centre, up).map_err(|e| bad(e.to_string()))?;
                Camera {
                    intrinsics: intr,
                    pose,
                }
            } else {
                let from = &base.cameras[rng.below(base.cameras.len() as u64) as usize];
                let mut cam = Session::sized(&from.camera, Some((o.width, o.height)))?;
                cam.intrinsics.distortion = Distortion::None;
                // Jitter: a point in a ball, a turn about a random axis.
                let radius = c.jitter_m / mpu;
                let dp = loop {
                    let d = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 2.0 - 1.0;
                    if d.length_squared() <= 1.0 {
                        break d * radius;
                    }
                };
                let axis = loop {
                    let d = DVec3::new(rng.normal(), rng.normal(), rng.normal());
                    if d.length_squared() > 1e-9 {
                        break d.normalize();
                    }
                };
                let angle = rng.range(0.0, c.jitter_deg).to_radians();
                let eye = cam.pose.center() + dp;
                let pose = match target {
                    Some(t) => Pose::look_at(eye, t, up).map_err(|e| bad(e.to_string()))?,
                    None => {
                        let r = DMat3::from_quat(DQuat::from_axis_angle(axis, angle))
                            * cam.pose.rotation();
                        Pose {
                            world_from_camera: DAffine3::from_mat3_translation(r, eye),
                        }
                    }
                };
                cam.pose = pose;
                cam
            };
            out.push(NamedCamera {
                name: format!("v{v}"),
                camera,
            });
        }
        Ok(out)
    }

    /// Sample `index` in memory: its actions, record, BOP files and (with `render`) its
    /// rendered views with their annotations — what [`make`](Self::make) writes, and what
    /// Python's `assist.generate` yields.
    pub fn sample(&self, index: u64, render: bool) -> Result<Sample> {
        let mut plan = self.plan(index)?;
        let session = self.apply(&plan)?;
        let cameras = self.cameras(&mut plan, &session)?;
        let base = &self.bases[plan.base];
        let objects = self.objects_json(&plan, base, session.description());
        let (scene_camera, scene_gt) = self.bop_cameras(&cameras, session.description());
        let (views, views_json) = if render {
            self.render_views(base, &session, &cameras)?
        } else {
            (Vec::new(), Vec::new())
        };
        let report = SampleReport {
            index,
            objects: objects.len(),
            draws: plan.draws,
            rejected: plan.rejected,
            gave_up: plan.gave_up.clone(),
            views: cameras.len(),
        };
        let sample = json!({
            "index": index,
            "seed": self.spec.seed,
            "scene": base.path,
            "objects": objects,
            "deleted": plan.deleted,
            "gave_up": plan.gave_up,
            "draws": plan.draws,
            "rejected": plan.rejected,
            "rejections": plan
                .rejections
                .iter()
                .map(|(r, k)| (r.name().to_string(), json!(k)))
                .collect::<serde_json::Map<String, Value>>(),
            "views": views_json,
            "rendered": render,
        });
        let writer = WriterConfig {
            classes: self.classes.clone(),
            ..session.writer_config(self.outputs.clone())
        };
        Ok(Sample {
            index,
            actions: plan.actions.clone(),
            record: sample,
            scene_camera: Value::Object(scene_camera),
            scene_gt: Value::Object(scene_gt),
            writer,
            views,
            report,
        })
    }

    /// The generator's class id of a label (0, the background's, when it has none).
    fn class_of(&self, label: &str) -> u16 {
        self.classes.iter().position(|c| c == label).unwrap_or(0) as u16
    }

    /// The sample's objects as they stand, for `sample.json`: pose, class, whether the
    /// plan added, moved or kept each, and the box its occupancy fills.
    fn objects_json(&self, plan: &Plan, base: &Base, scene: &assist_core::Scene) -> Vec<Value> {
        let up = scene.up.normalize();
        let mut objects = Vec::new();
        for n in scene.nodes.iter().filter(|n| !n.is_background()) {
            let posed = Posed::of(n);
            let placed = plan.placed.iter().find(|p| p.id == n.id);
            let shape = match placed.and_then(|p| p.library) {
                Some(k) => base.library[k].shape.clone(),
                None => base.shapes.get(&n.field).cloned().flatten(),
            };
            let status = match placed {
                Some(p) if p.library.is_some() => "added",
                Some(_) => "moved",
                None => "stays",
            };
            let mut o = json!({
                "id": n.id,
                "label": n.label,
                "class": self.class_of(n.class_name()),
                "status": status,
                "pose": pose_json(&n.world_from_local),
                "half_size": n.half_size.to_array(),
            });
            if let Some(p) = placed {
                o["yaw_deg"] = json!(p.yaw_deg);
                o["scale"] = json!(p.scale);
                o["support"] = json!(p.support);
                if let Some(k) = p.library {
                    o["library"] = json!(k);
                }
            }
            if let Some(s) = &shape {
                let b = posed.occupied_box(s);
                o["bottom"] = json!(posed.bottom(s, up));
                o["occupied_box"] = json!({
                    "center": b.center.to_array(),
                    "half_size": b.half_size.to_array(),
                    "rotation": rows(&b.rotation),
                });
            }
            objects.push(o);
        }
        objects
    }

    /// BOP's `scene_camera.json` and `scene_gt.json` entries of each camera (millimetres).
    fn bop_cameras(
        &self,
        cameras: &[NamedCamera],
        scene: &assist_core::Scene,
    ) -> (
        serde_json::Map<String, Value>,
        serde_json::Map<String, Value>,
    ) {
        let mpu = scene.meters_per_unit;
        let mut scene_camera = serde_json::Map::new();
        let mut scene_gt = serde_json::Map::new();
        for (v, c) in cameras.iter().enumerate() {
            let cam = &c.camera;
            let i = &cam.intrinsics;
            let r_c2w = cam.pose.rotation_opencv();
            let r_w2c = r_c2w.transpose();
            let t_w2c = -(r_w2c * cam.pose.center());
            let mm = 1000.0 * mpu;
            scene_camera.insert(
                v.to_string(),
                json!({
                    "cam_K": [i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0],
                    "cam_R_w2c": flat(&r_w2c),
                    "cam_t_w2c": (t_w2c * mm).to_array(),
                    "depth_scale": 1.0,
                    "width": i.width,
                    "height": i.height,
                }),
            );
            let gt: Vec<Value> = scene
                .nodes
                .iter()
                .filter(|n| !n.is_background())
                .map(|n| {
                    let r = r_w2c * DMat3::from_quat(n.world_from_local.rotation);
                    let t = r_w2c * n.world_from_local.translation + t_w2c;
                    json!({
                        "obj_id": self.class_of(n.class_name()),
                        "inst_id": n.id,
                        "cam_R_m2c": flat(&r),
                        "cam_t_m2c": (t * mm).to_array(),
                        "scale": n.world_from_local.scale.to_array(),
                    })
                })
                .collect();
            scene_gt.insert(v.to_string(), Value::Array(gt));
        }
        (scene_camera, scene_gt)
    }

    /// Each camera's render (with the background alone when the outputs ask for it),
    /// semantic classes and annotations.
    fn render_views(
        &self,
        base: &Base,
        session: &Session,
        cameras: &[NamedCamera],
    ) -> Result<(Vec<View>, Vec<Value>)> {
        let mut views = Vec::new();
        let mut views_json = Vec::new();
        // Every output from one render: the background alone from the same samples.
        let req = RenderRequest {
            layers: true,
            background: self.outputs.contains(&assist_data::Output::Background),
            ..Default::default()
        };
        for c in cameras {
            let mut frame = session.render(&c.camera, &req)?;
            let bg = req
                .background
                .then(|| std::mem::take(&mut frame.background));
            let (annotations, unobserved, coco_panoptic) =
                self.annotate(base, session, &c.name, &c.camera, &frame);
            views_json.push(annotations);
            let semantic = frame
                .panoptic
                .iter()
                .map(|&id| {
                    session
                        .node(id)
                        .filter(|n| !n.is_background())
                        .map(|n| self.class_of(n.class_name()))
                        .unwrap_or(0)
                })
                .collect();
            views.push(View {
                camera: c.clone(),
                frame,
                semantic,
                unobserved,
                coco_panoptic,
                background: bg,
            });
        }
        Ok((views, views_json))
    }

    /// Writes sample `s` into `dir` (a staging folder the caller commits).
    pub(crate) fn write_sample(&self, s: &Sample, dir: &Path, dry_run: bool) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
        // The actions, one per line: `assist edit BASE --actions actions.jsonl` replays them.
        let mut lines = String::new();
        for a in &s.actions {
            lines.push_str(&serde_json::to_string(a).expect("actions serialise"));
            lines.push('\n');
        }
        write(&dir.join("actions.jsonl"), lines.as_bytes())?;
        write(&dir.join("scene_camera.json"), &pretty(&s.scene_camera))?;
        write(&dir.join("scene_gt.json"), &pretty(&s.scene_gt))?;
        if !dry_run {
            let vdir = dir.join("views");
            let writer = DatasetWriter::create_in(&vdir, s.writer.clone())?;
            for (k, v) in s.views.iter().enumerate() {
                let f = &v.frame;
                let layers = assist_session::frame_layers(f);
                let img = assist_session::view_images(
                    f,
                    if writer.wants(assist_data::Output::Objects) {
                        &layers
                    } else {
                        &[]
                    },
                    v.background.as_deref(),
                );
                writer.write(k, &v.camera.name, &v.camera.camera, &img)?;
                let name = &v.camera.name;
                let (w, h) = (f.width, f.height);
                for (sub, what) in [("panoptic_coco", 0), ("unobserved", 1)] {
                    let d = vdir.join(sub);
                    std::fs::create_dir_all(&d).map_err(|e| io(&d, e))?;
                    let file = d.join(format!("{name}.png"));
                    if what == 0 {
                        assist_data::image_io::write_rgb8_png(&file, w, h, &v.coco_panoptic)?;
                    } else {
                        assist_data::image_io::write_gray8_png(&file, w, h, &v.unobserved)?;
                    }
                }
            }
            writer.finish()?;
            crate::bop::write_sample(dir, s)?;
        }
        write(&dir.join("sample.json"), &pretty(&s.record))
    }

    /// A rendered view's annotations: each object's visible and amodal extent, its COCO
    /// mask, the COCO panoptic image, and the unobserved-background mask.
    fn annotate(
        &self,
        base: &Base,
        session: &Session,
        name: &str,
        camera: &Camera,
        f: &Frame,
    ) -> (Value, Vec<u8>, Vec<u8>) {
        let (w, h) = (f.width as usize, f.height as usize);
        let class_of =
            |label: &str| self.classes.iter().position(|c| c == label).unwrap_or(0) as u16;
        let mut objs = Vec::new();
        for layer in &f.layers {
            if layer.id == 0 {
                continue;
            }
            let Some(n) = session.node(layer.id) else {
                continue;
            };
            let vis = |q: usize| f.panoptic[q] == layer.id;
            let amo = |q: usize| layer.opacity[q] >= 0.5 || f.panoptic[q] == layer.id;
            let visible = (0..w * h).filter(|&q| vis(q)).count() as u64;
            let amodal = (0..w * h).filter(|&q| amo(q)).count() as u64;
            objs.push(ViewObject {
                id: layer.id,
                class: class_of(n.class_name()),
                visible_pixels: visible,
                amodal_pixels: amodal,
                visibility: if amodal > 0 {
                    visible as f64 / amodal as f64
                } else {
                    0.0
                },
                bbox_visible: coco::bbox(w, h, vis),
                bbox_amodal: coco::bbox(w, h, amo),
                rle: (visible > 0).then(|| coco::rle_string(&coco::rle_counts(w, h, vis))),
                polygons: coco::polygons(w, h, vis),
            });
        }
        // COCO panoptic: segment id = instance id, background = 65536.
        let mut rgb = vec![0u8; 3 * w * h];
        for (q, &id) in f.panoptic.iter().enumerate() {
            let s: u32 = if id == 0 { 1 << 16 } else { id as u32 };
            rgb[3 * q] = (s & 255) as u8;
            rgb[3 * q + 1] = (s >> 8 & 255) as u8;
            rgb[3 * q + 2] = (s >> 16 & 255) as u8;
        }
        let mask = crate::surface::unobserved_mask(&base.seen, camera, f);
        let unseen = mask.iter().filter(|&&m| m != 0).count();
        let background = f.panoptic.iter().filter(|&&id| id == 0).count();
        let background_bbox = coco::bbox(w, h, |q| f.panoptic[q] == 0);
        let j = json!({
            "name": name,
            "width": w,
            "height": h,
            "objects": objs,
            "background_pixels": background,
            "background_bbox": background_bbox,
            "unobserved_pixels": unseen,
        });
        (j, mask, rgb)
    }
}

/// Draws of an orbit view's direction before a sample gives up.
const ORBIT_TRIES: usize = 1000;

/// An orbit view's direction from `centre` (unit): azimuth uniform, elevation uniform in
/// the spec's range, redrawn until it lies within `orbit_within_deg` of the direction of
/// some camera in `captured` (the training views) from the centre.
fn orbit_direction(
    rng: &mut Rng,
    c: &crate::spec::Cameras,
    f: &crate::surface::UpFrame,
    up: DVec3,
    centre: DVec3,
    captured: &[NamedCamera],
) -> std::result::Result<DVec3, String> {
    let seen: Vec<DVec3> = captured
        .iter()
        .filter_map(|n| (n.camera.pose.center() - centre).try_normalize())
        .collect();
    let cos_max = c.orbit_within_deg.to_radians().cos();
    for _ in 0..ORBIT_TRIES {
        let az = rng.range(0.0, std::f64::consts::TAU);
        let el = rng
            .range(c.elevation_deg[0], c.elevation_deg[1])
            .to_radians();
        let dir = (f.e1 * az.cos() + f.e2 * az.sin()) * el.cos() + up * el.sin();
        if c.orbit_within_deg >= 180.0 || seen.iter().any(|s| s.dot(dir) >= cos_max) {
            return Ok(dir);
        }
    }
    let (lo, hi) = seen
        .iter()
        .map(|s| s.dot(up).clamp(-1.0, 1.0).asin().to_degrees())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
            (a.min(e), b.max(e))
        });
    Err(format!(
        "no orbit view within {}° of a training camera in {ORBIT_TRIES} draws at elevations \
         {}–{}°; the training cameras see the orbit's centre from elevations {lo:.0}–{hi:.0}° \
         (widen cameras.elevation_deg or cameras.orbit_within_deg)",
        c.orbit_within_deg, c.elevation_deg[0], c.elevation_deg[1]
    ))
}

fn rows(m: &DMat3) -> Vec<[f64; 3]> {
    (0..3).map(|r| m.row(r).to_array()).collect()
}

fn flat(m: &DMat3) -> Vec<f64> {
    (0..3).flat_map(|r| m.row(r).to_array()).collect()
}

fn pose_json(p: &Similarity3) -> Value {
    json!({
        "rotation": rows(&DMat3::from_quat(p.rotation)),
        "translation": p.translation.to_array(),
        "scale": p.scale.to_array(),
    })
}

pub(crate) fn pretty(v: &Value) -> Vec<u8> {
    let mut s = serde_json::to_vec_pretty(v).expect("json serialises");
    s.push(b'\n');
    s
}

pub(crate) fn io(path: &Path, e: std::io::Error) -> GenError {
    GenError::Data(assist_data::DataError::io(path, e))
}

pub(crate) fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| io(path, e))
}
