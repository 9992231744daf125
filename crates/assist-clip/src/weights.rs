//! Reading a CLIP checkpoint from safetensors, in either naming: OpenAI's / open_clip's
//! (`visual.transformer.resblocks.N.attn.in_proj_weight`, …) or Hugging Face
//! transformers' (`vision_model.encoder.layers.N.self_attn.q_proj.weight`, …). Every
//! tensor is checked against the shape the architecture implies; the result holds the
//! matrices transposed for `x · W` products.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use safetensors::{Dtype, SafeTensors};

use crate::ClipError;
use crate::config::{Activation, ClipConfig, Declared, TextConfig, VisionConfig, default_heads};
use crate::config::{OPENAI_MEAN, OPENAI_STD};

/// One residual attention block (pre-norm), matrices as `[in, out]`.
pub(crate) struct Block {
    pub ln1: (Tensor, Tensor),
    pub qkv_w: Tensor,
    pub qkv_b: Tensor,
    pub out_w: Tensor,
    pub out_b: Tensor,
    pub ln2: (Tensor, Tensor),
    pub fc_w: Tensor,
    pub fc_b: Tensor,
    pub proj_w: Tensor,
    pub proj_b: Tensor,
}

pub(crate) struct Vision {
    /// `[3·p·p, width]`, rows in (channel, y, x) order.
    pub patch_w: Tensor,
    pub class: Tensor,
    pub pos: Tensor,
    pub ln_pre: (Tensor, Tensor),
    pub blocks: Vec<Block>,
    pub ln_post: (Tensor, Tensor),
    /// `[width, embed]`.
    pub proj: Tensor,
}

pub(crate) struct Text {
    pub token: Tensor,
    pub pos: Tensor,
    pub blocks: Vec<Block>,
    pub ln_final: (Tensor, Tensor),
    pub proj: Tensor,
}

pub(crate) struct Weights {
    pub config: ClipConfig,
    pub vision: Vision,
    pub text: Text,
    /// exp(logit_scale): CLIP's temperature for image–text similarities.
    pub logit_scale: f32,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Layout {
    OpenClip,
    HuggingFace,
}

struct Reader<'a> {
    file: PathBuf,
    st: SafeTensors<'a>,
    names: HashMap<String, ()>,
}

fn shape_str(s: &[usize]) -> String {
    format!(
        "[{}]",
        s.iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

impl<'a> Reader<'a> {
    fn has(&self, name: &str) -> bool {
        self.names.contains_key(name)
    }

    /// The shape of `name`, or an error saying what was looked for.
    fn shape(&self, name: &str, what: &str) -> Result<Vec<usize>, ClipError> {
        self.st
            .tensor(name)
            .map(|t| t.shape().to_vec())
            .map_err(|_| ClipError::Missing {
                file: self.file.clone(),
                tensor: name.into(),
                expected: what.into(),
            })
    }

    /// The values of `name` as f32, checked to have shape `want`.
    fn values(&self, name: &str, want: &[usize]) -> Result<Vec<f32>, ClipError> {
        let t = self.st.tensor(name).map_err(|_| ClipError::Missing {
            file: self.file.clone(),
            tensor: name.into(),
            expected: shape_str(want),
        })?;
        if t.shape() != want {
            return Err(ClipError::Shape {
                file: self.file.clone(),
                tensor: name.into(),
                expected: shape_str(want),
                found: shape_str(t.shape()),
            });
        }
        let b = t.data();
        let v: Vec<f32> = match t.dtype() {
            Dtype::F32 => b
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            Dtype::F16 => b
                .chunks_exact(2)
                .map(|c| half::f16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32())
                .collect(),
            Dtype::BF16 => b
                .chunks_exact(2)
                .map(|c| half::bf16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32())
                .collect(),
            other => {
                return Err(ClipError::Shape {
                    file: self.file.clone(),
                    tensor: name.into(),
                    expected: "float32, float16 or bfloat16 values".into(),
                    found: format!("{other:?}"),
                });
            }
        };
        Ok(v)
    }

    fn tensor(&self, name: &str, want: &[usize]) -> Result<Tensor, ClipError> {
        let v = self.values(name, want)?;
        Ok(Tensor::from_vec(v, want, &Device::Cpu)?)
    }

    /// `name` (stored `[out, in]`, as torch's Linear) as a `[in, out]` matrix.
    fn linear_t(&self, name: &str, out: usize, inp: usize) -> Result<Tensor, ClipError> {
        let v = self.values(name, &[out, inp])?;
        Ok(Tensor::from_vec(
            transpose(&v, out, inp),
            (inp, out),
            &Device::Cpu,
        )?)
    }

    /// Number of blocks `prefix{i}suffix` present (0, 1, 2, … contiguous).
    fn count(&self, prefix: &str, suffix: &str) -> usize {
        (0..)
            .take_while(|i| self.has(&format!("{prefix}{i}{suffix}")))
            .count()
    }
}

fn transpose(v: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut t = vec![0.0; v.len()];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = v[r * cols + c];
        }
    }
    t
}

