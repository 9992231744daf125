//! A field's hash tables packed as bf16 pairs, for rendering: half the memory and one
//! 4-byte gather per corner instead of an 8-byte one (`assist_simd::grid::packed`). Only
//! F = 2 tables (Nerfacto's) are packed; the MLPs and the interpolation stay f32. A packed
//! copy is a snapshot: whoever keeps one keeps it beside the parameters it was made from
//! (`assist_render::PackedTables` holds the node's `Arc`, so a training step that changes
//! them works on a copy and the snapshot is never used for them).

use rayon::prelude::*;

use assist_simd::grid::packed;

use super::Field;
use crate::hashgrid::encode2_from;

/// The hash tables of one field as bf16 pairs (feature 0 in the low half).
#[derive(Clone)]
pub struct PackedTables {
    entries: Vec<u32>,
}

impl std::fmt::Debug for PackedTables {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PackedTables({} entries)", self.entries.len())
    }
}

impl PackedTables {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.entries.len() * 4
    }
}

impl Field {
    /// The field's hash tables packed as bf16 pairs; `None` where the grid has other than
    /// two features per level.
    pub fn pack_tables(&self) -> Option<PackedTables> {
        let grid = &self.layout.grid;
        if grid.features != 2 {
            return None;
        }
        let (pairs, _) = self.params[..2 * grid.entries].as_chunks::<2>();
        let mut entries = vec![0u32; pairs.len()];
        entries
            .par_chunks_mut(1 << 16)
            .zip(pairs.par_chunks(1 << 16))
            .for_each(|(dst, src)| {
                for (d, e) in dst.iter_mut().zip(src) {
                    *d = packed::to_bf16(e[0]) as u32 | (packed::to_bf16(e[1]) as u32) << 16;
                }
            });
        Some(PackedTables { entries })
    }

    /// The encoding of `pos` from `tables` (this field's, from [`Self::pack_tables`]) into
    /// chunk-blocked `enc`, as `hashgrid::encode` does from the f32 parameters.
    pub(super) fn encode_packed(&self, tables: &PackedTables, pos: [&[f32]; 3], enc: &mut [f32]) {
        let grid = &self.layout.grid;
        assert!(
            grid.features == 2 && tables.entries.len() == grid.entries,
            "packed tables of another field"
        );
        let width = self.config.encoding_rows();
        encode2_from(grid, &tables.entries, packed::interp2_bf16, pos, width, enc);
    }
}
