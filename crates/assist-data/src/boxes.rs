//! Object boxes: the `bbox` of an instance (`{center, size, rotation}`, world coordinates,
//! `rotation` a row-major world-from-box matrix; the format of our `transforms.json`
//! extension), and files of boxes the user gives to override the dataset's or the estimated
//! ones (`assist train --boxes FILE`, written by `assist dataset boxes --json`):
//!
//! ```json
//! {"instances": [{"id": 3, "bbox": {"center": [0, 0, 0.1], "size": [0.2, 0.2, 0.2]}},
//!                {"label": "duck", "bbox": {"center": [..], "size": [..], "rotation": [[..], [..], [..]]}}]}
//! ```
//!
//! An entry names its instance by `id` or by `label` (or both, which must then agree).

use std::path::{Path, PathBuf};

use assist_core::{DMat3, InstanceId, Obb};
use serde_json::{Value, json};

use crate::dataset::checked_rotation;
use crate::error::{DataError, Result};
use crate::json::{Node, read_json};

/// Parses a `bbox` object: `center` and `size` (positive) 3-vectors, optional `rotation`.
pub fn parse_bbox(b: &Node) -> Result<Obb> {
    let size = b.req("size")?;
    let sz = size.vec3()?;
    if sz.min_element() <= 0.0 {
        return Err(size.err(format!("expected positive box sizes, got {sz}")));
    }
    let rotation = match b.get("rotation") {
        Some(r) => checked_rotation(r.mat3_rows()?, b.file, r.path())?,
        None => DMat3::IDENTITY,
    };
    Ok(Obb::new(b.req("center")?.vec3()?, sz, rotation))
}

/// The `bbox` object of a box (the inverse of [`parse_bbox`]).
pub fn bbox_json(b: &Obb) -> Value {
    let r = b.rotation.transpose().to_cols_array_2d();
    json!({
        "center": b.center.to_array(),
        "size": b.size().to_array(),
        "rotation": r,
    })
}

/// Which instance a user box is for.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxOverride {
    pub id: Option<InstanceId>,
    pub label: Option<String>,
    pub bbox: Obb,
    /// The file it came from and the entry (`instances[2]`), for error messages.
    pub file: PathBuf,
    pub entry: String,
}

impl BoxOverride {
    /// Whether this entry names the instance `(id, label)`; an error when it names it by
    /// one and contradicts it by the other.
    pub fn matches(&self, id: InstanceId, label: &str) -> Result<bool> {
        let by_id = self.id.map(|i| i == id);
        let by_label = self.label.as_deref().map(|l| l == label);
        match (by_id, by_label) {
            (Some(true), Some(false)) | (Some(false), Some(true)) => Err(DataError::field(
                &self.file,
                &self.entry,
                format!(
                    "id {} and label {:?} name different instances (instance {id} is {label:?})",
                    self.id.unwrap_or_default(),
                    self.label.as_deref().unwrap_or_default()
                ),
            )),
            (a, b) => Ok(a.or(b).unwrap_or(false)),
        }
    }
}

/// Reads a file of user boxes.
pub fn read_boxes(path: &Path) -> Result<Vec<BoxOverride>> {
    let value = read_json(path)?;
    let root = Node::root(&value, path);
    let mut out: Vec<BoxOverride> = Vec::new();
    for e in root.req("instances")?.items()? {
        let id = match e.get("id") {
            Some(n) => {
                let v = n.u32()?;
                if v == 0 || v > u16::MAX as u32 {
                    return Err(n.err(format!(
                        "expected an instance id in 1..=65535 (0 is the background), got {v}"
                    )));
                }
                Some(v as InstanceId)
            }
            None => None,
        };
        let label = e
            .get("label")
            .map(|l| l.str().map(str::to_string))
            .transpose()?;
        if id.is_none() && label.is_none() {
            return Err(e.err("expected an `id` or a `label` naming the instance"));
        }
        let bbox = parse_bbox(&e.req("bbox")?)?;
        let b = BoxOverride {
            id,
            label,
            bbox,
            file: path.to_path_buf(),
            entry: e.path().to_string(),
        };
        if let Some(prev) = out
            .iter()
            .find(|p| (p.id.is_some() && p.id == b.id) || (p.label.is_some() && p.label == b.label))
        {
            return Err(e.err(format!("names the same instance as {}", prev.entry)));
        }
        out.push(b);
    }
    Ok(out)
}

