//! Geometry proven on real data: COLMAP reprojection, depth reprojection between views,
//! and the Blender and nerfstudio readers agreeing on rays.

use assist_core::{DVec2, DVec3};
use assist_data::colmap::{intrinsics, read_model};
use assist_data::consistency::reproject;
use assist_data::{LoadOptions, load};
use assist_testkit::{TempDir, median, shared_dataset};

/// Projects every observed 3D point with the loaded cameras. Two checks: (1) for every
/// point, our mean reprojection error over its track equals the error COLMAP itself stored
/// in points3D.bin (to 1e-6 px) — our camera model and pose conversion are COLMAP's; (2)
/// the median error over all observations is the data's own residual. COLMAP's stored
/// residuals on beer have a median of 0.62 px, so the median cannot be below 0.5 px with
/// correct geometry; we bound it at 0.7 px and require an unbiased mean residual.
#[test]
fn colmap_points_reproject_onto_observations_beer() {
    let Some(dir) = shared_dataset("colmap_points_reproject_onto_observations_beer", "beer") else {
        return;
    };
    let model_dir = dir.join("sparse/0");
    let model = read_model(&model_dir, true).unwrap();
    let ds = load(&dir, &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 71);
    let mut errors = Vec::new();
    let mut mean_residual = DVec2::ZERO;
    let mut per_point: std::collections::HashMap<u64, (f64, usize)> = Default::default();
    for im in &model.images {
        let cam = model.cameras[&im.camera_id].clone();
        let intr = intrinsics(&cam, &model_dir.join("cameras.bin")).unwrap();
        let pose = assist_core::Pose::from_colmap(im.qvec, im.tvec, "t").unwrap();
        let camera = assist_core::Camera {
            intrinsics: intr,
            pose,
        };
        // The loaded dataset's frame for this image has the same camera.
        let frame = ds
            .frames
            .iter()
            .find(|f| f.image_path.ends_with(&im.name))
            .unwrap();
        assert_eq!(frame.camera.intrinsics, camera.intrinsics);
        for (xy, pid) in &im.points2d {
            if *pid < 0 {
                continue;
            }
            let p = model.points[&(*pid as u64)].xyz;
            let (px, _) = frame
                .camera
                .project(p)
                .expect("observed point in front of its camera");
            let e = (px - *xy).length();
            errors.push(e);
            mean_residual += px - *xy;
            let acc = per_point.entry(*pid as u64).or_default();
            acc.0 += e;
            acc.1 += 1;
        }
    }
    assert!(
        errors.len() > 1000,
        "too few observations: {}",
        errors.len()
    );
    let n = errors.len();
    mean_residual /= n as f64;
    let med = median(&mut errors);
    let worst_vs_colmap = per_point
        .iter()
        .map(|(id, (sum, k))| (sum / *k as f64 - model.points[id].error).abs())
        .fold(0.0f64, f64::max);
    eprintln!(
        "beer: {n} observations, median reprojection error {med:.3} px, mean residual {:.2e} px, max |ours − COLMAP's stored| {worst_vs_colmap:.2e} px",
        mean_residual.length()
    );
    assert!(
        worst_vs_colmap < 1e-6,
        "per-point error differs from COLMAP's by {worst_vs_colmap} px"
    );
    assert!(
        mean_residual.length() < 0.01,
        "biased residual {mean_residual}"
    );
    assert!(med < 0.7, "median reprojection error {med} px");
}

