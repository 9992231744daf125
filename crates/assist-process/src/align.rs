//! COLMAP's model in the frame training expects: gravity along +Z (perpendicular to the
//! cameras' right axes: people hold phones level; `assist_core::cameras_up`), the origin at the cameras' mean centre, and
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
    /// The two points `--scale-by` found under its pixels, in the new frame (so the
    /// user, and the tests, can see what was measured): `meters` apart.
    pub known: Option<[DVec3; 2]>,
    /// What the user should know about the result (a `--scale-by` pixel near a frame's
    /// border).
    pub warnings: Vec<String>,
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
        Ok(ScaleBy {
            a: point(a)?,
            b: point(b)?,
            meters: parse_distance(d)?,
        })
    }
}

/// A positive distance with its unit (`"0.30m"`, `"16cm"`, `"85mm"`) in metres.
pub fn parse_distance(d: &str) -> Result<f64, String> {
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
    Ok(value
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0 && *v < 1e6)
        .ok_or_else(|| format!("{d:?}: expected a positive distance"))?
        * factor)
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
    // Up: perpendicular to the cameras' right axes (+X of COLMAP's camera), on the side
    // of their up (−Y), as every reader takes a capture's up (`assist_core::cameras_up`).
    let up = assist_core::cameras_up(cams.iter().map(|(r, _)| (r.x_axis, -r.y_axis)))
        .unwrap_or_else(|| {
            cams.iter()
                .map(|(r, _)| -(r.y_axis))
                .sum::<DVec3>()
                .normalize_or(DVec3::Z)
        });
    let turn = DQuat::from_rotation_arc(up, DVec3::Z);
    let centre = cams.iter().map(|(_, c)| *c).sum::<DVec3>() / cams.len().max(1) as f64;
    let mut warnings = Vec::new();
    let (s, known) = match scale {
        Some(by) => {
            let a = known_point(model, &images, &by.a, model_dir, &mut warnings)?;
            let b = known_point(model, &images, &by.b, model_dir, &mut warnings)?;
            let d = a.distance(b);
            if d < 1e-9 {
                return Err(ProcessError::ScaleBy(
                    "both pixels show the same COLMAP point; pick two ends of the distance".into(),
                ));
            }
            (by.meters / d, Some([a, b]))
        }
        None => (1.0, None),
    };
    let place = |p: DVec3| turn * (p - centre) * s;
    let known = known.map(|k| k.map(place));
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
        known,
        warnings,
    })
}

/// Pixels within which a COLMAP point is the point under a pixel.
const SNAP_PX: f64 = 8.0;
/// Pixels around a pixel whose COLMAP points place it when none is within [`SNAP_PX`].
const NEAR_PX: f64 = 40.0;

/// The 3D point under a pixel of a frame: the COLMAP point seen there (within
/// [`SNAP_PX`]) unless it is a lone outlier in depth ([`shares_a_surface`]), else the
/// pixel's viewing ray at the median depth of the points seen within [`NEAR_PX`] (at least
/// three; the ray's direction interpolated from theirs, which carries the camera's
/// intrinsics and distortion). A rerun of COLMAP triangulates other
/// points, and a user's click rarely lands on one. A pixel near the frame's border adds
/// a warning to `warnings`.
fn known_point(
    model: &ColmapModel,
    images: &[&ColmapImage],
    (frame, px): &(String, [f64; 2]),
    model_dir: &Path,
    warnings: &mut Vec<String>,
) -> Result<DVec3, ProcessError> {
    let image = frame_named(images, frame)?;
    if let Some(cam) = model.cameras.get(&image.camera_id)
        && near_border(*px, cam.width, cam.height)
    {
        warnings.push(format!(
            "--scale-by: ({}, {}) in {} lies within {NEAR_PX} px of the frame's border, where COLMAP's points are fewer and less certain (such a pixel is placed less surely); one further inside measures the distance better",
            px[0], px[1], image.name
        ));
    }
    let at = assist_core::DVec2::from_array(*px);
    let mut seen: Vec<(assist_core::DVec2, DVec3)> = image
        .points2d
        .iter()
        .filter(|(_, id)| *id >= 0)
        .filter_map(|(q, id)| Some((*q, model.points.get(&(*id as u64))?.xyz)))
        .collect();
    seen.sort_by(|a, b| a.0.distance(at).total_cmp(&b.0.distance(at)));
    let Some(&(q, nearest)) = seen.first() else {
        return Err(ProcessError::ScaleBy(format!(
            "{} has no COLMAP points",
            image.name
        )));
    };
    let near: Vec<_> = seen
        .iter()
        .take_while(|(q, _)| q.distance(at) <= NEAR_PX)
        .copied()
        .collect();
    let (world_from_cam, centre) = camera(image);
    if q.distance(at) <= SNAP_PX && shares_a_surface(nearest, &near, world_from_cam, centre) {
        return Ok(nearest);
    }
    near_ray_point(&near, at, world_from_cam, centre).ok_or_else(|| {
        ProcessError::ScaleBy(format!(
            "no COLMAP point within {SNAP_PX} pixels of ({}, {}) in {}, and too few within {NEAR_PX} to place it: the nearest is at ({:.0}, {:.0}); pick a textured spot (the points are in {})",
            px[0],
            px[1],
            image.name,
            q.x,
            q.y,
            model_dir.display()
        ))
    })
}

