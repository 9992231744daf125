//! `assist demo`: the main job on the built-in default, with no downloads.
//!
//! Generates two synthetic tabletop scenes (perfect ground truth), trains the first (about
//! two minutes on 2 cores) and the second briefly, edits the first with plain-language
//! instructions — move, rotate, duplicate, delete, and insert an object from the second
//! scene — and renders test views before and after (RGB, depth, panoptic ids) into
//! `./assist-demo/`, with a contact sheet. Last, the first scene trained as if nobody had
//! labelled it gets its first object from one click.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assist_core::{Scene, SceneNode};
use assist_data::image_io::{ImageF32, write_rgb_png};
use assist_data::synth::SynthConfig;
use assist_data::visual::{captioned, contact_sheet, depth_image, ids_image, upscale};
use assist_data::{LoadOptions, Split};
use assist_session::{
    Appearance, DatasetOutput, Highlight, NamedCamera, Output, Session, TrainConfig, TrainJob,
};
use clap::Args;

/// What the demo writes for each rendered view.
const OUTPUTS: [Output; 3] = [Output::Rgb, Output::Depth, Output::Panoptic];

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "assist-demo")]
    pub out: PathBuf,
    /// Seed of the built-in scene and of training.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Training time of the main scene, seconds.
    #[arg(long, visible_alias = "max-time", default_value_t = 110.0)]
    pub train_seconds: f64,
    /// Training time of the second scene (the source of the inserted object), seconds.
    #[arg(long, default_value_t = 30.0)]
    pub other_seconds: f64,
    /// Training time of the scene trained as if nobody had labelled it (an object is then
    /// made from one click), seconds.
    #[arg(long, default_value_t = 40.0)]
    pub plain_seconds: f64,
    /// Train the scene without masks for this many iterations instead of --plain-seconds:
    /// the same scene, bit for bit, however busy the machine is (the tests use it).
    #[arg(long, value_name = "N", conflicts_with = "plain_seconds",
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub plain_iters: Option<usize>,
}

/// How long a demo scene trains: seconds, or iterations (deterministic under any load).
#[derive(Clone, Copy)]
enum Budget {
    Seconds(f64),
    Iters(usize),
}