fn sqrt_exact(n: usize) -> Option<usize> {
    let r = (n as f64).sqrt().round() as usize;
    (r * r == n).then_some(r)
}

pub(crate) fn load(
    file: &Path,
    bytes: &[u8],
    declared: &Declared,
) -> Result<(Weights, Layout), ClipError> {
    let st = SafeTensors::deserialize(bytes).map_err(|e| ClipError::Format {
        file: file.to_path_buf(),
        message: match e {
            safetensors::SafeTensorError::MetadataIncompleteBuffer
            | safetensors::SafeTensorError::HeaderTooSmall => format!(
                "{e} — the file is shorter than its header says ({} bytes): a truncated copy?",
                bytes.len()
            ),
            e => e.to_string(),
        },
    })?;
    let names = st
        .names()
        .into_iter()
        .map(|n| (n.to_string(), ()))
        .collect();
    let r = Reader {
        file: file.to_path_buf(),
        st,
        names,
    };
    let layout = if r.has("visual.conv1.weight") {
        Layout::OpenClip
    } else if r.has("vision_model.embeddings.patch_embedding.weight") {
        Layout::HuggingFace
    } else {
        let mut some: Vec<&String> = r.names.keys().collect();
        some.sort();
        some.truncate(5);
        return Err(ClipError::Missing {
            file: file.to_path_buf(),
            tensor: "visual.conv1.weight".into(),
            expected: format!(
                "a CLIP ViT checkpoint (open_clip's visual.conv1.weight or Hugging Face's vision_model.embeddings.patch_embedding.weight); the file has {} tensors, e.g. {some:?}",
                r.names.len()
            ),
        });
    };
    let w = match layout {
        Layout::OpenClip => open_clip(&r, declared)?,
        Layout::HuggingFace => hugging_face(&r, declared)?,
    };
    Ok((w, layout))
}

/// Names of one tower's tensors in a layout.
struct Names {
    /// Blocks are `{blocks}{i}.{suffix}`.
    blocks: String,
    /// (ln1, ln2, fc, proj, out) suffixes; attention input differs by layout.
    ln1: &'static str,
    ln2: &'static str,
    fc: &'static str,
    proj: &'static str,
    out: &'static str,
}

