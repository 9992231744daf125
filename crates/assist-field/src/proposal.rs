//! A proposal density field (mip-NeRF 360's, as Nerfacto sizes it): a small hash grid and
//! a one-hidden-layer density net over the same [0, 1]³ coordinates as the field it
//! serves. It is trained to bound that field's weights along rays (the interlevel loss, in
//! `assist_render::proposal`), so a ray's samples can be drawn where the field's weight
//! will be instead of at every step of a march. Cheap by design: its tables fit in cache
//! and its net is 16 wide, so querying it costs a small part of a field query.

use rayon::prelude::*;

use crate::config::FieldConfig;
use crate::field::MAX_RAW_DENSITY;
use crate::hashgrid::{CHUNK, GridLayout, Layout, encode, encode_backward};
use crate::mlp::{Linear, pad16};

/// A proposal field's sizes.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProposalConfig {
    pub levels: usize,
    pub features_per_level: usize,
    pub log2_table_size: u32,
    pub base_resolution: u32,
    pub max_resolution: u32,
    /// Width of the density net's one hidden layer.
    pub hidden: usize,
}

impl Default for ProposalConfig {
    /// Nerfacto's second proposal network: 5 levels × 2 features, T = 2^17, resolutions
    /// 16 → 256, 16 hidden units.
    fn default() -> Self {
        ProposalConfig {
            levels: 5,
            features_per_level: 2,
            log2_table_size: 17,
            base_resolution: 16,
            max_resolution: 256,
            hidden: 16,
        }
    }
}

impl ProposalConfig {
    /// The grid's sizes as a [`FieldConfig`] holds them (the nets' fields are unused).
    fn grid(&self) -> GridLayout {
        GridLayout::new(&FieldConfig {
            levels: self.levels,
            features_per_level: self.features_per_level,
            log2_table_size: self.log2_table_size,
            base_resolution: self.base_resolution,
            max_resolution: self.max_resolution,
            ..FieldConfig::nerfacto(0)
        })
    }
}

/// The proposal field: parameters `[grid entries | hidden layer | output layer]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ProposalField {
    pub config: ProposalConfig,
    pub params: Vec<f32>,
    grid: GridLayout,
    l1: Linear,
    l2: Linear,
    /// Encoding rows per chunk (levels × features, padded to 16).
    width: usize,
}

/// A node's proposal: the field, and how many samples each ray draws from its weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Proposal {
    pub field: ProposalField,
    pub samples: usize,
}

/// What [`ProposalField::forward_train`] keeps for the backward pass.
#[derive(Debug, Clone, Default)]
pub struct ProposalTape {
    n: usize,
    enc: Vec<f32>,
    hidden: Vec<f32>,
    sigma: Vec<f32>,
}

impl ProposalField {
    /// A proposal field with fresh parameters (deterministic for a seed), initialised as
    /// [`crate::Field::new`] does its own.
    pub fn new(config: ProposalConfig, seed: u64) -> Result<Self, crate::FieldError> {
        let bad = |f: &str, m: &str| {
            Err(crate::FieldError::Config {
                field: format!("proposal.{f}"),
                message: m.into(),
            })
        };
        if config.levels == 0 || config.levels > 16 {
            return bad("levels", "expected 1 to 16");
        }
        if ![1, 2, 4, 8].contains(&config.features_per_level) {
            return bad("features_per_level", "expected 1, 2, 4 or 8");
        }
        if !(10..=24).contains(&config.log2_table_size) {
            return bad("log2_table_size", "expected 10 to 24");
        }
        if config.base_resolution == 0 || config.max_resolution < config.base_resolution {
            return bad("max_resolution", "expected base_resolution ≥ 1 and ≤ max");
        }
        if config.hidden == 0 || config.hidden > 256 || !config.hidden.is_multiple_of(16) {
            return bad("hidden", "expected a multiple of 16 up to 256");
        }
        let grid = config.grid();
        let width = pad16(config.levels * config.features_per_level);
        let mut offset = grid.param_count();
        let l1 = Linear::new(config.hidden, width, &mut offset);
        let l2 = Linear::new(1, config.hidden, &mut offset);
        let mut params = vec![0.0f32; offset];
        let mut rng = assist_core::Rng::new(seed);
        for p in &mut params[..grid.param_count()] {
            *p = (rng.f32() * 2.0 - 1.0) * 1e-4;
        }
        for (l, inp) in [
            (l1, config.levels * config.features_per_level),
            (l2, config.hidden),
        ] {
            let bound = (6.0 / inp as f32).sqrt();
            for o in 0..l.out {
                for i in 0..inp {
                    params[l.w + o * l.inp_pad + i] = (rng.f32() * 2.0 - 1.0) * bound;
                }
            }
        }
        Ok(ProposalField {
            config,
            params,
            grid,
            l1,
            l2,
            width,
        })
    }

