//! `assist demo`: the main job on the built-in default scene, with no downloads.
//!
//! Generates a synth scene into `./assist-demo/scene`, validates it as any dataset, checks
//! multi-view depth consistency, and writes a contact sheet of a test view (RGB, depth,
//! instance masks, the background without objects, and each edit).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_data::image_io::{ImageF32, read_depth_png, read_ids, read_rgb, write_rgb_png};
use assist_data::synth::SynthConfig;
use assist_data::{LoadOptions, Split};
use clap::Args;

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "assist-demo")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Replace an output folder that was not written by a previous demo.
    #[arg(long)]
    pub force: bool,
}

const MARKER: &str = ".assist-demo";

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
    let scene_dir = out.join("scene");
    let cfg = SynthConfig {
        seed: a.seed,
        ..SynthConfig::default()
    };
    eprintln!(
        "1/3 generating the built-in scene ({} views at {}x{}, {} objects)",
        cfg.views, cfg.width, cfg.height, cfg.objects
    );
    let summary = crate::cmd_synth::synth(&cfg, &scene_dir, true, true)?;

    eprintln!("2/3 reading it back as a dataset and validating every file");
    let ds = assist_data::load(&scene_dir, &LoadOptions::default())?;
    let report = assist_data::validate::validate(&ds);
    if let Some(e) = report.errors.first() {
        bail!("generated scene failed validation: {e}");
    }
    let test: Vec<usize> = (0..ds.frames.len())
        .filter(|&i| ds.frames[i].split == Split::Test)
        .collect();
    let (a_idx, b_idx) = (test[0], nearest_view(&ds, test[0]));
    let r = assist_data::consistency::reproject(&ds, a_idx, b_idx, 1, None)?;
    eprintln!(
        "    {} files decode at the declared size; view {a_idx} -> {b_idx}: {:.1}% of reprojected pixels depth-consistent, median colour difference {:.2}/255",
        report.files_checked,
        100.0 * r.consistent_fraction(),
        r.median_abs_rgb * 255.0
    );

    eprintln!("3/3 writing the contact sheet");
    let sheet = out.join("contact_sheet.png");
    contact_sheet(&scene_dir, &ds.frames[a_idx].name, &summary.edits, &sheet)?;
    println!("Done. Look at:");
    println!(
        "  {}   (test view: RGB | depth | instances | background; then each edit)",
        sheet.display()
    );
    println!(
        "  {}/            (the dataset: images, depth, instances, background/, edits/)",
        scene_dir.display()
    );
    println!("  assist dataset info {}", scene_dir.display());
    Ok(())
}

fn nearest_view(ds: &assist_data::Dataset, a: usize) -> usize {
    let c = ds.frames[a].camera.pose.center();
    (0..ds.frames.len())
        .filter(|&b| b != a)
        .min_by(|&x, &y| {
            (ds.frames[x].camera.pose.center() - c)
                .length()
                .total_cmp(&(ds.frames[y].camera.pose.center() - c).length())
        })
        .unwrap_or(a)
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

fn ids_to_rgb(p: &Path) -> anyhow::Result<ImageF32> {
    let ids = read_ids(p)?;
    let mut out = ImageF32::new(ids.width, ids.height, 3);
    for (k, &v) in ids.data.iter().enumerate() {
        out.data[k * 3..k * 3 + 3].copy_from_slice(&id_color(v));
    }
    Ok(out)
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

fn contact_sheet(scene: &Path, name: &str, edits: &[String], out: &Path) -> anyhow::Result<()> {
    let file = format!("{name}.png");
    let mut tiles = vec![
        read_rgb(&scene.join("images").join(&file), [0.0; 3])?.0,
        depth_to_rgb(&read_depth_png(&scene.join("depth").join(&file), 0.001)?),
        ids_to_rgb(&scene.join("instances").join(&file))?,
        read_rgb(&scene.join("background/images").join(&file), [0.0; 3])?.0,
    ];
    for e in edits {
        let d = scene.join("edits").join(e);
        tiles.push(read_rgb(&d.join("images").join(&file), [0.0; 3])?.0);
        tiles.push(ids_to_rgb(&d.join("instances").join(&file))?);
    }
    while tiles.len() % 4 != 0 {
        let (w, h) = (tiles[0].width, tiles[0].height);
        let mut blank = ImageF32::new(w, h, 3);
        blank.data.fill(1.0);
        tiles.push(blank);
    }
    write_rgb_png(out, &tile(&tiles, 4))?;
    Ok(())
}
