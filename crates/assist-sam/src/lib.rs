//! Segment Anything (Kirillov et al. 2023) on candle: the ViT image encoder, the prompt
//! encoder (points and boxes) and the two-way-transformer mask decoder, read from the
//! user's own checkpoint (Meta's `sam_vit_b_01ec64.pth`, or any size, as `.pth` or
//! `.safetensors`; no weights ship with assist and none are downloaded). It follows
//! `segment_anything`'s reference code operation for operation (exact GELU, zero-padded
//! attention windows, decomposed relative positions), checked against it on random
//! weights in `tests/parity.rs`.
//!
//! assist uses it to sharpen the masks of objects made from clicks or boxes: each view
//! is prompted with the object's projected box and click ([`Sam::segment`]).

mod decoder;
mod encoder;
mod image;
pub mod random;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};

pub use decoder::{MaskDecoder, PromptEncoder};
pub use encoder::ImageEncoder;
pub use image::{mask_to_size, preprocess};

/// What can go wrong reading or running a SAM checkpoint.
#[derive(Debug, thiserror::Error)]
pub enum SamError {
    #[error("{path}: {msg}")]
    File { path: PathBuf, msg: String },
    #[error("{path}: tensor `{name}`: {msg}")]
    Tensor {
        path: PathBuf,
        name: String,
        msg: String,
    },
    #[error("SAM: {0}")]
    Candle(#[from] candle_core::Error),
    #[error("SAM: {0}")]
    Input(String),
}

pub type Result<T> = std::result::Result<T, SamError>;

/// A checkpoint's tensors by name, and where they came from (for errors).
pub(crate) struct Weights {
    pub path: PathBuf,
    pub map: HashMap<String, Tensor>,
}

impl Weights {
    /// The tensor `name`, which must have `shape` (`None` entries: any length).
    pub fn get(&self, name: &str, shape: &[Option<usize>]) -> Result<Tensor> {
        let t = self.map.get(name).ok_or_else(|| SamError::Tensor {
            path: self.path.clone(),
            name: name.into(),
            msg: "missing (is this a Segment Anything checkpoint?)".into(),
        })?;
        let dims = t.dims();
        let fits = dims.len() == shape.len()
            && dims
                .iter()
                .zip(shape)
                .all(|(d, s)| s.is_none_or(|s| s == *d));
        if !fits {
            return Err(SamError::Tensor {
                path: self.path.clone(),
                name: name.into(),
                msg: format!("has shape {dims:?}, expected {shape:?} (None: any)"),
            });
        }
        Ok(t.to_dtype(DType::F32)?)
    }

    pub fn has(&self, name: &str) -> bool {
        self.map.contains_key(name)
    }
}

/// A prompt in the model's input frame (the image resized so its longer side is the
/// encoder's input size): points with labels (1 object, 0 not the object) and a box.
#[derive(Debug, Clone, Default)]
pub struct Prompt {
    pub points: Vec<([f32; 2], u8)>,
    /// `[x0, y0, x1, y1]`.
    pub bbox: Option<[f32; 4]>,
}

/// The masks one prompt gives: low-resolution logits (`side` × `side`, 4 × the image
/// embedding's grid) with the model's own estimate of each mask's IoU.
#[derive(Debug, Clone)]
pub struct Masks {
    pub side: usize,
    pub logits: Vec<Vec<f32>>,
    pub iou: Vec<f32>,
}

/// A loaded Segment Anything model.
pub struct Sam {
    pub encoder: ImageEncoder,
    pub prompt: PromptEncoder,
    pub decoder: MaskDecoder,
}

/// An image's embedding, with the sizes needed to map prompts and masks.
pub struct Embedding {
    pub tensor: Tensor,
    /// The photograph's size and its size resized into the encoder's input.
    pub original: (usize, usize),
    pub resized: (usize, usize),
}

impl Sam {
    /// Reads a checkpoint (`.pth` as PyTorch saves a state dict, or `.safetensors`); the
    /// architecture's sizes are read from its tensors.
    pub fn load(path: &Path) -> Result<Sam> {
        let file_err = |msg: String| SamError::File {
            path: path.to_path_buf(),
            msg,
        };
        if !path.is_file() {
            return Err(file_err(
                "no such file (give a Segment Anything checkpoint, e.g. sam_vit_b_01ec64.pth)"
                    .into(),
            ));
        }
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let map: HashMap<String, Tensor> = match ext {
            "safetensors" => candle_core::safetensors::load(path, &Device::Cpu)
                .map_err(|e| file_err(format!("cannot read as safetensors: {e}")))?,
            "pth" | "pt" | "bin" => candle_core::pickle::read_all(path)
                .map_err(|e| file_err(format!("cannot read as a PyTorch state dict: {e}")))?
                .into_iter()
                .collect(),
            _ => {
                return Err(file_err(
                    "expected a .pth or .safetensors Segment Anything checkpoint".into(),
                ));
            }
        };
        let w = Weights {
            path: path.to_path_buf(),
            map,
        };
        let encoder = ImageEncoder::load(&w, "image_encoder")?;
        let grid = encoder.grid();
        let prompt = PromptEncoder::load(&w, "prompt_encoder", grid, encoder.img_size)?;
        let decoder = MaskDecoder::load(&w, "mask_decoder")?;
        Ok(Sam {
            encoder,
            prompt,
            decoder,
        })
    }

