//! JSON reading with field paths: the first stage of two-stage parsing (raw JSON → typed,
//! validated values). Every accessor knows the path to the value (`frames[3].fl_x`) so that
//! errors name the field. Non-standard `NaN`/`Infinity` tokens (written by Python's `json`)
//! are accepted by the tokenizer and then reported as non-finite at their field.

use std::path::{Path, PathBuf};

use assist_core::glam::DVec4;
use assist_core::{DMat3, DMat4, DVec3};
use serde_json::Value;

use crate::error::{DataError, Result};

const NONFINITE_TAG: &str = "\u{0}assist-nonfinite:";

/// Reads and parses a JSON file.
pub fn read_json(path: &Path) -> Result<Value> {
    let text = read_text(path)?;
    parse_json(path, &text)
}

/// Reads a UTF-8 text file (an error names the line and byte of the first bad byte).
pub fn read_text(path: &Path) -> Result<String> {
    Ok(assist_fs::read_text(path)?)
}

pub fn parse_json(path: &Path, text: &str) -> Result<Value> {
    let clean = replace_nonfinite_tokens(text);
    serde_json::from_str(&clean).map_err(|e| DataError::Json {
        path: path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    })
}

/// Replaces bare `NaN`, `Infinity`, `-Infinity` (outside strings) by tagged strings.
fn replace_nonfinite_tokens(text: &str) -> std::borrow::Cow<'_, str> {
    if !text.contains("NaN") && !text.contains("Infinity") {
        return std::borrow::Cow::Borrowed(text);
    }
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len() + 64);
    let mut i = 0;
    let mut in_str = false;
    let mut last = 0;
    while i < b.len() {
        let c = b[i];
        if in_str {
            if c == b'\\' {
                i += 2;
                continue;
            }
            if c == b'"' {
                in_str = false;
            }
            i += 1;
            continue;
        }
        if c == b'"' {
            in_str = true;
            i += 1;
            continue;
        }
        let mut matched = false;
        for tok in ["-Infinity", "Infinity", "-NaN", "NaN"] {
            if b[i..].starts_with(tok.as_bytes()) {
                out.push_str(&text[last..i]);
                out.push_str("\"\\u0000assist-nonfinite:");
                out.push_str(tok);
                out.push('"');
                i += tok.len();
                last = i;
                matched = true;
                break;
            }
        }
        if !matched {
            i += 1;
        }
    }
    if last < text.len() {
        out.push_str(&text[last.min(text.len())..]);
    }
    std::borrow::Cow::Owned(out)
}

/// A JSON value together with the file and the path that lead to it.
#[derive(Clone, Debug)]
pub struct Node<'a> {
    pub value: &'a Value,
    pub file: &'a Path,
    path: String,
}

impl<'a> Node<'a> {
    pub fn root(value: &'a Value, file: &'a Path) -> Self {
        Node {
            value,
            file,
            path: String::new(),
        }
    }
    pub fn path(&self) -> &str {
        if self.path.is_empty() {
            "(top level)"
        } else {
            &self.path
        }
    }
    fn child_path(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }
    pub fn err(&self, message: impl Into<String>) -> DataError {
        DataError::field(self.file, self.path(), message)
    }
    pub fn err_at(&self, key: &str, message: impl Into<String>) -> DataError {
        DataError::field(self.file, self.child_path(key), message)
    }
    pub fn file_buf(&self) -> PathBuf {
        self.file.to_path_buf()
    }

