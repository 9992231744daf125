//! `assist embed SCENE [--data DATA] [--clip DIR]`: each node's CLIP embedding (the paper's
//! fourth scene-node field) from the training views, stored in the scene, so that
//! instructions find objects by what they are ("the thing you drink from"), not only by
//! the words of their labels. Crops and masking: docs/embeddings.md.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use assist_session::clip::Clip;
use assist_session::{DEFAULT_EMBED_VIEWS, EmbedEvent, EmbedJob, EmbedSummary, Session};
use clap::Args;

#[derive(Args, Debug)]
pub struct EmbedArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    /// The capture the scene was trained on [default: the dataset its training recorded].
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// CLIP weights: a folder with the model as safetensors (open_clip's or Hugging
    /// Face's naming), its BPE vocabulary (bpe_simple_vocab_16e6.txt.gz or merges.txt) and
    /// open_clip_config.json or config.json [default: $ASSIST_CLIP].
    #[arg(long)]
    pub clip: Option<PathBuf>,
    /// Views (crops) per node at most, spread over the capture.
    #[arg(long, default_value_t = DEFAULT_EMBED_VIEWS)]
    pub views: usize,
    /// Read the images this many times smaller [default: as the scene was trained].
    #[arg(long)]
    pub downscale: Option<u32>,
    /// Save the embedded scene here instead of in place.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace embeddings the scene already has (and an existing --out scene).
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

/// The CLIP model of `--clip` or `ASSIST_CLIP`, or an error saying what to provide.
pub fn load_clip(flag: Option<&Path>) -> anyhow::Result<Arc<Clip>> {
    let clip = match flag {
        Some(p) => Clip::load(p),
        None => Clip::from_env().ok_or_else(|| {
            anyhow::anyhow!(
                "no CLIP weights: pass --clip DIR or set {}=DIR, DIR holding the model as safetensors (open_clip or Hugging Face naming), its BPE vocabulary (bpe_simple_vocab_16e6.txt.gz or merges.txt) and open_clip_config.json or config.json",
                assist_session::clip::ENV
            )
        })?,
    };
    Ok(Arc::new(clip.context("loading the CLIP model")?))
}

/// Embeds `session` and prints what was done (not in `--json` mode).
pub fn embed_session(
    session: &mut Session,
    clip: &Clip,
    job: &EmbedJob,
    quiet: bool,
) -> anyhow::Result<EmbedSummary> {
    let bar = crate::progress::bar(std::io::stderr().is_terminal() && !quiet, "embed");
    let summary = session.embed(clip, job, &mut |ev| match ev {
        EmbedEvent::Reading { views } => {
            if !quiet {
                bar.suspend(|| eprintln!("reading {views} training views"));
            }
        }
        EmbedEvent::Node {
            done,
            of,
            id,
            crops,
        } => {
            bar.set_length(of as u64);
            bar.set_position(done as u64);
            if !quiet {
                bar.suspend(|| eprintln!("node {id}: {crops} crop(s)"));
            }
        }
    })?;
    bar.finish_and_clear();
    Ok(summary)
}

pub fn run(a: EmbedArgs) -> anyhow::Result<()> {
    // The request's own values first: a bad flag is not a missing model.
    if a.views == 0 {
        anyhow::bail!("--views: expected at least 1 view per node");
    }
    if let Some(out) = &a.out {
        assist_fs::check_replaceable_as(out, a.force, assist_fs::Kind::Scene)?;
    }
    let clip = load_clip(a.clip.as_deref())?;
    let mut session =
        Session::open(&a.scene).with_context(|| format!("loading scene {}", a.scene.display()))?;
    let data = match &a.data {
        Some(d) => d.clone(),
        None => assist_session::recorded_dataset(&a.scene, session.info())?.ok_or_else(|| {
            anyhow::anyhow!(
                "{}: the scene does not record its dataset; pass --data",
                a.scene.display()
            )
        })?,
    };
    let downscale = a.downscale.unwrap_or_else(|| {
        session
            .info()
            .pointer("/options/downscale")
            .and_then(|v| v.as_u64())
            .unwrap_or(1) as u32
    });
    if downscale == 0 {
        anyhow::bail!("--downscale: expected 1 or more");
    }
    let mut job = EmbedJob::new(data);
    job.views = a.views;
    job.replace = a.force;
    job.load.downscale = downscale;
    let summary = embed_session(&mut session, &clip, &job, a.json)?;
    let (path, force) = match &a.out {
        Some(o) => (o.clone(), a.force),
        None => (a.scene.clone(), true),
    };
    session
        .save(&path, force)
        .with_context(|| format!("saving {}", path.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        for n in &summary.nodes {
            if n.crops == 0 {
                eprintln!(
                    "node {} {:?}: seen in no training view, not embedded",
                    n.id, n.label
                );
            } else {
                eprintln!(
                    "node {} {:?}: {} crop(s), agreement {:.2}",
                    n.id, n.label, n.crops, n.agreement
                );
            }
        }
        if !summary.shared.is_empty() {
            eprintln!("copies sharing an embedding: {:?}", summary.shared);
        }
        eprintln!(
            "embedded {} node(s) from {} crops with {} ({}-d) in {:.1} s; saved {}",
            summary.nodes.iter().filter(|n| n.crops > 0).count(),
            summary.crops,
            summary.model,
            summary.dim,
            summary.seconds,
            path.display()
        );
    }
    Ok(())
}
