//! `assist render SCENE --out DIR`: renders a trained (possibly edited) scene into a new
//! dataset others can train on: RGB PNG, z-depth (16-bit PNG in millimetres and float32
//! `.npy`), instance ids (16-bit PNG + JSON legend), semantic classes (16-bit PNG + legend),
//! per-node layers (RGBA, alpha = the node's opacity), the background alone, and a
//! nerfstudio `transforms.json` of the rendered cameras. Cameras come from a dataset split
//! (file names kept), a `transforms.json`, or an orbit around the objects.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_core::{Camera, DVec3, Intrinsics, Pose, Scene};
use assist_data::image_io::{ImageF32, write_atomic, write_gray16_png, write_rgb_png};
use assist_data::{LoadOptions, Split};
use assist_render::{NeuralScene, RenderOptions, RenderedImage, render_camera};
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Cameras: a dataset (directory), a transforms.json, or `orbit`.
    #[arg(long, default_value = "orbit")]
    pub cameras: String,
    /// Dataset split to render (train, val, test, all, or auto: the test split when the
    /// dataset declares its split — split.json, *_filenames, Blender's files — else every
    /// frame, e.g. for a bare transforms.json of cameras).
    #[arg(long, default_value = "auto")]
    pub split: String,
    /// With a dataset as --cameras: render its cameras N times smaller.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Comma-separated: rgb, depth, panoptic, semantic, objects, background.
    #[arg(long, default_value = "rgb,depth,panoptic")]
    pub outputs: String,
    /// Highlight this instance id (default: the scene's selection, if any).
    #[arg(long)]
    pub select: Option<u16>,
    /// Do not highlight the scene's selection.
    #[arg(long)]
    pub no_highlight: bool,
    /// Orbit: number of views.
    #[arg(long, default_value_t = 24)]
    pub frames: usize,
    /// Orbit: image size WxH.
    #[arg(long, default_value = "480x360")]
    pub size: String,
    /// Orbit: horizontal field of view in degrees.
    #[arg(long, default_value_t = 50.0)]
    pub fov: f64,
    /// Orbit: camera elevation above the horizon in degrees.
    #[arg(long, default_value_t = 30.0)]
    pub elevation: f64,
    /// Orbit: distance from the centre in world units (default: frames the objects).
    #[arg(long)]
    pub radius: Option<f64>,
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Output {
    Rgb,
    Depth,
    Panoptic,
    Semantic,
    Objects,
    Background,
}

fn parse_outputs(s: &str) -> anyhow::Result<Vec<Output>> {
    let mut v = Vec::new();
    for w in s.split(',').map(str::trim).filter(|w| !w.is_empty()) {
        v.push(match w {
            "rgb" => Output::Rgb,
            "depth" => Output::Depth,
            "panoptic" | "instances" => Output::Panoptic,
            "semantic" => Output::Semantic,
            "objects" | "layers" => Output::Objects,
            "background" => Output::Background,
            other => bail!(
                "--outputs: unknown output {other:?}; expected rgb, depth, panoptic, semantic, objects, background"
            ),
        });
    }
    if v.is_empty() {
        bail!("--outputs: expected at least one output");
    }
    v.sort();
    v.dedup();
    Ok(v)
}

/// A named camera to render.
pub struct View {
    pub name: String,
    pub camera: Camera,
}

/// The world box around the scene's objects (or the background's box when it has none).
fn objects_box(scene: &Scene) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let objects: Vec<_> = scene.nodes.iter().filter(|n| !n.is_background()).collect();
    let nodes: Vec<_> = if objects.is_empty() {
        scene.nodes.iter().collect()
    } else {
        objects
    };
    for n in nodes {
        for c in n.world_corners() {
            lo = lo.min(c);
            hi = hi.max(c);
        }
    }
    (lo, hi)
}

