//! Format details: COLMAP text equals binary, every COLMAP camera model maps to the right
//! projection, nerfstudio per-frame and fisheye intrinsics.

use assist_core::{DVec2, DVec3, Distortion};
use assist_data::colmap::{ColmapCamera, intrinsics, read_model};
use assist_data::{Format, LoadOptions, load};
use assist_testkit::{TempDir, shared_dataset};
use std::fmt::Write;

#[test]
fn colmap_text_reader_matches_binary_on_beer() {
    let Some(dir) = shared_dataset("colmap_text_reader_matches_binary_on_beer", "beer") else {
        return;
    };
    let bin = read_model(&dir.join("sparse/0"), true).unwrap();
    // Write the same model as COLMAP text, then read it back.
    let tmp = TempDir::new("colmap-text");
    let model = tmp.join("sparse/0");
    std::fs::create_dir_all(&model).unwrap();
    std::os::unix::fs::symlink(dir.join("images"), tmp.join("images")).unwrap();
    let mut cams = String::from("# Camera list with one line of data per camera:\n");
    let mut ids: Vec<_> = bin.cameras.keys().copied().collect();
    ids.sort();
    for id in ids {
        let c = &bin.cameras[&id];
        let p: Vec<String> = c.params.iter().map(|v| format!("{v:.17e}")).collect();
        writeln!(
            cams,
            "{} {} {} {} {}",
            c.id,
            c.model,
            c.width,
            c.height,
            p.join(" ")
        )
        .unwrap();
    }
    std::fs::write(model.join("cameras.txt"), cams).unwrap();
    let mut imgs = String::from("# Image list with two lines of data per image:\n");
    for im in &bin.images {
        let q: Vec<String> = im
            .qvec
            .iter()
            .chain(&im.tvec)
            .map(|v| format!("{v:.17e}"))
            .collect();
        writeln!(
            imgs,
            "{} {} {} {}",
            im.id,
            q.join(" "),
            im.camera_id,
            im.name
        )
        .unwrap();
        let obs: Vec<String> = im
            .points2d
            .iter()
            .map(|(xy, pid)| format!("{:.17e} {:.17e} {pid}", xy.x, xy.y))
            .collect();
        writeln!(imgs, "{}", obs.join(" ")).unwrap();
    }
    std::fs::write(model.join("images.txt"), imgs).unwrap();
    let mut pts = String::new();
    for p in bin.points.values() {
        writeln!(
            pts,
            "{} {:.17e} {:.17e} {:.17e} {} {} {} {:.17e} 1 0",
            p.id, p.xyz.x, p.xyz.y, p.xyz.z, p.rgb[0], p.rgb[1], p.rgb[2], p.error
        )
        .unwrap();
    }
    std::fs::write(model.join("points3D.txt"), pts).unwrap();

    let text = load(tmp.path(), &LoadOptions::default()).unwrap();
    assert_eq!(text.format, Format::ColmapText);
    let binary = load(&dir, &LoadOptions::default()).unwrap();
    assert_eq!(text.frames.len(), binary.frames.len());
    for (a, b) in text.frames.iter().zip(&binary.frames) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.camera, b.camera);
        assert_eq!(a.split, b.split);
    }
    assert_eq!(text.points.len(), binary.points.len());
    let t = read_model(&model, false).unwrap();
    assert_eq!(
        t.images.iter().map(|i| i.points2d.len()).sum::<usize>(),
        bin.images.iter().map(|i| i.points2d.len()).sum::<usize>()
    );
}

/// COLMAP's projection, written out per model from `camera_models.h`.
fn colmap_project(model: &str, p: &[f64], x: f64, y: f64) -> DVec2 {
    let (u, v) = (x, y);
    match model {
        "SIMPLE_PINHOLE" => DVec2::new(p[0] * u + p[1], p[0] * v + p[2]),
        "PINHOLE" => DVec2::new(p[0] * u + p[2], p[1] * v + p[3]),
        "SIMPLE_RADIAL" => {
            let r2 = u * u + v * v;
            let k = 1.0 + p[3] * r2;
            DVec2::new(p[0] * u * k + p[1], p[0] * v * k + p[2])
        }
        "RADIAL" => {
            let r2 = u * u + v * v;
            let k = 1.0 + p[3] * r2 + p[4] * r2 * r2;
            DVec2::new(p[0] * u * k + p[1], p[0] * v * k + p[2])
        }
        "OPENCV" | "FULL_OPENCV" => {
            let (k1, k2, p1, p2) = (p[4], p[5], p[6], p[7]);
            let k3 = if model == "FULL_OPENCV" { p[8] } else { 0.0 };
            let r2 = u * u + v * v;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
            let du = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u);
            let dv = v * radial + 2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v);
            DVec2::new(p[0] * du + p[2], p[1] * dv + p[3])
        }
        "OPENCV_FISHEYE" => {
            let r = (u * u + v * v).sqrt();
            if r == 0.0 {
                return DVec2::new(p[2], p[3]);
            }
            let th = r.atan();
            let t2 = th * th;
            let thd = th
                * (1.0
                    + p[4] * t2
                    + p[5] * t2 * t2
                    + p[6] * t2 * t2 * t2
                    + p[7] * t2 * t2 * t2 * t2);
            DVec2::new(p[0] * u * thd / r + p[2], p[1] * v * thd / r + p[3])
        }
        _ => unreachable!(),
    }
}

