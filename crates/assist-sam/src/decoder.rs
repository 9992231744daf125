//! SAM's prompt encoder (random Fourier positions for points and box corners, learned
//! point-type embeddings) and mask decoder (a two-way transformer between prompt tokens
//! and the image embedding, upscaling, hypernetwork heads and an IoU head).

use std::f64::consts::PI;

use candle_core::{Device, Tensor};

use crate::encoder::{layer_norm, layer_norm_2d, linear, load_linear, load_norm};
use crate::{Prompt, Result, Weights};

/// The prompt encoder's weights.
pub struct PromptEncoder {
    gauss: Tensor,
    point: [Tensor; 4],
    not_a_point: Tensor,
    no_mask: Tensor,
    pub dim: usize,
    /// The image embedding's grid and the encoder's input side.
    pub grid: usize,
    pub input: usize,
}

impl PromptEncoder {
    pub(crate) fn load(w: &Weights, p: &str, grid: usize, input: usize) -> Result<Self> {
        let gauss = w.get(
            &format!("{p}.pe_layer.positional_encoding_gaussian_matrix"),
            &[Some(2), None],
        )?;
        let dim = 2 * gauss.dim(1)?;
        let emb = |name: String| w.get(&name, &[Some(1), Some(dim)]);
        Ok(PromptEncoder {
            point: [
                emb(format!("{p}.point_embeddings.0.weight"))?,
                emb(format!("{p}.point_embeddings.1.weight"))?,
                emb(format!("{p}.point_embeddings.2.weight"))?,
                emb(format!("{p}.point_embeddings.3.weight"))?,
            ],
            not_a_point: emb(format!("{p}.not_a_point_embed.weight"))?,
            no_mask: emb(format!("{p}.no_mask_embed.weight"))?,
            gauss,
            dim,
            grid,
            input,
        })
    }

    /// sin/cos of 2π (2c − 1) G for coordinates `c` in [0, 1]²: `[n, dim]`.
    fn pe(&self, coords: &[[f32; 2]]) -> candle_core::Result<Tensor> {
        let flat: Vec<f32> = coords
            .iter()
            .flat_map(|c| [2.0 * c[0] - 1.0, 2.0 * c[1] - 1.0])
            .collect();
        let c = Tensor::from_vec(flat, (coords.len(), 2), &Device::Cpu)?;
        let c = (c.matmul(&self.gauss)? * (2.0 * PI))?;
        Tensor::cat(&[c.sin()?, c.cos()?], 1)
    }

    /// Sparse `[1, n, dim]` and dense `[1, dim, grid, grid]` embeddings of a prompt in
    /// the input frame.
    pub fn forward(&self, prompt: &Prompt) -> Result<(Tensor, Tensor)> {
        let s = self.input as f32;
        let mut rows = Vec::new();
        if !prompt.points.is_empty() {
            let mut pts: Vec<([f32; 2], i32)> = prompt
                .points
                .iter()
                .map(|&([x, y], l)| ([(x + 0.5) / s, (y + 0.5) / s], i32::from(l.min(1))))
                .collect();
            if prompt.bbox.is_none() {
                pts.push(([0.5 / s, 0.5 / s], -1));
            }
            let coords: Vec<[f32; 2]> = pts.iter().map(|p| p.0).collect();
            let pe = self.pe(&coords)?;
            for (k, (_, l)) in pts.iter().enumerate() {
                let row = pe.narrow(0, k, 1)?;
                rows.push(match l {
                    -1 => self.not_a_point.clone(),
                    0 => (row + &self.point[0])?,
                    _ => (row + &self.point[1])?,
                });
            }
        }
        if let Some([x0, y0, x1, y1]) = prompt.bbox {
            let pe = self.pe(&[
                [(x0 + 0.5) / s, (y0 + 0.5) / s],
                [(x1 + 0.5) / s, (y1 + 0.5) / s],
            ])?;
            rows.push((pe.narrow(0, 0, 1)? + &self.point[2])?);
            rows.push((pe.narrow(0, 1, 1)? + &self.point[3])?);
        }
        let sparse = if rows.is_empty() {
            Tensor::zeros((1, 0, self.dim), candle_core::DType::F32, &Device::Cpu)?
        } else {
            Tensor::cat(&rows, 0)?.unsqueeze(0)?
        };
        let dense = self
            .no_mask
            .reshape((1, self.dim, 1, 1))?
            .broadcast_as((1, self.dim, self.grid, self.grid))?
            .contiguous()?;
        Ok((sparse, dense))
    }

