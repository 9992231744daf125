//! The parsers of untrusted input, each with its seeds: real files from the shared data
//! where present (trimmed to a few frames so that an execution stays fast), else the small
//! files in `seeds/` (written by assist itself, or by hand for the COLMAP text format).

use std::path::{Path, PathBuf};

use assist_core::action::NoSources;
use assist_core::{Action, Scene};

use crate::Target;

fn seed_file(name: &str) -> Vec<u8> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("seeds")
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn write(dir: &Path, rel: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(rel);
    if let Some(parent) = p.parent() {
        let _ = std::fs::create_dir_all(parent);
    }
    let _ = std::fs::write(&p, bytes);
    p
}

fn tiny_png() -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    image::RgbImage::new(8, 6)
        .write_to(&mut buf, image::ImageFormat::Png)
        .expect("encode");
    buf.into_inner()
}

/// The first `frames` frames of a JSON dataset file (the rest only slow a run down).
fn json_frames(path: &Path, frames: usize) -> Option<Vec<u8>> {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).ok()?).ok()?;
    if let Some(f) = v.get_mut("frames").and_then(|f| f.as_array_mut()) {
        f.truncate(frames);
    }
    serde_json::to_vec_pretty(&v).ok()
}

/// COLMAP `images.bin` with its first `n` images and 3 points each.
fn trim_images_bin(b: &[u8], n: usize) -> Option<Vec<u8>> {
    let u64_at =
        |o: usize| -> Option<u64> { Some(u64::from_le_bytes(b.get(o..o + 8)?.try_into().ok()?)) };
    let count = u64_at(0)? as usize;
    let mut o = 8;
    let mut out = Vec::new();
    let mut kept = 0u64;
    for _ in 0..count.min(n) {
        let head = b.get(o..o + 4 + 32 + 24 + 4)?;
        o += head.len();
        let end = o + b.get(o..)?.iter().position(|&c| c == 0)?;
        let name = b.get(o..=end)?;
        o = end + 1;
        let pts = u64_at(o)? as usize;
        o += 8;
        let keep = pts.min(3);
        let p = b.get(o..o + 24 * keep)?;
        o += 24 * pts;
        out.extend_from_slice(head);
        out.extend_from_slice(name);
        out.extend_from_slice(&(keep as u64).to_le_bytes());
        out.extend_from_slice(p);
        kept += 1;
    }
    let mut v = kept.to_le_bytes().to_vec();
    v.extend(out);
    Some(v)
}

fn shared(rel: &str) -> Option<PathBuf> {
    let root = match std::env::var_os("ASSIST_DATA") {
        Some(p) => PathBuf::from(p),
        None => assist_testkit::workspace_root().join("../shared/data"),
    };
    let p = root.join(rel);
    p.exists().then_some(p)
}

fn load_dataset(dir: &Path) {
    let _ = assist_data::load(dir, &assist_data::LoadOptions::default());
}

fn scene() -> Scene {
    let text = String::from_utf8(seed_file("scene.json")).expect("utf-8 seed");
    assist_scene::scene_file::parse_scene_json(Path::new("scene.json"), &text)
        .expect("the seed scene loads")
        .0
}

/// Every target.
pub fn all() -> Vec<Target> {
    let mut t = dataset_targets();
    t.extend(file_targets());
    t
}

