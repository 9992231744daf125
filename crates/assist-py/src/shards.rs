//! A generation run written to a folder from Python, one shard at a time, as
//! `assist generate --shard i/n` does — what `assist.distributed` runs in each Ray task —
//! with `merge` and `status` beside it.

use super::*;
use assist_generate::{CocoMasks, Generator, RunOptions, Shard, shards};

/// A spec from a path (TOML/JSON) or a dict of the same fields, with `seed` and `count`
/// overriding its own, checked.
pub(crate) fn load_spec(
    spec: &Bound<'_, PyAny>,
    seed: Option<Whole>,
    count: Option<Whole>,
) -> PyResult<assist_generate::Spec> {
    let seed: Option<u64> = whole_opt("seed", seed)?;
    let count: Option<u64> = whole_opt("count", count)?;
    let (mut spec, name) = if let Ok(p) = spec.extract::<PathBuf>() {
        (assist_generate::Spec::load(&p).map_err(err)?, p)
    } else {
        let v = from_py(spec, "spec")?;
        let s: assist_generate::Spec = crate::from_value(v, "spec")?;
        (s, PathBuf::from("spec"))
    };
    if let Some(s) = seed {
        spec.seed = s;
    }
    if let Some(c) = count {
        spec.count = c;
    }
    spec.check(&name).map_err(err)?;
    Ok(spec)
}

fn coco_masks(m: &str) -> PyResult<CocoMasks> {
    match m {
        "polygon" => Ok(CocoMasks::Polygon),
        "rle" => Ok(CocoMasks::Rle),
        _ => Err(err(format!(
            "coco_masks: expected polygon or rle, got {m:?}"
        ))),
    }
}

/// Makes shard `shard` (`"i/n"`, 0-based; default: every sample) of the run `spec`
/// describes into the folder `out`, as `assist generate --spec … --out … --shard i/n`
/// does: the same files, a rerun remakes only what does not hold, a complete shard does
/// nothing (without loading a scene), and a whole run (`"0/1"`) merges at its end;
/// `device` is where the fields are queried ("cpu", "gpu" or "auto", as `--device`).
/// Returns the run's summary (`made`, `skipped`, `seconds`, `complete`, `record`, …).
#[pyfunction]
#[pyo3(signature = (spec, out, shard="0/1", seed=None, count=None, force=false, coco_masks="polygon", device="cpu"))]
pub(crate) fn generate_shard<'py>(
    py: Python<'py>,
    spec: &Bound<'py, PyAny>,
    out: PathBuf,
    shard: &str,
    seed: Option<Whole>,
    count: Option<Whole>,
    force: bool,
    coco_masks: &str,
    device: &str,
) -> PyResult<Bound<'py, PyAny>> {
    device.parse::<assist_gpu::DeviceChoice>().map_err(err)?;
    let spec = load_spec(spec, seed, count)?;
    let shard = Shard::parse(shard).map_err(|m| err(format!("shard: {m}")))?;
    let masks = self::coco_masks(coco_masks)?;
    assist_fs::check_kind(&out, assist_fs::Kind::Generated).map_err(err)?;
    let record = shards::record_path(&out, shard);
    let done = match force {
        true => None,
        false => py
            .detach(|| shards::rerun_if_complete(&out, &spec, shard, masks))
            .map_err(err)?,
    };
    let summary = match done {
        // A complete shard does nothing: no scene loaded, no device opened.
        Some(done) => serde_json::json!({
            "out": out, "shard": format!("{}/{}", shard.index, shard.count),
            "made": 0, "skipped": done.owned, "seconds": 0.0, "merged": done.merged,
        }),
        None => {
            let gpu = crate::device::open(py, device)?;
            let backend = crate::device::field_backend(&gpu);
            let s = py
                .detach(|| -> assist_generate::Result<_> {
                    let g = Generator::prepare_on(spec, backend, &mut ())?;
                    let opts = RunOptions {
                        out: out.clone(),
                        shard,
                        dry_run: false,
                        force,
                        coco_masks: masks,
                    };
                    g.run(&opts, |_| {})
                })
                .map_err(err)?;
            crate::device::report(py, &gpu)?;
            serde_json::to_value(s).expect("a summary serialises")
        }
    };
    let mut summary = summary;
    summary["complete"] = serde_json::json!(true);
    summary["record"] = serde_json::json!(record);
    to_py(py, &summary)
}

/// Joins the shards' samples in `out` into the COCO files and `index.json`, as `assist
/// generate merge` does; refuses shards that do not hold, naming them.
#[pyfunction]
#[pyo3(signature = (out, partial=false, coco_masks="polygon"))]
pub(crate) fn merge<'py>(
    py: Python<'py>,
    out: PathBuf,
    partial: bool,
    coco_masks: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let masks = self::coco_masks(coco_masks)?;
    let m = py
        .detach(|| assist_generate::merge(&out, partial, masks))
        .map_err(err)?;
    to_py(py, &m)
}

/// Which shards of the run in `out` are complete, partial, missing or another run's, as
/// `assist generate status --json` prints it (`shards`: the n of `i/n`, default the
/// completion records'; `hashes`: check every file's content).
#[pyfunction]
#[pyo3(signature = (out, shards=None, hashes=false))]
pub(crate) fn status<'py>(
    py: Python<'py>,
    out: PathBuf,
    shards: Option<Whole>,
    hashes: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let n: Option<u64> = whole_opt("shards", shards)?;
    let st = py
        .detach(|| assist_generate::status(&out, n, hashes))
        .map_err(err)?;
    to_py(py, &st)
}
