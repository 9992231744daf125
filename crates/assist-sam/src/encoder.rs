//! SAM's image encoder: a ViT over 16-pixel patches with absolute positions, windowed
//! attention in most blocks and global attention in a few, decomposed relative position
//! terms in every attention, and a convolutional neck to 256 channels.

use candle_core::{D, Tensor};

use crate::{Result, SamError, Weights};

pub(crate) fn linear(x: &Tensor, w: &(Tensor, Tensor)) -> candle_core::Result<Tensor> {
    let dims = x.dims().to_vec();
    let n = *dims.last().unwrap_or(&1);
    let flat = x.reshape(((), n))?;
    let y = flat.matmul(&w.0.t()?)?.broadcast_add(&w.1)?;
    let mut out = dims;
    if let Some(l) = out.last_mut() {
        *l = w.0.dim(0)?;
    }
    y.reshape(out)
}

pub(crate) fn layer_norm(
    x: &Tensor,
    p: &(Tensor, Tensor),
    eps: f32,
) -> candle_core::Result<Tensor> {
    candle_nn::ops::layer_norm(&x.contiguous()?, &p.0, &p.1, eps)
}

/// LayerNorm2d: over the channels of an NCHW tensor.
pub(crate) fn layer_norm_2d(x: &Tensor, p: &(Tensor, Tensor)) -> candle_core::Result<Tensor> {
    layer_norm(&x.permute((0, 2, 3, 1))?, p, 1e-6)?.permute((0, 3, 1, 2))
}

pub(crate) fn load_linear(w: &Weights, name: &str, inp: Option<usize>) -> Result<(Tensor, Tensor)> {
    let weight = w.get(&format!("{name}.weight"), &[None, inp])?;
    let out = weight.dim(0)?;
    Ok((weight, w.get(&format!("{name}.bias"), &[Some(out)])?))
}

pub(crate) fn load_norm(w: &Weights, name: &str, dim: usize) -> Result<(Tensor, Tensor)> {
    Ok((
        w.get(&format!("{name}.weight"), &[Some(dim)])?,
        w.get(&format!("{name}.bias"), &[Some(dim)])?,
    ))
}

struct Block {
    norm1: (Tensor, Tensor),
    qkv: (Tensor, Tensor),
    proj: (Tensor, Tensor),
    rel_h: Tensor,
    rel_w: Tensor,
    norm2: (Tensor, Tensor),
    lin1: (Tensor, Tensor),
    lin2: (Tensor, Tensor),
    heads: usize,
    /// 0: global attention.
    window: usize,
}

/// The encoder's weights and sizes.
pub struct ImageEncoder {
    patch_w: Tensor,
    patch_b: Tensor,
    pos: Tensor,
    blocks: Vec<Block>,
    neck0: Tensor,
    neck1: (Tensor, Tensor),
    neck2: Tensor,
    neck3: (Tensor, Tensor),
    /// The side of the (square, padded) input image.
    pub img_size: usize,
    pub patch: usize,
    pub dim: usize,
    /// Attention scores computed at once (floats); fewer heads or windows at a time
    /// below it (a global block's scores are 4096² per head, 0.8 GB for ViT-B's twelve).
    pub scores_per_chunk: usize,
}

