//! assist-sam against `segment_anything`'s reference code: a small SAM with random
//! weights (tests/sam_reference.py, in the Python named by `ASSIST_PYTHON` with torch and
//! segment-anything installed) must give the same image embedding, masks and IoU
//! estimates for point, box and mixed prompts, and the same masks at a photograph's size,
//! to 1e-4. Skips loudly without that Python, unless `ASSIST_REQUIRE_PYTHON` is set.

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

use assist_sam::{Prompt, Sam, mask_to_size};
use candle_core::{Device, Tensor};

fn python() -> Option<String> {
    let py = std::env::var("ASSIST_PYTHON").ok();
    let have = py.as_ref().is_some_and(|p| {
        Command::new(p)
            .args(["-c", "import torch, segment_anything, safetensors"])
            .status()
            .is_ok_and(|s| s.success())
    });
    if have {
        return py;
    }
    if std::env::var_os("ASSIST_REQUIRE_PYTHON").is_some() {
        panic!(
            "ASSIST_REQUIRE_PYTHON is set but ASSIST_PYTHON ({py:?}) lacks torch, segment-anything or safetensors"
        );
    }
    eprintln!(
        "SKIPPED the SAM parity test: set ASSIST_PYTHON to a python with torch, segment-anything and safetensors"
    );
    None
}

fn close(name: &str, a: &Tensor, b: &Tensor, tol: f32) {
    assert_eq!(a.dims(), b.dims(), "{name}: shapes");
    let a = a.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let b = b.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs() / (1.0 + y.abs()))
        .fold(0f32, f32::max);
    eprintln!("{name}: worst {worst:e}");
    assert!(
        worst <= tol,
        "{name}: worst difference {worst:e} (tolerance {tol:e})"
    );
}

#[test]
fn a_random_sam_matches_the_reference_code() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/sam_reference.py");
    let st = Command::new(&py)
        .arg(&script)
        .arg(dir.path())
        .status()
        .unwrap();
    assert!(st.success(), "{} failed", script.display());
    let sam = Sam::load(&dir.path().join("sam.safetensors")).unwrap();
    let r: HashMap<String, Tensor> =
        candle_core::safetensors::load(dir.path().join("reference.safetensors"), &Device::Cpu)
            .unwrap();
    assert_eq!(sam.encoder.img_size, 128);
    let emb = sam.encoder.forward(&r["input"]).unwrap();
    close("embedding", &emb, &r["embedding"], 1e-4);
    // One head or window at a time gives the same embedding.
    let mut one = Sam::load(&dir.path().join("sam.safetensors")).unwrap();
    one.encoder.scores_per_chunk = 1;
    close(
        "embedding, one head at a time",
        &one.encoder.forward(&r["input"]).unwrap(),
        &emb,
        1e-6,
    );
    let prompts: Vec<serde_like::P> = serde_like::read(&dir.path().join("prompts.json"));
    for (i, p) in prompts.iter().enumerate() {
        let prompt = Prompt {
            points: p
                .points
                .iter()
                .map(|q| ([q[0], q[1]], q[2] as u8))
                .collect(),
            bbox: p.bbox,
        };
        for multi in [false, true] {
            let m = sam
                .predict_resized(&r["embedding"], &prompt, multi)
                .unwrap();
            let key = format!("{i}_{}", u8::from(multi));
            let n = m.logits.len();
            let masks =
                Tensor::from_vec(m.logits.concat(), (1, n, m.side, m.side), &Device::Cpu).unwrap();
            close(
                &format!("masks {key}"),
                &masks,
                &r[&format!("masks_{key}")],
                1e-4,
            );
            let iou = Tensor::from_vec(m.iou.clone(), (1, n), &Device::Cpu).unwrap();
            close(&format!("iou {key}"), &iou, &r[&format!("iou_{key}")], 1e-4);
            if multi {
                let full: Vec<f32> = m
                    .logits
                    .iter()
                    .flat_map(|l| mask_to_size(l, m.side, 128, (128, 90), (100, 70)))
                    .collect();
                let full = Tensor::from_vec(full, (1, n, 70, 100), &Device::Cpu).unwrap();
                close(
                    &format!("full-size masks {i}"),
                    &full,
                    &r[&format!("full_{i}")],
                    1e-4,
                );
            }
        }
    }
}

/// The prompts file, read without a JSON dependency beyond what the test needs.
mod serde_like {
    pub struct P {
        pub points: Vec<[f32; 3]>,
        pub bbox: Option<[f32; 4]>,
    }

    pub fn read(path: &std::path::Path) -> Vec<P> {
        let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
        let num = |x: &serde_json::Value| x.as_f64().unwrap() as f32;
        v.as_array()
            .unwrap()
            .iter()
            .map(|p| P {
                points: p["points"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|q| [num(&q[0]), num(&q[1]), num(&q[2])])
                    .collect(),
                bbox: p["box"]
                    .as_array()
                    .map(|b| [num(&b[0]), num(&b[1]), num(&b[2]), num(&b[3])]),
            })
            .collect()
    }
}
