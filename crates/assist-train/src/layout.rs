//! How a capture's cameras stand around what they look at: facing one way (a forward-facing
//! or handheld capture) or all around it (a 360° walk-around). Walk-arounds see the room
//! behind the object from every side, each part of it by few views, and train best with
//! their own defaults (see `TrainConfig`'s `--layout`); the choice is made from the poses
//! alone, so that it carries to captures nobody measured.

use assist_core::{DMat3, DVec3};

use assist_core::NodeSpace;
use assist_scene::NeuralScene;

use crate::{GridResolution, View};

/// The largest azimuth gap, in degrees, the camera centres may leave around their focus
/// for the capture to count as a walk-around: under 180° the cameras stand on every side
/// of it (the focus lies inside their horizontal hull).
pub const SURROUND_MAX_GAP_DEGREES: f64 = 180.0;

/// How the cameras of a capture are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CaptureLayout {
    /// The cameras face one way (forward-facing, handheld, a half circle).
    Facing,
    /// The cameras stand all around what they look at.
    WalkAround,
}

impl CaptureLayout {
    pub fn as_str(self) -> &'static str {
        match self {
            CaptureLayout::Facing => "facing",
            CaptureLayout::WalkAround => "walk-around",
        }
    }
}

/// The layout a run trains for: read from the poses ([`capture_layout`]) or given.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LayoutChoice {
    #[default]
    Auto,
    Facing,
    WalkAround,
}

impl LayoutChoice {
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "auto" => LayoutChoice::Auto,
            "facing" => LayoutChoice::Facing,
            "walk-around" => LayoutChoice::WalkAround,
            _ => return None,
        })
    }

    /// The layout of `views` under this choice.
    pub fn resolve(self, views: &[View]) -> CaptureLayout {
        match self {
            LayoutChoice::Auto => capture_layout(views),
            LayoutChoice::Facing => CaptureLayout::Facing,
            LayoutChoice::WalkAround => CaptureLayout::WalkAround,
        }
    }
}

/// What an unbounded walk-around trains with where the user sets nothing else: the
/// background's finest level matched to the pixels, the hash tables' weight decay and
/// Nerfacto's distortion weight. Together they helped gold_cape, as one background node
/// and with its object node (once no single-view prior guessed what the object hides);
/// each cost the facing captures (measured in BENCHMARKS.md).
pub struct WalkAroundDefaults;

impl WalkAroundDefaults {
    pub const GRID_RESOLUTION: GridResolution = GridResolution::Auto;
    pub const GRID_DECAY: f32 = 1e-6;
    pub const DISTORTION: f32 = 0.002;
}

/// Whether a run takes [`WalkAroundDefaults`]: a walk-around whose background is
/// unbounded (contracted). A bounded room's walk-around (depth maps) keeps the others.
pub fn takes_walk_around_defaults(layout: CaptureLayout, space: NodeSpace) -> bool {
    layout == CaptureLayout::WalkAround && space == NodeSpace::Contracted
}

/// The point closest, in the least-squares sense, to every view's optical axis: what the
/// cameras look at. None when the axes are (nearly) parallel.
pub fn focus_point(views: &[View]) -> Option<DVec3> {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for v in views {
        let c = v.camera.pose.center();
        let d = v.camera.pose.forward().normalize();
        let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * c;
    }
    if views.is_empty() || a.determinant().abs() < 1e-9 {
        return None;
    }
    Some(a.inverse() * b)
}

/// The views' mean up direction (their image's up, in the world), normalised; None when
/// they cancel out.
pub fn mean_up(views: &[View]) -> Option<DVec3> {
    let s: DVec3 = views
        .iter()
        .map(|v| v.camera.pose.rotation() * DVec3::Y)
        .sum();
    (s.length() > 1e-9).then(|| s.normalize())
}

/// The largest gap, in degrees, between the azimuths of the camera centres seen from
/// `focus` about `up` (360 for one camera; None without cameras or where every centre
/// lies on the up axis through the focus).
pub fn largest_azimuth_gap(views: &[View], focus: DVec3, up: DVec3) -> Option<f64> {
    let up = up.normalize();
    let e1 = up.any_orthonormal_vector();
    let e2 = up.cross(e1);
    let mut az: Vec<f64> = views
        .iter()
        .filter_map(|v| {
            let r = v.camera.pose.center() - focus;
            let h = r - up * r.dot(up);
            (h.length() > 1e-9 * r.length().max(1e-12)).then(|| h.dot(e2).atan2(h.dot(e1)))
        })
        .map(f64::to_degrees)
        .collect();
    if az.is_empty() {
        return None;
    }
    az.sort_by(f64::total_cmp);
    let wrap = az[0] + 360.0 - az[az.len() - 1];
    Some(az.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max))
}