    /// The positional encoding of every cell of the embedding grid: `[1, dim, grid, grid]`.
    pub fn dense_pe(&self) -> Result<Tensor> {
        let g = self.grid;
        let coords: Vec<[f32; 2]> = (0..g * g)
            .map(|i| {
                [
                    ((i % g) as f32 + 0.5) / g as f32,
                    ((i / g) as f32 + 0.5) / g as f32,
                ]
            })
            .collect();
        Ok(self
            .pe(&coords)?
            .reshape((g, g, self.dim))?
            .permute((2, 0, 1))?
            .unsqueeze(0)?
            .contiguous()?)
    }
}

/// Multi-head attention between token sets, with an inner width `dim / downsample`.
struct Attention {
    q: (Tensor, Tensor),
    k: (Tensor, Tensor),
    v: (Tensor, Tensor),
    out: (Tensor, Tensor),
    heads: usize,
}

impl Attention {
    fn load(w: &Weights, p: &str, dim: usize, heads: usize) -> Result<Self> {
        Ok(Attention {
            q: load_linear(w, &format!("{p}.q_proj"), Some(dim))?,
            k: load_linear(w, &format!("{p}.k_proj"), Some(dim))?,
            v: load_linear(w, &format!("{p}.v_proj"), Some(dim))?,
            out: load_linear(w, &format!("{p}.out_proj"), None)?,
            heads,
        })
    }

    fn forward(&self, q: &Tensor, k: &Tensor, v: &Tensor) -> candle_core::Result<Tensor> {
        let split = |x: Tensor| -> candle_core::Result<Tensor> {
            let (b, n, c) = x.dims3()?;
            x.reshape((b, n, self.heads, c / self.heads))?
                .transpose(1, 2)?
                .contiguous()
        };
        let q = split(linear(q, &self.q)?)?;
        let k = split(linear(k, &self.k)?)?;
        let v = split(linear(v, &self.v)?)?;
        let (b, h, n, c) = q.dims4()?;
        let attn = (q.matmul(&k.t()?.contiguous()?)? / (c as f64).sqrt())?;
        let attn = candle_nn::ops::softmax_last_dim(&attn)?;
        let out = attn.matmul(&v)?.transpose(1, 2)?.reshape((b, n, h * c))?;
        linear(&out, &self.out)
    }
}

struct TwoWayBlock {
    self_attn: Attention,
    norm1: (Tensor, Tensor),
    to_image: Attention,
    norm2: (Tensor, Tensor),
    lin1: (Tensor, Tensor),
    lin2: (Tensor, Tensor),
    norm3: (Tensor, Tensor),
    norm4: (Tensor, Tensor),
    to_token: Attention,
    skip_first_pe: bool,
}

impl TwoWayBlock {
    fn forward(
        &self,
        queries: &Tensor,
        keys: &Tensor,
        qpe: &Tensor,
        kpe: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let queries = if self.skip_first_pe {
            self.self_attn.forward(queries, queries, queries)?
        } else {
            let q = (queries + qpe)?;
            (queries + self.self_attn.forward(&q, &q, queries)?)?
        };
        let queries = layer_norm(&queries, &self.norm1, 1e-5)?;
        let (q, k) = ((&queries + qpe)?, (keys + kpe)?);
        let queries = (&queries + self.to_image.forward(&q, &k, keys)?)?;
        let queries = layer_norm(&queries, &self.norm2, 1e-5)?;
        let mlp = linear(&linear(&queries, &self.lin1)?.relu()?, &self.lin2)?;
        let queries = layer_norm(&(queries + mlp)?, &self.norm3, 1e-5)?;
        let (q, k) = ((&queries + qpe)?, (keys + kpe)?);
        let keys = (keys + self.to_token.forward(&k, &q, &queries)?)?;
        let keys = layer_norm(&keys, &self.norm4, 1e-5)?;
        Ok((queries, keys))
    }
}

