//! Datasets out: the inverse of the nerfstudio reader. A [`DatasetWriter`] takes rendered
//! views (colour, z-depth, instance ids, per-object layers, the background alone) and
//! writes a folder that our readers and nerfstudio's read back:
//!
//! - `images/NAME.png`: RGB;
//! - `depth/NAME.png` (16-bit, millimetres) and `depth/NAME.npy` (float32, scene units);
//! - `panoptic/NAME.png`: 16-bit instance ids (0 = background) + `panoptic_legend.json`;
//! - `semantic/NAME.png`: 16-bit class ids, one class per distinct label (0 = background)
//!   + `semantic_legend.json`;
//! - `objects/ID/NAME.png`: each object's own colour, alpha = its opacity;
//! - `background/NAME.png`: the background node alone;
//! - `unseen/NAME.png`: 8-bit, 255 where no ray met a sample (what no training view saw,
//!   its colour and depth continued from the seen pixels around it), else 0;
//! - `transforms.json`: an OPENCV camera per frame, `depth_file_path`,
//!   `instance_mask_path`, `depth_unit_scale_factor`, `world_up` and the `instances`.
//!
//! With [`IdImages::Instances8`] the ids go to `instances/NAME.png` as 8-bit grey values
//! instead (the desk format `synth` writes). Every file is written atomically; the writer
//! refuses a non-empty folder unless told to write into it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use assist_core::{Camera, Obb};
use serde_json::{Value, json};

use crate::error::{DataError, Result};
use crate::image_io::{ImageF32, write_atomic, write_gray8_png, write_gray16_png, write_rgb_png};

/// One kind of file a view is written as.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Output {
    Rgb,
    Depth,
    Panoptic,
    Semantic,
    Objects,
    Background,
    Unseen,
}

impl Output {
    pub const ALL: [Output; 7] = [
        Output::Rgb,
        Output::Depth,
        Output::Panoptic,
        Output::Semantic,
        Output::Objects,
        Output::Background,
        Output::Unseen,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Output::Rgb => "rgb",
            Output::Depth => "depth",
            Output::Panoptic => "panoptic",
            Output::Semantic => "semantic",
            Output::Objects => "objects",
            Output::Background => "background",
            Output::Unseen => "unseen",
        }
    }

    /// The folder the output's files go to.
    pub fn folder(self) -> &'static str {
        match self {
            Output::Rgb => "images",
            other => other.name(),
        }
    }

    /// One output by name (`instances` and `layers` are accepted as aliases).
    pub fn parse(word: &str) -> std::result::Result<Output, String> {
        Ok(match word {
            "rgb" => Output::Rgb,
            "depth" => Output::Depth,
            "panoptic" | "instances" => Output::Panoptic,
            "semantic" => Output::Semantic,
            "objects" | "layers" => Output::Objects,
            "background" => Output::Background,
            "unseen" => Output::Unseen,
            other => {
                return Err(format!(
                    "unknown output {other:?}; expected rgb, depth, panoptic, semantic, objects, background, unseen"
                ));
            }
        })
    }

    /// A comma-separated list, sorted and without repeats; at least one.
    pub fn parse_list(s: &str) -> std::result::Result<Vec<Output>, String> {
        let mut v = s
            .split(',')
            .map(str::trim)
            .filter(|w| !w.is_empty())
            .map(Output::parse)
            .collect::<std::result::Result<Vec<_>, _>>()?;
        if v.is_empty() {
            return Err("expected at least one output".into());
        }
        v.sort();
        v.dedup();
        Ok(v)
    }
}

/// An object of the written scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    pub id: u16,
    pub label: String,
    /// Its semantic class when it differs from the label (a replica "mug 2" is a "mug").
    pub class: Option<String>,
    /// Its box in world units, written into `instances` when known.
    pub bbox: Option<Obb>,
}

impl Instance {
    /// Its semantic class: `class`, else the label.
    pub fn class_name(&self) -> &str {
        self.class.as_deref().unwrap_or(&self.label)
    }
}

/// How instance-id images are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IdImages {
    /// `panoptic/NAME.png`, 16-bit.
    #[default]
    Panoptic16,
    /// `instances/NAME.png`, 8-bit (ids above 255 are refused): the desk format.
    Instances8,
}

