//! Training a field on the GPU: the forward pass with its record, the backward pass
//! through the nets, the weight, appearance and hash-grid gradients, and Adam, all on
//! buffers resident in GPU memory. Gradients are summed with float atomics where the
//! adapter has them (a compare-exchange loop elsewhere), so their last bits depend on the
//! order the adapter runs them in; the CPU path is the bit-reproducible reference.

use assist_field::{Adam, Field};

use crate::codegen::{TapeRows, dw_groups, dw_layers, header, train_header};
use crate::kernels::{Kernels, RW, UNIFORM, bind, bind_layout, storage};
use crate::{Gpu, GpuError, GpuField};

const FIELD: &str = include_str!("shaders/field.wgsl");
const TRAIN: &str = include_str!("shaders/train.wgsl");
const ADAM: &str = include_str!("shaders/adam.wgsl");

/// Adam's settings and step count, mirrored from [`assist_field::Adam`].
struct AdamState {
    beta1: f32,
    beta2: f32,
    eps: f32,
    weight_decay: f32,
    decay: std::ops::Range<usize>,
    sparse: std::ops::Range<usize>,
    table_decay: f32,
    step: u32,
}

/// A field's training state on one GPU, beside its [`GpuField`] (which holds the
/// parameters and the batch).
pub struct GpuTrainer {
    grad: wgpu::Buffer,
    code_sums: wgpu::Buffer,
    forward: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    dw: Vec<wgpu::ComputePipeline>,
    /// Workgroups of each weight-gradient dispatch at most.
    dw_groups: u32,
    code_sums_k: wgpu::ComputePipeline,
    code_backward: wgpu::ComputePipeline,
    encode_backward: wgpu::ComputePipeline,
    layout1: wgpu::BindGroupLayout,
    /// Per-batch buffers (tape, gradients at the layers, loss gradients), for up to
    /// `capacity` samples, with their bind group.
    batch: Option<Batch>,
    adam: wgpu::ComputePipeline,
    /// Recomputes the per-code biases after Adam (they fold weights and codes).
    refresh: wgpu::ComputePipeline,
    /// The hyper-parameter block's layout words for `refresh_codes`.
    code_layout: [u32; 8],
    adam_bind: wgpu::BindGroup,
    hyper: wgpu::Buffer,
    state: AdamState,
    appearance: bool,
    code_threads: u32,
    param_count: usize,
}

struct Batch {
    capacity: usize,
    d_out: wgpu::Buffer,
    bind: wgpu::BindGroup,
}

/// Adam and the per-code bias refresh: their own module over the field's parameters and
/// the trainer's gradient and moments (`[grad, m, v]`); returns both kernels, their bind
/// group and the hyper-parameter block.
fn adam_kernels(
    gpu: &Gpu,
    gf: &GpuField,
    [grad, m, v]: [&wgpu::Buffer; 3],
) -> (
    wgpu::ComputePipeline,
    wgpu::ComputePipeline,
    wgpu::BindGroup,
    wgpu::Buffer,
) {
    let adam_layout = bind_layout(gpu, "adam", &[RW, RW, RW, RW, UNIFORM, RW]);
    let kernels = Kernels::new(gpu, "adam.wgsl", ADAM.into(), &[&adam_layout]);
    let hyper = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("adam.hyper"),
        size: 80,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let adam_bind = bind(
        gpu,
        "adam",
        &adam_layout,
        &[&gf.params, grad, m, v, &hyper, &gf.code_bias],
    );
    (
        kernels.pipeline(gpu, "adam"),
        kernels.pipeline(gpu, "refresh_codes"),
        adam_bind,
        hyper,
    )
}

/// The kernels of a training step, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    Encode,
    Forward,
    Backward,
    WeightGrads,
    Codes,
    GridGrads,
}

impl Stage {
    const ALL: [Stage; 6] = [
        Stage::Encode,
        Stage::Forward,
        Stage::Backward,
        Stage::WeightGrads,
        Stage::Codes,
        Stage::GridGrads,
    ];
    fn name(self) -> &'static str {
        match self {
            Stage::Encode => "encode",
            Stage::Forward => "forward_nets",
            Stage::Backward => "backward_nets",
            Stage::WeightGrads => "weight_grads",
            Stage::Codes => "code_grads",
            Stage::GridGrads => "grid_grads",
        }
    }
}

/// `refresh_codes`' words of the hyper-parameter block: the first colour layer's weight,
/// bias, row stride, outputs, first code column; the codes' offset, width and count.
fn code_layout(field: &Field) -> [u32; 8] {
    let (c, l) = (&field.config, &field.layout);
    let c0 = &l.color[0];
    [
        c0.w,
        c0.b,
        c0.inp_pad,
        c0.out,
        c.geo_features + c.sh_width(),
        l.appearance,
        c.appearance_dim,
        c.num_images,
    ]
    .map(|v| v as u32)
}

