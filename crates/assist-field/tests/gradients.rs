//! Backward against central finite differences, for every parameter group of the field
//! (each hash-grid level, every MLP weight and bias, the appearance codes). All failures are
//! collected and reported together.

use assist_core::Rng;
use assist_field::{Field, FieldConfig, Samples, Tape};

fn small_config() -> FieldConfig {
    FieldConfig {
        levels: 4,
        features_per_level: 2,
        log2_table_size: 8,
        base_resolution: 3,
        max_resolution: 24,
        hidden: 16,
        geo_features: 7,
        color_hidden: 16,
        color_layers: 2,
        sh_degree: 4,
        appearance_dim: 4,
        num_images: 3,
        reflect: false,
    }
}

/// The same with a predicted normal and the reflected view direction.
fn reflect_config() -> FieldConfig {
    FieldConfig {
        reflect: true,
        ..small_config()
    }
}

struct Batch {
    pos: [Vec<f32>; 3],
    dir: [Vec<f32>; 3],
    image: Vec<u32>,
    a: Vec<f32>,
    b: Vec<f32>,
    /// The normal loss's targets (three per sample, some zero: skipped) and weights.
    targets: Vec<f32>,
    weights: Vec<f32>,
}

impl Batch {
    /// `uniform`: one image per chunk of 64 samples (the fast path of the appearance code,
    /// as in training batches), the last chunk the average code; otherwise images mixed
    /// within chunks, one sample in five with the average code.
    fn new(n: usize, rng: &mut Rng, uniform: bool) -> Self {
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
        // Some samples use the average appearance code (u32::MAX).
        let image = (0..n)
            .map(|i| {
                if uniform {
                    if i / 64 < 2 {
                        (i / 64) as u32
                    } else {
                        u32::MAX
                    }
                } else if i % 5 == 4 {
                    u32::MAX
                } else {
                    rng.below(3) as u32
                }
            })
            .collect();
        let a = (0..n).map(|_| rng.f32() - 0.5).collect();
        let b = (0..3 * n).map(|_| rng.f32() - 0.5).collect();
        let mut targets = vec![0.0; 3 * n];
        for i in (0..n).filter(|i| i % 7 != 3) {
            let t = [rng.normal(), rng.normal(), rng.normal()];
            let len = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
            for k in 0..3 {
                targets[3 * i + k] = (t[k] / len) as f32;
            }
        }
        let weights = (0..n).map(|_| rng.f32()).collect();
        Batch {
            pos,
            dir,
            image,
            a,
            b,
            targets,
            weights,
        }
    }
    fn samples(&self) -> Samples<'_> {
        Samples {
            pos: [&self.pos[0], &self.pos[1], &self.pos[2]],
            dir: [&self.dir[0], &self.dir[1], &self.dir[2]],
            image: &self.image,
        }
    }
    /// L = Σ a·σ + Σ b·rgb, accumulated in f64.
    fn loss(&self, field: &Field) -> f64 {
        let n = self.pos[0].len();
        let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
        field.forward(&self.samples(), &mut sig, &mut rgb);
        sig.iter()
            .zip(&self.a)
            .map(|(s, a)| *s as f64 * *a as f64)
            .sum::<f64>()
            + rgb
                .iter()
                .zip(&self.b)
                .map(|(c, b)| *c as f64 * *b as f64)
                .sum::<f64>()
            + if field.config.reflect {
                let mut tape = Tape::default();
                field.forward_train(&self.samples(), &mut tape, &mut sig, &mut rgb);
                field.normal_loss(&mut tape, &self.targets, &self.weights)
            } else {
                0.0
            }
    }
}

#[test]
fn every_parameter_group_matches_central_differences() {
    check_every_group(small_config(), false, 42);
}

/// With the reflected direction and the normal loss: the normal's rows through the
/// reflection, the SH and the loss, into the density net and the tables.
#[test]
fn every_parameter_group_matches_central_differences_reflected() {
    check_every_group(reflect_config(), false, 43);
}

