//! Adam (bias-corrected) over a flat parameter vector, as one pass that also clears the
//! gradient for the next step. Optional weight decay applies to a chosen range (the MLP
//! weights); the hash tables have their own, applied only to the entries a step touches.
//! Learning-rate schedules belong to the trainer.

use rayon::prelude::*;

#[derive(Debug, Clone)]
pub struct Adam {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// L2 weight decay (added to the gradient) for parameters in `decay_range`.
    pub weight_decay: f32,
    pub decay_range: std::ops::Range<usize>,
    /// Parameters in this range whose gradient is exactly zero are left alone (moments
    /// included), as instant-NGP does for hash-table entries: a rarely touched entry then
    /// does not keep drifting on stale momentum after each hit, which made large tables
    /// diverge in training.
    pub sparse_range: std::ops::Range<usize>,
    /// L2 decay (added to the gradient) of the sparse range's entries that have a
    /// gradient this step: Zip-NeRF's weight decay on the hash grid, applied lazily so
    /// that untouched lines stay skipped. An entry the photographs pull on only weakly is
    /// drawn to zero instead of keeping what a few views put there (the fog a
    /// walk-around's held-out views see; measured in BENCHMARKS.md). 0 = none.
    pub table_decay: f32,
    pub step: u32,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
}

impl Adam {
    /// Nerfacto's settings: β = (0.9, 0.99), ε = 1e-15, no weight decay.
    pub fn new(n: usize) -> Self {
        Adam {
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-15,
            weight_decay: 0.0,
            decay_range: 0..0,
            sparse_range: 0..0,
            table_decay: 0.0,
            step: 0,
            m: vec![0.0; n],
            v: vec![0.0; n],
        }
    }

    /// Adam for a field's parameters as training uses it: the hash tables (everything
    /// before the MLPs) are sparse.
    pub fn for_field(field: &crate::Field) -> Self {
        let mut a = Adam::new(field.layout.total);
        a.sparse_range = 0..field.layout.mlp_start();
        a
    }

    /// One update with learning rate `lr`; zeroes `grad`.
    pub fn update(&mut self, lr: f32, params: &mut [f32], grad: &mut [f32]) {
        assert!(
            params.len() == self.m.len() && grad.len() == self.m.len(),
            "adam: sizes differ"
        );
        self.step += 1;
        let c1 = 1.0 - self.beta1.powi(self.step as i32);
        let c2 = 1.0 - self.beta2.powi(self.step as i32);
        // lr · m̂ / (√v̂ + ε) = (lr / c1) · m / (√v / √c2 + ε)
        let h = Hyper {
            b1: self.beta1,
            b2: self.beta2,
            eps: self.eps,
            step_size: lr / c1,
            inv_sqrt_c2: 1.0 / c2.sqrt(),
        };
        let (wd, dr) = (self.weight_decay, self.decay_range.clone());
        let sr = self.sparse_range.clone();
        let td = self.table_decay;
        const BLOCK: usize = 1 << 14;
        params
            .par_chunks_mut(BLOCK)
            .zip(grad.par_chunks_mut(BLOCK))
            .zip(self.m.par_chunks_mut(BLOCK))
            .zip(self.v.par_chunks_mut(BLOCK))
            .enumerate()
            .for_each(|(bi, (((p, g), m), v))| {
                let base = bi * BLOCK;
                let end = base + p.len();
                let decays = wd != 0.0 && dr.start < end && dr.end > base;
                let sparse = sr.start <= base && end <= sr.end;
                let partly = !sparse && sr.start < end && sr.end > base;
                // One small loop per case, each compiled into the SIMD variants on its own
                // (a closure holding all of them was too large to inline there, and ran at
                // the baseline level; the branchy general loop is 5× slower than the
                // select loop on hash tables).
                if decays || partly {
                    general(h, p, g, m, v, base, (wd, &dr), (td, &sr));
                } else if sparse {
                    assist_simd::simd(
                        #[inline(always)]
                        || sparse_block(h, p, g, m, v, td),
                    );
                } else {
                    assist_simd::simd(
                        #[inline(always)]
                        || dense_block(h, p, g, m, v),
                    );
                }
            });
    }
}

