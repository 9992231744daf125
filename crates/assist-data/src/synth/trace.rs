//! The ray tracer: exact ray–primitive intersection, Lambertian shading under an area
//! light with soft shadows and a sky-like ambient term, procedural textures, and a view
//! renderer giving anti-aliased RGB plus z-depth and instance ids sampled at pixel centres.

use assist_core::{Camera, DVec3, Ray, Rng};

use super::scene::{Material, Object, Pattern, Scene, Shape};

const EPS: f64 = 1e-7;

#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub t: f64,
    pub normal: DVec3,
    /// Index into `scene.objects`, or `None` for the room.
    pub object: Option<usize>,
    pub material: Option<Material>,
    pub point: DVec3,
}

/// Outward normal of the box face nearest to `q`, a point in box coordinates scaled so
/// that the faces are at ±1.
fn box_face_normal(q: DVec3) -> DVec3 {
    let a = q.abs();
    if a.x >= a.y && a.x >= a.z {
        DVec3::new(q.x.signum(), 0.0, 0.0)
    } else if a.y >= a.z {
        DVec3::new(0.0, q.y.signum(), 0.0)
    } else {
        DVec3::new(0.0, 0.0, q.z.signum())
    }
}

/// Ray–primitive intersection in the object's frame (base centre at the origin, z up).
fn intersect_shape(shape: &Shape, o: DVec3, d: DVec3, t_max: f64) -> Option<(f64, DVec3)> {
    match *shape {
        Shape::Box { half } => {
            let aabb = assist_core::Aabb::new(
                DVec3::new(-half.x, -half.y, 0.0),
                DVec3::new(half.x, half.y, 2.0 * half.z),
            );
            let (t0, _) = aabb.intersect(o, d, EPS, t_max)?;
            let p = o + d * t0 - DVec3::new(0.0, 0.0, half.z);
            let q = p / half;
            let n = box_face_normal(q);
            Some((t0, n))
        }
        Shape::Sphere { r } => {
            let c = DVec3::new(0.0, 0.0, r);
            let oc = o - c;
            let b = oc.dot(d);
            let cc = oc.length_squared() - r * r;
            let disc = b * b - cc;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            let t = if -b - s > EPS { -b - s } else { -b + s };
            (t > EPS && t < t_max).then(|| (t, (o + d * t - c) / r))
        }
        Shape::Cylinder { r, h } => {
            let mut best: Option<(f64, DVec3)> = None;
            let mut consider = |t: f64, n: DVec3| {
                if t > EPS && t < t_max && best.is_none_or(|b| t < b.0) {
                    best = Some((t, n));
                }
            };
            let a = d.x * d.x + d.y * d.y;
            if a > 1e-18 {
                let b = o.x * d.x + o.y * d.y;
                let c = o.x * o.x + o.y * o.y - r * r;
                let disc = b * b - a * c;
                if disc >= 0.0 {
                    for t in [(-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a] {
                        let z = o.z + d.z * t;
                        if (0.0..=h).contains(&z) {
                            let p = o + d * t;
                            consider(t, DVec3::new(p.x, p.y, 0.0) / r);
                        }
                    }
                }
            }
            if d.z.abs() > 1e-18 {
                for (zc, nz) in [(0.0, -1.0), (h, 1.0)] {
                    let t = (zc - o.z) / d.z;
                    let p = o + d * t;
                    if p.x * p.x + p.y * p.y <= r * r {
                        consider(t, DVec3::new(0.0, 0.0, nz));
                    }
                }
            }
            best
        }
        Shape::Cone { r, h } => {
            let mut best: Option<(f64, DVec3)> = None;
            let mut consider = |t: f64, n: DVec3| {
                if t > EPS && t < t_max && best.is_none_or(|b| t < b.0) {
                    best = Some((t, n));
                }
            };
            let k2 = (r / h) * (r / h);
            let w = h - o.z;
            let a = d.x * d.x + d.y * d.y - k2 * d.z * d.z;
            let b = 2.0 * (o.x * d.x + o.y * d.y + k2 * w * d.z);
            let c = o.x * o.x + o.y * o.y - k2 * w * w;
            let mut roots = Vec::with_capacity(2);
            if a.abs() > 1e-18 {
                let disc = b * b - 4.0 * a * c;
                if disc >= 0.0 {
                    roots.push((-b - disc.sqrt()) / (2.0 * a));
                    roots.push((-b + disc.sqrt()) / (2.0 * a));
                }
            } else if b.abs() > 1e-18 {
                roots.push(-c / b);
            }
            for t in roots {
                let p = o + d * t;
                if (0.0..=h).contains(&p.z) {
                    let n = DVec3::new(p.x, p.y, k2 * (h - p.z)).normalize_or_zero();
                    consider(t, n);
                }
            }
            if d.z.abs() > 1e-18 {
                let t = -o.z / d.z;
                let p = o + d * t;
                if p.x * p.x + p.y * p.y <= r * r {
                    consider(t, DVec3::NEG_Z);
                }
            }
            best
        }
    }
}

fn intersect_object(obj: &Object, ray: &Ray, t_max: f64) -> Option<(f64, DVec3)> {
    let rot = obj.rotation();
    let inv = rot.transpose();
    let o = inv * (ray.origin - obj.base);
    let d = inv * ray.dir;
    intersect_shape(&obj.shape, o, d, t_max).map(|(t, n)| (t, rot * n))
}

/// Nearest hit along `ray` within `t_max`.
pub fn trace(scene: &Scene, ray: &Ray, t_max: f64) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    let mut limit = t_max;
    for (i, obj) in scene.objects.iter().enumerate() {
        if let Some((t, n)) = intersect_object(obj, ray, limit) {
            limit = t;
            best = Some(Hit {
                t,
                normal: n,
                object: Some(i),
                material: None,
                point: ray.at(t),
            });
        }
    }
    for s in &scene.solids {
        if let Some((t0, _)) = s.aabb.intersect(ray.origin, ray.dir, EPS, limit) {
            if t0 <= EPS {
                continue; // inside a solid: ignore (cameras are never inside)
            }
            let p = ray.at(t0);
            let c = s.aabb.center();
            let q = (p - c) / (s.aabb.size() * 0.5);
            let n = box_face_normal(q);
            limit = t0;
            best = Some(Hit {
                t: t0,
                normal: n,
                object: None,
                material: Some(s.material),
                point: p,
            });
        }
    }
    best
}

