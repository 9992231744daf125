//! `EmbedJob`: each node's CLIP embedding, the paper's fourth scene-node field, from the
//! training views of the capture the scene was trained on.
//!
//! Crops (docs/embeddings.md):
//! - an object is cropped in each training view where its instance mask has at least
//!   [`MIN_PIXELS`] pixels and at least a quarter of its largest view's count; up to
//!   `views` of those views, spread evenly over the capture order;
//! - the crop is the square around the mask's bounding box, [`CONTEXT`] times its longer
//!   side (some surroundings: "a mug on a desk"), shifted to stay inside the image where
//!   it fits; what falls outside is the model's mean colour;
//! - pixels of *other* objects in the crop are painted the model's mean colour, so that
//!   a neighbour does not lend its features;
//! - the background node's crops are whole training views with every object painted out;
//! - the embedding is the normalised mean of the crops' normalised image embeddings.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use assist_clip::{Clip, normalize};
use assist_core::InstanceId;
use assist_data::{LoadOptions, Split};
use image::RgbImage;
use serde::Serialize;

use crate::{Result, Session, SessionError, request};

/// A view counts for an object when its mask has at least this many pixels.
pub const MIN_PIXELS: usize = 16;
/// The crop's side over the mask box's longer side.
pub const CONTEXT: f64 = 1.25;
/// Default number of views per node.
pub const DEFAULT_EMBED_VIEWS: usize = 12;

#[derive(Debug, Clone)]
pub struct EmbedJob {
    /// The capture the scene was trained on.
    pub data: PathBuf,
    pub load: LoadOptions,
    /// Views per node (at most).
    pub views: usize,
    /// Replace embeddings the scene already has.
    pub replace: bool,
}

impl EmbedJob {
    pub fn new(data: PathBuf) -> Self {
        EmbedJob {
            data,
            load: LoadOptions::default(),
            views: DEFAULT_EMBED_VIEWS,
            replace: false,
        }
    }
}

/// One node's embedding as made.
#[derive(Debug, Clone, Serialize)]
pub struct EmbeddedNode {
    pub id: InstanceId,
    pub label: String,
    /// Crops averaged (0: the node was seen in no view; it keeps what it had).
    pub crops: usize,
    /// Views the crops came from.
    pub views: Vec<String>,
    /// Mean cosine similarity of the crops' embeddings to their mean (1 = all alike).
    pub agreement: f32,
}

#[derive(Debug, Clone, Serialize)]
pub struct EmbedSummary {
    pub model: String,
    pub dim: usize,
    pub nodes: Vec<EmbeddedNode>,
    /// Nodes without masks in the capture (added by edits) given their source's embedding.
    pub shared: Vec<InstanceId>,
    pub crops: usize,
    pub seconds: f64,
}

/// Progress: views being read, then each node embedded.
#[derive(Debug, Clone)]
pub enum EmbedEvent {
    Reading {
        views: usize,
    },
    Node {
        done: usize,
        of: usize,
        id: InstanceId,
        crops: usize,
    },
}

fn to_u8(rgb: &[f32]) -> Vec<u8> {
    rgb.iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
}

/// The square crop around `(x0, y0)–(x1, y1)` (inclusive pixel box), `size` pixels a
/// side, with pixels where `paint` is true and outside the image set to `fill`.
#[allow(clippy::too_many_arguments)]
fn crop(
    rgb: &[u8],
    w: usize,
    h: usize,
    bbox: (usize, usize, usize, usize),
    context: f64,
    paint: &dyn Fn(usize) -> bool,
    fill: [u8; 3],
    size: u32,
) -> RgbImage {
    let (x0, y0, x1, y1) = bbox;
    let bw = (x1 - x0 + 1) as f64;
    let bh = (y1 - y0 + 1) as f64;
    let side = (bw.max(bh) * context).ceil().max(1.0);
    let cx = (x0 + x1 + 1) as f64 / 2.0;
    let cy = (y0 + y1 + 1) as f64 / 2.0;
    // Shift into the image where the square fits.
    let place = |c: f64, len: usize| {
        let mut lo = c - side / 2.0;
        if side <= len as f64 {
            lo = lo.clamp(0.0, len as f64 - side);
        }
        lo
    };
    let (left, top) = (place(cx, w), place(cy, h));
    let n = side as u32;
    let sq = RgbImage::from_fn(n, n, |i, j| {
        let x = (left + i as f64).floor();
        let y = (top + j as f64).floor();
        if x < 0.0 || y < 0.0 || x >= w as f64 || y >= h as f64 {
            return image::Rgb(fill);
        }
        let k = y as usize * w + x as usize;
        if paint(k) {
            image::Rgb(fill)
        } else {
            image::Rgb([rgb[3 * k], rgb[3 * k + 1], rgb[3 * k + 2]])
        }
    });
    if n == size {
        sq
    } else {
        image::imageops::resize(&sq, size, size, image::imageops::FilterType::CatmullRom)
    }
}

