//! The appearance code a view no photograph was taken from gets: the codes of the
//! training views whose cameras stood nearest, blended by inverse distance.
//!
//! Each training photograph has its own code (exposure, white balance, and whatever else
//! that photograph alone shows). The mean of all codes is not such a code: the colour
//! net never saw it, and where the codes differ much it renders grain and ghosts. The
//! codes of the nearest cameras, which saw the place from about there and under about
//! the same conditions, stay on what the net learnt.

use super::Field;

/// How many of the nearest training cameras a novel view's code blends: three enclose a
/// point on the surface the cameras stood on.
pub const NEAREST_VIEWS: usize = 3;

impl Field {
    pub(super) fn average_code(&self) -> Vec<f32> {
        let a = self.config.appearance_dim;
        let mut avg = vec![0.0f32; a];
        if a == 0 || self.config.num_images == 0 {
            return avg;
        }
        for i in 0..self.config.num_images {
            for k in 0..a {
                avg[k] += self.params[self.layout.appearance + i * a + k];
            }
        }
        avg.iter_mut()
            .for_each(|v| *v /= self.config.num_images as f32);
        avg
    }

    /// The first colour layer's bias for every appearance code, `out` floats each:
    /// `b + W_app · code` for each image, then the average code (novel views) last. The
    /// code is constant over the samples of an image, so its part of the product is folded
    /// into the bias once per call instead of being multiplied per sample. Public for other
    /// backends of the same field (the GPU's), which fold the code the same way.
    pub fn code_biases(&self) -> Vec<f32> {
        self.code_biases_for(None)
    }

    /// [`Field::code_biases`] with the last row (novel views') from `novel`, a code of
    /// `appearance_dim` values, instead of the average code.
    pub fn code_biases_for(&self, novel: Option<&[f32]>) -> Vec<f32> {
        let l = &self.layout.color[0];
        let (a, k0) = (self.config.appearance_dim, self.code_col());
        let b = &self.params[l.b..l.b + l.out];
        if a == 0 {
            return b.to_vec();
        }
        let last = match novel.filter(|c| c.len() == a) {
            Some(c) => c.to_vec(),
            None => self.average_code(),
        };
        let mut out = Vec::with_capacity((self.config.num_images + 1) * l.out);
        for i in 0..=self.config.num_images {
            let code = if i < self.config.num_images {
                let o = self.layout.appearance + i * a;
                &self.params[o..o + a]
            } else {
                &last[..]
            };
            for o in 0..l.out {
                let w = &self.params[l.w + o * l.inp_pad + k0..l.w + o * l.inp_pad + k0 + a];
                out.push(b[o] + w.iter().zip(code).map(|(w, c)| w * c).sum::<f32>());
            }
        }
        out
    }

    /// The code of a view from a camera at `at` (in the field's local frame, the frame of
    /// [`Field::anchors`]): the inverse-distance blend of the [`NEAREST_VIEWS`] nearest
    /// anchors' codes. `None` when the field has no codes or no anchors for them (then
    /// novel views take the average code).
    pub fn novel_code(&self, at: [f64; 3]) -> Option<Vec<f32>> {
        let (a, n) = (self.config.appearance_dim, self.config.num_images);
        if a == 0 || n == 0 || self.anchors.len() != n || !at.iter().all(|v| v.is_finite()) {
            return None;
        }
        let mut near: Vec<(f64, usize)> = self
            .anchors
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let d2: f64 = (0..3).map(|k| (p[k] as f64 - at[k]).powi(2)).sum();
                (d2.sqrt(), i)
            })
            .collect();
        let k = NEAREST_VIEWS.min(n);
        near.select_nth_unstable_by(k - 1, |x, y| x.0.total_cmp(&y.0));
        near.truncate(k);
        // A camera on an anchor takes that anchor's code (the weights' limit).
        let scale = near.iter().map(|x| x.0).fold(0.0, f64::max).max(1e-12);
        let w: Vec<f64> = near.iter().map(|x| 1.0 / (x.0 / scale + 1e-6)).collect();
        let total: f64 = w.iter().sum();
        let mut code = vec![0.0f32; a];
        for ((_, i), w) in near.iter().zip(&w) {
            let c = &self.params[self.layout.appearance + i * a..][..a];
            for (o, v) in code.iter_mut().zip(c) {
                *o += (w / total) as f32 * v;
            }
        }
        Some(code)
    }
}

