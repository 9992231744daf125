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
use crate::hashgrid::{CHUNK, Layout, encode};
use assist_simd::bf16::{self, PackedA};
use assist_simd::fixed16::{self, QuantA};

use crate::mlp::{Linear, bias_act};

mod appearance;
mod backward;
mod layout;
mod reflect;

use crate::sh::sh_encode_rows;
pub use backward::Tape;
mod packed;
mod two_pass;
pub use layout::ParamLayout;
use layout::Rows;
pub use packed::PackedTables;

/// Asks for every cache line of `s` ahead of its use: a chunk's record, which the forward
/// pass left in memory, read while the chunk before it is computed.
#[inline(always)]
pub(crate) fn prefetch_all(s: &[f32]) {
    for line in s.iter().step_by(16) {
        assist_simd::transpose::prefetch_l2(line);
    }
}

/// Arithmetic of inference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// f32 throughout: what training computes.
    F32,
    /// Rendering's: the hash tables read as bf16 pairs where the caller packed them (any
    /// CPU; see [`PackedTables`]), and the MLP products as `assist_simd::products` takes
    /// them on this CPU: bf16 with f32 sums, 16-bit fixed point with exact integer sums
    /// (`assist_simd::fixed16`), or f32. About 3 significant digits per table entry and
    /// bf16 operand, 4 per fixed-point operand (relative to its weight row's or sample's
    /// largest).
    Bf16,
}

impl Precision {
    /// Rendering's precision: `Bf16` unless `ASSIST_PRECISION=f32`.
    pub fn fastest() -> Self {
        if std::env::var("ASSIST_PRECISION").is_ok_and(|v| v == "f32") {
            Precision::F32
        } else {
            Precision::Bf16
        }
    }
}

/// The MLP weights of rendering's reduced-precision products, one entry per product.
enum Reduced {
    Bf16(Vec<PackedA>),
    /// `None` for a product of fewer than [`FIXED_MIN_ROWS`] rows, which stays f32.
    Fixed(Vec<Option<QuantA>>),
}

/// The fewest rows (outputs) of a product taken in fixed point: below it, scaling the
/// activations costs more than the narrower arithmetic saves (density's 16 outputs, the
/// three colours).
const FIXED_MIN_ROWS: usize = 32;

/// Largest raw density fed to `exp` (σ ≤ e^15); the gradient uses the same clamp
/// (`trunc_exp` as in Nerfacto).
pub const MAX_RAW_DENSITY: f32 = 15.0;

/// Per-sample inputs, structure of arrays. Positions are in the node's canonical box
/// scaled to [0, 1]³; directions are unit vectors in the same frame. `image[i]` selects an
/// appearance code; `u32::MAX` (or an empty slice) means a novel view's code
/// (`novel` where a query takes one, else the average code).
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

/// Seconds spent per phase, for benchmarks.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct PhaseTimes {
    pub encode_forward: f64,
    pub mlp_forward: f64,
    pub mlp_backward: f64,
    pub encode_backward: f64,
}

