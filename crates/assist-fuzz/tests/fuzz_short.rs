//! CI's short fuzzing run: every target for a fixed count with 0 panics, no input slower
//! than the limit, and no allocation above the limit (the allocator aborts on one). The
//! long runs (10⁶ executions per target) are `assist-fuzz --runs 1000000`; their counts
//! are in RELIABILITY.md.

use std::time::Duration;

#[test]
fn every_parser_survives_mutated_real_inputs() {
    // The real seeds come from the shared data; without it the built-in seeds still run.
    let _ = assist_testkit::shared_data("fuzz_short");
    let out = assist_testkit::TempDir(assist_fuzz::scratch_base());
    let targets = assist_fuzz::targets::all();
    let names: Vec<&str> = targets.iter().map(|t| t.name).collect();
    for want in [
        "nerfstudio",
        "blender",
        "colmap-text",
        "llff-npy",
        "scene-json",
        "history-json",
        "field-safetensors",
        "actions-jsonl",
        "instruction",
        "boxes-json",
        "viewer-message",
    ] {
        assert!(names.contains(&want), "target {want} missing: {names:?}");
    }
    for t in &targets {
        let r = assist_fuzz::fuzz(t, 10_000, 7, Duration::from_secs(10), out.path());
        eprintln!(
            "{}: {} executions, {} panics, slowest {:?}, largest allocation {} bytes",
            r.target, r.executions, r.panics, r.slowest, r.largest_allocation
        );
        assert_eq!(r.panics, 0, "{}: {:?}", r.target, r.first_panic);
        assert!(r.largest_allocation < assist_fuzz::ALLOCATION_LIMIT);
    }
}

#[test]
fn the_mutator_changes_inputs_and_is_deterministic() {
    let seed = br#"{"a": [1, 2.5, -3e2], "b": "x"}"#.to_vec();
    let mut a = assist_fuzz::Rng::new(3);
    let mut b = assist_fuzz::Rng::new(3);
    let mut changed = 0;
    for _ in 0..200 {
        let x = assist_fuzz::mutate(&mut a, &seed, std::slice::from_ref(&seed));
        let y = assist_fuzz::mutate(&mut b, &seed, std::slice::from_ref(&seed));
        assert_eq!(x, y);
        changed += (x != seed) as usize;
    }
    assert!(
        changed > 150,
        "only {changed} of 200 mutations changed the input"
    );
}

#[test]
fn a_panicking_parser_is_caught_and_its_input_saved() {
    let out = assist_testkit::TempDir::new("fuzz-panic");
    let t = assist_fuzz::Target {
        name: "always-panics-on-x",
        seeds: vec![b"abc".to_vec()],
        run: Box::new(|b, _| {
            if b.contains(&b'x') || b.is_empty() {
                panic!("found it");
            }
        }),
    };
    let r = assist_fuzz::fuzz(&t, 5_000, 1, Duration::from_secs(10), out.path());
    assert!(r.panics > 0);
    let (path, msg) = r.first_panic.unwrap();
    assert_eq!(msg, "found it");
    let saved = std::fs::read(path).unwrap();
    assert!(saved.contains(&b'x') || saved.is_empty());
}
