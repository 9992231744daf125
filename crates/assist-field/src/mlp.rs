//! Linear layers of the tiny MLPs over chunks of samples in feature-major layout
//! (`[feature][lane]`, `CHUNK` lanes), with forward and backward side by side. Products go
//! through `assist_simd::gemm` (runtime-dispatched AVX-512 / AVX2 / scalar).

use assist_simd::gemm::{Gemm, gemm};

use crate::hashgrid::CHUNK;

/// A dense layer `y = W x + b`. `W` is `out × inp_pad` row-major at `w` in the parameter
/// vector; input columns beyond `inp` are padding (always zero inputs, so their weights
/// stay zero and get zero gradient).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linear {
    pub out: usize,
    pub inp: usize,
    pub inp_pad: usize,
    pub w: usize,
    pub b: usize,
}

pub fn pad16(n: usize) -> usize {
    n.div_ceil(16) * 16
}

impl Linear {
    pub fn new(out: usize, inp: usize, offset: &mut usize) -> Self {
        let inp_pad = pad16(inp);
        let w = *offset;
        let b = w + out * inp_pad;
        *offset = b + out;
        Linear {
            out,
            inp,
            inp_pad,
            w,
            b,
        }
    }
    pub fn param_count(&self) -> usize {
        self.out * self.inp_pad + self.out
    }

    /// `y[out][CHUNK] = W x[inp_pad][CHUNK] + b`, then ReLU if `relu`.
    #[inline(always)]
    pub fn forward(&self, params: &[f32], x: &[f32], y: &mut [f32], relu: bool) {
        self.product(params, x, y, self.inp_pad);
        bias_act(
            &mut y[..self.out * CHUNK],
            &params[self.b..self.b + self.out],
            relu,
        );
    }

    /// `y[out][CHUNK] = W[:, ..cols] x[..cols][CHUNK]`: the product over the first `cols`
    /// inputs only (no bias).
    #[inline(always)]
    pub fn product(&self, params: &[f32], x: &[f32], y: &mut [f32], cols: usize) {
        assert!(cols <= self.inp_pad);
        let w = &params[self.w..self.w + self.out * self.inp_pad];
        gemm(
            &Gemm {
                m: self.out,
                n: CHUNK,
                k: cols,
                a: w,
                lda: self.inp_pad,
                b: x,
                ldb: CHUNK,
                ldc: CHUNK,
                accumulate: false,
            },
            y,
        );
    }

    /// Given `dy` (gradient at the pre-activation, `[out][CHUNK]`) and the input `x`,
    /// accumulates `dW[:, ..cols] += dy x[..cols]ᵀ` and `db += Σ dy` into `grad` (the
    /// parameter layout from offset `base` on: `grad[0]` is parameter `base`), and writes
    /// `dx = Wᵀ dy` for as many input rows as `dx` holds (`dx.len() / CHUNK` ≤ `inp_pad`).
    /// `wt` is `Wᵀ` (`inp_pad × out`) and `xt` scratch of `CHUNK × inp_pad`. `cols` is
    /// `inp_pad` except for a layer whose trailing inputs act through its bias.
    #[inline(always)]
    pub fn backward(
        &self,
        wt: &[f32],
        x: &[f32],
        dy: &[f32],
        grad: &mut [f32],
        base: usize,
        dx: Option<&mut [f32]>,
        xt: &mut [f32],
        cols: usize,
    ) {
        assert!(cols <= self.inp_pad);
        let k = self.inp_pad;
        assist_simd::transpose::transpose(x, cols, CHUNK, CHUNK, xt, cols);
        let (w0, b0) = (self.w - base, self.b - base);
        let gw = &mut grad[w0..w0 + self.out * k];
        gemm(
            &Gemm {
                m: self.out,
                n: cols,
                k: CHUNK,
                a: dy,
                lda: CHUNK,
                b: xt,
                ldb: cols,
                ldc: k,
                accumulate: true,
            },
            gw,
        );
        let gb = &mut grad[b0..b0 + self.out];
        for (o, row) in dy[..self.out * CHUNK].chunks_exact(CHUNK).enumerate() {
            gb[o] += row_sum(row);
        }
        if let Some(dx) = dx {
            let rows = dx.len() / CHUNK;
            assert!(rows <= k && dx.len() == rows * CHUNK);
            gemm(
                &Gemm {
                    m: rows,
                    n: CHUNK,
                    k: self.out,
                    a: wt,
                    lda: self.out,
                    b: dy,
                    ldb: CHUNK,
                    ldc: CHUNK,
                    accumulate: false,
                },
                dx,
            );
        }
    }

