//! Safetensors serialisation of a field (and optionally its occupancy grid): one tensor per
//! parameter group, the config and a format version in the metadata. Loading checks the
//! format, version, every name, dtype and shape, and says exactly what is wrong.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};

use crate::config::FieldConfig;
use crate::error::FieldError;
use crate::field::Field;
use crate::occupancy::OccupancyGrid;
use crate::proposal::{Proposal, ProposalConfig, ProposalField};
use crate::shade::ShadeGrid;

pub const FORMAT: &str = "assist-field";
pub const VERSION: &str = "1";

fn fmt_err(path: &Path, m: impl Into<String>) -> FieldError {
    FieldError::Format {
        path: path.to_path_buf(),
        message: m.into(),
    }
}

fn shape_of(field: &Field, name: &str, len: usize) -> Vec<usize> {
    if let Some(rest) = name.strip_suffix(".weight") {
        let l = if let Some(i) = rest.strip_prefix("density.") {
            field.layout.density[i.parse::<usize>().unwrap_or(0)]
        } else {
            field.layout.color[rest
                .trim_start_matches("color.")
                .parse::<usize>()
                .unwrap_or(0)]
        };
        vec![l.out, l.inp_pad]
    } else if name.starts_with("grid.") {
        vec![len / field.layout.grid.features, field.layout.grid.features]
    } else if name == "appearance" {
        vec![field.config.num_images, field.config.appearance_dim]
    } else {
        vec![len]
    }
}

/// Serialises to bytes.
pub fn to_bytes(field: &Field, occupancy: Option<&OccupancyGrid>) -> Result<Vec<u8>, FieldError> {
    to_bytes_node(field, occupancy, None, None)
}

/// Serialises a node's field to bytes, with the object's shadow grid when it has one
/// (tensor `shade`, `[r, r, r, 3]`, its extent in the metadata) and the proposal field
/// when it has one (tensor `proposal`, its sizes and samples per ray in the metadata).
pub fn to_bytes_node(
    field: &Field,
    occupancy: Option<&OccupancyGrid>,
    shade: Option<&ShadeGrid>,
    proposal: Option<&Proposal>,
) -> Result<Vec<u8>, FieldError> {
    let groups = field.layout.groups(&field.config);
    let mut bufs: Vec<(String, Vec<usize>, Vec<u8>, Dtype)> = Vec::new();
    for (name, start, len) in &groups {
        let bytes: Vec<u8> = field.params[*start..*start + *len]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        bufs.push((name.clone(), shape_of(field, name, *len), bytes, Dtype::F32));
    }
    if !field.anchors.is_empty() {
        let bytes: Vec<u8> = field
            .anchors
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        bufs.push((
            ANCHORS.into(),
            vec![field.anchors.len(), 3],
            bytes,
            Dtype::F32,
        ));
    }
    if let Some(o) = occupancy {
        // A cell still in warm-up, or known to hold a surface, is occupied whatever its
        // estimate: it is saved as never measured (infinite), which loads as occupied.
        let bytes: Vec<u8> = o
            .density
            .iter()
            .enumerate()
            .map(|(c, &d)| if o.warming(c) { f32::INFINITY } else { d })
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let r = o.res as usize;
        bufs.push(("occupancy.density".into(), vec![r, r, r], bytes, Dtype::F32));
    }
    if let Some(g) = shade {
        let bytes: Vec<u8> = g.values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let r = g.res;
        bufs.push(("shade".into(), vec![r, r, r, 3], bytes, Dtype::F32));
    }
    if let Some(p) = proposal {
        let bytes: Vec<u8> = p
            .field
            .params
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let n = p.field.params.len();
        bufs.push(("proposal".into(), vec![n], bytes, Dtype::F32));
    }
    let views: Vec<(String, TensorView)> = bufs
        .iter()
        .map(|(n, s, b, d)| {
            (
                n.clone(),
                TensorView::new(*d, s.clone(), b).expect("shape matches data"),
            )
        })
        .collect();
    let mut meta = HashMap::new();
    meta.insert("format".to_string(), FORMAT.to_string());
    meta.insert("version".to_string(), VERSION.to_string());
    meta.insert(
        "config".to_string(),
        serde_json::to_string(&field.config).expect("config serialises"),
    );
    if let Some(o) = occupancy {
        meta.insert(
            "occupancy".to_string(),
            serde_json::json!({"threshold": o.threshold, "decay": o.decay}).to_string(),
        );
    }
    if let Some(g) = shade {
        meta.insert(
            "shade".to_string(),
            serde_json::json!({"extent": g.extent}).to_string(),
        );
    }
    if let Some(p) = proposal {
        meta.insert(
            "proposal".to_string(),
            serde_json::json!({"config": p.field.config, "samples": p.samples}).to_string(),
        );
    }
    let bytes = safetensors::serialize(views, Some(meta)).map_err(|e| FieldError::Format {
        path: "(memory)".into(),
        message: e.to_string(),
    })?;
    Ok(canonical_header(bytes))
}