fn occluded(scene: &Scene, from: DVec3, to: DVec3) -> bool {
    let d = to - from;
    let dist = d.length();
    let ray = Ray {
        origin: from,
        dir: d / dist,
    };
    let t_max = dist * (1.0 - 1e-6);
    scene
        .objects
        .iter()
        .any(|o| intersect_object(o, &ray, t_max).is_some())
        || scene.solids.iter().any(|s| {
            s.material != Material::Ceiling
                && s.aabb.intersect(ray.origin, ray.dir, 1e-6, t_max).is_some()
        })
}

fn hash3(x: i64, y: i64, z: i64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn room_albedo(m: Material, p: DVec3, n: DVec3) -> DVec3 {
    match m {
        Material::Floor => {
            let plank = (p.x / 0.18).floor() as i64;
            let off = hash3(plank, 0, 7) * 1.2;
            let seg = ((p.y + off) / 1.2).floor() as i64;
            let v = hash3(plank, seg, 1);
            let grain = 0.5 + 0.5 * (p.y * 40.0 + (p.x * 7.0).sin() * 2.0).sin();
            let edge = if (p.x / 0.18).fract().abs() < 0.02 {
                0.5
            } else {
                1.0
            };
            DVec3::new(0.45, 0.30, 0.18) * (0.75 + 0.3 * v + 0.08 * grain) * edge
        }
        Material::Wall => {
            // Bricks 0.2 × 0.08 m with mortar; the along-wall coordinate depends on the face.
            let u = if n.x.abs() > 0.5 { p.y } else { p.x };
            let row = (p.z / 0.08).floor() as i64;
            let shift = if row % 2 == 0 { 0.0 } else { 0.1 };
            let col = ((u + shift) / 0.2).floor() as i64;
            let fu = ((u + shift) / 0.2).rem_euclid(1.0);
            let fz = (p.z / 0.08).rem_euclid(1.0);
            if fu < 0.05 || fz < 0.1 {
                DVec3::splat(0.72)
            } else {
                let v = hash3(col, row, 3);
                DVec3::new(0.55, 0.22, 0.15) * (0.8 + 0.4 * v)
            }
        }
        Material::Ceiling => DVec3::splat(0.8),
        Material::TableTop => {
            if n.z < 0.5 {
                return DVec3::new(0.35, 0.22, 0.12);
            }
            let ring = ((p.x * 3.0).powi(2) * 0.3 + p.y * 25.0 + (p.x * 11.0).sin() * 0.8).sin();
            let check = if ((p.x / 0.25).floor() as i64 + (p.y / 0.25).floor() as i64) % 2 == 0 {
                1.0
            } else {
                0.93
            };
            DVec3::new(0.72, 0.55, 0.36) * (0.88 + 0.12 * ring) * check
        }
        Material::TableLeg => DVec3::new(0.3, 0.2, 0.12),
        Material::Cabinet => {
            let door = if (p.x - 1.7).abs() < 0.01 || (p.z - 0.55).abs() < 0.01 {
                0.4
            } else {
                1.0
            };
            DVec3::new(0.45, 0.5, 0.55) * door
        }
    }
}

fn object_albedo(obj: &Object, p_world: DVec3) -> DVec3 {
    let p = obj.rotation().transpose() * (p_world - obj.base);
    let second = match obj.pattern {
        Pattern::Solid => false,
        Pattern::Stripes => (p.z / 0.015).floor() as i64 % 2 == 0,
        Pattern::Checker => {
            ((p.x / 0.02).floor() as i64
                + (p.y / 0.02).floor() as i64
                + (p.z / 0.02).floor() as i64)
                % 2
                == 0
        }
        Pattern::Dots => {
            let cell = 0.025;
            let q = (p / cell).fract_gl() - DVec3::splat(0.5);
            q.length() < 0.3
        }
    };
    if second { obj.color2 } else { obj.color }
}

/// Radiance (linear) seen along `ray`, with `shadow_samples` light samples.
fn shade(scene: &Scene, hit: &Hit, ray: &Ray, rng: &mut Rng, shadow_samples: u32) -> DVec3 {
    let mut n = hit.normal;
    if n.dot(ray.dir) > 0.0 {
        n = -n;
    }
    let albedo = match hit.object {
        Some(i) => object_albedo(&scene.objects[i], hit.point),
        None => room_albedo(hit.material.unwrap_or(Material::Wall), hit.point, n),
    };
    let p = hit.point + n * 1e-6;
    let l = &scene.light;
    let mut direct = 0.0;
    let k = (shadow_samples as f64).sqrt().ceil() as u32;
    for s in 0..shadow_samples {
        let (a, b) = ((s % k) as f64, (s / k) as f64);
        let sx = l.center.x + l.half * (2.0 * (a + rng.f64()) / k as f64 - 1.0);
        let sy = l.center.y + l.half * (2.0 * (b + rng.f64()) / k as f64 - 1.0);
        let sp = DVec3::new(sx, sy, l.center.z);
        let to = sp - p;
        let d2 = to.length_squared();
        let dir = to / d2.sqrt();
        let cos_s = n.dot(dir);
        let cos_l = dir.z;
        if cos_s <= 0.0 || cos_l <= 0.0 || occluded(scene, p, sp) {
            continue;
        }
        direct += cos_s * cos_l / d2;
    }
    direct *= l.power / shadow_samples as f64;
    let ambient = 0.22 * (0.6 + 0.4 * n.z);
    albedo * (ambient + direct)
}

fn to_srgb(v: f64) -> f32 {
    let v = v.clamp(0.0, 1.0);
    (if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }) as f32
}