/// What a dataset is written with.
#[derive(Debug, Clone)]
pub struct WriterConfig {
    pub outputs: Vec<Output>,
    /// Metres per scene unit (depth PNGs are in millimetres).
    pub meters_per_unit: f64,
    pub world_up: [f64; 3],
    /// The scene's objects (not the background), for the legends and `instances`.
    pub instances: Vec<Instance>,
    pub id_images: IdImages,
    /// A fixed list of semantic class names (class 0 first, then one per label), so that
    /// class ids stay the same across many datasets (a generator's samples); empty = the
    /// classes of `instances` ([`semantic_classes`]).
    pub classes: Vec<String>,
    /// Further top-level keys of `transforms.json` (the writer's own keys win).
    pub extra: serde_json::Map<String, Value>,
}

impl Default for WriterConfig {
    /// RGB, depth and panoptic ids of a metric scene with +z up and no objects.
    fn default() -> Self {
        WriterConfig {
            outputs: vec![Output::Rgb, Output::Depth, Output::Panoptic],
            meters_per_unit: 1.0,
            world_up: [0.0, 0.0, 1.0],
            instances: Vec::new(),
            id_images: IdImages::default(),
            classes: Vec::new(),
            extra: serde_json::Map::new(),
        }
    }
}

impl WriterConfig {
    /// The folder of an output's files.
    pub fn folder(&self, o: Output) -> &'static str {
        match (o, self.id_images) {
            (Output::Panoptic, IdImages::Instances8) => "instances",
            _ => o.folder(),
        }
    }
}

fn instance_json(i: &Instance) -> Value {
    let mut v = json!({"id": i.id, "label": i.label});
    if let Some(b) = &i.bbox {
        v["bbox"] = json!({
            "center": b.center.to_array(),
            "size": b.size().to_array(),
            "rotation": (0..3).map(|r| b.rotation.row(r).to_array().to_vec()).collect::<Vec<_>>(),
        });
    }
    v
}

/// One object's own rendering: colour (not premultiplied) and opacity.
#[derive(Debug, Clone, Copy)]
pub struct Layer<'a> {
    pub id: u16,
    pub rgb: &'a [f32],
    pub opacity: &'a [f32],
}

/// The images of one rendered view; which are needed depends on the outputs.
#[derive(Debug, Clone, Copy, Default)]
pub struct ViewImages<'a> {
    pub width: u32,
    pub height: u32,
    /// RGB, 3 floats per pixel in [0, 1].
    pub rgb: &'a [f32],
    /// z-depth in scene units (0 = nothing).
    pub depth: &'a [f32],
    /// Instance id per pixel (0 = background).
    pub panoptic: &'a [u16],
    pub layers: &'a [Layer<'a>],
    /// The background node alone, RGB.
    pub background: Option<&'a [f32]>,
    /// Per pixel, whether no ray met a sample there (its colour and depth filled).
    pub unseen: Option<&'a [bool]>,
}

/// Semantic classes of `instances`: distinct labels in id order of first appearance,
/// class 0 = background. Returns the class of each id and the class names.
pub fn semantic_classes(instances: &[Instance]) -> (BTreeMap<u16, u16>, Vec<String>) {
    let mut names = vec!["background".to_string()];
    let mut of_id = BTreeMap::new();
    let mut sorted: Vec<&Instance> = instances.iter().collect();
    sorted.sort_by_key(|i| i.id);
    for i in sorted {
        let k = match names.iter().position(|l| l == i.class_name()) {
            Some(k) => k,
            None => {
                names.push(i.class_name().to_string());
                names.len() - 1
            }
        };
        of_id.insert(i.id, k as u16);
    }
    (of_id, names)
}

/// z-depth in scene units → millimetres, clamped to 16 bits (0 stays 0).
pub fn depth_mm(depth: &[f32], meters_per_unit: f64) -> Vec<u16> {
    depth
        .iter()
        .map(|&z| {
            (z as f64 * meters_per_unit * 1000.0)
                .round()
                .clamp(0.0, 65535.0) as u16
        })
        .collect()
}

