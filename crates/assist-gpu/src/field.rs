//! One node's field resident on the GPU: its parameters, the level and layer tables, the
//! per-code biases, and sample/output buffers that grow with the largest batch seen.

use assist_field::{Field, Samples};

use crate::codegen::{header, tile};
use crate::kernels::{Kernels, RO, RW, UNIFORM, bind, bind_layout, storage};
use crate::{Gpu, GpuError};

const SHADER: &str = include_str!("shaders/field.wgsl");

/// A query submitted by [`GpuField::enqueue`]: its `n` samples' outputs (σ, then rgb
/// interleaved) on their way to a staging buffer.
pub(crate) struct Pending {
    staging: wgpu::Buffer,
    pub(crate) n: usize,
}

/// A buffer the outputs of `n` samples are read back through (σ and rgb: 16 bytes each).
pub(crate) fn staging_buffer(gpu: &Gpu, n: usize) -> Result<wgpu::Buffer, GpuError> {
    gpu.checked("allocating a read-back buffer", || {
        gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("staging"),
            size: 16 * n.max(1) as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })
}

/// Waits once for every query in `pending` and hands each one's σ and rgb to `out`;
/// gives back the staging buffers, unmapped, for reuse.
pub(crate) fn collect(
    gpu: &Gpu,
    pending: Vec<Pending>,
    mut out: impl FnMut(usize, &[f32], &[f32]),
) -> Result<Vec<wgpu::Buffer>, GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    for (k, p) in pending.iter().enumerate() {
        let tx = tx.clone();
        p.staging
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send((k, r));
            });
    }
    drop(tx);
    gpu.wait()?;
    for (_, r) in rx.iter() {
        r.map_err(|e| GpuError::Run(format!("reading back: {e}")))?;
    }
    for (k, p) in pending.iter().enumerate() {
        let view = p
            .staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| GpuError::Run(format!("reading back: {e}")))?;
        let v: &[f32] = bytemuck::cast_slice(&view);
        out(k, &v[..p.n], &v[p.n..4 * p.n]);
    }
    Ok(pending
        .into_iter()
        .map(|p| {
            p.staging.unmap();
            p.staging
        })
        .collect())
}

/// A field's parameters and kernels on one GPU.
pub struct GpuField {
    pub(crate) params: wgpu::Buffer,
    levels: wgpu::Buffer,
    pub(crate) code_bias: wgpu::Buffer,
    call: wgpu::Buffer,
    pub(crate) encode: wgpu::ComputePipeline,
    forward: wgpu::ComputePipeline,
    density: wgpu::ComputePipeline,
    pub(crate) bind_layout: wgpu::BindGroupLayout,
    /// Sample, image and output buffers for up to `capacity` samples.
    pub(crate) io: Option<Io>,
    /// Samples in the batch the buffers hold.
    pub(crate) n: usize,
    pub(crate) param_count: usize,
    /// Samples per workgroup of the nets' kernels.
    pub(crate) tile: u32,
    /// Features per sample (levels × features per level).
    enc_width: usize,
}

pub(crate) struct Io {
    pub(crate) capacity: usize,
    samples: wgpu::Buffer,
    image: wgpu::Buffer,
    pub(crate) out: wgpu::Buffer,
    /// The encoded features between the encoding and the nets.
    _enc: wgpu::Buffer,
    pub(crate) bind: wgpu::BindGroup,
}

impl GpuField {
    /// Uploads `field` and builds its kernels.
    pub fn new(gpu: &Gpu, field: &Field) -> Result<Self, GpuError> {
        Self::with_tile(gpu, field, None)
    }

