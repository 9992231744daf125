//! The architecture of a CLIP checkpoint: sizes read off its tensors, heads and activation
//! from the config file beside it (open_clip's `open_clip_config.json` or Hugging Face's
//! `config.json`), and the image normalisation.

use std::path::Path;

use serde_json::Value;

use crate::ClipError;

/// The MLP activation: OpenAI's weights were trained with QuickGELU, most open_clip
/// (LAION, DataComp) ViT weights with exact GELU. It cannot be read off the tensors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    Gelu,
    QuickGelu,
}

#[derive(Debug, Clone, PartialEq)]
pub struct VisionConfig {
    pub image_size: usize,
    pub patch_size: usize,
    pub width: usize,
    pub layers: usize,
    pub heads: usize,
    pub mlp: usize,
}

#[derive(Debug, Clone, PartialEq)]
pub struct TextConfig {
    pub context_length: usize,
    pub vocab_size: usize,
    pub width: usize,
    pub layers: usize,
    pub heads: usize,
    pub mlp: usize,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ClipConfig {
    /// Width of the joint embedding space (512 for ViT-B/32).
    pub embed_dim: usize,
    pub vision: VisionConfig,
    pub text: TextConfig,
    pub activation: Activation,
    /// Per-channel mean and standard deviation of the image normalisation.
    pub mean: [f32; 3],
    pub std: [f32; 3],
}

/// OpenAI's image normalisation (also open_clip's default).
pub const OPENAI_MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
pub const OPENAI_STD: [f32; 3] = [0.268_629_5, 0.261_302_6, 0.275_777_1];

/// What the config file says (all optional: sizes come from the tensors).
#[derive(Debug, Default, Clone)]
pub(crate) struct Declared {
    pub activation: Option<Activation>,
    pub vision_heads: Option<usize>,
    pub text_heads: Option<usize>,
    pub vision_head_width: Option<usize>,
    pub mean: Option<[f32; 3]>,
    pub std: Option<[f32; 3]>,
}

fn bad(file: &Path, field: &str, expected: &str) -> ClipError {
    ClipError::Config {
        file: file.to_path_buf(),
        message: format!("{field}: expected {expected}"),
    }
}

fn opt_usize(v: &Value, file: &Path, field: &str) -> Result<Option<usize>, ClipError> {
    let mut cur = v;
    for part in field.split('.') {
        match cur.get(part) {
            Some(x) => cur = x,
            None => return Ok(None),
        }
    }
    match cur.as_u64() {
        Some(n) if n > 0 => Ok(Some(n as usize)),
        _ if cur.is_null() => Ok(None),
        _ => Err(bad(file, field, "a positive integer")),
    }
}

fn opt_triple(v: Option<&Value>, file: &Path, field: &str) -> Result<Option<[f32; 3]>, ClipError> {
    let Some(v) = v else { return Ok(None) };
    if v.is_null() {
        return Ok(None);
    }
    let arr = v
        .as_array()
        .filter(|a| a.len() == 3 && a.iter().all(|x| x.as_f64().is_some()))
        .ok_or_else(|| bad(file, field, "three numbers"))?;
    let f = |i: usize| arr[i].as_f64().unwrap_or(0.0) as f32;
    Ok(Some([f(0), f(1), f(2)]))
}

fn activation_named(name: &str, file: &Path, field: &str) -> Result<Activation, ClipError> {
    match name {
        "quick_gelu" => Ok(Activation::QuickGelu),
        "gelu" => Ok(Activation::Gelu),
        _ => Err(bad(file, field, "\"quick_gelu\" or \"gelu\"")),
    }
}

/// Reads open_clip's `open_clip_config.json` (`{"model_cfg": {...}, "preprocess_cfg": {...}}`,
/// or a bare model config).
pub(crate) fn read_open_clip(file: &Path) -> Result<Declared, ClipError> {
    let v = read_json(file)?;
    let model = v.get("model_cfg").unwrap_or(&v);
    let mut d = Declared {
        ..Default::default()
    };
    d.activation = match model.get("quick_gelu") {
        None | Some(Value::Null) => Some(Activation::Gelu),
        Some(Value::Bool(true)) => Some(Activation::QuickGelu),
        Some(Value::Bool(false)) => Some(Activation::Gelu),
        Some(_) => return Err(bad(file, "model_cfg.quick_gelu", "true or false")),
    };
    d.text_heads = opt_usize(model, file, "text_cfg.heads")?;
    d.vision_head_width = opt_usize(model, file, "vision_cfg.head_width")?;
    d.vision_heads = None;
    let pre = v.get("preprocess_cfg");
    d.mean = opt_triple(pre.and_then(|p| p.get("mean")), file, "preprocess_cfg.mean")?;
    d.std = opt_triple(pre.and_then(|p| p.get("std")), file, "preprocess_cfg.std")?;
    Ok(d)
}

/// Reads a Hugging Face `CLIPModel` `config.json` (absent fields take `CLIPConfig`'s
/// defaults, as `save_pretrained` leaves them out).
pub(crate) fn read_hf(file: &Path) -> Result<Declared, ClipError> {
    let v = read_json(file)?;
    let act = |part: &str| -> Result<Activation, ClipError> {
        match v.get(part).and_then(|c| c.get("hidden_act")) {
            None => Ok(Activation::QuickGelu),
            Some(Value::String(s)) => activation_named(s, file, &format!("{part}.hidden_act")),
            Some(_) => Err(bad(file, &format!("{part}.hidden_act"), "a string")),
        }
    };
    let (ta, va) = (act("text_config")?, act("vision_config")?);
    if ta != va {
        return Err(bad(
            file,
            "text_config.hidden_act",
            "the same activation as vision_config.hidden_act",
        ));
    }
    Ok(Declared {
        activation: Some(ta),
        text_heads: Some(opt_usize(&v, file, "text_config.num_attention_heads")?.unwrap_or(8)),
        vision_heads: Some(opt_usize(&v, file, "vision_config.num_attention_heads")?.unwrap_or(12)),
        vision_head_width: None,
        mean: None,
        std: None,
    })
}

fn read_json(file: &Path) -> Result<Value, ClipError> {
    let text = std::fs::read_to_string(file).map_err(|e| ClipError::Io {
        file: file.to_path_buf(),
        source: e,
    })?;
    serde_json::from_str(&text).map_err(|e| ClipError::Config {
        file: file.to_path_buf(),
        message: format!("not JSON: {e}"),
    })
}

/// Heads of a width when nothing says: open_clip's convention of 64-wide heads.
pub(crate) fn default_heads(width: usize) -> usize {
    (width / 64).max(1)
}
