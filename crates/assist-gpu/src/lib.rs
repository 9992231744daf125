//! assist-gpu: the node fields on a GPU through wgpu (Vulkan, Metal, DX12), in WGSL compute
//! shaders. The CPU implementation in `assist-field` is the reference; every kernel here is
//! tested against it (on Mesa's software Vulkan, lavapipe, where no GPU is present).
//!
//! What runs here so far: a field's inference and its density alone ([`GpuField`]), and
//! its whole training step — forward with a record, backward, every parameter's gradient,
//! Adam ([`GpuTrainer`]) — over batches resident in GPU memory; and rendering's field
//! queries ([`GpuBackend`], `--device` on `render`, `eval`, `view` and `generate`), whose
//! samples still come from the CPU's marching and go back to its compositing.
//! Backends are loaded at run time, so a binary with this crate starts on a machine with
//! no GPU and no Vulkan loader; [`Gpu::open`] then finds no adapter.

#![forbid(unsafe_code)]

mod backend;
mod codegen;
mod field;
mod kernels;
mod optimizer;
mod train;

pub use backend::GpuBackend;
pub use field::GpuField;
pub use optimizer::{GpuOptimizer, GpuTraining};
pub use train::GpuTrainer;

/// Which processor runs the fields (`--device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DeviceChoice {
    /// A hardware GPU when one is present (software adapters such as lavapipe are passed
    /// over: they are slower than the CPU path), else the CPU.
    Auto,
    /// The CPU path, the reference.
    #[default]
    Cpu,
    /// A GPU adapter, software ones included; an error when there is none.
    Gpu,
}

impl std::str::FromStr for DeviceChoice {
    type Err = GpuError;
    fn from_str(s: &str) -> Result<Self, GpuError> {
        match s {
            "auto" => Ok(DeviceChoice::Auto),
            "cpu" => Ok(DeviceChoice::Cpu),
            "gpu" => Ok(DeviceChoice::Gpu),
            other => Err(GpuError::Choice(other.to_string())),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("device: expected auto, cpu or gpu, got {0:?}")]
    Choice(String),
    #[error(
        "--device gpu: no GPU adapter found (wgpu looked for Vulkan, Metal and DX12{}); use --device cpu or auto",
        if cfg!(target_os = "linux") { "; on Linux a Vulkan driver and loader are needed, e.g. Debian's mesa-vulkan-drivers and libvulkan1" } else { "" }
    )]
    NoAdapter,
    #[error("GPU adapter {adapter}: {message}")]
    Device { adapter: String, message: String },
    #[error("GPU: {0}")]
    Run(String),
}

/// An error unless `n` samples of `per_sample` bytes fit one storage binding.
pub(crate) fn check_batch(
    gpu: &Gpu,
    n: usize,
    per_sample: usize,
    what: &str,
) -> Result<(), GpuError> {
    let largest = gpu.limits.max_storage_buffer_binding_size;
    // Buffers hold whole tiles of 64 samples.
    let need = (n.next_multiple_of(64) as u64).saturating_mul(per_sample as u64);
    if need > largest || n > u32::MAX as usize / 8 {
        return Err(GpuError::Device {
            adapter: gpu.info.name.clone(),
            message: format!(
                "a batch of {n} samples needs {need} bytes of {what}, more than the adapter's largest storage binding ({largest} bytes): use a smaller batch (at most {} samples)",
                largest / per_sample as u64
            ),
        });
    }
    Ok(())
}

/// Samples to allocate for a batch of `n` (checked with `check_batch`): a quarter more
/// room, so that slowly growing batches do not reallocate each time, rounded to 4,096, no
/// more than fits; always whole tiles of 64.
pub(crate) fn capacity(gpu: &Gpu, n: usize, per_sample: usize) -> usize {
    let fits = (gpu.limits.max_storage_buffer_binding_size / per_sample as u64) as usize / 64 * 64;
    (n + n / 4)
        .next_multiple_of(4096)
        .min(fits)
        .max(n.next_multiple_of(64))
}

