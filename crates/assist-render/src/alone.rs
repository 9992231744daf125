//! The background's image alone from the samples of a full render: what a render of the
//! scene without its objects shows, without rendering it again.

use assist_core::Camera;
use assist_scene::NeuralScene;

use crate::render::{RenderOptions, RenderScratch, render_camera};

/// The background alone of a render that has a background node
/// ([`RenderOptions::background_alone`]).
pub(crate) struct BackgroundAlone {
    /// The background node's index in the scene.
    pub(crate) node: usize,
    rgb: Vec<f32>,
    unseen: Vec<bool>,
}

impl BackgroundAlone {
    /// For `scene` when it has a background node (`None` otherwise).
    pub(crate) fn of(scene: &NeuralScene, pixels: usize) -> Option<Self> {
        let node = scene.scene.nodes.iter().position(|n| n.is_background())?;
        Some(BackgroundAlone {
            node,
            rgb: vec![0.0; 3 * pixels],
            unseen: vec![false; pixels],
        })
    }

    /// A batch's rays: the background node composited alone (the batch's per-node
    /// composite) over the backdrop a scene of that node alone shows, the colour of its
    /// own last sample or the scene's colour, by the same formulas as the full composite.
    pub(crate) fn write_batch(
        &mut self,
        scene: &NeuralScene,
        sc: &RenderScratch,
        pixels: &[usize],
    ) {
        use crate::batch::{Behind, backdrop_colour, with_backdrop};
        let behind = Behind::of(&scene.scene);
        let nn = sc.out.n_nodes;
        let ns = sc.traced.nodes.iter().find(|ns| ns.node == self.node);
        for (r, &q) in pixels.iter().enumerate() {
            let a = sc.out.nodes[r * nn + self.node];
            // The node's own last sample, unshaded (no objects to shade it).
            let last = ns.and_then(|ns| {
                let j = ns.range(r).last()?;
                Some(backdrop_colour(&ns.rgb[3 * j..3 * j + 3], [1.0; 3]))
            });
            let backdrop = match behind {
                Behind::Color(c) => c,
                Behind::LastSample => last.unwrap_or([0.0; 3]),
            };
            let rgb = with_backdrop(a.rgb, a.opacity, backdrop);
            self.unseen[q] = behind == Behind::LastSample && a.opacity == 0.0 && rgb == [0.0; 3];
            self.rgb[3 * q..3 * q + 3].copy_from_slice(&rgb);
        }
    }

    /// The image, with what no view saw filled as [`crate::RenderedImage::fill_unseen`] fills it.
    pub(crate) fn finish(mut self, width: u32, height: u32) -> Vec<f32> {
        if self.unseen.iter().any(|&u| u) {
            let seen: Vec<bool> = self.unseen.iter().map(|u| !u).collect();
            let (w, h) = (width as usize, height as usize);
            crate::fill::pull_push(w, h, 3, &mut self.rgb, &seen, &self.unseen);
        }
        self.rgb
    }
}

/// The background alone rendered apart: the scene without its objects, no highlight (for
/// a render whose own samples cannot give it).
pub(crate) fn render_apart(
    scene: &NeuralScene,
    camera: &Camera,
    image: u32,
    opts: &RenderOptions,
) -> Vec<f32> {
    let mut bg = scene.clone();
    bg.scene.nodes.retain(|n| n.is_background());
    let o = RenderOptions {
        background_alone: false,
        layers: false,
        highlight: None,
        ..opts.clone()
    };
    render_camera(&bg, camera, image, &o).rgb
}
