//! Randomly initialised CLIP checkpoints on disk, in open_clip's layout, for tests and
//! benchmarks: the architecture of a real model (e.g. ViT-B/32) with weights drawn as
//! open_clip initialises them, and a made-up BPE merge table of the right length. Its
//! embeddings mean nothing; its speed and file handling are a real model's.

use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};

use crate::{ClipError, Result};

#[derive(Debug, Clone)]
pub struct RandomSpec {
    pub embed_dim: usize,
    pub image_size: usize,
    pub patch_size: usize,
    pub vision_width: usize,
    pub vision_layers: usize,
    pub vision_head_width: usize,
    pub text_width: usize,
    pub text_layers: usize,
    pub text_heads: usize,
    pub context_length: usize,
    pub vocab_size: usize,
    pub quick_gelu: bool,
}

impl RandomSpec {
    /// OpenAI's ViT-B/32: 224² images in 32² patches, 12 × 768 vision, 12 × 512 text,
    /// 512-d joint space (151 M parameters).
    pub fn vit_b_32() -> Self {
        RandomSpec {
            embed_dim: 512,
            image_size: 224,
            patch_size: 32,
            vision_width: 768,
            vision_layers: 12,
            vision_head_width: 64,
            text_width: 512,
            text_layers: 12,
            text_heads: 8,
            context_length: 77,
            vocab_size: 49408,
            quick_gelu: true,
        }
    }

    /// A small model for tests (fast to write and run).
    pub fn tiny() -> Self {
        RandomSpec {
            embed_dim: 32,
            image_size: 32,
            patch_size: 8,
            vision_width: 64,
            vision_layers: 2,
            vision_head_width: 32,
            text_width: 48,
            text_layers: 2,
            text_heads: 2,
            context_length: 77,
            vocab_size: 49408,
            quick_gelu: false,
        }
    }
}

/// A small deterministic generator (splitmix64) with normal draws.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        ((self.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f32 {
        let (u, v) = (self.uniform(), self.uniform());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    }
}

