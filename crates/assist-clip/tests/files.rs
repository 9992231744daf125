//! Loading CLIP checkpoints from disk: a random model round-trips, and every broken file
//! is an error naming the file, the tensor and the shape expected.

use std::path::Path;

use assist_clip::random::{RandomSpec, write_model};
use assist_clip::{Clip, ClipError};
use safetensors::SafeTensors;
use safetensors::tensor::TensorView;

fn tiny(dir: &Path) {
    write_model(dir, &RandomSpec::tiny(), 7).unwrap();
}

/// Rewrites the weights with `edit` applied to the (name, shape, bytes) list.
fn rewrite(dir: &Path, edit: impl FnOnce(&mut Vec<(String, Vec<usize>, Vec<u8>)>)) {
    let f = dir.join("open_clip_model.safetensors");
    let bytes = std::fs::read(&f).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let mut t: Vec<(String, Vec<usize>, Vec<u8>)> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.shape().to_vec(), v.data().to_vec()))
        .collect();
    edit(&mut t);
    let views: Vec<(String, TensorView<'_>)> = t
        .iter()
        .map(|(n, s, b)| {
            (
                n.clone(),
                TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap(),
            )
        })
        .collect();
    safetensors::serialize_to_file(views, None, &f).unwrap();
}

fn err(dir: &Path) -> String {
    match Clip::load(dir) {
        Ok(_) => panic!("loaded a broken model"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_random_model_embeds_images_and_texts() {
    let d = tempfile::tempdir().unwrap();
    tiny(d.path());
    let clip = Clip::load(d.path()).unwrap();
    let c = clip.config();
    assert_eq!((c.embed_dim, c.vision.heads, c.text.heads), (32, 2, 2));
    let imgs: Vec<image::RgbImage> = (0..3)
        .map(|k| {
            image::RgbImage::from_fn(40, 30, |x, y| {
                image::Rgb([(x * 6) as u8, (y * 8) as u8, k * 90])
            })
        })
        .collect();
    let all = clip.embed_images(&imgs).unwrap();
    assert_eq!(all.len(), 3);
    assert_eq!(all[0].len(), 32);
    // A batch gives each image the features it gets alone.
    let one = clip.embed_images(&imgs[2..]).unwrap();
    let diff = all[2]
        .iter()
        .zip(&one[0])
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(diff < 1e-5, "{diff}");
    assert!(all[0] != all[1]);
    let t = clip.text_features(&["a mug", "a duck", "a mug"]).unwrap();
    assert_eq!(t[0], t[2]);
    assert!(t[0] != t[1]);
    // Through a .safetensors path too.
    assert!(Clip::load(&d.path().join("open_clip_model.safetensors")).is_ok());
}

#[test]
fn a_truncated_file_says_so() {
    let d = tempfile::tempdir().unwrap();
    tiny(d.path());
    let f = d.path().join("open_clip_model.safetensors");
    let b = std::fs::read(&f).unwrap();
    std::fs::write(&f, &b[..b.len() / 3]).unwrap();
    let e = err(d.path());
    assert!(
        e.contains("open_clip_model.safetensors") && e.contains("truncated"),
        "{e}"
    );
    std::fs::write(&f, b"not a model").unwrap();
    let e = err(d.path());
    assert!(e.contains("not a readable safetensors file"), "{e}");
}

#[test]
fn a_wrong_shape_names_the_tensor_and_the_shape_expected() {
    let d = tempfile::tempdir().unwrap();
    tiny(d.path());
    rewrite(d.path(), |t| {
        let e = t
            .iter_mut()
            .find(|e| e.0 == "transformer.resblocks.1.mlp.c_fc.bias")
            .unwrap();
        e.1 = vec![10];
        e.2.truncate(40);
    });
    let e = err(d.path());
    assert!(
        e.contains("\"transformer.resblocks.1.mlp.c_fc.bias\"")
            && e.contains("[10]")
            && e.contains("expected [192]"),
        "{e}"
    );
}

#[test]
fn a_missing_tensor_is_named() {
    let d = tempfile::tempdir().unwrap();
    tiny(d.path());
    rewrite(d.path(), |t| t.retain(|e| e.0 != "visual.ln_post.bias"));
    let e = err(d.path());
    assert!(
        e.contains("\"visual.ln_post.bias\" is missing") && e.contains("[64]"),
        "{e}"
    );
    rewrite(d.path(), |t| t.retain(|e| !e.0.starts_with("visual.")));
    let e = err(d.path());
    assert!(e.contains("a CLIP ViT checkpoint"), "{e}");
}

#[test]
fn missing_or_mismatched_companions_are_explained() {
    let d = tempfile::tempdir().unwrap();
    tiny(d.path());
    std::fs::remove_file(d.path().join("open_clip_config.json")).unwrap();
    let e = err(d.path());
    assert!(e.contains("quick_gelu"), "{e}");
    tiny(d.path());
    let m = d.path().join("merges.txt");
    let text = std::fs::read_to_string(&m).unwrap();
    std::fs::write(&m, text.lines().take(1000).collect::<Vec<_>>().join("\n")).unwrap();
    let e = err(d.path());
    assert!(e.contains("merges.txt") && e.contains("48894"), "{e}");
    std::fs::remove_file(&m).unwrap();
    let e = err(d.path());
    assert!(e.contains("no BPE vocabulary"), "{e}");
    let e = Clip::load(&d.path().join("nowhere"))
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("does not exist"), "{e}");
    assert!(matches!(
        Clip::load(&d.path().join("nowhere")),
        Err(ClipError::NotFound { .. })
    ));
}
