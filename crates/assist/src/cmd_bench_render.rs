//! `assist bench render SCENE --data DATA`: what a rendered frame costs and where its time
//! goes — samples marched and queried per ray, seconds per stage (marching, pruning's
//! rounds, the field queries, shading and compositing) — for each renderer setting
//! asked for, on the same held-out views; and what each setting costs in PSNR, against the
//! photographs and against the first setting's render. With `--device gpu` (or auto
//! finding one) a last setting queries the fields on the GPU.

use std::path::PathBuf;

use anyhow::{Context, bail};
use assist_render::{Precision, RenderOptions, RenderStats, SceneTables, render_camera_timed};
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct RenderBenchArgs {
    /// Trained scene (NAME.assist).
    pub scene: PathBuf,
    /// Dataset with the cameras and photographs.
    #[arg(long)]
    pub data: PathBuf,
    /// The split whose views are rendered: test, val, train or all.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Views rendered, spread evenly over the split.
    #[arg(long, default_value_t = 3)]
    pub views: usize,
    /// Images N times smaller (default: as the scene was trained).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: Option<u32>,
    /// Render at this width instead (height by the aspect; no PSNR against the
    /// photographs then, only between settings): e.g. 1080 for a phone's 1080×1920.
    #[arg(long, value_parser = clap::value_parser!(u32).range(16..=16384))]
    pub width: Option<u32>,
    /// Pruning thresholds to compare (the transmittance below which a node's samples are
    /// dropped; rendering's default is 1e-4; 0 = off), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "0,1e-4")]
    pub prune_eps: Vec<f32>,
    /// Occupancy thresholds to compare, each as the opacity one smallest step through a
    /// cell must reach for the cell to be marched (the grid's own rule caps it by the
    /// mean density; these do not), comma-separated; each a setting without pruning.
    #[arg(long, value_delimiter = ',')]
    pub occupancy: Vec<f32>,
    /// Marching-step scales to compare (`render --quality draft` is 2), comma-separated;
    /// each a setting with the first `--tables` and no pruning.
    #[arg(long, value_delimiter = ',')]
    pub step_scale: Vec<f32>,
    /// Hash tables to compare, comma-separated: `bf16` (packed, what `render` reads) or
    /// `f32` (the parameters as trained); each with every `--prune-eps`.
    #[arg(long, value_delimiter = ',', default_value = "bf16")]
    pub tables: Vec<String>,
    /// Renders per view and setting (the median time is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// One JSON object with every setting's figures.
    #[arg(long)]
    pub json: bool,
    /// Also render on this device when it is a GPU (a last setting: the fields queried
    /// there in f32, no pruning, compared with the first).
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

use crate::cmd_bench::median_of as median;

/// PSNR between two images in [0, 1] (values clamped as written).
fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let se: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x.clamp(0.0, 1.0) as f64 - y.clamp(0.0, 1.0) as f64).powi(2))
        .sum();
    assist_train::metrics::mse_to_psnr(se / a.len().max(1) as f64)
}

/// Refuses settings that cannot be rendered, naming the flag.
fn check(a: &RenderBenchArgs) -> anyhow::Result<()> {
    if a.runs == 0 || a.views == 0 || a.prune_eps.is_empty() {
        bail!("--runs, --views and --prune-eps need at least one each");
    }
    if let Some(e) = a.prune_eps.iter().find(|e| !(0.0..1.0).contains(*e)) {
        bail!("--prune-eps: expected values in [0, 1), got {e}");
    }
    if let Some(t) = a.tables.iter().find(|t| *t != "bf16" && *t != "f32") {
        bail!("--tables: expected bf16 or f32, got {t:?}");
    }
    if a.tables.is_empty() {
        bail!("--tables: expected bf16, f32 or both");
    }
    if let Some(s) = a.step_scale.iter().find(|s| !(0.25..=16.0).contains(*s)) {
        bail!("--step-scale: expected values from 0.25 to 16, got {s}");
    }
    Ok(())
}

/// One setting compared (`tables` "gpu": the fields queried on the GPU).
#[derive(Clone, Copy)]
struct Setting<'a> {
    tables: &'a str,
    eps: f32,
    occ: Option<f32>,
    step: f32,
}

