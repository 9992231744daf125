//! Training's density pass, whose encoding the forward pass reads: of the samples kept,
//! and never of other samples.

use assist_core::Rng;
use assist_field::{Field, FieldConfig, Samples, Tape};

/// A small field with table entries of ±1 and `n` random samples (positions, directions,
/// images), and about two in five kept, in runs as along rays.
#[allow(clippy::type_complexity)]
fn setup(n: usize) -> (Field, [Vec<f32>; 3], [Vec<f32>; 3], Vec<u32>, Vec<u32>) {
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
        reflect: false,
    };
    let mut field = Field::new(cfg, 5).unwrap();
    let mut rng = Rng::new(12);
    let grid = field.layout.grid.param_count();
    for p in &mut field.params[..grid] {
        *p = rng.f32() * 2.0 - 1.0;
    }
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
    // Some samples with the average appearance code (`u32::MAX`).
    let image: Vec<u32> = (0..n)
        .map(|i| {
            if i % 7 == 0 {
                u32::MAX
            } else {
                rng.below(3) as u32
            }
        })
        .collect();
    let kept: Vec<u32> = (0..n as u32).filter(|i| (i / 9) % 5 < 2).collect();
    (field, pos, dir, image, kept)
}

/// The positions, directions and images of the samples `kept`, in order.
#[allow(clippy::type_complexity)]
fn pick_kept(
    pos: &[Vec<f32>; 3],
    dir: &[Vec<f32>; 3],
    image: &[u32],
    kept: &[u32],
) -> ([Vec<f32>; 3], [Vec<f32>; 3], Vec<u32>) {
    let pick = |v: &Vec<f32>| kept.iter().map(|&i| v[i as usize]).collect::<Vec<f32>>();
    let ki = kept.iter().map(|&i| image[i as usize]).collect();
    (pos.each_ref().map(pick), dir.each_ref().map(pick), ki)
}

/// Training's density pass over `pos`: the densities in `sigma`, the tape holding the
/// encoding.
fn density_pass(field: &Field, pos: &[Vec<f32>; 3], sigma: &mut [f32]) -> Tape {
    let mut tape = Tape::default();
    field.density_encoded([&pos[0], &pos[1], &pos[2]], sigma, &mut tape);
    tape
}

/// Training's forward and backward on one tape: outputs and the parameters' gradient.
fn train_pass(field: &Field, s: &Samples, tape: &mut Tape) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let m = s.len();
    let (mut sig, mut rgb) = (vec![0.0; m], vec![0.0; 3 * m]);
    field.forward_train(s, tape, &mut sig, &mut rgb);
    let d_sigma: Vec<f32> = (0..m).map(|j| ((j % 5) as f32 - 2.0) * 0.1).collect();
    let d_rgb: Vec<f32> = (0..3 * m).map(|j| ((j % 7) as f32 - 3.0) * 0.1).collect();
    let mut grad = vec![0.0; field.params.len()];
    field.backward(s, tape, &d_sigma, &d_rgb, &mut grad);
    (sig, rgb, grad)
}

#[test]
fn training_reads_the_density_pass_encoding_of_the_kept_samples() {
    let n = 1000;
    let (mut field, pos, dir, image, kept) = setup(n);
    let (kp, kd, ki) = pick_kept(&pos, &dir, &image, &kept);
    let s = Samples {
        pos: [&kp[0], &kp[1], &kp[2]],
        dir: [&kd[0], &kd[1], &kd[2]],
        image: &ki,
    };
    let mut sigma_all = vec![0.0; n];
    let mut tape = density_pass(&field, &pos, &mut sigma_all);
    field.keep_encoded(&mut tape, &kept, s.pos);
    let (sig2, rgb2, grad2) = train_pass(&field, &s, &mut tape);
    let (sig1, rgb1, grad1) = train_pass(&field, &s, &mut Tape::default());
    // Equal but for the last bits (the encoding's vector body and scalar tail round
    // differently, and a sample's place in the batch differs between the two).
    let close = |x: f32, y: f32, scale: f32| (x - y).abs() <= 1e-5 * scale.max(x.abs()).max(1.0);
    let gmax = grad1.iter().fold(0f32, |a, g| a.max(g.abs()));
    assert!(gmax > 0.0);
    for j in 0..kept.len() {
        assert!(
            close(sig1[j], sig2[j], 0.0),
            "σ {j}: {} vs {}",
            sig1[j],
            sig2[j]
        );
        assert!(
            close(sig1[j], sigma_all[kept[j] as usize], 0.0),
            "density pass σ {j}"
        );
        for c in 0..3 {
            assert!(close(rgb1[3 * j + c], rgb2[3 * j + c], 0.0), "rgb {j}");
        }
    }
    for (i, (a, b)) in grad1.iter().zip(&grad2).enumerate() {
        assert!(close(*a, *b, gmax), "gradient {i}: {a} vs {b}");
    }

    // The forward read the stored encoding rather than encoding again: with the table
    // changed between the passes, its outputs are those of the table as it was.
    let mut tape = density_pass(&field, &pos, &mut sigma_all);
    field.keep_encoded(&mut tape, &kept, s.pos);
    let grid = field.layout.grid.param_count();
    for p in &mut field.params[..grid] {
        *p = -*p;
    }
    let (sig3, _, _) = train_pass(&field, &s, &mut tape);
    assert!((0..kept.len()).all(|j| close(sig3[j], sig1[j], 0.0)));
    let (sig4, _, _) = train_pass(&field, &s, &mut Tape::default());
    assert!((0..kept.len()).any(|j| !close(sig4[j], sig1[j], 0.0)));
}

#[test]
fn a_stored_encoding_of_other_samples_is_not_read() {
    let n = 700;
    let (field, pos, dir, image, _) = setup(n);
    // Other positions, as many: the forward must encode them itself.
    let other: [Vec<f32>; 3] = pos.clone().map(|v| v.iter().map(|x| 1.0 - x).collect());
    let s = Samples {
        pos: [&other[0], &other[1], &other[2]],
        dir: [&dir[0], &dir[1], &dir[2]],
        image: &image,
    };
    let mut tape = density_pass(&field, &pos, &mut vec![0.0; n]);
    let (sig2, rgb2, grad2) = train_pass(&field, &s, &mut tape);
    let (sig1, rgb1, grad1) = train_pass(&field, &s, &mut Tape::default());
    assert_eq!(sig1, sig2);
    assert_eq!(rgb1, rgb2);
    assert_eq!(grad1, grad2);
}
