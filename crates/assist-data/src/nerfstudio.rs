//! nerfstudio `transforms.json`: global or per-frame intrinsics, `camera_model` PINHOLE /
//! OPENCV / OPENCV_FISHEYE, `mask_path`, `depth_file_path` with `depth_unit_scale_factor`,
//! and our extension (per-frame `instance_mask_path`, top-level `instances`, `split.json`).
//! Also reads instant-ngp style files that give `camera_angle_x` instead of focal lengths.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use assist_core::{Camera, Distortion, Intrinsics, Pose};

use crate::dataset::{Dataset, Format, Frame, InstanceInfo, Split, compute_bounds, holdout_split};
use crate::error::{DataError, Result};
use crate::image_io::image_dimensions;
use crate::json::{Node, read_json};

pub const CAMERA_MODELS: &[&str] = &["PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "OPENCV_FISHEYE"];

/// Resolves an image path given in a dataset file: relative to the file's folder; a path
/// without an extension gets `.png` when that file exists (Blender / instant-ngp style).
pub fn resolve_image_path(base: &Path, rel: &str) -> PathBuf {
    let p = Path::new(rel);
    let p = if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    };
    if p.extension().is_none() && !p.exists() {
        let png = p.with_extension("png");
        if png.exists() {
            return png;
        }
    }
    p
}

fn intrinsics_of(
    frame: &Node,
    top: &Node,
    file: &Path,
    image: &Path,
) -> Result<(Intrinsics, String)> {
    // A frame value overrides the top-level one.
    let get = |k: &str| frame.get(k).or_else(|| top.get(k));
    let model_node = get("camera_model");
    let model = match &model_node {
        Some(n) => n.str()?.to_string(),
        None => "OPENCV".to_string(),
    };
    if !CAMERA_MODELS.contains(&model.as_str()) {
        let field = model_node.map(|n| n.path().to_string()).unwrap_or_default();
        return Err(DataError::field(
            file,
            field,
            format!(
                "unknown camera model {model:?}; expected one of {}",
                CAMERA_MODELS.join(", ")
            ),
        ));
    }
    let (w, h) = match (get("w"), get("h")) {
        (Some(w), Some(h)) => (w.u32()?, h.u32()?),
        _ => image_dimensions(image)?,
    };
    let fx = match (get("fl_x"), get("camera_angle_x")) {
        (Some(f), _) => f.positive_f64()?,
        (None, Some(a)) => 0.5 * w as f64 / (0.5 * a.positive_f64()?).tan(),
        (None, None) => {
            return Err(top.err_at(
                "fl_x",
                "missing; expected fl_x (or camera_angle_x) at the top level or in every frame",
            ));
        }
    };
    let fy = match (get("fl_y"), get("camera_angle_y")) {
        (Some(f), _) => f.positive_f64()?,
        (None, Some(a)) if get("fl_x").is_none() => {
            0.5 * h as f64 / (0.5 * a.positive_f64()?).tan()
        }
        _ => fx,
    };
    let cx = match get("cx") {
        Some(v) => v.f64()?,
        None => w as f64 / 2.0,
    };
    let cy = match get("cy") {
        Some(v) => v.f64()?,
        None => h as f64 / 2.0,
    };
    let k = |name: &str| -> Result<f64> {
        get(name)
            .map(|n| n.f64())
            .transpose()
            .map(|v| v.unwrap_or(0.0))
    };
    let distortion = match model.as_str() {
        "OPENCV" => Distortion::OpenCv {
            k1: k("k1")?,
            k2: k("k2")?,
            k3: k("k3")?,
            p1: k("p1")?,
            p2: k("p2")?,
        },
        "OPENCV_FISHEYE" => Distortion::Fisheye {
            k1: k("k1")?,
            k2: k("k2")?,
            k3: k("k3")?,
            k4: k("k4")?,
        },
        _ => Distortion::None,
    };
    let distortion = if distortion.is_none() {
        Distortion::None
    } else {
        distortion
    };
    let intr = Intrinsics {
        width: w,
        height: h,
        fx,
        fy,
        cx,
        cy,
        distortion,
    };
    intr.validate(frame.path())
        .map_err(|e| DataError::core(file, e))?;
    Ok((intr, model))
}