/// `frames` cameras on a circle around the objects, looking at their centre.
pub fn orbit(
    scene: &Scene,
    frames: usize,
    width: u32,
    height: u32,
    fov_deg: f64,
    elevation_deg: f64,
    radius: Option<f64>,
) -> anyhow::Result<Vec<View>> {
    if frames == 0 || width == 0 || height == 0 {
        bail!("--frames and --size must be positive");
    }
    if !(1.0..179.0).contains(&fov_deg) {
        bail!("--fov: expected degrees between 1 and 179, got {fov_deg}");
    }
    if !(-89.0..=89.0).contains(&elevation_deg) {
        bail!("--elevation: expected degrees between -89 and 89, got {elevation_deg}");
    }
    let (lo, hi) = objects_box(scene);
    if !lo.is_finite() || !hi.is_finite() {
        bail!("the scene has no nodes to orbit around");
    }
    let centre = (lo + hi) * 0.5;
    let half_diag = ((hi - lo) * 0.5).length().max(1e-6);
    let fov_y = 2.0 * ((0.5 * fov_deg.to_radians()).tan() * height as f64 / width as f64).atan();
    let r = radius.unwrap_or(1.15 * half_diag / (0.5 * fov_y.min(fov_deg.to_radians())).sin());
    if !(r.is_finite() && r > 0.0) {
        bail!("--radius: expected a positive distance, got {r}");
    }
    let up = scene.up.normalize();
    let a = if up.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    let e1 = (a - up * a.dot(up)).normalize();
    let e2 = up.cross(e1);
    let el = elevation_deg.to_radians();
    let intr = Intrinsics::from_fov_x(width, height, fov_deg.to_radians());
    (0..frames)
        .map(|k| {
            let th = std::f64::consts::TAU * k as f64 / frames as f64;
            let dir = (e1 * th.cos() + e2 * th.sin()) * el.cos() + up * el.sin();
            let pose = Pose::look_at(centre + dir * r, centre, up)?;
            Ok(View {
                name: format!("orbit_{k:03}"),
                camera: Camera {
                    intrinsics: intr,
                    pose,
                },
            })
        })
        .collect()
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--size: expected WxH such as 480x360, got {s:?}"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("--size: bad width in {s:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("--size: bad height in {s:?}"))?;
    if w == 0 || h == 0 || w > 8192 || h > 8192 {
        bail!("--size: expected 1..8192 per side, got {s:?}");
    }
    Ok((w, h))
}

fn views(a: &RenderArgs, scene: &Scene) -> anyhow::Result<Vec<View>> {
    if a.cameras == "orbit" {
        let (w, h) = parse_size(&a.size)?;
        return orbit(scene, a.frames, w, h, a.fov, a.elevation, a.radius);
    }
    let path = Path::new(&a.cameras);
    let opts = LoadOptions {
        downscale: a.downscale,
        ..Default::default()
    };
    let ds = assist_data::load(path, &opts)
        .with_context(|| format!("--cameras: loading {}", path.display()))?;
    let all = a.split == "all" || (a.split == "auto" && !ds.split_declared);
    let frames: Vec<_> = if all {
        ds.frames.iter().collect()
    } else {
        let name = if a.split == "auto" { "test" } else { &a.split };
        let split = Split::parse(name).with_context(|| {
            format!(
                "--split: expected train, val, test, all or auto, got {:?}",
                a.split
            )
        })?;
        ds.frames_in(split).collect()
    };
    if frames.is_empty() {
        bail!(
            "--cameras {}: no frames in split {:?} (it has {} frames; try --split all)",
            path.display(),
            a.split,
            ds.frames.len()
        );
    }
    Ok(frames
        .into_iter()
        .map(|f| View {
            name: f.name.clone(),
            camera: f.camera,
        })
        .collect())
}