/// The dataset readers: each writes a small capture around the mutated file and loads it.
fn dataset_targets() -> Vec<Target> {
    let png = tiny_png();
    let mut t = Vec::new();

    // nerfstudio / desk transforms.json.
    let mut seeds = Vec::new();
    if let Some(s) = shared("desk/transforms.json").and_then(|p| json_frames(&p, 6)) {
        seeds.push(s);
    }
    seeds.push(
        br#"{"camera_model":"OPENCV","fl_x":50,"fl_y":50,"cx":4,"cy":3,"w":8,"h":6,"k1":0.01,
"frames":[{"file_path":"images/a.png","transform_matrix":[[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]],
"depth_file_path":"depth/a.png","instance_mask_path":"instances/a.png"}],
"instances":[{"id":1,"label":"mug","bbox":{"center":[0,0,0],"size":[1,1,1],"rotation":[[1,0,0],[0,1,0],[0,0,1]]}}]}"#
            .to_vec(),
    );
    let p = png.clone();
    t.push(Target {
        name: "nerfstudio",
        seeds,
        run: Box::new(move |b, dir| {
            write(dir, "images/a.png", &p);
            write(dir, "transforms.json", b);
            load_dataset(dir);
        }),
    });

    // Blender transforms_train.json.
    let mut seeds = Vec::new();
    if let Some(s) = shared("lego_400/transforms_train.json").and_then(|p| json_frames(&p, 6)) {
        seeds.push(s);
    }
    seeds.push(
        br#"{"camera_angle_x":0.69,"frames":[{"file_path":"./train/r_0","rotation":0.01,
"transform_matrix":[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#
            .to_vec(),
    );
    let p = png.clone();
    t.push(Target {
        name: "blender",
        seeds,
        run: Box::new(move |b, dir| {
            write(dir, "train/r_0.png", &p);
            write(dir, "transforms_train.json", b);
            load_dataset(dir);
        }),
    });

    // COLMAP binary: cameras.bin and images.bin (beer's, trimmed), each mutated in turn.
    let cams = shared("beer/sparse/0/cameras.bin").and_then(|p| std::fs::read(p).ok());
    let imgs = shared("beer/sparse/0/images.bin")
        .and_then(|p| std::fs::read(p).ok())
        .and_then(|b| trim_images_bin(&b, 6));
    if let (Some(cams), Some(imgs)) = (cams, imgs) {
        let points = 0u64.to_le_bytes().to_vec();
        for (name, which) in [("colmap-cameras-bin", 0), ("colmap-images-bin", 1)] {
            let (c, i, p) = (cams.clone(), imgs.clone(), points.clone());
            t.push(Target {
                name,
                seeds: vec![if which == 0 {
                    cams.clone()
                } else {
                    imgs.clone()
                }],
                run: Box::new(move |b, dir| {
                    let (cb, ib) = if which == 0 { (b, &i[..]) } else { (&c[..], b) };
                    write(dir, "sparse/0/cameras.bin", cb);
                    write(dir, "sparse/0/images.bin", ib);
                    write(dir, "sparse/0/points3D.bin", &p);
                    std::fs::create_dir_all(dir.join("images")).ok();
                    load_dataset(dir);
                }),
            });
        }
    }

    // COLMAP text: cameras.txt, images.txt and points3D.txt joined by a separator line.
    let text_seed = [
        seed_file("cameras.txt"),
        b"\n%%\n".to_vec(),
        seed_file("images.txt"),
        b"\n%%\n".to_vec(),
        seed_file("points3D.txt"),
    ]
    .concat();
    t.push(Target {
        name: "colmap-text",
        seeds: vec![text_seed],
        run: Box::new(|b, dir| {
            let parts: Vec<&[u8]> = split(b, b"\n%%\n");
            let get = |k: usize| parts.get(k).copied().unwrap_or(b"");
            write(dir, "sparse/0/cameras.txt", get(0));
            write(dir, "sparse/0/images.txt", get(1));
            write(dir, "sparse/0/points3D.txt", get(2));
            std::fs::create_dir_all(dir.join("images")).ok();
            load_dataset(dir);
        }),
    });

    // LLFF poses_bounds.npy (and the npy parser itself).
    let mut seeds = Vec::new();
    for rel in ["fern/poses_bounds.npy", "beer/poses_bounds.npy"] {
        if let Some(b) = shared(rel).and_then(|p| std::fs::read(p).ok()) {
            seeds.push(b);
        }
    }
    if seeds.is_empty() {
        seeds.push(assist_data::npy::encode_npy_f32(&[2, 17], &[0.5; 34]));
    }
    let p = png.clone();
    t.push(Target {
        name: "llff-npy",
        seeds,
        run: Box::new(move |b, dir| {
            let _ = assist_data::npy::parse_npy(Path::new("poses_bounds.npy"), b);
            write(dir, "images/a.png", &p);
            write(dir, "poses_bounds.npy", b);
            load_dataset(dir);
        }),
    });

    t
}