impl Setting<'_> {
    /// The setting in words, as the report names it.
    fn name(&self) -> String {
        let t = self.tables;
        if t == "gpu" {
            return "the GPU's f32 fields".into();
        }
        match self.occ {
            Some(o) => format!("{t} tables, occupancy {o}"),
            None if self.step != 1.0 => format!("{t} tables, step scale {}", self.step),
            None => format!("{t} tables, prune_eps {}", self.eps),
        }
    }
}

/// The settings compared, in order: tables × pruning, then the occupancy thresholds, then
/// the step scales, then the GPU's (when `gpu`).
fn settings_of(a: &RenderBenchArgs, gpu: bool) -> Vec<Setting<'_>> {
    let first = a.tables[0].as_str();
    let at = |tables, eps, occ, step| Setting {
        tables,
        eps,
        occ,
        step,
    };
    a.tables
        .iter()
        .flat_map(|t| {
            a.prune_eps
                .iter()
                .map(move |&e| at(t.as_str(), e, None, 1.0))
        })
        .chain(a.occupancy.iter().map(|&o| at(first, 0.0, Some(o), 1.0)))
        .chain(a.step_scale.iter().map(|&s| at(first, 0.0, None, s)))
        .chain(gpu.then(|| at("gpu", 0.0, None, 1.0)))
        .collect()
}

/// The scene's packed tables, their megabytes and the seconds packing took.
fn pack(scene: &assist_scene::NeuralScene) -> (Option<std::sync::Arc<SceneTables>>, f64, f64) {
    let t = std::time::Instant::now();
    let packed = std::sync::Arc::new(SceneTables::of(scene));
    let mb = packed.bytes() as f64 / 1e6;
    (Some(packed), mb, t.elapsed().as_secs_f64())
}

/// `--views` frames of the split, spread evenly over it.
fn pick_views<'a>(
    a: &RenderBenchArgs,
    ds: &'a assist_data::Dataset,
    split: Option<assist_data::Split>,
) -> anyhow::Result<Vec<&'a assist_data::Frame>> {
    let frames: Vec<_> = ds
        .frames
        .iter()
        .filter(|f| split.is_none_or(|s| f.split == s))
        .collect();
    if frames.is_empty() {
        bail!("{}: no frames in split {}", a.data.display(), a.split);
    }
    let n = a.views.min(frames.len());
    Ok((0..n).map(|i| frames[i * frames.len() / n]).collect())
}