/// One rendered view: RGB (sRGB, [0, 1]), z-depth in metres and instance ids at pixel centres.
pub struct ViewRender {
    pub rgb: Vec<f32>,
    pub depth: Vec<f32>,
    pub ids: Vec<u16>,
}

/// Renders a view with `spp` jittered (stratified) samples per pixel for colour.
pub fn render_view(
    scene: &Scene,
    cam: &Camera,
    seed: u64,
    spp: u32,
    shadow_samples: u32,
) -> ViewRender {
    let (w, h) = (cam.width(), cam.height());
    let n = (w * h) as usize;
    let mut out = ViewRender {
        rgb: vec![0.0; n * 3],
        depth: vec![0.0; n],
        ids: vec![0; n],
    };
    let k = (spp as f64).sqrt().ceil() as u32;
    let fwd = cam.pose.forward();
    for j in 0..h {
        let mut rng = Rng::stream(seed, j as u64);
        for i in 0..w {
            let idx = (j * w + i) as usize;
            if let Some(ray) = cam.pixel_ray(i, j)
                && let Some(hit) = trace(scene, &ray, 1e3)
            {
                out.depth[idx] = (hit.t * ray.dir.dot(fwd)) as f32;
                out.ids[idx] = hit.object.map(|o| scene.objects[o].id).unwrap_or(0);
            }
            let mut acc = DVec3::ZERO;
            for s in 0..spp {
                let u = i as f64 + ((s % k) as f64 + rng.f64()) / k as f64;
                let v = j as f64 + ((s / k) as f64 + rng.f64()) / k as f64;
                if let Some(ray) = cam.ray(u, v)
                    && let Some(hit) = trace(scene, &ray, 1e3)
                {
                    acc += shade(scene, &hit, &ray, &mut rng, shadow_samples);
                }
            }
            acc /= spp as f64;
            for c in 0..3 {
                out.rgb[idx * 3 + c] = to_srgb(acc[c]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_hit(shape: &Shape, o: DVec3, d: DVec3, inside: impl Fn(DVec3) -> bool) -> Option<f64> {
        let _ = shape;
        (1..40_000)
            .map(|i| i as f64 * 1e-4)
            .find(|&t| inside(o + d * t))
    }

    #[test]
    fn primitives_match_brute_force() {
        let shapes = [
            (
                Shape::Box {
                    half: DVec3::new(0.3, 0.2, 0.4),
                },
                Box::new(|p: DVec3| {
                    p.x.abs() <= 0.3 && p.y.abs() <= 0.2 && (0.0..=0.8).contains(&p.z)
                }) as Box<dyn Fn(DVec3) -> bool>,
            ),
            (
                Shape::Sphere { r: 0.5 },
                Box::new(|p: DVec3| (p - DVec3::new(0.0, 0.0, 0.5)).length() <= 0.5),
            ),
            (
                Shape::Cylinder { r: 0.3, h: 0.9 },
                Box::new(|p: DVec3| p.x * p.x + p.y * p.y <= 0.09 && (0.0..=0.9).contains(&p.z)),
            ),
            (
                Shape::Cone { r: 0.4, h: 0.8 },
                Box::new(|p: DVec3| {
                    (0.0..=0.8).contains(&p.z)
                        && (p.x * p.x + p.y * p.y).sqrt() <= 0.4 * (1.0 - p.z / 0.8)
                }),
            ),
        ];
        let mut rng = Rng::new(3);
        for (shape, inside) in &shapes {
            let mut hits = 0;
            for _ in 0..300 {
                let o = DVec3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-2.0, 2.0),
                    rng.range(-1.0, 2.0),
                )
                .normalize()
                    * 2.0
                    + DVec3::new(0.0, 0.0, 0.4);
                let target = DVec3::new(
                    rng.range(-0.4, 0.4),
                    rng.range(-0.4, 0.4),
                    rng.range(0.0, 0.9),
                );
                let d = (target - o).normalize();
                let fast = intersect_shape(shape, o, d, 10.0).map(|h| h.0);
                let slow = brute_hit(shape, o, d, inside);
                match (fast, slow) {
                    (Some(a), Some(b)) => {
                        hits += 1;
                        assert!((a - b).abs() < 2e-4, "{shape:?}: {a} vs {b}");
                    }
                    (None, None) => {}
                    (a, b) => panic!("{shape:?}: fast {a:?} brute {b:?}"),
                }
            }
            assert!(hits > 50, "{shape:?}: {hits}");
        }
    }
}