/// Semantic classes: distinct labels in id order of first appearance, 0 = background.
fn semantic_classes(scene: &Scene) -> (BTreeMap<u16, u16>, Vec<String>) {
    let mut names = vec!["background".to_string()];
    let mut of_id = BTreeMap::new();
    let mut nodes: Vec<_> = scene.nodes.iter().filter(|n| !n.is_background()).collect();
    nodes.sort_by_key(|n| n.id);
    for n in nodes {
        let k = match names.iter().position(|l| *l == n.label) {
            Some(k) => k,
            None => {
                names.push(n.label.clone());
                names.len() - 1
            }
        };
        of_id.insert(n.id, k as u16);
    }
    (of_id, names)
}

pub(crate) fn rgb_image(w: u32, h: u32, data: Vec<f32>) -> ImageF32 {
    ImageF32 {
        width: w,
        height: h,
        channels: 3,
        data,
    }
}

/// Writes the requested outputs of one rendered view (the folders must exist).
pub(crate) fn write_view(
    out: &Path,
    v: &View,
    img: &RenderedImage,
    bg: Option<&RenderedImage>,
    outputs: &[Output],
    scene: &NeuralScene,
    classes: &BTreeMap<u16, u16>,
) -> anyhow::Result<()> {
    let (w, h) = (img.width, img.height);
    let file = |dir: &str, ext: &str| out.join(dir).join(format!("{}.{ext}", v.name));
    for o in outputs {
        match o {
            Output::Rgb => {
                write_rgb_png(&file("images", "png"), &rgb_image(w, h, img.rgb.clone()))?
            }
            Output::Depth => {
                let mpu = scene.scene.meters_per_unit;
                let mm: Vec<u16> = img
                    .depth
                    .iter()
                    .map(|&z| (z as f64 * mpu * 1000.0).round().clamp(0.0, 65535.0) as u16)
                    .collect();
                write_gray16_png(&file("depth", "png"), w, h, &mm)?;
                let npy = assist_data::npy::encode_npy_f32(&[h as usize, w as usize], &img.depth);
                write_atomic(&file("depth", "npy"), &npy)?;
            }
            Output::Panoptic => write_gray16_png(&file("panoptic", "png"), w, h, &img.panoptic)?,
            Output::Semantic => {
                let sem: Vec<u16> = img
                    .panoptic
                    .iter()
                    .map(|id| classes.get(id).copied().unwrap_or(0))
                    .collect();
                write_gray16_png(&file("semantic", "png"), w, h, &sem)?;
            }
            Output::Objects => {
                for layer in &img.layers {
                    let mut data = Vec::with_capacity(layer.opacity.len() * 4);
                    for (k, &o) in layer.opacity.iter().enumerate() {
                        data.extend_from_slice(&layer.rgb[k * 3..k * 3 + 3]);
                        data.push(o);
                    }
                    let dir = out.join("objects").join(layer.id.to_string());
                    std::fs::create_dir_all(&dir)
                        .with_context(|| format!("creating {}", dir.display()))?;
                    write_rgb_png(
                        &dir.join(format!("{}.png", v.name)),
                        &ImageF32 {
                            width: w,
                            height: h,
                            channels: 4,
                            data,
                        },
                    )?;
                }
            }
            Output::Background => {
                let bg = bg.expect("rendered when asked for");
                write_rgb_png(&file("background", "png"), &rgb_image(w, h, bg.rgb.clone()))?;
            }
        }
    }
    Ok(())
}

