//! `assist-fuzz [TARGET…] [--runs N] [--seed S] [--limit-ms MS] [--out DIR]`: fuzzes the
//! named targets (all by default) and prints one line per target; exits 1 on any panic.

use std::time::Duration;

fn main() {
    let mut runs: u64 = 1_000_000;
    let mut seed: u64 = 1;
    let mut limit_ms: u64 = 5_000;
    let mut out = assist_fuzz::scratch_base();
    let mut names: Vec<String> = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = |flag: &str| {
            args.next()
                .unwrap_or_else(|| panic!("{flag} needs a value"))
        };
        match a.as_str() {
            "--runs" => runs = val("--runs").parse().expect("--runs: a count"),
            "--seed" => seed = val("--seed").parse().expect("--seed: a number"),
            "--limit-ms" => limit_ms = val("--limit-ms").parse().expect("--limit-ms: ms"),
            "--out" => out = val("--out").into(),
            "--list" => {
                for t in assist_fuzz::targets::all() {
                    println!("{}", t.name);
                }
                return;
            }
            other => names.push(other.to_string()),
        }
    }
    let mut failed = false;
    for t in assist_fuzz::targets::all() {
        if !names.is_empty() && !names.iter().any(|n| n == t.name) {
            continue;
        }
        let r = assist_fuzz::fuzz(&t, runs, seed, Duration::from_millis(limit_ms), &out);
        println!(
            "{:<20} {:>9} executions in {:>7.1} s, {} panics, slowest {:.1} ms, largest allocation {:.0} KiB{}",
            r.target,
            r.executions,
            r.seconds,
            r.panics,
            r.slowest.as_secs_f64() * 1e3,
            r.largest_allocation as f64 / 1024.0,
            match &r.first_panic {
                Some((p, m)) => format!("; first panic: {m} (input {})", p.display()),
                None => String::new(),
            }
        );
        failed |= r.panics > 0;
    }
    if failed {
        eprintln!("failing inputs kept in {}", out.display());
        std::process::exit(1);
    }
    let _ = std::fs::remove_dir_all(&out);
}
