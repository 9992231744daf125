//! COLMAP's model in the frame training expects: gravity along +Z (the cameras' mean up
//! taken as up: people hold phones upright), the origin at the cameras' mean centre, and
//! metres when the user names one known distance (`--scale-by`), else COLMAP's arbitrary
//! unit, said so. Cameras become nerfstudio's camera-to-world matrices (OpenGL axes: +X
//! right, +Y up, looking along −Z).

use std::path::Path;

use assist_core::{DMat3, DQuat, DVec3};
use assist_data::colmap::{ColmapImage, ColmapModel};

use crate::ProcessError;

/// One registered image: its file name and camera-to-world matrix (rows).
#[derive(Debug, Clone)]
pub struct Posed {
    pub name: String,
    pub c2w: [[f64; 4]; 4],
}

/// The capture in its new frame.
#[derive(Debug, Clone)]
pub struct Aligned {
    pub frames: Vec<Posed>,
    /// Sparse points and their colours.
    pub points: Vec<(DVec3, [u8; 3])>,
    /// Metres per unit: `Some(1.0)` when a known distance scaled the capture.
    pub meters_per_unit: Option<f64>,
}

/// One known distance: two pixels, each in a frame (index in capture order or file
/// name), and the metres between what they show.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleBy {
    pub a: (String, [f64; 2]),
    pub b: (String, [f64; 2]),
    pub meters: f64,
}

impl std::str::FromStr for ScaleBy {
    type Err = String;
    /// `"FRAME:x,y FRAME:x,y DISTANCE"`, the distance with its unit (m, cm, mm).
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split_whitespace().collect();
        let [a, b, d] = parts[..] else {
            return Err(format!(
                "expected \"FRAME:x,y FRAME:x,y DISTANCE\" (e.g. \"3:410,220 17:388,610 0.30m\"), got {s:?}"
            ));
        };
        let point = |p: &str| -> Result<(String, [f64; 2]), String> {
            let (frame, xy) = p
                .rsplit_once(':')
                .ok_or_else(|| format!("{p:?}: expected FRAME:x,y (a frame, then the pixel)"))?;
            let (x, y) = xy
                .split_once(',')
                .ok_or_else(|| format!("{p:?}: expected the pixel as x,y"))?;
            let num = |v: &str| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| format!("{p:?}: {v:?} is not a pixel coordinate"))
            };
            Ok((frame.to_string(), [num(x)?, num(y)?]))
        };
        let (value, unit) = d
            .find(|c: char| c.is_ascii_alphabetic())
            .map(|i| d.split_at(i))
            .ok_or_else(|| format!("{d:?}: give the distance with its unit (m, cm or mm)"))?;
        let factor = match unit {
            "m" => 1.0,
            "cm" => 0.01,
            "mm" => 0.001,
            _ => return Err(format!("{d:?}: unknown unit {unit:?} (m, cm or mm)")),
        };
        let meters = value
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| format!("{d:?}: expected a positive distance"))?
            * factor;
        Ok(ScaleBy {
            a: point(a)?,
            b: point(b)?,
            meters,
        })
    }
}

/// World-from-camera rotation (COLMAP's camera: +X right, +Y down, looking along +Z) and
/// centre of an image.
fn camera(image: &ColmapImage) -> (DMat3, DVec3) {
    let [w, x, y, z] = image.qvec;
    let cam_from_world = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
    let world_from_cam = cam_from_world.transpose();
    let centre = -(world_from_cam * DVec3::from_array(image.tvec));
    (world_from_cam, centre)
}

/// The model's registered images (by name) and points in the frame described in the
/// module docs; `scale` names one known distance.
pub fn align(
    model: &ColmapModel,
    scale: Option<&ScaleBy>,
    model_dir: &Path,
) -> Result<Aligned, ProcessError> {
    let mut images: Vec<&ColmapImage> = model.images.iter().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let cams: Vec<(DMat3, DVec3)> = images.iter().map(|i| camera(i)).collect();
    // Up: the mean of the cameras' up (−Y of COLMAP's camera).
    let up = cams
        .iter()
        .map(|(r, _)| -(r.y_axis))
        .sum::<DVec3>()
        .normalize_or(DVec3::Z);
    let turn = DQuat::from_rotation_arc(up, DVec3::Z);
    let centre = cams.iter().map(|(_, c)| *c).sum::<DVec3>() / cams.len().max(1) as f64;
    let s = match scale {
        Some(by) => {
            let a = known_point(model, &images, &by.a, model_dir)?;
            let b = known_point(model, &images, &by.b, model_dir)?;
            let d = a.distance(b);
            if d < 1e-9 {
                return Err(ProcessError::ScaleBy(
                    "both pixels show the same COLMAP point; pick two ends of the distance".into(),
                ));
            }
            by.meters / d
        }
        None => 1.0,
    };
    let place = |p: DVec3| turn * (p - centre) * s;
    let frames = images
        .iter()
        .zip(&cams)
        .map(|(img, (r, c))| {
            // OpenGL camera axes in the world: x, −y, −z of COLMAP's.
            let axes = [r.x_axis, -r.y_axis, -r.z_axis].map(|a| turn * a);
            let t = place(*c);
            let row = |k: usize| [axes[0][k], axes[1][k], axes[2][k], t[k]];
            Posed {
                name: img.name.clone(),
                c2w: [row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]],
            }
        })
        .collect();
    let mut ids: Vec<&u64> = model.points.keys().collect();
    ids.sort();
    let points = ids
        .into_iter()
        .map(|id| {
            let p = &model.points[id];
            (place(p.xyz), p.rgb)
        })
        .collect();
    Ok(Aligned {
        frames,
        points,
        meters_per_unit: scale.map(|_| 1.0),
    })
}