/// Creates the folders the outputs are written to.
pub(crate) fn create_dirs(out: &Path, outputs: &[Output]) -> anyhow::Result<()> {
    let dirs: &[(Output, &str)] = &[
        (Output::Rgb, "images"),
        (Output::Depth, "depth"),
        (Output::Panoptic, "panoptic"),
        (Output::Semantic, "semantic"),
        (Output::Objects, "objects"),
        (Output::Background, "background"),
    ];
    for (o, d) in dirs {
        if outputs.contains(o) {
            std::fs::create_dir_all(out.join(d))
                .with_context(|| format!("creating {}", out.join(d).display()))?;
        }
    }
    Ok(())
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() && !a.force {
        bail!(
            "{} exists and is not empty (pass --force to write into it)",
            a.out.display()
        );
    }
    let outputs = parse_outputs(&a.outputs)?;
    let (scene, _) = assist_render::scene_file::load(&a.scene)
        .with_context(|| format!("loading scene {}", a.scene.display()))?;
    let highlight = if a.no_highlight {
        None
    } else {
        a.select.or(scene.scene.selected)
    };
    if let Some(id) = highlight
        && scene.scene.node(id).is_none()
    {
        bail!("--select: no node with id {id} in {}", a.scene.display());
    }
    let views = views(&a, &scene.scene)?;
    create_dirs(&a.out, &outputs)?;
    let opts = RenderOptions {
        highlight: highlight.map(|id| (id, assist_render::HIGHLIGHT)),
        layers: outputs.contains(&Output::Objects),
        ..Default::default()
    };
    let background_only = outputs.contains(&Output::Background).then(|| {
        let mut s = scene.clone();
        s.scene.nodes.retain(|n| n.is_background());
        s
    });
    if background_only
        .as_ref()
        .is_some_and(|s| s.scene.nodes.is_empty())
    {
        bail!("--outputs background: the scene has no background node");
    }
    let (classes, class_names) = semantic_classes(&scene.scene);
    let bar = crate::progress::bar(std::io::stderr().is_terminal(), "render");
    bar.set_length(views.len() as u64);
    let mut out_frames = Vec::new();
    for v in &views {
        let img = render_camera(&scene, &v.camera, u32::MAX, &opts);
        let bg = background_only
            .as_ref()
            .map(|s| render_camera(s, &v.camera, u32::MAX, &RenderOptions::default()));
        write_view(&a.out, v, &img, bg.as_ref(), &outputs, &scene, &classes)?;
        let i = &v.camera.intrinsics;
        let mut f = json!({
            "file_path": format!("images/{}.png", v.name),
            "transform_matrix": v.camera.pose.to_matrix().transpose().to_cols_array_2d(),
            "fl_x": i.fx, "fl_y": i.fy, "cx": i.cx, "cy": i.cy,
            "w": img.width, "h": img.height,
        });
        if outputs.contains(&Output::Depth) {
            f["depth_file_path"] = json!(format!("depth/{}.png", v.name));
        }
        if outputs.contains(&Output::Panoptic) {
            f["instance_mask_path"] = json!(format!("panoptic/{}.png", v.name));
        }
        out_frames.push(f);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let objects: Vec<_> = scene
        .scene
        .nodes
        .iter()
        .filter(|n| !n.is_background())
        .collect();
    let legend: serde_json::Map<String, serde_json::Value> =
        std::iter::once(("0".to_string(), json!("background")))
            .chain(objects.iter().map(|n| (n.id.to_string(), json!(n.label))))
            .collect();
    let tj = json!({
        "camera_model": "OPENCV",
        "depth_unit_scale_factor": 0.001 / scene.scene.meters_per_unit,
        "world_up": scene.scene.up.to_array(),
        "frames": out_frames,
        "instances": objects.iter().map(|n| json!({"id": n.id, "label": n.label})).collect::<Vec<_>>(),
    });
    write_atomic(
        &a.out.join("transforms.json"),
        serde_json::to_string_pretty(&tj)?.as_bytes(),
    )?;
    if outputs.contains(&Output::Panoptic) {
        write_atomic(
            &a.out.join("panoptic_legend.json"),
            serde_json::to_string_pretty(&legend)?.as_bytes(),
        )?;
    }
    if outputs.contains(&Output::Semantic) {
        let sem: serde_json::Map<String, serde_json::Value> = class_names
            .iter()
            .enumerate()
            .map(|(k, n)| (k.to_string(), json!(n)))
            .collect();
        write_atomic(
            &a.out.join("semantic_legend.json"),
            serde_json::to_string_pretty(&sem)?.as_bytes(),
        )?;
    }
    eprintln!("rendered {} views into {}", views.len(), a.out.display());
    Ok(())
}