/// The mask decoder's weights.
pub struct MaskDecoder {
    layers: Vec<TwoWayBlock>,
    final_attn: Attention,
    norm_final: (Tensor, Tensor),
    iou_token: Tensor,
    mask_tokens: Tensor,
    up1: (Tensor, Tensor),
    up_norm: (Tensor, Tensor),
    up2: (Tensor, Tensor),
    hyper: Vec<Vec<(Tensor, Tensor)>>,
    iou_head: Vec<(Tensor, Tensor)>,
}

fn load_mlp(w: &Weights, p: &str) -> Result<Vec<(Tensor, Tensor)>> {
    let mut layers = Vec::new();
    while w.has(&format!("{p}.layers.{}.weight", layers.len())) {
        layers.push(load_linear(
            w,
            &format!("{p}.layers.{}", layers.len()),
            None,
        )?);
    }
    if layers.is_empty() {
        load_linear(w, &format!("{p}.layers.0"), None)?;
    }
    Ok(layers)
}

fn mlp(x: &Tensor, layers: &[(Tensor, Tensor)]) -> candle_core::Result<Tensor> {
    let mut x = x.clone();
    for (i, l) in layers.iter().enumerate() {
        x = linear(&x, l)?;
        if i + 1 < layers.len() {
            x = x.relu()?;
        }
    }
    Ok(x)
}

/// SAM's decoder has 8 heads in every attention.
const DECODER_HEADS: usize = 8;

impl MaskDecoder {
    pub(crate) fn load(w: &Weights, p: &str) -> Result<Self> {
        let iou_token = w.get(&format!("{p}.iou_token.weight"), &[Some(1), None])?;
        let dim = iou_token.dim(1)?;
        let mask_tokens = w.get(&format!("{p}.mask_tokens.weight"), &[None, Some(dim)])?;
        let t = format!("{p}.transformer");
        let mut layers = Vec::new();
        while w.has(&format!("{t}.layers.{}.norm1.weight", layers.len())) {
            let l = format!("{t}.layers.{}", layers.len());
            layers.push(TwoWayBlock {
                self_attn: Attention::load(w, &format!("{l}.self_attn"), dim, DECODER_HEADS)?,
                norm1: load_norm(w, &format!("{l}.norm1"), dim)?,
                to_image: Attention::load(
                    w,
                    &format!("{l}.cross_attn_token_to_image"),
                    dim,
                    DECODER_HEADS,
                )?,
                norm2: load_norm(w, &format!("{l}.norm2"), dim)?,
                lin1: load_linear(w, &format!("{l}.mlp.lin1"), Some(dim))?,
                lin2: load_linear(w, &format!("{l}.mlp.lin2"), None)?,
                norm3: load_norm(w, &format!("{l}.norm3"), dim)?,
                norm4: load_norm(w, &format!("{l}.norm4"), dim)?,
                to_token: Attention::load(
                    w,
                    &format!("{l}.cross_attn_image_to_token"),
                    dim,
                    DECODER_HEADS,
                )?,
                skip_first_pe: layers.is_empty(),
            });
        }
        let up1_w = w.get(
            &format!("{p}.output_upscaling.0.weight"),
            &[Some(dim), None, Some(2), Some(2)],
        )?;
        let c1 = up1_w.dim(1)?;
        let up2_w = w.get(
            &format!("{p}.output_upscaling.3.weight"),
            &[Some(c1), None, Some(2), Some(2)],
        )?;
        let c2 = up2_w.dim(1)?;
        let n = mask_tokens.dim(0)?;
        Ok(MaskDecoder {
            final_attn: Attention::load(
                w,
                &format!("{t}.final_attn_token_to_image"),
                dim,
                DECODER_HEADS,
            )?,
            norm_final: load_norm(w, &format!("{t}.norm_final_attn"), dim)?,
            layers,
            up1: (
                up1_w,
                w.get(&format!("{p}.output_upscaling.0.bias"), &[Some(c1)])?,
            ),
            up_norm: load_norm(w, &format!("{p}.output_upscaling.1"), c1)?,
            up2: (
                up2_w,
                w.get(&format!("{p}.output_upscaling.3.bias"), &[Some(c2)])?,
            ),
            hyper: (0..n)
                .map(|i| load_mlp(w, &format!("{p}.output_hypernetworks_mlps.{i}")))
                .collect::<Result<_>>()?,
            iou_head: load_mlp(w, &format!("{p}.iou_prediction_head"))?,
            iou_token,
            mask_tokens,
        })
    }