fn blocks(
    r: &Reader,
    n: &Names,
    layers: usize,
    width: usize,
    mlp: usize,
    fused_qkv: bool,
) -> Result<Vec<Block>, ClipError> {
    let dev = Device::Cpu;
    (0..layers)
        .map(|i| {
            let name = |s: &str| format!("{}{i}.{s}", n.blocks);
            let ln = |s: &str| -> Result<(Tensor, Tensor), ClipError> {
                Ok((
                    r.tensor(&name(&format!("{s}.weight")), &[width])?,
                    r.tensor(&name(&format!("{s}.bias")), &[width])?,
                ))
            };
            let (qkv_w, qkv_b) = if fused_qkv {
                (
                    r.linear_t(&name("attn.in_proj_weight"), 3 * width, width)?,
                    r.tensor(&name("attn.in_proj_bias"), &[3 * width])?,
                )
            } else {
                let mut w = Vec::with_capacity(3 * width * width);
                let mut b = Vec::with_capacity(3 * width);
                for p in ["q_proj", "k_proj", "v_proj"] {
                    w.extend(r.values(&name(&format!("self_attn.{p}.weight")), &[width, width])?);
                    b.extend(r.values(&name(&format!("self_attn.{p}.bias")), &[width])?);
                }
                (
                    Tensor::from_vec(transpose(&w, 3 * width, width), (width, 3 * width), &dev)?,
                    Tensor::from_vec(b, 3 * width, &dev)?,
                )
            };
            Ok(Block {
                ln1: ln(n.ln1)?,
                qkv_w,
                qkv_b,
                out_w: r.linear_t(&name(&format!("{}.weight", n.out)), width, width)?,
                out_b: r.tensor(&name(&format!("{}.bias", n.out)), &[width])?,
                ln2: ln(n.ln2)?,
                fc_w: r.linear_t(&name(&format!("{}.weight", n.fc)), mlp, width)?,
                fc_b: r.tensor(&name(&format!("{}.bias", n.fc)), &[mlp])?,
                proj_w: r.linear_t(&name(&format!("{}.weight", n.proj)), width, mlp)?,
                proj_b: r.tensor(&name(&format!("{}.bias", n.proj)), &[width])?,
            })
        })
        .collect()
}

fn ln(r: &Reader, prefix: &str, width: usize) -> Result<(Tensor, Tensor), ClipError> {
    Ok((
        r.tensor(&format!("{prefix}.weight"), &[width])?,
        r.tensor(&format!("{prefix}.bias"), &[width])?,
    ))
}

fn heads_check(file: &Path, what: &str, width: usize, heads: usize) -> Result<usize, ClipError> {
    if heads == 0 || !width.is_multiple_of(heads) {
        return Err(ClipError::Config {
            file: file.to_path_buf(),
            message: format!("{what}: {heads} heads do not divide the width {width}"),
        });
    }
    Ok(heads)
}

fn activation(r: &Reader, d: &Declared, layout: Layout) -> Result<Activation, ClipError> {
    match (d.activation, layout) {
        (Some(a), _) => Ok(a),
        // transformers' CLIPConfig default.
        (None, Layout::HuggingFace) => Ok(Activation::QuickGelu),
        (None, Layout::OpenClip) => Err(ClipError::Config {
            file: r.file.clone(),
            message: "no open_clip_config.json beside it says which activation these weights use: write one containing {\"model_cfg\": {\"quick_gelu\": true}} for OpenAI's weights, or false for LAION/DataComp ones".into(),
        }),
    }
}

fn logit_scale(r: &Reader) -> Result<f32, ClipError> {
    if r.has("logit_scale") {
        let shape = r.shape("logit_scale", "[]")?;
        let v = r.values("logit_scale", &shape)?;
        if v.len() == 1 {
            return Ok(v[0].exp());
        }
    }
    Ok(100.0)
}

/// `[width, 3, patch, patch]` of the patch embedding `name`: (width, patch).
fn patch_shape(r: &Reader, name: &str) -> Result<(usize, usize), ClipError> {
    let conv = r.shape(name, "[width, 3, patch, patch]")?;
    match conv[..] {
        [w, 3, p, p2] if p == p2 => Ok((w, p)),
        _ => Err(ClipError::Shape {
            file: r.file.clone(),
            tensor: name.into(),
            expected: "[width, 3, patch, patch] (square patches)".into(),
            found: shape_str(&conv),
        }),
    }
}

/// The side of the patch grid of the positional embedding `name` (`[1 + grid², width]`).
fn grid_of(r: &Reader, name: &str) -> Result<usize, ClipError> {
    let pos = r.shape(name, "[1 + grid², width]")?;
    sqrt_exact(pos[0].saturating_sub(1)).ok_or_else(|| ClipError::Shape {
        file: r.file.clone(),
        tensor: name.into(),
        expected: "[1 + grid², width] (a square grid of patches)".into(),
        found: shape_str(&pos),
    })
}

