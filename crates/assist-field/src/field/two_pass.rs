//! Rendering's two-pass inference: the density of every sample first (its density-net
//! outputs kept), then, once the caller has dropped the samples it does not need, the
//! colour net on the rest from those outputs. No sample is encoded twice.

use rayon::prelude::*;

use super::backward::fingerprint;
use super::{Field, MAX_RAW_DENSITY, PackedTables, Precision, Samples, Tape};
use crate::hashgrid::{CHUNK, Layout};

impl Field {
    /// Inference in two passes, for rendering's pruning: [`density_features`] gives every
    /// sample's density and keeps the density net's outputs in `tape`; the caller drops
    /// samples ([`keep_features`]); this runs the colour net on the rest. A sample's
    /// outputs are [`forward_at`]'s, except that the density net runs in f32 whatever
    /// `precision` (where the CPU has AVX-512 BF16, `forward_at`'s are bf16 products).
    ///
    /// [`density_features`]: Self::density_features
    /// [`keep_features`]: Self::keep_features
    /// [`forward_at`]: Self::forward_at
    pub fn forward_from_features(
        &self,
        precision: Precision,
        s: &Samples,
        tape: &Tape,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) {
        let n = s.len();
        assert!(sigma.len() >= n && rgb.len() >= 3 * n);
        let fw = self.density_rows();
        assert!(
            tape.act.len() >= Layout { width: fw }.len(n),
            "features of {n} samples"
        );
        self.nets(precision, s, &tape.act, fw, true, sigma, rgb);
    }

    /// Rows of the density net's output: raw density, then the geometry features.
    fn density_rows(&self) -> usize {
        self.layout.density[1].out
    }

    /// [`density_with`](Self::density_with), keeping every sample's density-net output
    /// (chunk-blocked) in `tape` for [`forward_from_features`](Self::forward_from_features);
    /// encoded from `tables` where given (as [`forward_at`](Self::forward_at)).
    pub fn density_features(
        &self,
        pos: [&[f32]; 3],
        tables: Option<&PackedTables>,
        sigma: &mut [f32],
        tape: &mut Tape,
    ) {
        let n = pos[0].len();
        let fw = self.density_rows();
        let len = Layout { width: fw }.len(n);
        if tape.act.len() < len {
            tape.act.resize(len, 0.0);
        }
        tape.n = 0;
        tape.encoded = None;
        let feats = &mut tape.act[..len];
        let enc = self.encode_blocked(pos, tables, &mut tape.enc);
        let width = self.config.encoding_rows();
        let d1 = self.layout.density[0];
        let d2 = self.layout.density[1];
        sigma[..n]
            .par_chunks_mut(CHUNK)
            .zip(feats.par_chunks_mut(fw * CHUNK))
            .enumerate()
            .for_each_init(
                || vec![0.0f32; d1.out * CHUNK],
                |h, (c, (sig, o))| {
                    let e = &enc[c * width * CHUNK..(c + 1) * width * CHUNK];
                    assist_simd::simd(
                        #[inline(always)]
                        || {
                            d1.forward(&self.params, e, h, true);
                            d2.forward(&self.params, h, o, false);
                            for l in 0..sig.len() {
                                sig[l] = assist_simd::math::exp(o[l].min(MAX_RAW_DENSITY));
                            }
                        },
                    )
                },
            );
    }

    /// Training's density pass ([`density_with`](Self::density_with)) with the encoding
    /// kept in `tape`: the [`forward_train`](Self::forward_train) that follows on the same
    /// samples, or on those [`keep_encoded`](Self::keep_encoded) leaves, reads it instead
    /// of encoding them again. On the same samples the bits are the same; on kept ones
    /// they can differ in the last bits, as a sample's encoding rounds by its place in
    /// the batch (the vector body or the scalar tail).
    pub fn density_encoded(&self, pos: [&[f32]; 3], sigma: &mut [f32], tape: &mut Tape) {
        self.density_with(pos, sigma, &mut tape.enc);
        tape.encoded = Some(fingerprint(pos));
    }

    /// Keeps in `tape`'s encoding (from [`density_encoded`](Self::density_encoded)) only
    /// the samples `kept` (ascending indices), in that order; `pos` are the kept samples'
    /// positions, the ones the next `forward_train` is given.
    pub fn keep_encoded(&self, tape: &mut Tape, kept: &[u32], pos: [&[f32]; 3]) {
        let width = self.config.encoding_rows();
        compact_rows(&mut tape.enc, width, kept);
        tape.encoded = Some(fingerprint(pos));
    }

    /// Keeps in `tape` (from [`density_features`](Self::density_features)) only the
    /// samples `kept` (ascending indices), in that order, as if only they had been queried.
    pub fn keep_features(&self, tape: &mut Tape, kept: &[u32]) {
        compact_rows(&mut tape.act, self.density_rows(), kept);
    }
}

/// Keeps in chunk-blocked `buf` (`width` rows per sample) only the samples `kept`
/// (ascending indices), in that order; the lanes after the last one in its chunk are
/// zeroed so they stay finite.
fn compact_rows(buf: &mut [f32], width: usize, kept: &[u32]) {
    let lay = Layout { width };
    // Ascending sources, each at or after its destination: in place, front to back.
    for (j, &i) in kept.iter().enumerate() {
        let i = i as usize;
        debug_assert!(i >= j);
        if i != j {
            for f in 0..lay.width {
                buf[lay.at(j, f)] = buf[lay.at(i, f)];
            }
        }
    }
    let n = kept.len();
    for j in n..n.div_ceil(CHUNK) * CHUNK {
        for f in 0..lay.width {
            buf[lay.at(j, f)] = 0.0;
        }
    }
}
