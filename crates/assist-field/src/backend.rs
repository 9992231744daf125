//! The seam a second implementation of the fields plugs into (a GPU, `assist-gpu`):
//! rendering hands each node's samples to a [`FieldBackend`] instead of calling
//! [`Field::forward`] when one is given. The CPU field stays the reference and the format:
//! a backend reads the same [`Field`] (configuration, layout, flat parameters) and must
//! give the same σ and rgb within its stated tolerance.

use crate::{Field, Samples};

/// One field's query in a [`FieldBackend::forward_all`] call.
pub struct FieldQuery<'a> {
    pub field: &'a Field,
    pub samples: Samples<'a>,
    /// The code of samples without an image's (`None`: the average code), as
    /// [`Field::forward_at`] takes it.
    pub novel: Option<&'a [f32]>,
    pub sigma: &'a mut [f32],
    pub rgb: &'a mut [f32],
}

/// Inference of fields somewhere other than this CPU.
pub trait FieldBackend: Send + Sync + std::fmt::Debug {
    /// What runs the fields ("NVIDIA H200 (Vulkan, DiscreteGpu)"), for logs and `--json`.
    fn name(&self) -> String;

    /// Inference as [`Field::forward`]: σ per sample and rgb interleaved, with the
    /// average appearance code where `s.image` is empty or `u32::MAX`. The backend keeps
    /// its own copy of `field`'s parameters and refreshes it when they changed.
    fn forward(
        &self,
        field: &Field,
        s: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Result<(), String>;

    /// [`forward`](Self::forward) for several fields at once (a render batch's nodes), so
    /// that a backend can submit them together and wait once.
    fn forward_all(&self, queries: &mut [FieldQuery<'_>]) -> Result<(), String> {
        for q in queries {
            self.forward(q.field, &q.samples, q.sigma, q.rgb)?;
        }
        Ok(())
    }
}