/// Sizes read off a checkpoint's tensors.
struct Sizes {
    embed: usize,
    grid: usize,
    patch: usize,
    vision: (usize, usize, usize),
    text: (usize, usize, usize),
    vocab: usize,
    context: usize,
}

/// The architecture from the tensors' sizes (`vision`/`text`: width, layers, MLP width)
/// and what the config file declares.
fn config(
    r: &Reader,
    d: &Declared,
    layout: Layout,
    s: &Sizes,
    vision_heads: usize,
) -> Result<ClipConfig, ClipError> {
    let (vw, vlayers, vmlp) = s.vision;
    let (tw, tlayers, tmlp) = s.text;
    let text_heads = d.text_heads.unwrap_or(default_heads(tw));
    Ok(ClipConfig {
        embed_dim: s.embed,
        vision: VisionConfig {
            image_size: s.grid * s.patch,
            patch_size: s.patch,
            width: vw,
            layers: vlayers,
            heads: heads_check(&r.file, "vision heads", vw, vision_heads)?,
            mlp: vmlp,
        },
        text: TextConfig {
            context_length: s.context,
            vocab_size: s.vocab,
            width: tw,
            layers: tlayers,
            heads: heads_check(&r.file, "text heads", tw, text_heads)?,
            mlp: tmlp,
        },
        activation: activation(r, d, layout)?,
        mean: d.mean.unwrap_or(OPENAI_MEAN),
        std: d.std.unwrap_or(OPENAI_STD),
    })
}

fn open_clip(r: &Reader, d: &Declared) -> Result<Weights, ClipError> {
    let (vw, p) = patch_shape(r, "visual.conv1.weight")?;
    let grid = grid_of(r, "visual.positional_embedding")?;
    let vproj = r.shape("visual.proj", "[width, embed]")?;
    let embed = *vproj.get(1).unwrap_or(&0);
    let vlayers = r.count("visual.transformer.resblocks.", ".ln_1.weight");
    let vmlp = r.shape(
        "visual.transformer.resblocks.0.mlp.c_fc.weight",
        "[mlp, width]",
    )?[0];
    let tok = r.shape("token_embedding.weight", "[vocab, width]")?;
    let (vocab, tw) = (tok[0], *tok.get(1).unwrap_or(&0));
    let ctx = r.shape("positional_embedding", "[context, width]")?[0];
    let tlayers = r.count("transformer.resblocks.", ".ln_1.weight");
    let tmlp = r.shape("transformer.resblocks.0.mlp.c_fc.weight", "[mlp, width]")?[0];
    let vheads = match d.vision_head_width {
        Some(hw) => vw / hw.max(1),
        None => default_heads(vw),
    };
    let sizes = Sizes {
        embed,
        grid,
        patch: p,
        vision: (vw, vlayers, vmlp),
        text: (tw, tlayers, tmlp),
        vocab,
        context: ctx,
    };
    let config = config(r, d, Layout::OpenClip, &sizes, vheads)?;
    let names = |prefix: &'static str| Names {
        blocks: format!("{prefix}transformer.resblocks."),
        ln1: "ln_1",
        ln2: "ln_2",
        fc: "mlp.c_fc",
        proj: "mlp.c_proj",
        out: "attn.out_proj",
    };
    let patch = r.values("visual.conv1.weight", &[vw, 3, p, p])?;
    let vision = Vision {
        patch_w: Tensor::from_vec(
            transpose(&patch, vw, 3 * p * p),
            (3 * p * p, vw),
            &Device::Cpu,
        )?,
        class: r.tensor("visual.class_embedding", &[vw])?,
        pos: r.tensor("visual.positional_embedding", &[grid * grid + 1, vw])?,
        ln_pre: ln(r, "visual.ln_pre", vw)?,
        blocks: blocks(r, &names("visual."), vlayers, vw, vmlp, true)?,
        ln_post: ln(r, "visual.ln_post", vw)?,
        proj: r.tensor("visual.proj", &[vw, embed])?,
    };
    let text = Text {
        token: r.tensor("token_embedding.weight", &[vocab, tw])?,
        pos: r.tensor("positional_embedding", &[ctx, tw])?,
        blocks: blocks(r, &names(""), tlayers, tw, tmlp, true)?,
        ln_final: ln(r, "ln_final", tw)?,
        proj: r.tensor("text_projection", &[tw, embed])?,
    };
    Ok(Weights {
        config,
        vision,
        text,
        logit_scale: logit_scale(r)?,
    })
}

