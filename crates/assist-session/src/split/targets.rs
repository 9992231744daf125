//! The objects a user asks for, as text: boxes `"cx,cy,cz,sx,sy,sz[,yaw]"` and clicks
//! `"VIEW:u,v"`, read, found in the scene (a click's box from [`click::box_at_click`]),
//! named and checked against the scene (inside the captured region, over no object it
//! has). `assist dataset masks`, `assist scene split`, the viewer and Python share them.

use assist_core::{Camera, DMat3, DVec3, InstanceId, Obb};
use assist_data::{Dataset, Frame, Split};

use super::SplitBox;
use super::click::{self, ClickOptions, RENDER_DOWNSCALE};
use crate::{Result, Session, request};

/// Comma-separated numbers; `None` when one is not a number.
fn numbers(text: &str) -> Option<Vec<f64>> {
    text.split(',')
        .map(|t| t.trim().parse::<f64>().ok())
        .collect()
}

/// `"cx,cy,cz,sx,sy,sz[,yaw]"` (centre, size along the box's axes, the last along `up`;
/// yaw in degrees about `up`) as a box standing upright along `up`.
pub fn parse_box(text: &str, up: DVec3) -> Result<Obb> {
    let bad = |m: &str| request("box", format!("{text:?}: {m}"));
    let v = numbers(text).ok_or_else(|| bad("expected numbers \"cx,cy,cz,sx,sy,sz[,yaw]\""))?;
    if !(v.len() == 6 || v.len() == 7) || v.iter().any(|x| !x.is_finite()) {
        return Err(bad(&format!(
            "expected 6 or 7 finite numbers \"cx,cy,cz,sx,sy,sz[,yaw]\", got {}",
            v.len()
        )));
    }
    if v[3..6].iter().any(|&s| s <= 0.0) {
        return Err(bad("expected sizes above 0"));
    }
    let yaw = v.get(6).copied().unwrap_or(0.0).to_radians();
    Ok(Obb::new(
        DVec3::new(v[0], v[1], v[2]),
        DVec3::new(v[3], v[4], v[5]),
        upright(up, yaw),
    ))
}

/// Axes of a box standing along `up`, turned by `yaw` about it: the third axis is up;
/// the first is the world's x (else y) made horizontal, turned.
pub fn upright(up: DVec3, yaw: f64) -> DMat3 {
    let up = up.normalize();
    let reference = [DVec3::X, DVec3::Y]
        .into_iter()
        .map(|a| a - up * a.dot(up))
        .find(|a| a.length() > 1e-6)
        .unwrap_or(DVec3::X)
        .normalize();
    let x = reference * yaw.cos() + up.cross(reference) * yaw.sin();
    DMat3::from_cols(x, up.cross(x), up)
}

/// `"VIEW:u,v"`: the frame of `ds` (by index, or by file name with or without its
/// extension) and the pixel of its full-size image.
pub fn parse_click<'a>(text: &str, ds: &'a Dataset) -> Result<(&'a Frame, (f64, f64))> {
    let bad = |m: String| request("click", format!("{text:?}: {m}"));
    let (view, px) = text
        .rsplit_once(':')
        .ok_or_else(|| bad("expected \"VIEW:u,v\"".into()))?;
    let uv = numbers(px).ok_or_else(|| bad("expected pixels \"u,v\" after the colon".into()))?;
    let [u, v] = uv[..] else {
        return Err(bad("expected two numbers \"u,v\" after the colon".into()));
    };
    let frame = match view.parse::<usize>() {
        Ok(k) => ds.frames.get(k).ok_or_else(|| {
            bad(format!(
                "view {k} does not exist ({} frames, 0 to {})",
                ds.frames.len(),
                ds.frames.len().saturating_sub(1)
            ))
        })?,
        Err(_) => ds
            .frames
            .iter()
            .find(|f| {
                f.image_path
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy() == view)
                    || assist_data::dataset::file_stem(&f.image_path) == view
            })
            .ok_or_else(|| bad(format!("no frame named {view:?} in {}", ds.root.display())))?,
    };
    let (w, h) = (frame.camera.width() as f64, frame.camera.height() as f64);
    if !(u >= 0.0 && v >= 0.0 && u < w && v < h) {
        return Err(bad(format!(
            "({u}, {v}) is outside the image ({w}×{h} pixels)"
        )));
    }
    Ok((frame, (u, v)))
}

