//! What a base scene offers to stand on, and what its training views saw.
//!
//! Support surfaces come from the trained background's own geometry: the background alone
//! (objects removed, what they hid inpainted by training) is rendered at the training
//! cameras at low resolution, each pixel is lifted to a world point, points whose surface
//! normal (from the neighbouring pixels) is within 20° of the scene's up are kept, and a
//! height map over the plane perpendicular to up stores, per cell, the highest level that a
//! good share of its points agree on. Only surfaces the training views saw can carry an
//! object, so objects stay inside the captured area.
//!
//! The same cameras render the whole base scene's depth, which decides whether a pixel of a
//! sample shows background that some training view observed (its point projects into a
//! training view at the depth that view saw) or background nobody saw (inpainted or
//! invented: the `unobserved` masks).

use assist_core::{Camera, DVec2, DVec3};
use assist_session::{Frame as RenderedImage, NamedCamera, Session};
use assist_session::{NeuralScene, RenderOptions, render_camera};
use rayon::prelude::*;

/// The scene's up and two axes spanning the plane perpendicular to it.
#[derive(Debug, Clone, Copy)]
pub struct UpFrame {
    pub up: DVec3,
    pub e1: DVec3,
    pub e2: DVec3,
}

impl UpFrame {
    pub fn new(up: DVec3) -> Self {
        let up = up.normalize();
        let a = if up.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
        let e1 = (a - up * a.dot(up)).normalize();
        let e2 = up.cross(e1);
        UpFrame { up, e1, e2 }
    }
    pub fn plane(&self, p: DVec3) -> DVec2 {
        DVec2::new(p.dot(self.e1), p.dot(self.e2))
    }
    pub fn height(&self, p: DVec3) -> f64 {
        p.dot(self.up)
    }
    pub fn point(&self, plane: DVec2, height: f64) -> DVec3 {
        self.e1 * plane.x + self.e2 * plane.y + self.up * height
    }
}

/// A height map of upward-facing surfaces.
#[derive(Debug, Clone)]
pub struct SupportMap {
    pub frame: UpFrame,
    /// Plane coordinates of cell (0, 0)'s corner.
    pub origin: DVec2,
    /// Cell edge, world units.
    pub cell: f64,
    pub nx: usize,
    pub ny: usize,
    /// Surface height per cell (NaN: no surface seen).
    pub height: Vec<f64>,
    /// Cells an object may stand on (seen, and at an allowed level).
    pub allowed: Vec<usize>,
    allowed_mask: Vec<bool>,
}

impl SupportMap {
    /// The cell under plane point `p`.
    pub fn cell_of(&self, p: DVec2) -> Option<usize> {
        let f = (p - self.origin) / self.cell;
        if !(f.x >= 0.0 && f.y >= 0.0) {
            return None;
        }
        let (i, j) = (f.x as usize, f.y as usize);
        (i < self.nx && j < self.ny).then_some(j * self.nx + i)
    }
    /// The allowed surface height under plane point `p`.
    pub fn allowed_height(&self, p: DVec2) -> Option<f64> {
        let c = self.cell_of(p)?;
        self.allowed_mask[c].then_some(self.height[c])
    }
    /// The surface height under `p`, allowed or not.
    pub fn height_at(&self, p: DVec2) -> Option<f64> {
        let c = self.cell_of(p)?;
        let h = self.height[c];
        h.is_finite().then_some(h)
    }
    /// The median surface height within `radius` of plane point `p` (the level around an
    /// object, seen past it); `None` when no surface was seen there.
    pub fn level_near(&self, p: DVec2, radius: f64) -> Option<f64> {
        let lo = ((p - radius - self.origin) / self.cell).floor();
        let hi = ((p + radius - self.origin) / self.cell).floor();
        let mut hs = Vec::new();
        for j in lo.y.max(0.0) as usize..=(hi.y.max(-1.0) as usize).min(self.ny.saturating_sub(1)) {
            for i in
                lo.x.max(0.0) as usize..=(hi.x.max(-1.0) as usize).min(self.nx.saturating_sub(1))
            {
                let c = j * self.nx + i;
                if self.height[c].is_finite() && (self.cell_center(c) - p).length() <= radius {
                    hs.push(self.height[c]);
                }
            }
        }
        if hs.is_empty() {
            return None;
        }
        hs.sort_by(f64::total_cmp);
        Some(hs[hs.len() / 2])
    }

