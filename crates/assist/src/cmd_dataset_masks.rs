//! `assist dataset masks DATA --scene SCENE --box … --label … --out DIR`: instance masks for
//! every image of a dataset nobody labelled, from boxes around its objects on a scene
//! trained on it without masks (`assist train --no-objects`). The folder holds one PNG
//! per image (named like it; 0 = background, the objects 1, 2, … in the order given),
//! `instances.json` (ids, labels, boxes) and `masks.json` (how they were made); any tool
//! reads it, and `assist train DATA --masks DIR` trains the objects from it.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_core::{DMat3, DVec3, Obb};
use assist_data::{LoadOptions, image_io};
use assist_session::Session;
use assist_session::split::click::{self, ClickOptions};
use assist_session::split::{MaskOptions, SplitBox};
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct MasksArgs {
    /// The dataset (any supported format).
    pub data: PathBuf,
    /// A scene trained on DATA (without masks: `assist train DATA --no-objects`).
    #[arg(long)]
    pub scene: PathBuf,
    /// An object's box in the scene's world units: "cx,cy,cz,sx,sy,sz[,yaw]" (centre,
    /// size along the box's axes, the last along the scene's up; yaw in degrees about
    /// up). Repeat for several objects.
    #[arg(long = "box", value_name = "BOX")]
    pub boxes: Vec<String>,
    /// An object under a pixel of a view: "VIEW:u,v" (VIEW a frame's index or file name,
    /// u,v pixels of the full-size image); its box is found from the scene and reported.
    /// Repeat for several objects.
    #[arg(long = "click", value_name = "VIEW:u,v")]
    pub clicks: Vec<String>,
    /// The objects' names: those of --box first, then those of --click, each in the order
    /// given (default "object 1", "object 2", …).
    #[arg(long = "label", value_name = "NAME")]
    pub labels: Vec<String>,
    /// Boxes from a file instead (as `assist dataset boxes --json` writes them).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["boxes", "clicks"])]
    pub boxes_file: Option<PathBuf>,
    /// The masks folder written.
    #[arg(long)]
    pub out: PathBuf,
    /// Render N times smaller than the images (the masks are then refined at full size).
    #[arg(long, default_value_t = assist_session::split::click::RENDER_DOWNSCALE, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub render_downscale: u32,
    /// Replace --out if assist wrote it.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

/// A point or size to a tenth of a millimetre in metres (for messages).
pub fn vec3(v: DVec3) -> String {
    format!("[{:.4}, {:.4}, {:.4}]", v.x, v.y, v.z)
}

/// Comma-separated numbers; `None` when one is not a number.
fn numbers(text: &str) -> Option<Vec<f64>> {
    text.split(',')
        .map(|t| t.trim().parse::<f64>().ok())
        .collect()
}

/// `"cx,cy,cz,sx,sy,sz[,yaw]"` as a box standing upright along `up`.
pub fn parse_box(text: &str, up: DVec3) -> anyhow::Result<Obb> {
    let v = numbers(text).ok_or_else(|| {
        anyhow::anyhow!("--box {text:?}: expected numbers \"cx,cy,cz,sx,sy,sz[,yaw]\"")
    })?;
    if !(v.len() == 6 || v.len() == 7) || v.iter().any(|x| !x.is_finite()) {
        bail!(
            "--box {text:?}: expected 6 or 7 finite numbers \"cx,cy,cz,sx,sy,sz[,yaw]\", got {}",
            v.len()
        );
    }
    if v[3..6].iter().any(|&s| s <= 0.0) {
        bail!("--box {text:?}: expected sizes above 0");
    }
    let yaw = v.get(6).copied().unwrap_or(0.0).to_radians();
    Ok(Obb::new(
        DVec3::new(v[0], v[1], v[2]),
        DVec3::new(v[3], v[4], v[5]),
        upright(up, yaw),
    ))
}

/// Axes of a box standing along `up`, turned by `yaw` about it: the third axis is up;
/// the first is the world's x (else y) made horizontal, turned.
fn upright(up: DVec3, yaw: f64) -> DMat3 {
    let up = up.normalize();
    let reference = [DVec3::X, DVec3::Y]
        .into_iter()
        .map(|a| a - up * a.dot(up))
        .find(|a| a.length() > 1e-6)
        .unwrap_or(DVec3::X)
        .normalize();
    let x = reference * yaw.cos() + up.cross(reference) * yaw.sin();
    DMat3::from_cols(x, up.cross(x), up)
}

pub fn run(a: MasksArgs) -> anyhow::Result<()> {
    assist_fs::check_replaceable(&a.out, a.force)?;
    assist_fs::check_not_input(&a.out, &[&a.data, &a.scene])?;
    let session = Session::open(&a.scene)?;
    let ds = assist_data::load(&a.data, &LoadOptions::default())
        .with_context(|| format!("reading {}", a.data.display()))?;
    let boxes = new_objects(&a, &session, &ds)?;
    check_inside(&boxes, &session)?;
    // Photographs are read one at a time, as each mask is refined.
    let photo_of = |f: &assist_data::Frame| -> anyhow::Result<image_io::ImageF32> {
        Ok(image_io::read_rgb(&f.image_path, [0.0; 3])?.0)
    };
    let staging = assist_fs::Staging::begin(&a.out, "dataset masks")?;
    let opts = MaskOptions::default();
    let started = std::time::Instant::now();
    let mut owned = vec![0u64; boxes.len()];
    let n = ds.frames.len();
    // The support under each box comes from all views: render them all first.
    let size = |c: &assist_core::Camera| {
        Some((
            (c.width() / a.render_downscale).max(1),
            (c.height() / a.render_downscale).max(1),
        ))
    };
    let show = !a.json && std::io::stderr().is_terminal();
    let bar = crate::progress::bar(show, "rendering views");
    let mut step = crate::progress::steps(&bar);
    let mut seen = Vec::with_capacity(n);
    for (k, f) in ds.frames.iter().enumerate() {
        seen.push(session.boxes_in_view(&f.camera, &boxes, size(&f.camera))?);
        step(k + 1, n);
    }
    bar.finish_and_clear();
    let bar = crate::progress::bar(show, "refining masks");
    let mut step = crate::progress::steps(&bar);
    let levels = session.support_levels(&boxes, &seen, &opts);
    for (k, (f, view)) in ds.frames.iter().zip(&seen).enumerate() {
        let photo = photo_of(f)?;
        let ids = view.mask(&boxes, &levels, Some(&photo), &opts);
        for (o, b) in owned.iter_mut().zip(&boxes) {
            *o += ids.iter().filter(|&&v| v == b.id).count() as u64;
        }
        let name = format!("{}.png", assist_data::dataset::file_stem(&f.image_path));
        let bytes: Vec<u8> = ids.iter().map(|&v| v as u8).collect();
        image_io::write_gray8_png(
            &staging.dir().join(&name),
            photo.width,
            photo.height,
            &bytes,
        )?;
        step(k + 1, n);
    }
    bar.finish_and_clear();
    let instances: Vec<_> = boxes
        .iter()
        .map(|b| {
            json!({
                "id": b.id,
                "label": b.label,
                "bbox": {
                    "center": b.obb.center.to_array(),
                    "size": b.obb.size().to_array(),
                    "rotation": (0..3).map(|r| (0..3).map(|c| b.obb.rotation.col(c)[r]).collect::<Vec<_>>()).collect::<Vec<_>>(),
                },
            })
        })
        .collect();
    write_json(
        &staging.dir().join(assist_data::masks::INSTANCES_FILE),
        &json!({ "instances": instances }),
    )?;
    let summary = json!({
        "data": a.data,
        "scene": a.scene,
        "out": a.out,
        "images": n,
        "render_downscale": a.render_downscale,
        "support_levels": levels,
        "objects": boxes.iter().zip(&owned).map(|(b, px)| json!({"id": b.id, "label": b.label, "pixels": px})).collect::<Vec<_>>(),
        "seconds": started.elapsed().as_secs_f64(),
    });
    write_json(&staging.dir().join("masks.json"), &summary)?;
    staging.commit()?;
    if let Some(i) = owned.iter().position(|&p| p == 0) {
        eprintln!(
            "warning: {} ({}) owns no pixel in any view: is its box around a surface the scene shows?",
            boxes[i].label, boxes[i].id
        );
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        for (b, px) in boxes.iter().zip(&owned) {
            println!("{:>3}  {:<24} {px} pixels over {n} images", b.id, b.label);
        }
        println!(
            "masks of {n} images in {:.1} s -> {} (train with: assist train {} --masks {})",
            started.elapsed().as_secs_f64(),
            a.out.display(),
            a.data.display(),
            a.out.display()
        );
    }
    Ok(())
}

fn write_json(path: &Path, v: &serde_json::Value) -> anyhow::Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// The objects of --box, --click and --label, or of --boxes-file, with ids 1, 2, … in
/// that order.
fn new_objects(
    a: &MasksArgs,
    session: &Session,
    ds: &assist_data::Dataset,
) -> anyhow::Result<Vec<SplitBox>> {
    let up = session.description().up;
    let mut obbs: Vec<(Obb, Option<String>)> = match &a.boxes_file {
        Some(p) => assist_data::boxes::read_boxes(p)?
            .into_iter()
            .map(|b| (b.bbox, b.label))
            .collect(),
        None => a
            .boxes
            .iter()
            .map(|t| parse_box(t, up).map(|b| (b, None)))
            .collect::<anyhow::Result<_>>()?,
    };
    let cameras: Vec<assist_core::Camera> = ds
        .frames
        .iter()
        .filter(|f| f.split == assist_data::Split::Train)
        .map(|f| f.camera)
        .collect();
    for c in &a.clicks {
        let (frame, uv) = parse_click(c, ds)?;
        let obb = click::box_at_click(
            session,
            &frame.camera,
            uv,
            &cameras,
            &ClickOptions {
                render_downscale: a.render_downscale,
                ..ClickOptions::default()
            },
        )
        .with_context(|| format!("--click {c}"))?;
        let (ctr, size) = (obb.center, obb.size());
        eprintln!("--click {c}: box centre {} size {}", vec3(ctr), vec3(size));
        obbs.push((obb, None));
    }
    if obbs.len() > 255 {
        bail!(
            "at most 255 objects at a time (8-bit masks), got {}",
            obbs.len()
        );
    }
    if obbs.is_empty() {
        bail!(
            "expected at least one object: --box \"cx,cy,cz,sx,sy,sz[,yaw]\", --click VIEW:u,v or --boxes-file FILE"
        );
    }
    if a.labels.len() > obbs.len() {
        bail!(
            "{} --label for {} objects: give one label per --box or --click, in the same order",
            a.labels.len(),
            obbs.len()
        );
    }
    Ok(obbs
        .into_iter()
        .enumerate()
        .map(|(k, (obb, file_label))| SplitBox {
            id: k as u16 + 1,
            label: a
                .labels
                .get(k)
                .cloned()
                .or(file_label)
                .unwrap_or_else(|| format!("object {}", k + 1)),
            obb,
        })
        .collect())
}

/// `"VIEW:u,v"`: the frame (by index, or by file name with or without its extension)
/// and the pixel.
fn parse_click<'a>(
    text: &str,
    ds: &'a assist_data::Dataset,
) -> anyhow::Result<(&'a assist_data::Frame, (f64, f64))> {
    let (view, px) = text
        .rsplit_once(':')
        .with_context(|| format!("--click {text:?}: expected \"VIEW:u,v\""))?;
    let uv = numbers(px).ok_or_else(|| {
        anyhow::anyhow!("--click {text:?}: expected pixels \"u,v\" after the colon")
    })?;
    let [u, v] = uv[..] else {
        bail!("--click {text:?}: expected two numbers \"u,v\" after the colon");
    };
    let frame = match view.parse::<usize>() {
        Ok(k) => ds.frames.get(k).with_context(|| {
            format!(
                "--click {text:?}: view {k} does not exist ({} frames, 0 to {})",
                ds.frames.len(),
                ds.frames.len().saturating_sub(1)
            )
        })?,
        Err(_) => ds
            .frames
            .iter()
            .find(|f| {
                f.image_path
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy() == view)
                    || assist_data::dataset::file_stem(&f.image_path) == view
            })
            .with_context(|| {
                format!(
                    "--click {text:?}: no frame named {view:?} in {}",
                    ds.root.display()
                )
            })?,
    };
    let (w, h) = (frame.camera.width() as f64, frame.camera.height() as f64);
    if !(u >= 0.0 && v >= 0.0 && u < w && v < h) {
        bail!("--click {text:?}: ({u}, {v}) is outside the image ({w}×{h} pixels)");
    }
    Ok((frame, (u, v)))
}

/// Each box must overlap the scene's captured region and no existing object node.
fn check_inside(boxes: &[SplitBox], session: &Session) -> anyhow::Result<()> {
    let scene = session.description();
    for b in boxes {
        let bb = b.obb.world_aabb();
        for n in &scene.nodes {
            let mut nb = assist_core::Aabb::empty();
            for c in n.world_corners() {
                nb.extend(c);
            }
            let overlap = bb.min.cmplt(nb.max).all() && nb.min.cmplt(bb.max).all();
            if n.is_background() {
                if !overlap {
                    bail!(
                        "the box of {} lies outside the captured region ({} to {}): give its centre and size in the scene's world units (`assist scene info` shows the region)",
                        b.label,
                        assist_core::fmt_vec(&nb.min.to_array()),
                        assist_core::fmt_vec(&nb.max.to_array())
                    );
                }
            } else if overlap {
                bail!(
                    "the box of {} overlaps the object {} ({}): an object the scene already has cannot be made again",
                    b.label,
                    n.id,
                    n.label
                );
            }
        }
    }
    Ok(())
}
