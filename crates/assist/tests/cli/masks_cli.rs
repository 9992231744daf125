//! Masks from any tool: a capture without instance masks in its description, with a
//! `masks/` folder beside its images, trains into one object node per instance value; a
//! binary mask gives one object; a capture without masks trains as background only and
//! says so; a folder missing a mask is a clear error.

use crate::common;

use std::path::Path;

use crate::common::{ok_stdout as ok, run as assist, s};
use assist_testkit::TempDir;
use serde_json::Value;

/// A synthetic capture as a phone user brings it: images and cameras only (no instance
/// masks, boxes or depth in transforms.json), plus the instance ids as `masks/NAME.png`.
fn capture(tmp: &TempDir) -> std::path::PathBuf {
    let data = tmp.join("capture");
    common::synth_small(&data, 24);
    let tf_path = data.join("transforms.json");
    let mut tf: Value = serde_json::from_slice(&std::fs::read(&tf_path).unwrap()).unwrap();
    tf.as_object_mut().unwrap().remove("instances");
    std::fs::create_dir_all(data.join("masks")).unwrap();
    for f in tf["frames"].as_array_mut().unwrap() {
        let f = f.as_object_mut().unwrap();
        let ids = f.remove("instance_mask_path").unwrap();
        f.remove("depth_file_path");
        let name = Path::new(f["file_path"].as_str().unwrap())
            .file_name()
            .unwrap()
            .to_owned();
        std::fs::rename(
            data.join(ids.as_str().unwrap()),
            data.join("masks").join(name),
        )
        .unwrap();
    }
    std::fs::write(&tf_path, serde_json::to_vec_pretty(&tf).unwrap()).unwrap();
    data
}

/// Trains `data` for 3 iterations into `out`.
fn train3(data: &Path, out: &Path) {
    ok(&assist(&[
        "train",
        s(data),
        "--out",
        s(out),
        "--iters",
        "3",
        "--json",
    ]));
}

fn nodes(scene: &Path) -> Vec<(u64, String)> {
    let v: Value =
        serde_json::from_slice(&std::fs::read(scene.join("scene.json")).unwrap()).unwrap();
    v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["id"].as_u64().unwrap(),
                n["space"].as_str().unwrap_or("box").to_string(),
            )
        })
        .collect()
}

#[test]
fn a_masks_folder_gives_one_node_per_instance() {
    let tmp = TempDir::new("cli-masks");
    let data = capture(&tmp);
    let info: Value =
        serde_json::from_str(&ok(&assist(&["dataset", "info", s(&data), "--json"]))).unwrap();
    assert_eq!(info["mask_folder"]["encoding"]["kind"], "ids", "{info}");
    assert_eq!(info["mask_folder"]["ids"], serde_json::json!([1, 2, 3]));
    assert_eq!(info["validation"]["errors"], serde_json::json!([]));

    let out = tmp.join("ids.assist");
    train3(&data, &out);
    // No depth: the background is contracted; one object node per mask value.
    assert_eq!(
        nodes(&out),
        vec![
            (0, "contracted".to_string()),
            (1, "box".to_string()),
            (2, "box".to_string()),
            (3, "box".to_string())
        ]
    );

    // Masks made for images two times smaller (`masks_2/`) serve `--downscale 2`, once the
    // reduced images are there too (`images_2/`); without them the error says so.
    let masks = data.join("masks");
    let masks2 = data.join("masks_2");
    std::fs::create_dir_all(&masks2).unwrap();
    for e in std::fs::read_dir(&masks).unwrap() {
        let p = e.unwrap().path();
        let img = image::open(&p).unwrap().to_luma8();
        let small = image::GrayImage::from_fn(img.width() / 2, img.height() / 2, |x, y| {
            *img.get_pixel(2 * x + 1, 2 * y + 1)
        });
        small.save(masks2.join(p.file_name().unwrap())).unwrap();
    }
    std::fs::rename(&masks, tmp.join("masks-aside")).unwrap();
    let r = assist(&["dataset", "info", s(&data), "--downscale", "2"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("already 2 times smaller"), "{err}");
    let images2 = data.join("images_2");
    std::fs::create_dir_all(&images2).unwrap();
    for e in std::fs::read_dir(data.join("images")).unwrap() {
        let p = e.unwrap().path();
        let img = image::open(&p).unwrap();
        img.resize_exact(32, 24, image::imageops::FilterType::Triangle)
            .save(images2.join(p.file_name().unwrap()))
            .unwrap();
    }
    let info: Value = serde_json::from_str(&ok(&assist(&[
        "dataset",
        "info",
        s(&data),
        "--downscale",
        "2",
        "--json",
    ])))
    .unwrap();
    assert_eq!(info["width"], 32, "{info}");
    assert_eq!(info["mask_folder"]["ids"], serde_json::json!([1, 2, 3]));
    assert_eq!(info["validation"]["errors"], serde_json::json!([]));
    std::fs::remove_dir_all(&masks2).unwrap();
    std::fs::remove_dir_all(&images2).unwrap();
    std::fs::rename(tmp.join("masks-aside"), &masks).unwrap();

    // The same masks as binary JPEGs (every object white): one object node.
    for e in std::fs::read_dir(data.join("masks")).unwrap() {
        let p = e.unwrap().path();
        let img = image::open(&p).unwrap().to_luma8();
        let bin = image::GrayImage::from_fn(img.width(), img.height(), |x, y| {
            image::Luma([if img.get_pixel(x, y).0[0] > 0 { 255 } else { 0 }])
        });
        bin.save(p.with_extension("jpg")).unwrap();
        std::fs::remove_file(&p).unwrap();
    }
    let info: Value =
        serde_json::from_str(&ok(&assist(&["dataset", "info", s(&data), "--json"]))).unwrap();
    assert_eq!(info["mask_folder"]["encoding"]["kind"], "binary", "{info}");
    assert_eq!(info["mask_folder"]["ids"], serde_json::json!([1]));
    let out = tmp.join("binary.assist");
    train3(&data, &out);
    assert_eq!(nodes(&out).iter().map(|n| n.0).collect::<Vec<_>>(), [0, 1]);

    // A missing mask names the image and the folder.
    let first = std::fs::read_dir(data.join("masks"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    std::fs::remove_file(&first).unwrap();
    let r = assist(&["dataset", "info", s(&data)]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(
        err.contains("masks") && err.contains("no mask for image"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    // Without the folder: background only, and the log says so.
    std::fs::remove_dir_all(data.join("masks")).unwrap();
    let out = tmp.join("bare.assist");
    let r = assist(&["train", s(&data), "--out", s(&out), "--iters", "3"]);
    ok(&r);
    let log = String::from_utf8_lossy(&r.stderr);
    assert!(log.contains("no instance masks"), "{log}");
    assert_eq!(nodes(&out).iter().map(|n| n.0).collect::<Vec<_>>(), [0]);
}
