//! One node's field resident on the GPU: its parameters, the level and layer tables, the
//! per-code biases, and sample/output buffers that grow with the largest batch seen.

use assist_field::{Field, Samples};
use wgpu::util::DeviceExt;

use crate::{Gpu, GpuError};

const SHADER: &str = include_str!("shaders/field.wgsl");
/// Invocations per workgroup (the shader's `@workgroup_size`).
const GROUP: u32 = 64;

/// The WGSL constants of one field configuration, prepended to the shader.
fn header(field: &Field) -> String {
    let c = &field.config;
    let l = &field.layout;
    let maxw = [
        c.encoding_width(),
        c.hidden,
        1 + c.geo_features,
        c.geo_features + c.sh_width(),
        c.color_hidden,
        3,
    ]
    .into_iter()
    .max()
    .unwrap_or(1);
    let mut h = format!(
        "const LEVELS: u32 = {}u;\nconst FEAT: u32 = {}u;\nconst ENC_W: u32 = {}u;\n\
         const GEO: u32 = {}u;\nconst SH_DEGREE: u32 = {}u;\n\
         const APPEARANCE: bool = {};\nconst NUM_IMAGES: u32 = {}u;\nconst MAXW: u32 = {}u;\n",
        c.levels,
        c.features_per_level,
        c.encoding_width(),
        c.geo_features,
        c.sh_degree,
        c.appearance_dim > 0,
        c.num_images,
        maxw
    );
    let d = &l.density;
    h += &layer_fn("layer0", &d[0], c.encoding_width(), Bias::Params, true);
    h += &layer_fn("layer1", &d[1], c.hidden, Bias::Params, false);
    // The colour net: its first layer over geometry + SH (the code acts through the bias).
    let nets = l.color.len();
    let cols0 = c.geo_features + c.sh_width();
    h += &layer_fn("color0", &l.color[0], cols0, Bias::Code, nets > 1);
    let mut body = String::from("    color0(slot, x, y);\n");
    for (k, ly) in l.color.iter().enumerate().skip(1) {
        let name = format!("color{k}");
        h += &layer_fn(&name, ly, l.color[k - 1].out, Bias::Params, k + 1 < nets);
        // Ping-pong: odd layers read y and write x, even ones the reverse.
        let (from, to) = if k % 2 == 1 { ("y", "x") } else { ("x", "y") };
        body += &format!("    {name}({from}, {to});\n");
    }
    let last = if nets % 2 == 0 { "x" } else { "y" };
    h += &format!(
        "// The colour net: input in x, result (pre-sigmoid rgb) returned; x and y are scratch.\n\
         fn color_net(slot: u32, x: ptr<function, array<f32, MAXW>>, y: ptr<function, array<f32, MAXW>>) -> vec3<f32> {{\n\
         {body}    return vec3<f32>((*{last})[0], (*{last})[1], (*{last})[2]);\n}}\n"
    );
    h
}

/// Where a layer's bias comes from: the parameters, or the per-code table (slot argument).
#[derive(PartialEq)]
enum Bias {
    Params,
    Code,
}

/// A WGSL function computing `y[..out] = act(W[:, ..cols] x + b)` for one layer, with its
/// sizes and offsets as constants.
fn layer_fn(name: &str, l: &assist_field::Linear, cols: usize, bias: Bias, relu: bool) -> String {
    let (slot_arg, b) = match bias {
        Bias::Params => (String::new(), format!("params[{}u + o]", l.b)),
        Bias::Code => (
            "slot: u32, ".into(),
            format!("code_bias[slot * {}u + o]", l.out),
        ),
    };
    let act = if relu { "max(acc, 0.0)" } else { "acc" };
    format!(
        "fn {name}({slot_arg}x: ptr<function, array<f32, MAXW>>, y: ptr<function, array<f32, MAXW>>) {{\n\
         \x20   for (var o = 0u; o < {out}u; o++) {{\n\
         \x20       var acc = {b};\n\
         \x20       for (var i = 0u; i < {cols}u; i++) {{\n\
         \x20           acc = fma(params[{w}u + o * {pad}u + i], (*x)[i], acc);\n\
         \x20       }}\n\
         \x20       (*y)[o] = {act};\n\
         \x20   }}\n}}\n",
        out = l.out,
        w = l.w,
        pad = l.inp_pad,
    )
}

/// A field's parameters and kernels on one GPU.
pub struct GpuField {
    params: wgpu::Buffer,
    levels: wgpu::Buffer,
    code_bias: wgpu::Buffer,
    call: wgpu::Buffer,
    forward: wgpu::ComputePipeline,
    density: wgpu::ComputePipeline,
    bind_layout: wgpu::BindGroupLayout,
    /// Sample, image and output buffers for up to `capacity` samples.
    io: Option<Io>,
    /// Samples in the batch the buffers hold.
    n: usize,
    param_count: usize,
}

struct Io {
    capacity: usize,
    samples: wgpu::Buffer,
    image: wgpu::Buffer,
    out: wgpu::Buffer,
    readback: wgpu::Buffer,
    bind: wgpu::BindGroup,
}

fn storage(gpu: &Gpu, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        })
}