/// The objects asked for, as a user gives them (`assist dataset masks`, `assist scene
/// split`, Python): boxes, clicks, names, a boxes file, and the size they are found at.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct Objects {
    /// An object's box in the scene's world units: "cx,cy,cz,sx,sy,sz[,yaw]" (centre,
    /// size along the box's axes, the last along the scene's up; yaw in degrees about
    /// up). Repeat for several objects.
    #[arg(long = "box", value_name = "BOX")]
    pub boxes: Vec<String>,
    /// An object under a pixel of a view: "VIEW:u,v" (VIEW a frame's index or file name,
    /// u,v pixels of the full-size image); its box is found from the scene and reported.
    /// Repeat for several objects.
    #[arg(long = "click", value_name = "VIEW:u,v")]
    pub clicks: Vec<String>,
    /// Boxes from a file (as `assist dataset boxes --json` writes them), before --box.
    #[arg(long, value_name = "FILE")]
    pub boxes_file: Option<std::path::PathBuf>,
    /// The objects' names: those of --boxes-file and --box first, then those of --click,
    /// each in the order given (default "object N", N its id).
    #[arg(long = "label", value_name = "NAME")]
    pub labels: Vec<String>,
    /// Render N times smaller than the images to find boxes and masks (the masks are
    /// then refined at full size).
    #[arg(long, default_value_t = RENDER_DOWNSCALE, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub render_downscale: u32,
    /// A Segment Anything checkpoint you supply (Meta's sam_vit_b_01ec64.pth or any
    /// size, .pth or .safetensors): each photograph's object masks are prompted with
    /// their box and innermost pixel, and SAM's mask replaces the geometric one where the
    /// two agree (IoU ≥ 0.7). Slow on a CPU (seconds per photograph for ViT-B).
    #[arg(long, value_name = "CHECKPOINT")]
    pub sam: Option<std::path::PathBuf>,
}

impl Default for Objects {
    fn default() -> Self {
        Objects {
            boxes: Vec::new(),
            clicks: Vec::new(),
            boxes_file: None,
            labels: Vec::new(),
            render_downscale: RENDER_DOWNSCALE,
            sam: None,
        }
    }
}

impl Objects {
    /// What they ask for in `up`'s scene: the boxes read (the file's first), the clicks
    /// and the names.
    pub fn targets(&self, up: DVec3) -> Result<Targets> {
        Targets::parse(&self.boxes, &self.clicks, &self.labels, up)?
            .with_file(self.boxes_file.as_deref())
    }
}

/// What a user asked for: boxes (with a name a boxes file may give), clicks, and names in
/// the order boxes then clicks.
#[derive(Debug, Clone, Default)]
pub struct Targets {
    pub boxes: Vec<(Obb, Option<String>)>,
    pub clicks: Vec<String>,
    pub labels: Vec<String>,
}

/// The most objects one call makes (masks are 8-bit images).
pub const MAX_OBJECTS: usize = 255;

impl Targets {
    /// Boxes as text (`"cx,cy,cz,sx,sy,sz[,yaw]"`, upright along `up`), clicks and labels.
    pub fn parse(
        boxes: &[String],
        clicks: &[String],
        labels: &[String],
        up: DVec3,
    ) -> Result<Self> {
        Ok(Targets {
            boxes: boxes
                .iter()
                .map(|t| parse_box(t, up).map(|b| (b, None)))
                .collect::<Result<_>>()?,
            clicks: clicks.to_vec(),
            labels: labels.to_vec(),
        })
    }

