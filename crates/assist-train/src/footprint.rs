//! What the photographs' pixels resolve: how far the content the training views see lies
//! from them, and the background's finest hash-grid resolution that follows from it.
//!
//! Nerfacto's finest level (2048 cells across the field's [0, 1]³ cube) is one fixed
//! number, whatever the capture. Where the cameras stand close to what they film, inside
//! a large inner box, a cell of it spans several pixels (gold_cape at `--downscale 2`:
//! about four on the object), and detail finer than a cell cannot be learnt, on the
//! training views either. `train --grid-resolution auto` sets the background's finest
//! level so that one cell spans about one pixel at the median depth of what the views
//! see. It helped a walk-around and cost forward-facing captures, so it is the default of
//! unbounded walk-arounds only ([`crate::WalkAroundDefaults`]) and Nerfacto's number stays
//! everyone else's (measured in BENCHMARKS.md).

use assist_core::{DVec3, NodeSpace};
use assist_data::Dataset;
use rayon::prelude::*;

use crate::views::View;

/// The least finest resolution a background gets: Nerfacto's.
pub const MIN_GRID_RESOLUTION: u32 = 2048;

/// The most: finer levels hash more of the scene into the same table for pixels no view
/// resolves better (Nerfacto-huge's finest level).
pub const MAX_GRID_RESOLUTION: u32 = 8192;

/// The background's finest hash-grid resolution as asked for: a number of cells, or
/// `auto` (one cell per pixel at the views' median depth, [`background_resolution`]).
/// Written as the number or the word (command line, config files, recorded configs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "serde_json::Value", into = "serde_json::Value")]
pub enum GridResolution {
    Auto,
    Cells(u32),
}

impl Default for GridResolution {
    /// Nerfacto's finest level.
    fn default() -> Self {
        GridResolution::Cells(MIN_GRID_RESOLUTION)
    }
}

impl GridResolution {
    /// The word `auto` or a whole number of cells (any other range is the caller's to
    /// check).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim() {
            "auto" => Some(GridResolution::Auto),
            n => n.parse().ok().map(GridResolution::Cells),
        }
    }

    /// The cells a background of half-size `half` in `space` gets for `ds` and `views`.
    pub fn resolve(self, ds: &Dataset, views: &[View], half: DVec3, space: NodeSpace) -> u32 {
        match self {
            GridResolution::Auto => background_resolution(ds, views, half, space),
            GridResolution::Cells(n) => n,
        }
    }
}

impl std::fmt::Display for GridResolution {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GridResolution::Auto => f.write_str("auto"),
            GridResolution::Cells(n) => write!(f, "{n}"),
        }
    }
}

impl From<GridResolution> for serde_json::Value {
    fn from(g: GridResolution) -> Self {
        match g {
            GridResolution::Auto => "auto".into(),
            GridResolution::Cells(n) => n.into(),
        }
    }
}

impl TryFrom<serde_json::Value> for GridResolution {
    type Error = String;
    fn try_from(v: serde_json::Value) -> Result<Self, String> {
        let parsed = match &v {
            serde_json::Value::String(s) => GridResolution::parse(s),
            serde_json::Value::Number(n) => n
                .as_u64()
                .and_then(|n| u32::try_from(n).ok())
                .map(GridResolution::Cells),
            _ => None,
        };
        parsed.ok_or_else(|| format!("expected a number of cells or \"auto\", got {v}"))
    }
}

/// The `pct`-th percentile (0–100) of the depths of what the views see: their depth maps
/// (every 7th pixel) where they have them, else the sparse points each view sees (at
/// most ~20k of them, every k-th: the percentile needs no more); `None` with fewer than
/// 100 depths.
pub fn content_depth_percentile(points: &[DVec3], views: &[View], pct: usize) -> Option<f64> {
    let pick = |mut d: Vec<f64>| {
        (d.len() >= 100).then(|| {
            let k = (d.len() * pct / 100).min(d.len() - 1);
            *d.select_nth_unstable_by(k, f64::total_cmp).1
        })
    };
    let seen: Vec<f64> = views
        .par_iter()
        .flat_map_iter(|v| {
            v.depth
                .iter()
                .flat_map(|d| d.iter().step_by(7))
                .filter(|&&z| z > 0.0)
                .map(|&z| z as f64)
        })
        .collect();
    if let Some(z) = pick(seen) {
        return Some(z);
    }
    let stride = points.len().div_ceil(20_000).max(1);
    let depths: Vec<f64> = views
        .par_iter()
        .flat_map_iter(|v| {
            points.iter().step_by(stride).filter_map(move |&p| {
                let (px, z) = v.camera.project(p)?;
                let inside =
                    px.x >= 0.0 && px.y >= 0.0 && px.x < v.width as f64 && px.y < v.height as f64;
                (inside && z > 0.0).then_some(z)
            })
        })
        .collect();
    pick(depths)
}