impl GpuField {
    /// Uploads `field` and builds its kernels.
    pub fn new(gpu: &Gpu, field: &Field) -> Result<Self, GpuError> {
        let bytes = std::mem::size_of_val(field.params.as_slice()) as u64;
        if bytes > gpu.limits.max_storage_buffer_binding_size as u64 {
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
        gpu.checked("building the field's kernels", || {
            Self::build(gpu, field, params, levels, code_bias, call)
        })
    }

    fn build(
        gpu: &Gpu,
        field: &Field,
        params: wgpu::Buffer,
        levels: wgpu::Buffer,
        code_bias: wgpu::Buffer,
        call: wgpu::Buffer,
    ) -> Self {
        let source = format!("{}{SHADER}", header(field));
        let module = gpu
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("field.wgsl"),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let entry = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let ro = wgpu::BufferBindingType::Storage { read_only: true };
        let mut entries: Vec<_> = (0..5).map(|b| entry(b, ro)).collect();
        entries.push(entry(
            5,
            wgpu::BufferBindingType::Storage { read_only: false },
        ));
        entries.push(entry(6, wgpu::BufferBindingType::Uniform));
        let bind_layout = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("field"),
                entries: &entries,
            });
        let pipeline_layout = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("field"),
                bind_group_layouts: &[Some(&bind_layout)],
                immediate_size: 0,
            });
        let pipeline = |name: &str| {
            gpu.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(name),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some(name),
                    compilation_options: Default::default(),
                    cache: None,
                })
        };
        let forward = pipeline("forward");
        let density = pipeline("density");
        GpuField {
            params,
            levels,
            code_bias,
            call,
            forward,
            density,
            bind_layout,
            io: None,
            n: 0,
            param_count: field.params.len(),
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

    /// Makes room for `n` samples (buffers grow, never shrink).
    fn reserve(&mut self, gpu: &Gpu, n: usize) -> Result<(), GpuError> {
        if self.io.as_ref().is_some_and(|io| io.capacity >= n) {
            return Ok(());
        }
        let capacity = n.max(1).next_power_of_two();
        let largest = gpu.limits.max_storage_buffer_binding_size as u64;
        if 6 * 4 * capacity as u64 > largest {
            return Err(GpuError::Run(format!(
                "a batch of {n} samples needs {} bytes of positions and directions, more than the adapter's largest storage binding ({largest} bytes)",
                6 * 4 * n
            )));
        }
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
            let readback = buffer("readback", 4 * capacity, U::MAP_READ | U::COPY_DST);
            let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("field"),
                layout: &self.bind_layout,
                entries: &[
                    &self.params,
                    &self.levels,
                    &self.code_bias,
                    &samples,
                    &image,
                    &out,
                    &self.call,
                ]
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect::<Vec<_>>(),
            });
            Io {
                capacity,
                samples,
                image,
                out,
                readback,
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
        let mut soa = Vec::with_capacity(6 * n);
        for a in 0..3 {
            soa.extend_from_slice(&s.pos[a][..n]);
        }
        for a in 0..3 {
            match s.dir[a].len() {
                0 => soa.resize(soa.len() + n, 0.0),
                _ => soa.extend_from_slice(&s.dir[a][..n]),
            }
        }
        let image: Vec<u32> = (0..n)
            .map(|i| s.image.get(i).copied().unwrap_or(u32::MAX))
            .collect();
        gpu.queue
            .write_buffer(&io.samples, 0, bytemuck::cast_slice(&soa));
        gpu.queue
            .write_buffer(&io.image, 0, bytemuck::cast_slice(&image));
        gpu.queue
            .write_buffer(&self.call, 0, bytemuck::cast_slice(&[n as u32, 0, 0, 0]));
        self.n = n;
        Ok(())
    }

    /// Runs one kernel over the loaded batch (submitted, not waited for).
    fn dispatch(&self, gpu: &Gpu, pipeline: &wgpu::ComputePipeline) {
        let Some(io) = self.io.as_ref().filter(|_| self.n > 0) else {
            return;
        };
        let groups = (self.n as u32).div_ceil(GROUP);
        let max = gpu.limits.max_compute_workgroups_per_dimension;
        let (x, y) = if groups <= max {
            (groups, 1)
        } else {
            (max, groups.div_ceil(max))
        };
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &io.bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// Inference over the loaded batch, waited for; the results stay on the GPU.
    pub fn run_forward(&self, gpu: &Gpu) -> Result<(), GpuError> {
        self.dispatch(gpu, &self.forward);
        gpu.wait()
    }

    /// Density over the loaded batch, waited for; the results stay on the GPU.
    pub fn run_density(&self, gpu: &Gpu) -> Result<(), GpuError> {
        self.dispatch(gpu, &self.density);
        gpu.wait()
    }

    /// The first `floats` outputs of the last run (σ, then rgb interleaved).
    fn read(&self, gpu: &Gpu, floats: usize) -> Result<Vec<f32>, GpuError> {
        let io = self.io.as_ref().expect("a batch was loaded");
        let bytes = 4 * floats as u64;
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(&io.out, 0, &io.readback, 0, bytes);
        gpu.queue.submit([enc.finish()]);
        let slice = io.readback.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        gpu.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Run(e.to_string()))?
            .map_err(|e| GpuError::Run(format!("reading results back: {e}")))?;
        let v = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Run(format!("reading results back: {e}")))?;
            bytemuck::cast_slice(&view).to_vec()
        };
        io.readback.unmap();
        Ok(v)
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
        self.run_forward(gpu)?;
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
        self.run_density(gpu)?;
        let v = self.read(gpu, n)?;
        sigma[..n].copy_from_slice(&v);
        Ok(())
    }
}
