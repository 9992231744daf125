//! The procedural tabletop scene: room, table, 3–6 primitive objects with procedural
//! textures and distinct colours, an area light, and inward-facing cameras.

use assist_core::{Aabb, Camera, DMat3, DVec3, Intrinsics, Obb, Pose, Rng};

/// World: Z-up, metres; the table top is the plane z = TABLE_Z.
pub const TABLE_Z: f64 = 0.75;
pub const TABLE_HALF: (f64, f64) = (0.75, 0.5);
pub const ROOM_HALF: f64 = 2.5;
pub const ROOM_HEIGHT: f64 = 2.6;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Half extents; the box rests on its base.
    Box {
        half: DVec3,
    },
    Sphere {
        r: f64,
    },
    Cylinder {
        r: f64,
        h: f64,
    },
    /// Base radius `r` at the bottom, apex at height `h`.
    Cone {
        r: f64,
        h: f64,
    },
}

impl Shape {
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Box { .. } => "box",
            Shape::Sphere { .. } => "ball",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Cone { .. } => "cone",
        }
    }
    /// Size of the tight box in the object's frame.
    pub fn size(&self) -> DVec3 {
        match *self {
            Shape::Box { half } => half * 2.0,
            Shape::Sphere { r } => DVec3::splat(2.0 * r),
            Shape::Cylinder { r, h } | Shape::Cone { r, h } => DVec3::new(2.0 * r, 2.0 * r, h),
        }
    }
    /// Radius of the circle around the footprint (for placement without overlap).
    pub fn footprint_radius(&self) -> f64 {
        let s = self.size();
        0.5 * (s.x * s.x + s.y * s.y).sqrt()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    Solid,
    Stripes,
    Checker,
    Dots,
}

impl Pattern {
    pub fn adjective(&self) -> &'static str {
        match self {
            Pattern::Solid => "",
            Pattern::Stripes => "striped ",
            Pattern::Checker => "checkered ",
            Pattern::Dots => "dotted ",
        }
    }
}

/// Named colours, far apart from each other and from the room's colours.
pub const PALETTE: &[(&str, [f64; 3])] = &[
    ("red", [0.80, 0.08, 0.07]),
    ("green", [0.10, 0.62, 0.15]),
    ("blue", [0.10, 0.22, 0.85]),
    ("yellow", [0.92, 0.80, 0.08]),
    ("purple", [0.50, 0.15, 0.70]),
    ("orange", [0.95, 0.45, 0.05]),
    ("cyan", [0.08, 0.70, 0.78]),
    ("pink", [0.95, 0.45, 0.65]),
];

#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    pub id: u16,
    pub label: String,
    pub shape: Shape,
    /// Centre of the object's base on the table.
    pub base: DVec3,
    /// Rotation about world +Z (radians).
    pub yaw: f64,
    pub pattern: Pattern,
    pub color: DVec3,
    pub color2: DVec3,
}

impl Object {
    pub fn rotation(&self) -> DMat3 {
        DMat3::from_rotation_z(self.yaw)
    }
    /// The tight oriented box in world coordinates.
    pub fn obb(&self) -> Obb {
        let s = self.shape.size();
        Obb::new(
            self.base + DVec3::new(0.0, 0.0, s.z * 0.5),
            s,
            self.rotation(),
        )
    }
}

