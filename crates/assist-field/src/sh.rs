//! Real spherical harmonics up to degree 4 (16 coefficients) of a unit direction, with the
//! constants and sign conventions of tiny-cuda-nn's SH encoding used by Nerfacto.

/// Writes `degree²` coefficients of direction `(x, y, z)` (unit length) into `out`: the
/// scalar reference the row encoder below is tested against.
#[cfg_attr(not(test), allow(dead_code))]
#[inline]
pub fn sh_encode(degree: usize, x: f32, y: f32, z: f32, out: &mut [f32]) {
    out[0] = 0.282_094_8;
    if degree <= 1 {
        return;
    }
    out[1] = -0.488_602_5 * y;
    out[2] = 0.488_602_5 * z;
    out[3] = -0.488_602_5 * x;
    if degree <= 2 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    out[4] = 1.092_548_4 * xy;
    out[5] = -1.092_548_4 * yz;
    out[6] = 0.946_174_7 * zz - 0.315_391_57;
    out[7] = -1.092_548_4 * xz;
    out[8] = 0.546_274_2 * (xx - yy);
    if degree <= 3 {
        return;
    }
    out[9] = 0.590_043_6 * y * (-3.0 * xx + yy);
    out[10] = 2.890_611_4 * xy * z;
    out[11] = 0.457_045_8 * y * (1.0 - 5.0 * zz);
    out[12] = 0.373_176_33 * z * (5.0 * zz - 3.0);
    out[13] = 0.457_045_8 * x * (1.0 - 5.0 * zz);
    out[14] = 1.445_305_7 * z * (xx - yy);
    out[15] = 0.590_043_6 * x * (-xx + 3.0 * yy);
}

/// The gradient of `Σ_k g[k] · Y_k(x, y, z)` with respect to `(x, y, z)` (the
/// coordinates taken as independent, not held to the unit sphere), for the `degree²`
/// coefficients of [`sh_encode`]: what the reflected direction's backward pass needs.
#[inline(always)]
pub fn sh_vjp(degree: usize, x: f32, y: f32, z: f32, g: &[f32]) -> [f32; 3] {
    const C1: f32 = 0.488_602_5;
    const C2: f32 = 1.092_548_4;
    let (mut dx, mut dy, mut dz) = (0.0f32, 0.0f32, 0.0f32);
    if degree >= 2 {
        dy -= C1 * g[1];
        dz += C1 * g[2];
        dx -= C1 * g[3];
    }
    if degree >= 3 {
        dx += C2 * y * g[4];
        dy += C2 * x * g[4];
        dy -= C2 * z * g[5];
        dz -= C2 * y * g[5];
        dz += 2.0 * 0.946_174_7 * z * g[6];
        dx -= C2 * z * g[7];
        dz -= C2 * x * g[7];
        dx += 2.0 * 0.546_274_2 * x * g[8];
        dy -= 2.0 * 0.546_274_2 * y * g[8];
    }
    if degree >= 4 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let (a9, a10, a11, a12) = (0.590_043_6, 2.890_611_4, 0.457_045_8, 0.373_176_33);
        let (a14, a15) = (1.445_305_7, 0.590_043_6);
        dx += a9 * -6.0 * x * y * g[9];
        dy += a9 * 3.0 * (yy - xx) * g[9];
        dx += a10 * y * z * g[10];
        dy += a10 * x * z * g[10];
        dz += a10 * x * y * g[10];
        dy += a11 * (1.0 - 5.0 * zz) * g[11];
        dz += a11 * -10.0 * y * z * g[11];
        dz += a12 * (15.0 * zz - 3.0) * g[12];
        dx += a11 * (1.0 - 5.0 * zz) * g[13];
        dz += a11 * -10.0 * x * z * g[13];
        dx += a14 * 2.0 * x * z * g[14];
        dy -= a14 * 2.0 * y * z * g[14];
        dz += a14 * (xx - yy) * g[14];
        dx += a15 * 3.0 * (yy - xx) * g[15];
        dy += a15 * 6.0 * x * y * g[15];
    }
    [dx, dy, dz]
}

