//! `assist bench view SCENE`: what the viewer's latency is made of, as medians — a preview
//! frame, a full frame, a drag update with the drag cache (and without it), each rendered
//! and JPEG-encoded as the viewer sends it; and preview frames per second with several
//! clients rendering at once.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use assist_core::{Action, ActionConfig, AxisSpec, Camera, Operation};
use assist_session::{CameraSource, DragCache, RenderRequest, Session, Steps};
use assist_viewer::{PREVIEW_DIVISOR, encode_jpeg};
use clap::Args;

#[derive(Args, Debug)]
pub struct ViewBenchArgs {
    /// Trained scene (NAME.assist).
    pub scene: PathBuf,
    /// Dataset whose first training camera is the view (default: an orbit camera).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Full frame width, pixels, as the viewer renders it.
    #[arg(long, default_value_t = 480)]
    pub width: u32,
    /// Full frame height, pixels.
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Frames timed per measure (the median is reported).
    #[arg(long, default_value_t = 20)]
    pub frames: usize,
    /// One JSON object: preview_ms, full_ms, drag_ms, drag_first_ms, clients (frames/s).
    #[arg(long)]
    pub json: bool,
    /// Where the viewer's renders query the fields.
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

use crate::cmd_bench::median_of as median;

/// Milliseconds of a render plus its JPEG.
fn timed(f: impl FnOnce() -> anyhow::Result<assist_session::Frame>) -> anyhow::Result<f64> {
    let t = Instant::now();
    let frame = f()?;
    let _ = encode_jpeg(&frame.rgb, frame.width, frame.height);
    Ok(t.elapsed().as_secs_f64() * 1e3)
}

pub fn run(a: ViewBenchArgs) -> anyhow::Result<()> {
    if a.frames < 3 {
        bail!("--frames: expected at least 3, got {}", a.frames);
    }
    let device = a.device.open()?;
    let mut s = Session::open(&a.scene)?;
    s.set_backend(device.field_backend());
    let cams = CameraSource::train_or_orbit(a.data.as_deref()).cameras(s.description())?;
    let cam: Camera = cams.first().context("no camera to view from")?.camera;
    let full = Some((a.width, a.height));
    let preview = Some((
        (a.width / PREVIEW_DIVISOR).max(1),
        (a.height / PREVIEW_DIVISOR).max(1),
    ));
    let req = |size| RenderRequest {
        size,
        highlight: true,
        ..RenderRequest::default()
    };
    let say = |m: String| {
        if !a.json {
            eprintln!("{m}");
        }
    };
    // The object to drag: the largest (by box volume).
    let moving = s
        .nodes()
        .iter()
        .filter(|n| !n.is_background())
        .max_by(|x, y| {
            let v = |n: &assist_core::SceneNode| {
                (n.half_size * n.world_from_local.scale).element_product()
            };
            v(x).total_cmp(&v(y))
        })
        .map(|n| n.id)
        .context("the scene has no object to drag")?;
    s.select(Some(moving))?;

    let mut previews = Vec::new();
    for _ in 0..a.frames {
        previews.push(timed(|| Ok(s.render(&cam, &req(preview))?))?);
    }
    let preview_ms = median(previews);
    say(format!(
        "preview {}×{}: {preview_ms:.1} ms",
        a.width / PREVIEW_DIVISOR,
        a.height / PREVIEW_DIVISOR
    ));
    let mut fulls = Vec::new();
    for _ in 0..a.frames {
        fulls.push(timed(|| Ok(s.render(&cam, &req(full))?))?);
    }
    let full_ms = median(fulls);
    say(format!("full {}×{}: {full_ms:.1} ms", a.width, a.height));

    // A drag: 1 cm steps along x, each a preview edit replacing the last (as the viewer does).
    let step = |s: &mut Session, k: usize| -> anyhow::Result<()> {
        if k > 0 {
            s.undo();
        }
        let config = ActionConfig {
            axis: Some(AxisSpec::Name("x".into())),
            distance: Some(0.01 * (k + 1) as f64),
            unit: Some("m".into()),
            ..ActionConfig::default()
        };
        s.apply_with(
            &[Action::new(moving, Operation::Translate, config)],
            Steps::One,
        )?;
        Ok(())
    };
    let mut cache = DragCache::default();
    let warm = timed(|| Ok(s.render_moving(&cam, &req(full), moving, &mut cache)?))?;
    let mut drags = Vec::new();
    for k in 0..a.frames {
        step(&mut s, k)?;
        drags.push(timed(|| {
            Ok(s.render_moving(&cam, &req(full), moving, &mut cache)?)
        })?);
    }
    let drag_ms = median(drags);
    say(format!(
        "drag update (cached, after a {warm:.0} ms first frame): {drag_ms:.1} ms"
    ));
    s.undo();

    // Several clients: each its own session on its own thread, previews as fast as it can.
    let mut clients_fps = Vec::new();
    for clients in [1usize, 2, 4] {
        let t = Instant::now();
        let per = a.frames;
        std::thread::scope(|sc| -> anyhow::Result<()> {
            let handles: Vec<_> = (0..clients)
                .map(|_| {
                    sc.spawn(|| -> anyhow::Result<()> {
                        let mut s = Session::open(&a.scene)?;
                        s.set_backend(device.field_backend());
                        for _ in 0..per {
                            let f = s.render(&cam, &req(preview))?;
                            let _ = encode_jpeg(&f.rgb, f.width, f.height);
                        }
                        Ok(())
                    })
                })
                .collect();
            for h in handles {
                h.join()
                    .map_err(|_| anyhow::anyhow!("a client thread panicked"))??;
            }
            Ok(())
        })?;
        let fps = (clients * per) as f64 / t.elapsed().as_secs_f64();
        say(format!(
            "{clients} client(s): {fps:.1} preview frames/s in all"
        ));
        clients_fps.push(serde_json::json!({"clients": clients, "frames_per_sec": fps}));
    }
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "scene": a.scene.display().to_string(),
                "width": a.width, "height": a.height, "frames": a.frames,
                "preview_width": a.width / PREVIEW_DIVISOR, "preview_height": a.height / PREVIEW_DIVISOR,
                "preview_ms": preview_ms,
                "full_ms": full_ms,
                "drag_ms": drag_ms,
                "drag_first_ms": warm,
                "drag_node": moving,
                "clients": clients_fps,
                "threads": rayon::current_num_threads(),
                "device": device.name(),
            })
        );
    }
    Ok(())
}