/// `k` of `items` spread evenly (all when there are fewer).
fn spread<T: Clone>(items: &[T], k: usize) -> Vec<T> {
    if items.len() <= k {
        return items.to_vec();
    }
    (0..k)
        .map(|i| items[(i * items.len() + items.len() / 2) / k].clone())
        .collect()
}

/// Per object id in a view: its pixel count and box (x0, y0, x1, y1).
type Boxes = BTreeMap<u16, (usize, (usize, usize, usize, usize))>;

/// A training view as the crops need it: colour as bytes, ids, and its objects' boxes.
struct Seen {
    name: String,
    width: usize,
    height: usize,
    rgb: Vec<u8>,
    ids: Option<Vec<u16>>,
    boxes: Boxes,
}

/// The training views `frames`, read in parallel.
fn read_views(frames: &[&assist_data::Frame], bg: [f32; 3]) -> Result<Vec<Seen>> {
    use rayon::prelude::*;
    frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| {
            let v = assist_train::load_view(f, i as u32, bg)?;
            let mut boxes: Boxes = BTreeMap::new();
            if let Some(ids) = &v.ids {
                for (k, &id) in ids.iter().enumerate() {
                    if id == 0 {
                        continue;
                    }
                    let (x, y) = (k % v.width, k / v.width);
                    let e = boxes.entry(id).or_insert((0, (x, y, x, y)));
                    e.0 += 1;
                    let b = &mut e.1;
                    *b = (b.0.min(x), b.1.min(y), b.2.max(x), b.3.max(y));
                }
            }
            Ok(Seen {
                name: v.name,
                width: v.width,
                height: v.height,
                rgb: to_u8(&v.rgb),
                ids: v.ids,
                boxes,
            })
        })
        .collect::<std::result::Result<_, assist_train::TrainError>>()
        .map_err(SessionError::Train)
}

/// A node's crops (at most `per_node`, spread over the views) and their views' names:
/// the background's centre squares with the objects painted over, or an object's box
/// with context in the views that see enough of it, other objects painted over.
fn node_crops(
    views: &[Seen],
    id: InstanceId,
    is_bg: bool,
    per_node: usize,
    fill: [u8; 3],
    size: u32,
) -> (Vec<RgbImage>, Vec<String>) {
    let mut crops = Vec::new();
    let mut names = Vec::new();
    if is_bg {
        for vi in spread(&(0..views.len()).collect::<Vec<_>>(), per_node) {
            let v = &views[vi];
            let ids = v.ids.as_deref();
            let paint = |p: usize| ids.is_some_and(|ids| ids[p] != 0);
            let whole = (0, 0, v.width - 1, v.height - 1);
            // The centre square of the view, as CLIP's transform would take.
            let side = v.width.min(v.height);
            let (x0, y0) = ((v.width - side) / 2, (v.height - side) / 2);
            let b = if side > 0 {
                (x0, y0, x0 + side - 1, y0 + side - 1)
            } else {
                whole
            };
            crops.push(crop(&v.rgb, v.width, v.height, b, 1.0, &paint, fill, size));
            names.push(v.name.clone());
        }
    } else {
        let counts: Vec<(usize, usize)> = views
            .iter()
            .enumerate()
            .filter_map(|(vi, v)| v.boxes.get(&id).map(|e| (vi, e.0)))
            .collect();
        let most = counts.iter().map(|c| c.1).max().unwrap_or(0);
        let good: Vec<usize> = counts
            .iter()
            .filter(|c| c.1 >= MIN_PIXELS && c.1 * 4 >= most)
            .map(|c| c.0)
            .collect();
        for vi in spread(&good, per_node) {
            let v = &views[vi];
            let ids = v.ids.as_deref().unwrap_or(&[]);
            let paint = |p: usize| ids[p] != 0 && ids[p] != id;
            let b = v.boxes[&id].1;
            crops.push(crop(
                &v.rgb, v.width, v.height, b, CONTEXT, &paint, fill, size,
            ));
            names.push(v.name.clone());
        }
    }
    (crops, names)
}

