//! The processed capture as a nerfstudio dataset: `transforms.json` (OPENCV cameras,
//! one for the capture or one per frame, distortion kept, OpenGL camera-to-world per frame, `world_up`, `meters_per_unit` when
//! known, `ply_file_path` to the sparse points), `split.json` (every 8th frame held out,
//! as `assist train` would choose), `sparse_pc.ply`, and `images_2/`, `images_4/`,
//! `images_8/` copies (each side divided and rounded down, each pixel the mean of its
//! block, as `--downscale` expects).

use std::path::Path;

use assist_core::Distortion;
use assist_data::colmap::{ColmapCamera, ColmapModel};
use serde_json::json;

use crate::ProcessError;
use crate::align::Aligned;

/// Factors of the downscaled copies.
pub const DOWNSCALES: [u32; 3] = [2, 4, 8];

fn io(path: &Path) -> impl Fn(std::io::Error) -> ProcessError + '_ {
    move |e| ProcessError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// `transforms.json`, `split.json` and `sparse_pc.ply` for `aligned` frames whose images
/// are in `dir/images/`; each frame's camera is its image's in `model`: written once at
/// the top level when every frame shares one, in each frame otherwise.
pub fn dataset_files(
    dir: &Path,
    model: &ColmapModel,
    aligned: &Aligned,
) -> Result<(), ProcessError> {
    let camera_of = |name: &str| -> Result<&ColmapCamera, ProcessError> {
        model
            .images
            .iter()
            .find(|i| i.name == name)
            .and_then(|i| model.cameras.get(&i.camera_id))
            .ok_or_else(|| ProcessError::Tool {
                tool: "colmap",
                what: "mapping".into(),
                message: format!("image {name} has no camera in the model"),
            })
    };
    let first = aligned.frames.first().ok_or(ProcessError::NoModel)?;
    let camera = camera_of(&first.name)?;
    let shared = model.cameras.len() == 1;
    let mut frames = Vec::with_capacity(aligned.frames.len());
    for f in &aligned.frames {
        let mut frame =
            json!({"file_path": format!("images/{}", f.name), "transform_matrix": f.c2w});
        if !shared {
            opencv_fields(dir, camera_of(&f.name)?, &mut frame)?;
        }
        frames.push(frame);
    }
    let mut t = json!({
        "camera_model": "OPENCV",
        "w": camera.width, "h": camera.height,
        "world_up": [0.0, 0.0, 1.0],
        "ply_file_path": "sparse_pc.ply",
        "frames": frames,
    });
    if shared {
        opencv_fields(dir, camera, &mut t)?;
    }
    if let Some(m) = aligned.meters_per_unit {
        t["meters_per_unit"] = json!(m);
    }
    let text = serde_json::to_string_pretty(&t).unwrap_or_default();
    let path = dir.join("transforms.json");
    std::fs::write(&path, text).map_err(io(&path))?;
    let n = aligned.frames.len();
    let (test, train): (Vec<usize>, Vec<usize>) = (0..n).partition(|i| i % 8 == 0);
    let path = dir.join("split.json");
    std::fs::write(&path, json!({"train": train, "test": test}).to_string()).map_err(io(&path))?;
    let path = dir.join("sparse_pc.ply");
    std::fs::write(&path, points_ply(&aligned.points)).map_err(io(&path))?;
    Ok(())
}

/// Sets nerfstudio's OPENCV fields (`fl_x` … `p2`) of `camera` in `obj`: any COLMAP
/// model without fisheye or third radial term (those `process` asks COLMAP for).
fn opencv_fields(
    dir: &Path,
    camera: &ColmapCamera,
    obj: &mut serde_json::Value,
) -> Result<(), ProcessError> {
    let bad = |message: String| ProcessError::Tool {
        tool: "colmap",
        what: "mapping".into(),
        message,
    };
    let i = assist_data::colmap::intrinsics(camera, &dir.join("colmap"))
        .map_err(|e| bad(e.to_string()))?;
    let (k1, k2, p1, p2) = match i.distortion {
        Distortion::None => (0.0, 0.0, 0.0, 0.0),
        Distortion::OpenCv {
            k1,
            k2,
            k3: 0.0,
            p1,
            p2,
        } => (k1, k2, p1, p2),
        _ => {
            return Err(bad(format!(
                "camera {} is {}, which nerfstudio's OPENCV model cannot hold",
                camera.id, camera.model
            )));
        }
    };
    for (k, v) in [
        ("fl_x", i.fx),
        ("fl_y", i.fy),
        ("cx", i.cx),
        ("cy", i.cy),
        ("k1", k1),
        ("k2", k2),
        ("p1", p1),
        ("p2", p2),
    ] {
        obj[k] = json!(v);
    }
    Ok(())
}