/// Threshold: median |ΔRGB| below 4/255 over depth-consistent pixels, with at least 80%
/// of the projected pixels depth-consistent; the flipped-axes control must fail.
#[test]
fn desk_depth_reprojects_with_matching_colour() {
    let Some(dir) = shared_dataset("desk_depth_reprojects_with_matching_colour", "desk") else {
        return;
    };
    let ds = load(&dir, &LoadOptions::default()).unwrap();
    for (a, b) in [(0, 21), (20, 41), (60, 81), (100, 113)] {
        let r = reproject(&ds, a, b, 3, None).unwrap();
        let (frac, med) = (r.consistent_fraction(), r.median_abs_rgb);
        eprintln!(
            "desk {a}->{b}: {r:?} depth-consistent {frac:.3} median |dRGB| {:.2}/255",
            med * 255.0
        );
        assert!(
            r.depth_consistent > 500 && frac > 0.8,
            "{a}->{b}: only {frac} consistent: {r:?}"
        );
        assert!(
            med < 4.0 / 255.0,
            "{a}->{b}: median colour difference {}/255",
            med * 255.0
        );
        // Control: the wrong camera convention (OpenCV axes read as OpenGL) must fail.
        let mut wrong = ds.frames[b].camera;
        let rot =
            wrong.pose.rotation() * assist_core::DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
        wrong.pose =
            assist_core::Pose::from_rotation_translation(rot, wrong.pose.center(), "flip").unwrap();
        let c = reproject(&ds, a, b, 3, Some(wrong)).unwrap();
        assert!(
            c.consistent_fraction() < 0.2,
            "control with flipped axes should not be consistent: {c:?}"
        );
    }
}

#[test]
fn blender_and_nerfstudio_give_identical_rays() {
    let Some(dir) = shared_dataset("blender_and_nerfstudio_give_identical_rays", "lego_400") else {
        return;
    };
    let blender = load(&dir, &LoadOptions::default()).unwrap();
    // The same cameras written as a nerfstudio transforms.json with absolute image paths.
    let raw: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("transforms_train.json")).unwrap())
            .unwrap();
    let angle = raw["camera_angle_x"].as_f64().unwrap();
    let f = 0.5 * 400.0 / (0.5 * angle).tan();
    let frames: Vec<serde_json::Value> = raw["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|fr| {
            let rel = fr["file_path"].as_str().unwrap();
            serde_json::json!({
                "file_path": dir.join(format!("{rel}.png")).display().to_string(),
                "transform_matrix": fr["transform_matrix"],
            })
        })
        .collect();
    let tmp = TempDir::new("ns-rays");
    let ns = serde_json::json!({"camera_model": "PINHOLE", "fl_x": f, "fl_y": f, "cx": 200.0, "cy": 200.0, "w": 400, "h": 400, "frames": frames});
    std::fs::write(
        tmp.join("transforms.json"),
        serde_json::to_string(&ns).unwrap(),
    )
    .unwrap();
    let nerfstudio = load(tmp.path(), &LoadOptions::default()).unwrap();
    let train: Vec<_> = blender.frames_in(assist_data::Split::Train).collect();
    assert_eq!(train.len(), nerfstudio.frames.len());
    let mut worst = 0.0f64;
    for (a, b) in train.iter().zip(&nerfstudio.frames) {
        for (i, j) in [
            (0, 0),
            (399, 0),
            (0, 399),
            (399, 399),
            (123, 271),
            (200, 200),
        ] {
            let ra = a.camera.pixel_ray(i, j).unwrap();
            let rb = b.camera.pixel_ray(i, j).unwrap();
            worst = worst
                .max((ra.origin - rb.origin).length())
                .max((ra.dir - rb.dir).length());
        }
    }
    assert!(worst < 1e-12, "rays differ by {worst}");
}

#[test]
fn llff_fern_poses_and_factor() {
    let Some(dir) = shared_dataset("llff_fern_poses_and_factor", "fern") else {
        return;
    };
    let ds = load(&dir, &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 20);
    let c = &ds.frames[0].camera;
    assert_eq!((c.width(), c.height()), (504, 378));
    // Forward-facing capture: every camera looks roughly the same way, at the scene (the
    // near-plane centre of each camera lies in front of all the others).
    let f0 = ds.frames[0].camera.pose.forward();
    for f in &ds.frames {
        assert!(f.camera.pose.forward().dot(f0) > 0.9);
    }
    // The sparse points of fern's COLMAP model project inside the images at positive depth.
    let pts = assist_data::colmap_bin::read_points(&dir.join("sparse/0/points3D.bin")).unwrap();
    let mut inside = 0;
    for p in pts.values() {
        if let Some((px, _)) = c.project(p.xyz)
            && px.x >= 0.0
            && px.y >= 0.0
            && px.x < 504.0
            && px.y < 378.0
        {
            inside += 1;
        }
    }
    let frac = inside as f64 / pts.len() as f64;
    eprintln!("fern: {frac:.3} of sparse points project into view 0");
    assert!(frac > 0.8, "{frac}");
    let _ = DVec2::ZERO;
}