/// Writes `open_clip_model.safetensors`, `open_clip_config.json` and `merges.txt` into
/// `dir` (created if needed).
pub fn write_model(dir: &Path, spec: &RandomSpec, seed: u64) -> Result<()> {
    let io = |file: &Path| {
        let file = file.to_path_buf();
        move |e: std::io::Error| ClipError::Io { file, source: e }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut rng = Rng(seed);
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    let mut add = |name: String, shape: Vec<usize>, fill: &mut dyn FnMut() -> f32| {
        let n: usize = shape.iter().product();
        let mut bytes = Vec::with_capacity(4 * n);
        for _ in 0..n {
            bytes.extend_from_slice(&fill().to_le_bytes());
        }
        tensors.push((name, shape, bytes));
    };
    let s = spec;
    let grid = s.image_size / s.patch_size;
    let mut towers = vec![(
        "visual.transformer.resblocks.",
        s.vision_width,
        s.vision_layers,
    )];
    towers.push(("transformer.resblocks.", s.text_width, s.text_layers));
    for (prefix, w, layers) in towers {
        let std = (w as f32).powf(-0.5);
        for i in 0..layers {
            let p = |x: &str| format!("{prefix}{i}.{x}");
            for ln in ["ln_1", "ln_2"] {
                add(p(&format!("{ln}.weight")), vec![w], &mut || {
                    1.0 + 0.1 * rng.normal()
                });
                add(p(&format!("{ln}.bias")), vec![w], &mut || {
                    0.1 * rng.normal()
                });
            }
            add(p("attn.in_proj_weight"), vec![3 * w, w], &mut || {
                std * rng.normal()
            });
            add(p("attn.in_proj_bias"), vec![3 * w], &mut || {
                0.02 * rng.normal()
            });
            add(p("attn.out_proj.weight"), vec![w, w], &mut || {
                std * rng.normal()
            });
            add(p("attn.out_proj.bias"), vec![w], &mut || {
                0.02 * rng.normal()
            });
            add(p("mlp.c_fc.weight"), vec![4 * w, w], &mut || {
                std * rng.normal()
            });
            add(p("mlp.c_fc.bias"), vec![4 * w], &mut || 0.02 * rng.normal());
            add(p("mlp.c_proj.weight"), vec![w, 4 * w], &mut || {
                0.5 * std * rng.normal()
            });
            add(p("mlp.c_proj.bias"), vec![w], &mut || 0.02 * rng.normal());
        }
    }
    let (vw, tw) = (s.vision_width, s.text_width);
    let vstd = (vw as f32).powf(-0.5);
    let tstd = (tw as f32).powf(-0.5);
    add(
        "visual.conv1.weight".into(),
        vec![vw, 3, s.patch_size, s.patch_size],
        &mut || 0.02 * rng.normal(),
    );
    add("visual.class_embedding".into(), vec![vw], &mut || {
        vstd * rng.normal()
    });
    add(
        "visual.positional_embedding".into(),
        vec![grid * grid + 1, vw],
        &mut || vstd * rng.normal(),
    );
    for ln in ["visual.ln_pre", "visual.ln_post", "ln_final"] {
        let w = if ln == "ln_final" { tw } else { vw };
        add(format!("{ln}.weight"), vec![w], &mut || {
            1.0 + 0.1 * rng.normal()
        });
        add(format!("{ln}.bias"), vec![w], &mut || 0.1 * rng.normal());
    }
    add("visual.proj".into(), vec![vw, s.embed_dim], &mut || {
        vstd * rng.normal()
    });
    add(
        "token_embedding.weight".into(),
        vec![s.vocab_size, tw],
        &mut || 0.02 * rng.normal(),
    );
    add(
        "positional_embedding".into(),
        vec![s.context_length, tw],
        &mut || 0.01 * rng.normal(),
    );
    add("text_projection".into(), vec![tw, s.embed_dim], &mut || {
        tstd * rng.normal()
    });
    add("logit_scale".into(), vec![], &mut || (1.0f32 / 0.07).ln());

    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(n, shape, b)| {
            TensorView::new(Dtype::F32, shape.clone(), b)
                .map(|v| (n.clone(), v))
                .map_err(|e| ClipError::Input(e.to_string()))
        })
        .collect::<Result<_>>()?;
    let wfile = dir.join("open_clip_model.safetensors");
    safetensors::serialize_to_file(views, None, &wfile).map_err(|e| ClipError::Format {
        file: wfile.clone(),
        message: e.to_string(),
    })?;
    let cfg = serde_json::json!({
        "model_cfg": {
            "embed_dim": s.embed_dim,
            "quick_gelu": s.quick_gelu,
            "vision_cfg": {"image_size": s.image_size, "layers": s.vision_layers,
                "width": vw, "patch_size": s.patch_size, "head_width": s.vision_head_width},
            "text_cfg": {"context_length": s.context_length, "vocab_size": s.vocab_size,
                "width": tw, "heads": s.text_heads, "layers": s.text_layers},
        },
        "note": "randomly initialised by assist for tests and benchmarks; its embeddings mean nothing"
    });
    let cfile = dir.join("open_clip_config.json");
    std::fs::write(
        &cfile,
        serde_json::to_string_pretty(&cfg).unwrap_or_default(),
    )
    .map_err(io(&cfile))?;
    // Merges of pairs of byte characters: distinct, and each merged string new.
    let chars: Vec<char> = super::tokenizer::byte_chars()
        .into_iter()
        .map(|(_, c)| c)
        .collect();
    let needed = s.vocab_size.saturating_sub(514);
    let mut merges = String::from("#version: random\n");
    for k in 0..needed {
        let (a, b) = (chars[k / 256 % 256], chars[k % 256]);
        merges.push_str(&format!("{a} {b}\n"));
    }
    let mfile = dir.join("merges.txt");
    std::fs::write(&mfile, merges).map_err(io(&mfile))?;
    Ok(())
}
