//! Random checkpoints of SAM's real architectures (names and shapes as Meta's), for
//! benchmarks and tests without weights: the times are a real model's, the masks noise.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{Device, Tensor};

use crate::Result;

/// The sizes of a SAM.
#[derive(Debug, Clone)]
pub struct RandomSpec {
    pub img_size: usize,
    pub embed_dim: usize,
    pub depth: usize,
    pub heads: usize,
    pub window: usize,
    pub global: Vec<usize>,
    /// The prompt and decoder width (256 in every released SAM).
    pub prompt_dim: usize,
}

impl RandomSpec {
    /// SAM ViT-B (`sam_vit_b_01ec64.pth`'s architecture, 91 M parameters).
    pub fn vit_b() -> Self {
        RandomSpec {
            img_size: 1024,
            embed_dim: 768,
            depth: 12,
            heads: 12,
            window: 14,
            global: vec![2, 5, 8, 11],
            prompt_dim: 256,
        }
    }

    /// A SAM small enough for tests: a 64-pixel input, two blocks (one windowed with a
    /// window that does not divide the grid, one global), 64-wide prompts.
    pub fn tiny() -> Self {
        RandomSpec {
            img_size: 64,
            embed_dim: 32,
            depth: 2,
            heads: 2,
            window: 3,
            global: vec![1],
            prompt_dim: 64,
        }
    }
}

/// Uniform values in ±`scale` from a xorshift generator (no dependency for noise).
struct Noise(u64);