impl ImageEncoder {
    pub(crate) fn load(w: &Weights, p: &str) -> Result<Self> {
        let patch_w = w.get(
            &format!("{p}.patch_embed.proj.weight"),
            &[None, Some(3), None, None],
        )?;
        let (dim, _, patch, _) = patch_w.dims4()?;
        let patch_b = w.get(&format!("{p}.patch_embed.proj.bias"), &[Some(dim)])?;
        let pos = w.get(&format!("{p}.pos_embed"), &[Some(1), None, None, Some(dim)])?;
        let grid = pos.dim(1)?;
        let mut blocks = Vec::new();
        while w.has(&format!("{p}.blocks.{}.norm1.weight", blocks.len())) {
            let b = format!("{p}.blocks.{}", blocks.len());
            let rel_h = w.get(&format!("{b}.attn.rel_pos_h"), &[None, None])?;
            let (len, head_dim) = rel_h.dims2()?;
            let side = len.div_ceil(2);
            if head_dim == 0 || dim % head_dim != 0 || len % 2 == 0 {
                return Err(SamError::Tensor {
                    path: w.path.clone(),
                    name: format!("{b}.attn.rel_pos_h"),
                    msg: format!(
                        "shape {:?} does not fit embedding width {dim}",
                        rel_h.dims()
                    ),
                });
            }
            blocks.push(Block {
                norm1: load_norm(w, &format!("{b}.norm1"), dim)?,
                qkv: load_linear(w, &format!("{b}.attn.qkv"), Some(dim))?,
                proj: load_linear(w, &format!("{b}.attn.proj"), Some(dim))?,
                rel_w: w.get(&format!("{b}.attn.rel_pos_w"), &[Some(len), Some(head_dim)])?,
                rel_h,
                norm2: load_norm(w, &format!("{b}.norm2"), dim)?,
                lin1: load_linear(w, &format!("{b}.mlp.lin1"), Some(dim))?,
                lin2: load_linear(w, &format!("{b}.mlp.lin2"), None)?,
                heads: dim / head_dim,
                window: if side == grid { 0 } else { side },
            });
        }
        if blocks.is_empty() {
            return Err(SamError::Tensor {
                path: w.path.clone(),
                name: format!("{p}.blocks.0.norm1.weight"),
                msg: "missing: no encoder blocks".into(),
            });
        }
        let neck0 = w.get(
            &format!("{p}.neck.0.weight"),
            &[None, Some(dim), Some(1), Some(1)],
        )?;
        let out = neck0.dim(0)?;
        Ok(ImageEncoder {
            patch_w,
            patch_b,
            pos,
            blocks,
            neck1: load_norm(w, &format!("{p}.neck.1"), out)?,
            neck2: w.get(
                &format!("{p}.neck.2.weight"),
                &[Some(out), Some(out), Some(3), Some(3)],
            )?,
            neck3: load_norm(w, &format!("{p}.neck.3"), out)?,
            neck0,
            img_size: grid * patch,
            patch,
            dim,
            scores_per_chunk: SCORES_PER_CHUNK,
        })
    }

    /// The embedding grid's side (input side / patch).
    pub fn grid(&self) -> usize {
        self.img_size / self.patch
    }

    /// `x`: `[1, 3, S, S]`, normalised and padded; returns `[1, 256, S/16, S/16]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x = x
            .conv2d(&self.patch_w, 0, self.patch, 1, 1)?
            .broadcast_add(&self.patch_b.reshape((1, (), 1, 1))?)?
            .permute((0, 2, 3, 1))?;
        let mut x = x.broadcast_add(&self.pos)?;
        for b in &self.blocks {
            x = b.forward(&x, self.scores_per_chunk)?;
        }
        let x = x.permute((0, 3, 1, 2))?.contiguous()?;
        let x = layer_norm_2d(&x.conv2d(&self.neck0, 0, 1, 1, 1)?, &self.neck1)?;
        let x = layer_norm_2d(
            &x.contiguous()?.conv2d(&self.neck2, 1, 1, 1, 1)?,
            &self.neck3,
        )?;
        Ok(x.contiguous()?)
    }
}

impl Block {
    fn forward(&self, x: &Tensor, per_chunk: usize) -> candle_core::Result<Tensor> {
        let (_, h, w, c) = x.dims4()?;
        let y = layer_norm(x, &self.norm1, 1e-6)?;
        let y = if self.window > 0 {
            let ws = self.window;
            let (hp, wp) = (h.div_ceil(ws) * ws, w.div_ceil(ws) * ws);
            // Zero padding after the norm, as the reference: padded tokens take part in
            // their window's attention.
            let y = y
                .pad_with_zeros(1, 0, hp - h)?
                .pad_with_zeros(2, 0, wp - w)?;
            let win = y
                .reshape((1, hp / ws, ws, wp / ws, ws, c))?
                .permute((0, 1, 3, 2, 4, 5))?
                .reshape(((), ws, ws, c))?;
            let a = self.attention(&win, per_chunk)?;
            a.reshape((1, hp / ws, wp / ws, ws, ws, c))?
                .permute((0, 1, 3, 2, 4, 5))?
                .reshape((1, hp, wp, c))?
                .narrow(1, 0, h)?
                .narrow(2, 0, w)?
        } else {
            self.attention(&y, per_chunk)?
        };
        let x = (x + y)?;
        let m = layer_norm(&x, &self.norm2, 1e-6)?;
        let m = linear(&linear(&m, &self.lin1)?.gelu_erf()?, &self.lin2)?;
        x + m
    }

