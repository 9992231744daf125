//! Where an edit leaves objects: pushed into the surface under them, floating above what
//! should carry them, or inside one another. Each check compares a node after an edit
//! with the same node before it, so what the capture itself shows (boxes that touch, a
//! base a little off the table) is never blamed on the edit.

use glam::DVec3;

use crate::InstanceId;
use crate::scene::{Scene, SceneNode};

/// What an edit did wrong to one object.
#[derive(Debug, Clone, PartialEq)]
pub enum Problem {
    /// Its box reaches this far (metres) into another object's box.
    Overlap {
        other: InstanceId,
        other_label: String,
        depth_m: f64,
    },
    /// Its base lies this far (metres) above the highest thing under it; `support`
    /// names that thing (`None`: the background's surface).
    Floating {
        gap_m: f64,
        support: Option<InstanceId>,
    },
}

/// A [`Problem`] of node `id`.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub id: InstanceId,
    pub label: String,
    pub problem: Problem,
}

impl std::fmt::Display for Placement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.problem {
            Problem::Overlap {
                other,
                other_label,
                depth_m,
            } => write!(
                f,
                "node {} {:?} would reach {:.0} cm into node {other} {other_label:?}",
                self.id,
                self.label,
                depth_m * 100.0
            ),
            Problem::Floating { gap_m, support } => write!(
                f,
                "node {} {:?} would float {:.0} cm above {}",
                self.id,
                self.label,
                gap_m * 100.0,
                match support {
                    Some(o) => format!("node {o} under it"),
                    None => "the surface under it".into(),
                }
            ),
        }
    }
}

/// Overlaps and gaps smaller than this (metres), or no larger than before the edit by
/// [`MARGIN_M`], are the capture's own looseness, not the edit's doing.
pub const TOLERANCE_M: f64 = 0.03;
pub const MARGIN_M: f64 = 0.02;

/// Changed nodes checked per edit: each costs a look down through the background (some
/// 33,000 density queries), so an edit that makes hundreds of copies checks the first
/// ones and says how many it left unchecked.
pub const MAX_CHECKED: usize = 64;

/// The objects `after` leaves inside one another or floating that `before` did not: for
/// each node that is new or moved, resized or turned, a box reaching more than
/// [`TOLERANCE_M`] into another object's (and [`MARGIN_M`] deeper than before), or a base
/// more than [`TOLERANCE_M`] above what carries it (and [`MARGIN_M`] higher than before).
/// `density` is the background's, per world unit at world points. Returns the problems
/// and how many changed nodes past [`MAX_CHECKED`] were not checked.
pub fn placement_problems(
    before: &Scene,
    after: &Scene,
    density: &mut dyn FnMut(&[DVec3]) -> Vec<f32>,
) -> (Vec<Placement>, usize) {
    let mpu = after.meters_per_unit;
    let objects: Vec<&SceneNode> = after.objects().collect();
    let was = |id: InstanceId| before.nodes.iter().find(|b| b.id == id);
    let mut out = Vec::new();
    let (mut checked, mut unchecked) = (0, 0);
    for n in &objects {
        let old = was(n.id);
        if old
            .is_some_and(|b| b.world_from_local == n.world_from_local && b.half_size == n.half_size)
        {
            continue;
        }
        if checked == MAX_CHECKED {
            unchecked += 1;
            continue;
        }
        checked += 1;
        for o in objects.iter().filter(|o| o.id != n.id) {
            // A pair where both changed is reported once.
            let o_changed = was(o.id).is_none_or(|b| b.world_from_local != o.world_from_local);
            if o_changed && o.id < n.id {
                continue;
            }
            let depth = penetration(n, o) * mpu;
            let depth0 = match (old, was(o.id)) {
                (Some(a), Some(b)) => penetration(a, b) * mpu,
                _ => 0.0,
            };
            if depth > TOLERANCE_M && depth > depth0 + MARGIN_M {
                out.push(Placement {
                    id: n.id,
                    label: n.label.clone(),
                    problem: Problem::Overlap {
                        other: o.id,
                        other_label: o.label.clone(),
                        depth_m: depth,
                    },
                });
            }
        }
        let others: Vec<&SceneNode> = objects.iter().copied().filter(|o| o.id != n.id).collect();
        let Some((gap, support)) = support_gap(n, &others, after.up, mpu, density) else {
            continue;
        };
        let gap0 = old
            .and_then(|b| {
                let others: Vec<&SceneNode> = before.objects().filter(|o| o.id != b.id).collect();
                support_gap(b, &others, before.up, mpu, density)
            })
            .map_or(0.0, |g| g.0);
        if gap > TOLERANCE_M && gap > gap0 + MARGIN_M {
            out.push(Placement {
                id: n.id,
                label: n.label.clone(),
                problem: Problem::Floating {
                    gap_m: gap,
                    support,
                },
            });
        }
    }
    (out, unchecked)
}

