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
use crate::mlp::Linear;
use crate::sh::sh_encode;

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
    scratch_sizes: (usize, usize, usize),
}

/// Per-thread buffers of the backward pass: the thread's MLP gradient and work rows.
#[derive(Default)]
struct Scratch {
    g: Vec<f32>,
    da: Vec<f32>,
    db: Vec<f32>,
    xt: Vec<f32>,
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
    1.0 / (1.0 + (-x).exp())
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
    pub fn mlp_macs_per_sample(&self) -> usize {
        self.layout
            .density
            .iter()
            .chain(&self.layout.color)
            .map(|l| l.out * l.inp)
            .sum()
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

    /// Fills the colour-net input rows of one chunk: geometry feature, SH, appearance.
    #[inline(always)]
    fn color_input(&self, s: &Samples, c0: usize, dens: &[f32], cin: &mut [f32], avg: &[f32]) {
        let cfg = &self.config;
        let (geo, shw, a) = (cfg.geo_features, cfg.sh_width(), cfg.appearance_dim);
        cin[..geo * CHUNK].copy_from_slice(&dens[CHUNK..(1 + geo) * CHUNK]);
        let n = s.len();
        let mut sh = [0f32; 16];
        for l in 0..CHUNK {
            let i = c0 + l;
            if i < n {
                sh_encode(
                    cfg.sh_degree,
                    s.dir[0][i],
                    s.dir[1][i],
                    s.dir[2][i],
                    &mut sh,
                );
            } else {
                sh.fill(0.0);
            }
            for k in 0..shw {
                cin[(geo + k) * CHUNK + l] = sh[k];
            }
            if a > 0 {
                let img = if i < n {
                    s.image.get(i).copied().unwrap_or(u32::MAX)
                } else {
                    u32::MAX
                };
                let code: &[f32] = if (img as usize) < cfg.num_images {
                    let o = self.layout.appearance + img as usize * a;
                    &self.params[o..o + a]
                } else {
                    avg
                };
                for k in 0..a {
                    cin[(geo + shw + k) * CHUNK + l] = code[k];
                }
            }
        }
        let used = geo + shw + a;
        cin[used * CHUNK..].fill(0.0);
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
        avg: &[f32],
    ) {
        let lay = &self.layout;
        let p = &self.params;
        let (h, rest) = act.split_at_mut(rows.dens * CHUNK);
        lay.density[0].forward(p, enc, h, true);
        let (dens, rest) = rest.split_at_mut((rows.cin - rows.dens) * CHUNK);
        lay.density[1].forward(p, h, dens, false);
        let (cin, rest) = rest.split_at_mut((rows.color[0] - rows.cin) * CHUNK);
        self.color_input(s, c0, dens, cin, avg);
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
            l.forward(p, prev, out, li + 1 < nl);
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
            act[sig + l] = raw.min(MAX_RAW_DENSITY).exp();
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
        avg: &[f32],
        sig: &mut [f32],
        col: &mut [f32],
    ) {
        assist_simd::simd(|| {
            self.chunk_forward(s, c * CHUNK, enc, act, rows, avg);
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
    /// enough); records nothing for backward.
    pub fn forward_with(
        &self,
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
        let avg = self.average_code();
        let block = width * CHUNK;
        sigma[..n]
            .par_chunks_mut(CHUNK)
            .zip(rgb[..3 * n].par_chunks_mut(3 * CHUNK))
            .enumerate()
            .for_each_init(
                || vec![0.0f32; rows.total * CHUNK],
                |act, (c, (sig, col))| {
                    self.chunk_outputs(
                        s,
                        c,
                        &enc[c * block..(c + 1) * block],
                        act,
                        &rows,
                        &avg,
                        sig,
                        col,
                    )
                },
            );
    }

    /// Density only (for occupancy-grid updates): encoding and the density net.
    pub fn density(&self, pos: [&[f32]; 3], sigma: &mut [f32]) {
        let n = pos[0].len();
        let width = self.config.encoding_rows();
        let mut enc = vec![0.0f32; Layout { width }.len(n)];
        encode(&self.layout.grid, &self.params, pos, width, &mut enc);
        let block = width * CHUNK;
        let (d1, d2) = (self.layout.density[0], self.layout.density[1]);
        sigma[..n].par_chunks_mut(CHUNK).enumerate().for_each_init(
            || (vec![0.0f32; d1.out * CHUNK], vec![0.0f32; d2.out * CHUNK]),
            |(h, o), (c, sig)| {
                d1.forward(&self.params, &enc[c * block..(c + 1) * block], h, true);
                d2.forward(&self.params, h, o, false);
                for l in 0..sig.len() {
                    sig[l] = o[l].min(MAX_RAW_DENSITY).exp();
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
        let avg = self.average_code();
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
                    &avg,
                    sig,
                    col,
                )
            });
        tape.times.mlp_forward += t1.elapsed().as_secs_f64();
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
        let max_in = lay
            .density
            .iter()
            .chain(&lay.color)
            .map(|l| l.inp_pad)
            .max()
            .unwrap_or(0);
        let max_rows = rows.total;
        let enc = &tape.enc;
        let act = &tape.act;
        let (geo, shw, a) = (cfg.geo_features, cfg.sh_width(), cfg.appearance_dim);
        // One scratch set per worker thread, kept in the tape across steps (no allocation
        // in the hot loop); each holds that thread's share of the MLP gradient.
        let threads = rayon::current_num_threads().max(1);
        let sizes = (mlp_len, max_rows * CHUNK, CHUNK * max_in);
        if tape.scratch.len() != threads || tape.scratch_sizes != sizes {
            tape.scratch = (0..threads)
                .map(|_| {
                    std::sync::Mutex::new(Scratch {
                        g: vec![0.0; sizes.0],
                        da: vec![0.0; sizes.1],
                        db: vec![0.0; sizes.1],
                        xt: vec![0.0; sizes.2],
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
                let Scratch { g, da, db, xt } = &mut *guard;
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
                    for li in (0..nl).rev() {
                        let l = &lay.color[li];
                        let (x, relu_in) = if li == 0 {
                            (row(rows.cin, l.inp_pad), false)
                        } else {
                            (row(rows.color[li - 1], l.inp_pad), true)
                        };
                        l.backward(
                            &wts[2 + li],
                            x,
                            &da[..l.out * CHUNK],
                            g,
                            mlp0,
                            Some(&mut db[..l.inp_pad * CHUNK]),
                            xt,
                        );
                        if relu_in {
                            relu_mask(&mut db[..l.inp_pad * CHUNK], x);
                        }
                        std::mem::swap(&mut da, &mut db);
                    }
                    // `da` = dL/d(colour input). Appearance codes.
                    if a > 0 {
                        let per_image = cfg.num_images;
                        let images = s.image.get(c0..c0 + lanes).unwrap_or(&[]);
                        let rows = &da[(geo + shw) * CHUNK..(geo + shw + a) * CHUNK];
                        let single = images.len() == lanes
                            && images.iter().all(|&i| i == images[0])
                            && (images[0] as usize) < per_image;
                        if single {
                            // One image for the whole chunk: row sums.
                            let o = lay.appearance - mlp0 + images[0] as usize * a;
                            for k in 0..a {
                                g[o + k] += rows[k * CHUNK..k * CHUNK + lanes].iter().sum::<f32>();
                            }
                        } else {
                            for l in 0..lanes {
                                let img = images.get(l).copied().unwrap_or(u32::MAX);
                                if (img as usize) < per_image {
                                    let o = lay.appearance - mlp0 + img as usize * a;
                                    for k in 0..a {
                                        g[o + k] += rows[k * CHUNK + l];
                                    }
                                } else {
                                    for i in 0..per_image {
                                        let o = lay.appearance - mlp0 + i * a;
                                        for k in 0..a {
                                            g[o + k] += rows[k * CHUNK + l] / per_image as f32;
                                        }
                                    }
                                }
                            }
                        }
                    }
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
                    );
                });
            });
        for sc in scratch {
            let mut sc = sc.lock().unwrap_or_else(|p| p.into_inner());
            for (g, m) in grad[mlp0..].iter_mut().zip(sc.g.iter_mut()) {
                *g += *m;
                *m = 0.0;
            }
        }
        let t1 = std::time::Instant::now();
        tape.times.mlp_backward += (t1 - t0).as_secs_f64();
        encode_backward(&lay.grid, s.pos, width, &tape.d_enc, &mut grad[..mlp0]);
        tape.times.encode_backward += t1.elapsed().as_secs_f64();
    }
}