impl Session {
    /// Embeds the scene's nodes with `clip` from the training views of `job.data` and
    /// stores the embeddings in the scene (save it to keep them). Nodes that already have
    /// one are refused unless `job.replace`.
    pub fn embed(
        &mut self,
        clip: &Clip,
        job: &EmbedJob,
        progress: &mut dyn FnMut(EmbedEvent),
    ) -> Result<EmbedSummary> {
        let t0 = Instant::now();
        if job.views == 0 {
            return Err(request("views", "expected at least 1 view per node".into()));
        }
        if !job.replace
            && let Some(n) = self.nodes().iter().find(|n| n.embedding.is_some())
        {
            return Err(request(
                "embed",
                format!(
                    "node {} {:?} already has an embedding; pass --force to replace the scene's embeddings",
                    n.id, n.label
                ),
            ));
        }
        let ds = assist_data::load(&job.data, &job.load).map_err(SessionError::Data)?;
        if let Some(before) = self
            .info()
            .get("dataset_fingerprint")
            .and_then(|v| v.as_str())
            && before != ds.fingerprint()
        {
            return Err(request(
                "embed",
                format!(
                    "{} is not the capture this scene was trained on (fingerprint {} against the scene's {before})",
                    job.data.display(),
                    ds.fingerprint()
                ),
            ));
        }
        let frames: Vec<&assist_data::Frame> = ds.frames_in(Split::Train).collect();
        progress(EmbedEvent::Reading {
            views: frames.len(),
        });
        let views = read_views(&frames, assist_train::background_color(&ds))?;
        let c = clip.config();
        let size = c.vision.image_size as u32;
        let fill = [0, 1, 2].map(|k| (c.mean[k] * 255.0).round() as u8);
        let nodes: Vec<(InstanceId, String, String, bool)> = self
            .nodes()
            .iter()
            .map(|n| (n.id, n.label.clone(), n.field.clone(), n.is_background()))
            .collect();
        let mut by_field: BTreeMap<String, Vec<f32>> = BTreeMap::new();
        let mut done = Vec::new();
        let mut total = 0;
        let of = nodes.len();
        for (k, (id, label, field, is_bg)) in nodes.iter().enumerate() {
            if by_field.contains_key(field) {
                continue;
            }
            let (crops, names) = node_crops(&views, *id, *is_bg, job.views, fill, size);
            if crops.is_empty() {
                done.push(EmbeddedNode {
                    id: *id,
                    label: label.clone(),
                    crops: 0,
                    views: Vec::new(),
                    agreement: 0.0,
                });
                continue;
            }
            let feats: Vec<Vec<f32>> = clip
                .embed_images(&crops)
                .map_err(|e| request("embed", e.to_string()))?
                .iter()
                .map(|f| normalize(f))
                .collect();
            let mut mean = vec![0f32; c.embed_dim];
            for f in &feats {
                for (m, v) in mean.iter_mut().zip(f) {
                    *m += v;
                }
            }
            let mean = normalize(&mean);
            let agreement = feats
                .iter()
                .map(|f| f.iter().zip(&mean).map(|(a, b)| a * b).sum::<f32>())
                .sum::<f32>()
                / feats.len() as f32;
            total += crops.len();
            progress(EmbedEvent::Node {
                done: k + 1,
                of,
                id: *id,
                crops: crops.len(),
            });
            by_field.insert(field.clone(), mean);
            done.push(EmbeddedNode {
                id: *id,
                label: label.clone(),
                crops: crops.len(),
                views: names,
                agreement,
            });
        }
        let shared: Vec<InstanceId> = nodes
            .iter()
            .filter(|(id, _, field, _)| {
                by_field.contains_key(field) && !done.iter().any(|d| d.id == *id)
            })
            .map(|n| n.0)
            .collect();
        self.editor.set_embeddings(&by_field);
        Ok(EmbedSummary {
            model: clip.files.weights.display().to_string(),
            dim: c.embed_dim,
            nodes: done,
            shared,
            crops: total,
            seconds: t0.elapsed().as_secs_f64(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_are_square_around_the_mask_and_paint_others() {
        // 20×10 image: red everywhere, a 4×2 object at x 8..12, y 4..6.
        let (w, h) = (20, 10);
        let rgb: Vec<u8> = (0..w * h).flat_map(|_| [200, 0, 0]).collect();
        let others = |p: usize| p % w < 2; // the first two columns are another object
        let c = crop(&rgb, w, h, (8, 4, 11, 5), 1.25, &others, [1, 2, 3], 5);
        // side = ceil(4 · 1.25) = 5: no resize.
        assert_eq!(c.dimensions(), (5, 5));
        assert!(c.pixels().all(|p| p.0 == [200, 0, 0]));
        // A box at the left edge: shifted inside, the painted columns show.
        let c = crop(&rgb, w, h, (0, 0, 3, 3), 2.0, &others, [1, 2, 3], 8);
        assert_eq!(c.get_pixel(0, 0).0, [1, 2, 3]);
        assert_eq!(c.get_pixel(2, 0).0, [200, 0, 0]);
        // Larger than the image: the outside is the fill colour.
        let c = crop(&rgb, w, h, (0, 0, 19, 9), 1.0, &|_| false, [1, 2, 3], 20);
        // (The square is 20 high, centred on the 10-high image: rows 5..15 are inside.)
        assert_eq!(c.get_pixel(10, 10).0, [200, 0, 0]);
        assert_eq!(c.get_pixel(10, 0).0, [1, 2, 3]);
        assert_eq!(c.get_pixel(10, 19).0, [1, 2, 3]);
    }

    #[test]
    fn spread_picks_evenly() {
        let v: Vec<usize> = (0..10).collect();
        // The middle of each of three equal parts.
        assert_eq!(spread(&v, 3), vec![1, 5, 8]);
        assert_eq!(spread(&v, 20).len(), 10);
    }
}
