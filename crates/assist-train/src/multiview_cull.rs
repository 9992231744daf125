//! Which source pixels of the multi-view fill ([`crate::multiview`]) can land on a
//! target's holes, decided a tile at a time: a source tile's points lie in a sphere, a
//! target's holes (grown by the largest splat) within a few cones of directions from its
//! camera, and a tile whose sphere meets no cone is skipped without projecting its
//! pixels. Objects cover a small part of each view, so most of every source is skipped;
//! the candidates kept are exactly those the full splat keeps, in the same order.

use assist_core::Camera;
use assist_core::glam::DVec3;

/// Source pixels per tile side.
pub(crate) const TILE: usize = 16;

/// Target pixels per side of the cells whose holes share a cone.
const CELL: usize = 32;

/// How far past a cell's pixels its cone reaches, in pixels: a splat covers its pixel
/// ± 2 (`MAX_SPLAT_RADIUS`), its centre floored, plus room for rounding.
const REACH: f64 = 4.0;

/// Along a cell's grown edges, a direction is taken every this many pixels (the cone's
/// edge where distortion bends the edges between corners).
const EDGE_STEP: f64 = 4.0;

/// The sphere holding the points of each tile of a source view (source camera frame);
/// `None` for a tile without a usable pixel.
pub(crate) struct Tiles {
    pub(crate) across: usize,
    pub(crate) spheres: Vec<Option<(DVec3, f64)>>,
}

impl Tiles {
    /// The tiles of a `w × h` view whose usable pixel `q` lies at `point(q)`.
    pub(crate) fn of(w: usize, h: usize, usable: &[bool], point: impl Fn(usize) -> DVec3) -> Tiles {
        let (across, down) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut spheres = Vec::with_capacity(across * down);
        for ty in 0..down {
            for tx in 0..across {
                let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for y in ty * TILE..((ty + 1) * TILE).min(h) {
                    for x in tx * TILE..((tx + 1) * TILE).min(w) {
                        let q = y * w + x;
                        if usable[q] {
                            let p = point(q);
                            lo = lo.min(p);
                            hi = hi.max(p);
                        }
                    }
                }
                spheres.push((lo.x <= hi.x).then(|| {
                    let c = (lo + hi) * 0.5;
                    // Grown beyond any rounding of the points or of the transform.
                    let r = (hi - lo).length() * 0.5;
                    (c, r * (1.0 + 1e-6) + 1e-9 * (1.0 + c.length()))
                }));
            }
        }
        Tiles { across, spheres }
    }
}

/// Cones of directions (target camera frame) that hold every direction a splat onto a
/// hole pixel can come from: each its unit axis and the cosine and sine of its
/// half-angle.
pub(crate) struct Cones(Vec<(DVec3, f64, f64)>);

impl Cones {
    /// The cones of `hole` (a `w × h` mask) seen by `camera`; `None` where a direction
    /// cannot be had (outside the lens model's range) or a cone would be too wide to
    /// bound: then nothing is skipped.
    pub(crate) fn of(camera: &Camera, hole: &[bool], w: usize, h: usize) -> Option<Cones> {
        let intr = &camera.intrinsics;
        let dir = |u: f64, v: f64| intr.direction_gl(u, v).map(|d| d.normalize());
        let mut cones = Vec::new();
        for cy in 0..h.div_ceil(CELL) {
            for cx in 0..w.div_ceil(CELL) {
                let (x0, x1) = (cx * CELL, ((cx + 1) * CELL).min(w));
                let (y0, y1) = (cy * CELL, ((cy + 1) * CELL).min(h));
                if !(y0..y1).any(|y| (x0..x1).any(|x| hole[y * w + x])) {
                    continue;
                }
                let (u0, u1) = (x0 as f64 - REACH, x1 as f64 + REACH);
                let (v0, v1) = (y0 as f64 - REACH, y1 as f64 + REACH);
                let axis = dir((u0 + u1) * 0.5, (v0 + v1) * 0.5)?;
                let mut half = 0.0f64;
                let mut edge = |u: f64, v: f64| -> Option<()> {
                    let d = dir(u, v)?;
                    half = half.max(axis.dot(d).clamp(-1.0, 1.0).acos());
                    Some(())
                };
                let (nu, nv) = (
                    ((u1 - u0) / EDGE_STEP).ceil() as usize,
                    ((v1 - v0) / EDGE_STEP).ceil() as usize,
                );
                for i in 0..=nu {
                    let u = (u0 + i as f64 * EDGE_STEP).min(u1);
                    edge(u, v0)?;
                    edge(u, v1)?;
                }
                for j in 0..=nv {
                    let v = (v0 + j as f64 * EDGE_STEP).min(v1);
                    edge(u0, v)?;
                    edge(u1, v)?;
                }
                // Room for the bending of the edges between the directions taken.
                let half = half * 1.02 + 1e-4;
                if half > 1.4 {
                    return None;
                }
                cones.push((axis, half.cos(), half.sin()));
            }
        }
        Some(Cones(cones))
    }