/// Rewrites the safetensors header with sorted keys: the writer emits `__metadata__` in
/// hash-map order, which differs between runs, so the same field would give different
/// bytes. Offsets are relative to the data, so only the header changes; it stays padded
/// with spaces to a multiple of 8 bytes as the format asks.
fn canonical_header(bytes: Vec<u8>) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8-byte length")) as usize;
    let header: serde_json::Value =
        serde_json::from_slice(&bytes[8..8 + n]).expect("safetensors wrote valid JSON");
    // serde_json's map is ordered by key (no `preserve_order`), so this output is sorted.
    let mut text = serde_json::to_string(&header).expect("JSON value serialises");
    while !(8 + text.len()).is_multiple_of(8) {
        text.push(' ');
    }
    let mut out = Vec::with_capacity(8 + text.len() + bytes.len() - 8 - n);
    out.extend_from_slice(&(text.len() as u64).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out.extend_from_slice(&bytes[8 + n..]);
    out
}

/// Writes atomically (temporary file beside it, then rename).
pub fn save(
    path: &Path,
    field: &Field,
    occupancy: Option<&OccupancyGrid>,
) -> Result<(), FieldError> {
    let bytes = to_bytes(field, occupancy)?;
    let tmp = path.with_file_name(format!(
        ".{}.tmp-{}",
        path.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    let io = |e| FieldError::Io {
        path: path.to_path_buf(),
        source: e,
    };
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        FieldError::Io {
            path: path.to_path_buf(),
            source: e,
        }
    })
}

pub fn load(path: &Path) -> Result<(Field, Option<OccupancyGrid>), FieldError> {
    let l = load_node(path)?;
    Ok((l.field, l.occupancy))
}

/// A node's field with what its file holds beside it.
#[derive(Debug)]
pub struct Loaded {
    pub field: Field,
    pub occupancy: Option<OccupancyGrid>,
    pub shade: Option<ShadeGrid>,
    pub proposal: Option<Proposal>,
}

/// Reads a node's field with its occupancy grid, shadow grid and proposal (each when the
/// file has one).
pub fn load_node(path: &Path) -> Result<Loaded, FieldError> {
    let bytes = std::fs::read(path).map_err(|e| FieldError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    from_bytes_node(path, &bytes)
}

/// Parses and validates; `path` names the file in errors.
pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<(Field, Option<OccupancyGrid>), FieldError> {
    let l = from_bytes_node(path, bytes)?;
    Ok((l.field, l.occupancy))
}

/// The file's metadata, checked to be an assist field of this build's version.
type Meta = std::collections::HashMap<String, String>;

/// Parses and validates, shadow grid and proposal included; `path` names the file in
/// errors.
pub fn from_bytes_node(path: &Path, bytes: &[u8]) -> Result<Loaded, FieldError> {
    let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| fmt_err(path, format!("not a valid safetensors file: {e}")))?;
    let st = safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| fmt_err(path, format!("not a valid safetensors file: {e}")))?;
    let md = meta.metadata().clone().unwrap_or_default();
    let cfg = read_config(path, &md, bytes.len())?;
    let mut field = Field::new(cfg, 0).map_err(|e| fmt_err(path, e.to_string()))?;
    read_params(path, &st, &mut field)?;
    field.anchors = read_anchors(path, &st, &field)?;
    let occupancy = read_occupancy(path, &st, &md)?;
    let shade = read_shade(path, &st, &md)?;
    let proposal = read_proposal(path, &st, &md)?;
    Ok(Loaded {
        field,
        occupancy,
        shade,
        proposal,
    })
}