    /// A field of `config` holding `params` (as read from a file): an error naming the
    /// expected count if it differs.
    pub fn with_params(
        config: ProposalConfig,
        params: Vec<f32>,
    ) -> Result<Self, crate::FieldError> {
        let mut f = ProposalField::new(config, 0)?;
        if params.len() != f.params.len() {
            return Err(crate::FieldError::Config {
                field: "proposal.params".into(),
                message: format!("expected {} values, got {}", f.params.len(), params.len()),
            });
        }
        f.params = params;
        Ok(f)
    }

    /// Where the nets' parameters start (the grid's entries come first): Adam treats the
    /// entries before it as sparse.
    pub fn mlp_start(&self) -> usize {
        self.grid.param_count()
    }

    /// The densities at `pos` (in [0, 1]³) into `sigma`. Runs on the calling thread (it
    /// is called from within parallel sampling); `scratch` is grown as needed and kept.
    /// The hidden layer reads the encoding's rows only, not its padding (the same sums:
    /// the padding's inputs and weights are zeros), so the padding is never cleared here.
    pub fn density(&self, pos: [&[f32]; 3], sigma: &mut [f32], scratch: &mut Vec<f32>) {
        let n = pos[0].len();
        let len = Layout { width: self.width }.len(n);
        if scratch.len() < len {
            scratch.resize(len, 0.0);
        }
        let enc = &mut scratch[..len];
        encode(&self.grid, &self.params, pos, self.width, enc);
        let hidden = self.config.hidden;
        let rows = self.config.levels * self.config.features_per_level;
        let mut h = vec![0.0f32; hidden * CHUNK];
        let mut o = [0.0f32; CHUNK];
        let block = self.width * CHUNK;
        for (c, sig) in sigma[..n].chunks_mut(CHUNK).enumerate() {
            let x = &enc[c * block..(c + 1) * block];
            self.l1.product(&self.params, x, &mut h, rows);
            crate::mlp::bias_act(&mut h, &self.params[self.l1.b..self.l1.b + hidden], true);
            self.l2.forward(&self.params, &h, &mut o, false);
            for (s, &raw) in sig.iter_mut().zip(&o) {
                *s = assist_simd::math::exp(raw.min(MAX_RAW_DENSITY));
            }
        }
    }

    /// The densities at `pos` with what the backward pass needs kept in `tape`.
    pub fn forward_train(&self, pos: [&[f32]; 3], tape: &mut ProposalTape) {
        let n = pos[0].len();
        let mut enc = std::mem::take(&mut tape.enc);
        self.encode_blocked(pos, &mut enc);
        let hidden = self.config.hidden;
        tape.hidden.resize(n.div_ceil(CHUNK) * hidden * CHUNK, 0.0);
        tape.sigma.resize(n.div_ceil(CHUNK) * CHUNK, 0.0);
        let block = self.width * CHUNK;
        tape.hidden
            .par_chunks_mut(hidden * CHUNK)
            .zip(tape.sigma.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(c, (h, sig))| {
                let mut o = [0.0f32; CHUNK];
                self.l1
                    .forward(&self.params, &enc[c * block..(c + 1) * block], h, true);
                self.l2.forward(&self.params, h, &mut o, false);
                for (s, &raw) in sig.iter_mut().zip(&o) {
                    *s = assist_simd::math::exp(raw.min(MAX_RAW_DENSITY));
                }
            });
        tape.enc = enc;
        tape.n = n;
    }