/// The same basis for many directions at once: coefficient `k` of lane `l` goes to
/// `out[k * stride + l]` (the chunk's feature-major rows). Lane loops, so it vectorises.
#[inline(always)]
pub fn sh_encode_rows(
    degree: usize,
    x: &[f32],
    y: &[f32],
    z: &[f32],
    out: &mut [f32],
    stride: usize,
) {
    let n = x.len().min(y.len()).min(z.len());
    let (x, y, z) = (&x[..n], &y[..n], &z[..n]);
    // Generic (not `dyn`), so each row's loop is inlined and vectorised.
    #[inline(always)]
    fn fill(r: &mut [f32], x: &[f32], y: &[f32], z: &[f32], f: impl Fn(f32, f32, f32) -> f32) {
        for l in 0..r.len() {
            r[l] = f(x[l], y[l], z[l]);
        }
    }
    macro_rules! row {
        ($k:expr, $f:expr) => {
            fill(&mut out[$k * stride..$k * stride + n], x, y, z, $f)
        };
    }
    row!(0, |_, _, _| 0.282_094_8);
    if degree <= 1 {
        return;
    }
    row!(1, |_, y, _| -0.488_602_5 * y);
    row!(2, |_, _, z| 0.488_602_5 * z);
    row!(3, |x, _, _| -0.488_602_5 * x);
    if degree <= 2 {
        return;
    }
    row!(4, |x, y, _| 1.092_548_4 * x * y);
    row!(5, |_, y, z| -1.092_548_4 * y * z);
    row!(6, |_, _, z| 0.946_174_7 * z * z - 0.315_391_57);
    row!(7, |x, _, z| -1.092_548_4 * x * z);
    row!(8, |x, y, _| 0.546_274_2 * (x * x - y * y));
    if degree <= 3 {
        return;
    }
    row!(9, |x, y, _| 0.590_043_6 * y * (-3.0 * x * x + y * y));
    row!(10, |x, y, z| 2.890_611_4 * x * y * z);
    row!(11, |_, y, z| 0.457_045_8 * y * (1.0 - 5.0 * z * z));
    row!(12, |_, _, z| 0.373_176_33 * z * (5.0 * z * z - 3.0));
    row!(13, |x, _, z| 0.457_045_8 * x * (1.0 - 5.0 * z * z));
    row!(14, |x, y, z| 1.445_305_7 * z * (x * x - y * y));
    row!(15, |x, y, _| 0.590_043_6 * x * (-x * x + 3.0 * y * y));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_match_per_direction() {
        let mut rng = assist_core::Rng::new(8);
        let n = 37;
        let d: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                let v = [
                    rng.normal() as f32,
                    rng.normal() as f32,
                    rng.normal() as f32,
                ];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|x| x / l)
            })
            .collect();
        let (x, y, z): (Vec<f32>, Vec<f32>, Vec<f32>) = (
            d.iter().map(|v| v[0]).collect(),
            d.iter().map(|v| v[1]).collect(),
            d.iter().map(|v| v[2]).collect(),
        );
        for degree in 1..=4 {
            let mut rows = vec![0f32; 16 * 40];
            sh_encode_rows(degree, &x, &y, &z, &mut rows, 40);
            let mut one = [0f32; 16];
            for l in 0..n {
                sh_encode(degree, x[l], y[l], z[l], &mut one);
                for k in 0..degree * degree {
                    assert!((rows[k * 40 + l] - one[k]).abs() < 1e-6, "{degree} {k}");
                }
            }
        }
    }

    /// The basis is orthonormal on the sphere: Monte-Carlo inner products ≈ identity.
    #[test]
    fn orthonormal() {
        let n = 200_000;
        let mut g = [[0f64; 16]; 16];
        let mut rng = assist_core::Rng::new(2);
        let mut c = [0f32; 16];
        for _ in 0..n {
            let z = rng.range(-1.0, 1.0);
            let phi = rng.range(0.0, std::f64::consts::TAU);
            let r = (1.0 - z * z).sqrt();
            sh_encode(
                4,
                (r * phi.cos()) as f32,
                (r * phi.sin()) as f32,
                z as f32,
                &mut c,
            );
            for i in 0..16 {
                for j in 0..16 {
                    g[i][j] += c[i] as f64 * c[j] as f64;
                }
            }
        }
        let area = 4.0 * std::f64::consts::PI;
        for i in 0..16 {
            for j in 0..16 {
                let v = g[i][j] / n as f64 * area;
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((v - want).abs() < 0.03, "<Y{i},Y{j}> = {v}");
            }
        }
    }

    /// The vector-Jacobian product against central differences of `sh_encode`, at every
    /// degree, for random directions off the unit sphere too.
    #[test]
    fn vjp_matches_central_differences() {
        let mut rng = assist_core::Rng::new(11);
        for degree in 1..=4 {
            let n = degree * degree;
            for _ in 0..20 {
                let p = [
                    rng.f32() * 2.0 - 1.0,
                    rng.f32() * 2.0 - 1.0,
                    rng.f32() * 2.0 - 1.0,
                ];
                let g: Vec<f32> = (0..n).map(|_| rng.f32() * 2.0 - 1.0).collect();
                let f = |q: [f64; 3]| {
                    let mut o = [0.0f32; 16];
                    sh_encode(degree, q[0] as f32, q[1] as f32, q[2] as f32, &mut o);
                    (0..n)
                        .map(|k| f64::from(o[k]) * f64::from(g[k]))
                        .sum::<f64>()
                };
                let got = sh_vjp(degree, p[0], p[1], p[2], &g);
                for a in 0..3 {
                    let h = 1e-3;
                    let mut q1 = p.map(f64::from);
                    let mut q0 = q1;
                    q1[a] += h;
                    q0[a] -= h;
                    let want = (f(q1) - f(q0)) / (2.0 * h);
                    assert!(
                        (f64::from(got[a]) - want).abs() < 2e-3 * (1.0 + want.abs()),
                        "degree {degree}, axis {a}: {} against {want}",
                        got[a]
                    );
                }
            }
        }
    }
}
