//! Frames of the scene as it is now: whole cameras (with a cancel flag), a dragged node's
//! cached re-render, and single pixels (pick, surface). Cameras far outside the scene are
//! refused before any ray is traced: their rays cross the boxes at huge distances and a
//! frame could take hours.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use assist_core::{Camera, DVec3, InstanceId};
use assist_render::{
    DragCache, HIGHLIGHT, RenderOptions, RenderScratch, SceneTables, render_camera,
    render_camera_moving, render_rays,
};

use crate::{Frame, Result, Session, SessionError, request};

/// How far a camera may stand from the scene's centre, in radii of the box around all
/// its nodes.
pub const MAX_CAMERA_RADII: f64 = 1000.0;

/// What to render besides colour, depth, opacity and instance ids.
#[derive(Debug, Clone, Default)]
pub struct RenderRequest {
    /// Set from another thread to stop the render between ray batches (a Ctrl+C, a viewer
    /// client gone); the render then returns [`SessionError::Cancelled`].
    pub cancel: Option<Arc<AtomicBool>>,
    /// Output size (the camera's intrinsics are scaled to it); `None` = the camera's.
    pub size: Option<(u32, u32)>,
    /// Each node's own colour and opacity too.
    pub layers: bool,
    /// The background alone too ([`Frame::background`]).
    pub background: bool,
    /// Highlight the selected node.
    pub highlight: bool,
    /// Appearance code of a training image; `None` = the average.
    pub image: Option<u32>,
}

impl Session {
    fn options(&self, req: &RenderRequest) -> RenderOptions {
        RenderOptions {
            cancel: req.cancel.clone(),
            layers: req.layers,
            background_alone: req.background,
            highlight: if req.highlight {
                self.editor.scene.scene.selected.map(|id| (id, HIGHLIGHT))
            } else {
                None
            },
            ..self.base_options()
        }
    }

    /// The packed hash tables of the scene's fields as they are now, packing those new or
    /// changed since the last render (`None` under `ASSIST_PRECISION=f32`, which reads
    /// the f32 parameters).
    pub fn packed_tables(&self) -> Option<Arc<SceneTables>> {
        if RenderOptions::default().precision != assist_render::Precision::Bf16 {
            return None;
        }
        let scene = &self.editor.scene;
        let mut held = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        if !held.covers(scene) {
            let mut t = (**held).clone();
            t.refresh(scene);
            *held = Arc::new(t);
        }
        Some(held.clone())
    }

    /// `camera` with its intrinsics scaled to `size`.
    pub fn sized(camera: &Camera, size: Option<(u32, u32)>) -> Result<Camera> {
        let Some((w, h)) = size else {
            return Ok(*camera);
        };
        if w == 0 || h == 0 || w > 1 << 14 || h > 1 << 14 {
            return Err(request(
                "size",
                format!("expected 1 to 16384 pixels each way, got {w}×{h}"),
            ));
        }
        let factor = camera.width() as f64 / w as f64;
        let mut c = *camera;
        c.intrinsics = camera.intrinsics.downscaled(factor, w, h);
        c.intrinsics.fy = camera.intrinsics.fy * h as f64 / camera.height() as f64;
        c.intrinsics.cy = camera.intrinsics.cy * h as f64 / camera.height() as f64;
        Ok(c)
    }

    /// Renders the scene as it is now: colour, z-depth, opacity, instance ids and, on
    /// request, per-node layers.
    pub fn render(&self, camera: &Camera, req: &RenderRequest) -> Result<Frame> {
        let camera = Self::sized(camera, req.size)?;
        self.check_camera(&camera)?;
        let frame = render_camera(
            &self.editor.scene,
            &camera,
            req.image.unwrap_or(u32::MAX),
            &self.options(req),
        );
        finished(req, frame)
    }

