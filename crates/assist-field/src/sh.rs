//! Real spherical harmonics up to degree 4 (16 coefficients) of a unit direction, with the
//! constants and sign conventions of tiny-cuda-nn's SH encoding used by Nerfacto.

/// Writes `degree²` coefficients of direction `(x, y, z)` (unit length) into `out`.
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
