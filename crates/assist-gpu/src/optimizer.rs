//! Training through the trainer's seam (`assist_train::NodeOptimizer`): each field's
//! forward and backward passes, gradients and Adam on the GPU ([`GpuOptimizer`]), made per
//! field by [`GpuTraining`] (`train --device gpu`), and the occupancy grid's density
//! queries. The trainer still samples and composites on the CPU; after each step the
//! parameters are read back into the field, so its held-out checks and checkpoints see
//! them as on the CPU path.

use std::sync::Arc;

use assist_core::Rng;
use assist_field::{Adam, Field, Samples, Tape};
use assist_scene::NodeField;
use assist_train::{NodeOptimizer, OptimizerFactory};

use crate::{Gpu, GpuError, GpuField, GpuTrainer};

/// Makes each field's [`GpuOptimizer`] on one GPU.
pub struct GpuTraining {
    gpu: Arc<Gpu>,
}

impl std::fmt::Debug for GpuTraining {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GpuTraining({})", self.gpu.name())
    }
}

impl GpuTraining {
    pub fn new(gpu: Arc<Gpu>) -> Self {
        GpuTraining { gpu }
    }
}

impl OptimizerFactory for GpuTraining {
    fn name(&self) -> String {
        self.gpu.name()
    }

    fn make(&self, field: &NodeField, grid_decay: f32) -> Result<Box<dyn NodeOptimizer>, String> {
        GpuOptimizer::new(self.gpu.clone(), field, grid_decay)
            .map(|o| Box::new(o) as Box<dyn NodeOptimizer>)
            .map_err(|e| e.to_string())
    }
}

/// One field's gradient and Adam moments on the GPU, with a copy of its parameters.
pub struct GpuOptimizer {
    gpu: Arc<Gpu>,
    field: GpuField,
    trainer: GpuTrainer,
    /// The buffer the parameters come back through after each step (kept: a new one
    /// each step cost more than the copy on an H200).
    readback: wgpu::Buffer,
    /// The digest of the parameters the GPU holds ([`crate::backend::digest`]): a field
    /// changed on the CPU since (a resumed or edited one) is uploaded before its next
    /// gradient.
    digest: u64,
    /// Whether a CPU fallback of the occupancy refresh was reported.
    warned: bool,
}

impl GpuOptimizer {
    /// `grid_decay`: the hash tables' decay (see [`Adam::table_decay`]).
    pub fn new(gpu: Arc<Gpu>, nf: &NodeField, grid_decay: f32) -> Result<Self, GpuError> {
        let field = GpuField::new(&gpu, &nf.field)?;
        let mut adam = Adam::for_field(&nf.field);
        adam.table_decay = grid_decay;
        let trainer = GpuTrainer::new(&gpu, &field, &nf.field, &adam)?;
        let readback = gpu.checked("allocating the parameters' read-back buffer", || {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("params readback"),
                size: std::mem::size_of_val(nf.field.params.as_slice()) as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        Ok(GpuOptimizer {
            readback,
            digest: crate::backend::digest(&nf.field),
            warned: false,
            gpu,
            field,
            trainer,
        })
    }

    /// Whether part of an occupancy refresh fell back to the CPU (for tests).
    #[doc(hidden)]
    pub fn fell_back(&self) -> bool {
        self.warned
    }

    fn accumulate_on(
        &mut self,
        nf: &NodeField,
        samples: &Samples,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) -> Result<(), GpuError> {
        self.sync(nf)?;
        self.field.load(&self.gpu, samples)?;
        self.trainer
            .set_loss_grads(&self.gpu, &self.field, &nf.field, d_sigma, d_rgb)?;
        self.trainer.submit_step(&self.gpu, &self.field, 1)
    }

    /// Uploads the field's parameters when they changed on the CPU since the GPU's copy
    /// was made or read back.
    fn sync(&mut self, nf: &NodeField) -> Result<(), GpuError> {
        self.sync_field(&nf.field)
    }

    fn sync_field(&mut self, field: &Field) -> Result<(), GpuError> {
        let d = crate::backend::digest(field);
        if d != self.digest {
            self.field.upload(&self.gpu, field)?;
            self.digest = d;
        }
        Ok(())
    }

    fn step_on(&mut self, nf: &mut NodeField, lr: f32) -> Result<(), GpuError> {
        self.trainer.submit_adam(&self.gpu, lr);
        crate::read_f32_into(
            &self.gpu,
            &self.field.params,
            &self.readback,
            &mut nf.field.params,
        )?;
        self.digest = crate::backend::digest(&nf.field);
        Ok(())
    }
}

impl NodeOptimizer for GpuOptimizer {
    /// The forward pass with its record runs again on the GPU (the CPU's tape stays
    /// there for the pose refinement), then backward into the GPU's gradient.
    fn accumulate(
        &mut self,
        field: &NodeField,
        samples: &Samples,
        _tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) -> Result<(), String> {
        if samples.is_empty() {
            return Ok(());
        }
        self.accumulate_on(field, samples, d_sigma, d_rgb)
            .map_err(|e| e.to_string())
    }

    fn step(&mut self, field: &mut NodeField, lr: f32) -> Result<(), String> {
        self.step_on(field, lr).map_err(|e| e.to_string())
    }

    /// The density at each cell's point queried on the GPU's copy (the grid itself stays
    /// on the CPU, which marches with it). Where the GPU fails, the rest of the round
    /// runs on the CPU and a warning says so once.
    fn refresh_occupancy(&mut self, nf: &mut NodeField, rng: &mut Rng, round: usize) {
        let NodeField {
            field, occupancy, ..
        } = nf;
        let mut failed = self.sync_field(field).err();
        let mut scratch = Vec::new();
        occupancy.update_round_with(rng, round, |pos, sigma| {
            if failed.is_none() {
                match self.field.density(&self.gpu, pos, sigma) {
                    Ok(()) => return,
                    Err(e) => failed = Some(e),
                }
            }
            field.density_with(pos, sigma, &mut scratch);
        });
        if let Some(e) = failed
            && !self.warned
        {
            self.warned = true;
            eprintln!("warning: the occupancy refresh ran on the CPU: {e}");
        }
    }

    /// On the GPU's copy (current: the parameters come back after each step, and a
    /// field changed on the CPU since is uploaded first).
    fn forward(
        &mut self,
        field: &NodeField,
        samples: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Option<Result<(), String>> {
        let mut run = || -> Result<(), GpuError> {
            self.sync(field)?;
            self.field.forward(&self.gpu, samples, sigma, rgb)
        };
        Some(run().map_err(|e| e.to_string()))
    }
}