    /// [`new`](Self::new) with the samples per workgroup forced (16, 32 or 64), for the
    /// tests of the smaller tiles that only narrow adapters or wide fields get.
    #[doc(hidden)]
    pub fn with_tile(gpu: &Gpu, field: &Field, force: Option<u32>) -> Result<Self, GpuError> {
        if field.config.reflect {
            return Err(GpuError::Device {
                adapter: gpu.info.name.clone(),
                message: "this field's colour follows the view direction reflected about a predicted normal (train --reflect), which the GPU kernels do not compute: use --device cpu".into(),
            });
        }
        let bytes = std::mem::size_of_val(field.params.as_slice()) as u64;
        if bytes > gpu.limits.max_storage_buffer_binding_size {
            return Err(GpuError::Device {
                adapter: gpu.info.name.clone(),
                message: format!(
                    "the field's {bytes} bytes of parameters exceed the adapter's largest storage binding ({} bytes)",
                    gpu.limits.max_storage_buffer_binding_size
                ),
            });
        }
        let lay = &field.layout;
        let levels: Vec<[u32; 4]> = lay
            .grid
            .levels
            .iter()
            .map(|l| [l.res, l.size, l.dense as u32, l.offset as u32])
            .collect();
        let (params, levels, code_bias, call) = gpu.checked("uploading the field", || {
            (
                storage(gpu, "params", bytemuck::cast_slice(&field.params)),
                storage(gpu, "levels", bytemuck::cast_slice(&levels)),
                storage(gpu, "code_bias", bytemuck::cast_slice(&field.code_biases())),
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("call"),
                    size: 16,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            )
        })?;
        let tile = match force {
            Some(t @ (16 | 32 | 64)) => t,
            Some(t) => {
                return Err(GpuError::Run(format!(
                    "tile: expected 16, 32 or 64, got {t}"
                )));
            }
            None => tile(gpu, field)?,
        };
        gpu.checked("building the field's kernels", || {
            Self::build(gpu, field, tile, params, levels, code_bias, call)
        })
    }

    fn build(
        gpu: &Gpu,
        field: &Field,
        tile: u32,
        params: wgpu::Buffer,
        levels: wgpu::Buffer,
        code_bias: wgpu::Buffer,
        call: wgpu::Buffer,
    ) -> Self {
        let source = format!("{}{SHADER}", header(field, tile, false));
        let bind_layout = bind_layout(gpu, "field", &[RO, RO, RO, RO, RO, RW, UNIFORM, RW]);
        let kernels = Kernels::new(gpu, "field.wgsl", source, &[&bind_layout]);
        let pipeline = |name: &str| kernels.pipeline(gpu, name);
        let encode = pipeline("encode");
        let forward = pipeline("forward_nets");
        let density = pipeline("density_nets");
        GpuField {
            params,
            levels,
            code_bias,
            call,
            encode,
            forward,
            density,
            bind_layout,
            io: None,
            n: 0,
            param_count: field.params.len(),
            tile,
            enc_width: field.config.encoding_width(),
        }
    }