    /// Allows only cells within `tol` of one of `levels` (no change for no levels).
    pub fn restrict_to_levels(&mut self, levels: &[f64], tol: f64) {
        if levels.is_empty() {
            return;
        }
        for (c, ok) in self.allowed_mask.iter_mut().enumerate() {
            *ok = *ok && levels.iter().any(|l| (self.height[c] - l).abs() <= tol);
        }
        self.allowed = (0..self.height.len())
            .filter(|&c| self.allowed_mask[c])
            .collect();
    }

    pub fn cell_center(&self, c: usize) -> DVec2 {
        let (i, j) = (c % self.nx, c / self.nx);
        self.origin + DVec2::new(i as f64 + 0.5, j as f64 + 0.5) * self.cell
    }
}

/// A training view at low resolution with the depth the base scene renders there.
pub struct SeenView {
    pub camera: Camera,
    pub depth: Vec<f32>,
}

/// Training cameras scaled down to at most `max_width` pixels wide and at most `max_views`
/// of them, evenly spread.
pub fn small_views(cams: &[NamedCamera], max_width: u32, max_views: usize) -> Vec<Camera> {
    let step = cams.len().div_ceil(max_views.max(1)).max(1);
    cams.iter()
        .step_by(step)
        .map(|c| {
            let w = c.camera.width().min(max_width).max(8);
            let h = ((c.camera.height() as f64 * w as f64 / c.camera.width() as f64).round()
                as u32)
                .max(6);
            Session::sized(&c.camera, Some((w, h))).unwrap_or(c.camera)
        })
        .collect()
}

/// Renders the base scene and its background alone at `views`: the views as seen (for
/// the observed test) and the upward-facing surface points of the background.
pub fn survey(
    scene: &NeuralScene,
    views: &[Camera],
    opts: &RenderOptions,
) -> (Vec<SeenView>, Vec<DVec3>) {
    let up = UpFrame::new(scene.scene.up);
    let mut bg = scene.clone();
    bg.scene.nodes.retain(|n| n.is_background());
    let mut seen = Vec::with_capacity(views.len());
    let mut points = Vec::new();
    for cam in views {
        let full = render_camera(scene, cam, u32::MAX, opts);
        // A filled pixel's depth is a guess: it counts as nothing seen.
        let depth = full
            .depth
            .iter()
            .zip(&full.unseen)
            .map(|(&d, &u)| if u { 0.0 } else { d })
            .collect();
        seen.push(SeenView {
            camera: *cam,
            depth,
        });
        if bg.scene.nodes.is_empty() {
            continue;
        }
        let img = render_camera(&bg, cam, u32::MAX, opts);
        let (w, h) = (img.width as usize, img.height as usize);
        let flat = 20f64.to_radians().cos();
        let normals = cam.depth_normals(&img.depth, w, h, |i| img.opacity[i] >= 0.9);
        points.extend(
            normals
                .into_iter()
                .flatten()
                .filter(|(_, n)| n.dot(up.up).abs() > flat)
                .map(|(p, _)| p),
        );
    }
    (seen, points)
}

