//! `assist bench merge`: `assist generate merge` on a run split into many shards — its time
//! and its peak memory, so that a merge of a thousand shards is seen to stream. The run is
//! made once in this process (the generator prepared once, then every shard `i/n` written
//! as `assist generate --shard i/n` writes it); each merge runs as its own process.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use assist_generate::{CocoMasks, Generator, RunOptions, Shard, Spec};

#[derive(clap::Args, Debug)]
pub struct MergeBenchArgs {
    /// The generation spec (as `assist generate --spec`).
    #[arg(long)]
    pub spec: PathBuf,
    /// The run's folder: made here unless it already holds this run, complete.
    #[arg(long)]
    pub out: PathBuf,
    /// Samples in the run (overrides the spec's `count`).
    #[arg(long)]
    pub count: Option<u64>,
    /// Shards the run is split into.
    #[arg(long, default_value_t = 1000)]
    pub shards: u64,
    /// Merges timed.
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Print the figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// A child's peak resident memory (VmHWM) in bytes, read from /proc until it exits.
fn run_measured(cmd: &mut std::process::Command) -> anyhow::Result<(f64, u64)> {
    let t0 = Instant::now();
    let mut child = cmd.spawn().context("starting the merge")?;
    let status_file = format!("/proc/{}/status", child.id());
    let mut peak = 0u64;
    loop {
        if let Ok(s) = std::fs::read_to_string(&status_file)
            && let Some(kb) = s
                .lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        {
            peak = peak.max(kb * 1024);
        }
        if let Some(st) = child.try_wait()? {
            anyhow::ensure!(st.success(), "the merge failed ({st})");
            return Ok((t0.elapsed().as_secs_f64(), peak));
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
}

pub fn run(a: MergeBenchArgs) -> anyhow::Result<()> {
    let mut spec = Spec::load(&a.spec)?;
    if let Some(c) = a.count {
        spec.count = c;
    }
    spec.check(&a.spec)?;
    anyhow::ensure!(a.shards >= 1, "--shards: expected at least 1");
    let n = a.shards;
    let complete = assist_generate::status(&a.out, Some(n), false)
        .map(|s| s.all_complete)
        .unwrap_or(false);
    let mut made_s = 0.0;
    if !complete {
        let t0 = Instant::now();
        let g = Generator::prepare(spec.clone(), &mut ()).context("preparing the run")?;
        for i in 0..n {
            let opts = RunOptions {
                out: a.out.clone(),
                shard: Shard { index: i, count: n },
                dry_run: false,
                force: false,
                coco_masks: CocoMasks::Polygon,
            };
            g.run(&opts, |_| {})?;
            if !a.json && (i + 1) % 100 == 0 {
                eprintln!("{} of {n} shards made", i + 1);
            }
        }
        made_s = t0.elapsed().as_secs_f64();
    }
    let exe = std::env::current_exe()?;
    let (mut times, mut peaks) = (Vec::new(), Vec::new());
    for _ in 0..a.runs.max(1) {
        let (t, m) = run_measured(
            std::process::Command::new(&exe)
                .args(["generate", "merge"])
                .arg(&a.out)
                .stderr(std::process::Stdio::null()),
        )?;
        times.push(t);
        peaks.push(m as f64);
    }
    let index: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.out.join("index.json"))?)?;
    let images = std::fs::read_to_string(a.out.join("annotations/instances.json"))
        .map(|t| t.matches("\"file_name\"").count())
        .unwrap_or(0);
    let r = serde_json::json!({
        "shards": n,
        "samples": index["count"],
        "images": images,
        "made_seconds": made_s,
        "merge_seconds_median": crate::cmd_bench::median_of(times.clone()),
        "merge_seconds": times,
        "merge_peak_rss_mb_median": crate::cmd_bench::median_of(peaks.clone()) / 1048576.0,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "merge of {n} shards ({} samples, {images} images): {:.2} s, peak memory {:.1} MB (medians of {}; VmHWM read every 2 ms)",
            r["samples"],
            r["merge_seconds_median"].as_f64().unwrap_or(0.0),
            r["merge_peak_rss_mb_median"].as_f64().unwrap_or(0.0),
            a.runs.max(1)
        );
    }
    Ok(())
}