impl Noise {
    fn tensor(&mut self, shape: &[usize], scale: f32) -> candle_core::Result<Tensor> {
        let n: usize = shape.iter().product();
        let v: Vec<f32> = (0..n)
            .map(|_| {
                self.0 ^= self.0 << 13;
                self.0 ^= self.0 >> 7;
                self.0 ^= self.0 << 17;
                ((self.0 >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * scale
            })
            .collect();
        Tensor::from_vec(v, shape, &Device::Cpu)
    }
}

/// The tensors being made.
struct Maker {
    t: HashMap<String, Tensor>,
    rng: Noise,
}

impl Maker {
    /// A tensor of `shape`, scaled by its fan-in.
    fn put(&mut self, name: String, shape: &[usize]) -> candle_core::Result<()> {
        let fan = shape.iter().skip(1).product::<usize>().max(1) as f32;
        let v = self.rng.tensor(shape, 1.0 / fan.sqrt())?;
        self.t.insert(name, v);
        Ok(())
    }

    fn linear(&mut self, name: &str, i: usize, o: usize) -> candle_core::Result<()> {
        self.put(format!("{name}.weight"), &[o, i])?;
        self.put(format!("{name}.bias"), &[o])
    }

    fn norm(&mut self, name: &str, n: usize) -> candle_core::Result<()> {
        self.put(format!("{name}.weight"), &[n])?;
        self.put(format!("{name}.bias"), &[n])
    }

    /// The decoder's attention of width `p` with an inner width `inner`.
    fn attn(&mut self, name: &str, p: usize, inner: usize) -> candle_core::Result<()> {
        for q in ["q_proj", "k_proj", "v_proj"] {
            self.linear(&format!("{name}.{q}"), p, inner)?;
        }
        self.linear(&format!("{name}.out_proj"), inner, p)
    }
}

/// Writes a random SAM of `spec` to `path` (safetensors).
pub fn write_random(path: &Path, spec: &RandomSpec, seed: u64) -> Result<()> {
    let mut m = Maker {
        t: HashMap::new(),
        rng: Noise(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1),
    };
    let (d, p) = (spec.embed_dim, spec.prompt_dim);
    let g = spec.img_size / 16;
    let e = "image_encoder";
    m.put(format!("{e}.patch_embed.proj.weight"), &[d, 3, 16, 16])?;
    m.put(format!("{e}.patch_embed.proj.bias"), &[d])?;
    m.put(format!("{e}.pos_embed"), &[1, g, g, d])?;
    for k in 0..spec.depth {
        let b = format!("{e}.blocks.{k}");
        let side = if spec.global.contains(&k) {
            g
        } else {
            spec.window
        };
        m.norm(&format!("{b}.norm1"), d)?;
        m.norm(&format!("{b}.norm2"), d)?;
        m.linear(&format!("{b}.attn.qkv"), d, 3 * d)?;
        m.linear(&format!("{b}.attn.proj"), d, d)?;
        m.put(
            format!("{b}.attn.rel_pos_h"),
            &[2 * side - 1, d / spec.heads],
        )?;
        m.put(
            format!("{b}.attn.rel_pos_w"),
            &[2 * side - 1, d / spec.heads],
        )?;
        m.linear(&format!("{b}.mlp.lin1"), d, 4 * d)?;
        m.linear(&format!("{b}.mlp.lin2"), 4 * d, d)?;
    }
    m.put(format!("{e}.neck.0.weight"), &[p, d, 1, 1])?;
    m.norm(&format!("{e}.neck.1"), p)?;
    m.put(format!("{e}.neck.2.weight"), &[p, p, 3, 3])?;
    m.norm(&format!("{e}.neck.3"), p)?;
    let pe = "prompt_encoder";
    m.put(
        format!("{pe}.pe_layer.positional_encoding_gaussian_matrix"),
        &[2, p / 2],
    )?;
    for k in 0..4 {
        m.put(format!("{pe}.point_embeddings.{k}.weight"), &[1, p])?;
    }
    m.put(format!("{pe}.not_a_point_embed.weight"), &[1, p])?;
    m.put(format!("{pe}.no_mask_embed.weight"), &[1, p])?;
    let md = "mask_decoder";
    m.put(format!("{md}.iou_token.weight"), &[1, p])?;
    m.put(format!("{md}.mask_tokens.weight"), &[4, p])?;
    let tr = format!("{md}.transformer");
    for k in 0..2 {
        let l = format!("{tr}.layers.{k}");
        m.attn(&format!("{l}.self_attn"), p, p)?;
        m.attn(&format!("{l}.cross_attn_token_to_image"), p, p / 2)?;
        m.attn(&format!("{l}.cross_attn_image_to_token"), p, p / 2)?;
        for n in ["norm1", "norm2", "norm3", "norm4"] {
            m.norm(&format!("{l}.{n}"), p)?;
        }
        m.linear(&format!("{l}.mlp.lin1"), p, 2048)?;
        m.linear(&format!("{l}.mlp.lin2"), 2048, p)?;
    }
    m.attn(&format!("{tr}.final_attn_token_to_image"), p, p / 2)?;
    m.norm(&format!("{tr}.norm_final_attn"), p)?;
    m.put(format!("{md}.output_upscaling.0.weight"), &[p, p / 4, 2, 2])?;
    m.put(format!("{md}.output_upscaling.0.bias"), &[p / 4])?;
    m.norm(&format!("{md}.output_upscaling.1"), p / 4)?;
    m.put(
        format!("{md}.output_upscaling.3.weight"),
        &[p / 4, p / 8, 2, 2],
    )?;
    m.put(format!("{md}.output_upscaling.3.bias"), &[p / 8])?;
    for k in 0..4 {
        let h = format!("{md}.output_hypernetworks_mlps.{k}");
        m.linear(&format!("{h}.layers.0"), p, p)?;
        m.linear(&format!("{h}.layers.1"), p, p)?;
        m.linear(&format!("{h}.layers.2"), p, p / 8)?;
    }
    let iou = format!("{md}.iou_prediction_head");
    m.linear(&format!("{iou}.layers.0"), p, 256)?;
    m.linear(&format!("{iou}.layers.1"), 256, 256)?;
    m.linear(&format!("{iou}.layers.2"), 256, 4)?;
    candle_core::safetensors::save(&m.t, path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Prompt, Sam};

    #[test]
    fn a_random_checkpoint_loads_and_segments() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sam.safetensors");
        write_random(&path, &RandomSpec::tiny(), 7).unwrap();
        let sam = Sam::load(&path).unwrap();
        assert_eq!((sam.encoder.img_size, sam.encoder.dim), (64, 32));
        let rgb = vec![0.5f32; 3 * 40 * 30];
        let emb = sam.embed(&rgb, 40, 30).unwrap();
        assert_eq!(emb.tensor.dims(), &[1, 64, 4, 4]);
        let prompt = Prompt {
            points: vec![([20.0, 15.0], 1)],
            bbox: Some([5.0, 5.0, 35.0, 25.0]),
        };
        let m = sam.predict(&emb, &prompt, true).unwrap();
        assert_eq!((m.logits.len(), m.side, m.iou.len()), (3, 16, 3));
        assert!(m.logits.iter().flatten().all(|v| v.is_finite()));
        let mask = sam.segment(&emb, &prompt, |_, iou| iou as f64).unwrap();
        assert_eq!(mask.len(), 40 * 30);
        // A file of another kind is refused by name.
        let junk = dir.path().join("junk.pth");
        std::fs::write(&junk, b"nope").unwrap();
        let e = Sam::load(&junk).err().unwrap().to_string();
        assert!(e.contains("junk.pth") && e.contains("PyTorch"), "{e}");
    }
}