    /// Whether the sphere (`centre`, `radius`; target camera frame) meets a cone.
    #[inline(always)]
    pub(crate) fn meet(&self, centre: DVec3, radius: f64) -> bool {
        let dist = centre.length();
        if dist <= radius {
            return true;
        }
        // The sphere subtends `spread` from the apex: it meets a cone when its centre lies
        // within the half-angle plus `spread` of the axis, i.e. when the centre's cosine
        // to the axis is at least cos(half + spread) (half + spread < π: half ≤ 1.4).
        let (sin_s, c) = (radius / dist, centre / dist);
        let cos_s = (1.0 - sin_s * sin_s).sqrt();
        self.0
            .iter()
            .any(|&(axis, cos_h, sin_h)| axis.dot(c) >= cos_h * cos_s - sin_h * sin_s - 1e-12)
    }
}

/// Pixels a hole is grown by for [`Quick`]: a splat reaches 2 pixels past its floored
/// centre, and the quick projection's floor is at most one off the exact one.
pub(crate) const NEAR: usize = 5;

/// A quick projection in f32 into a target without lens distortion, to pass over the
/// source pixels whose splat lands nowhere near a hole before the exact projection.
pub(crate) struct Quick<'a> {
    /// Target camera from source camera (OpenGL frames), rows of a 3 × 4 matrix.
    m: [[f32; 4]; 3],
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    w: usize,
    h: usize,
    /// The target's holes grown by [`NEAR`].
    near: &'a [bool],
}

impl<'a> Quick<'a> {
    /// For `target` (`None` where its lens distorts: the quick projection has no lens).
    pub(crate) fn new(
        target: &Camera,
        to_target: &assist_core::glam::DAffine3,
        near: &'a [bool],
    ) -> Option<Self> {
        let i = &target.intrinsics;
        if i.distortion != assist_core::Distortion::None {
            return None;
        }
        let (r, t) = (to_target.matrix3, to_target.translation);
        let row = |k: usize| [r.x_axis[k], r.y_axis[k], r.z_axis[k], t[k]].map(|v| v as f32);
        Some(Quick {
            m: [row(0), row(1), row(2)],
            fx: i.fx as f32,
            fy: i.fy as f32,
            cx: i.cx as f32,
            cy: i.cy as f32,
            w: target.width() as usize,
            h: target.height() as usize,
            near,
        })
    }

