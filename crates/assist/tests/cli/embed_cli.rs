//! Scene-node embeddings as a user meets them: `assist train --clip` and `assist embed`
//! with randomly initialised CLIP checkpoints (their embeddings mean nothing, so what is
//! checked is the plumbing: every node embedded from its own crops, stored, kept through
//! replicate and cross-scene add, shown by `scene info`, used to resolve phrases by
//! meaning — a pick or a "too close to call" with scores, never a guess — and clear
//! errors without weights or with broken ones).

use crate::common;

use std::path::Path;

use crate::common::{bin, ok, refused, run, s};
use assist_session::clip::random::{RandomSpec, write_model};

fn scene_json(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("scene.json")).unwrap()).unwrap()
}

fn embeddings(dir: &Path) -> Vec<(u64, Option<Vec<f64>>)> {
    scene_json(dir)["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["id"].as_u64().unwrap(),
                serde_json::from_value(n["embedding"].clone()).unwrap(),
            )
        })
        .collect()
}

/// `assist edit SCENE --do TEXT --out OUT` with `ASSIST_CLIP` as given.
fn edit(scene: &Path, text: &str, out: &Path, clip: Option<&Path>) -> std::process::Output {
    let mut c = bin();
    c.args(["edit", s(scene), "--do", text, "--out", s(out)]);
    match clip {
        Some(p) => c.env("ASSIST_CLIP", p),
        None => c.env_remove("ASSIST_CLIP"),
    };
    c.output().unwrap()
}