#[test]
fn every_colmap_camera_model_projects_like_colmap() {
    let cases: Vec<(&str, Vec<f64>)> = vec![
        ("SIMPLE_PINHOLE", vec![500.0, 320.0, 240.0]),
        ("PINHOLE", vec![500.0, 510.0, 320.0, 240.0]),
        ("SIMPLE_RADIAL", vec![500.0, 320.0, 240.0, -0.1]),
        ("RADIAL", vec![500.0, 320.0, 240.0, -0.1, 0.02]),
        (
            "OPENCV",
            vec![500.0, 510.0, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3],
        ),
        (
            "OPENCV_FISHEYE",
            vec![300.0, 305.0, 320.0, 240.0, 0.05, -0.01, 0.002, -0.0003],
        ),
        (
            "FULL_OPENCV",
            vec![
                500.0, 510.0, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3, 0.01, 0.0, 0.0, 0.0,
            ],
        ),
    ];
    for (model, params) in cases {
        let cam = ColmapCamera {
            id: 1,
            model: model.into(),
            width: 640,
            height: 480,
            params: params.clone(),
        };
        let intr = intrinsics(&cam, std::path::Path::new("cameras.txt")).unwrap();
        for (x, y) in [(0.1, -0.2), (-0.3, 0.25), (0.0, 0.0), (0.4, 0.3)] {
            // A point at OpenCV camera coordinates (x, y, 1) is (x, −y, −1) in OpenGL.
            let (px, _) = intr.project_gl(DVec3::new(x, -y, -1.0)).unwrap();
            let want = colmap_project(model, &params, x, y);
            assert!((px - want).length() < 1e-9, "{model}: {px} vs {want}");
        }
    }
    // Unsupported models and rational FULL_OPENCV terms are clear errors.
    let fov = ColmapCamera {
        id: 3,
        model: "FOV".into(),
        width: 10,
        height: 10,
        params: vec![1.0; 5],
    };
    let e = intrinsics(&fov, std::path::Path::new("cameras.bin"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cameras.bin") && e.contains("camera 3.model") && e.contains("FOV"),
        "{e}"
    );
    let mut p = vec![
        500.0, 510.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0,
    ];
    let full = ColmapCamera {
        id: 4,
        model: "FULL_OPENCV".into(),
        width: 10,
        height: 10,
        params: p.clone(),
    };
    assert!(intrinsics(&full, std::path::Path::new("c")).is_err());
    p.truncate(5);
    let short = ColmapCamera {
        id: 5,
        model: "OPENCV".into(),
        width: 10,
        height: 10,
        params: p,
    };
    assert!(
        intrinsics(&short, std::path::Path::new("c"))
            .unwrap_err()
            .to_string()
            .contains("takes 8 parameters")
    );
}

#[test]
fn nerfstudio_fisheye_and_per_frame_intrinsics() {
    let tmp = TempDir::new("ns-fisheye");
    std::fs::create_dir_all(tmp.join("images")).unwrap();
    for k in 0..2 {
        let (w, h) = if k == 0 { (16, 12) } else { (20, 10) };
        let img = assist_data::ImageF32 {
            width: w,
            height: h,
            channels: 3,
            data: vec![0.2; (w * h * 3) as usize],
        };
        assist_data::image_io::write_rgb_png(&tmp.join(format!("images/{k}.png")), &img).unwrap();
    }
    let json = serde_json::json!({
        "camera_model": "OPENCV_FISHEYE", "fl_x": 7.0, "fl_y": 7.5, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12,
        "k1": 0.05, "k2": -0.01, "k3": 0.001, "k4": 0.0,
        "frames": [
            {"file_path": "images/0.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},
            {"file_path": "images/1", "camera_model": "OPENCV", "fl_x": 9.0, "w": 20, "h": 10, "cx": 10.0, "cy": 5.0,
             "k1": -0.1, "k2": 0.0, "p1": 0.001, "p2": 0.0, "k3": 0.0,
             "transform_matrix": [[0,-1,0,1],[1,0,0,2],[0,0,1,3]]}
        ]
    });
    std::fs::write(tmp.join("transforms.json"), json.to_string()).unwrap();
    let ds = load(tmp.path(), &LoadOptions::default()).unwrap();
    let a = &ds.frames[0].camera.intrinsics;
    assert_eq!(
        a.distortion,
        Distortion::Fisheye {
            k1: 0.05,
            k2: -0.01,
            k3: 0.001,
            k4: 0.0
        }
    );
    assert_eq!((a.fx, a.fy), (7.0, 7.5));
    let b = &ds.frames[1].camera;
    // Per-frame values override key by key (fl_y stays the top-level one, as in
    // nerfstudio); a 3×4 matrix is completed; an extension-less path finds its .png.
    assert_eq!(
        (b.intrinsics.width, b.intrinsics.fx, b.intrinsics.fy),
        (20, 9.0, 7.5)
    );
    assert!(
        matches!(b.intrinsics.distortion, Distortion::OpenCv { k1, p1, .. } if k1 == -0.1 && p1 == 0.001)
    );
    assert!((b.pose.center() - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    assert!(ds.frames[1].image_path.ends_with("images/1.png"));
    let report = assist_data::validate::validate(&ds);
    assert!(report.errors.is_empty(), "{:?}", report.errors);
    // Photographs unless the file names its renderer (then training takes no
    // appearance codes by default).
    assert!(!ds.rendered);
    let mut rendered = json.clone();
    rendered["renderer"] = serde_json::json!("Blender Cycles");
    std::fs::write(tmp.join("transforms.json"), rendered.to_string()).unwrap();
    assert!(load(tmp.path(), &LoadOptions::default()).unwrap().rendered);
}