/// An ASCII PLY of coloured points (what nerfstudio's `sparse_pc.ply` holds).
fn points_ply(points: &[(assist_core::DVec3, [u8; 3])]) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment assist process: COLMAP's sparse points\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    );
    for (p, c) in points {
        s.push_str(&format!(
            "{} {} {} {} {} {}\n",
            p.x as f32, p.y as f32, p.z as f32, c[0], c[1], c[2]
        ));
    }
    s
}

/// `images_N/` copies of every image in `dir/images/` named in `names`.
pub fn downscaled_copies(dir: &Path, names: &[String]) -> Result<(), ProcessError> {
    for f in DOWNSCALES {
        let out = dir.join(format!("images_{f}"));
        std::fs::create_dir_all(&out).map_err(io(&out))?;
    }
    for name in names {
        let src = dir.join("images").join(name);
        let img = image::open(&src)
            .map_err(|e| ProcessError::Input {
                path: src.clone(),
                message: format!("not an image this build can read: {e}"),
            })?
            .to_rgb8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let data: Vec<f32> = img.as_raw().iter().map(|&v| f32::from(v)).collect();
        for f in DOWNSCALES {
            let (sw, sh) = (w / f as usize, h / f as usize);
            if sw == 0 || sh == 0 {
                continue;
            }
            let small = assist_data::downscale::reduce_mean(&data, w, h, 3, f as usize);
            let bytes: Vec<u8> = small
                .iter()
                .map(|v| v.round().clamp(0.0, 255.0) as u8)
                .collect();
            let out = dir.join(format!("images_{f}")).join(name);
            let small =
                image::RgbImage::from_raw(sw as u32, sh as u32, bytes).ok_or_else(|| {
                    ProcessError::Io {
                        path: out.clone(),
                        message: "downscaled image has the wrong size".into(),
                    }
                })?;
            save_copy(&small, &out).map_err(|e| ProcessError::Io {
                path: out.clone(),
                message: e.to_string(),
            })?;
        }
    }
    Ok(())
}

/// Saves a downscaled copy in its name's format; JPEG at quality 95 (the encoder's
/// default, 75, would add visible blocking to what training and evaluation read).
fn save_copy(img: &image::RgbImage, out: &Path) -> image::ImageResult<()> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or_default()
        .to_ascii_lowercase();
    if ext == "jpg" || ext == "jpeg" {
        let file = std::io::BufWriter::new(std::fs::File::create(out)?);
        image::codecs::jpeg::JpegEncoder::new_with_quality(file, 95).encode_image(img)
    } else {
        img.save(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::align::Posed;
    use assist_data::colmap::ColmapImage;

    fn model(cameras: &[(&str, Vec<f64>)]) -> (ColmapModel, Aligned) {
        let mut model = ColmapModel::default();
        let mut frames = Vec::new();
        for (k, (kind, params)) in cameras.iter().enumerate() {
            let id = k as u32 + 1;
            model.cameras.insert(
                id,
                ColmapCamera {
                    id,
                    model: kind.to_string(),
                    width: 64,
                    height: 48,
                    params: params.clone(),
                },
            );
        }
        for k in 0..3 {
            let name = format!("f{k}.png");
            model.images.push(ColmapImage {
                id: k + 1,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0; 3],
                camera_id: if cameras.len() == 1 { 1 } else { k + 1 },
                name: name.clone(),
                points2d: vec![],
            });
            let mut c2w = [[0.0; 4]; 4];
            for (a, row) in c2w.iter_mut().enumerate() {
                row[a] = 1.0;
            }
            c2w[0][3] = k as f64;
            frames.push(Posed { name, c2w });
        }
        let aligned = Aligned {
            frames,
            points: vec![],
            meters_per_unit: None,
            known: None,
            warnings: vec![],
        };
        (model, aligned)
    }

    fn written(dir: &Path, model: &ColmapModel, aligned: &Aligned) -> assist_data::Dataset {
        std::fs::create_dir_all(dir.join("images")).unwrap();
        for f in &aligned.frames {
            image::RgbImage::new(64, 48)
                .save(dir.join("images").join(&f.name))
                .unwrap();
        }
        dataset_files(dir, model, aligned).unwrap();
        assist_data::nerfstudio::load(&dir.join("transforms.json")).unwrap()
    }

    /// One camera per frame (COLMAP's SIMPLE_RADIAL): each frame's focal length and
    /// radial term come back from the written dataset as they were solved.
    #[test]
    fn each_frame_keeps_its_own_camera() {
        let cams: Vec<(&str, Vec<f64>)> = (0..3)
            .map(|k| {
                (
                    "SIMPLE_RADIAL",
                    vec![50.0 + k as f64, 31.0, 23.5, 0.01 * k as f64],
                )
            })
            .collect();
        let (model, aligned) = model(&cams);
        let dir = assist_testkit::TempDir::new("per-frame-cameras");
        let data = written(dir.path(), &model, &aligned);
        let text = std::fs::read_to_string(dir.path().join("transforms.json")).unwrap();
        let t: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert!(t.get("fl_x").is_none(), "no top-level focal length: {t}");
        assert_eq!(data.frames.len(), 3);
        for (k, f) in data.frames.iter().enumerate() {
            let i = &f.camera.intrinsics;
            assert_eq!(
                (i.fx, i.fy, i.cx, i.cy),
                (50.0 + k as f64, 50.0 + k as f64, 31.0, 23.5)
            );
            let want = if k == 0 {
                Distortion::None
            } else {
                Distortion::OpenCv {
                    k1: 0.01 * k as f64,
                    k2: 0.0,
                    k3: 0.0,
                    p1: 0.0,
                    p2: 0.0,
                }
            };
            assert_eq!(i.distortion, want, "frame {k}");
        }
    }

    /// One shared OPENCV camera is written once, at the top level, with all its terms.
    #[test]
    fn a_shared_camera_is_written_once() {
        let p = vec![52.0, 51.0, 32.0, 24.0, 0.02, -0.01, 0.001, 0.002];
        let (model, aligned) = model(&[("OPENCV", p)]);
        let dir = assist_testkit::TempDir::new("shared-camera");
        let data = written(dir.path(), &model, &aligned);
        let text = std::fs::read_to_string(dir.path().join("transforms.json")).unwrap();
        let t: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(t["fl_x"], 52.0);
        assert!(t["frames"][0].get("fl_x").is_none());
        for f in &data.frames {
            let i = &f.camera.intrinsics;
            assert_eq!((i.fx, i.fy, i.cx, i.cy), (52.0, 51.0, 32.0, 24.0));
            assert_eq!(
                i.distortion,
                Distortion::OpenCv {
                    k1: 0.02,
                    k2: -0.01,
                    k3: 0.0,
                    p1: 0.001,
                    p2: 0.002
                }
            );
        }
    }
}