/// The first `floats` values of a buffer (made with `COPY_SRC`), through a staging
/// buffer; waits for the work submitted so far.
pub(crate) fn read_f32(gpu: &Gpu, buf: &wgpu::Buffer, floats: usize) -> Result<Vec<f32>, GpuError> {
    let staging = gpu.checked("reading back", || {
        gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("staging"),
            size: 4 * floats as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })?;
    let mut out = vec![0.0; floats];
    read_f32_into(gpu, buf, &staging, &mut out)?;
    Ok(out)
}

/// The first `out.len()` values of `buf` into `out`, through `staging` (a `MAP_READ`
/// buffer at least that large, kept by the caller: allocating one the size of a field's
/// parameters on every step costs more than the copy); waits for the work submitted so
/// far.
pub(crate) fn read_f32_into(
    gpu: &Gpu,
    buf: &wgpu::Buffer,
    staging: &wgpu::Buffer,
    out: &mut [f32],
) -> Result<(), GpuError> {
    let bytes = 4 * out.len() as u64;
    gpu.checked("reading back", || {
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(buf, 0, staging, 0, bytes);
        gpu.queue.submit([enc.finish()]);
    })?;
    let slice = staging.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
    rx.recv()
        .map_err(|e| GpuError::Run(e.to_string()))?
        .map_err(|e| GpuError::Run(format!("reading back: {e}")))?;
    {
        let view = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Run(format!("reading back: {e}")))?;
        out.copy_from_slice(bytemuck::cast_slice(&view));
    }
    staging.unmap();
    Ok(())
}

/// An opened GPU: the adapter's description, its device and queue.
pub struct Gpu {
    pub info: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub limits: wgpu::Limits,
    /// Errors the device raised outside [`Gpu::checked`] (wgpu's default is to panic);
    /// [`Gpu::wait`] reports the first.
    errors: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Gpu({})", self.name())
    }
}

impl Gpu {
    /// Opens the device `choice` asks for: `Cpu` → `None`; `Auto` → the first hardware
    /// adapter, or `None`; `Gpu` → the first adapter of any kind, or [`GpuError::NoAdapter`].
    /// Hardware adapters are preferred (discrete, integrated, virtual, then software).
    pub fn open(choice: DeviceChoice) -> Result<Option<Gpu>, GpuError> {
        if choice == DeviceChoice::Cpu {
            return Ok(None);
        }
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
        desc.flags = wgpu::InstanceFlags::empty();
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            wgpu::DeviceType::Other => 3,
            wgpu::DeviceType::Cpu => 4,
        };
        adapters.sort_by_key(|a| rank(a.get_info().device_type));
        let hardware = |a: &wgpu::Adapter| a.get_info().device_type != wgpu::DeviceType::Cpu;
        let Some(adapter) = adapters
            .into_iter()
            .find(|a| choice == DeviceChoice::Gpu || hardware(a))
        else {
            return match choice {
                DeviceChoice::Gpu => Err(GpuError::NoAdapter),
                _ => Ok(None),
            };
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("assist"),
            // Float atomics sum the gradients where the adapter has them (Vulkan's
            // VK_EXT_shader_atomic_float: NVIDIA, AMD, lavapipe); a slower loop elsewhere.
            required_features: adapter.features() & wgpu::Features::SHADER_FLOAT32_ATOMIC,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
        let errors = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(std::sync::Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        Ok(Some(Gpu {
            info,
            device,
            queue,
            limits,
            errors,
        }))
    }

    /// "NAME (backend, kind)", for logs and `--json`.
    pub fn name(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// Runs `f` with the device's validation and out-of-memory errors captured, so that a
    /// kernel or buffer the adapter refuses becomes a [`GpuError`] naming `what`, not a
    /// panic.
    pub fn checked<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T, GpuError> {
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let valid = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let v = f();
        let errors = [
            pollster::block_on(valid.pop()),
            pollster::block_on(memory.pop()),
        ];
        match errors.into_iter().flatten().next() {
            Some(e) => Err(GpuError::Device {
                adapter: self.info.name.clone(),
                message: format!("{what}: {e}"),
            }),
            None => Ok(v),
        }
    }

    /// Waits until everything submitted so far has run.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Run(e.to_string()))?;
        let first = self.errors.lock().ok().and_then(|mut v| v.drain(..).next());
        match first {
            Some(e) => Err(GpuError::Run(e)),
            None => Ok(()),
        }
    }
}