    /// Embeds an RGB image (`rgb` in [0, 1], row-major, 3 channels).
    pub fn embed(&self, rgb: &[f32], width: usize, height: usize) -> Result<Embedding> {
        let (input, resized) = preprocess(rgb, width, height, self.encoder.img_size)?;
        Ok(Embedding {
            tensor: self.encoder.forward(&input)?,
            original: (width, height),
            resized,
        })
    }

    /// The masks for `prompt` (given in the photograph's pixels) on `emb`.
    pub fn predict(&self, emb: &Embedding, prompt: &Prompt, multimask: bool) -> Result<Masks> {
        let s = emb.resized.0 as f32 / emb.original.0 as f32;
        let scaled = Prompt {
            points: prompt
                .points
                .iter()
                .map(|&([x, y], l)| ([x * s, y * s], l))
                .collect(),
            bbox: prompt.bbox.map(|b| b.map(|v| v * s)),
        };
        self.predict_resized(&emb.tensor, &scaled, multimask)
    }

    /// The masks for `prompt` (in the model's input frame) on an image embedding.
    pub fn predict_resized(&self, emb: &Tensor, prompt: &Prompt, multimask: bool) -> Result<Masks> {
        let (sparse, dense) = self.prompt.forward(prompt)?;
        let pe = self.prompt.dense_pe()?;
        let (masks, iou) = self.decoder.forward(emb, &pe, &sparse, &dense, multimask)?;
        let (_, n, h, w) = masks.dims4()?;
        let logits: Vec<Vec<f32>> = (0..n)
            .map(|k| masks.get(0)?.get(k)?.flatten_all()?.to_vec1::<f32>())
            .collect::<candle_core::Result<_>>()?;
        debug_assert_eq!(h, w);
        Ok(Masks {
            side: h,
            logits,
            iou: iou.get(0)?.to_vec1::<f32>()?,
        })
    }

    /// The best mask for `prompt` at the photograph's size (true = object): of the
    /// model's three, the one `choose` scores highest (given each mask and the model's
    /// IoU estimate).
    pub fn segment(
        &self,
        emb: &Embedding,
        prompt: &Prompt,
        mut choose: impl FnMut(&[bool], f32) -> f64,
    ) -> Result<Vec<bool>> {
        let m = self.predict(emb, prompt, true)?;
        let mut best: Option<(f64, Vec<bool>)> = None;
        for (logits, &iou) in m.logits.iter().zip(&m.iou) {
            let mask = mask_to_size(
                logits,
                m.side,
                self.encoder.img_size,
                emb.resized,
                emb.original,
            )
            .into_iter()
            .map(|v| v > 0.0)
            .collect::<Vec<bool>>();
            let score = choose(&mask, iou);
            if best.as_ref().is_none_or(|(b, _)| score > *b) {
                best = Some((score, mask));
            }
        }
        best.map(|(_, m)| m)
            .ok_or_else(|| SamError::Input("the decoder gave no mask".into()))
    }
}
