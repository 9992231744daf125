//! assist-clip: CLIP image and text encoders for scene-node embeddings.
//!
//! Weights are the user's: a folder (or a `.safetensors` file in it) holding
//! - the model as safetensors, in OpenAI/open_clip naming (`open_clip_model.safetensors`)
//!   or Hugging Face transformers naming (`model.safetensors`); float32, float16 or
//!   bfloat16; any ViT size (read off the tensors);
//! - the BPE merges: open_clip's `bpe_simple_vocab_16e6.txt.gz` or Hugging Face's
//!   `merges.txt`;
//! - a config when the tensors cannot say everything: `open_clip_config.json`
//!   (`model_cfg.quick_gelu`, heads, `preprocess_cfg` mean/std) or Hugging Face's
//!   `config.json`. OpenAI-named weights need one, for the activation.
//!
//! [`Clip::from_env`] reads the path from `ASSIST_CLIP`. Every file problem is an error
//! naming the file, and for tensors the tensor and the shape expected.

#![forbid(unsafe_code)]

mod config;
mod model;
mod preprocess;
pub mod random;
mod tokenizer;
mod weights;

use std::path::{Path, PathBuf};

pub use config::{Activation, ClipConfig, TextConfig, VisionConfig};
pub use preprocess::{preprocess, resize_crop};
pub use tokenizer::Tokenizer;
pub use weights::Layout;

/// The environment variable naming the CLIP folder.
pub const ENV: &str = "ASSIST_CLIP";

#[derive(Debug, thiserror::Error)]
pub enum ClipError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: {message}", path.display())]
    NotFound { path: PathBuf, message: String },
    #[error("{}: {message}", file.display())]
    Config { file: PathBuf, message: String },
    #[error("{}: not a readable safetensors file: {message}", file.display())]
    Format { file: PathBuf, message: String },
    #[error("{}: tensor {tensor:?} is missing (expected {expected})", file.display())]
    Missing {
        file: PathBuf,
        tensor: String,
        expected: String,
    },
    #[error("{}: tensor {tensor:?} has shape {found}, expected {expected}", file.display())]
    Shape {
        file: PathBuf,
        tensor: String,
        expected: String,
        found: String,
    },
    #[error("{}: BPE vocabulary: {message}", file.display())]
    Vocab { file: PathBuf, message: String },
    #[error("CLIP input: {0}")]
    Input(String),
    /// A failure inside the tensor library (its first line; candle appends a backtrace).
    #[error("CLIP compute: {0}")]
    Compute(String),
}

pub type Result<T> = std::result::Result<T, ClipError>;

impl From<candle_core::Error> for ClipError {
    fn from(e: candle_core::Error) -> Self {
        let s = e.to_string();
        ClipError::Compute(s.lines().next().unwrap_or_default().to_string())
    }
}

/// Where a model came from.
#[derive(Debug, Clone)]
pub struct ClipFiles {
    pub weights: PathBuf,
    pub vocab: PathBuf,
    pub config: Option<PathBuf>,
    pub layout: Layout,
}

/// A loaded CLIP model with its tokenizer.
pub struct Clip {
    w: weights::Weights,
    tokenizer: Tokenizer,
    pub files: ClipFiles,
}

/// Images per forward pass (bounds memory; large enough for the GEMMs to be efficient).
const IMAGE_BATCH: usize = 16;
const TEXT_BATCH: usize = 64;