    /// Replaces the parameters (same configuration) with `field`'s, e.g. after CPU steps.
    pub fn upload(&self, gpu: &Gpu, field: &Field) -> Result<(), GpuError> {
        if field.params.len() != self.param_count {
            return Err(GpuError::Run(format!(
                "upload: field has {} parameters, the GPU copy {}",
                field.params.len(),
                self.param_count
            )));
        }
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::cast_slice(&field.params));
        gpu.queue.write_buffer(
            &self.code_bias,
            0,
            bytemuck::cast_slice(&field.code_biases()),
        );
        Ok(())
    }

    /// The code of novel views' samples for the next queries: the last row of the
    /// code biases, from `novel` or the average code (see `Field::code_biases_for`).
    pub(crate) fn set_novel(&self, gpu: &Gpu, field: &Field, novel: Option<&[f32]>) {
        if field.config.appearance_dim == 0 {
            return;
        }
        let out = field.layout.color[0].out;
        let rows = field.code_biases_for(novel);
        let last = &rows[field.config.num_images * out..];
        let at = (field.config.num_images * out * std::mem::size_of::<f32>()) as u64;
        gpu.queue
            .write_buffer(&self.code_bias, at, bytemuck::cast_slice(last));
    }

    /// Makes room for `n` samples (buffers grow, never shrink).
    fn reserve(&mut self, gpu: &Gpu, n: usize) -> Result<(), GpuError> {
        if self.io.as_ref().is_some_and(|io| io.capacity >= n) {
            return Ok(());
        }
        // The widest per-sample buffer: the features (or positions and directions).
        let per_sample = 4 * self.enc_width.max(6);
        crate::check_batch(gpu, n, per_sample, "features")?;
        let capacity = crate::capacity(gpu, n, per_sample);
        let what = format!("allocating a batch of {n} samples");
        let io = gpu.checked(&what, || {
            let buffer = |label: &str, floats: usize, usage: wgpu::BufferUsages| {
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: 4 * floats as u64,
                    usage,
                    mapped_at_creation: false,
                })
            };
            use wgpu::BufferUsages as U;
            let samples = buffer("samples", 6 * capacity, U::STORAGE | U::COPY_DST);
            let image = buffer("image", capacity, U::STORAGE | U::COPY_DST);
            let out = buffer("out", 4 * capacity, U::STORAGE | U::COPY_SRC);
            let tiles = capacity.div_ceil(self.tile as usize) * self.tile as usize;
            let enc = buffer("enc", tiles * self.enc_width, U::STORAGE);
            let bind = bind(
                gpu,
                "field",
                &self.bind_layout,
                &[
                    &self.params,
                    &self.levels,
                    &self.code_bias,
                    &samples,
                    &image,
                    &out,
                    &self.call,
                    &enc,
                ],
            );
            Io {
                capacity,
                samples,
                image,
                out,
                _enc: enc,
                bind,
            }
        })?;
        self.io = Some(io);
        Ok(())
    }

    /// Copies a batch of samples to the GPU (directions and codes may be left empty for
    /// density-only work: directions then read as zero, codes as the average).
    pub fn load(&mut self, gpu: &Gpu, s: &Samples) -> Result<(), GpuError> {
        let n = s.len();
        self.reserve(gpu, n)?;
        let io = self.io.as_ref().expect("reserved");
        // Positions then directions, each axis a run of n values (no copy made here:
        // each slice goes straight to wgpu's staging memory).
        let zeros = match s.dir.iter().any(|d| d.is_empty()) {
            true => vec![0.0f32; n],
            false => Vec::new(),
        };
        for a in 0..6 {
            let v = if a < 3 { s.pos[a] } else { s.dir[a - 3] };
            let v = if v.is_empty() { &zeros[..] } else { &v[..n] };
            gpu.queue
                .write_buffer(&io.samples, (4 * a * n) as u64, bytemuck::cast_slice(v));
        }
        let image: Vec<u32>;
        let image = match s.image.len() >= n {
            true => &s.image[..n],
            false => {
                image = (0..n)
                    .map(|i| s.image.get(i).copied().unwrap_or(u32::MAX))
                    .collect();
                &image[..]
            }
        };
        gpu.queue
            .write_buffer(&io.image, 0, bytemuck::cast_slice(image));
        gpu.queue
            .write_buffer(&self.call, 0, bytemuck::cast_slice(&[n as u32, 0, 0, 0]));
        self.n = n;
        Ok(())
    }

    /// Workgroups of a dispatch over the loaded batch, `per` samples each (x, y: past the
    /// adapter's largest x, the rest goes to y).
    pub(crate) fn groups(&self, gpu: &Gpu, per: u32) -> (u32, u32) {
        let groups = (self.n as u32).div_ceil(per);
        let max = gpu.limits.max_compute_workgroups_per_dimension;
        if groups <= max {
            (groups, 1)
        } else {
            (max, groups.div_ceil(max))
        }
    }

    /// Submits `reps` runs of the encoding then `nets` over the loaded batch, back to back
    /// in one command buffer, and returns without waiting.
    fn submit(&self, gpu: &Gpu, nets: &wgpu::ComputePipeline, reps: usize) {
        let Some(io) = self.io.as_ref().filter(|_| self.n > 0) else {
            return;
        };
        let (ex, ey) = self.groups(gpu, 64);
        let (nx, ny) = self.groups(gpu, self.tile);
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_bind_group(0, &io.bind, &[]);
            for _ in 0..reps {
                pass.set_pipeline(&self.encode);
                pass.dispatch_workgroups(ex, ey, 1);
                pass.set_pipeline(nets);
                pass.dispatch_workgroups(nx, ny, 1);
            }
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// Inference over the loaded batch, `reps` times back to back, waited for; the results
    /// stay on the GPU.
    pub fn run_forward(&self, gpu: &Gpu, reps: usize) -> Result<(), GpuError> {
        self.submit(gpu, &self.forward, reps);
        gpu.wait()
    }

    /// Density over the loaded batch, `reps` times back to back, waited for.
    pub fn run_density(&self, gpu: &Gpu, reps: usize) -> Result<(), GpuError> {
        self.submit(gpu, &self.density, reps);
        gpu.wait()
    }

    /// Loads `s`, submits its inference and the copy of its outputs to `staging` (a
    /// readable buffer of at least 16 bytes a sample, see [`staging_buffer`]), and returns
    /// without waiting: several fields' queries then share one wait ([`collect`]). Queue
    /// order keeps a later load of the same field from overwriting this one's samples
    /// before they are used.
    pub(crate) fn enqueue(
        &mut self,
        gpu: &Gpu,
        s: &Samples,
        staging: wgpu::Buffer,
    ) -> Result<Pending, GpuError> {
        self.load(gpu, s)?;
        self.submit(gpu, &self.forward, 1);
        Ok(self.copy_out(gpu, staging))
    }

    /// Submits the copy of the last run's outputs to `staging` (at least 16 bytes a
    /// sample), for [`collect`].
    pub(crate) fn copy_out(&self, gpu: &Gpu, staging: wgpu::Buffer) -> Pending {
        let n = self.n;
        if let Some(io) = self.io.as_ref().filter(|_| n > 0) {
            let mut enc = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            enc.copy_buffer_to_buffer(&io.out, 0, &staging, 0, 16 * n as u64);
            gpu.queue.submit([enc.finish()]);
        }
        Pending { staging, n }
    }

    /// The first `floats` outputs of the last run (σ, then rgb interleaved).
    fn read(&self, gpu: &Gpu, floats: usize) -> Result<Vec<f32>, GpuError> {
        let io = self.io.as_ref().expect("a batch was loaded");
        crate::read_f32(gpu, &io.out, floats)
    }

    /// Inference, as `Field::forward`: σ per sample and rgb interleaved.
    pub fn forward(
        &mut self,
        gpu: &Gpu,
        s: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Result<(), GpuError> {
        let n = s.len();
        if n == 0 {
            return Ok(());
        }
        self.load(gpu, s)?;
        self.run_forward(gpu, 1)?;
        let v = self.read(gpu, 4 * n)?;
        sigma[..n].copy_from_slice(&v[..n]);
        rgb[..3 * n].copy_from_slice(&v[n..4 * n]);
        Ok(())
    }

    /// Density only, as `Field::density`.
    pub fn density(
        &mut self,
        gpu: &Gpu,
        pos: [&[f32]; 3],
        sigma: &mut [f32],
    ) -> Result<(), GpuError> {
        let n = pos[0].len();
        if n == 0 {
            return Ok(());
        }
        let s = Samples {
            pos,
            dir: [&[], &[], &[]],
            image: &[],
        };
        self.load(gpu, &s)?;
        self.run_density(gpu, 1)?;
        let v = self.read(gpu, n)?;
        sigma[..n].copy_from_slice(&v);
        Ok(())
    }
}