    /// Multi-head attention over each `[B, H, W, C]` grid, with decomposed relative
    /// positions.
    fn attention(&self, x: &Tensor, per_chunk: usize) -> candle_core::Result<Tensor> {
        let (b, h, w, c) = x.dims4()?;
        let nh = self.heads;
        let hd = c / nh;
        let qkv = linear(x, &self.qkv)?
            .reshape((b, h * w, 3, nh, hd))?
            .permute((2, 0, 3, 1, 4))?
            .reshape((3, b * nh, h * w, hd))?;
        let (q, k, v) = (qkv.get(0)?, qkv.get(1)?, qkv.get(2)?);
        let rh = rel_pos(h, &self.rel_h)?.t()?.contiguous()?; // [H, hd, H]
        let rw = rel_pos(w, &self.rel_w)?.t()?.contiguous()?; // [W, hd, W]
        let bq = b * nh;
        let chunk = (per_chunk / (h * w * h * w)).clamp(1, bq);
        let mut outs = Vec::new();
        for start in (0..bq).step_by(chunk) {
            let n = chunk.min(bq - start);
            let q = q.narrow(0, start, n)?;
            let (k, v) = (k.narrow(0, start, n)?, v.narrow(0, start, n)?);
            outs.push(self.scores(&q, &k, &v, (&rh, &rw), (h, w))?);
        }
        let attn_v = Tensor::cat(&outs, 0)?;
        let out = attn_v
            .reshape((b, nh, h, w, hd))?
            .permute((0, 2, 3, 1, 4))?
            .reshape((b, h, w, c))?;
        linear(&out, &self.proj)
    }

    /// softmax(q·kᵀ/√d + relative positions)·v for `n` heads or windows of an `h` × `w`
    /// grid: `[n, h·w, hd]`.
    fn scores(
        &self,
        q: &Tensor,
        k: &Tensor,
        v: &Tensor,
        (rh, rw): (&Tensor, &Tensor),
        (h, w): (usize, usize),
    ) -> candle_core::Result<Tensor> {
        let (n, _, hd) = q.dims3()?;
        let scale = (hd as f64).powf(-0.5);
        let attn = (q * scale)?.matmul(&k.t()?.contiguous()?)?;
        let rq = q.reshape((n, h, w, hd))?;
        // rel_h[b, y, x, k] = Σ_c q[b, y, x, c] · Rh[y, k, c]
        let rel_h = rq
            .permute((1, 0, 2, 3))?
            .reshape((h, n * w, hd))?
            .matmul(rh)?
            .reshape((h, n, w, h))?
            .permute((1, 0, 2, 3))?;
        // rel_w[b, y, x, k] = Σ_c q[b, y, x, c] · Rw[x, k, c]
        let rel_w = rq
            .permute((2, 0, 1, 3))?
            .reshape((w, n * h, hd))?
            .matmul(rw)?
            .reshape((w, n, h, w))?
            .permute((1, 2, 0, 3))?;
        let attn = attn
            .reshape((n, h, w, h, w))?
            .broadcast_add(&rel_h.unsqueeze(4)?)?
            .broadcast_add(&rel_w.unsqueeze(3)?)?
            .reshape((n, h * w, h * w))?;
        let attn = candle_nn::ops::softmax_last_dim(&attn)?;
        attn.matmul(&v.contiguous()?)
    }
}

/// Attention scores computed at once by default (floats): 16 M, 64 MB.
pub const SCORES_PER_CHUNK: usize = 1 << 24;

/// The relative-position table for a `size` × `size` grid: `[size (query), size (key),
/// head_dim]`, entry `q − k + size − 1` of `table`.
fn rel_pos(size: usize, table: &Tensor) -> candle_core::Result<Tensor> {
    let len = table.dim(0)?;
    if len != 2 * size - 1 {
        candle_core::bail!(
            "relative position table of {len} rows for a {size}-wide grid (expected {})",
            2 * size - 1
        );
    }
    let idx: Vec<u32> = (0..size)
        .flat_map(|q| (0..size).map(move |k| (q + size - 1 - k) as u32))
        .collect();
    let idx = Tensor::from_vec(idx, size * size, table.device())?;
    table
        .index_select(&idx, 0)?
        .reshape((size, size, table.dim(D::Minus1)?))
}