fn check_config(dir: &Path, cfg: &WriterConfig) -> Result<()> {
    if cfg.outputs.is_empty() {
        return Err(DataError::field(
            dir,
            "outputs",
            "expected at least one output",
        ));
    }
    if !(cfg.meters_per_unit.is_finite() && cfg.meters_per_unit > 0.0) {
        return Err(DataError::field(
            dir,
            "meters_per_unit",
            format!("expected a positive number, got {}", cfg.meters_per_unit),
        ));
    }
    if dir.is_file() {
        return Err(DataError::field(
            dir,
            "output folder",
            "is a file; expected a folder to write the dataset into",
        ));
    }
    Ok(())
}

/// Writes views into a dataset folder; views may be written from several threads.
pub struct DatasetWriter {
    /// The folder the dataset is for.
    dir: PathBuf,
    /// Where its files are written: a staging folder beside `dir` (swapped into place by
    /// [`DatasetWriter::finish`]) or `dir` itself ([`DatasetWriter::create_in`]).
    root: PathBuf,
    staging: Option<assist_fs::Staging>,
    cfg: WriterConfig,
    classes: BTreeMap<u16, u16>,
    class_names: Vec<String>,
    frames: Mutex<BTreeMap<usize, Value>>,
}

impl DatasetWriter {
    /// A writer whose dataset appears at `dir` whole, or not at all: the views are written
    /// into a staging folder beside it, swapped into place by [`DatasetWriter::finish`]
    /// (dropping the writer unfinished leaves `dir` as it was). An existing non-empty `dir`
    /// is replaced only with `force`, and only when assist wrote it.
    pub fn create(dir: &Path, cfg: WriterConfig, force: bool) -> Result<Self> {
        check_config(dir, &cfg)?;
        assist_fs::check_replaceable_as(dir, force, assist_fs::Kind::Dataset)?;
        let staging = assist_fs::Staging::begin(dir, "writing a dataset")?;
        let root = staging.dir().to_path_buf();
        Self::open(dir, root, Some(staging), cfg)
    }

    /// A writer that writes straight into `dir`, which must be missing or empty (a folder
    /// inside a dataset that is itself being staged).
    pub fn create_in(dir: &Path, cfg: WriterConfig) -> Result<Self> {
        check_config(dir, &cfg)?;
        let non_empty = dir.is_dir()
            && std::fs::read_dir(dir)
                .map_err(|e| DataError::io(dir, e))?
                .next()
                .is_some();
        if non_empty || dir.is_file() {
            return Err(DataError::Exists { path: dir.into() });
        }
        Self::open(dir, dir.to_path_buf(), None, cfg)
    }

