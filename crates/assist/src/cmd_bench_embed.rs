//! `assist bench embed SCENE [--data DATA] [--clip DIR]`: how long embedding a scene's
//! nodes takes (model load, reading the views, the CLIP crops) and how long resolving an
//! object phrase by meaning takes (text encoder + cosine match), medians over runs.
//! Without `--clip` the model is a randomly initialised ViT-B/32 written to a temporary
//! folder: the real architecture and size, so the times are a real model's.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use assist_session::clip::Clip;
use assist_session::clip::random::{RandomSpec, write_model};
use assist_session::{EmbedJob, Session};
use clap::Args;
use serde_json::json;

#[derive(Args, Debug)]
pub struct EmbedBenchArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    /// The capture it was trained on [default: the dataset its training recorded].
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// CLIP weights [default: a random ViT-B/32 in a temporary folder].
    #[arg(long)]
    pub clip: Option<PathBuf>,
    /// Views per node.
    #[arg(long, default_value_t = assist_session::DEFAULT_EMBED_VIEWS)]
    pub views: usize,
    /// Embedding runs (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Instructions whose object no label word matches, so each is resolved by meaning.
const PHRASES: &[&str] = &[
    "move the drinking vessel left 5 cm",
    "delete the bathtub floater",
    "rotate the thing you brew tea in by 90 degrees",
    "move the porcelain vessel up 2 cm",
    "scale the squeaky companion by 2",
];

use crate::cmd_bench::median_of as median;

pub fn run(a: EmbedBenchArgs) -> anyhow::Result<()> {
    let tmp;
    let (dir, model) = match &a.clip {
        Some(d) => (d.clone(), "given".to_string()),
        None => {
            tmp = tempfile::tempdir()?;
            let t = Instant::now();
            write_model(tmp.path(), &RandomSpec::vit_b_32(), 1)?;
            eprintln!(
                "wrote a random ViT-B/32 in {:.1} s",
                t.elapsed().as_secs_f64()
            );
            (tmp.path().to_path_buf(), "random ViT-B/32".to_string())
        }
    };
    let t = Instant::now();
    let clip = std::sync::Arc::new(Clip::load(&dir)?);
    let load_s = t.elapsed().as_secs_f64();
    let base =
        Session::open(&a.scene).with_context(|| format!("loading scene {}", a.scene.display()))?;
    let data = match &a.data {
        Some(d) => d.clone(),
        None => PathBuf::from(
            base.info()
                .get("dataset")
                .and_then(|v| v.as_str())
                .context("the scene does not record its dataset; pass --data")?,
        ),
    };
    let mut job = EmbedJob::new(data);
    job.views = a.views;
    job.replace = true;
    let mut times = Vec::new();
    let mut summary = None;
    for _ in 0..a.runs.max(1) {
        let mut s = base.fork();
        let t = Instant::now();
        let sum = s.embed(&clip, &job, &mut |_| {})?;
        times.push(t.elapsed().as_secs_f64());
        summary = Some((sum, s));
    }
    let (sum, mut session) = summary.expect("one run");
    session.set_clip(clip.clone());
    let mut lat = Vec::new();
    let mut outcomes = Vec::new();
    for _ in 0..3 {
        for p in PHRASES {
            let t = Instant::now();
            let r = session.resolve(p, None);
            lat.push(t.elapsed().as_secs_f64() * 1e3);
            outcomes.push(match r {
                Ok(r) => format!("{p}: object {}", r.actions[0].instance_id),
                Err(e) => format!("{p}: {e}"),
            });
        }
    }
    let v = json!({
        "model": model,
        "load_s": load_s,
        "embed_s_median": median(times.clone()),
        "embed_s": times,
        "nodes": sum.nodes.iter().filter(|n| n.crops > 0).count(),
        "crops": sum.crops,
        "phrase_ms_median": median(lat.clone()),
        "phrase_ms_max": lat.iter().cloned().fold(0.0, f64::max),
        "phrases": PHRASES.len(),
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        for o in outcomes.iter().take(PHRASES.len()) {
            eprintln!("  {o}");
        }
        println!(
            "{model}: load {:.2} s; embed {} nodes from {} crops: median {:.2} s over {} run(s); resolve a phrase by meaning: median {:.1} ms (max {:.1}) over {} phrases",
            load_s,
            v["nodes"],
            sum.crops,
            v["embed_s_median"].as_f64().unwrap_or(0.0),
            a.runs.max(1),
            v["phrase_ms_median"].as_f64().unwrap_or(0.0),
            v["phrase_ms_max"].as_f64().unwrap_or(0.0),
            lat.len()
        );
    }
    Ok(())
}