#[cfg(test)]
mod copies {
    use super::*;

    /// The downscaled copies hold each block's mean with no more loss than a
    /// high-quality JPEG adds (the encoder's default quality, 75, fails this on texture).
    #[test]
    fn downscaled_copies_keep_the_block_means() {
        let dir = assist_testkit::TempDir::new("downscaled-copies");
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let (w, h) = (128u32, 96u32);
        let mut state = 7u32;
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let n = (state >> 24) as f32 / 255.0;
            let v = |k: f32| {
                let t = 0.5 + 0.3 * ((x as f32 * 0.21 + k).sin() * (y as f32 * 0.17).cos());
                ((t + 0.2 * (n - 0.5)) * 255.0).clamp(0.0, 255.0) as u8
            };
            image::Rgb([v(0.0), v(1.0), v(2.0)])
        });
        img.save(dir.path().join("images/a.png")).unwrap();
        // A JPEG source (quality 100): its copies are JPEG too.
        let file = std::fs::File::create(dir.path().join("images/b.jpg")).unwrap();
        image::codecs::jpeg::JpegEncoder::new_with_quality(file, 100)
            .encode_image(&img)
            .unwrap();
        downscaled_copies(dir.path(), &["a.png".into(), "b.jpg".into()]).unwrap();
        for (name, min_db) in [("a.png", 60.0), ("b.jpg", 38.0)] {
            let src = image::open(dir.path().join("images").join(name))
                .unwrap()
                .to_rgb8();
            let data: Vec<f32> = src.as_raw().iter().map(|&v| f32::from(v)).collect();
            let want = assist_data::downscale::reduce_mean(&data, w as usize, h as usize, 3, 2);
            let got = image::open(dir.path().join("images_2").join(name))
                .unwrap()
                .to_rgb8();
            assert_eq!((got.width(), got.height()), (w / 2, h / 2));
            let mse = got
                .as_raw()
                .iter()
                .zip(&want)
                .map(|(&g, &e)| (f64::from(g) - f64::from(e.round())).powi(2))
                .sum::<f64>()
                / want.len() as f64;
            let psnr = 10.0 * (255.0f64.powi(2) / mse.max(1e-12)).log10();
            assert!(
                psnr > min_db,
                "{name}: {psnr:.1} dB from the exact block means"
            );
        }
    }
}