/// The COLMAP point seen nearest a pixel of a frame (within 8 pixels).
fn known_point(
    model: &ColmapModel,
    images: &[&ColmapImage],
    (frame, px): &(String, [f64; 2]),
    model_dir: &Path,
) -> Result<DVec3, ProcessError> {
    let image = images
        .iter()
        .find(|i| {
            i.name == *frame || Path::new(&i.name).file_stem().and_then(|s| s.to_str()) == Some(frame)
        })
        .or_else(|| frame.parse::<usize>().ok().and_then(|k| images.get(k)))
        .ok_or_else(|| {
            ProcessError::ScaleBy(format!(
                "no registered frame {frame:?} (a frame's index from 0 to {} in name order, or its file name)",
                images.len().saturating_sub(1)
            ))
        })?;
    let at = assist_core::DVec2::from_array(*px);
    let nearest = image
        .points2d
        .iter()
        .filter(|(_, id)| *id >= 0 && model.points.contains_key(&(*id as u64)))
        .min_by(|a, b| a.0.distance(at).total_cmp(&b.0.distance(at)));
    match nearest {
        Some((q, id)) if q.distance(at) <= 8.0 => Ok(model.points[&(*id as u64)].xyz),
        Some((q, _)) => Err(ProcessError::ScaleBy(format!(
            "no COLMAP point within 8 pixels of ({}, {}) in {}: the nearest is at ({:.0}, {:.0}); pick a textured spot (the points are in {})",
            px[0],
            px[1],
            image.name,
            q.x,
            q.y,
            model_dir.display()
        ))),
        None => Err(ProcessError::ScaleBy(format!(
            "{} has no COLMAP points",
            image.name
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_distance_parses_with_its_unit() {
        let s: ScaleBy = "3:410,220 frame_0017.jpg:388.5,610 30cm".parse().unwrap();
        assert_eq!(s.a, ("3".into(), [410.0, 220.0]));
        assert_eq!(s.b, ("frame_0017.jpg".into(), [388.5, 610.0]));
        assert!((s.meters - 0.3).abs() < 1e-12);
        for bad in [
            "3:1,2 4:5,6",
            "3:1,2 4:5,6 30",
            "3:1,2 4:5,6 1ft",
            "3:1 4:5,6 1m",
            "3:1,2 4:5,6 -1m",
        ] {
            assert!(bad.parse::<ScaleBy>().is_err(), "{bad}");
        }
    }

    /// Cameras on a ring looking inward, all tilted the same way: after alignment their
    /// mean up is +Z, their mean centre the origin, and a known distance sets metres.
    #[test]
    fn cameras_come_out_upright_centred_and_scaled() {
        let tilt = DQuat::from_rotation_x(0.4) * DQuat::from_rotation_y(-0.3);
        let mut model = ColmapModel::default();
        for k in 0..8 {
            let a = k as f64 * std::f64::consts::TAU / 8.0;
            // A camera at (3cos a, 3 sin a, 1) looking at the origin, "up" = +Z, in a
            // world turned by `tilt` and shifted.
            let c = DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 1.0);
            let fwd = (-c).normalize();
            let right = fwd.cross(DVec3::Z).normalize();
            let down = fwd.cross(right);
            let world_from_cam = DMat3::from_cols(right, down, fwd);
            let wfc = DMat3::from_quat(tilt) * world_from_cam;
            let centre = tilt * c + DVec3::new(5.0, -2.0, 7.0);
            let cfw = wfc.transpose();
            let q = DQuat::from_mat3(&cfw);
            let t = -(cfw * centre);
            model.images.push(ColmapImage {
                id: k + 1,
                qvec: [q.w, q.x, q.y, q.z],
                tvec: t.to_array(),
                camera_id: 1,
                name: format!("f{k}.jpg"),
                points2d: vec![],
            });
        }
        let out = align(&model, None, Path::new("m")).unwrap();
        let mean: DVec3 = out
            .frames
            .iter()
            .map(|f| DVec3::new(f.c2w[0][3], f.c2w[1][3], f.c2w[2][3]))
            .sum::<DVec3>()
            / 8.0;
        assert!(mean.length() < 1e-9, "{mean}");
        for f in &out.frames {
            // The camera's +Y (up) column has no sideways tilt: its x, y parts vanish
            // against the horizontal ring, and all centres lie at one height.
            let up = DVec3::new(f.c2w[0][1], f.c2w[1][1], f.c2w[2][1]);
            assert!(up.z > 0.9, "{up}");
            assert!(f.c2w[2][3].abs() < 1e-9);
            // Looking along −Z of the camera: towards the ring's axis.
            let look = -DVec3::new(f.c2w[0][2], f.c2w[1][2], f.c2w[2][2]);
            let c = DVec3::new(f.c2w[0][3], f.c2w[1][3], 0.0);
            assert!(look.dot(-c.normalize()) > 0.9);
            assert!((c.length() - 3.0).abs() < 1e-9);
        }
        assert_eq!(out.meters_per_unit, None);
    }
}