    /// Adds to `grad` (the parameters' layout) the gradient of a loss given `d_sigma`,
    /// its derivative with respect to each density of the last
    /// [`forward_train`](Self::forward_train) at the same `pos`.
    pub fn backward(
        &self,
        pos: [&[f32]; 3],
        tape: &ProposalTape,
        d_sigma: &[f32],
        grad: &mut [f32],
    ) {
        let n = tape.n;
        assert!(
            pos[0].len() == n && d_sigma.len() == n,
            "proposal backward: sizes differ"
        );
        assert_eq!(grad.len(), self.params.len());
        let hidden = self.config.hidden;
        let block = self.width * CHUNK;
        let mlp0 = self.mlp_start();
        let wt1 = self.l1.transposed(&self.params);
        let wt2 = self.l2.transposed(&self.params);
        let mut d_enc = vec![0.0f32; Layout { width: self.width }.len(n)];
        // One contiguous run of chunks per thread, each summed in chunk order into its
        // own gradient, and the runs summed in order: the same bits on every run with the
        // same thread count (a fold over rayon's adaptive splits grouped the chunks
        // differently from run to run, so training with a proposal was not repeatable).
        let nc = n.div_ceil(CHUNK);
        let per = nc.div_ceil(rayon::current_num_threads().max(1)).max(1);
        let runs: Vec<Vec<f32>> = d_enc[..nc * block]
            .par_chunks_mut(per * block)
            .enumerate()
            .map(|(run, d_run)| {
                let mut g = vec![0.0f32; self.params.len() - mlp0];
                let mut dh = vec![0.0f32; hidden * CHUNK];
                let mut xt = vec![0.0f32; CHUNK * self.width.max(pad16(hidden))];
                for (k, de) in d_run.chunks_mut(block).enumerate() {
                    let c = run * per + k;
                    let lanes = (n - c * CHUNK).min(CHUNK);
                    let mut d_raw = [0.0f32; CHUNK];
                    for l in 0..lanes {
                        let s = tape.sigma[c * CHUNK + l];
                        // trunc_exp: the derivative of the clamped exp is its value.
                        d_raw[l] = d_sigma[c * CHUNK + l] * s;
                    }
                    let h = &tape.hidden[c * hidden * CHUNK..(c + 1) * hidden * CHUNK];
                    self.l2.backward(
                        &wt2,
                        h,
                        &d_raw,
                        &mut g,
                        mlp0,
                        Some(&mut dh),
                        &mut xt,
                        self.l2.inp_pad,
                    );
                    for (d, &a) in dh.iter_mut().zip(h) {
                        if a <= 0.0 {
                            *d = 0.0;
                        }
                    }
                    let x = &tape.enc[c * block..(c + 1) * block];
                    self.l1
                        .backward(&wt1, x, &dh, &mut g, mlp0, Some(de), &mut xt, self.width);
                }
                g
            })
            .collect();
        for g in &runs {
            grad[mlp0..].iter_mut().zip(g).for_each(|(x, y)| *x += y);
        }
        encode_backward(&self.grid, pos, self.width, &d_enc, &mut grad[..mlp0]);
    }

