//! Training's two passes: the density of every sample first, its encoding kept, then,
//! once the caller has dropped the samples it does not need, the forward pass of the rest
//! from that encoding. No sample is encoded twice.

use super::backward::fingerprint;
use super::{Field, Tape};
use crate::hashgrid::{CHUNK, Layout};

impl Field {
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