/// How deep the boxes of `a` and `b` interpenetrate (world units): the least overlap of
/// their projections over the 15 separating axes of two boxes; 0 when they are apart.
pub fn penetration(a: &SceneNode, b: &SceneNode) -> f64 {
    let axes_of = |n: &SceneNode| {
        let r = n.world_from_local.rotation;
        [r * DVec3::X, r * DVec3::Y, r * DVec3::Z]
    };
    let (aa, ba) = (axes_of(a), axes_of(b));
    let mut axes: Vec<DVec3> = aa.iter().chain(&ba).copied().collect();
    for x in &aa {
        for y in &ba {
            let c = x.cross(*y);
            if c.length() > 1e-9 {
                axes.push(c.normalize());
            }
        }
    }
    let (ca, cb) = (a.world_corners(), b.world_corners());
    let mut least = f64::INFINITY;
    for ax in axes {
        let span = |c: &[DVec3; 8]| {
            c.iter()
                .map(|p| p.dot(ax))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                    (lo.min(v), hi.max(v))
                })
        };
        let ((alo, ahi), (blo, bhi)) = (span(&ca), span(&cb));
        let overlap = ahi.min(bhi) - alo.max(blo);
        if overlap <= 0.0 {
            return 0.0;
        }
        least = least.min(overlap);
    }
    least
}

/// How far (metres) `node`'s base lies above what carries it, and what that is: the
/// background's surface (as [`sinking_depth`] finds it, looking down as far as 2 m) or the
/// top of another object whose footprint holds the node's centre, whichever is higher
/// but not above the base (within [`TOLERANCE_M`]). `None` when nothing is found.
pub fn support_gap(
    node: &SceneNode,
    others: &[&SceneNode],
    up: DVec3,
    meters_per_unit: f64,
    density: &mut dyn FnMut(&[DVec3]) -> Vec<f32>,
) -> Option<(f64, Option<InstanceId>)> {
    let up = up.normalize();
    let unit = 1.0 / meters_per_unit.max(1e-12);
    let low = base(node, up);
    let mut best: Option<(f64, Option<InstanceId>)> = support_level(
        node,
        up,
        meters_per_unit,
        density,
        TOLERANCE_M,
        2.0,
        Look::Densest,
    )
    .map(|l| (l, None));
    let centre = node.world_from_local.translation;
    for o in others {
        let top = o
            .world_corners()
            .iter()
            .map(|c| c.dot(up))
            .fold(f64::NEG_INFINITY, f64::max);
        // The node's centre, dropped onto the other's top, lies within its box.
        let dropped = centre - up * (centre.dot(up) - top + 1e-6 * unit);
        let inside = {
            let l = o.world_from_local.local_from_world_point(dropped);
            (l.abs() - o.half_size).max_element() <= 0.0
        };
        if inside && top <= low + TOLERANCE_M * unit && best.is_none_or(|(b, _)| top > b) {
            best = Some((top, Some(o.id)));
        }
    }
    best.map(|(level, what)| (((low - level) * meters_per_unit).max(0.0), what))
}

/// The lowest point of `node`'s box along `up`.
fn base(node: &SceneNode, up: DVec3) -> f64 {
    node.world_corners()
        .iter()
        .map(|c| c.dot(up))
        .fold(f64::INFINITY, f64::min)
}

/// The level (along `up`, world units) of the surface under `node`, looked for from 10 cm
/// above its lowest point to 10 cm below (see [`support_level`]); `None` when no flat
/// surface is there.
pub fn support_height(
    node: &SceneNode,
    up: DVec3,
    meters_per_unit: f64,
    density: &mut dyn FnMut(&[DVec3]) -> Vec<f32>,
) -> Option<f64> {
    support_level(
        node,
        up.normalize(),
        meters_per_unit,
        density,
        0.1,
        0.1,
        Look::Ring,
    )
}

/// How far (metres) node `node`'s base lies below the surface that should carry it (see
/// [`support_level`], searched from 10 cm above the node's lowest point to 10 cm below).
pub fn sinking_depth(
    node: &SceneNode,
    up: DVec3,
    meters_per_unit: f64,
    density: &mut dyn FnMut(&[DVec3]) -> Vec<f32>,
) -> Option<f64> {
    let up = up.normalize();
    let low = base(node, up);
    support_level(node, up, meters_per_unit, density, 0.1, 0.1, Look::Median)
        .map(|level| ((level - low) * meters_per_unit).max(0.0))
}

/// Which columns decide a support level, and how.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Look {
    /// All 41; their median, if the middle half agree within 1.5 cm.
    Median,
    /// All 41; the 1.5 cm band most of them meet.
    Densest,
    /// The 16 around the footprint only (what stands under the object may be its own
    /// residue in the background); the lowest level of the lowest cluster four of them
    /// meet.
    Ring,
}

