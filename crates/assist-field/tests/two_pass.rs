//! Rendering's two-pass inference (density for every sample, the colour net for the ones
//! kept) against the one-pass query of the kept samples alone.

use assist_core::Rng;
use assist_field::{Field, FieldConfig, Precision, Samples, Tape};

#[test]
fn the_colour_pass_on_kept_samples_is_the_full_query_of_them() {
    let cfg = FieldConfig {
        levels: 6,
        features_per_level: 2,
        log2_table_size: 10,
        base_resolution: 4,
        max_resolution: 64,
        hidden: 32,
        geo_features: 15,
        color_hidden: 32,
        color_layers: 2,
        sh_degree: 4,
        appearance_dim: 4,
        num_images: 3,
    };
    let mut field = Field::new(cfg, 5).unwrap();
    let mut rng = Rng::new(11);
    // Table entries of ±1, so each sample's outputs depend on where it is.
    let grid = field.layout.grid.param_count();
    for p in &mut field.params[..grid] {
        *p = rng.f32() * 2.0 - 1.0;
    }
    let n = 1000;
    let mut pos = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut dir = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    for i in 0..n {
        let d = [rng.normal(), rng.normal(), rng.normal()];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        for k in 0..3 {
            pos[k][i] = rng.f32();
            dir[k][i] = (d[k] / len) as f32;
        }
    }
    let image: Vec<u32> = (0..n)
        .map(|i| {
            if i % 7 == 0 {
                u32::MAX
            } else {
                rng.below(3) as u32
            }
        })
        .collect();
    // Kept: about two in five, in runs (as along rays), ascending.
    let kept: Vec<u32> = (0..n as u32).filter(|i| (i / 9) % 5 < 2).collect();

    let mut tape = Tape::default();
    let mut sigma_all = vec![0.0; n];
    field.density_features([&pos[0], &pos[1], &pos[2]], None, &mut sigma_all, &mut tape);
    field.keep_features(&mut tape, &kept);
    let pick = |v: &[f32]| kept.iter().map(|&i| v[i as usize]).collect::<Vec<f32>>();
    let (kp, kd) = (pos.clone().map(|v| pick(&v)), dir.clone().map(|v| pick(&v)));
    let ki: Vec<u32> = kept.iter().map(|&i| image[i as usize]).collect();
    let s = Samples {
        pos: [&kp[0], &kp[1], &kp[2]],
        dir: [&kd[0], &kd[1], &kd[2]],
        image: &ki,
    };
    let m = kept.len();
    let (mut sig2, mut rgb2) = (vec![0.0; m], vec![0.0; 3 * m]);
    field.forward_from_features(Precision::F32, &s, &tape, &mut sig2, &mut rgb2);
    let (mut sig1, mut rgb1) = (vec![0.0; m], vec![0.0; 3 * m]);
    field.forward_at(
        Precision::F32,
        None,
        &s,
        &mut Tape::default(),
        &mut sig1,
        &mut rgb1,
    );

    // Equal but for the last bits: the encoding's vector body and its scalar tail round
    // differently, and a sample's place in the batch differs between the two.
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * x.abs().max(y.abs()).max(1.0);
    for j in 0..m {
        assert!(
            close(sig1[j], sig2[j]),
            "σ of kept {j}: {} vs {}",
            sig1[j],
            sig2[j]
        );
        assert!(
            close(sig1[j], sigma_all[kept[j] as usize]),
            "first pass σ {j}"
        );
        for c in 0..3 {
            let (a, b) = (rgb1[3 * j + c], rgb2[3 * j + c]);
            assert!(close(a, b), "rgb of kept {j}: {a} vs {b}");
        }
    }
    let spread = sig1.iter().cloned().fold(f32::MIN, f32::max)
        - sig1.iter().cloned().fold(f32::MAX, f32::min);
    assert!(spread > 0.1, "densities vary with position: {spread}");
}