/// The file [`read_boxes`] reads, for `(id, label, box)` triples.
pub fn boxes_json(boxes: &[(InstanceId, String, Obb)]) -> Value {
    let list: Vec<Value> = boxes
        .iter()
        .map(|(id, label, b)| json!({"id": id, "label": label, "bbox": bbox_json(b)}))
        .collect();
    json!({ "instances": list })
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{DQuat, DVec3};

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn round_trip_and_matching() {
        let dir = std::env::temp_dir().join(format!("assist-boxes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rot = DMat3::from_quat(DQuat::from_rotation_z(0.7));
        let boxes = vec![
            (
                3,
                "duck".to_string(),
                Obb::new(DVec3::new(0.1, -0.2, 0.3), DVec3::new(0.2, 0.3, 0.4), rot),
            ),
            (
                5,
                "mug".to_string(),
                Obb::new(DVec3::ONE, DVec3::ONE, DMat3::IDENTITY),
            ),
        ];
        let text = serde_json::to_string_pretty(&boxes_json(&boxes)).unwrap();
        let p = write(&dir, "boxes.json", &text);
        let read = read_boxes(&p).unwrap();
        assert_eq!(read.len(), 2);
        for ((id, label, b), r) in boxes.iter().zip(&read) {
            assert_eq!(r.id, Some(*id));
            assert_eq!(r.label.as_deref(), Some(label.as_str()));
            assert!((r.bbox.center - b.center).length() < 1e-12);
            assert!((r.bbox.half_size - b.half_size).length() < 1e-12);
            assert!((r.bbox.rotation - b.rotation).abs_diff_eq(DMat3::ZERO, 1e-12));
            assert!(r.matches(*id, label).unwrap());
            assert!(!r.matches(*id + 1, "cow").unwrap());
            assert!(r.matches(*id + 1, label).is_err());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_files_name_the_field() {
        let dir = std::env::temp_dir().join(format!("assist-boxes-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cases = [
            (r#"{"boxes": []}"#, "instances"),
            (
                r#"{"instances": [{"bbox": {"center": [0,0,0], "size": [1,1,1]}}]}"#,
                "instances[0]",
            ),
            (
                r#"{"instances": [{"id": 0, "bbox": {"center": [0,0,0], "size": [1,1,1]}}]}"#,
                "instances[0].id",
            ),
            (
                r#"{"instances": [{"id": 2, "bbox": {"center": [0,0,0], "size": [1,-1,1]}}]}"#,
                "instances[0].bbox.size",
            ),
            (
                r#"{"instances": [{"id": 2, "bbox": {"size": [1,1,1]}}]}"#,
                "instances[0].bbox.center",
            ),
            (
                r#"{"instances": [{"id": 2, "bbox": {"center": [0,0,0], "size": [1,1,1], "rotation": [[2,0,0],[0,1,0],[0,0,1]]}}]}"#,
                "instances[0].bbox.rotation",
            ),
            (
                r#"{"instances": [{"label": "a", "bbox": {"center": [0,0,0], "size": [1,1,1]}}, {"label": "a", "bbox": {"center": [0,0,0], "size": [1,1,1]}}]}"#,
                "instances[1]",
            ),
        ];
        for (i, (text, field)) in cases.iter().enumerate() {
            let p = write(&dir, &format!("b{i}.json"), text);
            let e = read_boxes(&p).unwrap_err().to_string();
            assert!(
                e.contains(&format!("b{i}.json")) && e.contains(field),
                "case {i}: {e}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