#[derive(Clone, Copy)]
struct Hyper {
    b1: f32,
    b2: f32,
    eps: f32,
    step_size: f32,
    inv_sqrt_c2: f32,
}

/// The Adam rule for one entry with gradient `g`, the moment decays `b1`, `b2` and the
/// step size `step` given (the hyper-parameters', or 1, 1, 0 to leave the entry as it is).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn entry(h: Hyper, b1: f32, b2: f32, step: f32, g: f32, p: &mut f32, m: &mut f32, v: &mut f32) {
    let g = flush_grad(g);
    let mi = flush(b1 * *m + (1.0 - h.b1) * g);
    let vi = flush(b2 * *v + (1.0 - h.b2) * g * g);
    *m = mi;
    *v = vi;
    *p -= step * mi / (vi.sqrt() * h.inv_sqrt_c2 + h.eps);
}

/// Moments below 1e-30 (far from mattering: the step they give is below 1e-15 of the
/// learning rate) are flushed to zero before they decay into subnormal floats, whose
/// arithmetic is tens of times slower on x86: in training, rarely hit hash entries of
/// large backgrounds made Adam 4× slower that way (40 ms per step against 11 ms).
#[inline(always)]
fn flush(x: f32) -> f32 {
    if x.abs() < 1e-30 { 0.0 } else { x }
}

/// Gradients below 1e-17 count as zero (an untouched entry, for the sparse rule): their
/// squares would be subnormal, and with ε = 1e-15 the step they give is below 1e-3 of
/// the learning rate once, then nothing.
#[inline(always)]
fn flush_grad(g: f32) -> f32 {
    if g.abs() < 1e-17 { 0.0 } else { g }
}

/// Every entry updated, except that a cache line whose gradient and moments are all
/// +0.0 is skipped: the rule would leave it exactly as it is (no step, moments and
/// gradient still zero). Most of a shadow grid's lines are such: only the lattice points
/// near the background's surface ever get a gradient.
#[inline(always)]
fn dense_block(h: Hyper, p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32]) {
    const LINE: usize = 16;
    let n = p.len();
    let (g, m, v) = (&mut g[..n], &mut m[..n], &mut v[..n]);
    let bits = |x: &[f32]| x.iter().fold(0u32, |a, x| a | x.to_bits());
    for (((p, g), m), v) in p
        .chunks_mut(LINE)
        .zip(g.chunks_mut(LINE))
        .zip(m.chunks_mut(LINE))
        .zip(v.chunks_mut(LINE))
    {
        if bits(g) == 0 && bits(m) == 0 && bits(v) == 0 {
            continue;
        }
        let k = p.len();
        let (g, m, v) = (&mut g[..k], &mut m[..k], &mut v[..k]);
        for i in 0..k {
            entry(
                h,
                h.b1,
                h.b2,
                h.step_size,
                g[i],
                &mut p[i],
                &mut m[i],
                &mut v[i],
            );
            g[i] = 0.0;
        }
    }
}

