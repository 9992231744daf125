//! `assist bench sam [--checkpoint FILE]`: how long Segment Anything takes on this
//! machine — loading, embedding a photograph (the ViT encoder), one prompt's masks —
//! medians over runs. Without `--checkpoint` the model is a random SAM ViT-B written to a
//! temporary folder: the real architecture and size, so the times are a real model's.

use std::path::PathBuf;
use std::time::Instant;

use assist_sam::random::{RandomSpec, write_random};
use assist_sam::{Prompt, Sam};
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct SamBenchArgs {
    /// SAM weights (.pth or .safetensors) [default: a random ViT-B].
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// The photograph's size (a synthetic one), "WxH".
    #[arg(long, default_value = "1008x756")]
    pub size: String,
    /// Attention scores computed at once (floats; the encoder's default is 16 M): larger
    /// computes more heads at once, for comparing.
    #[arg(long)]
    pub scores_per_chunk: Option<usize>,
    /// Timed runs of each stage (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

use crate::cmd_bench::median_of as median;

pub fn run(a: SamBenchArgs) -> anyhow::Result<()> {
    let (w, h) = a
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<usize>().ok()?, h.parse::<usize>().ok()?)))
        .filter(|&(w, h)| w > 0 && h > 0)
        .ok_or_else(|| anyhow::anyhow!("--size: expected WxH, e.g. 1008x756, got {:?}", a.size))?;
    let runs = a.runs.max(1);
    let tmp = tempfile::tempdir()?;
    let (path, model) = match &a.checkpoint {
        Some(p) => (p.clone(), "given".to_string()),
        None => {
            let p = tmp.path().join("sam-vit-b-random.safetensors");
            write_random(&p, &RandomSpec::vit_b(), 1)?;
            (p, "random ViT-B".to_string())
        }
    };
    let t = Instant::now();
    let mut sam = Sam::load(&path)?;
    let load = t.elapsed().as_secs_f64();
    if let Some(n) = a.scores_per_chunk {
        sam.encoder.scores_per_chunk = n.max(1);
    }
    let rgb: Vec<f32> = (0..w * h)
        .flat_map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            [x, y, 0.5 * (x + y)]
        })
        .collect();
    let mut embed = Vec::new();
    let mut emb = None;
    for _ in 0..runs {
        let t = Instant::now();
        emb = Some(sam.embed(&rgb, w, h)?);
        embed.push(t.elapsed().as_secs_f64());
    }
    let emb = emb.expect("at least one run");
    let prompt = Prompt {
        points: vec![([w as f32 / 2.0, h as f32 / 2.0], 1)],
        bbox: Some([
            w as f32 * 0.3,
            h as f32 * 0.3,
            w as f32 * 0.7,
            h as f32 * 0.7,
        ]),
    };
    let mut predict = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        sam.segment(&emb, &prompt, |_, iou| iou as f64)?;
        predict.push(t.elapsed().as_secs_f64());
    }
    let out = json!({
        "model": model,
        "checkpoint": path,
        "image": [w, h],
        "encoder": {"img_size": sam.encoder.img_size, "dim": sam.encoder.dim},
        "load_seconds": load,
        "embed_seconds": median(embed),
        "masks_seconds": median(predict),
        "runs": runs,
        "scores_per_chunk": sam.encoder.scores_per_chunk,
        "threads": rayon_threads(),
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "SAM ({model}, input {}, width {}): load {:.1} s, embed a {w}×{h} photograph {:.2} s, one prompt's masks at full size {:.3} s (medians of {runs})",
            sam.encoder.img_size,
            sam.encoder.dim,
            load,
            out["embed_seconds"].as_f64().unwrap_or(0.0),
            out["masks_seconds"].as_f64().unwrap_or(0.0),
        );
    }
    Ok(())
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
