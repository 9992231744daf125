//! Training through the trainer's seam (`assist_train::NodeOptimizer`): each field's
//! forward and backward passes, gradients and Adam on the GPU ([`GpuOptimizer`]), made per
//! field by [`GpuTraining`] (`train --device gpu`), and the occupancy grid's density
//! queries. The trainer still samples and composites on the CPU. The stepped parameters
//! stay on the GPU; they are read back into the field only when the trainer pulls them
//! (before its held-out checks, checkpoints, the end of a run and any CPU forward pass).

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
    /// The buffer the parameters come back through when pulled (kept: a new one each
    /// time cost more than the copy on an H200).
    readback: wgpu::Buffer,
    /// The digest ([`crate::backend::digest`]) of the field as last uploaded or read
    /// back: a field changed on the CPU since (a resumed or edited one) is uploaded before
    /// its next gradient.
    digest: u64,
    /// Whether the GPU's parameters are newer than the field's (stepped, not yet pulled).
    ahead: bool,
    /// The batch whose forward pass left its training record on the GPU (by where its
    /// samples lie): its gradient then needs no second forward pass.
    recorded: Option<BatchKey>,
    /// The forward pass started and not yet collected, and the buffer its outputs come
    /// back through (kept between steps).
    pending: Option<Started>,
    staging: Option<wgpu::Buffer>,
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
            ahead: false,
            recorded: None,
            pending: None,
            staging: None,
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
        if self.recorded.take() == Some(BatchKey::of(samples)) {
            self.trainer
                .set_loss_grads(&self.gpu, &self.field, &nf.field, d_sigma, d_rgb)?;
            return self.trainer.submit_backward(&self.gpu, &self.field);
        }
        // A batch larger than one storage binding holds (the first steps, before the
        // occupancy grid thins the samples) goes in parts; the gradient adds up.
        for r in parts(samples.len(), GpuTrainer::max_batch(&self.gpu, &nf.field)) {
            self.field.load(&self.gpu, &part(samples, r.clone()))?;
            let (ds, drgb) = (&d_sigma[r.clone()], &d_rgb[3 * r.start..3 * r.end]);
            self.trainer
                .set_loss_grads(&self.gpu, &self.field, &nf.field, ds, drgb)?;
            self.trainer.submit_step(&self.gpu, &self.field, 1)?;
        }
        Ok(())
    }

    /// Uploads the field's parameters when they changed on the CPU since the GPU's copy
    /// was made or read back. A change while the GPU's copy is ahead would lose one or
    /// the other, and is refused.
    fn sync(&mut self, nf: &NodeField) -> Result<(), GpuError> {
        self.sync_field(&nf.field)
    }

    fn sync_field(&mut self, field: &Field) -> Result<(), GpuError> {
        let d = crate::backend::digest(field);
        if d != self.digest {
            self.recorded = None;
            if self.ahead {
                return Err(changed_while_ahead());
            }
            self.field.upload(&self.gpu, field)?;
            self.digest = d;
        }
        Ok(())
    }

    /// The GPU's parameters into the field, when they are newer.
    fn pull_into(&mut self, field: &mut Field) -> Result<(), GpuError> {
        if !self.ahead {
            return Ok(());
        }
        if crate::backend::digest(field) != self.digest {
            return Err(changed_while_ahead());
        }
        crate::read_f32_into(
            &self.gpu,
            &self.field.params,
            &self.readback,
            &mut field.params,
        )?;
        self.digest = crate::backend::digest(field);
        self.ahead = false;
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

    /// Adam on the GPU's copy; the field is left as it was until [`Self::pull`].
    fn step(&mut self, _field: &mut NodeField, lr: f32) -> Result<(), String> {
        self.trainer.submit_adam(&self.gpu, lr);
        self.ahead = true;
        Ok(())
    }

    fn fills_tape(&self) -> bool {
        false
    }

    fn pull(&mut self, field: &mut NodeField) -> Result<(), String> {
        self.pull_into(&mut field.field).map_err(|e| e.to_string())
    }

    /// The density at each cell's point queried on the GPU's copy (the grid itself stays
    /// on the CPU, which marches with it). Where the GPU fails, the rest of the round
    /// runs on the CPU and a warning says so once.
    fn refresh_occupancy(&mut self, nf: &mut NodeField, rng: &mut Rng, round: usize) {
        let NodeField {
            field, occupancy, ..
        } = nf;
        self.recorded = None;
        let mut failed = self.sync_field(field).err();
        let mut scratch = Vec::new();
        occupancy.update_round_with(rng, round, |pos, sigma| {
            if failed.is_none() {
                match self.field.density(&self.gpu, pos, sigma) {
                    Ok(()) => return,
                    Err(e) => failed = Some(e),
                }
            }
            if failed.is_some() {
                // The CPU's copy is behind the GPU's until pulled, which may fail too: then
                // the grid follows the field as last read back.
                let _ = self.pull_into(field);
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

    /// Queued on the GPU's copy (current: a field changed on the CPU since is uploaded
    /// first), with its training record kept for the gradient that follows.
    fn forward_submit(
        &mut self,
        field: &NodeField,
        samples: &Samples,
    ) -> Option<Result<(), String>> {
        Some(
            self.forward_submit_on(field, samples)
                .map_err(|e| e.to_string()),
        )
    }

    fn forward_finish(&mut self, sigma: &mut [f32], rgb: &mut [f32]) -> Result<(), String> {
        let pending = match self.pending.take() {
            Some(Started::Queued(p)) => p,
            Some(Started::Done(v)) => {
                let n = v.len() / 4;
                sigma[..n].copy_from_slice(&v[..n]);
                rgb[..3 * n].copy_from_slice(&v[n..]);
                return Ok(());
            }
            None => return Err("no forward pass was started".into()),
        };
        let mut staging = crate::field::collect(&self.gpu, vec![pending], |_, s, c| {
            sigma[..s.len()].copy_from_slice(s);
            rgb[..c.len()].copy_from_slice(c);
        })
        .map_err(|e| e.to_string())?;
        self.staging = staging.pop();
        Ok(())
    }
}

impl GpuOptimizer {
    fn forward_submit_on(&mut self, field: &NodeField, samples: &Samples) -> Result<(), GpuError> {
        self.sync(field)?;
        self.recorded = None;
        self.pending = None;
        let n = samples.len();
        let max = GpuTrainer::max_batch(&self.gpu, &field.field);
        if n > max {
            // In parts, each waited for (the first steps only, before the occupancy
            // grid thins the samples); no record is kept.
            let mut v = vec![0f32; 4 * n];
            let (sigma, rgb) = v.split_at_mut(n);
            for r in parts(n, max) {
                let (s, c) = (&mut sigma[r.clone()], &mut rgb[3 * r.start..3 * r.end]);
                self.field.forward(&self.gpu, &part(samples, r), s, c)?;
            }
            self.pending = Some(Started::Done(v));
            return Ok(());
        }
        self.field.load(&self.gpu, samples)?;
        let (gpu, gf) = (&self.gpu, &self.field);
        self.trainer
            .submit_forward_recorded(gpu, gf, &field.field)?;
        let staging = match self.staging.take() {
            Some(b) if b.size() >= 16 * n as u64 => b,
            _ => crate::field::staging_buffer(&self.gpu, n + n / 4)?,
        };
        self.pending = Some(Started::Queued(self.field.copy_out(&self.gpu, staging)));
        self.recorded = Some(BatchKey::of(samples));
        Ok(())
    }
}

/// A forward pass started by [`GpuOptimizer`]'s `forward_submit`.
enum Started {
    /// Queued: its outputs on their way to a staging buffer.
    Queued(crate::field::Pending),
    /// Done already (in parts): σ then rgb.
    Done(Vec<f32>),
}

/// A field changed on the CPU while its GPU copy held newer parameters: one of the two
/// would be lost.
fn changed_while_ahead() -> GpuError {
    GpuError::Run(
        "the field's parameters changed on the CPU while the GPU held newer ones \
         (pull them before changing the field)"
            .into(),
    )
}

/// Which batch a training record belongs to: where its samples lie and how many there
/// are (the trainer passes the same arrays to the forward pass and to the gradient).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct BatchKey([usize; 8]);

impl BatchKey {
    fn of(s: &Samples) -> Self {
        let p = |v: &[f32]| v.as_ptr() as usize;
        BatchKey([
            s.len(),
            p(s.pos[0]),
            p(s.pos[1]),
            p(s.pos[2]),
            p(s.dir[0]),
            p(s.dir[1]),
            p(s.dir[2]),
            s.image.as_ptr() as usize ^ s.image.len().rotate_left(40),
        ])
    }
}

/// `0..n` in consecutive ranges of at most `max` (at least 64).
fn parts(n: usize, max: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    let max = max.max(64);
    (0..n.div_ceil(max)).map(move |k| k * max..((k + 1) * max).min(n))
}

/// The samples in `r` (directions and codes, where given, with them; codes missing at
/// the end read as the average, as in [`GpuField::load`]).
fn part<'a>(s: &Samples<'a>, r: std::ops::Range<usize>) -> Samples<'a> {
    let cut = |v: &'a [f32]| if v.is_empty() { v } else { &v[r.clone()] };
    Samples {
        pos: s.pos.map(cut),
        dir: s.dir.map(cut),
        image: &s.image[r.start.min(s.image.len())..r.end.min(s.image.len())],
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn parts_cover_a_batch_in_order() {
        let all: Vec<_> = super::parts(300, 128).collect();
        assert_eq!(all, [0..128, 128..256, 256..300]);
        assert_eq!(super::parts(0, 128).count(), 0);
        // At least 64 a part.
        let one: Vec<_> = super::parts(10, 0).collect();
        assert_eq!((one.len(), one[0].clone()), (1, 0..10));
    }
}
