//! `assist.Clip`: the CLIP model from weights on disk — config, tokenizer, text and image
//! embeddings as numpy arrays.

use super::*;

/// A CLIP model from weights on disk (see `assist embed --help` for the files):
/// `Clip(path=None)`, `None` meaning the `ASSIST_CLIP` environment variable.
#[pyclass(module = "assist", frozen)]
pub(crate) struct Clip {
    inner: std::sync::Arc<assist_session::clip::Clip>,
}

pub(crate) fn rows_to_array<'py>(
    py: Python<'py>,
    rows: Vec<Vec<f32>>,
    dim: usize,
    normalize: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let n = rows.len();
    let flat: Vec<f32> = rows
        .into_iter()
        .flat_map(|r| {
            if normalize {
                assist_session::clip::normalize(&r)
            } else {
                r
            }
        })
        .collect();
    Ok(PyArray1::from_vec(py, flat).reshape([n, dim])?.into_any())
}

#[pymethods]
impl Clip {
    #[new]
    #[pyo3(signature = (path=None))]
    fn new(py: Python<'_>, path: Option<PathBuf>) -> PyResult<Self> {
        let clip = py
            .detach(move || match path {
                Some(p) => Some(assist_session::clip::Clip::load(&p)),
                None => assist_session::clip::Clip::from_env(),
            })
            .ok_or_else(|| {
                err("no CLIP weights: pass a path or set ASSIST_CLIP to a folder holding them")
            })?
            .map_err(err)?;
        Ok(Clip {
            inner: std::sync::Arc::new(clip),
        })
    }

    /// Sizes, activation, normalisation and where the files came from.
    #[getter]
    fn config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.config();
        let f = &self.inner.files;
        to_py(
            py,
            &serde_json::json!({
                "embed_dim": c.embed_dim,
                "image_size": c.vision.image_size,
                "patch_size": c.vision.patch_size,
                "vision_width": c.vision.width,
                "vision_layers": c.vision.layers,
                "vision_heads": c.vision.heads,
                "context_length": c.text.context_length,
                "vocab_size": c.text.vocab_size,
                "text_width": c.text.width,
                "text_layers": c.text.layers,
                "text_heads": c.text.heads,
                "quick_gelu": c.activation == assist_session::clip::Activation::QuickGelu,
                "mean": c.mean,
                "std": c.std,
                "logit_scale": self.inner.logit_scale(),
                "weights": f.weights,
                "vocab": f.vocab,
                "layout": format!("{:?}", f.layout),
            }),
        )
    }

    /// The token ids of `text` (start, BPE tokens, end, zero padding to the context).
    fn tokenize<'py>(&self, py: Python<'py>, text: &str) -> Bound<'py, PyArray1<i64>> {
        let t: Vec<i64> = self
            .inner
            .tokenizer()
            .tokenize(text)
            .into_iter()
            .map(i64::from)
            .collect();
        PyArray1::from_vec(py, t)
    }

    /// Text features, `len(texts) × embed_dim` float32 (unit length if `normalize`).
    #[pyo3(signature = (texts, normalize=false))]
    fn encode_text<'py>(
        &self,
        py: Python<'py>,
        texts: Vec<String>,
        normalize: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.clone();
        let rows = py
            .detach(move || {
                let t: Vec<&str> = texts.iter().map(String::as_str).collect();
                c.text_features(&t)
            })
            .map_err(err)?;
        rows_to_array(py, rows, self.inner.config().embed_dim, normalize)
    }

    /// Image features, `n × embed_dim` float32 (unit length if `normalize`). `images`:
    /// uint8 RGB, `H×W×3` or `n×H×W×3` (resized, centre-cropped and normalised as
    /// open_clip's evaluation transform), or float32 `n×3×S×S` already preprocessed.
    #[pyo3(signature = (images, normalize=false))]
    fn encode_image<'py>(
        &self,
        py: Python<'py>,
        images: &Bound<'py, PyAny>,
        normalize: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let c = self.inner.clone();
        let s = c.config().vision.image_size;
        let rows = if let Ok(a) = images.extract::<PyReadonlyArrayDyn<'_, u8>>() {
            let shape = a.shape().to_vec();
            let (n, h, w) = match shape[..] {
                [h, w, 3] => (1, h, w),
                [n, h, w, 3] => (n, h, w),
                _ => {
                    return Err(err(format!(
                        "images: expected H×W×3 or n×H×W×3 uint8, got shape {shape:?}"
                    )));
                }
            };
            let data = a.as_slice().map_err(err)?.to_vec();
            py.detach(move || {
                let imgs: Vec<image::RgbImage> = data
                    .chunks(h * w * 3)
                    .take(n)
                    .map(|px| {
                        image::RgbImage::from_raw(w as u32, h as u32, px.to_vec())
                            .expect("a full image")
                    })
                    .collect();
                c.embed_images(&imgs)
            })
        } else if let Ok(a) = images.extract::<PyReadonlyArrayDyn<'_, f32>>() {
            let shape = a.shape().to_vec();
            if !matches!(shape[..], [_, 3, h, w] if h == s && w == s) {
                return Err(err(format!(
                    "images: expected float32 n×3×{s}×{s}, got shape {shape:?}"
                )));
            }
            let data = a.as_slice().map_err(err)?.to_vec();
            py.detach(move || {
                let px: Vec<Vec<f32>> = data.chunks(3 * s * s).map(<[f32]>::to_vec).collect();
                c.image_features(&px)
            })
        } else {
            return Err(err(
                "images: expected a numpy array, uint8 H×W×3 / n×H×W×3 or float32 n×3×S×S",
            ));
        }
        .map_err(err)?;
        rows_to_array(py, rows, self.inner.config().embed_dim, normalize)
    }
}