    /// The encoding of `pos` in `scratch`, chunk-blocked, the lanes past the end zero.
    fn encode_blocked<'a>(&self, pos: [&[f32]; 3], scratch: &'a mut Vec<f32>) -> &'a [f32] {
        let n = pos[0].len();
        let len = Layout { width: self.width }.len(n);
        scratch.clear();
        scratch.resize(len, 0.0);
        encode(&self.grid, &self.params, pos, self.width, scratch);
        &scratch[..len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points(n: usize, seed: u64) -> [Vec<f32>; 3] {
        let mut rng = assist_core::Rng::new(seed);
        std::array::from_fn(|_| (0..n).map(|_| rng.f32()).collect())
    }

    fn field() -> ProposalField {
        let cfg = ProposalConfig {
            log2_table_size: 12,
            max_resolution: 64,
            ..ProposalConfig::default()
        };
        let mut f = ProposalField::new(cfg, 3).unwrap();
        // Entries large enough that the densities vary between points.
        let mut rng = assist_core::Rng::new(9);
        let grid = f.mlp_start();
        for p in &mut f.params[..grid] {
            *p = (rng.f32() * 2.0 - 1.0) * 0.5;
        }
        f
    }

    /// The loss Σ cᵢ σᵢ.
    fn loss(f: &ProposalField, p: &[Vec<f32>; 3], c: &[f32]) -> f64 {
        let mut sig = vec![0.0; c.len()];
        f.density([&p[0], &p[1], &p[2]], &mut sig, &mut Vec::new());
        sig.iter().zip(c).map(|(&s, &c)| s as f64 * c as f64).sum()
    }

    #[test]
    fn training_densities_are_the_plain_ones() {
        let f = field();
        let p = points(150, 1);
        let pos = [&p[0][..], &p[1][..], &p[2][..]];
        let mut sig = vec![0.0; 150];
        f.density(pos, &mut sig, &mut Vec::new());
        let mut tape = ProposalTape::default();
        f.forward_train(pos, &mut tape);
        assert_eq!(&tape.sigma[..150], &sig[..]);
        // A kept scratch holding anything (NaN here) gives the same densities: the
        // encoding's padding rows are never read.
        let mut kept = vec![f32::NAN; 40_000];
        let mut again = vec![0.0; 150];
        f.density(pos, &mut again, &mut kept);
        assert_eq!(again, sig);
        assert!(sig.iter().all(|s| s.is_finite() && *s > 0.0));
        let (lo, hi) = sig
            .iter()
            .fold((f32::MAX, 0f32), |(a, b), &s| (a.min(s), b.max(s)));
        assert!(hi > 1.5 * lo, "densities barely vary: {lo} … {hi}");
    }

    /// The gradient is the same bits however rayon's threads happen to share the chunks:
    /// training with a proposal repeats run to run. Many chunks over more threads than
    /// the machine has make the old fold over adaptive splits differ within a few calls.
    #[test]
    fn gradient_repeats_bit_for_bit() {
        let f = field();
        let n = 64 * 300 + 17;
        let p = points(n, 5);
        let pos = [&p[0][..], &p[1][..], &p[2][..]];
        let mut rng = assist_core::Rng::new(6);
        let c: Vec<f32> = (0..n).map(|_| rng.f32() * 2.0 - 1.0).collect();
        let mut tape = ProposalTape::default();
        f.forward_train(pos, &mut tape);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(6)
            .build()
            .unwrap();
        let grad = || {
            let mut g = vec![0.0f32; f.params.len()];
            pool.install(|| f.backward(pos, &tape, &c, &mut g));
            g.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        let first = grad();
        for call in 1..24 {
            assert!(grad() == first, "call {call} differs from the first");
        }
    }

    /// Every parameter group's gradient against central differences (in f64 sums).
    #[test]
    fn gradients_match_central_differences() {
        let mut f = field();
        let n = 70;
        let p = points(n, 2);
        let pos = [&p[0][..], &p[1][..], &p[2][..]];
        let mut rng = assist_core::Rng::new(4);
        let c: Vec<f32> = (0..n).map(|_| rng.f32() * 2.0 - 1.0).collect();
        let mut tape = ProposalTape::default();
        f.forward_train(pos, &mut tape);
        let mut grad = vec![0.0f32; f.params.len()];
        f.backward(pos, &tape, &c, &mut grad);
        let mlp0 = f.mlp_start();
        // The entries one sample touches, the hidden layer's weights and biases, the output.
        let touched: Vec<usize> = (0..mlp0).filter(|&i| grad[i] != 0.0).take(12).collect();
        assert!(touched.len() == 12);
        let nets: Vec<usize> = (mlp0..f.params.len()).step_by(7).collect();
        let mut checked = 0;
        for &i in touched.iter().chain(&nets) {
            let h = 2e-4f32;
            let v = f.params[i];
            f.params[i] = v + h;
            let up = loss(&f, &p, &c);
            f.params[i] = v - h;
            let down = loss(&f, &p, &c);
            f.params[i] = v;
            let numeric = (up - down) / (2.0 * h as f64);
            let err = (numeric - grad[i] as f64).abs();
            assert!(
                err <= 2e-2 * numeric.abs().max(grad[i].abs() as f64) + 2e-3,
                "parameter {i}: analytic {} numeric {numeric}",
                grad[i]
            );
            checked += 1;
        }
        assert!(checked > 40);
    }

    #[test]
    fn bad_sizes_are_named() {
        let e = ProposalField::new(
            ProposalConfig {
                features_per_level: 3,
                ..ProposalConfig::default()
            },
            0,
        )
        .unwrap_err();
        assert!(e.to_string().contains("proposal.features_per_level"), "{e}");
        let e = ProposalField::with_params(ProposalConfig::default(), vec![0.0; 5]).unwrap_err();
        assert!(e.to_string().contains("expected"), "{e}");
    }
}
