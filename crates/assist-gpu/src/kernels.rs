//! The wgpu plumbing every kernel set shares: bind group layouts of plain buffers, bind
//! groups over a list of buffers, and a WGSL module's compute pipelines.

use crate::Gpu;

/// Storage (read-only or read-write) or uniform, per binding in order.
pub(crate) const RO: wgpu::BufferBindingType = wgpu::BufferBindingType::Storage { read_only: true };
pub(crate) const RW: wgpu::BufferBindingType =
    wgpu::BufferBindingType::Storage { read_only: false };
pub(crate) const UNIFORM: wgpu::BufferBindingType = wgpu::BufferBindingType::Uniform;

/// A bind group layout of buffers, binding `i` of kind `kinds[i]`, for compute.
pub(crate) fn bind_layout(
    gpu: &Gpu,
    label: &str,
    kinds: &[wgpu::BufferBindingType],
) -> wgpu::BindGroupLayout {
    let entries: Vec<_> = kinds
        .iter()
        .enumerate()
        .map(|(i, &ty)| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    gpu.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &entries,
        })
}

/// A bind group binding `buffers[i]` whole at binding `i`.
pub(crate) fn bind(
    gpu: &Gpu,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<_> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// A WGSL module and the pipeline layout its kernels share.
pub(crate) struct Kernels {
    module: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
}

impl Kernels {
    pub(crate) fn new(
        gpu: &Gpu,
        label: &str,
        source: String,
        groups: &[&wgpu::BindGroupLayout],
    ) -> Self {
        let module = gpu
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let groups: Vec<_> = groups.iter().map(|g| Some(*g)).collect();
        let layout = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &groups,
                immediate_size: 0,
            });
        Kernels { module, layout }
    }

    /// The compute pipeline of entry point `name`.
    pub(crate) fn pipeline(&self, gpu: &Gpu, name: &str) -> wgpu::ComputePipeline {
        gpu.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(name),
                layout: Some(&self.layout),
                module: &self.module,
                entry_point: Some(name),
                compilation_options: Default::default(),
                cache: None,
            })
    }
}

/// A storage buffer holding `bytes` (copied to and from as well).
pub(crate) fn storage(gpu: &Gpu, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
        })
}