impl GpuTrainer {
    /// The most samples one training batch of `field` may hold on `gpu`: its record (the
    /// widest per-sample buffer) must fit one storage binding, in whole tiles of 64.
    pub fn max_batch(gpu: &Gpu, field: &Field) -> usize {
        let rows = TapeRows::new(field);
        let per_sample = 4 * rows
            .total
            .max(rows.d_total)
            .max(field.config.encoding_width())
            .max(6);
        (gpu.limits.max_storage_buffer_binding_size / per_sample as u64) as usize / 64 * 64
    }

    /// Builds the training kernels of `field` (uploaded as `gf`) with `adam`'s settings
    /// and moments.
    pub fn new(gpu: &Gpu, gf: &GpuField, field: &Field, adam: &Adam) -> Result<Self, GpuError> {
        let float_atomics = gpu
            .device
            .features()
            .contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
        Self::with_atomics(gpu, gf, field, adam, float_atomics)
    }

    /// [`new`](Self::new) with float atomics forced off (`false`: the compare-exchange
    /// path), for the tests of adapters that lack them.
    #[doc(hidden)]
    pub fn with_atomics(
        gpu: &Gpu,
        gf: &GpuField,
        field: &Field,
        adam: &Adam,
        float_atomics: bool,
    ) -> Result<Self, GpuError> {
        let err = |message: String| GpuError::Device {
            adapter: gpu.info.name.clone(),
            message,
        };
        let limit = gpu.limits.max_storage_buffers_per_shader_stage;
        if limit < 13 {
            return Err(err(format!(
                "training needs 13 storage buffers per kernel (7 of the field, 6 of training); the adapter allows {limit}"
            )));
        }
        let float_atomics = float_atomics
            && gpu
                .device
                .features()
                .contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
        let dw_groups = dw_groups()?;
        let extra = train_header(field, gf.tile, float_atomics).map_err(err)?;
        let source = format!("{}{extra}{FIELD}{TRAIN}", header(field, gf.tile, true));
        let n = field.params.len();
        let state = AdamState {
            beta1: adam.beta1,
            beta2: adam.beta2,
            eps: adam.eps,
            weight_decay: adam.weight_decay,
            decay: adam.decay_range.clone(),
            sparse: adam.sparse_range.clone(),
            table_decay: adam.table_decay,
            step: adam.step,
        };
        if adam.m.len() != n {
            return Err(GpuError::Run(format!(
                "adam: moments for {} parameters, the field has {n}",
                adam.m.len()
            )));
        }
        gpu.checked("building the training kernels", || {
            let storage = |label: &str, bytes: &[u8]| storage(gpu, label, bytes);
            let grad = storage("grad", bytemuck::cast_slice(&vec![0f32; n]));
            let m = storage("adam.m", bytemuck::cast_slice(&adam.m));
            let v = storage("adam.v", bytemuck::cast_slice(&adam.v));
            let code_rows = (field.config.num_images + 1) * field.layout.color[0].out;
            let code_sums = storage("code_sums", bytemuck::cast_slice(&vec![0f32; code_rows]));
            let layout1 = bind_layout(gpu, "train", &[RW; 6]);
            let kernels = Kernels::new(gpu, "train.wgsl", source, &[&gf.bind_layout, &layout1]);
            let pipeline = |name: &str| kernels.pipeline(gpu, name);
            let dw = dw_layers(field).iter().map(|y| pipeline(&y.name)).collect();
            let (adam_p, refresh, adam_bind, hyper) = adam_kernels(gpu, gf, [&grad, &m, &v]);
            let cfg = &field.config;
            GpuTrainer {
                forward: pipeline("forward_nets"),
                backward: pipeline("backward_nets"),
                dw,
                dw_groups: dw_groups.min(gpu.limits.max_compute_workgroups_per_dimension),
                code_sums_k: pipeline("code_sums_of_tile"),
                code_backward: pipeline("code_backward"),
                encode_backward: pipeline("encode_backward"),
                grad,
                code_sums,
                layout1,
                batch: None,
                adam: adam_p,
                refresh,
                code_layout: code_layout(field),
                adam_bind,
                hyper,
                state,
                appearance: cfg.appearance_dim > 0,
                code_threads: ((cfg.num_images + field.layout.color[0].out) * cfg.appearance_dim)
                    as u32,
                param_count: n,
            }
        })
    }

    /// Caps the workgroups of the weight-gradient dispatches (`ASSIST_GPU_DW_GROUPS`), for
    /// the tests of workgroups that loop over several tiles.
    #[doc(hidden)]
    pub fn set_dw_groups(&mut self, groups: u32) {
        self.dw_groups = groups.max(1);
    }