/// The level (along `up`, world units) of the surface under `node`: where a look straight
/// down first meets a surface of the surroundings (`density`, per world unit at world
/// points, dense enough that 1 cm of it is more than half opaque), found in 41 vertical
/// columns — a 5×5 grid over the inner 80% of the box face most nearly facing down and 16
/// around it at 1.5 times its size — searched in 2.5 mm steps from `above_m` above the
/// node's lowest point to `below_m` below it. The level is the median of the columns
/// that meet something (a third of them at least: a radiance field holds a table as a
/// thin opaque shell, with nothing inside it and often a hole where an object hid it, so
/// the ring around the footprint carries the level there); `None` when too few do, or
/// when the middle half of the levels spans more than 1.5 cm (clutter or floaters, not a
/// flat support). With `densest`, the level is instead the median of the 1.5 cm band
/// that most columns meet, if a third of them do.
fn support_level(
    node: &SceneNode,
    up: DVec3,
    meters_per_unit: f64,
    density: &mut dyn FnMut(&[DVec3]) -> Vec<f32>,
    above_m: f64,
    below_m: f64,
    look: Look,
) -> Option<f64> {
    let densest = look != Look::Median;
    const STEP_M: f64 = 0.0025;
    let w = &node.world_from_local;
    let axis = |a: usize| w.rotation * DVec3::AXES[a];
    // The local axis most nearly along up; the other two span the footprint.
    let vertical = (0..3)
        .max_by(|&a, &b| axis(a).dot(up).abs().total_cmp(&axis(b).dot(up).abs()))
        .unwrap_or(2);
    let (u, v) = match vertical {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let low = node
        .world_corners()
        .iter()
        .map(|c| c.dot(up))
        .fold(f64::INFINITY, f64::min);
    let mut fractions: Vec<(f64, f64)> = Vec::with_capacity(41);
    for i in 0..5 {
        for j in 0..5 {
            let f = |k: usize| (k as f64 / 4.0 - 0.5) * 1.6;
            fractions.push((f(i), f(j)));
        }
    }
    if look == Look::Ring {
        fractions.clear();
    }
    for k in 0..4 {
        let t = -1.5 + k as f64;
        fractions.extend([(t, -1.5), (1.5, t), (-t, 1.5), (-1.5, -t)]);
    }
    let unit = 1.0 / meters_per_unit.max(1e-12);
    let (step, reach) = (STEP_M * unit, above_m * unit);
    let n_steps = ((above_m + below_m) / STEP_M).round() as usize;
    // A surface: density that makes 1 cm more than half opaque. Fog and haze, which add
    // up to opacity only over many centimetres, are not one.
    let dense = std::f64::consts::LN_2 / (0.01 * unit);
    let mut pts = Vec::with_capacity(fractions.len() * n_steps);
    for (a, b) in &fractions {
        let mut l = DVec3::ZERO;
        l[u] = a * node.half_size[u];
        l[v] = b * node.half_size[v];
        let p = w.transform_point(l);
        let top = p - up * (p.dot(up) - low - reach);
        pts.extend((0..n_steps).map(|k| top - up * (step * (k as f64 + 0.5))));
    }
    let sigma = density(&pts);
    let mut levels: Vec<f64> = sigma
        .chunks(n_steps)
        .filter_map(|col| {
            col.iter()
                .position(|&s| s as f64 >= dense)
                .map(|k| low + reach - step * (k as f64 + 0.5))
        })
        .collect();
    levels.sort_by(f64::total_cmp);
    if look == Look::Ring {
        // The lowest cluster (levels closer than 1.5 cm in a row) that four columns meet:
        // higher ones are neighbours or the object's own residue in the background. Its
        // lowest level: a trained table reads a little above its true top, and a cut
        // must only take what surely lies below the table.
        let gap = 0.015 / meters_per_unit.max(1e-12);
        let mut start = 0;
        for i in 1..=levels.len() {
            if i == levels.len() || levels[i] - levels[i - 1] > gap {
                if i - start >= 4 {
                    return Some(levels[start]);
                }
                start = i;
            }
        }
        return None;
    }
    if levels.len() * 3 < fractions.len() {
        return None;
    }
    // A support is flat where it carries the node: the middle half of the levels within
    // 1.5 cm, else what was met is clutter or floaters, not a surface.
    let n = levels.len();
    if !densest && (levels[3 * n / 4] - levels[n / 4]) * meters_per_unit > 0.015 {
        return None;
    }
    if !densest {
        return Some(levels[n / 2]);
    }
    // The 1.5 cm band holding the most levels, if a third of the columns meet it: the
    // surface most of the footprint and its ring stand on, past a neighbour's residue.
    let band = 0.015 * unit;
    let (mut best, mut start) = (0, 0);
    let mut j = 0;
    for i in 0..n {
        while levels[i] - levels[j] > band {
            j += 1;
        }
        if i + 1 - j > best {
            (best, start) = (i + 1 - j, j);
        }
    }
    (best * 3 >= fractions.len()).then(|| levels[start + best / 2])
}