#[test]
fn train_embed_edit_and_resolve_by_meaning() {
    let tmp = assist_testkit::TempDir::new("embed-cli");
    let root = tmp.path().to_path_buf();
    let clip = root.join("clip");
    write_model(&clip, &RandomSpec::tiny(), 5).unwrap();
    let cap = root.join("cap");
    ok(&run(&[
        "synth",
        "--out",
        s(&cap),
        "--views",
        "12",
        "--size",
        "96x72",
        "--objects",
        "3",
    ]));
    let a = root.join("a.assist");
    // Training with --clip embeds every node at the end.
    let err = ok(&bin()
        .args([
            "train",
            s(&cap),
            "--out",
            s(&a),
            "--iters",
            "20",
            "--clip",
            s(&clip),
        ])
        .env_remove("ASSIST_CLIP")
        .output()
        .unwrap());
    assert!(err.contains("embedded 4 node(s)"), "{err}");
    let e = embeddings(&a);
    assert_eq!(e.len(), 4);
    for (id, v) in &e {
        let v = v
            .as_ref()
            .unwrap_or_else(|| panic!("node {id} has no embedding"));
        assert_eq!(v.len(), 32);
        let n: f64 = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((n - 1.0).abs() < 1e-4, "node {id}: |e| = {n}");
    }
    // Each node's own crops: no two objects share an embedding.
    for i in 1..e.len() {
        for j in i + 1..e.len() {
            assert_ne!(e[i].1, e[j].1, "nodes {} and {}", e[i].0, e[j].0);
        }
    }
    // --json reports the embedding with the training.
    let a2 = root.join("a2.assist");
    let o = bin()
        .args([
            "train",
            s(&cap),
            "--out",
            s(&a2),
            "--iters",
            "3",
            "--clip",
            s(&clip),
            "--json",
        ])
        .env_remove("ASSIST_CLIP")
        .output()
        .unwrap();
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        v["embedding"]["nodes"].as_array().map(Vec::len),
        Some(4),
        "{v}"
    );
    assert_eq!(v["embedding"]["dim"], 32);
    let o = run(&["scene", "info", s(&a)]);
    let info = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        info.contains("embeddings: every node (32-d CLIP)"),
        "{info}"
    );

    // Again: refused without --force (the scene is left as it was), then replaced.
    let before = std::fs::read(a.join("scene.json")).unwrap();
    refused(
        &run(&["embed", s(&a), "--clip", s(&clip)]),
        &["already has an embedding", "--force"],
    );
    assert_eq!(before, std::fs::read(a.join("scene.json")).unwrap());
    let o = run(&[
        "embed",
        s(&a),
        "--clip",
        s(&clip),
        "--force",
        "--json",
        "--views",
        "3",
    ]);
    ok(&o);
    let sum: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let nodes = sum["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 4);
    for n in nodes {
        let crops = n["crops"].as_u64().unwrap();
        assert!((1..=3).contains(&crops), "{n}");
    }
    assert_eq!(sum["dim"], 32);

    // A copy keeps the embedding (replicas share it), and so does a node added from
    // another scene.
    let label = scene_json(&a)["nodes"][1]["label"]
        .as_str()
        .unwrap()
        .to_string();
    let first = e[1].1.clone();
    let b = root.join("b.assist");
    ok(&edit(&a, "duplicate object 1", &b, None));
    let eb = embeddings(&b);
    assert_eq!(eb.len(), 5);
    assert_eq!(eb[4].1, embeddings(&a)[1].1, "the copy of {label}");
    let plain = root.join("plain.assist");
    ok(&run(&[
        "train",
        s(&cap),
        "--out",
        s(&plain),
        "--iters",
        "5",
    ]));
    assert!(embeddings(&plain).iter().all(|e| e.1.is_none()));
    let c = root.join("c.assist");
    ok(&edit(
        &plain,
        &format!("add object 2 from {}", a.display()),
        &c,
        None,
    ));
    let ec = embeddings(&c);
    assert_eq!(ec.last().unwrap().1, embeddings(&a)[2].1);
    assert!(first.is_some());

    // Resolution by meaning: a phrase no label word matches. With weights: a node, or a
    // refusal listing the candidates with their similarities — never "no object".
    let d = root.join("d.assist");
    let o = edit(&a, "move the drinking vessel left 5 cm", &d, Some(&clip));
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!err.contains("panicked"), "{err}");
    if o.status.success() {
        assert!(d.join("scene.json").exists());
    } else {
        // Each candidate with its similarity to three decimals.
        let scored = err
            .split(", ")
            .filter(|c| c.contains("\" ") && c.contains('.'))
            .count();
        assert!(
            err.contains("too close to call by meaning") && scored >= 2,
            "{err}"
        );
    }
    // --clip does what ASSIST_CLIP does.
    let o2 = bin()
        .args([
            "edit",
            s(&a),
            "--do",
            "move the drinking vessel left 5 cm",
            "--dry-run",
        ])
        .args(["--clip", s(&clip)])
        .env_remove("ASSIST_CLIP")
        .output()
        .unwrap();
    assert_eq!(o2.status.success(), o.status.success());
    // Without weights the error says what to provide; without embeddings too.
    refused(
        &edit(&a, "move the drinking vessel left 5 cm", &d, None),
        &["no object called \"drinking vessel\"", "ASSIST_CLIP"],
    );
    refused(
        &edit(
            &plain,
            "move the drinking vessel left 5 cm",
            &d,
            Some(&clip),
        ),
        &["assist embed"],
    );
    // Broken weights: named when the phrase needs them.
    let broken = root.join("broken");
    write_model(&broken, &RandomSpec::tiny(), 6).unwrap();
    let w = broken.join("open_clip_model.safetensors");
    let bytes = std::fs::read(&w).unwrap();
    std::fs::write(&w, &bytes[..bytes.len() / 2]).unwrap();
    refused(
        &edit(&a, "move the drinking vessel left 5 cm", &d, Some(&broken)),
        &["open_clip_model.safetensors", "truncated"],
    );
    // No weights at all for `assist embed`.
    let o = bin()
        .args(["embed", s(&plain)])
        .env_remove("ASSIST_CLIP")
        .output()
        .unwrap();
    refused(&o, &["no CLIP weights", "--clip", "ASSIST_CLIP"]);
    // A bad flag is named before the model is looked for (issue 47 item 18).
    let o = bin()
        .args(["embed", s(&plain), "--views", "0"])
        .env_remove("ASSIST_CLIP")
        .output()
        .unwrap();
    let e = refused(&o, &["--views"]);
    assert!(!e.contains("CLIP"), "{e}");
    refused(
        &run(&["embed", s(&plain), "--clip", s(&broken)]),
        &["open_clip_model.safetensors", "truncated"],
    );
    assert!(embeddings(&plain).iter().all(|e| e.1.is_none()));
}

/// Desk with a ViT-B/32-sized random model: all five objects and the background embedded
/// from their own crops.
#[test]
fn embed_desk_with_a_vit_b_32_sized_model() {
    let Some(desk) =
        assist_testkit::shared_dataset("embed_desk_with_a_vit_b_32_sized_model", "desk")
    else {
        return;
    };
    let tmp = assist_testkit::TempDir::new("embed-desk");
    let root = tmp.path().to_path_buf();
    let clip = root.join("vit-b-32");
    write_model(&clip, &RandomSpec::vit_b_32(), 2).unwrap();
    let scene = root.join("desk.assist");
    common::train_quarter(&desk, &scene, 10, &[]);
    let o = run(&["embed", s(&scene), "--clip", s(&clip), "--json"]);
    ok(&o);
    let sum: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    eprintln!("desk: {sum}");
    assert_eq!(sum["dim"], 512);
    let nodes = sum["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 6, "{sum}");
    for n in nodes {
        assert_eq!(n["crops"], 12, "{n}");
    }
    let e = embeddings(&scene);
    assert!(
        e.iter()
            .all(|(_, v)| v.as_ref().is_some_and(|v| v.len() == 512))
    );
}