/// The field's configuration from the metadata, after its format and version; refused
/// when the parameters it asks for cannot be in a file of `file_len` bytes.
fn read_config(path: &Path, md: &Meta, file_len: usize) -> Result<FieldConfig, FieldError> {
    match md.get("format").map(String::as_str) {
        Some(FORMAT) => {}
        other => {
            return Err(fmt_err(
                path,
                format!("metadata.format: expected {FORMAT:?}, got {other:?}"),
            ));
        }
    }
    match md.get("version").map(String::as_str) {
        Some(VERSION) => {}
        other => {
            return Err(fmt_err(
                path,
                format!(
                    "metadata.version: expected {VERSION:?} (this build reads version {VERSION}), got {other:?}"
                ),
            ));
        }
    }
    let cfg_text = md
        .get("config")
        .ok_or_else(|| fmt_err(path, "metadata.config: missing"))?;
    let cfg: FieldConfig = serde_json::from_str(cfg_text)
        .map_err(|e| fmt_err(path, format!("metadata.config: {e}")))?;
    cfg.validate()
        .map_err(|e| fmt_err(path, format!("metadata.config: {e}")))?;
    // The parameters the configuration asks for must be in the file before anything is
    // allocated for them (a forged config could otherwise ask for gigabytes).
    let want = crate::field::ParamLayout::new(&cfg).total as u64 * 4;
    if want > file_len as u64 {
        return Err(fmt_err(
            path,
            format!(
                "metadata.config: asks for {want} bytes of parameters, but the file holds {file_len}"
            ),
        ));
    }
    Ok(cfg)
}