fn hugging_face(r: &Reader, d: &Declared) -> Result<Weights, ClipError> {
    let pe = "vision_model.embeddings.patch_embedding.weight";
    let (vw, p) = patch_shape(r, pe)?;
    let vp = "vision_model.embeddings.position_embedding.weight";
    let grid = grid_of(r, vp)?;
    let embed = r.shape("visual_projection.weight", "[embed, width]")?[0];
    let vlayers = r.count("vision_model.encoder.layers.", ".layer_norm1.weight");
    let vmlp = r.shape(
        "vision_model.encoder.layers.0.mlp.fc1.weight",
        "[mlp, width]",
    )?[0];
    let tok = r.shape(
        "text_model.embeddings.token_embedding.weight",
        "[vocab, width]",
    )?;
    let (vocab, tw) = (tok[0], *tok.get(1).unwrap_or(&0));
    let ctx = r.shape(
        "text_model.embeddings.position_embedding.weight",
        "[context, width]",
    )?[0];
    let tlayers = r.count("text_model.encoder.layers.", ".layer_norm1.weight");
    let tmlp = r.shape("text_model.encoder.layers.0.mlp.fc1.weight", "[mlp, width]")?[0];
    let sizes = Sizes {
        embed,
        grid,
        patch: p,
        vision: (vw, vlayers, vmlp),
        text: (tw, tlayers, tmlp),
        vocab,
        context: ctx,
    };
    let vheads = d.vision_heads.unwrap_or(default_heads(vw));
    let config = config(r, d, Layout::HuggingFace, &sizes, vheads)?;
    let names = |prefix: &'static str| Names {
        blocks: format!("{prefix}.encoder.layers."),
        ln1: "layer_norm1",
        ln2: "layer_norm2",
        fc: "mlp.fc1",
        proj: "mlp.fc2",
        out: "self_attn.out_proj",
    };
    let patch = r.values(pe, &[vw, 3, p, p])?;
    let vision = Vision {
        patch_w: Tensor::from_vec(
            transpose(&patch, vw, 3 * p * p),
            (3 * p * p, vw),
            &Device::Cpu,
        )?,
        class: r.tensor("vision_model.embeddings.class_embedding", &[vw])?,
        pos: r.tensor(vp, &[grid * grid + 1, vw])?,
        // (sic: transformers' name)
        ln_pre: ln(r, "vision_model.pre_layrnorm", vw)?,
        blocks: blocks(r, &names("vision_model"), vlayers, vw, vmlp, false)?,
        ln_post: ln(r, "vision_model.post_layernorm", vw)?,
        proj: r.linear_t("visual_projection.weight", embed, vw)?,
    };
    let text = Text {
        token: r.tensor("text_model.embeddings.token_embedding.weight", &[vocab, tw])?,
        pos: r.tensor(
            "text_model.embeddings.position_embedding.weight",
            &[ctx, tw],
        )?,
        blocks: blocks(r, &names("text_model"), tlayers, tw, tmlp, false)?,
        ln_final: ln(r, "text_model.final_layer_norm", tw)?,
        proj: r.linear_t("text_projection.weight", embed, tw)?,
    };
    Ok(Weights {
        config,
        vision,
        text,
        logit_scale: logit_scale(r)?,
    })
}
