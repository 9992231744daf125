//! `assist render SCENE --out DIR`: renders a trained scene from a dataset's cameras into a
//! new dataset: RGB PNG, z-depth (16-bit PNG in millimetres and float32 `.npy`), instance
//! ids (16-bit PNG with a JSON legend), and a `transforms.json` of the rendered cameras.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_data::image_io::{ImageF32, write_atomic, write_gray16_png, write_rgb_png};
use assist_data::{LoadOptions, Split};
use assist_render::{RenderOptions, render_camera};
use clap::Args;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Dataset whose cameras are rendered.
    #[arg(long)]
    pub cameras: PathBuf,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Highlight this instance id.
    #[arg(long)]
    pub select: Option<u16>,
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() && !a.force {
        bail!(
            "{} exists and is not empty (pass --force to write into it)",
            a.out.display()
        );
    }
    let split = Split::parse(&a.split)
        .with_context(|| format!("--split: expected train, val or test, got {:?}", a.split))?;
    let (scene, _) = assist_render::scene_file::load(&a.scene)
        .with_context(|| format!("loading scene {}", a.scene.display()))?;
    if let Some(id) = a.select
        && scene.scene.node(id).is_none()
    {
        bail!("--select: no node with id {id} in {}", a.scene.display());
    }
    let ds = assist_data::load(&a.cameras, &LoadOptions::default())
        .with_context(|| format!("loading cameras {}", a.cameras.display()))?;
    for d in ["images", "depth", "panoptic"] {
        std::fs::create_dir_all(a.out.join(d))?;
    }
    let opts = RenderOptions {
        highlight: a.select.map(|id| (id, assist_render::HIGHLIGHT)),
        ..Default::default()
    };
    let frames: Vec<_> = ds.frames_in(split).collect();
    let bar = crate::progress::bar(std::io::stderr().is_terminal(), "render");
    bar.set_length(frames.len() as u64);
    let mut out_frames = Vec::new();
    for f in &frames {
        let img = render_camera(&scene, &f.camera, u32::MAX, &opts);
        let (w, h) = (img.width, img.height);
        let rgb = ImageF32 {
            width: w,
            height: h,
            channels: 3,
            data: img.rgb.clone(),
        };
        write_rgb_png(&a.out.join("images").join(format!("{}.png", f.name)), &rgb)?;
        let mm: Vec<u16> = img
            .depth
            .iter()
            .map(|&z| {
                (z as f64 * scene.scene.meters_per_unit * 1000.0)
                    .round()
                    .clamp(0.0, 65535.0) as u16
            })
            .collect();
        write_gray16_png(
            &a.out.join("depth").join(format!("{}.png", f.name)),
            w,
            h,
            &mm,
        )?;
        let npy = assist_data::npy::encode_npy_f32(&[h as usize, w as usize], &img.depth);
        write_atomic(&a.out.join("depth").join(format!("{}.npy", f.name)), &npy)?;
        write_gray16_png(
            &a.out.join("panoptic").join(format!("{}.png", f.name)),
            w,
            h,
            &img.panoptic,
        )?;
        out_frames.push(serde_json::json!({
            "file_path": format!("images/{}.png", f.name),
            "depth_file_path": format!("depth/{}.png", f.name),
            "instance_mask_path": format!("panoptic/{}.png", f.name),
            "transform_matrix": f.camera.pose.to_matrix().transpose().to_cols_array_2d(),
            "fl_x": f.camera.intrinsics.fx, "fl_y": f.camera.intrinsics.fy,
            "cx": f.camera.intrinsics.cx, "cy": f.camera.intrinsics.cy,
            "w": w, "h": h,
        }));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let legend: serde_json::Map<String, serde_json::Value> =
        std::iter::once(("0".to_string(), serde_json::json!("background")))
            .chain(
                scene
                    .scene
                    .nodes
                    .iter()
                    .filter(|n| !n.is_background())
                    .map(|n| (n.id.to_string(), serde_json::json!(n.label))),
            )
            .collect();
    let tj = serde_json::json!({
        "camera_model": "OPENCV",
        "depth_unit_scale_factor": 0.001 / scene.scene.meters_per_unit,
        "frames": out_frames,
        "instances": scene.scene.nodes.iter().filter(|n| !n.is_background()).map(|n| serde_json::json!({"id": n.id, "label": n.label})).collect::<Vec<_>>(),
    });
    write_atomic(
        &a.out.join("transforms.json"),
        serde_json::to_string_pretty(&tj)?.as_bytes(),
    )?;
    write_atomic(
        &a.out.join("panoptic_legend.json"),
        serde_json::to_string_pretty(&legend)?.as_bytes(),
    )?;
    eprintln!("rendered {} views into {}", frames.len(), a.out.display());
    Ok(())
}