/// Frame `frame` of `images` (in name order): its file name, its name without extension,
/// or its index.
fn frame_named<'a>(
    images: &[&'a ColmapImage],
    frame: &str,
) -> Result<&'a ColmapImage, ProcessError> {
    images
        .iter()
        .find(|i| {
            i.name == frame || Path::new(&i.name).file_stem().and_then(|s| s.to_str()) == Some(frame)
        })
        .or_else(|| frame.parse::<usize>().ok().and_then(|k| images.get(k)))
        .ok_or_else(|| {
            ProcessError::ScaleBy(format!(
                "no registered frame {frame:?} (a frame's index from 0 to {} in name order, or its file name)",
                images.len().saturating_sub(1)
            ))
        })
        .copied()
}

/// Whether pixel `px` lies within [`NEAR_PX`] of the border of a `width` × `height` frame,
/// where its neighbourhood is cut off.
fn near_border(px: [f64; 2], width: u32, height: u32) -> bool {
    let (w, h) = (width as f64, height as f64);
    px[0] < NEAR_PX || px[1] < NEAR_PX || px[0] > w - NEAR_PX || px[1] > h - NEAR_PX
}

/// Depth, as a share of a point's own, within which two points seen near one pixel lie on
/// one surface.
const SAME_SURFACE: f64 = 0.1;

/// Whether `point` lies on a surface that another of the points seen `near` it (the point
/// itself among them) shares, by depth from the camera at `centre`, or too few points are
/// near to judge. A lone point at another depth than all its neighbours is a
/// mistriangulated one (a wrong match far in front or behind), not what the user clicked;
/// one at a depth edge still shares its depth with its own side's points.
fn shares_a_surface(
    point: DVec3,
    near: &[(assist_core::DVec2, DVec3)],
    world_from_cam: DMat3,
    centre: DVec3,
) -> bool {
    let depth = |x: DVec3| (world_from_cam.transpose() * (x - centre)).z;
    let d = depth(point);
    let others: Vec<f64> = near
        .iter()
        .filter(|(_, x)| *x != point)
        .map(|(_, x)| depth(*x))
        .collect();
    others.len() < 2
        || others
            .iter()
            .any(|o| (o - d).abs() <= SAME_SURFACE * d.abs())
}

