//! `RenderJob`: cameras → a labelled dataset on disk, through assist-data's writer.

use std::path::PathBuf;

use assist_core::InstanceId;
use assist_data::{DatasetWriter, Layer, Output, ViewImages};
use assist_render::{HIGHLIGHT, RenderOptions, render_camera};
use serde::{Deserialize, Serialize};

use crate::cameras::{CameraSource, NamedCamera};
use crate::{Frame, Result, Session, SessionError, request};

/// Which node to highlight in a render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Highlight {
    /// The scene's selection, if any.
    #[default]
    Selected,
    None,
    Node(InstanceId),
}

/// How finely rays are marched (`render --quality`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// The steps the scene was trained with.
    #[default]
    Full,
    /// Steps twice as long: about half the samples per ray, for previews (its PSNR cost
    /// is in `BENCHMARKS.md` and `render --help`).
    Draft,
}

impl Quality {
    /// The marching-step scale (`RenderOptions::step_scale`).
    pub fn step_scale(self) -> f32 {
        match self {
            Quality::Full => 1.0,
            Quality::Draft => 2.0,
        }
    }
}

/// Where and what a render writes.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DatasetOutput {
    pub out: PathBuf,
    pub outputs: Vec<Output>,
    #[serde(default)]
    pub highlight: Highlight,
    /// Write into a non-empty `out`.
    #[serde(default)]
    pub force: bool,
    #[serde(default)]
    pub quality: Quality,
}

/// A render of a scene into a dataset folder.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RenderJob {
    pub cameras: CameraSource,
    #[serde(flatten)]
    pub output: DatasetOutput,
}

/// One view rendered and written, as a render job reports it.
pub struct ViewDone<'a> {
    /// 0-based position of the view among `total`.
    pub index: usize,
    pub total: usize,
    pub camera: &'a NamedCamera,
    pub frame: &'a Frame,
}

/// What a finished render job wrote.
#[derive(Debug, Clone)]
pub struct RenderSummary {
    pub views: usize,
    pub out: PathBuf,
}

impl Session {
    /// Renders every camera of `job` and writes the dataset; `on_view` is told of each
    /// view once it is written.
    pub fn run_render(
        &self,
        job: &RenderJob,
        on_view: impl FnMut(&ViewDone),
    ) -> Result<RenderSummary> {
        let cameras = job.cameras.cameras(&self.scene().scene)?;
        self.write_dataset(&cameras, &job.output, on_view)
    }

    /// Renders `cameras` and writes them as a dataset.
    pub fn write_dataset(
        &self,
        cameras: &[NamedCamera],
        job: &DatasetOutput,
        on_view: impl FnMut(&ViewDone),
    ) -> Result<RenderSummary> {
        let cfg = self.writer_config(job.outputs.clone());
        let writer = DatasetWriter::create(&job.out, cfg, job.force).map_err(SessionError::Data)?;
        self.render_into(&writer, cameras, job, false, on_view)?;
        let views = writer.finish().map_err(SessionError::Data)?;
        Ok(RenderSummary {
            views,
            out: job.out.clone(),
        })
    }

    /// Renders `cameras` into `writer` (views 0, 1, … in order), with each node's own
    /// layer when the writer wants objects or `layers` is set; `on_view` sees each frame
    /// once it is written. The caller finishes the writer.
    pub fn render_into(
        &self,
        writer: &DatasetWriter,
        cameras: &[NamedCamera],
        job: &DatasetOutput,
        layers: bool,
        mut on_view: impl FnMut(&ViewDone),
    ) -> Result<()> {
        let scene = self.scene();
        let highlight = match job.highlight {
            Highlight::Selected => scene.scene.selected,
            Highlight::None => None,
            Highlight::Node(id) => {
                if scene.scene.node(id).is_none() {
                    return Err(request(
                        "highlight",
                        format!("no node with id {id} (the scene has {})", self.ids()),
                    ));
                }
                Some(id)
            }
        };
        let background = writer.wants(Output::Background);
        if background && !scene.scene.nodes.iter().any(|n| n.is_background()) {
            return Err(request(
                "outputs",
                "background: the scene has no background node".into(),
            ));
        }
        let opts = RenderOptions {
            highlight: highlight.map(|id| (id, HIGHLIGHT)),
            layers: layers || writer.wants(Output::Objects),
            background_alone: background,
            step_scale: job.quality.step_scale(),
            ..self.base_options()
        };
        for c in cameras {
            self.check_camera(&c.camera)
                .map_err(|e| request("camera", format!("{}: {e}", c.name)))?;
        }
        let total = cameras.len();
        for (k, c) in cameras.iter().enumerate() {
            let img = render_camera(scene, &c.camera, u32::MAX, &opts);
            let layers = frame_layers(&img);
            let v = view_images(
                &img,
                if writer.wants(Output::Objects) {
                    &layers
                } else {
                    &[]
                },
                background.then_some(img.background.as_slice()),
            );
            writer
                .write(k, &c.name, &c.camera, &v)
                .map_err(SessionError::Data)?;
            on_view(&ViewDone {
                index: k,
                total,
                camera: c,
                frame: &img,
            });
        }
        Ok(())
    }
}

/// A frame's per-node layers as the dataset writer takes them.
pub fn frame_layers(frame: &Frame) -> Vec<Layer<'_>> {
    frame
        .layers
        .iter()
        .map(|l| Layer {
            id: l.id,
            rgb: &l.rgb,
            opacity: &l.opacity,
        })
        .collect()
}

/// A frame as the dataset writer takes it, with `layers` (empty unless objects are
/// written) and the background alone when rendered.
pub fn view_images<'a>(
    frame: &'a Frame,
    layers: &'a [Layer<'a>],
    background: Option<&'a [f32]>,
) -> ViewImages<'a> {
    ViewImages {
        width: frame.width,
        height: frame.height,
        rgb: &frame.rgb,
        depth: &frame.depth,
        panoptic: &frame.panoptic,
        layers,
        background,
        unseen: Some(&frame.unseen),
    }
}

impl Session {
    /// The dataset writer's settings for renders of this scene: its units, up, objects
    /// and class list (the same class ids in every render of it), and `outputs`.
    pub fn writer_config(&self, outputs: Vec<Output>) -> assist_data::WriterConfig {
        let d = self.description();
        assist_data::WriterConfig {
            outputs,
            meters_per_unit: d.meters_per_unit,
            world_up: d.up.to_array(),
            instances: self.instances(),
            classes: d.class_names(),
            ..assist_data::WriterConfig::default()
        }
    }

    /// The scene's objects as a dataset writer lists them (id and label; the background
    /// is not an instance).
    pub fn instances(&self) -> Vec<assist_data::Instance> {
        self.nodes()
            .iter()
            .filter(|n| !n.is_background())
            .map(|n| assist_data::Instance {
                id: n.id,
                label: n.label.clone(),
                class: n.class.clone(),
                bbox: None,
            })
            .collect()
    }
}