    fn open(
        dir: &Path,
        root: PathBuf,
        staging: Option<assist_fs::Staging>,
        cfg: WriterConfig,
    ) -> Result<Self> {
        for o in &cfg.outputs {
            let d = root.join(cfg.folder(*o));
            std::fs::create_dir_all(&d).map_err(|e| DataError::io(&d, e))?;
        }
        let (classes, class_names) = if cfg.classes.is_empty() {
            semantic_classes(&cfg.instances)
        } else {
            let mut of_id = BTreeMap::new();
            for i in &cfg.instances {
                let Some(k) = cfg.classes.iter().position(|c| c == i.class_name()) else {
                    return Err(DataError::field(
                        dir,
                        "classes",
                        format!(
                            "instance {} is of class {:?}, which is not one of the classes {:?}",
                            i.id,
                            i.class_name(),
                            cfg.classes
                        ),
                    ));
                };
                of_id.insert(i.id, k as u16);
            }
            (of_id, cfg.classes.clone())
        };
        Ok(DatasetWriter {
            dir: dir.to_path_buf(),
            root,
            staging,
            cfg,
            classes,
            class_names,
            frames: Mutex::new(BTreeMap::new()),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn outputs(&self) -> &[Output] {
        &self.cfg.outputs
    }

    /// Whether the views must carry per-object layers / the background alone.
    pub fn wants(&self, o: Output) -> bool {
        self.cfg.outputs.contains(&o)
    }

    /// The class of each instance id and the class names (see [`semantic_classes`]).
    pub fn classes(&self) -> (&BTreeMap<u16, u16>, &[String]) {
        (&self.classes, &self.class_names)
    }

    fn check(&self, name: &str, v: &ViewImages) -> Result<()> {
        let n = v.width as usize * v.height as usize;
        let bad = |field: &str, got: usize, want: usize| {
            Err(DataError::field(
                self.dir.join(name),
                field,
                format!(
                    "expected {want} values for a {}×{} view, got {got}",
                    v.width, v.height
                ),
            ))
        };
        if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(DataError::field(
                &self.dir,
                "view name",
                format!("expected a file name without folders, got {name:?}"),
            ));
        }
        for o in &self.cfg.outputs {
            match o {
                Output::Rgb if v.rgb.len() != 3 * n => return bad("rgb", v.rgb.len(), 3 * n),
                Output::Depth if v.depth.len() != n => return bad("depth", v.depth.len(), n),
                Output::Panoptic | Output::Semantic if v.panoptic.len() != n => {
                    return bad("panoptic", v.panoptic.len(), n);
                }
                Output::Objects => {
                    for l in v.layers {
                        if l.rgb.len() != 3 * n || l.opacity.len() != n {
                            return bad("layers", l.opacity.len(), n);
                        }
                    }
                }
                Output::Background => match v.background {
                    None => return bad("background", 0, 3 * n),
                    Some(b) if b.len() != 3 * n => return bad("background", b.len(), 3 * n),
                    _ => {}
                },
                Output::Unseen => match v.unseen {
                    None => return bad("unseen", 0, n),
                    Some(u) if u.len() != n => return bad("unseen", u.len(), n),
                    _ => {}
                },
                _ => {}
            }
        }
        Ok(())
    }

    /// Writes view `index` (its order in `transforms.json`) named `name` (file stem).
    pub fn write(&self, index: usize, name: &str, camera: &Camera, v: &ViewImages) -> Result<()> {
        self.check(name, v)?;
        let (w, h) = (v.width, v.height);
        let file = |o: Output, ext: &str| {
            self.root
                .join(self.cfg.folder(o))
                .join(format!("{name}.{ext}"))
        };
        let rgb = |data: &[f32]| ImageF32 {
            width: w,
            height: h,
            channels: 3,
            data: data.to_vec(),
        };
        for &o in &self.cfg.outputs {
            match o {
                Output::Rgb => write_rgb_png(&file(o, "png"), &rgb(v.rgb))?,
                Output::Depth => {
                    let mm = depth_mm(v.depth, self.cfg.meters_per_unit);
                    write_gray16_png(&file(o, "png"), w, h, &mm)?;
                    let npy = crate::npy::encode_npy_f32(&[h as usize, w as usize], v.depth);
                    write_atomic(&file(o, "npy"), &npy)?;
                }
                Output::Panoptic => match self.cfg.id_images {
                    IdImages::Panoptic16 => write_gray16_png(&file(o, "png"), w, h, v.panoptic)?,
                    IdImages::Instances8 => {
                        let ids = v
                            .panoptic
                            .iter()
                            .map(|&id| u8::try_from(id))
                            .collect::<std::result::Result<Vec<u8>, _>>()
                            .map_err(|_| {
                                DataError::field(
                                    file(o, "png"),
                                    "instance ids",
                                    "expected ids up to 255 in 8-bit instance images",
                                )
                            })?;
                        write_gray8_png(&file(o, "png"), w, h, &ids)?
                    }
                },
                Output::Semantic => {
                    let sem: Vec<u16> = v
                        .panoptic
                        .iter()
                        .map(|id| self.classes.get(id).copied().unwrap_or(0))
                        .collect();
                    write_gray16_png(&file(o, "png"), w, h, &sem)?;
                }
                Output::Objects => {
                    for layer in v.layers {
                        let mut data = Vec::with_capacity(layer.opacity.len() * 4);
                        for (k, &a) in layer.opacity.iter().enumerate() {
                            data.extend_from_slice(&layer.rgb[k * 3..k * 3 + 3]);
                            data.push(a);
                        }
                        let d = self.root.join("objects").join(layer.id.to_string());
                        std::fs::create_dir_all(&d).map_err(|e| DataError::io(&d, e))?;
                        let img = ImageF32 {
                            width: w,
                            height: h,
                            channels: 4,
                            data,
                        };
                        write_rgb_png(&d.join(format!("{name}.png")), &img)?;
                    }
                }
                Output::Background => {
                    let b = v.background.expect("checked above");
                    write_rgb_png(&file(o, "png"), &rgb(b))?;
                }
                Output::Unseen => {
                    let u = v.unseen.expect("checked above");
                    let mask: Vec<u8> = u.iter().map(|&x| if x { 255 } else { 0 }).collect();
                    write_gray8_png(&file(o, "png"), w, h, &mask)?;
                }
            }
        }
        let i = &camera.intrinsics;
        let mut f = json!({
            "file_path": format!("images/{name}.png"),
            "transform_matrix": camera.pose.to_matrix().transpose().to_cols_array_2d(),
            "fl_x": i.fx, "fl_y": i.fy, "cx": i.cx, "cy": i.cy,
            "w": w, "h": h,
            "frame_index": index,
        });
        if self.wants(Output::Depth) {
            f["depth_file_path"] = json!(format!("depth/{name}.png"));
        }
        if self.wants(Output::Panoptic) {
            let folder = self.cfg.folder(Output::Panoptic);
            f["instance_mask_path"] = json!(format!("{folder}/{name}.png"));
        }
        self.frames
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(index, f);
        Ok(())
    }

    /// Writes `transforms.json` and the legends and, for a staged writer, swaps the
    /// dataset into place; returns the number of views written.
    pub fn finish(mut self) -> Result<usize> {
        let frames: Vec<Value> =
            std::mem::take(&mut *self.frames.lock().unwrap_or_else(|e| e.into_inner()))
                .into_values()
                .collect();
        let n = frames.len();
        let cfg = &self.cfg;
        let mut tj = json!({
            "camera_model": "OPENCV",
            "depth_unit_scale_factor": 0.001 / cfg.meters_per_unit,
            "world_up": cfg.world_up,
            "frames": frames,
        });
        tj["instances"] = cfg.instances.iter().map(instance_json).collect();
        // Rendered, not photographed (`Dataset::rendered`): training needs no per-image
        // appearance codes for it. A renderer named in `extra` is kept.
        if !cfg.extra.contains_key("renderer") {
            tj["renderer"] = json!(concat!("assist ", env!("CARGO_PKG_VERSION")));
        }
        for (k, v) in &cfg.extra {
            if tj.get(k).is_none() {
                tj[k] = v.clone();
            }
        }
        let pretty = |v: &Value| serde_json::to_string_pretty(v).expect("JSON values serialise");
        write_atomic(&self.root.join("transforms.json"), pretty(&tj).as_bytes())?;
        if self.wants(Output::Panoptic) {
            let legend: serde_json::Map<String, Value> =
                std::iter::once(("0".to_string(), json!("background")))
                    .chain(
                        cfg.instances
                            .iter()
                            .map(|i| (i.id.to_string(), json!(i.label))),
                    )
                    .collect();
            write_atomic(
                &self.root.join("panoptic_legend.json"),
                pretty(&Value::Object(legend)).as_bytes(),
            )?;
        }
        if self.wants(Output::Semantic) {
            let sem: serde_json::Map<String, Value> = self
                .class_names
                .iter()
                .enumerate()
                .map(|(k, n)| (k.to_string(), json!(n)))
                .collect();
            write_atomic(
                &self.root.join("semantic_legend.json"),
                pretty(&Value::Object(sem)).as_bytes(),
            )?;
        }
        if let Some(staging) = self.staging.take() {
            staging.commit()?;
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{DVec3, Intrinsics, Pose};

    fn camera() -> Camera {
        Camera {
            intrinsics: Intrinsics::from_fov_x(4, 3, 1.0),
            pose: Pose::look_at(DVec3::new(0.0, -2.0, 0.5), DVec3::ZERO, DVec3::Z).unwrap(),
        }
    }

    #[test]
    fn written_dataset_reads_back() {
        let dir = std::env::temp_dir().join(format!("assist-writer-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cfg = WriterConfig {
            outputs: Output::ALL.to_vec(),
            meters_per_unit: 0.5,
            world_up: [0.0, 0.0, 1.0],
            instances: vec![
                Instance {
                    id: 3,
                    label: "mug".into(),
                    class: None,
                    bbox: None,
                },
                Instance {
                    id: 7,
                    label: "mug".into(),
                    class: None,
                    bbox: None,
                },
                Instance {
                    id: 9,
                    label: "book".into(),
                    class: None,
                    bbox: None,
                },
            ],
            ..WriterConfig::default()
        };
        let w = DatasetWriter::create(&dir, cfg.clone(), false).unwrap();
        let n = 12;
        let rgb: Vec<f32> = (0..3 * n).map(|k| (k % 7) as f32 / 6.0).collect();
        let depth: Vec<f32> = (0..n).map(|k| 1.0 + k as f32 * 0.25).collect();
        let ids: Vec<u16> = [0, 3, 7, 9].repeat(3);
        let op = vec![0.5; n];
        let unseen: Vec<bool> = (0..n).map(|k| k % 5 == 2).collect();
        let layers = [Layer {
            id: 3,
            rgb: &rgb,
            opacity: &op,
        }];
        let v = ViewImages {
            width: 4,
            height: 3,
            rgb: &rgb,
            depth: &depth,
            panoptic: &ids,
            layers: &layers,
            background: Some(&rgb),
            unseen: Some(&unseen),
        };
        // Written out of order: transforms.json keeps the index order.
        w.write(1, "b", &camera(), &v).unwrap();
        w.write(0, "a", &camera(), &v).unwrap();
        assert_eq!(w.finish().unwrap(), 2);

        let ds = crate::load(&dir, &crate::LoadOptions::default()).unwrap();
        assert_eq!(ds.frames.len(), 2);
        assert_eq!(ds.frames[0].name, "a");
        let c = &ds.frames[0].camera;
        let want = camera();
        assert!((c.intrinsics.fx - want.intrinsics.fx).abs() < 1e-9);
        assert!((c.pose.center() - want.pose.center()).length() < 1e-9);
        // Depth PNGs are millimetres: 1.25 units × 0.5 m = 625 mm, read back in units.
        let d = crate::image_io::read_depth_png(&dir.join("depth/a.png"), 0.001).unwrap();
        assert_eq!(d.data[1], 0.625);
        let npy = crate::npy::read_npy(&dir.join("depth/a.npy")).unwrap();
        assert_eq!(npy.shape, vec![3, 4]);
        assert_eq!(
            crate::image_io::read_ids(&dir.join("panoptic/a.png"))
                .unwrap()
                .data,
            ids
        );
        // Both mugs are class 1, the book class 2.
        let sem = crate::image_io::read_ids(&dir.join("semantic/a.png")).unwrap();
        assert_eq!(&sem.data[..4], &[0, 1, 1, 2]);
        let legend: Value =
            serde_json::from_slice(&std::fs::read(dir.join("semantic_legend.json")).unwrap())
                .unwrap();
        assert_eq!(legend["2"], "book");
        assert!(dir.join("objects/3/b.png").is_file());
        assert!(dir.join("background/a.png").is_file());
        let mask = image::open(dir.join("unseen/a.png")).unwrap().to_luma8();
        let want: Vec<u8> = unseen.iter().map(|&u| if u { 255 } else { 0 }).collect();
        assert_eq!(mask.into_raw(), want);

        // A non-empty folder is refused without force; a wrong-sized view is an error.
        assert!(matches!(
            DatasetWriter::create(&dir, cfg.clone(), false),
            Err(DataError::Output(assist_fs::FsError::Exists { .. }))
        ));
        let w = DatasetWriter::create(&dir, cfg, true).unwrap();
        let short = ViewImages {
            depth: &depth[..5],
            ..v
        };
        let e = w.write(0, "c", &camera(), &short).unwrap_err().to_string();
        assert!(e.contains("depth") && e.contains("expected 12"), "{e}");
        let without = ViewImages { unseen: None, ..v };
        let e = w
            .write(0, "c", &camera(), &without)
            .unwrap_err()
            .to_string();
        assert!(e.contains("unseen"), "{e}");
        assert!(w.write(0, "../x", &camera(), &v).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