#[cfg(test)]
mod tests {
    use crate::{Field, FieldConfig, Samples};

    fn field_with_codes(n: usize) -> Field {
        let cfg = FieldConfig {
            log2_table_size: 12,
            levels: 4,
            max_resolution: 64,
            appearance_dim: 8,
            ..FieldConfig::object(n)
        };
        let mut f = Field::new(cfg, 3).unwrap();
        f.anchors = (0..n).map(|i| [i as f32, 0.0, 0.0]).collect();
        f
    }

    /// A camera on an anchor renders as that photograph's code does; one between two
    /// anchors as their blend, nearer the nearer one.
    #[test]
    fn a_camera_at_a_training_view_takes_its_code() {
        let f = field_with_codes(6);
        let a = f.config.appearance_dim;
        let code = |i: usize| f.params[f.layout.appearance + i * a..][..a].to_vec();
        let at2 = f.novel_code([2.0, 0.0, 0.0]).unwrap();
        for (x, y) in at2.iter().zip(code(2)) {
            assert!((x - y).abs() < 1e-5, "{x} {y}");
        }
        // Between anchors 2 and 3, a quarter of the way: anchors 1, 2 and 3 are the
        // nearest three, at 1.25, 0.25 and 0.75.
        let mid = f.novel_code([2.25, 0.0, 0.0]).unwrap();
        let w = [1.0 / 1.25, 1.0 / 0.25, 1.0 / 0.75];
        let t: f64 = w.iter().sum();
        for j in 0..a {
            let want = [1, 2, 3]
                .iter()
                .zip(w)
                .map(|(&i, w)| (w / t) as f32 * code(i)[j])
                .sum::<f32>();
            assert!((mid[j] - want).abs() < 1e-5, "{j}: {} {want}", mid[j]);
        }
        // Samples of a novel view with that code render as the photograph's own.
        let (x, y, z) = ([0.3f32, 0.6], [0.5f32, 0.2], [0.7f32, 0.4]);
        let d = ([0.0f32, 0.6], [0.0f32, 0.0], [1.0f32, 0.8]);
        // Rendering's query and training's (a held-out camera's fit) alike.
        let run = |image: &[u32], novel: Option<&[f32]>, train: bool| {
            let s = Samples {
                pos: [&x, &y, &z],
                dir: [&d.0, &d.1, &d.2],
                image,
            };
            let (mut sig, mut rgb) = (vec![0.0; 2], vec![0.0; 6]);
            let mut tape = crate::Tape::default();
            if train {
                f.forward_train_novel(&s, novel, &mut tape, &mut sig, &mut rgb);
            } else {
                f.forward_at(
                    crate::Precision::F32,
                    None,
                    novel,
                    &s,
                    &mut tape,
                    &mut sig,
                    &mut rgb,
                );
            }
            rgb
        };
        for train in [false, true] {
            let own = run(&[2, 2], None, train);
            let novel = run(&[u32::MAX, u32::MAX], Some(&at2), train);
            let average = run(&[u32::MAX, u32::MAX], None, train);
            for (p, q) in own.iter().zip(&novel) {
                assert!((p - q).abs() < 1e-5, "train {train}: {own:?} {novel:?}");
            }
            assert!(own.iter().zip(&average).any(|(p, q)| (p - q).abs() > 1e-4));
        }
    }

    /// Without anchors (fields trained before them), or without codes, novel views keep
    /// the average code.
    #[test]
    fn no_anchors_no_blend() {
        let mut f = field_with_codes(4);
        f.anchors.clear();
        assert!(f.novel_code([0.0; 3]).is_none());
        assert_eq!(f.code_biases_for(None), f.code_biases());
        let g = Field::new(
            FieldConfig {
                appearance_dim: 0,
                ..f.config.clone()
            },
            1,
        )
        .unwrap();
        assert!(g.novel_code([0.0; 3]).is_none());
    }
}
