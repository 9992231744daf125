//! Checks that every file a dataset refers to exists and decodes at the declared size.

use rayon::prelude::*;

use crate::dataset::Dataset;
use crate::error::DataError;
use crate::image_io::{decoded_size, read_instance_mask};

/// What validation found.
#[derive(Debug, Default)]
pub struct Report {
    pub files_checked: usize,
    pub errors: Vec<DataError>,
    /// Instance ids seen in masks that the dataset does not declare.
    pub undeclared_ids: Vec<u16>,
}

/// Says which frame field referred to a file that is missing or unreadable.
fn with_field(e: DataError, frame: usize, field: &str) -> DataError {
    match e {
        DataError::Io { path, source } => {
            let what = if source.kind() == std::io::ErrorKind::NotFound {
                "file not found".to_string()
            } else {
                source.to_string()
            };
            DataError::Field {
                path,
                field: format!("frames[{frame}].{field}"),
                message: what,
            }
        }
        DataError::Image { path, message } => DataError::Field {
            path,
            field: format!("frames[{frame}].{field}"),
            message: format!("cannot decode image: {message}"),
        },
        other => other,
    }
}

/// Decodes every image, mask and depth map (in parallel) and checks sizes.
pub fn validate(ds: &Dataset) -> Report {
    let results: Vec<(usize, Vec<DataError>, Vec<u16>)> = ds
        .frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| {
            let (w, h) = (f.camera.width(), f.camera.height());
            // Files reduced on reading (`--downscale`) are `pixel_factor` times larger.
            let k = f.pixel_factor.max(1);
            let fits = |gw: u32, gh: u32| (gw / k, gh / k) == (w, h);
            let mut errs = Vec::new();
            let mut ids = Vec::new();
            let mut n = 0;
            let mut check = |path: &std::path::Path, field: &str, errs: &mut Vec<DataError>| {
                n += 1;
                match decoded_size(path) {
                    Ok((gw, gh)) if !fits(gw, gh) => errs.push(DataError::ImageSize {
                        path: path.into(),
                        field: format!("frames[{i}].{field}"),
                        got_w: gw,
                        got_h: gh,
                        want_w: w * k,
                        want_h: h * k,
                    }),
                    Ok(_) => {}
                    Err(e) => errs.push(with_field(e, i, field)),
                }
            };
            check(&f.image_path, "file_path", &mut errs);
            if let Some(p) = &f.mask_path {
                check(p, "mask_path", &mut errs);
            }
            if let Some(p) = &f.depth_path {
                check(p, "depth_file_path", &mut errs);
            }
            if let Some(p) = &f.instance_mask_path {
                n += 1;
                match read_instance_mask(p, f.mask_encoding) {
                    Ok(m) if !fits(m.width, m.height) => errs.push(DataError::ImageSize {
                        path: p.clone(),
                        field: format!("frames[{i}].instance_mask_path"),
                        got_w: m.width,
                        got_h: m.height,
                        want_w: w * k,
                        want_h: h * k,
                    }),
                    Ok(m) => {
                        let mut seen = [false; 65536];
                        for &v in &m.data {
                            seen[v as usize] = true;
                        }
                        ids.extend((1..65536).filter(|&k| seen[k]).map(|k| k as u16));
                    }
                    Err(e) => errs.push(with_field(e, i, "instance_mask_path")),
                }
            }
            (n, errs, ids)
        })
        .collect();
    let mut report = Report::default();
    let mut all_ids = std::collections::BTreeSet::new();
    for (n, errs, ids) in results {
        report.files_checked += n;
        report.errors.extend(errs);
        all_ids.extend(ids);
    }
    if !ds.instances.is_empty() {
        report.undeclared_ids = all_ids
            .into_iter()
            .filter(|id| ds.instance(*id).is_none())
            .collect();
    }
    report
}