fn pick(dir: &Path, names: &[&str], ext: &str) -> Result<Option<PathBuf>> {
    for n in names {
        let p = dir.join(n);
        if p.is_file() {
            return Ok(Some(p));
        }
    }
    let rd = std::fs::read_dir(dir).map_err(|e| ClipError::Io {
        file: dir.to_path_buf(),
        source: e,
    })?;
    let mut found: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.to_string_lossy().ends_with(ext))
        .collect();
    found.sort();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => Err(ClipError::NotFound {
            path: dir.to_path_buf(),
            message: format!(
                "several {ext} files ({}); name one, or keep one of {names:?}",
                found
                    .iter()
                    .map(|p| p
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .into_owned())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}

impl Clip {
    /// Loads the model at `path`: a folder, or a `.safetensors` file whose folder holds
    /// the vocabulary (and config).
    pub fn load(path: &Path) -> Result<Clip> {
        let (dir, weights_file) = if path.is_dir() {
            let w = pick(
                path,
                &["open_clip_model.safetensors", "model.safetensors"],
                ".safetensors",
            )?
            .ok_or_else(|| ClipError::NotFound {
                path: path.to_path_buf(),
                message: "no CLIP weights here: expected open_clip_model.safetensors, model.safetensors or one other .safetensors file".into(),
            })?;
            (path.to_path_buf(), w)
        } else if path.is_file() {
            let dir = path
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .to_path_buf();
            (dir, path.to_path_buf())
        } else {
            return Err(ClipError::NotFound {
                path: path.to_path_buf(),
                message: "does not exist (expected a folder with CLIP weights as safetensors and their BPE vocabulary)".into(),
            });
        };
        let config_file = ["open_clip_config.json", "config.json"]
            .iter()
            .map(|n| dir.join(n))
            .find(|p| p.is_file());
        let declared = match &config_file {
            None => config::Declared::default(),
            Some(f) => {
                let text = std::fs::read_to_string(f).map_err(|e| ClipError::Io {
                    file: f.clone(),
                    source: e,
                })?;
                if text.contains("\"vision_config\"") {
                    config::read_hf(f)?
                } else {
                    config::read_open_clip(f)?
                }
            }
        };
        let bytes = std::fs::read(&weights_file).map_err(|e| ClipError::Io {
            file: weights_file.clone(),
            source: e,
        })?;
        let (w, layout) = weights::load(&weights_file, &bytes, &declared)?;
        drop(bytes);
        let vocab = pick(
            &dir,
            &["bpe_simple_vocab_16e6.txt.gz", "merges.txt"],
            ".txt.gz",
        )?
        .ok_or_else(|| ClipError::NotFound {
            path: dir.clone(),
            message: "no BPE vocabulary beside the weights: copy open_clip's bpe_simple_vocab_16e6.txt.gz (it ships inside the open_clip Python package) or Hugging Face's merges.txt here".into(),
        })?;
        let tokenizer = Tokenizer::from_file(
            &vocab,
            w.config.text.vocab_size,
            w.config.text.context_length,
        )?;
        let v = &w.config.vision;
        if v.image_size % v.patch_size != 0 {
            return Err(ClipError::Config {
                file: weights_file,
                message: "image size is not a multiple of the patch size".into(),
            });
        }
        Ok(Clip {
            w,
            tokenizer,
            files: ClipFiles {
                weights: weights_file,
                vocab,
                config: config_file,
                layout,
            },
        })
    }

    /// The model named by `ASSIST_CLIP`, if it is set (and not empty).
    pub fn from_env() -> Option<Result<Clip>> {
        let p = std::env::var_os(ENV).filter(|v| !v.is_empty())?;
        Some(Clip::load(Path::new(&p)))
    }

    pub fn config(&self) -> &ClipConfig {
        &self.w.config
    }

    /// exp(logit_scale), the model's temperature for similarities (100 for OpenAI's).
    pub fn logit_scale(&self) -> f32 {
        self.w.logit_scale
    }

    pub fn tokenizer(&self) -> &Tokenizer {
        &self.tokenizer
    }

    /// Features (not normalised) of images already preprocessed: each
    /// `3 × size × size` floats, channel-major, normalised by the model's mean and std.
    pub fn image_features(&self, pixels: &[Vec<f32>]) -> Result<Vec<Vec<f32>>> {
        let c = &self.w.config;
        let s = c.vision.image_size;
        if let Some(bad) = pixels.iter().position(|p| p.len() != 3 * s * s) {
            return Err(ClipError::Input(format!(
                "image {bad} has {} values, expected 3×{s}×{s}",
                pixels[bad].len()
            )));
        }
        let mut out = Vec::with_capacity(pixels.len());
        for chunk in pixels.chunks(IMAGE_BATCH) {
            let flat: Vec<f32> = chunk.iter().flatten().copied().collect();
            let f = model::encode_image(
                &self.w.vision,
                &flat,
                chunk.len(),
                s,
                c.vision.patch_size,
                c.vision.heads,
                c.activation,
            )?;
            out.extend(f.to_vec2::<f32>()?);
        }
        Ok(out)
    }

    /// Features (not normalised) of RGB images: resized so the shorter side is the
    /// model's size (bicubic), centre-cropped square, normalised — open_clip's
    /// evaluation transform.
    pub fn embed_images(&self, images: &[image::RgbImage]) -> Result<Vec<Vec<f32>>> {
        let c = &self.w.config;
        let px: Vec<Vec<f32>> = images
            .iter()
            .map(|im| preprocess(im, c.vision.image_size, c.mean, c.std))
            .collect::<Result<_>>()?;
        self.image_features(&px)
    }

    /// Features (not normalised) of texts.
    pub fn text_features(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>> {
        let c = &self.w.config;
        let mut out = Vec::with_capacity(texts.len());
        for chunk in texts.chunks(TEXT_BATCH) {
            let toks: Vec<Vec<u32>> = chunk.iter().map(|t| self.tokenizer.tokenize(t)).collect();
            let f = model::encode_text(&self.w.text, &toks, c.text.heads, c.activation)?;
            out.extend(f.to_vec2::<f32>()?);
        }
        Ok(out)
    }
}

/// `v / |v|` (zero stays zero).
pub fn normalize(v: &[f32]) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        v.iter().map(|x| x / n).collect()
    } else {
        v.to_vec()
    }
}
