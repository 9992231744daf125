//! `assist demo`: the main job on the built-in default, with no downloads.
//!
//! Generates two synthetic tabletop scenes (perfect ground truth), trains the first (about
//! two minutes on 2 cores) and the second briefly, edits the first with plain-language
//! instructions — move, rotate, duplicate, delete, and insert an object from the second
//! scene — and renders test views before and after (RGB, depth, panoptic ids) into
//! `./assist-demo/`, with a contact sheet.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_core::{Scene, SceneNode};
use assist_data::image_io::{ImageF32, write_rgb_png};
use assist_data::synth::SynthConfig;
use assist_data::{LoadOptions, Split};
use assist_lang::ParseOptions;
use assist_render::{Editor, RenderOptions, render_camera};
use clap::Args;

use crate::cmd_render::{Output, View, create_dirs, rgb_image, write_view};

/// What the demo writes for each rendered view.
const OUTPUTS: [Output; 3] = [Output::Rgb, Output::Depth, Output::Panoptic];

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "assist-demo")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Training time of the main scene, seconds.
    #[arg(long, default_value_t = 110.0)]
    pub train_seconds: f64,
    /// Training time of the second scene (the source of the inserted object), seconds.
    #[arg(long, default_value_t = 30.0)]
    pub other_seconds: f64,
    /// Replace an output folder that was not written by a previous demo.
    #[arg(long)]
    pub force: bool,
}

const MARKER: &str = ".assist-demo";

fn train(data: &Path, out: &Path, seconds: f64, seed: u64) -> anyhow::Result<()> {
    // Through the command line's own parser, so that the demo trains with `assist train`'s
    // defaults and cannot drift from them.
    use clap::Parser;
    #[derive(Parser)]
    struct Wrap {
        #[command(flatten)]
        train: crate::cmd_train::TrainArgs,
    }
    let (data, out) = (data.as_os_str(), out.as_os_str());
    let max_time = seconds.to_string();
    let seed = seed.to_string();
    let args: [&std::ffi::OsStr; 15] = [
        "demo".as_ref(),
        data,
        "--out".as_ref(),
        out,
        "--iters".as_ref(),
        "1000000".as_ref(),
        "--max-time".as_ref(),
        max_time.as_ref(),
        "--appearance".as_ref(),
        "off".as_ref(),
        "--seed".as_ref(),
        seed.as_ref(),
        "--checkpoint-every".as_ref(),
        "1e9".as_ref(),
        "--force".as_ref(),
    ];
    let w = Wrap::try_parse_from(args).context("demo: training arguments")?;
    crate::cmd_train::run(w.train)
}

fn objects(scene: &Scene) -> Vec<&SceneNode> {
    let mut v: Vec<&SceneNode> = scene.nodes.iter().filter(|n| !n.is_background()).collect();
    v.sort_by_key(|n| n.id);
    v
}

