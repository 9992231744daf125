//! What the trainer asks of a node's field once the forward pass is done: take a
//! batch's output gradients, step the parameters, refresh the occupancy grid. The trainer
//! holds one [`NodeOptimizer`] per field and never writes parameters itself; this is the
//! seam a GPU backend implements (its gradient, Adam moments and parameters live in device
//! buffers). Such an optimizer may hold parameters newer than the field's between steps:
//! the trainer asks it to [`NodeOptimizer::pull`] them before anything on the CPU reads
//! the field (a held-out check, a checkpoint, the end of a run, a CPU forward pass).
//!
//! [`CpuOptimizer`] keeps the gradient buffer and Adam moments beside the field.
//! [`OptimizerFactory`] makes the optimizers of a run (`train --device`).

use assist_core::Rng;
use assist_field::{Adam, Samples, Tape};
use assist_scene::NodeField;
use rayon::prelude::*;

/// A field's training state: gradient accumulation, the optimiser step and the
/// occupancy refresh.
pub trait NodeOptimizer: Send {
    /// Adds the gradient of the loss with respect to the parameters for one batch of
    /// samples, given the loss's gradient with respect to their density and colour.
    fn accumulate(
        &mut self,
        field: &NodeField,
        samples: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) -> Result<(), String>;

    /// One optimiser step with learning rate `lr`; clears the accumulated gradient.
    fn step(&mut self, field: &mut NodeField, lr: f32) -> Result<(), String>;

    /// Starts the training forward pass where this optimizer keeps its own copy of the
    /// field (a GPU: the pass is queued, and no CPU tape is recorded), for
    /// [`NodeOptimizer::forward_finish`] to hand over; `None` leaves it to the CPU's
    /// `Field::forward_train`. The trainer starts every node's pass before it waits for
    /// the first, so a GPU runs them back to back.
    fn forward_submit(
        &mut self,
        _field: &NodeField,
        _samples: &Samples,
    ) -> Option<Result<(), String>> {
        None
    }

    /// σ and rgb of the pass [`NodeOptimizer::forward_submit`] started, once it is done.
    fn forward_finish(&mut self, _sigma: &mut [f32], _rgb: &mut [f32]) -> Result<(), String> {
        Err("no forward pass was started".into())
    }

    /// Both halves of the forward pass in one call (`None`: left to the CPU).
    fn forward(
        &mut self,
        field: &NodeField,
        samples: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Option<Result<(), String>> {
        Some(
            self.forward_submit(field, samples)?
                .and_then(|()| self.forward_finish(sigma, rgb)),
        )
    }

    /// Refreshes the field's occupancy grid from its density (`round` counts refreshes).
    fn refresh_occupancy(&mut self, field: &mut NodeField, rng: &mut Rng, round: usize) {
        field.occupancy.update_round(&field.field, rng, round);
    }

    /// Whether [`NodeOptimizer::accumulate`] leaves dL/d(encoding) in the tape, as the
    /// CPU's backward pass does. A GPU's does not: pose refinement, which needs it, then
    /// runs the nets' backward pass on the CPU for it.
    fn fills_tape(&self) -> bool {
        true
    }

    /// Brings parameters this optimizer holds that are newer than `field`'s into it (a
    /// GPU's copy after its steps); the CPU's optimizer steps the field itself.
    fn pull(&mut self, _field: &mut NodeField) -> Result<(), String> {
        Ok(())
    }

    /// Whether every parameter is finite (checked before a checkpoint is written).
    fn is_finite(&self, field: &NodeField) -> bool {
        field.field.params.par_iter().all(|v| v.is_finite())
    }
}

/// Adam on the CPU with a dense gradient buffer (the hash tables are updated sparsely,
/// see [`Adam::for_field`]).
#[derive(Debug, Clone)]
pub struct CpuOptimizer {
    adam: Adam,
    grad: Vec<f32>,
}

impl CpuOptimizer {
    /// Adam for `field` with its hash tables decayed by `grid_decay` (see
    /// [`Adam::table_decay`]).
    pub fn new(field: &NodeField, grid_decay: f32) -> Self {
        let mut adam = Adam::for_field(&field.field);
        adam.table_decay = grid_decay;
        CpuOptimizer {
            adam,
            grad: vec![0.0; field.field.layout.total],
        }
    }
}

impl NodeOptimizer for CpuOptimizer {
    fn accumulate(
        &mut self,
        field: &NodeField,
        samples: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) -> Result<(), String> {
        field
            .field
            .backward(samples, tape, d_sigma, d_rgb, &mut self.grad);
        Ok(())
    }

    fn step(&mut self, field: &mut NodeField, lr: f32) -> Result<(), String> {
        self.adam
            .update(lr, &mut field.field.params, &mut self.grad);
        Ok(())
    }
}

/// Makes a run's optimizer for each field (a GPU's, for `train --device gpu`); without
/// one the trainer uses [`CpuOptimizer`].
pub trait OptimizerFactory: Send + Sync + std::fmt::Debug {
    /// What steps the fields, for logs ("NVIDIA H200 (Vulkan, DiscreteGpu)").
    fn name(&self) -> String;
    /// The optimizer of `field`, its state fresh, its hash tables decayed by
    /// `grid_decay` (see [`Adam::table_decay`]).
    fn make(&self, field: &NodeField, grid_decay: f32) -> Result<Box<dyn NodeOptimizer>, String>;
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::DVec3;
    use assist_field::{Field, FieldConfig, OccupancyGrid};

    #[test]
    fn a_step_moves_parameters_against_the_gradient_and_clears_it() {
        let cfg = FieldConfig {
            levels: 4,
            log2_table_size: 10,
            base_resolution: 4,
            max_resolution: 32,
            appearance_dim: 0,
            num_images: 0,
            ..FieldConfig::nerfacto(0)
        };
        let field = Field::new(cfg, 3).unwrap();
        let occ = OccupancyGrid::new(8);
        let mut nf = NodeField::new(field, occ, DVec3::ONE);
        let before = nf.field.params.clone();
        let mut opt = CpuOptimizer::new(&nf, 0.0);
        let k = nf.field.layout.mlp_start();
        opt.grad[k] = 1.0;
        opt.step(&mut nf, 1e-2).unwrap();
        assert!(nf.field.params[k] < before[k], "moved against the gradient");
        assert!(opt.grad.iter().all(|&g| g == 0.0), "gradient cleared");
        let moved = nf
            .field
            .params
            .iter()
            .zip(&before)
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(moved, 1, "only the parameter with a gradient moved");
        assert!(opt.is_finite(&nf));
        nf.field.params[k] = f32::NAN;
        assert!(!opt.is_finite(&nf));
    }
}
