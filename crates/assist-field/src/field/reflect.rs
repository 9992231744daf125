//! The reflected view direction of [`FieldConfig::reflect`](crate::FieldConfig) (Ref-NeRF):
//! the density net's last three outputs `m` are a normal `n = m / |m|`, and the colour net
//! sees the ray's direction mirrored about it, `r = d − 2 (d·n) n`, in place of `d`. The
//! predicted normal is held to the density's own (its negative gradient) by a loss the
//! trainer weighs per sample ([`Field::normal_loss`]); the density is not pulled towards
//! the predicted normal (the target's gradient is not taken).

use super::{Field, Samples, Tape};
use crate::hashgrid::{CHUNK, position_grad};

/// Below this length a predicted normal is divided by it instead (a field at its start).
const MIN_LEN: f32 = 1e-6;

/// Lane `l`'s predicted normal from the three rows `m` (`CHUNK` apart), and the length
/// it was divided by.
#[inline(always)]
pub(super) fn unit_normal(m: &[f32], l: usize) -> ([f32; 3], f32) {
    let v = [m[l], m[CHUNK + l], m[2 * CHUNK + l]];
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        .sqrt()
        .max(MIN_LEN);
    (v.map(|x| x / len), len)
}

/// The directions `d` (one slice per axis, a chunk's lanes) mirrored about the normals of
/// the rows `m`, into `out` (per axis; lanes past `d`'s are left as they were).
#[inline(always)]
pub(super) fn reflected(m: &[f32], d: [&[f32]; 3], out: &mut [[f32; CHUNK]; 3]) {
    for l in 0..d[0].len() {
        let (n, _) = unit_normal(m, l);
        let dn = d[0][l] * n[0] + d[1][l] * n[1] + d[2][l] * n[2];
        for a in 0..3 {
            out[a][l] = d[a][l] - 2.0 * dn * n[a];
        }
    }
}

/// Lane `l`'s gradient with respect to the rows `m`, given the gradient `dr` of the
/// reflected direction and `dn_extra` of the unit normal (the normal loss's), for ray
/// direction `d`.
#[inline(always)]
pub(super) fn reflected_backward(
    m: &[f32],
    l: usize,
    d: [f32; 3],
    dr: [f32; 3],
    dn_extra: [f32; 3],
) -> [f32; 3] {
    let (n, len) = unit_normal(m, l);
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (d_n, dr_n) = (dot(d, n), dot(dr, n));
    // r = d − 2 (d·n) n  ⇒  ∂L/∂n = −2 (d (dr·n) + (d·n) dr).
    let g: [f32; 3] = std::array::from_fn(|k| -2.0 * (d[k] * dr_n + d_n * dr[k]) + dn_extra[k]);
    let raw = [m[l], m[CHUNK + l], m[2 * CHUNK + l]];
    if dot(raw, raw).sqrt() <= MIN_LEN {
        return g.map(|x| x / MIN_LEN);
    }
    let ng = dot(n, g);
    std::array::from_fn(|k| (g[k] - n[k] * ng) / len)
}

impl Field {
    /// The first row of the predicted normal in a chunk's activations.
    pub(super) fn normal_row(&self, dens_row: usize) -> usize {
        dens_row + 1 + self.config.geo_features
    }

    /// After a [`forward_train`](Field::forward_train) on `tape`: the density's own
    /// normal at each sample, `−∇σ / |∇σ|`, in a frame where the box's `[0, 1]³` spans
    /// `scale` along its axes (the node's size, so that normals are those of the node's
    /// unscaled shape), into `out` (three per sample; zero where the gradient vanishes).
    pub fn density_normals(&self, s: &Samples, tape: &Tape, scale: [f32; 3], out: &mut [f32]) {
        let n = tape.n;
        assert_eq!(s.len(), n, "density_normals: samples differ from the tape");
        assert!(out.len() >= 3 * n);
        let cfg = &self.config;
        let rows = self.rows();
        let width = cfg.encoding_rows();
        let (d1, d2) = (&self.layout.density[0], &self.layout.density[1]);
        let p = &self.params;
        // dσ_raw/d(encoding) per chunk: W1ᵀ (W2[0] ⊙ [h > 0]).
        let nc = n.div_ceil(CHUNK);
        let mut d_enc = vec![0.0f32; nc * width * CHUNK];
        use rayon::prelude::*;
        d_enc
            .par_chunks_mut(width * CHUNK)
            .enumerate()
            .for_each_init(
                || vec![0.0f32; d1.out * CHUNK],
                |dh, (c, de)| {
                    let act = &tape.act[c * rows.total * CHUNK..(c + 1) * rows.total * CHUNK];
                    for j in 0..d1.out {
                        let w = p[d2.w + j];
                        let h = &act[(rows.hidden + j) * CHUNK..(rows.hidden + j + 1) * CHUNK];
                        for l in 0..CHUNK {
                            dh[j * CHUNK + l] = if h[l] > 0.0 { w } else { 0.0 };
                        }
                    }
                    for f in 0..cfg.encoding_width() {
                        let row = &mut de[f * CHUNK..(f + 1) * CHUNK];
                        for j in 0..d1.out {
                            let w = p[d1.w + j * d1.inp_pad + f];
                            for l in 0..CHUNK {
                                row[l] += w * dh[j * CHUNK + l];
                            }
                        }
                    }
                },
            );
        let mut g = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
        let [gx, gy, gz] = &mut g;
        let grid = &self.layout.grid;
        position_grad(
            grid,
            &p[..grid.param_count()],
            s.pos,
            width,
            &d_enc,
            [gx, gy, gz],
        );
        for i in 0..n {
            let v = [g[0][i] / scale[0], g[1][i] / scale[1], g[2][i] / scale[2]];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let o = &mut out[3 * i..3 * i + 3];
            if len > 1e-12 && len.is_finite() {
                o.iter_mut().zip(v).for_each(|(o, v)| *o = -v / len);
            } else {
                o.fill(0.0);
            }
        }
    }

