//! Simulator model files for exported node meshes: MuJoCo MJCF (one body per object with a
//! free joint, the background as static geometry) and URDF (one file per object — a single
//! link, as PyBullet's `loadURDF` and Isaac's importer take objects — and `scene.urdf`, a
//! static snapshot with every object fixed at its pose). Meshes are referenced in the
//! nodes' frames and placed at the nodes' poses; lengths are in metres (mesh files stay in
//! world units, scaled by `meters_per_unit` in the model); masses and inertias come from
//! the closed meshes at a given density (kg/m³).

use std::fmt::Write as _;

use assist_core::glam::EulerRot;
use assist_core::{DQuat, DVec3};

use crate::MassProperties;
use crate::pad::Pad;

/// One body of a model: a mesh file (OBJ, node frame, world units) at a pose.
#[derive(Debug, Clone)]
pub struct Body {
    /// A name of letters, digits and `_` ([`crate::write::obj_name`]).
    pub name: String,
    /// The mesh file, relative to the model file.
    pub mesh_file: String,
    /// Pose of the node frame in the world: translation in world units.
    pub translation: DVec3,
    pub rotation: DQuat,
    /// Mass properties in the node frame, metres and kilograms (`None`: no closed mesh).
    pub mass: Option<MassProperties>,
    /// Mean colour of the mesh.
    pub rgb: [f32; 3],
    /// The background: static, no joint.
    pub fixed: bool,
    /// A thin box under a flat base, in the node frame (world units), so that the
    /// object rests on several contacts ([`crate::pad`]).
    pub pad: Option<Pad>,
}

/// A static slab an object rests on: its top at `level` along the scene's up (world
/// units), covering `lo`..`hi` along the two horizontal axes of [`horizontal_axes`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Support {
    pub level: f64,
    pub lo: [f64; 2],
    pub hi: [f64; 2],
}

/// Two unit axes across `up` (the images of x and y under the turn that takes z to up).
pub fn horizontal_axes(up: DVec3) -> [DVec3; 2] {
    let q = DQuat::from_rotation_arc(DVec3::Z, up.normalize_or(DVec3::Z));
    [q * DVec3::X, q * DVec3::Y]
}

/// The slabs objects resting at `bases` stand on: each base is a level and a footprint
/// (world units, along [`horizontal_axes`]); bases within `tolerance` of each other share
/// one slab, its top at the highest of them (the others start at most `tolerance` above
/// it, never inside it), grown by `margin` around the footprints.
pub fn supports(bases: &[Support], tolerance: f64, margin: f64) -> Vec<Support> {
    let mut sorted: Vec<Support> = bases.to_vec();
    sorted.sort_by(|a, b| a.level.total_cmp(&b.level));
    let mut out: Vec<Support> = Vec::new();
    let mut first_level = f64::NEG_INFINITY;
    for b in sorted {
        match out.last_mut() {
            Some(s) if b.level - first_level <= tolerance => {
                s.level = s.level.max(b.level);
                for a in 0..2 {
                    s.lo[a] = s.lo[a].min(b.lo[a] - margin);
                    s.hi[a] = s.hi[a].max(b.hi[a] + margin);
                }
            }
            _ => {
                first_level = b.level;
                out.push(Support {
                    level: b.level,
                    lo: b.lo.map(|v| v - margin),
                    hi: b.hi.map(|v| v + margin),
                });
            }
        }
    }
    out
}

