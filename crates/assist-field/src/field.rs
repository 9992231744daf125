//! The radiance field of one scene node: hash-grid encoding → density net (one hidden
//! layer; output = raw density + geometry feature) → colour net (geometry feature +
//! spherical harmonics of the view direction + optional per-image appearance code →
//! hidden layers → RGB, sigmoid). Density is `trunc_exp` of the raw output.
//!
//! All parameters live in one flat `Vec<f32>` (named ranges in [`ParamLayout`]) so that
//! Adam and serialisation are single passes. Forward for inference keeps nothing; forward
//! for training records a [`Tape`] that backward consumes.

use rayon::prelude::*;

use crate::config::FieldConfig;
use crate::hashgrid::{CHUNK, GridLayout, Layout, encode, encode_backward};
use assist_simd::bf16::{self, PackedA};

use crate::mlp::{Linear, bias_act};
use crate::sh::sh_encode_rows;

/// Arithmetic of the MLP products at inference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// f32 throughout: what training computes.
    F32,
    /// bf16 weights and activations in the products, f32 sums (AVX-512 BF16 only; f32
    /// elsewhere). About 3 significant digits per product operand; for rendering.
    Bf16,
}

impl Precision {
    /// The fastest precision this machine runs (`ASSIST_PRECISION=f32` forces f32).
    pub fn fastest() -> Self {
        if bf16::available() {
            Precision::Bf16
        } else {
            Precision::F32
        }
    }
}

/// Largest raw density fed to `exp` (σ ≤ e^15); the gradient uses the same clamp
/// (`trunc_exp` as in Nerfacto).
pub const MAX_RAW_DENSITY: f32 = 15.0;

/// Where each parameter group lives in the flat vector.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamLayout {
    pub grid: GridLayout,
    pub density: [Linear; 2],
    pub color: Vec<Linear>,
    /// Offset of the appearance table (`num_images × appearance_dim`).
    pub appearance: usize,
    pub total: usize,
}

impl ParamLayout {
    pub fn new(cfg: &FieldConfig) -> Self {
        let grid = GridLayout::new(cfg);
        let mut off = grid.param_count();
        let enc = cfg.encoding_width();
        let d1 = Linear::new(cfg.hidden, enc, &mut off);
        let d2 = Linear::new(1 + cfg.geo_features, cfg.hidden, &mut off);
        let cin = cfg.geo_features + cfg.sh_width() + cfg.appearance_dim;
        let mut color = vec![Linear::new(cfg.color_hidden, cin, &mut off)];
        for _ in 1..cfg.color_layers {
            color.push(Linear::new(cfg.color_hidden, cfg.color_hidden, &mut off));
        }
        color.push(Linear::new(3, cfg.color_hidden, &mut off));
        let appearance = off;
        off += cfg.num_images * cfg.appearance_dim;
        ParamLayout {
            grid,
            density: [d1, d2],
            color,
            appearance,
            total: off,
        }
    }

    /// Named groups `(name, start, len)`, for serialisation and gradient checks.
    pub fn groups(&self, cfg: &FieldConfig) -> Vec<(String, usize, usize)> {
        let mut g = Vec::new();
        for (i, lv) in self.grid.levels.iter().enumerate() {
            g.push((
                format!("grid.level{i:02}"),
                lv.offset * self.grid.features,
                lv.size as usize * self.grid.features,
            ));
        }
        for (i, l) in self.density.iter().enumerate() {
            g.push((format!("density.{i}.weight"), l.w, l.out * l.inp_pad));
            g.push((format!("density.{i}.bias"), l.b, l.out));
        }
        for (i, l) in self.color.iter().enumerate() {
            g.push((format!("color.{i}.weight"), l.w, l.out * l.inp_pad));
            g.push((format!("color.{i}.bias"), l.b, l.out));
        }
        if cfg.appearance_dim > 0 {
            g.push((
                "appearance".into(),
                self.appearance,
                cfg.num_images * cfg.appearance_dim,
            ));
        }
        g
    }

    /// Start of the MLP + appearance parameters (everything after the grid).
    pub fn mlp_start(&self) -> usize {
        self.grid.param_count()
    }
}