/// The instruction the demo gives, naming objects by their labels.
fn instruction(scene: &Scene, other: &Scene, other_path: &str) -> anyhow::Result<String> {
    let o = objects(scene);
    let src = objects(other);
    if o.len() < 4 || src.is_empty() {
        bail!("the demo scenes need at least 4 objects and 1 object to insert");
    }
    // The inserted object stands where the deleted one stood, resting on the table.
    let gone = o[3];
    let corners = gone.world_corners();
    let table = corners
        .iter()
        .map(|c| c.dot(scene.up))
        .fold(f64::INFINITY, f64::min);
    let ins = src[0];
    let ins_bottom = ins
        .world_corners()
        .iter()
        .map(|c| c.dot(other.up))
        .fold(f64::INFINITY, f64::min);
    let half_height = ins.world_from_local.translation.dot(other.up) - ins_bottom;
    let at = gone.world_from_local.translation;
    let p = at - scene.up * at.dot(scene.up) + scene.up * (table + half_height);
    Ok(format!(
        "move the {} 8 cm to the left, rotate the {} by 60 degrees, duplicate the {} and move the copy 10 cm forward, delete the {}, then add the {} from {} at {:.4} {:.4} {:.4}",
        o[0].label, o[1].label, o[2].label, gone.label, ins.label, other_path, p.x, p.y, p.z
    ))
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    let out = &a.out;
    if out.exists() && !out.join(MARKER).exists() && !a.force {
        let non_empty = std::fs::read_dir(out)
            .map(|mut d| d.next().is_some())
            .unwrap_or(true);
        if non_empty {
            bail!(
                "{}: exists and was not written by `assist demo`; pass --force to replace it, or --out elsewhere",
                out.display()
            );
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join(MARKER), "written by assist demo\n")
        .with_context(|| format!("writing {}", out.join(MARKER).display()))?;
    let t0 = std::time::Instant::now();
    let (data_a, data_b) = (out.join("scene"), out.join("other"));
    let cfg = SynthConfig {
        seed: a.seed,
        ..SynthConfig::default()
    };
    eprintln!(
        "1/6 generating two built-in scenes ({} views at {}x{}, {} objects each)",
        cfg.views, cfg.width, cfg.height, cfg.objects
    );
    crate::cmd_synth::synth(&cfg, &data_a, true, false)?;
    let cfg_b = SynthConfig {
        seed: a.seed.wrapping_add(1),
        ..cfg
    };
    crate::cmd_synth::synth(&cfg_b, &data_b, true, false)?;
    let ds = assist_data::load(&data_a, &LoadOptions::default())?;
    let report = assist_data::validate::validate(&ds);
    if let Some(e) = report.errors.first() {
        bail!("generated scene failed validation: {e}");
    }

    let (scene_a, scene_b) = (out.join("scene.assist"), out.join("other.assist"));
    eprintln!("2/6 training the scene for {:.0} s", a.train_seconds);
    train(&data_a, &scene_a, a.train_seconds, a.seed)?;
    eprintln!(
        "3/6 training the second scene for {:.0} s (the object to insert comes from it)",
        a.other_seconds
    );
    train(&data_b, &scene_b, a.other_seconds, a.seed)?;

    eprintln!("4/6 measuring the trained scene on its test views");
    let (trained, _) = assist_render::scene_file::load(&scene_a)?;
    let r = assist_train::eval::evaluate(&trained, &ds, Some(Split::Test), 1, |_, _| {})?;
    eprintln!(
        "    test PSNR {:.2} dB, SSIM {:.3}, panoptic mIoU {:.3}, background depth error {:.1}% ({} views)",
        r.psnr,
        r.ssim,
        r.panoptic_miou.unwrap_or(f64::NAN),
        100.0 * r.background_depth_error.unwrap_or(f64::NAN),
        r.images
    );

    eprintln!("5/6 editing with plain language");
    let mut ed = Editor::open(&scene_a)?;
    let (other, _) = assist_render::scene_file::load_scene_json(&scene_b)?;
    let text = instruction(&ed.scene.scene, &other, &scene_b.to_string_lossy())?;
    eprintln!("    \"{text}\"");
    let actions = assist_lang::parse(
        &text,
        &ed.scene.scene,
        &ParseOptions::default(),
        &mut ed.sources,
    )?;
    let edits = ed.apply_all(&actions)?;
    let mut log = String::new();
    for e in &edits {
        let line = serde_json::to_string(&e.to_action(ed.scene.scene.meters_per_unit))?;
        eprintln!("    {line}");
        log.push_str(&line);
        log.push('\n');
    }
    assist_data::image_io::write_atomic(&out.join("edits.jsonl"), log.as_bytes())?;
    let edited = out.join("edited.assist");
    ed.save(&edited, true)?;

    eprintln!("6/6 rendering test views before and after");
    let test: Vec<usize> = (0..ds.frames.len())
        .filter(|&i| ds.frames[i].split == Split::Test)
        .collect();
    let picks = [test[0], test[test.len() / 2]];
    let mut tiles = Vec::new();
    for &i in &picks {
        let f = &ds.frames[i];
        for (tag, s) in [("before", &trained), ("after", &ed.scene)] {
            let img = render_camera(s, &f.camera, u32::MAX, &RenderOptions::default());
            let dir = out.join("render").join(tag);
            create_dirs(&dir, &OUTPUTS)?;
            let view = View {
                name: f.name.clone(),
                camera: f.camera,
            };
            write_view(&dir, &view, &img, None, &OUTPUTS, s, &Default::default())?;
            tiles.push(rgb_image(img.width, img.height, img.rgb.clone()));
            tiles.push(depth_to_rgb(&ImageF32 {
                width: img.width,
                height: img.height,
                channels: 1,
                data: img.depth.clone(),
            }));
            tiles.push(ids_image(img.width, img.height, &img.panoptic));
        }
    }
    let tiles: Vec<ImageF32> = tiles.iter().map(|t| upscale(t, 2)).collect();
    let sheet = out.join("contact_sheet.png");
    write_rgb_png(&sheet, &tile(&tiles, 6))?;
    println!("Done in {:.0} s. Look at:", t0.elapsed().as_secs_f64());
    println!(
        "  {}   (each row: before RGB | depth | panoptic, after RGB | depth | panoptic)",
        sheet.display()
    );
    println!(
        "  {}/   (before/ and after/: images, depth, panoptic of two test views)",
        out.join("render").display()
    );
    println!(
        "  {}   (the resolved actions; replay with assist edit --actions)",
        out.join("edits.jsonl").display()
    );
    println!(
        "  {} and {}   (trained and edited scenes)",
        scene_a.display(),
        edited.display()
    );
    println!(
        "Try: assist edit {} --do \"swap the ... and the ...\" --out swapped.assist",
        edited.display()
    );
    Ok(())
}

fn ids_image(w: u32, h: u32, ids: &[u16]) -> ImageF32 {
    let mut out = ImageF32::new(w, h, 3);
    for (k, &v) in ids.iter().enumerate() {
        out.data[k * 3..k * 3 + 3].copy_from_slice(&id_color(v));
    }
    out
}

/// Nearest-neighbour enlargement by an integer factor.
fn upscale(img: &ImageF32, f: u32) -> ImageF32 {
    let mut out = ImageF32::new(img.width * f, img.height * f, 3);
    for y in 0..out.height {
        for x in 0..out.width {
            let src = img.pixel(x / f, y / f);
            let k = ((y * out.width + x) * 3) as usize;
            out.data[k..k + 3].copy_from_slice(&src[..3]);
        }
    }
    out
}

/// Distinct colours for instance ids (0 = black).
pub fn id_color(id: u16) -> [f32; 3] {
    if id == 0 {
        return [0.0; 3];
    }
    let h = (id as f32 * 0.618_034).fract();
    let (r, g, b) = hsv(h, 0.75, 0.95);
    [r, g, b]
}

fn hsv(h: f32, s: f32, v: f32) -> (f32, f32, f32) {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    match i as i32 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    }
}