    /// With the boxes of a file (as `assist dataset boxes --json` writes them) before
    /// the others.
    pub fn with_file(mut self, file: Option<&std::path::Path>) -> Result<Self> {
        if let Some(p) = file {
            let listed = assist_data::boxes::read_boxes(p).map_err(crate::SessionError::Data)?;
            let given = std::mem::take(&mut self.boxes);
            self.boxes = listed.into_iter().map(|b| (b.bbox, b.label)).collect();
            self.boxes.extend(given);
        }
        Ok(self)
    }

    /// The objects as boxes in `session`'s scene with ids from `first_id` on, boxes first
    /// and then clicks, each click's box found over `ds`'s training views; `on_click` is
    /// told each click's box. Refused: no object, too many, more labels than objects, a
    /// click on nothing that stands apart from its support, a box outside the captured
    /// region or over an object the scene has.
    pub fn resolve(
        &self,
        session: &Session,
        ds: &Dataset,
        first_id: InstanceId,
        render_downscale: u32,
        mut on_click: impl FnMut(&str, &Obb),
    ) -> Result<Vec<SplitBox>> {
        let n = self.boxes.len() + self.clicks.len();
        if n == 0 {
            return Err(request(
                "objects",
                "expected at least one object: a box \"cx,cy,cz,sx,sy,sz[,yaw]\" or a click \"VIEW:u,v\"".into(),
            ));
        }
        if n > MAX_OBJECTS || first_id as usize + n - 1 > MAX_OBJECTS {
            return Err(request(
                "objects",
                format!(
                    "at most {MAX_OBJECTS} objects in a scene with masks (8-bit images), asked for {n} more from id {first_id}"
                ),
            ));
        }
        if self.labels.len() > n {
            return Err(request(
                "label",
                format!(
                    "{} labels for {n} objects: give one label per box or click, in the same order",
                    self.labels.len()
                ),
            ));
        }
        let cameras: Vec<Camera> = ds
            .frames
            .iter()
            .filter(|f| f.split == Split::Train)
            .map(|f| f.camera)
            .collect();
        let mut obbs = self.boxes.clone();
        for c in &self.clicks {
            let (frame, uv) = parse_click(c, ds)?;
            let opts = ClickOptions {
                render_downscale,
                ..ClickOptions::default()
            };
            let obb =
                click::box_at_click(session, &frame.camera, uv, &cameras, &opts).map_err(|e| {
                    match e {
                        crate::SessionError::Request { message, .. } => {
                            request("click", format!("{c:?}: {message}"))
                        }
                        e => e,
                    }
                })?;
            on_click(c, &obb);
            obbs.push((obb, None));
        }
        let boxes: Vec<SplitBox> = obbs
            .into_iter()
            .enumerate()
            .map(|(k, (obb, file_label))| SplitBox {
                id: first_id + k as InstanceId,
                label: self
                    .labels
                    .get(k)
                    .cloned()
                    .or(file_label)
                    .unwrap_or_else(|| format!("object {}", first_id as usize + k)),
                obb,
            })
            .collect();
        check_inside(&boxes, session)?;
        Ok(boxes)
    }
}

/// Each box must overlap the scene's captured region and no existing object node.
pub fn check_inside(boxes: &[SplitBox], session: &Session) -> Result<()> {
    let scene = session.description();
    for b in boxes {
        let bb = b.obb.world_aabb();
        for n in &scene.nodes {
            let mut nb = assist_core::Aabb::empty();
            for c in n.world_corners() {
                nb.extend(c);
            }
            let overlap = bb.min.cmplt(nb.max).all() && nb.min.cmplt(bb.max).all();
            if n.is_background() && !overlap {
                return Err(request(
                    "box",
                    format!(
                        "the box of {} lies outside the captured region ({} to {}): give its centre and size in the scene's world units (`assist scene info` shows the region)",
                        b.label,
                        assist_core::fmt_vec(&nb.min.to_array()),
                        assist_core::fmt_vec(&nb.max.to_array())
                    ),
                ));
            }
            if !n.is_background() && overlap {
                return Err(request(
                    "box",
                    format!(
                        "the box of {} overlaps the object {} ({}): an object the scene already has cannot be made again",
                        b.label, n.id, n.label
                    ),
                ));
            }
        }
    }
    Ok(())
}