/// A number for a model file: six decimals, trailing zeros cut; below 0.001 in scientific
/// notation with seven significant digits (a small object's inertia is ~1e-5 kg·m²).
fn f(v: f64) -> String {
    if v != 0.0 && v.abs() < 1e-3 {
        return format!("{v:.6e}");
    }
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

fn vec3(v: [f64; 3]) -> String {
    format!("{} {} {}", f(v[0]), f(v[1]), f(v[2]))
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Half a base pad's thickness, metres.
const PAD_HALF_THICK_M: f64 = crate::pad::THICKNESS_M / 2.0;

/// A MuJoCo model of `bodies` (`up`: the scene's up, for gravity).
pub fn mjcf(
    model: &str,
    bodies: &[Body],
    meters_per_unit: f64,
    up: DVec3,
    supports: &[Support],
) -> String {
    let m = meters_per_unit;
    let g = -up.normalize_or(DVec3::Z) * 9.81;
    let mut s = format!(
        "<mujoco model=\"{}\">\n  <!-- written by assist export: meshes in node frames, lengths in metres -->\n  \
         <compiler angle=\"radian\" meshdir=\".\"/>\n  <option gravity=\"{}\"/>\n  <asset>\n",
        xml_escape(model),
        vec3(g.to_array())
    );
    for b in bodies {
        let _ = writeln!(
            s,
            "    <mesh name=\"{}\" file=\"{}\" scale=\"{}\"/>",
            b.name,
            xml_escape(&b.mesh_file),
            vec3([m; 3])
        );
    }
    s += "  </asset>\n  <worldbody>\n";
    // What the objects rest on: static slabs 2 cm thick, their tops at the supports.
    let up_n = up.normalize_or(DVec3::Z);
    let [e1, e2] = horizontal_axes(up_n);
    let q = DQuat::from_rotation_arc(DVec3::Z, up_n);
    for (k, sp) in supports.iter().enumerate() {
        let half_thick = 0.01;
        let mid = [0, 1].map(|a| (sp.lo[a] + sp.hi[a]) / 2.0);
        let centre = (e1 * mid[0] + e2 * mid[1] + up_n * sp.level) * m - up_n * half_thick;
        let size = [
            (sp.hi[0] - sp.lo[0]) * m / 2.0,
            (sp.hi[1] - sp.lo[1]) * m / 2.0,
            half_thick,
        ];
        let _ = writeln!(
            s,
            "    <geom name=\"support_{k}\" type=\"box\" pos=\"{}\" quat=\"{} {} {} {}\" size=\"{}\" rgba=\"0.5 0.5 0.5 0.4\"/>",
            vec3(centre.to_array()),
            f(q.w),
            f(q.x),
            f(q.y),
            f(q.z),
            vec3(size)
        );
    }
    for b in bodies {
        let pos = vec3((b.translation * m).to_array());
        let q = b.rotation;
        let quat = format!("{} {} {} {}", f(q.w), f(q.x), f(q.y), f(q.z));
        let rgba = format!(
            "{} {} {} 1",
            f(b.rgb[0] as f64),
            f(b.rgb[1] as f64),
            f(b.rgb[2] as f64)
        );
        if b.fixed {
            // The room is drawn, not collided with: MuJoCo would take its convex hull, with
            // the objects inside it. The supports carry them.
            let _ = writeln!(
                s,
                "    <geom name=\"{n}\" type=\"mesh\" mesh=\"{n}\" pos=\"{pos}\" quat=\"{quat}\" rgba=\"{rgba}\" contype=\"0\" conaffinity=\"0\"/>",
                n = b.name
            );
            continue;
        }
        let _ = writeln!(
            s,
            "    <body name=\"{}\" pos=\"{pos}\" quat=\"{quat}\">",
            b.name
        );
        s += "      <freejoint/>\n";
        if let Some(mp) = &b.mass {
            let i = mp.inertia;
            let _ = writeln!(
                s,
                "      <inertial pos=\"{}\" mass=\"{}\" fullinertia=\"{} {} {} {} {} {}\"/>",
                vec3(mp.center),
                f(mp.mass),
                f(i[0][0]),
                f(i[1][1]),
                f(i[2][2]),
                f(i[0][1]),
                f(i[0][2]),
                f(i[1][2])
            );
        }
        let _ = writeln!(
            s,
            "      <geom type=\"mesh\" mesh=\"{}\" rgba=\"{rgba}\"/>",
            b.name
        );
        if let Some(p) = &b.pad {
            // Drawn in group 3 (hidden by MuJoCo's viewer): it sits inside the mesh.
            let centre = p.base * m + p.rotation * DVec3::Z * PAD_HALF_THICK_M;
            let q = p.rotation;
            let _ = writeln!(
                s,
                "      <geom name=\"{}_pad\" type=\"box\" pos=\"{}\" quat=\"{} {} {} {}\" size=\"{}\" group=\"3\" rgba=\"{rgba}\"/>",
                b.name,
                vec3(centre.to_array()),
                f(q.w),
                f(q.x),
                f(q.y),
                f(q.z),
                vec3([p.half[0] * m, p.half[1] * m, PAD_HALF_THICK_M])
            );
        }
        s += "    </body>\n";
    }
    s += "  </worldbody>\n</mujoco>\n";
    s
}

/// URDF `xyz` and `rpy` (roll about x, then pitch about y, then yaw about z, fixed axes).
fn origin(translation: DVec3, rotation: DQuat) -> String {
    let (yaw, pitch, roll) = rotation.to_euler(EulerRot::ZYX);
    format!(
        "<origin xyz=\"{}\" rpy=\"{}\"/>",
        vec3(translation.to_array()),
        vec3([roll, pitch, yaw])
    )
}

fn link(b: &Body, m: f64, indent: &str) -> String {
    let mut s = format!("{indent}<link name=\"{}\">\n", b.name);
    if let Some(mp) = &b.mass {
        let i = mp.inertia;
        let _ = write!(
            s,
            "{indent}  <inertial>\n{indent}    <origin xyz=\"{}\" rpy=\"0 0 0\"/>\n{indent}    <mass value=\"{}\"/>\n\
             {indent}    <inertia ixx=\"{}\" ixy=\"{}\" ixz=\"{}\" iyy=\"{}\" iyz=\"{}\" izz=\"{}\"/>\n{indent}  </inertial>\n",
            vec3(mp.center),
            f(mp.mass),
            f(i[0][0]),
            f(i[0][1]),
            f(i[0][2]),
            f(i[1][1]),
            f(i[1][2]),
            f(i[2][2])
        );
    }
    let geom = format!(
        "<geometry><mesh filename=\"{}\" scale=\"{}\"/></geometry>",
        xml_escape(&b.mesh_file),
        vec3([m; 3])
    );
    let _ = write!(
        s,
        "{indent}  <visual>{geom}<material name=\"{}_colour\"><color rgba=\"{} {} {} 1\"/></material></visual>\n\
         {indent}  <collision>{geom}</collision>\n{indent}</link>\n",
        b.name,
        f(b.rgb[0] as f64),
        f(b.rgb[1] as f64),
        f(b.rgb[2] as f64)
    );
    s
}

/// One object as a URDF of a single link in its node frame (place it at its pose when
/// loading: the pose is in `export.json`).
pub fn urdf_object(b: &Body, meters_per_unit: f64) -> String {
    format!(
        "<?xml version=\"1.0\"?>\n<robot name=\"{}\">\n{}</robot>\n",
        b.name,
        link(b, meters_per_unit, "  ")
    )
}

/// The whole scene as one URDF: a `world` link (the background's, when exported) and every
/// object fixed to it at its pose.
pub fn urdf_scene(model: &str, bodies: &[Body], meters_per_unit: f64) -> String {
    let m = meters_per_unit;
    let mut s = format!(
        "<?xml version=\"1.0\"?>\n<!-- written by assist export: a static snapshot (objects fixed at their poses); \
         each object is also its own URDF -->\n<robot name=\"{}\">\n  <link name=\"world\"/>\n",
        xml_escape(model)
    );
    for b in bodies {
        s += &link(b, m, "  ");
        let _ = writeln!(
            s,
            "  <joint name=\"{n}_joint\" type=\"fixed\">\n    <parent link=\"world\"/>\n    <child link=\"{n}\"/>\n    {}\n  </joint>",
            origin(b.translation * m, b.rotation),
            n = b.name
        );
    }
    s += "</robot>\n";
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(fixed: bool) -> Body {
        Body {
            name: "node_2_mug".into(),
            mesh_file: "node_2_mug.obj".into(),
            translation: DVec3::new(1.0, 2.0, 0.5),
            rotation: DQuat::from_rotation_z(0.3),
            mass: Some(MassProperties {
                volume: 1e-4,
                mass: 0.1,
                center: [0.0, 0.0, 0.01],
                inertia: [[1e-4, 0.0, 0.0], [0.0, 2e-4, 0.0], [0.0, 0.0, 3e-4]],
            }),
            rgb: [0.5, 0.25, 1.0],
            fixed,
            pad: None,
        }
    }

    #[test]
    fn urdf_angles_rebuild_the_rotation() {
        let q = DQuat::from_euler(EulerRot::ZYX, 0.4, -0.2, 1.1);
        let (yaw, pitch, roll) = q.to_euler(EulerRot::ZYX);
        let r = DQuat::from_rotation_z(yaw)
            * DQuat::from_rotation_y(pitch)
            * DQuat::from_rotation_x(roll);
        assert!(r.angle_between(q) < 1e-9);
        let s = origin(DVec3::ZERO, q);
        assert!(s.contains("rpy=\"1.1 -0.2 0.4\""), "{s}");
    }

    #[test]
    fn models_scale_lengths_to_metres_and_carry_inertia() {
        let s = mjcf("desk", &[body(false), body(true)], 0.5, DVec3::Z, &[]);
        assert!(s.contains("pos=\"0.5 1 0.25\""), "{s}");
        assert!(s.contains("scale=\"0.5 0.5 0.5\""));
        assert!(s.contains("<freejoint/>"));
        assert!(
            s.contains("fullinertia=\"1.000000e-4 2.000000e-4 3.000000e-4 0 0 0\""),
            "{s}"
        );
        assert!(s.contains("gravity=\"0 0 -9.81\""));
        // A pad goes in its body, 2 mm thick in metres, its bottom on the base.
        let padded = Body {
            pad: Some(Pad {
                base: DVec3::new(0.0, 0.0, -0.02),
                rotation: DQuat::IDENTITY,
                half: [0.01, 0.02],
            }),
            ..body(false)
        };
        let s = mjcf("desk", &[padded], 0.5, DVec3::Z, &[]);
        assert!(
            s.contains("type=\"box\" pos=\"0 0 -0.009\" quat=\"1 0 0 0\" size=\"0.005 0.01 0.001\" group=\"3\""),
            "{s}"
        );
        assert!(s.find("_pad\"").unwrap() < s.find("</body>").unwrap());
        let u = urdf_scene("desk", &[body(false)], 0.5);
        assert!(u.contains("<mass value=\"0.1\"/>"));
        assert!(u.contains("xyz=\"0.5 1 0.25\""), "{u}");
        assert!(urdf_object(&body(false), 1.0).contains("<robot name=\"node_2_mug\">"));
    }
}