/// An axis-aligned solid of the room (floor, walls, table…), with its material.
#[derive(Debug, Clone, Copy)]
pub struct Solid {
    pub aabb: Aabb,
    pub material: Material,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Material {
    Floor,
    Wall,
    Ceiling,
    TableTop,
    TableLeg,
    Cabinet,
}

#[derive(Debug, Clone, Copy)]
pub struct AreaLight {
    pub center: DVec3,
    pub half: f64,
    /// Radiant intensity scale (emits downward).
    pub power: f64,
}

#[derive(Debug, Clone)]
pub struct Scene {
    pub solids: Vec<Solid>,
    pub objects: Vec<Object>,
    pub light: AreaLight,
}

impl Scene {
    pub fn without(&self, id: u16) -> Scene {
        Scene {
            objects: self
                .objects
                .iter()
                .filter(|o| o.id != id)
                .cloned()
                .collect(),
            ..self.clone()
        }
    }
    pub fn without_objects(&self) -> Scene {
        Scene {
            objects: vec![],
            ..self.clone()
        }
    }
}

fn room() -> Vec<Solid> {
    let (r, h, t) = (ROOM_HALF, ROOM_HEIGHT, 0.1);
    let mut s = vec![
        Solid {
            aabb: Aabb::new(
                DVec3::new(-r - t, -r - t, -t),
                DVec3::new(r + t, r + t, 0.0),
            ),
            material: Material::Floor,
        },
        Solid {
            aabb: Aabb::new(
                DVec3::new(-r - t, -r - t, h),
                DVec3::new(r + t, r + t, h + t),
            ),
            material: Material::Ceiling,
        },
        Solid {
            aabb: Aabb::new(DVec3::new(-r - t, -r - t, 0.0), DVec3::new(-r, r + t, h)),
            material: Material::Wall,
        },
        Solid {
            aabb: Aabb::new(DVec3::new(r, -r - t, 0.0), DVec3::new(r + t, r + t, h)),
            material: Material::Wall,
        },
        Solid {
            aabb: Aabb::new(DVec3::new(-r, -r - t, 0.0), DVec3::new(r, -r, h)),
            material: Material::Wall,
        },
        Solid {
            aabb: Aabb::new(DVec3::new(-r, r, 0.0), DVec3::new(r, r + t, h)),
            material: Material::Wall,
        },
    ];
    let (tx, ty) = TABLE_HALF;
    s.push(Solid {
        aabb: Aabb::new(
            DVec3::new(-tx, -ty, TABLE_Z - 0.04),
            DVec3::new(tx, ty, TABLE_Z),
        ),
        material: Material::TableTop,
    });
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let c = DVec3::new(sx * (tx - 0.06), sy * (ty - 0.06), 0.0);
        s.push(Solid {
            aabb: Aabb::new(
                c + DVec3::new(-0.03, -0.03, 0.0),
                c + DVec3::new(0.03, 0.03, TABLE_Z - 0.04),
            ),
            material: Material::TableLeg,
        });
    }
    // A cabinet against one wall, so every direction has structure.
    s.push(Solid {
        aabb: Aabb::new(DVec3::new(1.2, 2.0, 0.0), DVec3::new(2.2, 2.5, 1.1)),
        material: Material::Cabinet,
    });
    s
}

/// Places `k` objects on the table without overlap, each with its own colour.
pub fn build_scene(rng: &mut Rng, k: usize) -> Scene {
    let mut colors: Vec<usize> = (0..PALETTE.len()).collect();
    rng.shuffle(&mut colors);
    let mut objects: Vec<Object> = Vec::new();
    let mut used_labels = std::collections::HashSet::new();
    // Every kind of shape appears once before any repeats (a box always among them).
    let mut kinds: Vec<u64> = vec![0, 1, 2, 3];
    rng.shuffle(&mut kinds);
    if kinds[3] == 0 {
        kinds.swap(0, 3);
    }
    for i in 0..k {
        let kind = if i < 4 { kinds[i] } else { rng.below(4) };
        let shape = match kind {
            0 => Shape::Box {
                half: DVec3::new(
                    rng.range(0.025, 0.06),
                    rng.range(0.025, 0.06),
                    rng.range(0.025, 0.06),
                ),
            },
            1 => Shape::Sphere {
                r: rng.range(0.03, 0.055),
            },
            2 => Shape::Cylinder {
                r: rng.range(0.025, 0.045),
                h: rng.range(0.06, 0.14),
            },
            _ => Shape::Cone {
                r: rng.range(0.03, 0.055),
                h: rng.range(0.07, 0.14),
            },
        };
        let pattern = match rng.below(4) {
            0 => Pattern::Solid,
            1 => Pattern::Stripes,
            2 => Pattern::Checker,
            _ => Pattern::Dots,
        };
        let (cname, c) = PALETTE[colors[i % PALETTE.len()]];
        let color = DVec3::from_array(c);
        let color2 = color * 0.35 + DVec3::splat(0.6);
        let mut label = format!("{cname} {}{}", pattern.adjective(), shape.name());
        if !used_labels.insert(label.clone()) {
            label = format!("{label} {}", i + 1);
        }
        // Rejection sampling of a free spot near the table centre.
        let rad = shape.footprint_radius();
        let mut base = DVec3::new(0.0, 0.0, TABLE_Z);
        for attempt in 0..1000 {
            let spread = if attempt < 500 { 1.0 } else { 1.3 };
            let cand = DVec3::new(
                rng.range(-0.32, 0.32) * spread,
                rng.range(-0.22, 0.22) * spread,
                TABLE_Z,
            );
            let free = objects.iter().all(|o| {
                (o.base - cand).truncate().length() > rad + o.shape.footprint_radius() + 0.03
            });
            if free {
                base = cand;
                break;
            }
        }
        objects.push(Object {
            id: (i + 1) as u16,
            label,
            shape,
            base,
            yaw: rng.range(0.0, std::f64::consts::PI),
            pattern,
            color,
            color2,
        });
    }
    Scene {
        solids: room(),
        objects,
        light: AreaLight {
            center: DVec3::new(0.45, -0.55, 2.1),
            half: 0.3,
            power: 2.4,
        },
    }
}