fn depth_to_rgb(d: &ImageF32) -> ImageF32 {
    let valid: Vec<f32> = d.data.iter().copied().filter(|&v| v > 0.0).collect();
    let lo = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = valid.iter().copied().fold(0.0, f32::max);
    let mut out = ImageF32::new(d.width, d.height, 3);
    for (k, &v) in d.data.iter().enumerate() {
        let t = if v > 0.0 {
            1.0 - ((v - lo) / (hi - lo).max(1e-6)).sqrt()
        } else {
            0.0
        };
        out.data[k * 3..k * 3 + 3].copy_from_slice(&[t, t, t]);
    }
    out
}

/// Tiles equally sized images into rows of `cols`.
pub fn tile(images: &[ImageF32], cols: usize) -> ImageF32 {
    let (w, h) = (images[0].width, images[0].height);
    let rows = images.len().div_ceil(cols);
    let gap = 2;
    let mut out = ImageF32::new(cols as u32 * (w + gap), rows as u32 * (h + gap), 3);
    out.data.fill(1.0);
    for (n, img) in images.iter().enumerate() {
        let (ox, oy) = ((n % cols) as u32 * (w + gap), (n / cols) as u32 * (h + gap));
        for y in 0..h {
            for x in 0..w {
                let src = img.pixel(x, y);
                let k = (((oy + y) * out.width + ox + x) * 3) as usize;
                out.data[k..k + 3].copy_from_slice(&src[..3]);
            }
        }
    }
    out
}
