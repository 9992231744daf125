//! Issue 47, item 15: `merge` trusted whatever was in the folder — a sample copied from a
//! run with another seed, an image deleted or emptied — and a rerun skipped the damaged
//! sample; a killed merge's temporary stayed. Each sample now carries a manifest of its
//! run and files, checked before it is indexed or skipped.

use std::path::Path;

use assist_generate::integrity::{MANIFEST, check, run_identity, write_manifest};
use assist_generate::merge;
use serde_json::json;

/// A run folder with one hand-made sample (no views), as `generate` lays it out.
fn run_folder(out: &Path, seed: u64) -> serde_json::Value {
    let manifest = json!({
        "format": "assist-generate",
        "version": 1,
        "spec": {"count": 1, "seed": seed},
        "classes": ["background"],
    });
    std::fs::create_dir_all(out).unwrap();
    std::fs::write(out.join("generate.json"), manifest.to_string()).unwrap();
    std::fs::write(out.join(assist_fs::MARKER), "written by assist generate\n").unwrap();
    let dir = out.join("samples/000000");
    std::fs::create_dir_all(dir.join("views/images")).unwrap();
    std::fs::write(dir.join("sample.json"), r#"{"views": [], "objects": []}"#).unwrap();
    std::fs::write(dir.join("views/images/a.png"), b"not really a png").unwrap();
    write_manifest(&dir, &run_identity(&manifest)).unwrap();
    std::fs::write(dir.join(assist_fs::MARKER), "written by assist\n").unwrap();
    manifest
}

#[test]
fn merge_refuses_samples_that_do_not_hold() {
    let tmp = assist_testkit::TempDir::new("gen-integrity");
    let out = tmp.join("g");
    let manifest = run_folder(&out, 0);
    let run = run_identity(&manifest);
    let dir = out.join("samples/000000");
    // As made: merged, and a killed merge's temporary is removed.
    std::fs::write(out.join(".index.json.tmp-4000000"), "half").unwrap();
    assert_eq!(merge(&out, false, Default::default()).unwrap().samples, 1);
    assert!(!out.join(".index.json.tmp-4000000").exists());
    assert!(check(&dir, &run, true).is_ok());

    // An image emptied, then deleted: refused, naming the sample and the file.
    let img = dir.join("views/images/a.png");
    std::fs::write(&img, b"").unwrap();
    let e = merge(&out, false, Default::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("sample 000000") && e.contains("views/images/a.png"),
        "{e}"
    );
    assert!(check(&dir, &run, false).is_err(), "a rerun must remake it");
    std::fs::remove_file(&img).unwrap();
    let e = merge(&out, false, Default::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("is missing"), "{e}");
    // Same size, other bytes: found by the hash.
    std::fs::write(&img, b"not really a pnG").unwrap();
    let e = merge(&out, false, Default::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("changed since it was made"), "{e}");

    // A sample copied in from a run with another seed.
    let other = tmp.join("h");
    run_folder(&other, 99);
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::rename(other.join("samples/000000"), &dir).unwrap();
    let e = merge(&out, false, Default::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("another run"), "{e}");
    // Without a manifest (an older assist, or not finished): refused too.
    std::fs::remove_file(dir.join(MANIFEST)).unwrap();
    let e = merge(&out, false, Default::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains(MANIFEST), "{e}");
}