/// The scene, history, field, action, instruction, box and viewer-message parsers.
fn file_targets() -> Vec<Target> {
    let mut t = Vec::new();
    // scene.json.
    t.push(Target {
        name: "scene-json",
        seeds: vec![seed_file("scene.json")],
        run: Box::new(|b, _| {
            if let Ok(text) = std::str::from_utf8(b) {
                let _ = assist_scene::scene_file::parse_scene_json(Path::new("scene.json"), text);
            }
        }),
    });

    // history.json.
    t.push(Target {
        name: "history-json",
        seeds: vec![seed_file("history.json")],
        run: Box::new(|b, _| {
            if let Ok(text) = std::str::from_utf8(b) {
                let _ = assist_scene::scene_file::parse_history(Path::new("history.json"), text);
            }
        }),
    });

    // Field safetensors: config and tensors (a small field so that a run stays fast).
    let cfg = assist_field::FieldConfig {
        levels: 4,
        log2_table_size: 8,
        base_resolution: 4,
        max_resolution: 32,
        hidden: 16,
        color_hidden: 16,
        appearance_dim: 4,
        num_images: 3,
        ..assist_field::FieldConfig::object(3)
    };
    let field = assist_field::Field::new(cfg, 1).expect("a small field");
    let occ = assist_field::OccupancyGrid::new(8);
    let bytes = assist_field::io::to_bytes(&field, Some(&occ)).expect("serialise");
    t.push(Target {
        name: "field-safetensors",
        seeds: vec![bytes],
        run: Box::new(|b, _| {
            let _ = assist_field::io::from_bytes(Path::new("field.safetensors"), b);
        }),
    });

    // Action scripts (JSON Lines) validated against a scene.
    let sc = scene();
    t.push(Target {
        name: "actions-jsonl",
        seeds: vec![
            br#"{"instance_id": 1, "operation": "translate", "config": {"axis": "x", "distance": 0.1}}
{"instance_id": 2, "operation": "rotate", "config": {"axis": "z", "angle": 90}}
{"instance_id": 3, "operation": "scale", "config": {"factor": 1.5}}
{"instance_id": 1, "operation": "replicate", "config": {"position": [0.1, 0.2, 0.8]}}
{"instance_id": 2, "operation": "delete", "config": {}}"#
                .to_vec(),
        ],
        run: Box::new(move |b, _| {
            let Ok(text) = std::str::from_utf8(b) else { return };
            let mut s = sc.clone();
            for line in text.lines() {
                let Ok(a) = serde_json::from_str::<Action>(line) else { continue };
                if let Ok(e) = a.validate(&s, &mut NoSources, &Default::default()) {
                    let _ = assist_core::edit::apply(&mut s, &e);
                }
            }
        }),
    });

    // Plain-language instructions.
    let sc = scene();
    t.push(Target {
        name: "instruction",
        seeds: vec![
            b"move the green box 10 cm left and rotate it by 90 degrees".to_vec(),
            b"duplicate the ball and move the copy 5 cm forward, then delete the cone".to_vec(),
            b"make the box twice as big; undo; scale object 2 by 0.5".to_vec(),
            b"swap the box and the ball, then highlight the cone".to_vec(),
        ],
        run: Box::new(move |b, _| {
            let Ok(text) = std::str::from_utf8(b) else {
                return;
            };
            let _ = assist_lang::parse(text, &sc, &Default::default(), &mut NoSources);
        }),
    });

    // Box files.
    t.push(Target {
        name: "boxes-json",
        seeds: vec![seed_file("boxes.json")],
        run: Box::new(|b, dir| {
            let p = write(dir, "boxes.json", b);
            let _ = assist_data::boxes::read_boxes(&p);
        }),
    });

    // The viewer's client messages.
    t.push(Target {
        name: "viewer-message",
        seeds: vec![
            br#"{"type": "view", "view": {"world_from_camera": [[1,0,0,0],[0,0,-1,-0.8],[0,1,0,0.05],[0,0,0,1]], "fov_y_degrees": 40, "width": 64, "height": 48}}"#.to_vec(),
            br#"{"type": "click", "x": 20.0, "y": 22.0}"#.to_vec(),
            br#"{"type": "text", "text": "move the ball 3 cm left"}"#.to_vec(),
            br#"{"type": "save", "path": "copy.assist", "force": true}"#.to_vec(),
            br#"{"type": "drag", "dx": 3.5, "dy": -2}"#.to_vec(),
        ],
        run: Box::new(|b, _| {
            let Ok(text) = std::str::from_utf8(b) else { return };
            if let Ok(m) = assist_viewer::protocol::parse_client(text)
                && let assist_viewer::protocol::ClientMsg::View { view } = m
            {
                let _ = view.camera();
            }
        }),
    });
    t
}

fn split<'a>(b: &'a [u8], sep: &[u8]) -> Vec<&'a [u8]> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut i = 0;
    while i + sep.len() <= b.len() {
        if &b[i..i + sep.len()] == sep {
            out.push(&b[start..i]);
            i += sep.len();
            start = i;
        } else {
            i += 1;
        }
    }
    out.push(&b[start..]);
    out
}