/// The background's finest hash-grid resolution for a node of half-size `half` in
/// `space` ([`footprint_resolution`]): at the median depth of what the views see (the
/// LLFF bounds' geometric mean where nothing else tells it), with the views' median
/// focal length.
pub fn background_resolution(ds: &Dataset, views: &[View], half: DVec3, space: NodeSpace) -> u32 {
    let depth = content_depth_percentile(&ds.points, views, 50).or(match ds.depth_range {
        Some((near, far)) if near > 0.0 && far > near => Some((near * far).sqrt()),
        _ => None,
    });
    let mut focal: Vec<f64> = views.iter().map(|v| v.camera.intrinsics.fx).collect();
    focal.sort_by(f64::total_cmp);
    match (depth, focal.get(focal.len() / 2)) {
        (Some(depth), Some(&f)) => footprint_resolution(depth, f, half, space),
        _ => MIN_GRID_RESOLUTION,
    }
}

/// The cells across a field's [0, 1]³ cube (the box itself, or for a contracted node the
/// box and its shell: four half-sizes) that make one cell, along the box's longest axis,
/// as wide as a pixel of focal length `focal` (in pixels) at `depth`; within
/// [`MIN_GRID_RESOLUTION`, `MAX_GRID_RESOLUTION`].
pub fn footprint_resolution(depth: f64, focal: f64, half: DVec3, space: NodeSpace) -> u32 {
    let span = match space {
        NodeSpace::Box => 2.0,
        NodeSpace::Contracted => 4.0,
    } * half.max_element();
    let cells = span * focal / depth;
    if !cells.is_finite() || cells <= 0.0 {
        return MIN_GRID_RESOLUTION;
    }
    cells
        .round()
        .clamp(MIN_GRID_RESOLUTION as f64, MAX_GRID_RESOLUTION as f64) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_cell_per_pixel_at_the_given_depth_within_the_bounds() {
        let half = DVec3::new(1.0, 3.0, 2.0);
        // 6 units across the box (its longest axis), a pixel of 1/1000 at depth 2: 3000.
        assert_eq!(
            footprint_resolution(2.0, 1000.0, half, NodeSpace::Box),
            3000
        );
        // A contracted node's cube also holds the shell: twice the cells.
        assert_eq!(
            footprint_resolution(2.0, 1000.0, half, NodeSpace::Contracted),
            6000
        );
        // Pixels coarser than Nerfacto's cells keep them; finer ones stop at the most.
        assert_eq!(
            footprint_resolution(20.0, 1000.0, half, NodeSpace::Box),
            MIN_GRID_RESOLUTION
        );
        assert_eq!(
            footprint_resolution(0.2, 1000.0, half, NodeSpace::Box),
            MAX_GRID_RESOLUTION
        );
        for bad in [0.0, -1.0, f64::NAN] {
            assert_eq!(
                footprint_resolution(bad, 1000.0, half, NodeSpace::Box),
                MIN_GRID_RESOLUTION
            );
        }
    }

    #[test]
    fn grid_resolution_reads_and_writes_a_number_or_auto() {
        assert_eq!(GridResolution::parse("auto"), Some(GridResolution::Auto));
        assert_eq!(
            GridResolution::parse("4096"),
            Some(GridResolution::Cells(4096))
        );
        assert_eq!(GridResolution::parse("fine"), None);
        assert_eq!(GridResolution::parse("-1"), None);
        for g in [GridResolution::Auto, GridResolution::Cells(3000)] {
            let v = serde_json::to_value(g).unwrap();
            assert_eq!(serde_json::from_value::<GridResolution>(v).unwrap(), g);
            assert_eq!(GridResolution::parse(&g.to_string()), Some(g));
        }
        let e = serde_json::from_value::<GridResolution>(serde_json::json!(1.5)).unwrap_err();
        assert!(e.to_string().contains("auto"), "{e}");
        assert_eq!(GridResolution::default(), GridResolution::Cells(2048));
    }

    #[test]
    fn depth_percentiles_from_depth_maps_else_points() {
        // The view stands at z = 1 looking at the origin: a point (0, 0, 1 − d) lies d in
        // front of it, on its axis.
        let mut views = vec![View::blank(32, 24)];
        let points: Vec<DVec3> = (1..=200)
            .map(|k| DVec3::new(0.0, 0.0, 1.0 - 0.01 * k as f64))
            .collect();
        let behind = [DVec3::new(0.0, 0.0, 5.0)];
        let p50 = content_depth_percentile(&points, &views, 50).unwrap();
        assert!((p50 - 1.01).abs() < 1e-9, "{p50}");
        let p1 = content_depth_percentile(&points, &views, 1).unwrap();
        assert!((p1 - 0.03).abs() < 1e-9, "{p1}");
        // Points behind the camera count for nothing; fewer than 100 depths say nothing.
        assert_eq!(content_depth_percentile(&behind, &views, 50), None);
        assert_eq!(content_depth_percentile(&points[..99], &views, 50), None);
        // Depth maps, where the views have them, come first.
        views[0].depth = Some(vec![0.5; 32 * 24]);
        assert_eq!(content_depth_percentile(&points, &views, 50), Some(0.5));
    }
}