/// Fills the field's parameters from its tensors: every one present, F32, of the
/// shape the configuration gives, finite; no tensor that is not part of a field.
fn read_params(
    path: &Path,
    st: &safetensors::SafeTensors,
    field: &mut Field,
) -> Result<(), FieldError> {
    let groups = field.layout.groups(&field.config);
    let mut expected: Vec<&str> = groups.iter().map(|g| g.0.as_str()).collect();
    expected.push("occupancy.density");
    expected.push("shade");
    expected.push("proposal");
    expected.push(ANCHORS);
    for name in st.names() {
        if !expected.contains(&&*name.to_string()) {
            return Err(fmt_err(
                path,
                format!(
                    "tensor {name:?}: not part of an assist field (expected {})",
                    groups
                        .iter()
                        .map(|g| g.0.clone())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
    }
    for (name, start, len) in &groups {
        let t = st
            .tensor(name)
            .map_err(|_| fmt_err(path, format!("tensor {name:?}: missing")))?;
        let shape = shape_of(field, name, *len);
        if t.dtype() != Dtype::F32 {
            return Err(fmt_err(
                path,
                format!("tensor {name:?}: dtype {:?}, expected F32", t.dtype()),
            ));
        }
        if t.shape() != shape.as_slice() {
            return Err(fmt_err(
                path,
                format!("tensor {name:?}: shape {:?}, expected {shape:?}", t.shape()),
            ));
        }
        for (dst, src) in field.params[*start..*start + *len]
            .iter_mut()
            .zip(t.data().chunks_exact(4))
        {
            *dst = f32::from_le_bytes([src[0], src[1], src[2], src[3]]);
        }
        if let Some(bad) = field.params[*start..*start + *len]
            .iter()
            .position(|v| !v.is_finite())
        {
            return Err(fmt_err(
                path,
                format!("tensor {name:?}: element {bad} is not finite"),
            ));
        }
    }
    Ok(())
}

/// Tensor of [`Field::anchors`]: `[num_images, 3]`, absent in fields without them.
const ANCHORS: &str = "appearance.anchors";

/// Where each appearance code's view was taken from, when the file says: one finite
/// point per code.
fn read_anchors(
    path: &Path,
    st: &safetensors::SafeTensors,
    field: &Field,
) -> Result<Vec<[f32; 3]>, FieldError> {
    let Ok(t) = st.tensor(ANCHORS) else {
        return Ok(Vec::new());
    };
    let n = field.config.num_images;
    if t.dtype() != Dtype::F32 || t.shape() != [n, 3] || n == 0 {
        return Err(fmt_err(
            path,
            format!(
                "tensor {ANCHORS:?}: {:?} {:?}, expected F32 [{n}, 3] (one point per appearance code)",
                t.dtype(),
                t.shape()
            ),
        ));
    }
    let v = finite_f32s(path, ANCHORS, &t)?;
    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Tensor `name`'s values (F32, little-endian), each one finite.
fn finite_f32s(path: &Path, name: &str, t: &TensorView) -> Result<Vec<f32>, FieldError> {
    let v: Vec<f32> = t
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if let Some(bad) = v.iter().position(|x| !x.is_finite()) {
        return Err(fmt_err(
            path,
            format!("tensor {name:?}: element {bad} is not finite"),
        ));
    }
    Ok(v)
}

/// The occupancy grid, when the file has one.
fn read_occupancy(
    path: &Path,
    st: &safetensors::SafeTensors,
    md: &Meta,
) -> Result<Option<OccupancyGrid>, FieldError> {
    Ok(match st.tensor("occupancy.density") {
        Ok(t) => {
            let s = t.shape();
            if t.dtype() != Dtype::F32 || s.len() != 3 || s[0] != s[1] || s[1] != s[2] || s[0] == 0
            {
                return Err(fmt_err(
                    path,
                    format!(
                        "tensor \"occupancy.density\": expected F32 of shape [r, r, r], got {:?} {s:?}",
                        t.dtype()
                    ),
                ));
            }
            let mut g = OccupancyGrid::new(s[0] as u32);
            if let Some(o) = md
                .get("occupancy")
                .and_then(|t| serde_json::from_str::<serde_json::Value>(t).ok())
            {
                g.threshold = o["threshold"].as_f64().unwrap_or(g.threshold as f64) as f32;
                g.decay = o["decay"].as_f64().unwrap_or(g.decay as f64) as f32;
            }
            let d: Vec<f32> = t
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            g.density = vec![f32::INFINITY; d.len()];
            g.update_from(&d);
            g.density = d;
            Some(g)
        }
        Err(_) => None,
    })
}

/// The shadow grid, when the file has one.
fn read_shade(
    path: &Path,
    st: &safetensors::SafeTensors,
    md: &Meta,
) -> Result<Option<ShadeGrid>, FieldError> {
    Ok(match st.tensor("shade") {
        Ok(t) => {
            // `[r, r, r, 3]`: a factor per colour channel; `[r, r, r]`: one factor for all
            // three (files written before the factors had colour).
            let s = t.shape();
            let cube = s.len() >= 3 && s[0] == s[1] && s[1] == s[2];
            let grey = s.len() == 3;
            if t.dtype() != Dtype::F32 || !cube || !(grey || (s.len() == 4 && s[3] == 3)) {
                return Err(fmt_err(
                    path,
                    format!(
                        "tensor \"shade\": expected F32 of shape [r, r, r, 3] (or [r, r, r]), \
                         got {:?} {s:?}",
                        t.dtype()
                    ),
                ));
            }
            let extent = md
                .get("shade")
                .and_then(|t| serde_json::from_str::<serde_json::Value>(t).ok())
                .and_then(|v| v["extent"].as_f64())
                .ok_or_else(|| fmt_err(path, "metadata.shade.extent: missing"))?
                as f32;
            let values: Vec<f32> = t
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let g = if grey {
                ShadeGrid::from_grey(s[0], extent, &values)
            } else {
                ShadeGrid {
                    res: s[0],
                    extent,
                    values,
                }
            };
            g.validate()
                .map_err(|e| fmt_err(path, format!("tensor \"shade\": {e}")))?;
            Some(g)
        }
        Err(_) => None,
    })
}

/// The proposal field, when the file has one: its sizes and samples per ray from the
/// metadata, its parameters of the count they give, every one finite.
fn read_proposal(
    path: &Path,
    st: &safetensors::SafeTensors,
    md: &Meta,
) -> Result<Option<Proposal>, FieldError> {
    let Ok(t) = st.tensor("proposal") else {
        return Ok(None);
    };
    let meta: serde_json::Value = md
        .get("proposal")
        .and_then(|t| serde_json::from_str(t).ok())
        .ok_or_else(|| fmt_err(path, "metadata.proposal: missing or not JSON"))?;
    let config: ProposalConfig = serde_json::from_value(meta["config"].clone())
        .map_err(|e| fmt_err(path, format!("metadata.proposal.config: {e}")))?;
    let samples = meta["samples"]
        .as_u64()
        .filter(|&n| (1..=1024).contains(&n))
        .ok_or_else(|| fmt_err(path, "metadata.proposal.samples: expected 1 to 1024"))?
        as usize;
    if t.dtype() != Dtype::F32 || t.shape().len() != 1 {
        return Err(fmt_err(
            path,
            format!(
                "tensor \"proposal\": expected F32 of shape [n], got {:?} {:?}",
                t.dtype(),
                t.shape()
            ),
        ));
    }
    let params = finite_f32s(path, "proposal", &t)?;
    let field = ProposalField::with_params(config, params)
        .map_err(|e| fmt_err(path, format!("tensor \"proposal\": {e}")))?;
    Ok(Some(Proposal { field, samples }))
}
