//! Blender synthetic (NeRF): `transforms_{train,val,test}.json` with `camera_angle_x` and
//! RGBA images whose alpha is the object mask (composited on a chosen background colour
//! when the images are read).

use std::path::Path;

use assist_core::{Camera, Intrinsics, Pose};

use crate::dataset::{Dataset, Format, Frame, Split, compute_bounds};
use crate::error::{DataError, Result};
use crate::image_io::image_dimensions;
use crate::json::{Node, read_json};
use crate::nerfstudio::resolve_image_path;

pub fn load(dir: &Path) -> Result<Dataset> {
    let mut frames = Vec::new();
    let mut size: Option<(u32, u32)> = None;
    let mut found = false;
    for split in [Split::Train, Split::Val, Split::Test] {
        let file = dir.join(format!("transforms_{}.json", split.name()));
        if !file.is_file() {
            continue;
        }
        found = true;
        let v = read_json(&file)?;
        let top = Node::root(&v, &file);
        let angle = top.req("camera_angle_x")?.positive_f64()?;
        if angle >= std::f64::consts::PI {
            return Err(crate::error::DataError::field(
                &file,
                "camera_angle_x",
                format!("expected a horizontal field of view below π radians (180°), got {angle}"),
            ));
        }
        for fr in top.req("frames")?.items()? {
            let image_path = resolve_image_path(dir, fr.req("file_path")?.str()?);
            let (w, h) = match size {
                Some(s) => s,
                None => {
                    // The first image sets every frame's size: name where it was listed.
                    let s = image_dimensions(&image_path).map_err(|e| {
                        DataError::field(
                            &file,
                            format!("{}.file_path", fr.path()),
                            format!("the first frame's image sets the size of all: {e}"),
                        )
                    })?;
                    size = Some(s);
                    s
                }
            };
            let m = fr.req("transform_matrix")?;
            let pose = Pose::from_matrix(m.mat4_rows()?, m.path())
                .map_err(|e| DataError::core(&file, e))?;
            let camera = Camera {
                intrinsics: Intrinsics::from_fov_x(w, h, angle),
                pose,
            };
            frames.push(Frame {
                alpha_is_mask: true,
                ..Frame::new(image_path, camera, "PINHOLE", split)
            });
        }
    }
    if !found {
        return Err(DataError::NotADataset {
            path: dir.into(),
            message: "no transforms_train.json, transforms_val.json or transforms_test.json".into(),
        });
    }
    let (bounds, normalization) = compute_bounds(&frames, &[], &[], None);
    Ok(Dataset {
        format: Format::Blender,
        root: dir.to_path_buf(),
        frames,
        instances: vec![],
        world_up: Some(assist_core::DVec3::Z),
        meters_per_unit: None,
        points: vec![],
        depth_range: None,
        split_declared: true,
        rendered: true,
        split_source: "transforms_{train,val,test}.json".into(),
        bounds,
        normalization,
        mask_folder: None,
        prior_folder: None,
    })
}