    /// A child of an object, if present and not null.
    pub fn get(&self, key: &str) -> Option<Node<'a>> {
        let v = self.value.as_object()?.get(key)?;
        if v.is_null() {
            return None;
        }
        Some(Node {
            value: v,
            file: self.file,
            path: self.child_path(key),
        })
    }
    pub fn req(&self, key: &str) -> Result<Node<'a>> {
        if !self.value.is_object() {
            return Err(self.err(format!("expected an object, got {}", kind(self.value))));
        }
        self.get(key)
            .ok_or_else(|| self.err_at(key, "missing; this field is required"))
    }
    pub fn items(&self) -> Result<Vec<Node<'a>>> {
        let arr = self
            .value
            .as_array()
            .ok_or_else(|| self.err(format!("expected an array, got {}", kind(self.value))))?;
        Ok(arr
            .iter()
            .enumerate()
            .map(|(i, v)| Node {
                value: v,
                file: self.file,
                path: format!("{}[{i}]", self.path),
            })
            .collect())
    }
    pub fn f64(&self) -> Result<f64> {
        match self.value {
            Value::Number(n) => n.as_f64().ok_or_else(|| self.err("expected a number")),
            Value::String(s) if s.starts_with(NONFINITE_TAG) => Err(self.err(format!(
                "expected a finite number, got {}",
                &s[NONFINITE_TAG.len()..]
            ))),
            v => Err(self.err(format!("expected a number, got {}", kind(v)))),
        }
        .and_then(|x| {
            if x.is_finite() {
                Ok(x)
            } else {
                Err(self.err(format!("expected a finite number, got {x}")))
            }
        })
    }
    pub fn positive_f64(&self) -> Result<f64> {
        let v = self.f64()?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(format!("expected a number > 0, got {v}")))
        }
    }
    pub fn u32(&self) -> Result<u32> {
        let v = self.f64()?;
        if v >= 0.0 && v.fract() == 0.0 && v <= u32::MAX as f64 {
            Ok(v as u32)
        } else {
            Err(self.err(format!("expected a non-negative whole number, got {v}")))
        }
    }
    pub fn str(&self) -> Result<&'a str> {
        match self.value {
            Value::String(s) if !s.starts_with(NONFINITE_TAG) => Ok(s.as_str()),
            v => Err(self.err(format!("expected a string, got {}", kind(v)))),
        }
    }
    pub fn f64s(&self, n: usize) -> Result<Vec<f64>> {
        let items = self.items()?;
        if items.len() != n {
            return Err(self.err(format!("expected {n} numbers, got {}", items.len())));
        }
        items.iter().map(|c| c.f64()).collect()
    }
    pub fn vec3(&self) -> Result<DVec3> {
        let v = self.f64s(3)?;
        Ok(DVec3::new(v[0], v[1], v[2]))
    }
    /// A row-major matrix of `rows` × `cols` numbers.
    pub fn matrix(&self, rows: usize, cols: usize) -> Result<Vec<Vec<f64>>> {
        let items = self.items()?;
        if items.len() != rows {
            return Err(self.err(format!(
                "expected {rows} rows of {cols} numbers, got {} rows",
                items.len()
            )));
        }
        items.iter().map(|r| r.f64s(cols)).collect()
    }
    /// A row-major 3×3 matrix.
    pub fn mat3_rows(&self) -> Result<DMat3> {
        let m = self.matrix(3, 3)?;
        Ok(DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        ))
    }
    /// A row-major 4×4 (or 3×4, completed with `0 0 0 1`) matrix.
    pub fn mat4_rows(&self) -> Result<DMat4> {
        let n = self.items()?.len();
        let m = if n == 3 {
            self.matrix(3, 4)?
        } else {
            self.matrix(4, 4)?
        };
        let row = |r: usize| {
            if r < m.len() {
                DVec4::new(m[r][0], m[r][1], m[r][2], m[r][3])
            } else {
                DVec4::new(0.0, 0.0, 0.0, 1.0)
            }
        };
        Ok(DMat4::from_cols(row(0), row(1), row(2), row(3)).transpose())
    }
}

fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(s) if s.starts_with(NONFINITE_TAG) => "a non-finite number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_is_reported_at_its_field() {
        let p = Path::new("t.json");
        let v = parse_json(
            p,
            r#"{"a": {"m": [[1, NaN], [0, 1]]}, "s": "NaN in a string"}"#,
        )
        .unwrap();
        let root = Node::root(&v, p);
        let a = root.req("a").unwrap();
        let m = a.req("m").unwrap();
        let e = m.matrix(2, 2).unwrap_err().to_string();
        assert!(e.contains("a.m[0][1]") && e.contains("NaN"), "{e}");
        assert_eq!(root.req("s").unwrap().str().unwrap(), "NaN in a string");
    }

    #[test]
    fn malformed_json_names_line() {
        let e = parse_json(Path::new("x.json"), "{\n \"a\": [1,\n}")
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.json") && e.contains("line 3"), "{e}");
    }

    #[test]
    fn missing_and_wrong_type() {
        let p = Path::new("t.json");
        let v = parse_json(p, r#"{"frames": [{"w": "wide"}]}"#).unwrap();
        let f = Node::root(&v, p).req("frames").unwrap().items().unwrap();
        let e = f[0].req("w").unwrap().u32().unwrap_err().to_string();
        assert!(
            e.contains("frames[0].w") && e.contains("expected a number"),
            "{e}"
        );
        let e = f[0].req("h").unwrap_err().to_string();
        assert!(e.contains("frames[0].h") && e.contains("missing"), "{e}");
    }
}