/// Per-sample inputs, structure of arrays. Positions are in the node's canonical box
/// scaled to [0, 1]³; directions are unit vectors in the same frame. `image[i]` selects an
/// appearance code; `u32::MAX` (or an empty slice) means the average code (novel views).
#[derive(Clone, Copy)]
pub struct Samples<'a> {
    pub pos: [&'a [f32]; 3],
    pub dir: [&'a [f32]; 3],
    pub image: &'a [u32],
}

impl Samples<'_> {
    pub fn len(&self) -> usize {
        self.pos[0].len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Activations recorded by `forward_train` for `backward`. Reused across steps: buffers
/// grow to the largest batch and are not reallocated after that.
#[derive(Default)]
pub struct Tape {
    n: usize,
    enc: Vec<f32>,
    d_enc: Vec<f32>,
    act: Vec<f32>,
    /// Time spent in each phase by the calls on this tape (accumulated; reset at will).
    pub times: PhaseTimes,
    scratch: Vec<std::sync::Mutex<Scratch>>,
    scratch_sizes: (usize, usize, usize, usize),
}

/// Per-thread buffers of the backward pass: the thread's MLP gradient and work rows.
#[derive(Default)]
struct Scratch {
    g: Vec<f32>,
    da: Vec<f32>,
    db: Vec<f32>,
    xt: Vec<f32>,
    /// Σ dL/d(first colour layer pre-activation) per appearance code (`code_biases` rows).
    code_sums: Vec<f32>,
}

/// Seconds spent per phase, for benchmarks.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct PhaseTimes {
    pub encode_forward: f64,
    pub mlp_forward: f64,
    pub mlp_backward: f64,
    pub encode_backward: f64,
}

/// Row offsets (in units of CHUNK floats) of one chunk's activations.
#[derive(Debug, Clone)]
struct Rows {
    hidden: usize,
    dens: usize,
    cin: usize,
    color: Vec<usize>,
    rgb: usize,
    sigma: usize,
    total: usize,
}

impl Rows {
    fn new(cfg: &FieldConfig, lay: &ParamLayout) -> Self {
        let mut r = 0;
        let mut take = |n: usize| {
            let o = r;
            r += n;
            o
        };
        let hidden = take(cfg.hidden);
        let dens = take(1 + cfg.geo_features);
        let cin = take(lay.color[0].inp_pad);
        let color: Vec<usize> = (0..cfg.color_layers)
            .map(|_| take(cfg.color_hidden))
            .collect();
        let rgb = take(3);
        let sigma = take(1);
        Rows {
            hidden,
            dens,
            cin,
            color,
            rgb,
            sigma,
            total: r,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Field {
    pub config: FieldConfig,
    pub layout: ParamLayout,
    pub params: Vec<f32>,
}

/// Copies one chunk's σ and RGB rows into the interleaved outputs.
#[inline(always)]
fn write_outputs(act: &[f32], rows: &Rows, sig: &mut [f32], col: &mut [f32]) {
    let lanes = sig.len();
    sig.copy_from_slice(&act[rows.sigma * CHUNK..rows.sigma * CHUNK + lanes]);
    for l in 0..lanes {
        for k in 0..3 {
            col[3 * l + k] = act[(rows.rgb + k) * CHUNK + l];
        }
    }
}

/// `d ← d · [x > 0]` (ReLU backward), branch-free so that it vectorises.
#[inline(always)]
fn relu_mask(d: &mut [f32], x: &[f32]) {
    for (d, v) in d.iter_mut().zip(x) {
        *d = if *v > 0.0 { *d } else { 0.0 };
    }
}

#[inline(always)]
fn sigmoid(x: f32) -> f32 {
    assist_simd::math::sigmoid(x)
}

impl Field {
    /// A field with freshly initialised parameters (deterministic for a seed): table
    /// entries uniform in ±1e-4, weights He-uniform, biases zero, appearance codes ±0.1.
    pub fn new(config: FieldConfig, seed: u64) -> Result<Self, crate::FieldError> {
        config.validate()?;
        let layout = ParamLayout::new(&config);
        let mut params = vec![0.0f32; layout.total];
        let mut rng = assist_core::Rng::new(seed);
        for p in &mut params[..layout.grid.param_count()] {
            *p = (rng.f32() * 2.0 - 1.0) * 1e-4;
        }
        for l in layout.density.iter().chain(&layout.color) {
            let bound = (6.0 / l.inp as f32).sqrt();
            for o in 0..l.out {
                for i in 0..l.inp {
                    params[l.w + o * l.inp_pad + i] = (rng.f32() * 2.0 - 1.0) * bound;
                }
            }
        }
        for p in &mut params[layout.appearance..] {
            *p = (rng.f32() * 2.0 - 1.0) * 0.1;
        }
        Ok(Field {
            config,
            layout,
            params,
        })
    }

    pub fn param_count(&self) -> usize {
        self.layout.total
    }

    /// Multiply-adds of the MLPs per sample (forward), for GFLOP/s figures.
    /// Multiply-adds of the forward MLP products per sample (the first colour layer
    /// without its appearance columns, which act as a per-image bias).
    pub fn mlp_macs_per_sample(&self) -> usize {
        let c0 = &self.layout.color[0];
        self.layout
            .density
            .iter()
            .chain(&self.layout.color[1..])
            .map(|l| l.out * l.inp)
            .sum::<usize>()
            + c0.out * self.code_col()
    }

    fn average_code(&self) -> Vec<f32> {
        let a = self.config.appearance_dim;
        let mut avg = vec![0.0f32; a];
        if a == 0 || self.config.num_images == 0 {
            return avg;
        }
        for i in 0..self.config.num_images {
            for k in 0..a {
                avg[k] += self.params[self.layout.appearance + i * a + k];
            }
        }
        avg.iter_mut()
            .for_each(|v| *v /= self.config.num_images as f32);
        avg
    }

    /// Fills the colour-net input rows of one chunk that go through the product: geometry
    /// feature and SH. (The appearance code enters as a per-code bias; see `code_biases`.)
    #[inline(always)]
    fn color_input(&self, s: &Samples, c0: usize, dens: &[f32], cin: &mut [f32]) {
        let cfg = &self.config;
        let (geo, shw) = (cfg.geo_features, cfg.sh_width());
        cin[..geo * CHUNK].copy_from_slice(&dens[CHUNK..(1 + geo) * CHUNK]);
        let lanes = CHUNK.min(s.len() - c0);
        let d = |a: usize| &s.dir[a][c0..c0 + lanes];
        sh_encode_rows(
            cfg.sh_degree,
            d(0),
            d(1),
            d(2),
            &mut cin[geo * CHUNK..],
            CHUNK,
        );
        if lanes < CHUNK {
            for k in 0..shw {
                cin[(geo + k) * CHUNK + lanes..(geo + k + 1) * CHUNK].fill(0.0);
            }
        }
        // Rows up to the product's padded width are zero (their columns are appearance
        // weights, which act through the bias).
        cin[(geo + shw) * CHUNK..self.product_cols() * CHUNK].fill(0.0);
    }

    /// Inputs of the first colour layer that go through the product: geometry + SH,
    /// padded to 16 for the kernels with zero rows (see `color_input`).
    fn product_cols(&self) -> usize {
        let real = self.config.geo_features + self.config.sh_width();
        crate::mlp::pad16(real).min(self.layout.color[0].inp_pad)
    }

    /// First column of the appearance code in the first colour layer's weights.
    fn code_col(&self) -> usize {
        self.config.geo_features + self.config.sh_width()
    }

    /// The first colour layer's bias for every appearance code, `out` floats each:
    /// `b + W_app · code` for each image, then the average code (novel views) last. The
    /// code is constant over the samples of an image, so its part of the product is folded
    /// into the bias once per call instead of being multiplied per sample.
    fn code_biases(&self) -> Vec<f32> {
        let l = &self.layout.color[0];
        let (a, k0) = (self.config.appearance_dim, self.code_col());
        let b = &self.params[l.b..l.b + l.out];
        if a == 0 {
            return b.to_vec();
        }
        let avg = self.average_code();
        let mut out = Vec::with_capacity((self.config.num_images + 1) * l.out);
        for i in 0..=self.config.num_images {
            let code = if i < self.config.num_images {
                let o = self.layout.appearance + i * a;
                &self.params[o..o + a]
            } else {
                &avg[..]
            };
            for o in 0..l.out {
                let w = &self.params[l.w + o * l.inp_pad + k0..l.w + o * l.inp_pad + k0 + a];
                out.push(b[o] + w.iter().zip(code).map(|(w, c)| w * c).sum::<f32>());
            }
        }
        out
    }

    /// Which row of `code_biases` sample `i` uses.
    #[inline(always)]
    fn code_slot(&self, s: &Samples, i: usize) -> usize {
        let cfg = &self.config;
        if cfg.appearance_dim == 0 {
            return 0;
        }
        let img = s.image.get(i).copied().unwrap_or(u32::MAX) as usize;
        img.min(cfg.num_images)
    }

    /// Slots of the lanes of the chunk at `c0` (lanes past the end repeat the first), and
    /// whether they are all the same.
    #[inline(always)]
    fn chunk_slots(&self, s: &Samples, c0: usize, slots: &mut [u32; CHUNK]) -> bool {
        let lanes = CHUNK.min(s.len() - c0);
        let first = self.code_slot(s, c0);
        let mut same = true;
        for l in 0..CHUNK {
            let v = if l < lanes {
                self.code_slot(s, c0 + l)
            } else {
                first
            };
            same &= v == first;
            slots[l] = v as u32;
        }
        same
    }

    /// Runs the MLPs of one chunk, writing activations into `act` (one chunk's rows).
    #[inline(always)]
    fn chunk_forward(
        &self,
        s: &Samples,
        c0: usize,
        enc: &[f32],
        act: &mut [f32],
        rows: &Rows,
        biases: &[f32],
        fast: Option<(&[PackedA], &mut [u32])>,
    ) {
        let lay = &self.layout;
        let p = &self.params;
        // Product `y = W[:, ..cols] x` of layer `i` (density 0, 1, then colour layers), in
        // f32 or through the bf16 kernel (activations packed into `bp` first).
        let simd = assist_simd::level();
        let mut fast = fast;
        let mut product =
            |i: usize, l: &Linear, x: &[f32], y: &mut [f32], cols: usize| match fast.as_mut() {
                Some((packed, bp)) => {
                    bf16::pack_b(simd, x, cols, CHUNK, CHUNK, bp);
                    bf16::gemm(simd, &packed[i], bp, CHUNK, y, CHUNK);
                }
                None => l.product(p, x, y, cols),
            };
        let (h, rest) = act.split_at_mut(rows.dens * CHUNK);
        let (d0, d1) = (&lay.density[0], &lay.density[1]);
        product(0, d0, enc, h, d0.inp_pad);
        bias_act(&mut h[..d0.out * CHUNK], &p[d0.b..d0.b + d0.out], true);
        let (dens, rest) = rest.split_at_mut((rows.cin - rows.dens) * CHUNK);
        product(1, d1, h, dens, d1.inp_pad);
        bias_act(&mut dens[..d1.out * CHUNK], &p[d1.b..d1.b + d1.out], false);
        let (cin, rest) = rest.split_at_mut((rows.color[0] - rows.cin) * CHUNK);
        self.color_input(s, c0, dens, cin);
        // Colour layers: cin → hidden… → rgb (pre-activation into the rgb rows).
        let nl = lay.color.len();
        let mut prev: &[f32] = cin;
        let mut rest = rest;
        for (li, l) in lay.color.iter().enumerate() {
            let width = if li + 1 < nl {
                rows.color.get(li + 1).copied().unwrap_or(rows.rgb) - rows.color[li]
            } else {
                rows.sigma - rows.rgb
            };
            let (out, r2) = rest.split_at_mut(width * CHUNK);
            if li == 0 {
                // Geometry + SH through the product; the appearance code as a bias.
                product(2, l, prev, out, self.product_cols());
                let mut slots = [0u32; CHUNK];
                let out = &mut out[..l.out * CHUNK];
                if self.chunk_slots(s, c0, &mut slots) {
                    let b = slots[0] as usize * l.out;
                    bias_act(out, &biases[b..b + l.out], nl > 1);
                } else {
                    for (o, row) in out.chunks_exact_mut(CHUNK).enumerate() {
                        for (v, &sl) in row.iter_mut().zip(&slots) {
                            *v += biases[sl as usize * l.out + o];
                        }
                    }
                    if nl > 1 {
                        out.iter_mut().for_each(|v| *v = v.max(0.0));
                    }
                }
            } else {
                product(2 + li, l, prev, out, l.inp_pad);
                bias_act(&mut out[..l.out * CHUNK], &p[l.b..l.b + l.out], li + 1 < nl);
            }
            prev = out;
            rest = r2;
        }
        // `prev` is the rgb rows; `rest` begins with the sigma row.
        let rgb_start = rows.rgb * CHUNK;
        for v in &mut act[rgb_start..rgb_start + 3 * CHUNK] {
            *v = sigmoid(*v);
        }
        let sig = rows.sigma * CHUNK;
        for l in 0..CHUNK {
            let raw = act[rows.dens * CHUNK + l];
            act[sig + l] = assist_simd::math::exp(raw.min(MAX_RAW_DENSITY));
        }
    }

    /// Chunk `c`: its MLPs (SIMD-dispatched) and its σ and RGB copied to the outputs.
    fn chunk_outputs(
        &self,
        s: &Samples,
        c: usize,
        enc: &[f32],
        act: &mut [f32],
        rows: &Rows,
        biases: &[f32],
        fast: Option<(&[PackedA], &mut [u32])>,
        sig: &mut [f32],
        col: &mut [f32],
    ) {
        assist_simd::simd(|| {
            self.chunk_forward(s, c * CHUNK, enc, act, rows, biases, fast);
            write_outputs(act, rows, sig, col);
        })
    }

    fn rows(&self) -> Rows {
        Rows::new(&self.config, &self.layout)
    }

    /// Inference: density and colour (`rgb` interleaved, 3 per sample); keeps nothing.
    pub fn forward(&self, s: &Samples, sigma: &mut [f32], rgb: &mut [f32]) {
        self.forward_with(s, &mut Tape::default(), sigma, rgb)
    }

    /// Inference reusing `scratch`'s encoding buffer (no allocation once it is large
    /// enough); records nothing for backward. Exact f32 (see `forward_at`).
    pub fn forward_with(
        &self,
        s: &Samples,
        scratch: &mut Tape,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) {
        self.forward_at(Precision::F32, s, scratch, sigma, rgb)
    }

    /// The MLP weights packed for the bf16 kernel, in product order: density 0 and 1,
    /// then the colour layers (the first without its appearance columns).
    fn packed_bf16(&self) -> Vec<PackedA> {
        let lay = &self.layout;
        let p = &self.params;
        let pack = |l: &Linear, cols: usize| PackedA::new(&p[l.w..], l.out, cols, l.inp_pad);
        let mut v = vec![
            pack(&lay.density[0], lay.density[0].inp_pad),
            pack(&lay.density[1], lay.density[1].inp_pad),
            pack(&lay.color[0], self.product_cols()),
        ];
        v.extend(lay.color[1..].iter().map(|l| pack(l, l.inp_pad)));
        v
    }

    /// Inference at a given precision of the MLP products (the encoding, biases and
    /// activations are f32 either way). `Precision::Bf16` falls back to f32 where the CPU
    /// lacks AVX-512 BF16.
    pub fn forward_at(
        &self,
        precision: Precision,
        s: &Samples,
        scratch: &mut Tape,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) {
        let n = s.len();
        assert!(sigma.len() >= n && rgb.len() >= 3 * n);
        let width = self.config.encoding_rows();
        let need = Layout { width }.len(n);
        if scratch.enc.len() < need {
            scratch.enc.resize(need, 0.0);
        }
        scratch.n = 0;
        let enc = &mut scratch.enc[..need];
        self.encode(s, enc);
        let rows = self.rows();
        let biases = self.code_biases();
        let packed =
            (precision == Precision::Bf16 && bf16::available()).then(|| self.packed_bf16());
        let max_in = self.max_inputs();
        let block = width * CHUNK;
        sigma[..n]
            .par_chunks_mut(CHUNK)
            .zip(rgb[..3 * n].par_chunks_mut(3 * CHUNK))
            .enumerate()
            .for_each_init(
                || {
                    let bp = if packed.is_some() {
                        max_in.div_ceil(2) * CHUNK
                    } else {
                        0
                    };
                    (vec![0.0f32; rows.total * CHUNK], vec![0u32; bp])
                },
                |(act, bp), (c, (sig, col))| {
                    self.chunk_outputs(
                        s,
                        c,
                        &enc[c * block..(c + 1) * block],
                        act,
                        &rows,
                        &biases,
                        packed.as_deref().map(|p| (p, bp.as_mut_slice())),
                        sig,
                        col,
                    )
                },
            );
    }

    /// The widest layer input (padded).
    fn max_inputs(&self) -> usize {
        let lay = &self.layout;
        lay.density
            .iter()
            .chain(&lay.color)
            .map(|l| l.inp_pad)
            .max()
            .unwrap_or(0)
    }

    /// Density only (for occupancy-grid updates): encoding and the density net.
    pub fn density(&self, pos: [&[f32]; 3], sigma: &mut [f32]) {
        self.density_with(pos, sigma, &mut Vec::new());
    }

    /// [`density`](Self::density) with the encoding buffer `scratch` kept by the caller
    /// (grown as needed), so repeated calls do not allocate and fault in a fresh one.
    pub fn density_with(&self, pos: [&[f32]; 3], sigma: &mut [f32], scratch: &mut Vec<f32>) {
        let n = pos[0].len();
        let width = self.config.encoding_rows();
        let len = Layout { width }.len(n);
        if scratch.len() < len {
            scratch.resize(len, 0.0);
        }
        let enc = &mut scratch[..len];
        let block = width * CHUNK;
        // Lanes past the end of the last chunk are zeroed so they stay finite.
        if !n.is_multiple_of(CHUNK) {
            enc[len - block..].fill(0.0);
        }
        encode(&self.layout.grid, &self.params, pos, width, enc);
        let (d1, d2) = (self.layout.density[0], self.layout.density[1]);
        sigma[..n].par_chunks_mut(CHUNK).enumerate().for_each_init(
            || (vec![0.0f32; d1.out * CHUNK], vec![0.0f32; d2.out * CHUNK]),
            |(h, o), (c, sig)| {
                d1.forward(&self.params, &enc[c * block..(c + 1) * block], h, true);
                d2.forward(&self.params, h, o, false);
                for l in 0..sig.len() {
                    sig[l] = assist_simd::math::exp(o[l].min(MAX_RAW_DENSITY));
                }
            },
        );
    }

    fn encode(&self, s: &Samples, enc: &mut [f32]) {
        encode(
            &self.layout.grid,
            &self.params,
            s.pos,
            self.config.encoding_rows(),
            enc,
        );
    }

    /// Training forward: like `forward`, recording activations in `tape`.
    pub fn forward_train(&self, s: &Samples, tape: &mut Tape, sigma: &mut [f32], rgb: &mut [f32]) {
        let n = s.len();
        assert!(sigma.len() >= n && rgb.len() >= 3 * n);
        let width = self.config.encoding_rows();
        let rows = self.rows();
        let nc = n.div_ceil(CHUNK);
        let enc_len = Layout { width }.len(n);
        if tape.enc.len() < enc_len {
            tape.enc.resize(enc_len, 0.0);
            tape.d_enc.resize(enc_len, 0.0);
        }
        if tape.act.len() < nc * rows.total * CHUNK {
            tape.act.resize(nc * rows.total * CHUNK, 0.0);
        }
        tape.n = n;
        // Lanes past the end of the last chunk are zeroed so they stay finite.
        if !n.is_multiple_of(CHUNK) {
            let last = &mut tape.enc[(nc - 1) * width * CHUNK..nc * width * CHUNK];
            last.fill(0.0);
        }
        let t0 = std::time::Instant::now();
        encode(&self.layout.grid, &self.params, s.pos, width, &mut tape.enc);
        let t1 = std::time::Instant::now();
        tape.times.encode_forward += (t1 - t0).as_secs_f64();
        let biases = self.code_biases();
        let block = width * CHUNK;
        let enc = &tape.enc;
        tape.act[..nc * rows.total * CHUNK]
            .par_chunks_mut(rows.total * CHUNK)
            .zip(sigma[..n].par_chunks_mut(CHUNK))
            .zip(rgb[..3 * n].par_chunks_mut(3 * CHUNK))
            .enumerate()
            .for_each(|(c, ((act, sig), col))| {
                self.chunk_outputs(
                    s,
                    c,
                    &enc[c * block..(c + 1) * block],
                    act,
                    &rows,
                    &biases,
                    None,
                    sig,
                    col,
                )
            });
        tape.times.mlp_forward += t1.elapsed().as_secs_f64();
    }

    /// The appearance part of the first colour layer, from `sums` (per code, Σ of dL/dy
    /// over its samples): `dW_app += s codeᵀ` and `d code += W_appᵀ s`; the average code
    /// spreads its gradient evenly over every image's code.
    fn code_backward(&self, sums: &[f32], grad: &mut [f32]) {
        let (cfg, l) = (&self.config, &self.layout.color[0]);
        let (a, k0, ni) = (cfg.appearance_dim, self.code_col(), cfg.num_images);
        let avg = self.average_code();
        for (slot, sm) in sums.chunks_exact(l.out).enumerate() {
            if sm.iter().all(|&v| v == 0.0) {
                continue;
            }
            let code_at = |k: usize| {
                if slot < ni {
                    self.params[self.layout.appearance + slot * a + k]
                } else {
                    avg[k]
                }
            };
            let mut dcode = vec![0.0f32; a];
            for (o, &so) in sm.iter().enumerate() {
                let w0 = l.w + o * l.inp_pad + k0;
                for k in 0..a {
                    grad[w0 + k] += so * code_at(k);
                    dcode[k] += self.params[w0 + k] * so;
                }
            }
            if slot < ni {
                let o = self.layout.appearance + slot * a;
                grad[o..o + a]
                    .iter_mut()
                    .zip(&dcode)
                    .for_each(|(g, d)| *g += d);
            } else {
                for i in 0..ni {
                    let o = self.layout.appearance + i * a;
                    grad[o..o + a]
                        .iter_mut()
                        .zip(&dcode)
                        .for_each(|(g, d)| *g += d / ni as f32);
                }
            }
        }
    }

    /// Backward: given dL/dσ and dL/drgb (interleaved) for the samples of the last
    /// `forward_train`, accumulates dL/dθ into `grad` (same layout as `params`).
    pub fn backward(
        &self,
        s: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
        grad: &mut [f32],
    ) {
        let n = tape.n;
        assert_eq!(
            s.len(),
            n,
            "backward: samples differ from the recorded forward"
        );
        assert!(grad.len() == self.layout.total);
        let cfg = &self.config;
        let lay = &self.layout;
        let rows = self.rows();
        let width = cfg.encoding_rows();
        let block = width * CHUNK;
        let nc = n.div_ceil(CHUNK);
        let mlp0 = lay.mlp_start();
        let mlp_len = lay.total - mlp0;
        let t0 = std::time::Instant::now();
        let wts: Vec<Vec<f32>> = lay
            .density
            .iter()
            .chain(&lay.color)
            .map(|l| l.transposed(&self.params))
            .collect();
        let max_in = self.max_inputs();
        let max_rows = rows.total;
        let enc = &tape.enc;
        let act = &tape.act;
        let (geo, a) = (cfg.geo_features, cfg.appearance_dim);
        // One scratch set per worker thread, kept in the tape across steps (no allocation
        // in the hot loop); each holds that thread's share of the MLP gradient.
        let threads = rayon::current_num_threads().max(1);
        let k0 = self.product_cols();
        let code_rows = if a > 0 { cfg.num_images + 1 } else { 0 };
        let sizes = (
            mlp_len,
            max_rows * CHUNK,
            CHUNK * max_in,
            code_rows * lay.color[0].out,
        );
        if tape.scratch.len() != threads || tape.scratch_sizes != sizes {
            tape.scratch = (0..threads)
                .map(|_| {
                    std::sync::Mutex::new(Scratch {
                        g: vec![0.0; sizes.0],
                        da: vec![0.0; sizes.1],
                        db: vec![0.0; sizes.1],
                        xt: vec![0.0; sizes.2],
                        code_sums: vec![0.0; sizes.3],
                    })
                })
                .collect();
            tape.scratch_sizes = sizes;
        }
        let scratch = &tape.scratch;
        tape.d_enc[..nc * block]
            .par_chunks_mut(block)
            .enumerate()
            .for_each(|(c, d_enc)| {
                let slot = rayon::current_thread_index().unwrap_or(0) % scratch.len();
                let mut guard = scratch[slot].lock().unwrap_or_else(|p| p.into_inner());
                let Scratch {
                    g,
                    da,
                    db,
                    xt,
                    code_sums,
                } = &mut *guard;
                let (g, mut da, mut db, xt) = (
                    g.as_mut_slice(),
                    da.as_mut_slice(),
                    db.as_mut_slice(),
                    xt.as_mut_slice(),
                );
                assist_simd::simd(|| {
                    let act = &act[c * rows.total * CHUNK..(c + 1) * rows.total * CHUNK];
                    let row = |r: usize, k: usize| &act[r * CHUNK..(r + k) * CHUNK];
                    let c0 = c * CHUNK;
                    let lanes = CHUNK.min(n - c0);
                    // dL/d(rgb pre-activation) into `da` (3 rows).
                    da[..3 * CHUNK].fill(0.0);
                    for l in 0..lanes {
                        for k in 0..3 {
                            let y = act[(rows.rgb + k) * CHUNK + l];
                            da[k * CHUNK + l] = d_rgb[3 * (c0 + l) + k] * y * (1.0 - y);
                        }
                    }
                    // Colour layers, last to first; `da` holds dL/d(pre-activation).
                    let nl = lay.color.len();
                    for li in (1..nl).rev() {
                        let l = &lay.color[li];
                        let x = row(rows.color[li - 1], l.inp_pad);
                        l.backward(
                            &wts[2 + li],
                            x,
                            &da[..l.out * CHUNK],
                            g,
                            mlp0,
                            Some(&mut db[..l.inp_pad * CHUNK]),
                            xt,
                            l.inp_pad,
                        );
                        relu_mask(&mut db[..l.inp_pad * CHUNK], x);
                        std::mem::swap(&mut da, &mut db);
                    }
                    // First colour layer: the product's columns (geometry + SH), dx for the
                    // geometry rows only (SH has no parameters), and the appearance part
                    // summed per code: Σ dy over a code's lanes gives both its weight
                    // gradient and its code gradient (after the loop over chunks).
                    let l0 = &lay.color[0];
                    l0.backward(
                        &wts[2],
                        row(rows.cin, l0.inp_pad),
                        &da[..l0.out * CHUNK],
                        g,
                        mlp0,
                        // (16 rows rather than the 15 geometry ones: the fast kernel.)
                        Some(&mut db[..crate::mlp::pad16(geo).min(l0.inp_pad) * CHUNK]),
                        xt,
                        k0,
                    );
                    if a > 0 {
                        let mut slots = [0u32; CHUNK];
                        let dy = &da[..l0.out * CHUNK];
                        if self.chunk_slots(s, c0, &mut slots) {
                            let sum = &mut code_sums[slots[0] as usize * l0.out..][..l0.out];
                            for (o, r) in dy.chunks_exact(CHUNK).enumerate() {
                                sum[o] += r[..lanes].iter().sum::<f32>();
                            }
                        } else {
                            for (o, r) in dy.chunks_exact(CHUNK).enumerate() {
                                for (&v, &sl) in r[..lanes].iter().zip(&slots) {
                                    code_sums[sl as usize * l0.out + o] += v;
                                }
                            }
                        }
                    }
                    std::mem::swap(&mut da, &mut db);
                    // dL/d(density net output) into `db`: row 0 from σ, rows 1.. from geo.
                    let d2 = &lay.density[1];
                    db[..d2.out * CHUNK].fill(0.0);
                    for l in 0..lanes {
                        let sig = act[rows.sigma * CHUNK + l];
                        db[l] = d_sigma[c0 + l] * sig;
                    }
                    db[CHUNK..(1 + geo) * CHUNK].copy_from_slice(&da[..geo * CHUNK]);
                    let hid = row(rows.hidden, d2.inp_pad);
                    d2.backward(
                        &wts[1],
                        hid,
                        &db[..d2.out * CHUNK],
                        g,
                        mlp0,
                        Some(&mut da[..d2.inp_pad * CHUNK]),
                        xt,
                        d2.inp_pad,
                    );
                    relu_mask(&mut da[..d2.inp_pad * CHUNK], hid);
                    let d1 = &lay.density[0];
                    d1.backward(
                        &wts[0],
                        &enc[c * block..(c + 1) * block],
                        &da[..d1.out * CHUNK],
                        g,
                        mlp0,
                        Some(d_enc),
                        xt,
                        d1.inp_pad,
                    );
                });
            });
        let mut sums = vec![0.0f32; sizes.3];
        for sc in scratch {
            let mut sc = sc.lock().unwrap_or_else(|p| p.into_inner());
            for (g, m) in grad[mlp0..].iter_mut().zip(sc.g.iter_mut()) {
                *g += *m;
                *m = 0.0;
            }
            for (t, m) in sums.iter_mut().zip(sc.code_sums.iter_mut()) {
                *t += *m;
                *m = 0.0;
            }
        }
        if a > 0 {
            self.code_backward(&sums, grad);
        }
        let t1 = std::time::Instant::now();
        tape.times.mlp_backward += (t1 - t0).as_secs_f64();
        encode_backward(&lay.grid, s.pos, width, &tape.d_enc, &mut grad[..mlp0]);
        tape.times.encode_backward += t1.elapsed().as_secs_f64();
    }
}