#[test]
fn every_parameter_group_matches_central_differences_one_image_per_chunk() {
    check_every_group(small_config(), true, 42);
}

fn check_every_group(config: FieldConfig, uniform: bool, seed: u64) {
    let mut rng = Rng::new(seed);
    let mut field = Field::new(config, 7).unwrap();
    // Larger table values than the default init, so the encoding matters to the output.
    let grid_len = field.layout.grid.param_count();
    for p in &mut field.params[..grid_len] {
        *p = rng.f32() - 0.5;
    }
    // Likewise larger appearance codes, so that their gradients stand above the f32 noise
    // of the central differences.
    let app = field.layout.appearance;
    for p in &mut field.params[app..] {
        *p = 4.0 * (rng.f32() - 0.5);
    }
    let batch = Batch::new(150, &mut rng, uniform); // not a multiple of the chunk size

    let s = batch.samples();
    let n = s.len();
    let mut tape = Tape::default();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    field.forward_train(&s, &mut tape, &mut sig, &mut rgb);
    // forward_train and forward agree.
    let (mut sig2, mut rgb2) = (vec![0.0; n], vec![0.0; 3 * n]);
    field.forward(&s, &mut sig2, &mut rgb2);
    assert_eq!(sig, sig2);
    assert_eq!(rgb, rgb2);
    eprintln!(
        "sigma max {} mean {}",
        sig.iter().cloned().fold(0.0f32, f32::max),
        sig.iter().sum::<f32>() / n as f32
    );
    let mut grad = vec![0.0f32; field.param_count()];
    if field.config.reflect {
        field.normal_loss(&mut tape, &batch.targets, &batch.weights);
    }
    field.backward(&s, &mut tape, &batch.a, &batch.b, &mut grad);

    let eps = 1e-4f32;
    let mut failures = Vec::new();
    let mut checked = 0;
    let mut kinks = 0;
    let groups = field.layout.groups(&field.config);
    for (name, start, len) in &groups {
        // Up to 12 entries per group: the largest gradients plus random ones.
        let mut idx: Vec<usize> = (*start..start + len).collect();
        idx.sort_by(|&x, &y| grad[y].abs().total_cmp(&grad[x].abs()));
        let mut pick: Vec<usize> = idx.iter().take(6).copied().collect();
        for _ in 0..6 {
            pick.push(start + rng.below(*len as u64) as usize);
        }
        let mut nonzero = 0;
        eprintln!("{name}: largest |gradient| {:.2e}", grad[idx[0]].abs());
        for &i in &pick {
            let orig = field.params[i];
            field.params[i] = orig + eps;
            let lp = batch.loss(&field);
            field.params[i] = orig - eps;
            let lm = batch.loss(&field);
            field.params[i] = orig;
            let l0 = batch.loss(&field);
            let num = (lp - lm) / (2.0 * eps as f64);
            let ana = grad[i] as f64;
            if ana.abs() > 1e-6 {
                nonzero += 1;
            }
            checked += 1;
            let close = |x: f64| (x - ana).abs() <= 2e-2 * x.abs().max(ana.abs()) + 2e-3;
            if !close(num) {
                // A ReLU kink inside [−ε, ε] makes the one-sided slopes differ; the
                // analytic gradient must then equal one of them (a subgradient).
                let (right, left) = ((lp - l0) / eps as f64, (l0 - lm) / eps as f64);
                let kink = (right - left).abs() > 2e-2 * right.abs().max(left.abs()) + 2e-3;
                if kink && (close(right) || close(left)) {
                    kinks += 1;
                } else {
                    failures.push(format!("{name}[{}]: analytic {ana:.6} central {num:.6} (right {right:.6}, left {left:.6})", i - start));
                }
            }
        }
        // Padding weights (inputs beyond the real width) are the only ones allowed to be
        // always zero; every real group must receive gradient.
        if nonzero == 0 {
            failures.push(format!(
                "{name}: no non-zero gradient among {} checked entries",
                pick.len()
            ));
        }
    }
    eprintln!(
        "checked {checked} parameters in {} groups; {kinks} straddled a ReLU kink; {} failures",
        groups.len(),
        failures.len()
    );
    assert!(
        kinks * 10 < checked,
        "too many kinks ({kinks}) for a meaningful check"
    );
    assert!(
        failures.is_empty(),
        "{} of {checked} gradient checks failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn density_path_matches_full_forward() {
    let mut rng = Rng::new(3);
    let field = Field::new(small_config(), 1).unwrap();
    let batch = Batch::new(97, &mut rng, false);
    let (mut sig, mut rgb) = (vec![0.0; 97], vec![0.0; 3 * 97]);
    field.forward(&batch.samples(), &mut sig, &mut rgb);
    let mut sig2 = vec![0.0; 97];
    field.density([&batch.pos[0], &batch.pos[1], &batch.pos[2]], &mut sig2);
    assert_eq!(sig, sig2);
}

/// A field (seed 3) whose tables are large random values, so the encoding matters, and
/// `n` samples away from the box's faces, so a step of ε stays inside it.
fn field_and_inner_batch(config: FieldConfig, rng: &mut Rng, n: usize) -> (Field, Batch) {
    let mut field = Field::new(config, 3).unwrap();
    let grid_len = field.layout.grid.param_count();
    for p in &mut field.params[..grid_len] {
        *p = rng.f32() - 0.5;
    }
    let mut batch = Batch::new(n, rng, false);
    for a in 0..3 {
        for v in &mut batch.pos[a] {
            *v = 0.05 + 0.9 * *v;
        }
    }
    (field, batch)
}

#[test]
fn the_position_gradient_matches_central_differences() {
    // dL/dpos through the whole field (encoding, density net, colour net), for the
    // camera-pose refinement: each sample moved alone along each axis.
    let mut rng = Rng::new(5);
    let (field, mut batch) = field_and_inner_batch(small_config(), &mut rng, 130);
    let n = batch.pos[0].len();
    let mut tape = Tape::default();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    field.forward_train(&batch.samples(), &mut tape, &mut sig, &mut rgb);
    let mut grad = vec![0.0f32; field.param_count()];
    field.backward(&batch.samples(), &mut tape, &batch.a, &batch.b, &mut grad);
    let mut g = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    {
        let [gx, gy, gz] = &mut g;
        field.position_grad(&batch.samples(), &tape, [gx, gy, gz]);
    }
    let eps = 2e-4f32;
    let (mut checked, mut kinks, mut nonzero) = (0, 0, 0);
    let mut failures = Vec::new();
    for s in (0..n).step_by(3) {
        for a in 0..3 {
            let orig = batch.pos[a][s];
            batch.pos[a][s] = orig + eps;
            let lp = batch.loss(&field);
            batch.pos[a][s] = orig - eps;
            let lm = batch.loss(&field);
            batch.pos[a][s] = orig;
            let l0 = batch.loss(&field);
            let num = (lp - lm) / (2.0 * eps as f64);
            let ana = g[a][s] as f64;
            checked += 1;
            if ana.abs() > 1e-4 {
                nonzero += 1;
            }
            let close = |x: f64| (x - ana).abs() <= 3e-2 * x.abs().max(ana.abs()) + 5e-3;
            if !close(num) {
                // A cell face or ReLU kink within ±ε: the analytic value must be one of
                // the one-sided slopes.
                let (right, left) = ((lp - l0) / eps as f64, (l0 - lm) / eps as f64);
                if close(right) || close(left) {
                    kinks += 1;
                } else {
                    failures.push(format!(
                        "sample {s} axis {a}: analytic {ana:.5} central {num:.5} (right {right:.5}, left {left:.5})"
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(kinks * 5 < checked, "{kinks} of {checked} at kinks");
    assert!(
        nonzero * 2 > checked,
        "only {nonzero} of {checked} non-zero"
    );
}

#[test]
fn the_backward_to_the_encoding_alone_gives_the_same_position_gradient() {
    // A camera fitted to a frozen scene takes the encoding's gradient without the
    // parameters': the position gradient must be the same bits, and a full backward
    // after it the same as on a fresh tape (nothing of the nets' gradient left behind).
    let mut rng = Rng::new(9);
    let mut field = Field::new(small_config(), 3).unwrap();
    for p in &mut field.params {
        *p = 0.5 * (rng.f32() - 0.5);
    }
    let batch = Batch::new(300, &mut rng, false);
    let n = batch.pos[0].len();
    let pos_grad = |tape: &Tape| {
        let mut g = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
        let [gx, gy, gz] = &mut g;
        field.position_grad(&batch.samples(), tape, [gx, gy, gz]);
        g
    };
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    let mut full = Tape::default();
    field.forward_train(&batch.samples(), &mut full, &mut sig, &mut rgb);
    let mut grad = vec![0.0f32; field.param_count()];
    field.backward(&batch.samples(), &mut full, &batch.a, &batch.b, &mut grad);
    let want = pos_grad(&full);
    assert!(want[0].iter().any(|&g| g != 0.0));

    let mut tape = Tape::default();
    field.forward_train(&batch.samples(), &mut tape, &mut sig, &mut rgb);
    field.backward_to_encoding(&batch.samples(), &mut tape, &batch.a, &batch.b);
    assert_eq!(pos_grad(&tape), want);
    field.forward_train(&batch.samples(), &mut tape, &mut sig, &mut rgb);
    let mut again = vec![0.0f32; field.param_count()];
    field.backward(&batch.samples(), &mut tape, &batch.a, &batch.b, &mut again);
    assert_eq!(again, grad);
}

/// The density's own normals against central differences of the density, in a box
/// scaled unevenly: `−∇σ / |∇σ|` with the gradient taken per unit of the scaled axes.
#[test]
fn density_normals_match_central_differences() {
    let mut rng = Rng::new(21);
    let (field, batch) = field_and_inner_batch(reflect_config(), &mut rng, 90);
    let n = batch.pos[0].len();
    let mut tape = Tape::default();
    let (mut sig, mut rgb) = (vec![0.0; n], vec![0.0; 3 * n]);
    field.forward_train(&batch.samples(), &mut tape, &mut sig, &mut rgb);
    let scale = [1.0f32, 2.0, 0.5];
    let mut got = vec![0.0f32; 3 * n];
    field.density_normals(&batch.samples(), &tape, scale, &mut got);
    let density = |p: [f32; 3]| {
        let mut s = [0.0f32];
        field.density([&[p[0]], &[p[1]], &[p[2]]], &mut s);
        f64::from(s[0])
    };
    let eps = 2e-4f32;
    let (mut checked, mut close_ones) = (0, 0);
    for i in 0..n {
        let p = [batch.pos[0][i], batch.pos[1][i], batch.pos[2][i]];
        let g: Vec<f64> = (0..3)
            .map(|a| {
                let (mut hi, mut lo) = (p, p);
                hi[a] += eps;
                lo[a] -= eps;
                (density(hi) - density(lo)) / (2.0 * f64::from(eps)) / f64::from(scale[a])
            })
            .collect();
        let len = g.iter().map(|v| v * v).sum::<f64>().sqrt();
        if len < 1e-3 {
            continue;
        }
        checked += 1;
        let err: f64 = (0..3)
            .map(|a| (f64::from(got[3 * i + a]) + g[a] / len).powi(2))
            .sum::<f64>()
            .sqrt();
        // A cell face or ReLU kink within ±ε moves a few; the rest agree closely.
        if err < 2e-2 {
            close_ones += 1;
        }
    }
    assert!(checked > n / 2, "only {checked} of {n} with a gradient");
    assert!(
        close_ones * 10 >= checked * 9,
        "{close_ones} of {checked} normals within 0.02"
    );
}
