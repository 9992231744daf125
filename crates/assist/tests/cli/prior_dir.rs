//! Background priors made elsewhere (`--prior-dir`, the paper's inpainting path): the
//! folder is found and reported, bad folders are clear errors, and training follows the
//! supplied prior where objects hide the background.

use crate::common;

use std::path::{Path, PathBuf};

use crate::common::{ok_stdout as ok, run as assist, s};
use assist_testkit::TempDir;
use serde_json::Value;

fn synth(tmp: &TempDir) -> PathBuf {
    let data = tmp.join("capture");
    common::synth_small(&data, 24);
    data
}

fn frames(data: &Path) -> Vec<Value> {
    let tf: Value =
        serde_json::from_slice(&std::fs::read(data.join("transforms.json")).unwrap()).unwrap();
    tf["frames"].as_array().unwrap().clone()
}

/// A prior folder as an inpainting tool would write it: each image with the pixels its
/// objects cover (and a 2-pixel border) painted over — here in magenta, a colour no tool
/// would choose, so that its effect is unmistakable — and a float depth for the first
/// `depths` frames.
fn prior_folder(data: &Path, dir: &Path, depths: usize) {
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    for (i, f) in frames(data).iter().enumerate() {
        let file = Path::new(f["file_path"].as_str().unwrap());
        let stem = file.file_stem().unwrap().to_str().unwrap();
        let mut img = image::open(data.join(file)).unwrap().to_rgb8();
        let ids = image::open(data.join(f["instance_mask_path"].as_str().unwrap()))
            .unwrap()
            .to_luma16();
        let (w, h) = img.dimensions();
        for y in 0..h {
            for x in 0..w {
                let near = (y.saturating_sub(2)..(y + 3).min(h)).any(|v| {
                    (x.saturating_sub(2)..(x + 3).min(w)).any(|u| ids.get_pixel(u, v).0[0] != 0)
                });
                if near {
                    img.put_pixel(x, y, image::Rgb([255, 0, 255]));
                }
            }
        }
        img.save(dir.join(format!("{stem}.png"))).unwrap();
        if i < depths {
            let mut npy = b"\x93NUMPY\x01\x00".to_vec();
            let mut header =
                format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}), }}");
            while (10 + header.len() + 1) % 64 != 0 {
                header.push(' ');
            }
            header.push('\n');
            npy.extend((header.len() as u16).to_le_bytes());
            npy.extend(header.as_bytes());
            for _ in 0..w * h {
                npy.extend(2.0f32.to_le_bytes());
            }
            std::fs::write(dir.join("depth").join(format!("{stem}.npy")), npy).unwrap();
        }
    }
}

#[test]
fn a_prior_folder_is_reported_and_bad_ones_are_clear_errors() {
    let tmp = TempDir::new("prior-dir-info");
    let data = synth(&tmp);
    let priors = tmp.join("priors");
    prior_folder(&data, &priors, 3);
    let info: Value = serde_json::from_str(&ok(&assist(&[
        "dataset",
        "info",
        s(&data),
        "--prior-dir",
        s(&priors),
        "--json",
    ])))
    .unwrap();
    let p = &info["prior_folder"];
    let train = p["train_frames"].as_u64().unwrap();
    assert_eq!(p["images"].as_u64(), Some(train), "{p}");
    assert!(p["depths"].as_u64().unwrap() <= 3, "{p}");
    assert_eq!(p["missing"].as_array().unwrap().len(), 0);

    // A folder matching no image names the folder and the names expected.
    let empty = tmp.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = assist(&["dataset", "info", s(&data), "--prior-dir", s(&empty)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("empty") && err.contains("expected names such as"),
        "{err}"
    );
    // Not a folder.
    let out = assist(&[
        "dataset",
        "info",
        s(&data),
        "--prior-dir",
        s(&tmp.join("nope")),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a folder"));
    // A depth without its image.
    let lonely = tmp.join("lonely");
    std::fs::create_dir_all(lonely.join("depth")).unwrap();
    let first = frames(&data)[0]["file_path"].as_str().unwrap().to_string();
    let stem = Path::new(&first).file_stem().unwrap().to_str().unwrap();
    std::fs::write(lonely.join("depth").join(format!("{stem}.npy")), b"x").unwrap();
    let out = assist(&["dataset", "info", s(&data), "--prior-dir", s(&lonely)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("without its image"), "{err}");
}

/// Mean distance to magenta of the rendered background over the pixels objects cover in
/// the dataset's own instance masks.
fn magenta_distance(data: &Path, render: &Path) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for f in frames(render) {
        let name = Path::new(f["file_path"].as_str().unwrap())
            .file_name()
            .unwrap()
            .to_owned();
        let bg = image::open(render.join("background").join(&name))
            .unwrap()
            .to_rgb8();
        let ids = image::open(data.join("instances").join(&name))
            .unwrap()
            .to_luma16();
        for (p, id) in bg.pixels().zip(ids.pixels()) {
            if id.0[0] == 0 {
                continue;
            }
            let d = (p.0[0] as f64 - 255.0).abs() + p.0[1] as f64 + (p.0[2] as f64 - 255.0).abs();
            sum += d / (3.0 * 255.0);
            n += 1;
        }
    }
    assert!(n > 50, "too few object pixels: {n}");
    sum / n as f64
}

#[test]
fn training_follows_a_supplied_prior_under_the_objects() {
    let tmp = TempDir::new("prior-dir-train");
    let data = synth(&tmp);
    let priors = tmp.join("priors");
    prior_folder(&data, &priors, 0);
    let mut dist = Vec::new();
    for (name, extra) in [("own", None), ("user", Some(&priors))] {
        let scene = tmp.join(format!("{name}.assist"));
        let mut args = vec![
            "train",
            s(&data),
            "--out",
            s(&scene),
            "--iters",
            "150",
            "--seed",
            "1",
            // An opaque background where the prior speaks: without it the premultiplied
            // colour term is met by a background left transparent behind the objects.
            "--lambda-bg-opacity",
            "0.5",
        ];
        if let Some(p) = extra {
            args.extend(["--prior-dir", s(p)]);
        }
        let out = assist(&args);
        let log = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{log}");
        if extra.is_some() {
            assert!(log.contains("background prior from"), "{log}");
        }
        let render = tmp.join(format!("{name}-render"));
        ok(&assist(&[
            "render",
            s(&scene),
            "--cameras",
            s(&data),
            "--outputs",
            "rgb,background",
            "--out",
            s(&render),
        ]));
        dist.push(magenta_distance(&data, &render));
    }
    // With the built-in fill the hidden background is table-coloured; with the supplied
    // prior it is pulled towards magenta.
    assert!(
        dist[1] < dist[0] - 0.1,
        "distance to magenta under the objects: built-in {:.3}, supplied {:.3}",
        dist[0],
        dist[1]
    );
}