fn train(
    data: &Path,
    out: &Path,
    budget: Budget,
    seed: u64,
    no_objects: bool,
) -> anyhow::Result<()> {
    let (max_time, iters) = match budget {
        Budget::Seconds(s) => (Some(s), None),
        Budget::Iters(n) => (None, Some(n)),
    };
    // `assist train`'s defaults (declared once, in the job's configuration).
    let cfg = TrainConfig {
        data: data.to_path_buf(),
        out: out.to_path_buf(),
        max_time,
        iters,
        appearance: Appearance::Off,
        seed,
        checkpoint_every: 1e9,
        force: true,
        no_objects,
        ..TrainConfig::default()
    };
    TrainJob::new(cfg).run(|_| {})?;
    Ok(())
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
    // A previous demo's folder is rewritten; a folder assist did not write never is.
    assist_fs::check_replaceable_as(out, true, assist_fs::Kind::Demo)?;
    let _lock = assist_fs::lock(out, "assist demo")?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join(assist_fs::MARKER), "written by assist demo\n")
        .with_context(|| format!("writing {}", out.join(assist_fs::MARKER).display()))?;
    let t0 = std::time::Instant::now();
    let (data_a, data_b) = (out.join("scene"), out.join("other"));
    // A demo folder from before output markers: its datasets are the demo's own.
    for d in [&data_a, &data_b] {
        if d.is_dir() && !assist_fs::has_marker(d) && d.join("transforms.json").is_file() {
            std::fs::remove_dir_all(d).with_context(|| format!("removing {}", d.display()))?;
        }
    }
    let cfg = SynthConfig {
        seed: a.seed,
        ..SynthConfig::default()
    };
    eprintln!(
        "1/7 generating two built-in scenes ({} views at {}x{}, {} objects each)",
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
    eprintln!("2/7 training the scene for {:.0} s", a.train_seconds);
    train(
        &data_a,
        &scene_a,
        Budget::Seconds(a.train_seconds),
        a.seed,
        false,
    )?;
    eprintln!(
        "3/7 training the second scene for {:.0} s (the object to insert comes from it)",
        a.other_seconds
    );
    train(
        &data_b,
        &scene_b,
        Budget::Seconds(a.other_seconds),
        a.seed,
        false,
    )?;

    eprintln!("4/7 measuring the trained scene on its test views");
    let before = Session::open(&scene_a)?;
    let r = before.evaluate(&ds, Some(Split::Test), 1, |_, _| {})?;
    eprintln!(
        "    test PSNR {:.2} dB, SSIM {:.3}, panoptic mIoU {:.3}, background depth error {:.1}% ({} views)",
        r.psnr,
        r.ssim,
        r.panoptic_miou.unwrap_or(f64::NAN),
        100.0 * r.background_depth_error.unwrap_or(f64::NAN),
        r.images
    );

    eprintln!("5/7 editing with plain language");
    let mut session = Session::open(&scene_a)?;
    let other = Session::describe(&scene_b)?;
    let text = instruction(&session.scene().scene, &other, &scene_b.to_string_lossy())?;
    eprintln!("    \"{text}\"");
    let edits = session.apply_text(&text, None)?;
    let mut log = String::new();
    for e in &edits {
        let line = serde_json::to_string(&e.to_action(session.description().meters_per_unit))?;
        eprintln!("    {line}");
        log.push_str(&line);
        log.push('\n');
    }
    assist_data::image_io::write_atomic(&out.join("edits.jsonl"), log.as_bytes())?;
    let edited = out.join("edited.assist");
    session.save(&edited, true)?;

    let plain = out.join("plain.assist");
    let (budget, how_long) = match a.plain_iters {
        Some(n) => (Budget::Iters(n), format!("{n} iterations")),
        None => (
            Budget::Seconds(a.plain_seconds),
            format!("{:.0} s", a.plain_seconds),
        ),
    };
    eprintln!(
        "6/7 training the scene as if nobody had labelled it for {how_long}, then making an object from one click"
    );
    train(&data_a, &plain, budget, a.seed, true)?;
    let said = object_from_a_click(&ds, &plain)?;
    eprintln!("    {said}");

    eprintln!("7/7 rendering test views before and after");
    let sheet = contact_sheet_of(&ds, &r, &before, &session, out)?;
    println!("Done in {:.0} s. Look at:", t0.elapsed().as_secs_f64());
    println!(
        "  {}   (each row: ground truth | render, depth, panoptic | the same after the edit)",
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

/// Clicks the first object where a training view shows the most of it (the pixel of its
/// mask nearest the mask's centre), makes its box on the `plain` scene (trained without
/// masks), and measures the mask it owns on the test views against the ground truth.
fn object_from_a_click(ds: &assist_data::Dataset, plain: &Path) -> anyhow::Result<String> {
    let session = Session::open(plain)?;
    let id = ds
        .instances
        .iter()
        .map(|i| i.id)
        .min()
        .context("no objects")?;
    let label = ds.instance(id).map(|i| i.label.clone()).unwrap_or_default();
    let ids_of = |f: &assist_data::Frame| -> anyhow::Result<Vec<u16>> {
        let p = f.instance_mask_path.as_ref().context("no instance mask")?;
        Ok(assist_data::image_io::read_instance_mask(p, f.mask_encoding)?.data)
    };
    let mut best: Option<(usize, &assist_data::Frame, (f64, f64))> = None;
    for f in ds.frames.iter().filter(|f| f.split == Split::Train) {
        let m = ids_of(f)?;
        let w = f.camera.width() as usize;
        let px: Vec<(f64, f64)> = (0..m.len())
            .filter(|&i| m[i] == id)
            .map(|i| ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5))
            .collect();
        if px.len() > best.as_ref().map_or(0, |b| b.0) {
            let n = px.len() as f64;
            let c = px
                .iter()
                .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
            let d = |p: &(f64, f64)| (p.0 - c.0).powi(2) + (p.1 - c.1).powi(2);
            let at = px
                .iter()
                .copied()
                .min_by(|a, b| d(a).total_cmp(&d(b)))
                .unwrap_or(c);
            best = Some((px.len(), f, at));
        }
    }
    let (_, frame, at) = best.context("the first object is in no training view")?;
    let cams: Vec<_> = ds
        .frames
        .iter()
        .filter(|f| f.split == Split::Train)
        .map(|f| f.camera)
        .collect();
    let opts = assist_session::split::click::ClickOptions {
        render_downscale: 1,
        ..Default::default()
    };
    let obb =
        assist_session::split::click::box_at_click(&session, &frame.camera, at, &cams, &opts)?;
    let boxes = [assist_session::split::SplitBox {
        id,
        label: label.clone(),
        obb,
    }];
    let test: Vec<&assist_data::Frame> = ds
        .frames
        .iter()
        .filter(|f| f.split == Split::Test)
        .collect();
    let photos = test
        .iter()
        .map(|f| Ok(assist_data::image_io::read_rgb(&f.image_path, [0.0; 3])?.0))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let views: Vec<_> = test
        .iter()
        .zip(&photos)
        .map(|(f, p)| assist_session::split::MaskView {
            camera: f.camera,
            photo: Some(p),
        })
        .collect();
    let masks = session.box_masks(&views, &boxes, None, &Default::default(), |_| {})?;
    let pairs = masks
        .into_iter()
        .zip(&test)
        .map(|(m, f)| Ok((m, ids_of(f)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let iou = assist_session::split::iou_per_id(&pairs, &[id])[0].1;
    Ok(format!(
        "a click on the {label} at ({:.0}, {:.0}) of {}: box centre {}, size {}; its mask on the {} test views: IoU {iou:.3}",
        at.0,
        at.1,
        frame.name,
        crate::cmd_dataset_masks::vec3(obb.center),
        crate::cmd_dataset_masks::vec3(obb.size()),
        test.len()
    ))
}

/// Renders two test views before and after the edit into `out/render/` and writes the
/// contact sheet: per view the photograph, then render (with its PSNR in `r`), depth and
/// panoptic ids before the edit and after it.
fn contact_sheet_of(
    ds: &assist_data::Dataset,
    r: &assist_session::EvalReport,
    before: &Session,
    session: &Session,
    out: &std::path::Path,
) -> anyhow::Result<std::path::PathBuf> {
    let test: Vec<usize> = (0..ds.frames.len())
        .filter(|&i| ds.frames[i].split == Split::Test)
        .collect();
    let picks_at = [test[0], test[test.len() / 2]];
    let picks: Vec<NamedCamera> = picks_at
        .iter()
        .map(|&i| NamedCamera {
            name: ds.frames[i].name.clone(),
            camera: ds.frames[i].camera,
        })
        .collect();
    // Each row of the sheet: one view's photograph (the generator's ground truth), then
    // the trained scene's render, depth and panoptic before the edit and after it.
    let mut tiles: Vec<Vec<(ImageF32, String)>> = Vec::new();
    for &i in &picks_at {
        let f = &ds.frames[i];
        let v = assist_session::photograph(f, before.description().background_color)?;
        let psnr = r
            .per_image
            .iter()
            .find(|s| s.name == f.name)
            .map(|s| format!(" {:.1} dB", s.psnr))
            .unwrap_or_default();
        let truth = ImageF32 {
            width: v.width as u32,
            height: v.height as u32,
            channels: 3,
            data: v.rgb,
        };
        tiles.push(vec![
            (truth, format!("truth {}", f.name)),
            (ImageF32::new(1, 1, 3), psnr),
        ]);
    }
    for (tag, s) in [("before", &before), ("after", &session)] {
        let job = DatasetOutput {
            out: out.join("render").join(tag),
            outputs: OUTPUTS.to_vec(),
            highlight: Highlight::None,
            force: true,
            quality: Default::default(),
        };
        s.write_dataset(&picks, &job, |v| {
            let (f, (w, h)) = (v.frame, (v.frame.width, v.frame.height));
            let row = &mut tiles[v.index];
            let rgb = ImageF32 {
                width: w,
                height: h,
                channels: 3,
                data: f.rgb.clone(),
            };
            if tag == "before" {
                // The placeholder after the truth carries the view's PSNR.
                let psnr = row.pop().map(|(_, p)| p).unwrap_or_default();
                row.push((rgb, format!("render{psnr}")));
            } else {
                row.push((rgb, "after the edit".into()));
            }
            row.push((depth_image(w, h, &f.depth), format!("{tag}: depth")));
            row.push((ids_image(w, h, &f.panoptic), format!("{tag}: panoptic")));
        })?;
    }
    let tiles: Vec<ImageF32> = tiles
        .concat()
        .iter()
        .map(|(t, label)| captioned(&upscale(t, 2), label, 1))
        .collect();
    let sheet = out.join("contact_sheet.png");
    write_rgb_png(&sheet, &contact_sheet(&tiles, 7))?;
    Ok(sheet)
}