#[derive(Debug, Clone)]
pub struct Field {
    pub config: FieldConfig,
    pub layout: ParamLayout,
    pub params: Vec<f32>,
    /// Where each appearance code's photograph was taken from: its camera's centre in
    /// the field's local frame, one per code (empty: not known, and novel views take the
    /// average code; see [`Field::novel_code`]).
    pub anchors: Vec<[f32; 3]>,
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
            anchors: Vec::new(),
        })
    }

    /// Fault injection for the tests of divergence handling: the last colour bias
    /// becomes NaN, so every output does.
    #[doc(hidden)]
    pub fn poison(&mut self) {
        let b = self.layout.color.last().expect("colour layers").b;
        self.params[b] = f32::NAN;
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

    /// Fills the colour-net input rows of one chunk that go through the product: geometry
    /// feature and SH. (The appearance code enters as a per-code bias; see `code_biases`.)
    #[inline(always)]
    fn color_input(&self, s: &Samples, c0: usize, dens: &[f32], cin: &mut [f32]) {
        let cfg = &self.config;
        let (geo, shw) = (cfg.geo_features, cfg.sh_width());
        cin[..geo * CHUNK].copy_from_slice(&dens[CHUNK..(1 + geo) * CHUNK]);
        let lanes = CHUNK.min(s.len() - c0);
        let d = |a: usize| &s.dir[a][c0..c0 + lanes];
        if cfg.reflect {
            let mut r = [[0.0f32; CHUNK]; 3];
            reflect::reflected(&dens[(1 + geo) * CHUNK..], [d(0), d(1), d(2)], &mut r);
            let [rx, ry, rz] = &r;
            let (rx, ry, rz) = (&rx[..lanes], &ry[..lanes], &rz[..lanes]);
            sh_encode_rows(cfg.sh_degree, rx, ry, rz, &mut cin[geo * CHUNK..], CHUNK);
        } else {
            sh_encode_rows(
                cfg.sh_degree,
                d(0),
                d(1),
                d(2),
                &mut cin[geo * CHUNK..],
                CHUNK,
            );
        }
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
        fast: Option<(&Reduced, &mut [u32])>,
    ) {
        let lay = &self.layout;
        let p = &self.params;
        // Product `y = W[:, ..cols] x` of layer `i` (density 0, 1, then colour layers), in
        // f32 or through a reduced-precision kernel (activations packed into `bp` first).
        let simd = assist_simd::level();
        let mut fast = fast;
        let mut product =
            |i: usize, l: &Linear, x: &[f32], y: &mut [f32], cols: usize| match fast.as_mut() {
                Some((Reduced::Bf16(packed), bp)) => {
                    bf16::pack_b(simd, x, cols, CHUNK, CHUNK, bp);
                    bf16::gemm(simd, &packed[i], bp, CHUNK, y, CHUNK);
                }
                Some((Reduced::Fixed(q), bp)) if q[i].is_some() => {
                    let q = q[i].as_ref().expect("checked");
                    let mut sb = [0.0f32; CHUNK];
                    fixed16::quant_b(simd, x, cols, CHUNK, CHUNK, bp, &mut sb);
                    fixed16::gemm(simd, q, bp, &sb, CHUNK, y, CHUNK);
                }
                Some((Reduced::Fixed(_), _)) | None => l.product(p, x, y, cols),
            };
        let (h, rest) = act.split_at_mut(rows.dens * CHUNK);
        let (d0, d1) = (&lay.density[0], &lay.density[1]);
        let (dens, rest) = rest.split_at_mut((rows.cin - rows.dens) * CHUNK);
        product(0, d0, enc, h, d0.inp_pad);
        bias_act(&mut h[..d0.out * CHUNK], &p[d0.b..d0.b + d0.out], true);
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
                    crate::mlp::bias_by_slot(out, biases, &slots, l.out);
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
        fast: Option<(&Reduced, &mut [u32])>,
        sig: &mut [f32],
        col: &mut [f32],
    ) {
        assist_simd::simd(
            #[inline(always)]
            || {
                self.chunk_forward(s, c * CHUNK, enc, act, rows, biases, fast);
                write_outputs(act, rows, sig, col);
            },
        )
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
        self.forward_at(Precision::F32, None, None, s, scratch, sigma, rgb)
    }

    /// The MLP weights of each product, in product order (density 0 and 1, then the
    /// colour layers, the first without its appearance columns), made by `pack` from the
    /// weights, the rows, the columns and the row stride.
    fn packed<T>(&self, pack: impl Fn(&[f32], usize, usize, usize) -> T) -> Vec<T> {
        let lay = &self.layout;
        let p = &self.params;
        let one = |l: &Linear, cols: usize| pack(&p[l.w..], l.out, cols, l.inp_pad);
        let mut v = vec![
            one(&lay.density[0], lay.density[0].inp_pad),
            one(&lay.density[1], lay.density[1].inp_pad),
            one(&lay.color[0], self.product_cols()),
        ];
        v.extend(lay.color[1..].iter().map(|l| one(l, l.inp_pad)));
        v
    }

    /// The weights as `precision`'s products take them on this CPU (`None`: f32).
    fn reduced(&self, precision: Precision) -> Option<Reduced> {
        match precision {
            Precision::F32 => None,
            Precision::Bf16 if bf16::available() => Some(Reduced::Bf16(self.packed(PackedA::new))),
            Precision::Bf16 if fixed16::available() => {
                Some(Reduced::Fixed(self.packed(|w, m, k, ld| {
                    (m >= FIXED_MIN_ROWS).then(|| QuantA::new(w, m, k, ld))
                })))
            }
            Precision::Bf16 => None,
        }
    }

    /// Inference at a given precision of the MLP products (biases and activations are f32
    /// either way; `Precision::Bf16`'s products are `assist_simd::products`').
    /// The encoding reads `tables` (this field's packed copy, see [`PackedTables`]) where
    /// given, else the f32 parameters.
    /// `novel` is the code of samples without an image's (`u32::MAX`; `None`: the
    /// average code; see [`Field::novel_code`]).
    #[allow(clippy::too_many_arguments)]
    pub fn forward_at(
        &self,
        precision: Precision,
        tables: Option<&PackedTables>,
        novel: Option<&[f32]>,
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
        self.encode(s.pos, tables, enc);
        self.nets(precision, novel, s, &*enc, width, sigma, rgb);
    }

    /// The nets over every chunk of `s`, from the encoding (`width` rows per chunk).
    #[allow(clippy::too_many_arguments)]
    fn nets(
        &self,
        precision: Precision,
        novel: Option<&[f32]>,
        s: &Samples,
        input: &[f32],
        width: usize,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) {
        let n = s.len();
        let rows = self.rows();
        let biases = self.code_biases_for(novel);
        let packed = self.reduced(precision);
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
                    let input = &input[c * block..(c + 1) * block];
                    assist_simd::simd(
                        #[inline(always)]
                        || {
                            let fast = packed.as_ref().map(|p| (p, bp.as_mut_slice()));
                            self.chunk_forward(s, c * CHUNK, input, act, &rows, &biases, fast);
                            write_outputs(act, &rows, sig, col);
                        },
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
        let block = width * CHUNK;
        let enc = self.encode_blocked(pos, None, scratch);
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

    /// The encoding of `pos` in `scratch` (grown as needed), chunk-blocked, the lanes
    /// past the end of the last chunk zero so they stay finite.
    fn encode_blocked<'a>(
        &self,
        pos: [&[f32]; 3],
        tables: Option<&PackedTables>,
        scratch: &'a mut Vec<f32>,
    ) -> &'a [f32] {
        let n = pos[0].len();
        let width = self.config.encoding_rows();
        let len = Layout { width }.len(n);
        if scratch.len() < len {
            scratch.resize(len, 0.0);
        }
        let enc = &mut scratch[..len];
        if !n.is_multiple_of(CHUNK) {
            enc[len - width * CHUNK..].fill(0.0);
        }
        self.encode(pos, tables, enc);
        enc
    }

    /// The encoding of `pos` into chunk-blocked `enc`: from the f32 parameters, or from
    /// `tables` (this field's packed copy) where given.
    fn encode(&self, pos: [&[f32]; 3], tables: Option<&PackedTables>, enc: &mut [f32]) {
        match tables {
            Some(t) => self.encode_packed(t, pos, enc),
            None => encode(
                &self.layout.grid,
                &self.params,
                pos,
                self.config.encoding_rows(),
                enc,
            ),
        }
    }
}
