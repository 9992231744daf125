//! COLMAP's binary model files (little-endian), read with bounds checks so that a
//! truncated file reports which record and field it ends in.

use std::collections::HashMap;
use std::path::Path;

use assist_core::{DVec2, DVec3};

use crate::colmap_model::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, model_name};
use crate::error::{DataError, Result};

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &dyn Fn() -> String) -> Result<&'a [u8]> {
        if self.b.len() - self.pos < n {
            return Err(DataError::Truncated {
                path: self.path.into(),
                message: format!(
                    "file ends at byte {} inside {} (needed {n} more bytes, {} left)",
                    self.b.len(),
                    what(),
                    self.b.len() - self.pos
                ),
            });
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u64(&mut self, what: &dyn Fn() -> String) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn i64(&mut self, what: &dyn Fn() -> String) -> Result<i64> {
        Ok(i64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn i32(&mut self, what: &dyn Fn() -> String) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn u32(&mut self, what: &dyn Fn() -> String) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn f64(&mut self, what: &dyn Fn() -> String) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn remaining(&self) -> usize {
        self.b.len() - self.pos
    }
    /// A count that must fit in the rest of the file at `min_record` bytes per item.
    fn count(&mut self, min_record: usize, what: &dyn Fn() -> String) -> Result<usize> {
        let n = self.u64(what)?;
        if n as u128 * min_record as u128 > self.remaining() as u128 {
            return Err(DataError::Truncated {
                path: self.path.into(),
                message: format!(
                    "{} says {n} records, but only {} bytes follow (at least {min_record} per record)",
                    what(),
                    self.remaining()
                ),
            });
        }
        Ok(n as usize)
    }
}

fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

pub fn read(dir: &Path) -> Result<ColmapModel> {
    let cameras = read_cameras(&dir.join("cameras.bin"))?;
    let images = read_images(&dir.join("images.bin"))?;
    let pfile = dir.join("points3D.bin");
    let points = if pfile.is_file() {
        read_points(&pfile)?
    } else {
        HashMap::new()
    };
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

pub fn read_cameras(path: &Path) -> Result<HashMap<u32, ColmapCamera>> {
    let bytes = read_file(path)?;
    let mut r = Reader {
        b: &bytes,
        pos: 0,
        path,
    };
    let n = r.count(24, &|| "the camera count".into())?;
    let mut out = HashMap::new();
    for k in 0..n {
        let id = r.i32(&|| format!("camera #{k} (camera_id)"))?;
        let model_id = r.i32(&|| format!("camera {id} (model_id)"))?;
        let width = r.u64(&|| format!("camera {id} (width)"))?;
        let height = r.u64(&|| format!("camera {id} (height)"))?;
        let (model, np) = model_name(model_id).ok_or_else(|| {
            DataError::field(
                path,
                format!("camera {id}.model_id"),
                format!("unknown COLMAP camera model id {model_id}; expected 0..=10"),
            )
        })?;
        let mut params = Vec::with_capacity(np);
        for j in 0..np {
            params.push(r.f64(&|| format!("camera {id} (params[{j}])"))?);
        }
        if width == 0 || height == 0 || width > u32::MAX as u64 || height > u32::MAX as u64 {
            return Err(DataError::field(
                path,
                format!("camera {id}.width/height"),
                format!("expected a positive image size, got {width}x{height}"),
            ));
        }
        out.insert(
            id as u32,
            ColmapCamera {
                id: id as u32,
                model: model.into(),
                width: width as u32,
                height: height as u32,
                params,
            },
        );
    }
    Ok(out)
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    let bytes = read_file(path)?;
    let mut r = Reader {
        b: &bytes,
        pos: 0,
        path,
    };
    let n = r.count(64, &|| "the image count".into())?;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let id = r.u32(&|| format!("image #{k} (image_id)"))?;
        let mut qvec = [0.0; 4];
        for (j, q) in qvec.iter_mut().enumerate() {
            *q = r.f64(&|| format!("image {id} (qvec[{j}])"))?;
        }
        let mut tvec = [0.0; 3];
        for (j, t) in tvec.iter_mut().enumerate() {
            *t = r.f64(&|| format!("image {id} (tvec[{j}])"))?;
        }
        let camera_id = r.u32(&|| format!("image {id} (camera_id)"))?;
        let mut name = Vec::new();
        loop {
            let c = r.take(1, &|| format!("image {id} (name)"))?[0];
            if c == 0 {
                break;
            }
            name.push(c);
        }
        let name = String::from_utf8(name).map_err(|_| {
            DataError::field(path, format!("image {id}.name"), "expected UTF-8 text")
        })?;
        let np = r.count(24, &|| format!("image {id} ({name}) num_points2D"))?;
        let mut points2d = Vec::with_capacity(np);
        for j in 0..np {
            let what = || format!("image {id} ({name}) points2D[{j}]");
            let x = r.f64(&what)?;
            let y = r.f64(&what)?;
            let pid = r.i64(&what)?;
            points2d.push((DVec2::new(x, y), pid));
        }
        out.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    Ok(out)
}

pub fn read_points(path: &Path) -> Result<HashMap<u64, ColmapPoint>> {
    let bytes = read_file(path)?;
    let mut r = Reader {
        b: &bytes,
        pos: 0,
        path,
    };
    let n = r.count(51, &|| "the point count".into())?;
    let mut out = HashMap::with_capacity(n);
    for k in 0..n {
        let id = r.u64(&|| format!("point #{k} (point3D_id)"))?;
        let what = || format!("point {id}");
        let xyz = DVec3::new(r.f64(&what)?, r.f64(&what)?, r.f64(&what)?);
        let c = r.take(3, &what)?;
        let rgb = [c[0], c[1], c[2]];
        let error = r.f64(&what)?;
        let tl = r.count(8, &|| format!("point {id} track_length"))?;
        r.take(tl * 8, &|| format!("point {id} track"))?;
        out.insert(
            id,
            ColmapPoint {
                id,
                xyz,
                rgb,
                error,
            },
        );
    }
    Ok(out)
}
