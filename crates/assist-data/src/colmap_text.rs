//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`).

use std::path::Path;

use assist_core::{DVec2, DVec3};

use crate::colmap_model::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, model_params};
use crate::error::{DataError, Result};

fn lines(path: &Path) -> Result<Vec<(usize, String)>> {
    let text = crate::json::read_text(path)?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect())
}

fn num<T: std::str::FromStr>(
    path: &Path,
    line: usize,
    field: &str,
    tok: Option<&str>,
) -> Result<T> {
    let tok =
        tok.ok_or_else(|| DataError::field(path, format!("line {line}: {field}"), "missing"))?;
    tok.parse().map_err(|_| {
        DataError::field(
            path,
            format!("line {line}: {field}"),
            format!("expected a number, got {tok:?}"),
        )
    })
}

pub fn read(dir: &Path) -> Result<ColmapModel> {
    let mut model = ColmapModel::default();
    let cpath = dir.join("cameras.txt");
    for (ln, l) in lines(&cpath)? {
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut t = l.split_whitespace();
        let id: u32 = num(&cpath, ln, "CAMERA_ID", t.next())?;
        let model_name = t
            .next()
            .ok_or_else(|| DataError::field(&cpath, format!("line {ln}: MODEL"), "missing"))?
            .to_string();
        let width: u32 = num(&cpath, ln, "WIDTH", t.next())?;
        let height: u32 = num(&cpath, ln, "HEIGHT", t.next())?;
        let params: Vec<f64> = t
            .enumerate()
            .map(|(j, tok)| num(&cpath, ln, &format!("PARAMS[{j}]"), Some(tok)))
            .collect::<Result<_>>()?;
        if model_params(&model_name).is_none() {
            return Err(DataError::field(
                &cpath,
                format!("line {ln}: MODEL"),
                format!("unknown COLMAP camera model {model_name:?}"),
            ));
        }
        model.cameras.insert(
            id,
            ColmapCamera {
                id,
                model: model_name,
                width,
                height,
                params,
            },
        );
    }
    let ipath = dir.join("images.txt");
    let ls: Vec<(usize, String)> = lines(&ipath)?
        .into_iter()
        .filter(|(_, l)| !l.starts_with('#'))
        .collect();
    let mut i = 0;
    while i < ls.len() {
        let (ln, l) = &ls[i];
        if l.is_empty() {
            i += 1;
            continue;
        }
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 10 {
            return Err(DataError::field(
                &ipath,
                format!("line {ln}"),
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
            ));
        }
        let id: u32 = num(&ipath, *ln, "IMAGE_ID", Some(t[0]))?;
        let mut qvec = [0.0; 4];
        for j in 0..4 {
            qvec[j] = num(&ipath, *ln, ["QW", "QX", "QY", "QZ"][j], Some(t[1 + j]))?;
        }
        let mut tvec = [0.0; 3];
        for j in 0..3 {
            tvec[j] = num(&ipath, *ln, ["TX", "TY", "TZ"][j], Some(t[5 + j]))?;
        }
        let camera_id: u32 = num(&ipath, *ln, "CAMERA_ID", Some(t[8]))?;
        let name = t[9..].join(" ");
        // The observations line follows (possibly empty).
        let mut points2d = Vec::new();
        if let Some((ln2, l2)) = ls.get(i + 1) {
            let p: Vec<&str> = l2.split_whitespace().collect();
            if !p.len().is_multiple_of(3) {
                return Err(DataError::field(
                    &ipath,
                    format!("line {ln2}: POINTS2D"),
                    "expected triples X Y POINT3D_ID",
                ));
            }
            for c in p.chunks(3) {
                let x: f64 = num(&ipath, *ln2, "X", Some(c[0]))?;
                let y: f64 = num(&ipath, *ln2, "Y", Some(c[1]))?;
                let pid: i64 = num(&ipath, *ln2, "POINT3D_ID", Some(c[2]))?;
                points2d.push((DVec2::new(x, y), pid));
            }
        }
        model.images.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
        i += 2;
    }
    let ppath = dir.join("points3D.txt");
    if ppath.is_file() {
        for (ln, l) in lines(&ppath)? {
            if l.is_empty() || l.starts_with('#') {
                continue;
            }
            let t: Vec<&str> = l.split_whitespace().collect();
            let id: u64 = num(&ppath, ln, "POINT3D_ID", t.first().copied())?;
            let xyz = DVec3::new(
                num(&ppath, ln, "X", t.get(1).copied())?,
                num(&ppath, ln, "Y", t.get(2).copied())?,
                num(&ppath, ln, "Z", t.get(3).copied())?,
            );
            let rgb = [
                num(&ppath, ln, "R", t.get(4).copied())?,
                num(&ppath, ln, "G", t.get(5).copied())?,
                num(&ppath, ln, "B", t.get(6).copied())?,
            ];
            let error = num(&ppath, ln, "ERROR", t.get(7).copied())?;
            model.points.insert(
                id,
                ColmapPoint {
                    id,
                    xyz,
                    rgb,
                    error,
                },
            );
        }
    }
    Ok(model)
}