/// Reads the split: `split.json` beside the file (`{"train": [indices], "test": [...]}`),
/// else `train_filenames`/`val_filenames`/`test_filenames`, else every 8th frame held out.
fn read_splits(
    file: &Path,
    top: &Node,
    frames: &mut [Frame],
    rel_paths: &[String],
) -> Result<(String, bool)> {
    let split_file = file.with_file_name("split.json");
    if split_file.is_file() {
        let v = read_json(&split_file)?;
        let root = Node::root(&v, &split_file);
        let mut assigned = vec![None; frames.len()];
        let obj = v
            .as_object()
            .ok_or_else(|| root.err("expected an object {\"train\": [...], \"test\": [...]}"))?;
        for key in obj.keys() {
            let split = Split::parse(key)
                .ok_or_else(|| root.err_at(key, "unknown split; expected train, val or test"))?;
            for item in root.req(key)?.items()? {
                let i = item.u32()? as usize;
                if i >= frames.len() {
                    return Err(item.err(format!(
                        "frame index {i} out of range: the dataset has {} frames",
                        frames.len()
                    )));
                }
                assigned[i] = Some(split);
            }
        }
        // Frames that split.json does not list are used for training.
        for (f, s) in frames.iter_mut().zip(&assigned) {
            f.split = s.unwrap_or(Split::Train);
        }
        return Ok((format!("{}", split_file.display()), true));
    }
    let lists: Vec<(Split, &str)> = vec![
        (Split::Train, "train_filenames"),
        (Split::Val, "val_filenames"),
        (Split::Test, "test_filenames"),
    ];
    if lists.iter().any(|(_, k)| top.get(k).is_some()) {
        let mut by_name: HashMap<String, Split> = HashMap::new();
        for (split, key) in &lists {
            if let Some(n) = top.get(key) {
                for item in n.items()? {
                    by_name.insert(normalise_rel(item.str()?), *split);
                }
            }
        }
        for (f, rel) in frames.iter_mut().zip(rel_paths) {
            f.split = *by_name.get(&normalise_rel(rel)).unwrap_or(&Split::Train);
        }
        return Ok(("train_filenames/val_filenames/test_filenames".into(), true));
    }
    for (i, f) in frames.iter_mut().enumerate() {
        f.split = holdout_split(i);
    }
    Ok(("every 8th frame held out for test".into(), false))
}

fn normalise_rel(s: &str) -> String {
    s.trim_start_matches("./").to_string()
}

pub fn load(file: &Path) -> Result<Dataset> {
    let base = file.parent().map(Path::to_path_buf).unwrap_or_default();
    let v = read_json(file)?;
    let top = Node::root(&v, file);
    if !v.is_object() {
        return Err(top.err("expected a JSON object with a \"frames\" list"));
    }
    let depth_scale_node = top.get("depth_unit_scale_factor");
    let depth_scale = match &depth_scale_node {
        Some(n) => n.positive_f64()?,
        None => 1e-3,
    };
    let mut frames = Vec::new();
    let mut rel_paths = Vec::new();
    for fr in top.req("frames")?.items()? {
        let rel = fr.req("file_path")?.str()?.to_string();
        let image_path = resolve_image_path(&base, &rel);
        let (intrinsics, model) = intrinsics_of(&fr, &top, file, &image_path)?;
        let m = fr.req("transform_matrix")?;
        let pose =
            Pose::from_matrix(m.mat4_rows()?, m.path()).map_err(|e| DataError::core(file, e))?;
        let opt_path = |k: &str| -> Result<Option<PathBuf>> {
            fr.get(k)
                .map(|n| n.str().map(|s| resolve_image_path(&base, s)))
                .transpose()
        };
        frames.push(Frame {
            mask_path: opt_path("mask_path")?,
            instance_mask_path: opt_path("instance_mask_path")?,
            depth_path: opt_path("depth_file_path")?,
            depth_scale,
            inpaint_path: opt_path("inpaint_path")?,
            inpaint_depth_path: opt_path("inpaint_depth_path")?,
            ..Frame::new(
                image_path,
                Camera { intrinsics, pose },
                &model,
                Split::Train,
            )
        });
        rel_paths.push(rel);
    }
    let (split_source, split_declared) = read_splits(file, &top, &mut frames, &rel_paths)?;
    let mut instances = Vec::new();
    if let Some(list) = top.get("instances") {
        for inst in list.items()? {
            let idn = inst.req("id")?;
            let id = idn.u32()?;
            if id == 0 || id > u16::MAX as u32 {
                return Err(idn.err(format!(
                    "expected an instance id in 1..=65535 (0 is the background), got {id}"
                )));
            }
            let label = match inst.get("label") {
                Some(l) => l.str()?.to_string(),
                None => format!("object {id}"),
            };
            let bbox = inst
                .get("bbox")
                .map(|b| crate::boxes::parse_bbox(&b))
                .transpose()?;
            if instances.iter().any(|i: &InstanceInfo| i.id == id as u16) {
                return Err(idn.err(format!("instance id {id} appears twice")));
            }
            instances.push(InstanceInfo {
                id: id as u16,
                label,
                bbox,
            });
        }
    }
    let world_up = top.get("world_up").map(|n| n.vec3()).transpose()?;
    let meters_per_unit = match top.get("meters_per_unit") {
        Some(n) => Some(n.positive_f64()?),
        // nerfstudio's contract: depth × depth_unit_scale_factor is metres and depth is in
        // the poses' units, so a dataset that declares the factor has metric poses.
        None if depth_scale_node.is_some() => Some(1.0),
        None => None,
    };
    // nerfstudio's sparse points (`ns-process-data`, `assist process`), in the poses'
    // frame: where the content is, for the background's inner region and near plane.
    let points = match top.get("ply_file_path") {
        Some(n) => crate::ply::read_points(&resolve_image_path(&base, n.str()?))?,
        None => vec![],
    };
    let (bounds, normalization) = compute_bounds(&frames, &points, &instances, None);
    Ok(Dataset {
        format: Format::Nerfstudio,
        root: file.to_path_buf(),
        frames,
        instances,
        world_up,
        meters_per_unit,
        points,
        depth_range: None,
        split_source,
        split_declared,
        rendered: top.get("renderer").is_some(),
        bounds,
        normalization,
        mask_folder: None,
        prior_folder: None,
    })
}