/// The point on pixel `at`'s viewing ray at the median depth of the points `near` (their
/// pixels and world positions): the ray's direction in the camera, as (x/z, y/z), is
/// fitted as an affine function of the pixel over them by least squares. None with fewer
/// than three points or when they lie on a line in the image.
fn near_ray_point(
    near: &[(assist_core::DVec2, DVec3)],
    at: assist_core::DVec2,
    world_from_cam: DMat3,
    centre: DVec3,
) -> Option<DVec3> {
    if near.len() < 3 {
        return None;
    }
    let cam_from_world = world_from_cam.transpose();
    let local: Vec<(assist_core::DVec2, DVec3)> = near
        .iter()
        .map(|(q, x)| (*q - at, cam_from_world * (*x - centre)))
        .filter(|(_, c)| c.z > 0.0)
        .collect();
    if local.len() < 3 {
        return None;
    }
    // Normal equations of [u v 1]·w = x/z (and y/z), pixels relative to `at`: the fitted
    // value at `at` is the constant term.
    let mut m = DMat3::ZERO;
    let (mut bx, mut by) = (DVec3::ZERO, DVec3::ZERO);
    for (d, c) in &local {
        let row = DVec3::new(d.x, d.y, 1.0);
        m += DMat3::from_cols(row * row.x, row * row.y, row * row.z);
        bx += row * (c.x / c.z);
        by += row * (c.y / c.z);
    }
    if m.determinant().abs() < 1e-9 * m.x_axis.x.max(1.0) * m.y_axis.y.max(1.0) {
        return None;
    }
    let inv = m.inverse();
    let (dx, dy) = ((inv * bx).z, (inv * by).z);
    let mut depths: Vec<f64> = local.iter().map(|(_, c)| c.z).collect();
    depths.sort_by(f64::total_cmp);
    let z = depths[depths.len() / 2];
    Some(centre + world_from_cam * DVec3::new(dx * z, dy * z, z))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel with no COLMAP point under it is placed on its ray at the depth of the
    /// points around it: exact for a pinhole camera facing a plane.
    #[test]
    fn a_pixel_between_points_lands_on_their_surface() {
        let (f, cx, cy) = (500.0, 320.0, 240.0);
        let world_from_cam = DMat3::from_quat(DQuat::from_rotation_y(0.3));
        let centre = DVec3::new(0.5, -0.2, 1.0);
        // Points of the plane z = 2 in front of the camera, seen at these pixels.
        let on_plane = |u: f64, v: f64| {
            let c = DVec3::new((u - cx) / f * 2.0, (v - cy) / f * 2.0, 2.0);
            centre + world_from_cam * c
        };
        let pixels = [
            (280.0, 200.0),
            (350.0, 210.0),
            (300.0, 270.0),
            (345.0, 262.0),
        ];
        let near: Vec<_> = pixels
            .iter()
            .map(|&(u, v)| (assist_core::DVec2::new(u, v), on_plane(u, v)))
            .collect();
        let at = assist_core::DVec2::new(321.0, 236.0);
        let p = near_ray_point(&near, at, world_from_cam, centre).unwrap();
        assert!(p.distance(on_plane(321.0, 236.0)) < 1e-9, "{p}");
        // Two points do not place it; nor do three on a line.
        assert!(near_ray_point(&near[..2], at, world_from_cam, centre).is_none());
        let line: Vec<_> = [(280.0, 200.0), (300.0, 220.0), (320.0, 240.0)]
            .iter()
            .map(|&(u, v)| (assist_core::DVec2::new(u, v), on_plane(u, v)))
            .collect();
        assert!(near_ray_point(&line, at, world_from_cam, centre).is_none());
    }

    /// A lone point far behind its neighbours (a wrong match) is not the point under a
    /// pixel; a point at a depth edge, on the near side with one neighbour of its own, is.
    #[test]
    fn a_lone_outlier_in_depth_is_not_snapped_to() {
        let world_from_cam = DMat3::from_quat(DQuat::from_rotation_x(-0.2));
        let centre = DVec3::new(0.1, 0.4, -0.3);
        let at_depth = |u: f64, v: f64, z: f64| {
            let px = assist_core::DVec2::new(u, v);
            (
                px,
                centre + world_from_cam * DVec3::new(u * 0.002 * z, v * 0.002 * z, z),
            )
        };
        let wall: Vec<_> = [(10.0, 5.0), (-12.0, 8.0), (4.0, -15.0), (-6.0, -9.0)]
            .iter()
            .map(|&(u, v)| at_depth(u, v, 2.0 + 0.01 * u))
            .collect();
        let outlier = at_depth(1.0, 1.0, 7.5).1;
        assert!(!shares_a_surface(outlier, &wall, world_from_cam, centre));
        for (_, x) in &wall {
            assert!(shares_a_surface(*x, &wall, world_from_cam, centre));
        }
        // The near side of an edge: one other point shares its depth.
        let mut edge = wall.clone();
        edge.push(at_depth(3.0, 3.0, 1.0));
        let corner = at_depth(2.0, 2.0, 1.02).1;
        assert!(shares_a_surface(corner, &edge, world_from_cam, centre));
        // Too few neighbours to judge: the point is taken.
        assert!(shares_a_surface(
            outlier,
            &wall[..1],
            world_from_cam,
            centre
        ));
    }

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
    /// up is +Z and their mean centre the origin; then a known distance sets metres.
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
        assert!(out.warnings.is_empty());

        // A known distance: points of a plane 2 units in front of frame f0 (a 640×480
        // pinhole camera), seen at pixels around each end. The two ends come out the given
        // metres apart, and a pixel near the border is warned about, one inside is not.
        let (f, cx, cy) = (500.0, 320.0, 240.0);
        model.cameras.insert(
            1,
            assist_data::colmap::ColmapCamera {
                id: 1,
                model: "PINHOLE".into(),
                width: 640,
                height: 480,
                params: vec![f, f, cx, cy],
            },
        );
        let (wfc, centre) = camera(&model.images[0]);
        let mut seen = vec![];
        for (k, (u, v)) in [(100.0, 100.0), (20.0, 300.0)]
            .iter()
            .flat_map(|&(u, v)| {
                [(0.0, 0.0), (12.0, 3.0), (-5.0, 14.0), (9.0, -11.0)]
                    .map(|(du, dv)| (u + du, v + dv))
            })
            .enumerate()
        {
            let x = centre + wfc * DVec3::new((u - cx) / f * 2.0, (v - cy) / f * 2.0, 2.0);
            model.points.insert(
                k as u64,
                assist_data::colmap::ColmapPoint {
                    id: k as u64,
                    xyz: x,
                    rgb: [0; 3],
                    error: 0.5,
                },
            );
            seen.push((assist_core::DVec2::new(u, v), k as i64));
        }
        model.images[0].points2d = seen;
        let by: ScaleBy = "f0.jpg:100,100 f0:20,300 0.5m".parse().unwrap();
        let out = align(&model, Some(&by), Path::new("m")).unwrap();
        let [a, b] = out.known.unwrap();
        assert!((a.distance(b) - 0.5).abs() < 1e-9, "{}", a.distance(b));
        assert_eq!(out.meters_per_unit, Some(1.0));
        assert_eq!(out.warnings.len(), 1, "{:?}", out.warnings);
        assert!(
            out.warnings[0].contains("(20, 300) in f0.jpg") && out.warnings[0].contains("border"),
            "{:?}",
            out.warnings
        );
    }
}
