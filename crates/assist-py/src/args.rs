//! Reading Python arguments the way the library's errors read: a whole number out of its
//! range, a NaN deep in a dict or a value JSON cannot hold raise `AssistError` naming the
//! argument and the field, not pyo3's `OverflowError` or a JSON parser's line and column.

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use crate::err;

/// The range of a whole-number argument type, for messages.
pub(crate) trait WholeRange: TryFrom<i64> {
    const MAX: u64;
}

macro_rules! whole_range {
    ($($t:ty),*) => {$(
        impl WholeRange for $t {
            const MAX: u64 = <$t>::MAX as u64;
        }
    )*};
}
whole_range!(u16, u32, u64, usize);

/// A whole-number argument as Python gave it: the value, or the text of an int beyond
/// 64 bits. Anything but an int raises `TypeError` naming the argument (pyo3 adds it).
#[derive(Debug, Clone)]
pub(crate) struct Whole(Result<i64, String>);

impl Whole {
    /// A default value in a signature.
    pub(crate) const fn of(n: i64) -> Self {
        Whole(Ok(n))
    }

    /// The value as `T`, or `AssistError` naming `what` with the range expected.
    pub(crate) fn get<T: WholeRange>(&self, what: &str) -> PyResult<T> {
        let got = match &self.0 {
            Ok(n) => match T::try_from(*n) {
                Ok(v) => return Ok(v),
                Err(_) => n.to_string(),
            },
            Err(text) => text.clone(),
        };
        Err(err(format!(
            "{what}: expected a whole number from 0 to {}, got {got}",
            T::MAX
        )))
    }
}

impl<'a, 'py> FromPyObject<'a, 'py> for Whole {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if obj.is_instance_of::<PyBool>() || !obj.is_instance_of::<PyInt>() {
            return Err(PyTypeError::new_err(format!(
                "expected a whole number (int), got {}",
                type_name(&obj)
            )));
        }
        Ok(Whole(obj.extract::<i64>().map_err(|_| {
            obj.str().map(|s| s.to_string()).unwrap_or_default()
        })))
    }
}

/// [`Whole::get`] for an optional argument.
pub(crate) fn whole_opt<T: WholeRange>(what: &str, v: Option<Whole>) -> PyResult<Option<T>> {
    v.map(|v| v.get(what)).transpose()
}

fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// Python objects → a JSON value: dicts with str keys, lists, tuples, str, int, float,
/// bool, None, numpy scalars and arrays (through `tolist()`). `path` names the value in
/// errors (`spec.cameras.jitter_m`, `actions[2].config.vector[0]`).
pub(crate) fn to_json(v: &Bound<'_, PyAny>, path: &str) -> PyResult<serde_json::Value> {
    use serde_json::Value;
    if v.is_none() {
        return Ok(Value::Null);
    }
    if let Ok(b) = v.cast::<PyBool>() {
        return Ok(Value::Bool(b.is_true()));
    }
    if v.is_instance_of::<PyInt>() {
        if let Ok(n) = v.extract::<i64>() {
            return Ok(n.into());
        }
        if let Ok(n) = v.extract::<u64>() {
            return Ok(n.into());
        }
        return Err(err(format!(
            "{path}: the integer {} is too large",
            v.str()?
        )));
    }
    if v.is_instance_of::<PyFloat>() {
        let f: f64 = v.extract()?;
        return serde_json::Number::from_f64(f)
            .map(Value::Number)
            .ok_or_else(|| err(format!("{path}: expected a finite number, got {f}")));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(Value::String(s.to_string()));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut m = serde_json::Map::new();
        for (k, x) in d.iter() {
            let Ok(k) = k.extract::<String>() else {
                return Err(err(format!(
                    "{path}: expected str keys, got a key of type {}",
                    type_name(&k)
                )));
            };
            let inner = to_json(&x, &format!("{path}.{k}"))?;
            m.insert(k, inner);
        }
        return Ok(Value::Object(m));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        let mut out = Vec::new();
        for (i, x) in v.try_iter()?.enumerate() {
            out.push(to_json(&x?, &format!("{path}[{i}]"))?);
        }
        return Ok(Value::Array(out));
    }
    // numpy scalars and arrays: as the Python values they hold.
    if v.hasattr("tolist")? {
        let plain = v.call_method0("tolist")?;
        if !plain.is(v) {
            return to_json(&plain, path);
        }
    }
    Err(err(format!(
        "{path}: expected a number, str, bool, None, list or dict, got {}",
        type_name(v)
    )))
}