/// LLFF and COLMAP state no up; the readers take it from how the cameras were held
/// (`assist_core::cameras_up`). On gold_cape (a
/// walk around an object) it is checked against geometry it was not computed from: the
/// camera centres lie near one level plane (the walk), whose normal must be up. On the
/// forward-facing captures every camera's up is within 45° of it, and beer's COLMAP model
/// gives the same up as its LLFF file (one frame).
#[test]
fn captures_without_a_stated_up_take_it_from_how_the_cameras_were_held() {
    let Some(gold) = shared_dataset("captures_without_a_stated_up", "gold_cape") else {
        return;
    };
    let ds = load(&gold, &LoadOptions::default()).unwrap();
    let up = ds.world_up.expect("an up for gold_cape");
    let centres: Vec<DVec3> = ds.frames.iter().map(|f| f.camera.pose.center()).collect();
    let mean = centres.iter().sum::<DVec3>() / centres.len() as f64;
    let mut cov = assist_core::DMat3::ZERO;
    for c in &centres {
        let d = *c - mean;
        cov += assist_core::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    // The plane's normal: the covariance's weakest direction.
    let n = assist_core::up::symmetric_eigen(cov).1[2];
    let angle = n.dot(up).abs().clamp(-1.0, 1.0).acos().to_degrees();
    eprintln!("gold_cape up {up:.3}, the walk's plane normal {n:.3}: {angle:.1}° apart");
    assert!(angle < 10.0, "{angle}°");

    for name in ["fern", "beer"] {
        let Some(dir) = shared_dataset("captures_without_a_stated_up", name) else {
            return;
        };
        let ds = load(&dir, &LoadOptions::default()).unwrap();
        let up = ds.world_up.expect("an up");
        let worst = ds
            .frames
            .iter()
            .map(|f| f.camera.pose.rotation().y_axis.dot(up))
            .fold(1.0, f64::min);
        eprintln!("{name}: up {up:.3}, least agreeing camera {worst:.3}");
        assert!(worst > 45f64.to_radians().cos(), "{name}: {worst}");
        if name == "beer" {
            let colmap = assist_data::colmap::load_dataset(
                &dir.join("sparse/0"),
                assist_data::Format::ColmapBinary,
            )
            .unwrap();
            let other = colmap.world_up.expect("an up from COLMAP");
            assert!(other.dot(up) > 0.9999, "{other} vs {up}");
            // The can stands upright on the floor: the principal axis of the sparse
            // points on it (within 1.5 units of its middle, in the files' own frame) is
            // gravity. The cameras look down at it from one side, so their mean up leant
            // 19° from that axis.
            let middle = DVec3::new(2.44, 2.2, 3.18);
            let can: Vec<DVec3> = colmap
                .points
                .iter()
                .copied()
                .filter(|p| p.distance(middle) < 1.5)
                .collect();
            assert!(can.len() > 1000, "{} points on the can", can.len());
            let mean = can.iter().sum::<DVec3>() / can.len() as f64;
            let mut cov = assist_core::DMat3::ZERO;
            for p in &can {
                let d = *p - mean;
                cov += assist_core::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            }
            let axis = assist_core::up::symmetric_eigen(cov).1[0];
            let lean = axis.dot(up).abs().min(1.0).acos().to_degrees();
            eprintln!("beer: the can's axis is {lean:.1}° from up");
            assert!(lean < 8.0, "the can leans {lean}° from up");
        }
    }
}