/// The largest azimuth gap, in degrees, the camera centres of `views` leave around the
/// point they look at, about the views' mean up (None where that point or up is
/// undefined: parallel axes, no views).
pub fn azimuth_gap(views: &[View]) -> Option<f64> {
    let (focus, up) = focus_point(views).zip(mean_up(views))?;
    largest_azimuth_gap(views, focus, up)
}

/// The layout of `views`: a walk-around when the camera centres leave no azimuth gap of
/// [`SURROUND_MAX_GAP_DEGREES`] or more around the point they look at (about the views'
/// mean up), else facing.
pub fn capture_layout(views: &[View]) -> CaptureLayout {
    match azimuth_gap(views) {
        Some(g) if g < SURROUND_MAX_GAP_DEGREES => CaptureLayout::WalkAround,
        _ => CaptureLayout::Facing,
    }
}

/// The background's finest resolution where none is given: the walk-around's
/// ([`WalkAroundDefaults`]) where [`takes_walk_around_defaults`] holds for the scene
/// [`crate::build_scene`] makes with `background`, else Nerfacto's.
pub fn default_grid_resolution(
    layout: CaptureLayout,
    views: &[View],
    background: crate::BackgroundSpace,
) -> GridResolution {
    if takes_walk_around_defaults(layout, background.resolve(views)) {
        WalkAroundDefaults::GRID_RESOLUTION
    } else {
        GridResolution::default()
    }
}

/// The finest hash-grid resolution of `scene`'s background, if it has one.
pub fn background_grid_resolution(scene: &NeuralScene) -> Option<u32> {
    let node = scene.scene.nodes.iter().find(|n| n.is_background())?;
    Some(scene.fields.get(&node.field)?.field.config.max_resolution)
}

/// [`takes_walk_around_defaults`] for a built `scene`: its background's space (contracted
/// where any node is).
pub fn scene_takes_walk_around_defaults(layout: CaptureLayout, scene: &NeuralScene) -> bool {
    let unbounded = scene
        .fields
        .values()
        .any(|f| f.space == NodeSpace::Contracted);
    let space = if unbounded {
        NodeSpace::Contracted
    } else {
        NodeSpace::Box
    };
    takes_walk_around_defaults(layout, space)
}

