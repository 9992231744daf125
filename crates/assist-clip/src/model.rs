//! The forward passes: a pre-norm ViT over image patches (class token pooled) and a
//! causal text transformer (pooled at the end-of-text token), each projected into the
//! joint space. Matrix products run in candle (multi-threaded, SIMD GEMM on the CPU).

use candle_core::{Device, Result, Tensor};
use candle_nn::ops::{layer_norm, sigmoid, softmax_last_dim};

use crate::config::Activation;
use crate::weights::{Block, Text, Vision};

const LN_EPS: f32 = 1e-5;

fn ln(x: &Tensor, p: &(Tensor, Tensor)) -> Result<Tensor> {
    layer_norm(&x.contiguous()?, &p.0, &p.1, LN_EPS)
}

/// `x [n, in] · w [in, out] + b`.
fn linear(x: &Tensor, w: &Tensor, b: &Tensor) -> Result<Tensor> {
    x.matmul(w)?.broadcast_add(b)
}

fn block(
    x: &Tensor,
    b: &Block,
    heads: usize,
    mask: Option<&Tensor>,
    act: Activation,
) -> Result<Tensor> {
    let (n, t, d) = x.dims3()?;
    let hd = d / heads;
    let h = ln(x, &b.ln1)?.reshape((n * t, d))?;
    let qkv = linear(&h, &b.qkv_w, &b.qkv_b)?
        .reshape((n, t, 3, heads, hd))?
        .permute((2, 0, 3, 1, 4))?;
    let q = (qkv.get(0)?.contiguous()? * (1.0 / (hd as f64).sqrt()))?;
    let k = qkv.get(1)?.contiguous()?;
    let v = qkv.get(2)?.contiguous()?;
    let mut att = q.matmul(&k.t()?.contiguous()?)?;
    if let Some(m) = mask {
        att = att.broadcast_add(m)?;
    }
    let att = softmax_last_dim(&att)?;
    let o = att
        .matmul(&v)?
        .transpose(1, 2)?
        .contiguous()?
        .reshape((n * t, d))?;
    let x = (x + linear(&o, &b.out_w, &b.out_b)?.reshape((n, t, d))?)?;
    let h = ln(&x, &b.ln2)?.reshape((n * t, d))?;
    let h = linear(&h, &b.fc_w, &b.fc_b)?;
    let h = match act {
        Activation::Gelu => h.gelu_erf()?,
        Activation::QuickGelu => (&h * sigmoid(&(&h * 1.702)?)?)?,
    };
    let h = linear(&h, &b.proj_w, &b.proj_b)?.reshape((n, t, d))?;
    x + h
}

/// Image features of `pixels` (`n` images, each 3×size×size, normalised, channel-major).
pub(crate) fn encode_image(
    w: &Vision,
    pixels: &[f32],
    n: usize,
    size: usize,
    patch: usize,
    heads: usize,
    act: Activation,
) -> Result<Tensor> {
    let g = size / patch;
    let k = 3 * patch * patch;
    let mut rows = vec![0f32; n * g * g * k];
    for i in 0..n {
        let img = &pixels[i * 3 * size * size..(i + 1) * 3 * size * size];
        for gy in 0..g {
            for gx in 0..g {
                let row = &mut rows[((i * g + gy) * g + gx) * k..][..k];
                for c in 0..3 {
                    for ky in 0..patch {
                        let src = &img[(c * size + gy * patch + ky) * size + gx * patch..][..patch];
                        row[(c * patch + ky) * patch..][..patch].copy_from_slice(src);
                    }
                }
            }
        }
    }
    let width = w.class.dims1()?;
    let patches = Tensor::from_vec(rows, (n * g * g, k), &Device::Cpu)?
        .matmul(&w.patch_w)?
        .reshape((n, g * g, width))?;
    let cls = w.class.reshape((1, 1, width))?.repeat((n, 1, 1))?;
    let mut x = Tensor::cat(&[&cls, &patches], 1)?.broadcast_add(&w.pos)?;
    x = ln(&x, &w.ln_pre)?;
    for b in &w.blocks {
        x = block(&x, b, heads, None, act)?;
    }
    let pooled = x.narrow(1, 0, 1)?.squeeze(1)?;
    ln(&pooled, &w.ln_post)?.matmul(&w.proj)
}

/// Text features of `tokens` (`n` rows of the context length, zero padded).
pub(crate) fn encode_text(
    w: &Text,
    tokens: &[Vec<u32>],
    heads: usize,
    act: Activation,
) -> Result<Tensor> {
    let n = tokens.len();
    // Pooled at the end-of-text token, the largest id (the reference's argmax); with a
    // causal mask nothing after the last one in the batch can change it, so the
    // sequence is cut there.
    let ends: Vec<usize> = tokens
        .iter()
        .map(|t| {
            t.iter()
                .enumerate()
                .max_by_key(|(i, v)| (**v, std::cmp::Reverse(*i)))
                .map(|(i, _)| i)
                .unwrap_or(0)
        })
        .collect();
    let t = ends.iter().max().map_or(1, |m| m + 1);
    let flat: Vec<u32> = tokens.iter().flat_map(|r| r[..t].iter().copied()).collect();
    let ids = Tensor::from_vec(flat, n * t, &Device::Cpu)?;
    let width = w.token.dims2()?.1;
    let mut x = w
        .token
        .index_select(&ids, 0)?
        .reshape((n, t, width))?
        .broadcast_add(&w.pos.narrow(0, 0, t)?)?;
    let mut mask = vec![0f32; t * t];
    for i in 0..t {
        for j in i + 1..t {
            mask[i * t + j] = f32::NEG_INFINITY;
        }
    }
    let mask = Tensor::from_vec(mask, (t, t), &Device::Cpu)?;
    for b in &w.blocks {
        x = block(&x, b, heads, Some(&mask), act)?;
    }
    let x = ln(&x, &w.ln_final)?;
    let rows: Vec<u32> = ends
        .iter()
        .enumerate()
        .map(|(i, e)| (i * t + e) as u32)
        .collect();
    let pooled = x
        .reshape((n * t, width))?
        .index_select(&Tensor::from_vec(rows, n, &Device::Cpu)?, 0)?;
    pooled.matmul(&w.proj)
}
