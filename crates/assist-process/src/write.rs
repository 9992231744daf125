//! The processed capture as a nerfstudio dataset: `transforms.json` (one OPENCV camera,
//! distortion kept, OpenGL camera-to-world per frame, `world_up`, `meters_per_unit` when
//! known, `ply_file_path` to the sparse points), `split.json` (every 8th frame held out,
//! as `assist train` would choose), `sparse_pc.ply`, and `images_2/`, `images_4/`,
//! `images_8/` copies (each side divided and rounded down, each pixel the mean of its
//! block, as `--downscale` expects).

use std::path::Path;

use assist_data::colmap::ColmapCamera;
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
/// are in `dir/images/`.
pub fn dataset_files(
    dir: &Path,
    camera: &ColmapCamera,
    aligned: &Aligned,
) -> Result<(), ProcessError> {
    let p = &camera.params;
    let [fx, fy, cx, cy, k1, k2, p1, p2] = p[..] else {
        return Err(ProcessError::Tool {
            tool: "colmap",
            what: "mapping".into(),
            message: format!(
                "camera {} is {} with {} parameters, expected OPENCV's 8",
                camera.id,
                camera.model,
                p.len()
            ),
        });
    };
    let frames: Vec<serde_json::Value> = aligned
        .frames
        .iter()
        .map(|f| json!({"file_path": format!("images/{}", f.name), "transform_matrix": f.c2w}))
        .collect();
    let mut t = json!({
        "camera_model": "OPENCV",
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
        "w": camera.width, "h": camera.height,
        "k1": k1, "k2": k2, "p1": p1, "p2": p2,
        "world_up": [0.0, 0.0, 1.0],
        "ply_file_path": "sparse_pc.ply",
        "frames": frames,
    });
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
            image::RgbImage::from_raw(sw as u32, sh as u32, bytes)
                .ok_or_else(|| ProcessError::Io {
                    path: out.clone(),
                    message: "downscaled image has the wrong size".into(),
                })?
                .save(&out)
                .map_err(|e| ProcessError::Io {
                    path: out.clone(),
                    message: e.to_string(),
                })?;
        }
    }
    Ok(())
}