    /// Refuses a camera farther than [`MAX_CAMERA_RADII`] from the scene, or with a
    /// centre that is not finite.
    pub fn check_camera(&self, camera: &Camera) -> Result<()> {
        let eye = camera.pose.center();
        let (lo, hi) = self
            .description()
            .nodes
            .iter()
            .flat_map(|n| n.world_corners())
            .fold(
                (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                |(lo, hi), c| (lo.min(c), hi.max(c)),
            );
        if !lo.is_finite() || !hi.is_finite() {
            return Ok(());
        }
        let radius = ((hi - lo).length() / 2.0).max(1e-6);
        let far = eye.distance((lo + hi) / 2.0) / radius;
        if far.is_finite() && far <= MAX_CAMERA_RADII {
            return Ok(());
        }
        Err(request(
            "camera",
            format!(
                "its centre {} is {} scene radii from the scene's centre; expected at most {MAX_CAMERA_RADII} (the scene's radius is {})",
                assist_core::fmt_vec(&eye.to_array()),
                assist_core::fmt_num(far),
                assist_core::fmt_num(radius)
            ),
        ))
    }

    /// Renders like [`Session::render`], keeping in `cache` what does not change while node
    /// `moving` alone is edited under the same camera (a drag): then only that node is
    /// sampled and queried again. The image is the same as `render`'s.
    pub fn render_moving(
        &self,
        camera: &Camera,
        req: &RenderRequest,
        moving: InstanceId,
        cache: &mut DragCache,
    ) -> Result<Frame> {
        let camera = Self::sized(camera, req.size)?;
        self.check_camera(&camera)?;
        let frame = render_camera_moving(
            &self.editor.scene,
            &camera,
            req.image.unwrap_or(u32::MAX),
            &self.options(req),
            moving,
            cache,
        );
        finished(req, frame)
    }

    /// Renders the ray of pixel `(x, y)` alone: the ray and its composited outputs
    /// (`None` when the pixel has no ray); `what` names the request in errors.
    fn trace_pixel(
        &self,
        what: &str,
        camera: &Camera,
        x: f64,
        y: f64,
    ) -> Result<Option<(assist_core::Ray, RenderScratch)>> {
        let (w, h) = (camera.width() as f64, camera.height() as f64);
        if !(0.0..w).contains(&x) || !(0.0..h).contains(&y) {
            return Err(request(
                what,
                format!("pixel ({x}, {y}) is outside the {w}×{h} image"),
            ));
        }
        self.check_camera(camera)?;
        let Some(ray) = camera.ray(x, y) else {
            return Ok(None);
        };
        let scene = &self.editor.scene;
        let mut sc = RenderScratch::default();
        sc.rays.near = scene.scene.near as f32;
        sc.rays.push(&ray, u32::MAX);
        render_rays(scene, &self.options(&RenderRequest::default()), &mut sc);
        Ok(Some((ray, sc)))
    }

    /// The node seen at pixel `(x, y)` of `camera` (the one with the largest share of
    /// the composited weight, as in the instance output); `None` for the background or
    /// nothing.
    pub fn pick(&self, camera: &Camera, x: f64, y: f64) -> Result<Option<InstanceId>> {
        let Some((_, sc)) = self.trace_pixel("pick", camera, x, y)? else {
            return Ok(None);
        };
        let nodes = &self.editor.scene.scene.nodes;
        Ok(sc.out.winner(0).and_then(|k| {
            let n = &nodes[k];
            (!n.is_background()).then_some(n.id)
        }))
    }

    /// The world point of the surface seen at pixel `(x, y)` of `camera` (the expected
    /// depth of the composited weight along the pixel's ray); `None` where the ray meets
    /// nearly nothing.
    pub fn surface(&self, camera: &Camera, x: f64, y: f64) -> Result<Option<DVec3>> {
        let Some((ray, sc)) = self.trace_pixel("surface", camera, x, y)? else {
            return Ok(None);
        };
        let c = sc.out.rays[0];
        if c.opacity < 0.5 {
            return Ok(None);
        }
        Ok(Some(ray.origin + ray.dir * (c.depth / c.opacity) as f64))
    }
}

/// The frame, or [`SessionError::Cancelled`] when the request's flag stopped it.
fn finished(req: &RenderRequest, frame: Frame) -> Result<Frame> {
    match &req.cancel {
        Some(c) if c.load(Ordering::Relaxed) => Err(SessionError::Cancelled),
        _ => Ok(frame),
    }
}
