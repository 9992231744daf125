//! `device=` on the calls that render or train (`Scene.load`, `generate`,
//! `generate_shard`, `train`): "cpu" (the reference, the default), "gpu" (a GPU adapter,
//! software ones such as lavapipe included; an error without one) or "auto" (a hardware
//! GPU when one is present, else the CPU), as `--device` is on the command line.

use super::*;
use assist_gpu::{DeviceChoice, Gpu, GpuBackend, GpuError};
use std::sync::Arc;

/// Opens the device `device` names: a GPU's backend, or `None` for the CPU.
pub(crate) fn open(py: Python<'_>, device: &str) -> PyResult<Option<Arc<GpuBackend>>> {
    let choice: DeviceChoice = device.parse().map_err(err)?;
    let gpu = py.detach(|| Gpu::open(choice)).map_err(|e| match e {
        GpuError::NoAdapter => err(format!(
            "device={device:?}: no GPU adapter found (wgpu looked for Vulkan, Metal and DX12; \
             on Linux a Vulkan driver and loader are needed, e.g. Debian's mesa-vulkan-drivers \
             and libvulkan1); use device=\"cpu\" or \"auto\""
        )),
        other => err(other),
    })?;
    Ok(gpu.map(|g| Arc::new(GpuBackend::new(g))))
}

/// The backend as renders take it.
pub(crate) fn field_backend(
    backend: &Option<Arc<GpuBackend>>,
) -> Option<Arc<dyn assist_session::FieldBackend>> {
    backend
        .clone()
        .map(|b| b as Arc<dyn assist_session::FieldBackend>)
}

/// Training's optimizers on the backend's GPU (`None`: the CPU's).
pub(crate) fn optimizers(
    backend: &Option<Arc<GpuBackend>>,
) -> Option<Arc<dyn assist_train::OptimizerFactory>> {
    backend.as_ref().map(|b| {
        Arc::new(assist_gpu::GpuTraining::new(b.gpu().clone()))
            as Arc<dyn assist_train::OptimizerFactory>
    })
}

/// A GPU that failed part-way answered the rest on the CPU: say so as a Python warning.
pub(crate) fn report(py: Python<'_>, backend: &Option<Arc<GpuBackend>>) -> PyResult<()> {
    if let Some(e) = backend.as_ref().and_then(|b| b.failure()) {
        let msg = format!("the GPU failed ({e}); the rest of the queries ran on the CPU");
        let warn = py.import("warnings")?;
        warn.call_method1(
            "warn",
            (msg, py.get_type::<pyo3::exceptions::PyRuntimeWarning>()),
        )?;
    }
    Ok(())
}