/// What a run says of its cameras' layout (`given`: by `--layout`; `gap`: the largest
/// azimuth gap, [`azimuth_gap`]) and of the defaults it took.
pub fn describe_layout(
    layout: CaptureLayout,
    given: bool,
    gap: Option<f64>,
    walk_around_defaults: bool,
) -> String {
    let source = if given { "--layout" } else { "from the poses" };
    let gap = gap
        .map(|g| format!("; the largest gap around the point they look at: {g:.0}°"))
        .unwrap_or_default();
    let what = match layout {
        CaptureLayout::WalkAround => "all around what they look at",
        CaptureLayout::Facing => "facing one way",
    };
    let defaults = if walk_around_defaults {
        format!(
            "; an unbounded walk-around: --grid-resolution {}, --grid-decay {:e} and --lambda-distortion {} where not given",
            WalkAroundDefaults::GRID_RESOLUTION,
            WalkAroundDefaults::GRID_DECAY,
            WalkAroundDefaults::DISTORTION
        )
    } else {
        String::new()
    };
    format!("cameras: {what} ({source}{gap}){defaults}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::Pose;

    fn view_with(pose: Pose) -> View {
        let mut v = View::blank(8, 6);
        v.camera.pose = pose;
        v
    }

    fn view_at(eye: DVec3, target: DVec3) -> View {
        view_with(Pose::look_at(eye, target, DVec3::Z).unwrap())
    }

    /// Cameras on a circle of radius 3 around (1, 2, 0.5), 0.8 above it, from `a0` to `a1`
    /// degrees, each looking at the centre.
    fn ring(n: usize, a0: f64, a1: f64) -> Vec<View> {
        let target = DVec3::new(1.0, 2.0, 0.5);
        (0..n)
            .map(|i| {
                let a = (a0 + (a1 - a0) * i as f64 / n as f64).to_radians();
                let eye = target + DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.8);
                view_at(eye, target)
            })
            .collect()
    }

    #[test]
    fn the_focus_is_where_the_axes_meet() {
        let views = ring(12, 0.0, 360.0);
        let f = focus_point(&views).unwrap();
        assert!((f - DVec3::new(1.0, 2.0, 0.5)).length() < 1e-9, "{f}");
        let up = mean_up(&views).unwrap();
        assert!(up.dot(DVec3::Z) > 0.95, "{up}");
        // Parallel axes meet nowhere.
        let par: Vec<View> = (0..4)
            .map(|i| {
                let e = DVec3::new(i as f64, 0.0, 0.0);
                view_at(e, e + DVec3::Y)
            })
            .collect();
        assert!(focus_point(&par).is_none());
        assert!(focus_point(&[]).is_none());
    }

    #[test]
    fn a_full_ring_is_a_walk_around_and_an_arc_is_not() {
        // 12 cameras all around: gaps of 30°.
        let full = ring(12, 0.0, 360.0);
        let g = largest_azimuth_gap(&full, DVec3::new(1.0, 2.0, 0.5), DVec3::Z).unwrap();
        assert!((g - 30.0).abs() < 1e-6, "{g}");
        assert_eq!(capture_layout(&full), CaptureLayout::WalkAround);
        // Three quarters of a circle: a 90° gap (plus one step) is still all around.
        let most = ring(12, 0.0, 270.0);
        let g = largest_azimuth_gap(&most, DVec3::new(1.0, 2.0, 0.5), DVec3::Z).unwrap();
        assert!((g - (90.0 + 22.5)).abs() < 1e-6, "{g}");
        assert_eq!(capture_layout(&most), CaptureLayout::WalkAround);
        // A half circle or less faces one way.
        assert_eq!(capture_layout(&ring(12, 0.0, 160.0)), CaptureLayout::Facing);
        assert_eq!(
            capture_layout(&ring(12, -20.0, 20.0)),
            CaptureLayout::Facing
        );
    }

    #[test]
    fn forward_facing_cameras_face_one_way() {
        // A grid of cameras a little apart, all looking along +Y at a wall 10 away, each
        // axis converging loosely on one point (as a handheld forward capture does).
        let target = DVec3::new(0.0, 10.0, 0.0);
        let views: Vec<View> = (0..9)
            .map(|i| {
                let eye = DVec3::new((i % 3) as f64 * 0.3 - 0.3, 0.0, (i / 3) as f64 * 0.2);
                view_at(eye, target + DVec3::new(0.05 * i as f64, 0.0, 0.0))
            })
            .collect();
        assert_eq!(capture_layout(&views), CaptureLayout::Facing);
        // No views: facing (nothing to go on).
        assert_eq!(capture_layout(&[]), CaptureLayout::Facing);
    }

    #[test]
    fn the_layout_does_not_depend_on_the_world_frame() {
        // The same ring turned and moved: the mean up follows the cameras.
        let rot = assist_core::DQuat::from_axis_angle(DVec3::new(1.0, 0.3, -0.2).normalize(), 1.1);
        let shift = DVec3::new(-4.0, 0.5, 9.0);
        for (a1, want) in [
            (360.0, CaptureLayout::WalkAround),
            (150.0, CaptureLayout::Facing),
        ] {
            let views: Vec<View> = ring(16, 0.0, a1)
                .into_iter()
                .map(|v| {
                    let eye = rot * v.camera.pose.center() + shift;
                    let target = rot * DVec3::new(1.0, 2.0, 0.5) + shift;
                    view_with(Pose::look_at(eye, target, rot * DVec3::Z).unwrap())
                })
                .collect();
            assert_eq!(capture_layout(&views), want, "arc {a1}");
        }
    }

    #[test]
    fn only_an_unbounded_walk_around_takes_its_defaults() {
        use CaptureLayout::{Facing, WalkAround};
        use NodeSpace::{Box, Contracted};
        assert!(takes_walk_around_defaults(WalkAround, Contracted));
        assert!(!takes_walk_around_defaults(WalkAround, Box));
        assert!(!takes_walk_around_defaults(Facing, Contracted));
        // The choice: auto reads the poses, the others are kept.
        let full = ring(12, 0.0, 360.0);
        assert_eq!(LayoutChoice::Auto.resolve(&full), WalkAround);
        assert_eq!(LayoutChoice::Facing.resolve(&full), Facing);
        assert_eq!(
            LayoutChoice::WalkAround.resolve(&ring(12, 0.0, 90.0)),
            WalkAround
        );
        assert_eq!(
            LayoutChoice::parse("walk-around"),
            Some(LayoutChoice::WalkAround)
        );
        assert_eq!(LayoutChoice::parse("around"), None);
    }
}
