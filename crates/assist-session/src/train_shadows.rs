//! A training job's background prior and shadows: what objects hide in each view filled
//! from the others, the objects' shadow grids added, the prior made shadow-free near them,
//! the new grids' first estimate from the photographs.

use assist_scene::NeuralScene;

use crate::train_config::{OnOff, Shadows};
use crate::train_job::{TrainEvent, TrainJob};

impl TrainJob {
    /// Fills each view's background prior where objects hide it (the configured kind).
    /// `multi-view` in an unbounded walk-around adds no single-view guess: there the other
    /// views see what objects hide in each, and the background learns it from them (a
    /// guess from one image contradicts them; measured in BENCHMARKS.md).
    pub(crate) fn priors(
        &self,
        views: &mut [assist_train::View],
        layout: assist_train::CaptureLayout,
        on_event: &mut impl FnMut(&TrainEvent),
    ) {
        let c = &self.config;
        let space = c.background.resolve(views);
        let guess = c.prior != assist_train::PriorKind::MultiView
            || !assist_train::takes_walk_around_defaults(layout, space);
        if c.prior != assist_train::PriorKind::None && views.iter().any(|v| v.ids.is_some()) {
            on_event(&TrainEvent::Stage {
                name: "background prior, from the other views",
            });
        }
        if let Some(mv) = assist_train::fill_priors(views, c.prior, guess)
            && mv.hole_pixels > 0
        {
            on_event(&TrainEvent::Prior {
                seen_share: mv.filled_pixels as f64 / mv.hole_pixels as f64,
            });
        }
    }

    /// Gives the objects their shadow grids (as configured), makes the background prior
    /// shadow-free near them and estimates new grids from the photographs; returns the
    /// lattice points the photographs hold (see [`Trainer::shade_held`]).
    pub(crate) fn shadows(
        &self,
        scene: &mut NeuralScene,
        views: &mut [assist_train::View],
        depth: bool,
        on_event: &mut impl FnMut(&TrainEvent),
    ) -> std::collections::BTreeMap<String, Vec<bool>> {
        let c = &self.config;
        let estimate = c.learns_shadows(depth)
            && (c.shadow_estimate == OnOff::On || c.shadows.resolve(depth) == Shadows::Fixed);
        if estimate && scene.scene.nodes.iter().any(|n| !n.is_background()) {
            on_event(&TrainEvent::Stage {
                name: "shadows' first estimate from the photographs",
            });
        }
        // Objects learn their shadows (a resumed scene's grids train on whatever the flag).
        let objects = if c.learns_shadows(depth) {
            assist_train::add_shadow_grids(scene)
        } else {
            0
        };
        let st = assist_train::shadow_free_priors(scene, views);
        // New grids start from the photographs' darkening (trained ones are left as they are).
        let est = if estimate {
            assist_train::estimate_shadows(scene, views)
        } else {
            assist_train::ShadowEstimate::default()
        };
        if objects > 0 || st.views > 0 {
            on_event(&TrainEvent::Shadows {
                objects,
                covered: st.covered,
                seen: st.seen,
                estimated: est.pixels,
            });
        }
        est.held
    }
}