pub fn run(a: RenderBenchArgs) -> anyhow::Result<()> {
    check(&a)?;
    let (scene, info) = assist_scene::scene_file::load(&a.scene)
        .with_context(|| format!("reading {}", a.scene.display()))?;
    let split = crate::cmd_eval::parse_split(&a.split)?;
    let opts = assist_data::LoadOptions {
        downscale: a
            .downscale
            .unwrap_or_else(|| assist_session::trained_downscale(&info)),
        ..Default::default()
    };
    let ds = assist_data::load(&a.data, &opts)?;
    let picked = pick_views(&a, &ds, split)?;
    let n = picked.len();
    let say = |m: String| {
        if !a.json {
            eprintln!("{m}");
        }
    };
    let bg = scene.scene.background_color;
    let mut settings = Vec::new();
    let mut first: Vec<Vec<f32>> = Vec::new();
    let device = a.device.open()?;
    let runs = settings_of(&a, device.backend.is_some());
    let (packed, pack_mb, pack_s) = pack(&scene);
    if a.tables.iter().any(|t| t == "bf16") {
        say(format!(
            "packed the hash tables: {pack_mb:.1} MB in {:.0} ms (once per scene loaded)",
            pack_s * 1e3
        ));
    }
    for (si, set) in runs.iter().enumerate() {
        let (tables, eps, occ, step) = (set.tables, set.eps, set.occ, set.step);
        let mut scene = scene.clone();
        let mut ro = RenderOptions {
            prune_eps: eps,
            step_scale: step,
            precision: if tables == "bf16" {
                Precision::Bf16
            } else {
                Precision::F32
            },
            tables: packed.clone(),
            backend: (tables == "gpu").then(|| device.field_backend()).flatten(),
            ..RenderOptions::default()
        };
        if let Some(o) = occ {
            for nf in scene.fields.values_mut() {
                let nf = std::sync::Arc::make_mut(nf);
                let thr = nf.occupancy.threshold * o / 0.01;
                nf.occupancy.refresh_bits_above(thr);
            }
            // The fields are copies now (the packed tables are found by identity).
            ro.tables = Some(std::sync::Arc::new(SceneTables::of(&scene)));
        }
        let scene = &scene;
        let (mut times, mut truth_psnr, mut vs_first) = (Vec::new(), Vec::new(), Vec::new());
        let mut stats = RenderStats::default();
        for (vi, f) in picked.iter().enumerate() {
            let mut cam = f.camera;
            if let Some(w) = a.width {
                let k = f.camera.width() as f64 / w as f64;
                let h = ((f.camera.height() as f64 / k).round() as u32).max(1);
                cam.intrinsics = f.camera.intrinsics.downscaled(k, w, h);
            }
            let mut per = Vec::new();
            let mut last = None;
            for _ in 0..a.runs {
                let (img, st) = render_camera_timed(scene, &cam, u32::MAX, &ro);
                per.push(st);
                last = Some(img);
            }
            let img = last.expect("runs ≥ 1");
            per.sort_by(|x, y| x.wall_s.total_cmp(&y.wall_s));
            let mid = per[per.len() / 2];
            times.push(mid.wall_s);
            stats.add(&mid);
            if a.width.is_none() {
                let v = assist_train::load_view(f, u32::MAX, bg)?;
                truth_psnr.push(psnr(&img.rgb, &v.rgb));
            }
            if si == 0 {
                first.push(img.rgb);
            } else {
                vs_first.push(psnr(&img.rgb, &first[vi]));
            }
        }
        let rays = stats.rays.max(1) as f64;
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let (w, h) = (picked[0].camera.width(), picked[0].camera.height());
        let (w, h) = a.width.map_or((w, h), |w2| {
            (w2, (h as f64 * w2 as f64 / w as f64).round() as u32)
        });
        let frame_s = median(times.clone());
        let s = json!({
            "tables": tables,
            "prune_eps": eps,
            "occupancy": occ,
            "step_scale": step,
            "frame_s": frame_s,
            "frame_s_each": times,
            "marched_per_ray": stats.marched as f64 / rays,
            "queried_per_ray": stats.queried as f64 / rays,
            "seconds": {
                "sample": stats.sample_s / n as f64,
                "prune": stats.prune_s / n as f64,
                "query": stats.query_s / n as f64,
                "composite": stats.composite_s / n as f64,
            },
            "psnr": mean(&truth_psnr),
            "psnr_vs_first": mean(&vs_first),
        });
        let name = set.name();
        say(format!(
            "{name}: {frame_s:.2} s per {w}×{h} frame (median of {n} views); \
             samples per ray {:.1} marched, {:.1} queried; per frame: sample {:.2} s, prune {:.2} s, query {:.2} s, composite {:.2} s{}{}",
            stats.marched as f64 / rays,
            stats.queried as f64 / rays,
            stats.sample_s / n as f64,
            stats.prune_s / n as f64,
            stats.query_s / n as f64,
            stats.composite_s / n as f64,
            mean(&truth_psnr).map_or(String::new(), |p| format!("; PSNR {p:.3} dB")),
            mean(&vs_first).map_or(String::new(), |p| format!(
                " ({p:.1} dB against the first setting)"
            )),
        ));
        settings.push(s);
    }
    device.report();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "scene": a.scene.display().to_string(),
                "data": a.data.display().to_string(),
                "views": picked.iter().map(|f| f.name.clone()).collect::<Vec<_>>(),
                "runs": a.runs,
                "threads": rayon::current_num_threads(),
                "simd": assist_simd::level().name(),
                "packed_tables": {"megabytes": pack_mb, "seconds": pack_s},
                "device": device.name(),
                "settings": settings,
            }))?
        );
    }
    Ok(())
}