    /// Sets the loss's gradients for the batch loaded in `gf`: dL/dσ per sample and
    /// dL/drgb interleaved.
    pub fn set_loss_grads(
        &mut self,
        gpu: &Gpu,
        gf: &GpuField,
        field: &Field,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) -> Result<(), GpuError> {
        let n = gf.n;
        if d_sigma.len() != n || d_rgb.len() != 3 * n {
            return Err(GpuError::Run(format!(
                "loss gradients: expected {n} and {} values for the loaded batch, got {} and {}",
                3 * n,
                d_sigma.len(),
                d_rgb.len()
            )));
        }
        self.reserve(gpu, gf, field)?;
        let b = self.batch.as_ref().expect("allocated");
        // σ's gradients, then rgb's (each slice straight to wgpu's staging memory).
        if n > 0 {
            gpu.queue
                .write_buffer(&b.d_out, 0, bytemuck::cast_slice(d_sigma));
            gpu.queue
                .write_buffer(&b.d_out, 4 * n as u64, bytemuck::cast_slice(d_rgb));
        }
        Ok(())
    }

    /// Makes room for the training record of the batch loaded in `gf`.
    fn reserve(&mut self, gpu: &Gpu, gf: &GpuField, field: &Field) -> Result<(), GpuError> {
        let n = gf.n;
        if gf.io.is_none() {
            return Err(GpuError::Run("no batch loaded".into()));
        }
        let rows = TapeRows::new(field);
        let per_sample = 4 * rows.total.max(rows.d_total);
        crate::check_batch(gpu, n, per_sample, "training record")?;
        if self.batch.as_ref().is_none_or(|b| b.capacity < n) {
            let capacity = crate::capacity(gpu, n, per_sample);
            let tiles = capacity;
            let what = format!("allocating the training record of {capacity} samples");
            let batch = gpu.checked(&what, || {
                let buffer = |label: &str, floats: usize| {
                    gpu.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some(label),
                        size: 4 * floats as u64,
                        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                        mapped_at_creation: false,
                    })
                };
                let tape = buffer("tape", tiles * rows.total);
                let dtape = buffer("dtape", tiles * rows.d_total);
                let d_enc = buffer("d_enc", tiles * field.config.encoding_width());
                let d_out = buffer("d_out", 4 * capacity);
                let bind = bind(
                    gpu,
                    "train",
                    &self.layout1,
                    &[&tape, &dtape, &d_enc, &d_out, &self.grad, &self.code_sums],
                );
                Batch {
                    capacity,
                    d_out,
                    bind,
                }
            })?;
            self.batch = Some(batch);
        }
        Ok(())
    }

    /// Submits `reps` forward + backward passes over the loaded batch (gradients summed
    /// into the gradient buffer, as `Field::backward` sums into `grad`), without waiting.
    pub fn submit_step(&self, gpu: &Gpu, gf: &GpuField, reps: usize) -> Result<(), GpuError> {
        self.submit_stages(gpu, gf, reps, &Stage::ALL)
    }

    /// Submits the forward pass over the batch loaded in `gf`, keeping its training
    /// record (σ and rgb in the outputs as from [`GpuField::forward`]), without waiting:
    /// [`Self::submit_backward`] (after [`Self::set_loss_grads`]) then needs no second
    /// forward pass.
    pub fn submit_forward_recorded(
        &mut self,
        gpu: &Gpu,
        gf: &GpuField,
        field: &Field,
    ) -> Result<(), GpuError> {
        self.reserve(gpu, gf, field)?;
        self.submit_stages(gpu, gf, 1, &Stage::ALL[..2])
    }

    /// The backward pass from the record of [`Self::submit_forward_recorded`] (the same batch
    /// still loaded) and the loss gradients set since, without waiting.
    pub fn submit_backward(&self, gpu: &Gpu, gf: &GpuField) -> Result<(), GpuError> {
        self.submit_stages(gpu, gf, 1, &Stage::ALL[2..])
    }

    /// Submits `reps` runs of the given stages, in their order.
    fn submit_stages(
        &self,
        gpu: &Gpu,
        gf: &GpuField,
        reps: usize,
        stages: &[Stage],
    ) -> Result<(), GpuError> {
        let (Some(io), Some(b)) = (gf.io.as_ref(), self.batch.as_ref()) else {
            return Err(GpuError::Run("no batch or loss gradients loaded".into()));
        };
        if gf.n == 0 {
            return Ok(());
        }
        let (ex, ey) = gf.groups(gpu, 64);
        let (tx, ty) = gf.groups(gpu, gf.tile);
        let dw_groups = (gf.n as u32).div_ceil(gf.tile).min(self.dw_groups);
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        for _ in 0..reps {
            let codes = self.appearance && stages.contains(&Stage::Codes);
            if codes {
                enc.clear_buffer(&self.code_sums, 0, None);
            }
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_bind_group(0, &io.bind, &[]);
            pass.set_bind_group(1, &b.bind, &[]);
            for stage in stages {
                match stage {
                    Stage::Encode => {
                        pass.set_pipeline(&gf.encode);
                        pass.dispatch_workgroups(ex, ey, 1);
                    }
                    Stage::Forward => {
                        pass.set_pipeline(&self.forward);
                        pass.dispatch_workgroups(tx, ty, 1);
                    }
                    Stage::Backward => {
                        pass.set_pipeline(&self.backward);
                        pass.dispatch_workgroups(tx, ty, 1);
                    }
                    Stage::WeightGrads => {
                        for p in &self.dw {
                            pass.set_pipeline(p);
                            pass.dispatch_workgroups(dw_groups, 1, 1);
                        }
                    }
                    Stage::Codes if codes => {
                        pass.set_pipeline(&self.code_sums_k);
                        pass.dispatch_workgroups(tx, ty, 1);
                        pass.set_pipeline(&self.code_backward);
                        pass.dispatch_workgroups(self.code_threads.div_ceil(64).max(1), 1, 1);
                    }
                    Stage::Codes => {}
                    Stage::GridGrads => {
                        pass.set_pipeline(&self.encode_backward);
                        pass.dispatch_workgroups(ex, ey, 1);
                    }
                }
            }
        }
        gpu.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Seconds per run of each stage of a training step over the loaded batch, each
    /// timed alone (`reps` runs queued, one wait), for benchmarks: where a step's time
    /// goes. Leaves gradients summed in the gradient buffer (run before real steps, or
    /// zero them with an Adam step).
    pub fn time_stages(
        &mut self,
        gpu: &Gpu,
        gf: &GpuField,
        reps: usize,
    ) -> Result<Vec<(&'static str, f64)>, GpuError> {
        let reps = reps.max(1);
        let mut out = Vec::new();
        // Fill the record once so that every stage reads what a step would.
        self.submit_step(gpu, gf, 1)?;
        gpu.wait()?;
        for stage in Stage::ALL {
            let t0 = std::time::Instant::now();
            self.submit_stages(gpu, gf, reps, &[stage])?;
            gpu.wait()?;
            out.push((stage.name(), t0.elapsed().as_secs_f64() / reps as f64));
        }
        let t0 = std::time::Instant::now();
        for _ in 0..reps {
            self.submit_adam(gpu, 0.0);
        }
        gpu.wait()?;
        out.push(("adam", t0.elapsed().as_secs_f64() / reps as f64));
        Ok(out)
    }

    /// One Adam step with learning rate `lr` (zeroes the gradient), submitted.
    pub fn submit_adam(&mut self, gpu: &Gpu, lr: f32) {
        let s = &mut self.state;
        s.step += 1;
        let c1 = 1.0 - s.beta1.powi(s.step as i32);
        let c2 = 1.0 - s.beta2.powi(s.step as i32);
        let f = [
            s.beta1,
            s.beta2,
            s.eps,
            lr / c1,
            1.0 / c2.sqrt(),
            s.weight_decay,
        ];
        let u = [
            self.param_count as u32,
            s.decay.start as u32,
            s.decay.end as u32,
            s.sparse.start as u32,
            s.sparse.end as u32,
        ];
        let mut bytes = Vec::with_capacity(80);
        bytes.extend_from_slice(bytemuck::cast_slice(&f));
        bytes.extend_from_slice(bytemuck::cast_slice(&u));
        bytes.extend_from_slice(bytemuck::cast_slice(&self.code_layout));
        bytes.extend_from_slice(&s.table_decay.to_le_bytes());
        gpu.queue.write_buffer(&self.hyper, 0, &bytes);
        let groups = (self.param_count as u32).div_ceil(256);
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
            pass.set_pipeline(&self.adam);
            pass.set_bind_group(0, &self.adam_bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
            pass.set_pipeline(&self.refresh);
            let [_, _, _, out, .., images] = self.code_layout;
            pass.dispatch_workgroups(((images + 1) * out).div_ceil(64), 1, 1);
        }
        gpu.queue.submit([enc.finish()]);
    }

    /// The summed gradient (waits for the work submitted so far).
    pub fn read_grad(&self, gpu: &Gpu) -> Result<Vec<f32>, GpuError> {
        crate::read_f32(gpu, &self.grad, self.param_count)
    }
}

impl GpuField {
    /// The parameters as they are on the GPU (after training steps there).
    pub fn read_params(&self, gpu: &Gpu) -> Result<Vec<f32>, GpuError> {
        crate::read_f32(gpu, &self.params, self.param_count)
    }
}