/// The height map of `points` (upward-facing surface points) with cells of `cell` world
/// units; a cell's height is the median of its points' heights when three quarters of
/// them lie within `tol` of it (else the cell straddles an edge or two levels and is no
/// surface).
/// Every cell with a height is allowed ([`SupportMap::restrict_to_levels`] narrows that).
pub fn support_map(up: DVec3, points: &[DVec3], cell: f64, tol: f64) -> Option<SupportMap> {
    let frame = UpFrame::new(up);
    if points.is_empty() {
        return None;
    }
    let mut lo = DVec2::splat(f64::INFINITY);
    let mut hi = DVec2::splat(f64::NEG_INFINITY);
    for p in points {
        let q = frame.plane(*p);
        lo = lo.min(q);
        hi = hi.max(q);
    }
    // At most 1024 cells a side.
    let span = (hi - lo).max_element();
    let cell = cell.max(span / 1024.0);
    let nx = ((hi.x - lo.x) / cell).floor() as usize + 1;
    let ny = ((hi.y - lo.y) / cell).floor() as usize + 1;
    let mut per: Vec<Vec<f64>> = vec![Vec::new(); nx * ny];
    for p in points {
        let f = (frame.plane(*p) - lo) / cell;
        let (i, j) = ((f.x as usize).min(nx - 1), (f.y as usize).min(ny - 1));
        per[j * nx + i].push(frame.height(*p));
    }
    let height: Vec<f64> = per
        .par_iter_mut()
        .map(|hs| {
            if hs.len() < 3 {
                return f64::NAN;
            }
            hs.sort_by(|a, b| a.total_cmp(b));
            let median = hs[hs.len() / 2];
            // Mixed cells (an edge, two levels) are not a surface.
            let near = hs.iter().filter(|&&v| (v - median).abs() <= tol).count();
            if near * 4 >= hs.len() * 3 {
                return median;
            }
            f64::NAN
        })
        .collect();
    let allowed_mask: Vec<bool> = height.iter().map(|h| h.is_finite()).collect();
    let allowed = (0..height.len()).filter(|&c| allowed_mask[c]).collect();
    Some(SupportMap {
        frame,
        origin: lo,
        cell,
        nx,
        ny,
        height,
        allowed,
        allowed_mask,
    })
}

/// Whether world point `p` (seen by some camera at z-depth) lies on a surface one of the
/// training views observed: it projects inside that view at about the depth that view saw
/// there.
pub fn observed(views: &[SeenView], p: DVec3) -> bool {
    views.iter().any(|v| {
        let Some((px, z)) = v.camera.project(p) else {
            return false;
        };
        let (w, h) = (v.camera.width() as f64, v.camera.height() as f64);
        if !(px.x >= 0.0 && px.y >= 0.0 && px.x < w && px.y < h) || z <= 0.0 {
            return false;
        }
        // The view's depth at the pixel or a neighbour (its depth is coarse at edges).
        let (w, h) = (w as i64, h as i64);
        let (x, y) = (px.x as i64, px.y as i64);
        [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]
            .iter()
            .any(|(dx, dy)| {
                let (x, y) = (x + dx, y + dy);
                if x < 0 || y < 0 || x >= w || y >= h {
                    return false;
                }
                let d = v.depth[(y * w + x) as usize] as f64;
                d > 0.0 && (d - z).abs() <= 0.03 * z
            })
    })
}

/// The unobserved mask of a rendered view: 255 where the pixel shows background that no
/// training view observed (a pixel the render filled included), else 0.
pub fn unobserved_mask(views: &[SeenView], camera: &Camera, frame: &RenderedImage) -> Vec<u8> {
    let w = camera.width() as usize;
    frame
        .depth
        .par_iter()
        .zip(frame.panoptic.par_iter())
        .zip(frame.unseen.par_iter())
        .enumerate()
        .map(|(q, ((&z, &id), &unseen))| {
            if id != 0 {
                return 0;
            }
            if z <= 0.0 || unseen {
                return 255;
            }
            let (i, j) = (q % w, q / w);
            match camera.unproject(i as f64 + 0.5, j as f64 + 0.5, z as f64) {
                Some(p) if observed(views, p) => 0,
                _ => 255,
            }
        })
        .collect()
}