    /// Masks `[1, n, 4g, 4g]` and IoU estimates `[1, n]`: all four (`multimask` false:
    /// the first; true: the other three, as the reference).
    pub fn forward(
        &self,
        emb: &Tensor,
        pe: &Tensor,
        sparse: &Tensor,
        dense: &Tensor,
        multimask: bool,
    ) -> Result<(Tensor, Tensor)> {
        let out_tokens = Tensor::cat(&[&self.iou_token, &self.mask_tokens], 0)?.unsqueeze(0)?;
        let tokens = Tensor::cat(&[&out_tokens, sparse], 1)?;
        let src = (emb + dense)?;
        let (b, c, h, w) = src.dims4()?;
        let keys0 = src.flatten_from(2)?.transpose(1, 2)?.contiguous()?;
        let kpe = pe.flatten_from(2)?.transpose(1, 2)?.contiguous()?;
        let (mut queries, mut keys) = (tokens.clone(), keys0);
        for l in &self.layers {
            (queries, keys) = l.forward(&queries, &keys, &tokens, &kpe)?;
        }
        let (q, k) = ((&queries + &tokens)?, (&keys + &kpe)?);
        let queries = (&queries + self.final_attn.forward(&q, &k, &keys)?)?;
        let hs = layer_norm(&queries, &self.norm_final, 1e-5)?;
        let src = keys.transpose(1, 2)?.reshape((b, c, h, w))?;
        let up = src
            .conv_transpose2d(&self.up1.0, 0, 0, 2, 1)?
            .broadcast_add(&self.up1.1.reshape((1, (), 1, 1))?)?;
        let up = layer_norm_2d(&up, &self.up_norm)?
            .gelu_erf()?
            .contiguous()?;
        let up = up
            .conv_transpose2d(&self.up2.0, 0, 0, 2, 1)?
            .broadcast_add(&self.up2.1.reshape((1, (), 1, 1))?)?
            .gelu_erf()?;
        let (_, cu, hu, wu) = up.dims4()?;
        let n = self.hyper.len();
        let hyper: Vec<Tensor> = (0..n)
            .map(|i| mlp(&hs.narrow(1, 1 + i, 1)?.squeeze(1)?, &self.hyper[i]))
            .collect::<candle_core::Result<_>>()?;
        let hyper = Tensor::stack(&hyper, 1)?; // [b, n, cu]
        let masks = hyper
            .matmul(&up.reshape((b, cu, hu * wu))?)?
            .reshape((b, n, hu, wu))?;
        let iou = mlp(&hs.narrow(1, 0, 1)?.squeeze(1)?, &self.iou_head)?;
        let (start, len) = if multimask { (1, n - 1) } else { (0, 1) };
        Ok((masks.narrow(1, start, len)?, iou.narrow(1, start, len)?))
    }
}