/// Entries with an exactly zero gradient are left alone. The rule is folded into the
/// coefficients (β = 1 and step 0 for an untouched entry, whose gradient is 0, so m, v and
/// the parameter come out bit-identical) rather than written as selects between the old
/// and new values: LLVM turns a select whose operand holds a division into a branch, which
/// left this loop scalar (3× slower than the dense loop with every entry touched).
///
/// A cache line of gradients that are all +0.0 is skipped whole: the rule would leave its
/// parameters, moments and gradients as they are, and not reading or writing them is most
/// of the saving, since the sweep is bound by memory and a hash table's step touches few
/// of its entries (two thirds of its lines).
#[inline(always)]
fn sparse_block(h: Hyper, p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], td: f32) {
    const LINE: usize = 16;
    let n = p.len();
    let (g, m, v) = (&mut g[..n], &mut m[..n], &mut v[..n]);
    for (((p, g), m), v) in p
        .chunks_mut(LINE)
        .zip(g.chunks_mut(LINE))
        .zip(m.chunks_mut(LINE))
        .zip(v.chunks_mut(LINE))
    {
        if g.iter().fold(0u32, |a, x| a | x.to_bits()) == 0 {
            continue;
        }
        let k = p.len();
        let (g, m, v) = (&mut g[..k], &mut m[..k], &mut v[..k]);
        for i in 0..k {
            let gi = flush_grad(g[i]);
            let touched = gi != 0.0;
            // (An untouched entry's gradient stays exactly 0: td · p is not added.)
            let gi = if touched { gi + td * p[i] } else { 0.0 };
            let b1 = if touched { h.b1 } else { 1.0 };
            let b2 = if touched { h.b2 } else { 1.0 };
            let step = if touched { h.step_size } else { 0.0 };
            entry(h, b1, b2, step, gi, &mut p[i], &mut m[i], &mut v[i]);
            g[i] = 0.0;
        }
    }
}