    /// `Wᵀ` (`inp_pad × out`), for the input-gradient products.
    pub fn transposed(&self, params: &[f32]) -> Vec<f32> {
        let k = self.inp_pad;
        let mut t = vec![0.0; k * self.out];
        for o in 0..self.out {
            for i in 0..k {
                t[i * self.out + o] = params[self.w + o * k + i];
            }
        }
        t
    }
}

/// The sum of a row of lanes, in 16 partial sums (lane `i` into partial `i mod 16`)
/// added pairwise at the end. It vectorises: a plain fold is one chain of dependent adds,
/// which cost as much as a layer's weight-gradient product (64 rows of 64 lanes a chunk).
#[inline(always)]
pub fn row_sum(row: &[f32]) -> f32 {
    let mut acc = [0f32; 16];
    let mut blocks = row.chunks_exact(16);
    for b in &mut blocks {
        for i in 0..16 {
            acc[i] += b[i];
        }
    }
    for (a, v) in acc.iter_mut().zip(blocks.remainder()) {
        *a += v;
    }
    let mut w = 16;
    while w > 1 {
        w /= 2;
        for i in 0..w {
            acc[i] += acc[i + w];
        }
    }
    acc[0]
}

/// Adds `bias[o]` to row `o` of `y` (`[out][CHUNK]`), then ReLU if `relu`.
#[inline(always)]
pub fn bias_act(y: &mut [f32], bias: &[f32], relu: bool) {
    for (row, &bo) in y.chunks_exact_mut(CHUNK).zip(bias) {
        if relu {
            for v in row {
                *v = (*v + bo).max(0.0);
            }
        } else {
            for v in row {
                *v += bo;
            }
        }
    }
}

/// The runs of equal slots in `slots` (a chunk's lanes by image: a ray's samples are
/// adjacent and share one), in lane order: each slot with its lanes.
pub fn slot_runs(slots: &[u32]) -> impl Iterator<Item = (u32, std::ops::Range<usize>)> + '_ {
    let mut l0 = 0;
    std::iter::from_fn(move || {
        let &slot = slots.get(l0)?;
        let l1 = l0 + slots[l0..].iter().take_while(|&&s| s == slot).count();
        let run = (slot, l0..l1);
        l0 = l1;
        Some(run)
    })
}

/// Adds to lane `l` of every row `o` of `y` (`[out][CHUNK]`) the bias of its image,
/// `biases[slots[l] · out + o]`: a chunk whose samples come from several images, by runs
/// of one image, each a constant added along the run.
#[inline(always)]
pub fn bias_by_slot(y: &mut [f32], biases: &[f32], slots: &[u32; CHUNK], out: usize) {
    for (sl, run) in slot_runs(slots) {
        let b = &biases[sl as usize * out..][..out];
        for (row, &bo) in y.chunks_exact_mut(CHUNK).zip(b) {
            row[run.clone()].iter_mut().for_each(|v| *v += bo);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The row sum in partial sums equals the exact sum within rounding at every length
    /// (the tail shorter than 16 lanes included), and is exact on integers.
    #[test]
    fn row_sum_matches_the_exact_sum() {
        for n in [0usize, 1, 5, 15, 16, 17, 63, 64, 100] {
            let row: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.3).collect();
            let exact: f64 = row.iter().map(|&v| v as f64).sum();
            let got = row_sum(&row) as f64;
            assert!((got - exact).abs() < 1e-4, "n {n}: {got} vs {exact}");
            let ints: Vec<f32> = (0..n).map(|i| i as f32).collect();
            assert_eq!(row_sum(&ints), (n * n.saturating_sub(1) / 2) as f32);
        }
    }
}
