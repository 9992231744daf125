//! `--device auto|cpu|gpu` on the commands that render (`render`, `eval`, `view`,
//! `generate`, `bench render`): where the fields are queried (rays are still marched and
//! composited on the CPU; the GPU answers each batch's field queries); and on `train`:
//! where the fields' forward and backward passes and Adam run (`assist-gpu`).

use std::sync::Arc;

use assist_gpu::{DeviceChoice, Gpu, GpuBackend};
use assist_session::FieldBackend;
use clap::Args;

#[derive(Args, Debug, Clone, Copy)]
pub struct DeviceArg {
    /// Where the fields are queried: cpu (this processor, the reference), gpu (a GPU
    /// adapter, software ones such as lavapipe included; an error without one) or auto (a
    /// hardware GPU when one is present, else the CPU). Marching and compositing run on
    /// the CPU either way.
    #[arg(long, default_value = "cpu")]
    pub device: DeviceChoice,
}

/// The device a command's renders use: a GPU's backend, or none (the CPU).
pub struct Device {
    pub backend: Option<Arc<GpuBackend>>,
}

impl DeviceArg {
    /// Opens the device asked for and says which it is on stderr.
    pub fn open(self) -> anyhow::Result<Device> {
        let gpu = Gpu::open(self.device)?;
        match (&gpu, self.device) {
            (Some(g), _) => eprintln!("device: {}", g.name()),
            (None, DeviceChoice::Auto) => eprintln!("device: the CPU (auto: no hardware GPU)"),
            _ => {}
        }
        Ok(Device {
            backend: gpu.map(|g| Arc::new(GpuBackend::new(g))),
        })
    }
}

impl Device {
    /// The backend as renders take it.
    pub fn field_backend(&self) -> Option<Arc<dyn FieldBackend>> {
        self.backend.clone().map(|b| b as Arc<dyn FieldBackend>)
    }

    /// Training's optimizers on the GPU (`train --device`), or none (the CPU's).
    pub fn training(&self) -> Option<Arc<assist_gpu::GpuTraining>> {
        self.backend
            .as_ref()
            .map(|b| Arc::new(assist_gpu::GpuTraining::new(b.gpu().clone())))
    }

    /// What answered, for `--json`: the adapter's name, or "cpu".
    pub fn name(&self) -> String {
        self.backend
            .as_ref()
            .map_or_else(|| "cpu".to_string(), |b| b.name())
    }

    /// Warns when the GPU failed part-way (its queries then ran on the CPU).
    pub fn report(&self) {
        if let Some(e) = self.backend.as_ref().and_then(|b| b.failure()) {
            eprintln!("warning: the GPU failed ({e}); the rest of the queries ran on the CPU");
        }
    }
}