/// Blocks where the sparse or the decay range starts or ends (and the MLP weights, which
/// decay): per-entry tests.
#[allow(clippy::too_many_arguments)]
fn general(
    h: Hyper,
    p: &mut [f32],
    g: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    base: usize,
    (wd, dr): (f32, &std::ops::Range<usize>),
    (td, sr): (f32, &std::ops::Range<usize>),
) {
    for i in 0..p.len() {
        let mut gi = flush_grad(g[i]);
        if sr.contains(&(base + i)) {
            if gi == 0.0 {
                continue;
            }
            gi += td * p[i];
        }
        if wd != 0.0 && dr.contains(&(base + i)) {
            gi += wd * p[i];
        }
        entry(
            h,
            h.b1,
            h.b2,
            h.step_size,
            gi,
            &mut p[i],
            &mut m[i],
            &mut v[i],
        );
        g[i] = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradients_whose_squares_would_be_subnormal_count_as_zero() {
        // A whole sparse block (so the vectorised loop runs) with one tiny and one normal
        // gradient: the tiny one leaves its entry untouched, moments included.
        let n = 1 << 14;
        let mut adam = Adam::new(n);
        adam.sparse_range = 0..n;
        let mut p = vec![1.0f32; n];
        let mut g = vec![0.0f32; n];
        g[3] = 1e-20;
        g[5] = 1e-3;
        adam.update(0.1, &mut p, &mut g);
        assert_eq!((p[3], adam.m[3], adam.v[3]), (1.0, 0.0, 0.0));
        assert!((p[5] - 0.9).abs() < 1e-4, "{}", p[5]);
        assert!(adam.v.iter().all(|v| *v == 0.0 || v.is_normal()));
    }

    #[test]
    fn weight_decay_applies_beside_a_sparse_range() {
        // Sparse 0..2 and decay 2..4 in one block: a zero gradient still decays 2..4.
        let mut adam = Adam::new(4);
        adam.sparse_range = 0..2;
        adam.decay_range = 2..4;
        adam.weight_decay = 0.5;
        let mut p = vec![1.0f32; 4];
        adam.update(0.1, &mut p, &mut [0.0; 4]);
        assert_eq!(&p[..2], &[1.0, 1.0]);
        assert!(p[2] < 1.0 && p[3] < 1.0, "{p:?}");
    }

    #[test]
    fn sparse_range_leaves_untouched_entries_alone() {
        let mut adam = Adam::new(4);
        adam.sparse_range = 0..2;
        let mut p = vec![1.0f32; 4];
        adam.update(0.1, &mut p, &mut [1.0; 4]);
        let after_first = p.clone();
        let (m_first, v_first) = (adam.m.clone(), adam.v.clone());
        // Zero gradients: entries 0..2 (sparse) stay, 2..4 keep moving on momentum.
        adam.update(0.1, &mut p, &mut [0.0; 4]);
        assert_eq!(&p[..2], &after_first[..2]);
        assert!(p[2] < after_first[2] && p[3] < after_first[3]);
        assert_eq!(&adam.m[..2], &m_first[..2]);
        assert_eq!(&adam.v[..2], &v_first[..2]);
        assert!(adam.m[2] < m_first[2] && adam.v[2] < v_first[2]);
    }

    /// A direct transcription of the Adam paper's algorithm in f64 (β 0.9/0.99, ε 1e-8,
    /// lr 1e-2), with instant-NGP's sparse rule and L2 weight decay over given ranges.
    struct Reference {
        p: Vec<f64>,
        m: Vec<f64>,
        v: Vec<f64>,
        sparse: std::ops::Range<usize>,
        decay: (std::ops::Range<usize>, f64),
        /// L2 decay of the sparse entries a step gives a gradient.
        table_decay: f64,
    }

    impl Reference {
        fn new(p: &[f32]) -> Self {
            Reference {
                p: p.iter().map(|&x| x as f64).collect(),
                m: vec![0.0; p.len()],
                v: vec![0.0; p.len()],
                sparse: 0..0,
                decay: (0..0, 0.0),
                table_decay: 0.0,
            }
        }
        /// Step `t` (from 1); returns which entries it updated.
        fn step(&mut self, t: i32, g: &[f32]) -> Vec<bool> {
            (0..g.len())
                .map(|i| {
                    let mut gi = g[i] as f64;
                    if self.sparse.contains(&i) {
                        if gi == 0.0 {
                            return false;
                        }
                        gi += self.table_decay * self.p[i];
                    }
                    if self.decay.0.contains(&i) {
                        gi += self.decay.1 * self.p[i];
                    }
                    self.m[i] = 0.9 * self.m[i] + 0.1 * gi;
                    self.v[i] = 0.99 * self.v[i] + 0.01 * gi * gi;
                    let mh = self.m[i] / (1.0 - 0.9f64.powi(t));
                    let vh = self.v[i] / (1.0 - 0.99f64.powi(t));
                    self.p[i] -= 1e-2 * mh / (vh.sqrt() + 1e-8);
                    true
                })
                .collect()
        }
        fn worst(&self, p: &[f32]) -> f64 {
            p.iter()
                .zip(&self.p)
                .map(|(a, b)| (*a as f64 - b).abs())
                .fold(0.0, f64::max)
        }
    }

    /// Against the reference.
    #[test]
    fn matches_reference_adam() {
        let n = 40_000;
        let mut rng = assist_core::Rng::new(4);
        let mut p: Vec<f32> = (0..n).map(|_| rng.f32() - 0.5).collect();
        let mut reference = Reference::new(&p);
        let mut adam = Adam::new(n);
        adam.eps = 1e-8;
        for t in 1..=5 {
            let g: Vec<f32> = (0..n).map(|_| rng.f32() - 0.5).collect();
            let mut gg = g.clone();
            adam.update(1e-2, &mut p, &mut gg);
            assert!(gg.iter().all(|&x| x == 0.0));
            reference.step(t, &g);
        }
        let worst = reference.worst(&p);
        assert!(worst < 1e-5, "{worst}");
    }

    /// The dense rule skips lines whose gradient and moments are all zero, which it would
    /// leave as they are: the same bits as every entry updated one by one (a shadow grid,
    /// most of whose lines never get a gradient); a line touched once keeps moving on its
    /// momentum after its gradient stops.
    #[test]
    fn dense_skips_only_idle_lines() {
        let n = (1 << 14) + 200;
        let mut rng = assist_core::Rng::new(6);
        let p0: Vec<f32> = (0..n).map(|_| rng.f32() - 0.5).collect();
        let (mut p, mut q) = (p0.clone(), p0.clone());
        let mut adam = Adam::new(n);
        let (mut m, mut v) = (vec![0.0f32; n], vec![0.0f32; n]);
        // Lines touched at the first step only, at every step, or never.
        let kind: Vec<u8> = (0..n.div_ceil(16))
            .map(|_| (rng.f32() * 3.0) as u8)
            .collect();
        for t in 1..=4 {
            let g: Vec<f32> = (0..n)
                .map(|i| match (kind[i / 16], t) {
                    (0, 1) | (1, _) => rng.f32() - 0.5,
                    _ => 0.0,
                })
                .collect();
            let mut gg = g.clone();
            adam.update(1e-2, &mut p, &mut gg);
            assert!(gg.iter().all(|&x| x == 0.0));
            let c1 = 1.0 - adam.beta1.powi(t);
            let c2 = 1.0 - adam.beta2.powi(t);
            let h = Hyper {
                b1: adam.beta1,
                b2: adam.beta2,
                eps: adam.eps,
                step_size: 1e-2 / c1,
                inv_sqrt_c2: 1.0 / c2.sqrt(),
            };
            for i in 0..n {
                entry(
                    h,
                    h.b1,
                    h.b2,
                    h.step_size,
                    g[i],
                    &mut q[i],
                    &mut m[i],
                    &mut v[i],
                );
            }
        }
        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&p), bits(&q));
        assert_eq!(bits(&adam.m), bits(&m));
        assert_eq!(bits(&adam.v), bits(&v));
        for (i, k) in kind.iter().enumerate() {
            let (a, b) = (16 * i, (16 * i + 16).min(n));
            let moved = p[a..b] != p0[a..b];
            assert_eq!(moved, *k != 2, "line {i} of kind {k}");
        }
    }

    /// The sparse rule against the reference, over blocks that are wholly sparse (the
    /// vectorised select loop, with untouched lines skipped), partly sparse and dense,
    /// with weight decay beside them and the tables' own decay on their touched entries.
    #[test]
    fn sparse_matches_reference_adam() {
        let n = 3 * (1 << 14) + 100;
        let (sr, dr) = (5000..2 * (1 << 14) + 7000, 2 * (1 << 14) + 8000..n);
        let mut rng = assist_core::Rng::new(5);
        let mut p: Vec<f32> = (0..n).map(|_| rng.f32() - 0.5).collect();
        let p0 = p.clone();
        let mut touched = vec![false; n];
        let mut reference = Reference::new(&p);
        reference.sparse = sr.clone();
        reference.decay = (dr.clone(), 0.1);
        reference.table_decay = 0.05;
        let mut adam = Adam::new(n);
        adam.eps = 1e-8;
        adam.sparse_range = sr.clone();
        adam.table_decay = 0.05;
        adam.decay_range = dr.clone();
        adam.weight_decay = 0.1;
        for t in 1..=6 {
            // Half the lines of 16 untouched (the skipped path), the rest 40% untouched
            // entries, some of them -0.0 (untouched too, but not skipped as a line).
            let mut g = vec![0.0f32; n];
            for line in g.chunks_mut(16) {
                if rng.f32() < 0.5 {
                    continue;
                }
                for x in line {
                    let r = rng.f32();
                    *x = if r < 0.05 {
                        -0.0
                    } else if r < 0.4 {
                        0.0
                    } else {
                        rng.f32() - 0.5
                    };
                }
            }
            let mut gg = g.clone();
            adam.update(1e-2, &mut p, &mut gg);
            assert!(gg.iter().all(|&x| x == 0.0));
            for (t, u) in touched.iter_mut().zip(reference.step(t, &g)) {
                *t |= u;
            }
        }
        let worst = reference.worst(&p);
        assert!(worst < 1e-5, "{worst}");
        // Sparse entries never touched are bit-identical to the start.
        let untouched: Vec<usize> = sr.clone().filter(|&i| !touched[i]).collect();
        assert!(untouched.len() > 20, "{}", untouched.len());
        for i in untouched {
            assert!(
                p[i] == p0[i] && adam.m[i] == 0.0 && adam.v[i] == 0.0,
                "entry {i}"
            );
        }
    }
}