/// How the cameras are placed around the table.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraPath {
    /// Spread evenly over a spherical cap (a Fibonacci spiral): every view different.
    #[default]
    Spiral,
    /// One walk around the table in order, the camera bobbing gently up and down, as a
    /// phone video is filmed: neighbouring views are close.
    Walk,
}

/// Inward-facing cameras along `path`, looking at a point just above the table centre,
/// no roll.
pub fn cameras(rng: &mut Rng, n: usize, width: u32, height: u32, path: CameraPath) -> Vec<Camera> {
    match path {
        CameraPath::Spiral => spiral(rng, n, width, height),
        CameraPath::Walk => walk(rng, n, width, height),
    }
}

/// One turn at 0.8–0.9 m, the elevation 30–42° (two bobs per turn), the target within
/// 1 cm of the table's centre.
fn walk(rng: &mut Rng, n: usize, width: u32, height: u32) -> Vec<Camera> {
    let intr = Intrinsics::from_fov_x(width, height, 2.0 * (18.0f64 / 35.0).atan());
    let turn = std::f64::consts::TAU;
    (0..n)
        .map(|k| {
            let f = k as f64 / n as f64;
            let elev = (36.0 + 6.0 * (2.0 * turn * f).sin()).to_radians();
            let az = turn * f;
            let radius = 0.85 + 0.05 * (turn * f).cos();
            let target = DVec3::new(
                rng.range(-0.01, 0.01),
                rng.range(-0.01, 0.01),
                TABLE_Z + 0.05,
            );
            aimed(intr, target, radius, elev, az)
        })
        .collect()
}

/// A camera `radius` from `target` at elevation `elev` and azimuth `az`, looking at it,
/// no roll.
fn aimed(intrinsics: Intrinsics, target: DVec3, radius: f64, elev: f64, az: f64) -> Camera {
    let eye =
        target + radius * DVec3::new(elev.cos() * az.cos(), elev.cos() * az.sin(), elev.sin());
    let pose = Pose::look_at(eye, target, DVec3::Z).expect("cameras are never vertical");
    Camera { intrinsics, pose }
}

/// On a Fibonacci spiral over a spherical cap (elevation 20–60°), 0.7–0.95 m from the
/// target.
fn spiral(rng: &mut Rng, n: usize, width: u32, height: u32) -> Vec<Camera> {
    let intr = Intrinsics::from_fov_x(width, height, 2.0 * (18.0f64 / 35.0).atan());
    let golden = std::f64::consts::PI * (3.0 - 5.0f64.sqrt());
    (0..n)
        .map(|k| {
            let f = (k as f64 + 0.5) / n as f64;
            let (lo, hi) = (20.0f64.to_radians().sin(), 60.0f64.to_radians().sin());
            let elev = (lo + (hi - lo) * f).asin();
            let az = k as f64 * golden + rng.range(-0.05, 0.05);
            let radius = rng.range(0.7, 0.95);
            let target = DVec3::new(
                rng.range(-0.03, 0.03),
                rng.range(-0.03, 0.03),
                TABLE_Z + 0.05,
            );
            aimed(intr, target, radius, elev, az)
        })
        .collect()
}