    /// The normal loss `Σ_i w_i |n_i − t_i|²` of the predicted normals `n` of the samples
    /// of the last [`forward_train`](Field::forward_train) on `tape` against `targets`
    /// (three per sample, taken as constants; zero ones skip their sample): its value,
    /// and its gradient left in the tape for the next [`backward`](Field::backward).
    pub fn normal_loss(&self, tape: &mut Tape, targets: &[f32], weights: &[f32]) -> f64 {
        assert!(
            self.config.reflect,
            "normal_loss: the field predicts no normal"
        );
        let n = tape.n;
        assert!(targets.len() >= 3 * n && weights.len() >= n);
        let rows = self.rows();
        let nr = self.normal_row(rows.dens);
        tape.d_normal.clear();
        tape.d_normal.resize(3 * n, 0.0);
        let mut loss = 0.0f64;
        for i in 0..n {
            let t = &targets[3 * i..3 * i + 3];
            if t.iter().all(|&v| v == 0.0) || weights[i] == 0.0 {
                continue;
            }
            let (c, l) = (i / CHUNK, i % CHUNK);
            let act = &tape.act[c * rows.total * CHUNK..(c + 1) * rows.total * CHUNK];
            let (nv, _) = unit_normal(&act[nr * CHUNK..], l);
            for a in 0..3 {
                let e = nv[a] - t[a];
                loss += f64::from(weights[i]) * f64::from(e) * f64::from(e);
                tape.d_normal[3 * i + a] = 2.0 * weights[i] * e;
            }
        }
        loss
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reflection's backward against central differences of `d − 2 (d·n) n` (n the
    /// unit normal of `m`) under a random linear loss, with and without the normal's own
    /// gradient.
    #[test]
    fn reflection_backward_matches_central_differences() {
        let mut rng = assist_core::Rng::new(5);
        let mut r = || rng.f32() * 2.0 - 1.0;
        for _ in 0..50 {
            let mut m = vec![0.0f32; 3 * CHUNK];
            let l = 3;
            for a in 0..3 {
                m[a * CHUNK + l] = r();
            }
            let mut d = [r(), r(), r()];
            let dl = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d = d.map(|x| x / dl);
            let (dr, dn) = ([r(), r(), r()], [r(), r(), r()]);
            let loss = |m: &[f32]| {
                let (n, _) = unit_normal(m, l);
                let mut out = [[0.0f32; CHUNK]; 3];
                let ds: [Vec<f32>; 3] = std::array::from_fn(|a| vec![d[a]; l + 1]);
                reflected(m, [&ds[0], &ds[1], &ds[2]], &mut out);
                (0..3)
                    .map(|a| f64::from(dr[a] * out[a][l] + dn[a] * n[a]))
                    .sum::<f64>()
            };
            let got = reflected_backward(&m, l, d, dr, dn);
            for a in 0..3 {
                let h = 1e-3;
                let (mut p, mut q) = (m.clone(), m.clone());
                p[a * CHUNK + l] += h;
                q[a * CHUNK + l] -= h;
                let want = (loss(&p) - loss(&q)) / (2.0 * f64::from(h));
                assert!(
                    (f64::from(got[a]) - want).abs() < 1e-2 * (1.0 + want.abs()),
                    "axis {a}: {} against {want}",
                    got[a]
                );
            }
        }
    }
}