    /// Whether the point `p` (source camera frame) certainly splats onto no hole. Points
    /// near the target's camera plane or far off its axis, where f32 loses the pixel,
    /// are never passed over.
    #[inline(always)]
    pub(crate) fn misses(&self, p: [f32; 3]) -> bool {
        let [a, b, c] = self
            .m
            .map(|r| r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + r[3]);
        let z = -c;
        if z.is_nan() || z <= 1e-6 {
            return false;
        }
        let (nx, ny) = (a / z, -b / z);
        if !(nx.abs() < 100.0 && ny.abs() < 100.0) {
            return false;
        }
        let (x, y) = (self.fx * nx + self.cx, self.fy * ny + self.cy);
        let (w, h) = (self.w as f32, self.h as f32);
        let reach = NEAR as f32;
        // (As the pixel's floor would be compared: the bounds are whole numbers.)
        if x < -reach || y < -reach || x >= w + reach || y >= h + reach {
            return true;
        }
        // The nearest pixel of the image (truncation floors a number ≥ 0; no call to
        // `floor`, which the baseline instruction set lacks).
        let xi = (x.max(0.0) as usize).min(self.w - 1);
        let yi = (y.max(0.0) as usize).min(self.h - 1);
        !self.near[yi * self.w + xi]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multiview::fill_multiview_culled;
    use crate::multiview::tests::{cameras, render_on};
    use assist_core::Distortion;

    /// The fill of `views` with and without the culling: the same bits.
    fn same_fill(cams: &[Camera], table: Option<f64>) {
        let mut culled: Vec<_> = cams.iter().map(|c| render_on(c, true, table)).collect();
        let mut full = culled.clone();
        let a = fill_multiview_culled(&mut culled, true);
        let b = fill_multiview_culled(&mut full, false);
        assert!(a.hole_pixels > 0 && a.filled_pixels > 0);
        assert_eq!(
            (a.hole_pixels, a.filled_pixels),
            (b.hole_pixels, b.filled_pixels)
        );
        let bits = |v: &Option<Vec<f32>>| {
            v.as_ref()
                .unwrap()
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        for (c, f) in culled.iter().zip(&full) {
            assert_eq!(bits(&c.inpaint), bits(&f.inpaint));
            assert_eq!(bits(&c.inpaint_depth), bits(&f.inpaint_depth));
            assert_eq!(bits(&c.prior_confidence), bits(&f.prior_confidence));
        }
    }

    #[test]
    fn skipping_tiles_keeps_every_candidate() {
        let cams = cameras(12);
        same_fill(&cams, None);
        same_fill(&cams, Some(0.45));
        // Every other camera three times as close: a far view's pixels splat over several of a
        // near view's (the splat's reach past its pixel).
        let near: Vec<Camera> = cams
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let mut c = *c;
                if k % 2 == 0 {
                    let eye = c.pose.world_from_camera.translation * 0.3;
                    c.pose = assist_core::Pose::look_at(eye, DVec3::ZERO, DVec3::Z).unwrap();
                }
                c
            })
            .collect();
        same_fill(&near, Some(0.45));
        // A lens that bends the holes' edges: the cones must still hold them.
        let bent: Vec<Camera> = cams
            .iter()
            .map(|c| {
                let mut c = *c;
                c.intrinsics.distortion = Distortion::OpenCv {
                    k1: -0.25,
                    k2: 0.08,
                    k3: 0.0,
                    p1: 0.004,
                    p2: -0.003,
                };
                c
            })
            .collect();
        same_fill(&bent, Some(0.45));
    }

    #[test]
    fn most_tiles_of_a_source_miss_a_small_hole() {
        let cams = cameras(12);
        let (target, src) = (
            render_on(&cams[0], true, None),
            render_on(&cams[3], true, None),
        );
        let hole: Vec<bool> = target
            .ids
            .as_ref()
            .unwrap()
            .iter()
            .map(|&i| i != 0)
            .collect();
        let cones = Cones::of(&target.camera, &hole, target.width, target.height).unwrap();
        let depth = src.depth.as_ref().unwrap();
        let usable: Vec<bool> = depth.iter().map(|&z| z > 0.0).collect();
        let (w, h) = (src.width, src.height);
        let tiles = Tiles::of(w, h, &usable, |q| {
            let d = src
                .camera
                .intrinsics
                .direction_gl((q % w) as f64 + 0.5, (q / w) as f64 + 0.5)
                .unwrap();
            d / -d.z * depth[q] as f64
        });
        let to_target = target.camera.pose.camera_from_world() * src.camera.pose.world_from_camera;
        let kept = tiles
            .spheres
            .iter()
            .flatten()
            .filter(|&&(c, r)| cones.meet(to_target.transform_point3(c), r))
            .count();
        let all = tiles.spheres.iter().flatten().count();
        assert!(kept > 0 && kept < all, "{kept} of {all} tiles kept");
    }
}
