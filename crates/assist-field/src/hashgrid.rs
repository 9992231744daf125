//! Multiresolution hash encoding (instant-NGP): L levels of F features, a table of T
//! entries per level; coarse levels whose grid fits the table are indexed directly,
//! finer ones through the spatial hash `x·1 ⊕ y·2654435761 ⊕ z·805459861 mod T`;
//! trilinear interpolation of the 8 corners. Inputs are positions in the node's canonical
//! box, scaled to [0, 1]³ (values outside are clamped).
//!
//! Forward runs level-major (one level's table at a time, so it stays in cache) over the
//! whole batch; backward runs one level per task, so every scatter-add of a level is done
//! by one thread and needs no atomics.

use rayon::prelude::*;

use assist_simd::grid::{self, GridLevel};

use crate::config::FieldConfig;

/// Samples per chunk of the chunk-blocked feature layout (see [`Layout`]).
pub const CHUNK: usize = 64;

/// Geometry of one level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    /// Cells per axis; grid points per axis are `res + 1`.
    pub res: u32,
    /// Entries in this level's table.
    pub size: u32,
    /// Indexed directly (dense) rather than hashed.
    pub dense: bool,
    /// First entry of this level in the parameter vector (in entries, not floats).
    pub offset: usize,
}

/// The grid's levels and parameter count.
#[derive(Debug, Clone, PartialEq)]
pub struct GridLayout {
    pub levels: Vec<Level>,
    pub features: usize,
    pub entries: usize,
}

impl Level {
    /// The level as the SIMD kernels take it.
    pub fn grid(&self) -> GridLevel {
        GridLevel {
            res: self.res,
            size: self.size,
            dense: self.dense,
        }
    }
}

impl GridLayout {
    pub fn new(cfg: &FieldConfig) -> Self {
        let t = 1u64 << cfg.log2_table_size;
        let l = cfg.levels;
        let growth = if l > 1 {
            ((cfg.max_resolution as f64).ln() - (cfg.base_resolution as f64).ln()) / (l - 1) as f64
        } else {
            0.0
        };
        let mut levels = Vec::with_capacity(l);
        let mut offset = 0usize;
        for i in 0..l {
            let res = (cfg.base_resolution as f64 * (growth * i as f64).exp())
                .floor()
                .max(1.0) as u32;
            let side = res as u64 + 1;
            let dense_size = side * side * side;
            let (size, dense) = if dense_size <= t {
                (dense_size as u32, true)
            } else {
                (t as u32, false)
            };
            levels.push(Level {
                res,
                size,
                dense,
                offset,
            });
            offset += size as usize;
        }
        GridLayout {
            levels,
            features: cfg.features_per_level,
            entries: offset,
        }
    }
    pub fn param_count(&self) -> usize {
        self.entries * self.features
    }
}

/// Cell corner and trilinear fractions of a position at a level.
#[inline(always)]
fn locate(lv: &Level, p: [f32; 3]) -> ([u32; 3], [f32; 3]) {
    let r = lv.res as f32;
    let mut cell = [0u32; 3];
    let mut frac = [0f32; 3];
    for a in 0..3 {
        let x = p[a].clamp(0.0, 1.0) * r;
        let c = (x.floor() as u32).min(lv.res - 1);
        cell[a] = c;
        frac[a] = x - c as f32;
    }
    (cell, frac)
}

/// The 8 corner indices (entries, with the level's offset) and trilinear weights: the
/// plain reference implementation, against which the optimised `corners_local` is tested.
pub fn corners(lv: &Level, p: [f32; 3]) -> ([usize; 8], [f32; 8]) {
    let (c, f) = locate(lv, p);
    let mut idx = [0usize; 8];
    let mut w = [0f32; 8];
    for k in 0..8 {
        let (dx, dy, dz) = ((k & 1) as u32, ((k >> 1) & 1) as u32, ((k >> 2) & 1) as u32);
        let (x, y, z) = (c[0] + dx, c[1] + dy, c[2] + dz);
        idx[k] = lv.offset
            + if lv.dense {
                let s = lv.res + 1;
                (x + s * (y + s * z)) as usize
            } else {
                let h = x ^ y.wrapping_mul(2_654_435_761) ^ z.wrapping_mul(805_459_861);
                (h & (lv.size - 1)) as usize
            };
        let wx = if dx == 1 { f[0] } else { 1.0 - f[0] };
        let wy = if dy == 1 { f[1] } else { 1.0 - f[1] };
        let wz = if dz == 1 { f[2] } else { 1.0 - f[2] };
        w[k] = wx * wy * wz;
    }
    (idx, w)
}

/// Chunk-blocked layout of per-sample feature vectors: sample `s` lives in chunk
/// `s / CHUNK` at lane `s % CHUNK`; within a chunk, feature `f` of all lanes is contiguous
/// (`[chunk][feature][lane]`), which is what the MLP's matrix products consume.
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    pub width: usize,
}

impl Layout {
    #[inline(always)]
    pub fn at(&self, sample: usize, feature: usize) -> usize {
        (sample / CHUNK * self.width + feature) * CHUNK + sample % CHUNK
    }
    pub fn len(&self, samples: usize) -> usize {
        samples.div_ceil(CHUNK) * self.width * CHUNK
    }
}

/// Corner indices (within the level's table) and trilinear weights of one position.
#[inline(always)]
fn corners_local(lv: &Level, x: f32, y: f32, z: f32) -> ([usize; 8], [f32; 8]) {
    let (i, w) = grid::corners_one(&lv.grid(), x, y, z);
    (i.map(|i| i as usize), w)
}

/// Encodes `n` positions (structure of arrays, in [0, 1]) into `out`, chunk-blocked with
/// `width ≥ L·F` rows per chunk (rows past `L·F` are left as they are: keep them zero).
/// `out` must hold `Layout { width }.len(n)` values.
pub fn encode(grid: &GridLayout, params: &[f32], pos: [&[f32]; 3], width: usize, out: &mut [f32]) {
    match grid.features {
        1 => encode_f::<1>(grid, params, pos, width, out),
        2 => encode2(grid, params, pos, width, out),
        4 => encode_f::<4>(grid, params, pos, width, out),
        8 => encode_f::<8>(grid, params, pos, width, out),
        f => panic!("unsupported features per level {f}"),
    }
}

/// F = 2 (Nerfacto's), through the vectorised interpolation kernel; same order of work as
/// `encode_f`.
fn encode2(grid: &GridLayout, params: &[f32], pos: [&[f32]; 3], width: usize, out: &mut [f32]) {
    let (table_all, _) = params.as_chunks::<2>();
    encode2_from(grid, table_all, grid::interp2, pos, width, out);
}

/// One F = 2 interpolation kernel over a level's table (f32 pairs or packed bf16 pairs).
pub(crate) type Interp2<T> =
    fn(assist_simd::Level, &GridLevel, &[T], [&[f32]; 3], &mut [f32], &mut [f32]);

/// F = 2 encoding from `table_all` (every level's entries, in the parameters' order)
/// through `interp`, level-major over chunk-blocked rows.
pub(crate) fn encode2_from<T: Sync>(
    grid: &GridLayout,
    table_all: &[T],
    interp: Interp2<T>,
    pos: [&[f32]; 3],
    width: usize,
    out: &mut [f32],
) {
    let n = pos[0].len();
    assert!(width >= grid.levels.len() * 2 && pos[1].len() == n && pos[2].len() == n);
    assert!(
        table_all.len() >= grid.entries,
        "grid: table shorter than the layout"
    );
    let block = width * CHUNK;
    let nc = n.div_ceil(CHUNK);
    assert!(out.len() >= nc * block);
    let simd = assist_simd::level();
    let chunks_per_task = 16;
    for (li, lv) in grid.levels.iter().enumerate() {
        let table = &table_all[lv.offset..lv.offset + lv.size as usize];
        let glv = lv.grid();
        out[..nc * block]
            .par_chunks_mut(block * chunks_per_task)
            .enumerate()
            .for_each(|(t, dst)| {
                let chunks = dst.len() / block;
                for ci in 0..chunks {
                    // This level's rows lie a chunk's block apart (see `backward_level`):
                    // asked for two chunks ahead of their writing.
                    if ci + 2 < chunks {
                        let ahead = (ci + 2) * block + li * 2 * CHUNK;
                        for line in dst[ahead..ahead + 2 * CHUNK].iter().step_by(16) {
                            assist_simd::transpose::prefetch(line);
                        }
                    }
                    let chunk = &mut dst[ci * block..(ci + 1) * block];
                    let s0 = (t * chunks_per_task + ci) * CHUNK;
                    let s1 = (s0 + CHUNK).min(n);
                    let (f0, rest) =
                        chunk[li * 2 * CHUNK..(li + 1) * 2 * CHUNK].split_at_mut(CHUNK);
                    let p = [&pos[0][s0..s1], &pos[1][s0..s1], &pos[2][s0..s1]];
                    interp(simd, &glv, table, p, f0, rest);
                }
            });
    }
}

fn encode_f<const F: usize>(
    grid: &GridLayout,
    params: &[f32],
    pos: [&[f32]; 3],
    width: usize,
    out: &mut [f32],
) {
    let n = pos[0].len();
    assert!(width >= grid.levels.len() * F && pos[1].len() == n && pos[2].len() == n);
    let block = width * CHUNK;
    let nc = n.div_ceil(CHUNK);
    assert!(out.len() >= nc * block);
    let (table_all, _) = params.as_chunks::<F>();
    // Tasks of several chunks; every level in turn over the whole batch, so one level's
    // table is in cache at a time.
    let chunks_per_task = 16;
    for (li, lv) in grid.levels.iter().enumerate() {
        let table = &table_all[lv.offset..lv.offset + lv.size as usize];
        out[..nc * block]
            .par_chunks_mut(block * chunks_per_task)
            .enumerate()
            .for_each(|(t, dst)| {
                assist_simd::simd(
                    #[inline(always)]
                    || encode_task::<F>(lv, table, li, pos, n, t * chunks_per_task, block, dst),
                )
            });
    }
}

#[inline(always)]
fn encode_task<const F: usize>(
    lv: &Level,
    table: &[[f32; F]],
    li: usize,
    pos: [&[f32]; 3],
    n: usize,
    first_chunk: usize,
    block: usize,
    dst: &mut [f32],
) {
    {
        {
            for (ci, chunk) in dst.chunks_mut(block).enumerate() {
                let s0 = (first_chunk + ci) * CHUNK;
                let lanes = CHUNK.min(n - s0);
                let rows = &mut chunk[li * F * CHUNK..(li + 1) * F * CHUNK];
                let (px, py, pz) = (
                    &pos[0][s0..s0 + lanes],
                    &pos[1][s0..s0 + lanes],
                    &pos[2][s0..s0 + lanes],
                );
                // Pass 1: corners and weights of every lane, prefetching the table entries;
                // pass 2: gather. The loads of a whole chunk are in flight together.
                let mut idxs = [[0usize; 8]; CHUNK];
                let mut ws = [[0f32; 8]; CHUNK];
                let last = table.len() - 1;
                for l in 0..lanes {
                    let (idx, w) = corners_local(lv, px[l], py[l], pz[l]);
                    if !lv.dense {
                        for &i in &idx {
                            assist_simd::transpose::prefetch(&table[i.min(last)]);
                        }
                    }
                    idxs[l] = idx;
                    ws[l] = w;
                }
                for l in 0..lanes {
                    let (idx, w) = (&idxs[l], &ws[l]);
                    let mut acc = [0f32; F];
                    for k in 0..8 {
                        let e = &table[idx[k].min(last)];
                        for f in 0..F {
                            acc[f] += w[k] * e[f];
                        }
                    }
                    for f in 0..F {
                        rows[f * CHUNK + l] = acc[f];
                    }
                }
            }
        }
    }
}

/// Accumulates into `grad` (same layout as the parameters) the gradient of the loss with
/// respect to the table entries, given `d_out` (chunk-blocked like `encode`'s output,
/// `width` rows per chunk). One task per level: no two threads add to the same entry.
pub fn encode_backward(
    grid: &GridLayout,
    pos: [&[f32]; 3],
    width: usize,
    d_out: &[f32],
    grad: &mut [f32],
) {
    match grid.features {
        1 => backward_f::<1>(grid, pos, width, d_out, grad),
        2 => backward_f::<2>(grid, pos, width, d_out, grad),
        4 => backward_f::<4>(grid, pos, width, d_out, grad),
        8 => backward_f::<8>(grid, pos, width, d_out, grad),
        f => panic!("unsupported features per level {f}"),
    }
}

fn backward_f<const F: usize>(
    grid: &GridLayout,
    pos: [&[f32]; 3],
    width: usize,
    d_out: &[f32],
    grad: &mut [f32],
) {
    let n = pos[0].len();
    assert!(width >= grid.levels.len() * F);
    let block = width * CHUNK;
    let (g_all, _) = grad.as_chunks_mut::<F>();
    let mut slices: Vec<(usize, &Level, &mut [[f32; F]])> = Vec::with_capacity(grid.levels.len());
    let mut rest = g_all;
    for (li, lv) in grid.levels.iter().enumerate() {
        let (head, tail) = rest.split_at_mut(lv.size as usize);
        slices.push((li, lv, head));
        rest = tail;
    }
    slices.into_par_iter().for_each(|(li, lv, g)| {
        assist_simd::simd(
            #[inline(always)]
            || backward_level::<F>(li, lv, g, pos, n, block, d_out),
        )
    });
}

#[inline(always)]
fn backward_level<const F: usize>(
    li: usize,
    lv: &Level,
    g: &mut [[f32; F]],
    pos: [&[f32]; 3],
    n: usize,
    block: usize,
    d_out: &[f32],
) {
    let last = g.len() - 1;
    let glv = lv.grid();
    let simd = assist_simd::level();
    let mut idx = [0u32; 8 * CHUNK];
    let mut w = [0f32; 8 * CHUNK];
    let mut live = [0u8; CHUNK];
    let nc = n.div_ceil(CHUNK);
    for c in 0..nc {
        let s0 = c * CHUNK;
        let s1 = (s0 + CHUNK).min(n);
        let rows = &d_out[c * block + li * F * CHUNK..c * block + (li + 1) * F * CHUNK];
        // This level's rows of a chunk lie a whole chunk's block apart: a stride the
        // hardware's prefetchers do not follow, so each chunk's rows are asked for two
        // chunks ahead.
        if c + 2 < nc {
            let ahead = (c + 2) * block + li * F * CHUNK;
            for line in d_out[ahead..ahead + F * CHUNK].iter().step_by(16) {
                assist_simd::transpose::prefetch(line);
            }
        }
        let p = [&pos[0][s0..s1], &pos[1][s0..s1], &pos[2][s0..s1]];
        // Corners of every lane (vectorised), then the lanes with a gradient: prefetch
        // their entries, then add.
        grid::corners(simd, &glv, p, &mut idx, &mut w, CHUNK);
        let mut nlive = 0;
        for l in 0..s1 - s0 {
            if (0..F).any(|f| rows[f * CHUNK + l] != 0.0) {
                live[nlive] = l as u8;
                nlive += 1;
                if !lv.dense {
                    for k in 0..8 {
                        assist_simd::transpose::prefetch(
                            &g[(idx[k * CHUNK + l] as usize).min(last)],
                        );
                    }
                }
            }
        }
        for &l in &live[..nlive] {
            let l = l as usize;
            let d: [f32; F] = std::array::from_fn(|f| rows[f * CHUNK + l]);
            for k in 0..8 {
                let wk = w[k * CHUNK + l];
                let e = &mut g[(idx[k * CHUNK + l] as usize).min(last)];
                for f in 0..F {
                    e[f] += wk * d[f];
                }
            }
        }
    }
}

/// The gradient of the loss with respect to each sample's position, given `d_out` =
/// dL/d(encoding) (chunk-blocked like `encode`'s output, `width` rows per chunk; what the
/// backward pass leaves in a tape): the derivative of every level's trilinear weights,
/// `res · Σ_corners ∂w/∂frac · ⟨d, entry⟩`. Written into `out` (one slice per axis, `n`
/// each); zero along an axis where the position is outside [0, 1] (the encoding clamps
/// it there). Level-major like `encode`; used by camera-pose refinement.
pub fn position_grad(
    grid: &GridLayout,
    params: &[f32],
    pos: [&[f32]; 3],
    width: usize,
    d_out: &[f32],
    out: [&mut [f32]; 3],
) {
    let n = pos[0].len();
    let fc = grid.features;
    assert!(width >= grid.levels.len() * fc);
    assert!(d_out.len() >= Layout { width }.len(n));
    let [ox, oy, oz] = out;
    assert!(ox.len() >= n && oy.len() >= n && oz.len() >= n);
    for o in [&mut *ox, &mut *oy, &mut *oz] {
        o[..n].fill(0.0);
    }
    let block = width * CHUNK;
    let chunks_per_task = 16;
    // Level-major, as `encode`: one level's table is in cache at a time.
    for (li, lv) in grid.levels.iter().enumerate() {
        let table = &params[lv.offset * fc..(lv.offset + lv.size as usize) * fc];
        ox[..n]
            .par_chunks_mut(CHUNK * chunks_per_task)
            .zip(oy[..n].par_chunks_mut(CHUNK * chunks_per_task))
            .zip(oz[..n].par_chunks_mut(CHUNK * chunks_per_task))
            .enumerate()
            .for_each(|(t, ((tx, ty), tz))| {
                assist_simd::simd(
                    #[inline(always)]
                    || {
                        for (ci, ((gx, gy), gz)) in tx
                            .chunks_mut(CHUNK)
                            .zip(ty.chunks_mut(CHUNK))
                            .zip(tz.chunks_mut(CHUNK))
                            .enumerate()
                        {
                            let c = t * chunks_per_task + ci;
                            let s0 = c * CHUNK;
                            let rows = &d_out
                                [c * block + li * fc * CHUNK..c * block + (li + 1) * fc * CHUNK];
                            let p = [0, 1, 2].map(|a| &pos[a][s0..s0 + gx.len()]);
                            position_grad_chunk(lv, table, fc, p, rows, [gx, gy, gz]);
                        }
                    },
                )
            });
    }
    // The encoding clamps positions into the box: no gradient along an axis outside it.
    for (a, o) in [ox, oy, oz].into_iter().enumerate() {
        for (g, &x) in o[..n].iter_mut().zip(pos[a]) {
            if !(0.0..=1.0).contains(&x) {
                *g = 0.0;
            }
        }
    }
}

/// One level's share of [`position_grad`] for one chunk of lanes (`p`, `rows` = dL/d of
/// this level's features, `CHUNK` apart), added into `out`. The corners and fractions of
/// every lane first (vectorised), then the entries of the lanes with a gradient
/// prefetched, then each corner's `⟨d, entry⟩` for all lanes (independent loads), then
/// the derivative of the trilinear weights per lane.
#[inline(always)]
fn position_grad_chunk(
    lv: &Level,
    table: &[f32],
    fc: usize,
    p: [&[f32]; 3],
    rows: &[f32],
    out: [&mut [f32]; 3],
) {
    let lanes = p[0].len();
    let last = lv.size as usize - 1;
    let res = lv.res as f32;
    let top = (lv.res - 1) as f32;
    let mut idx = [0u32; 8 * CHUNK];
    let mut w = [0f32; 8 * CHUNK];
    grid::corners(assist_simd::level(), &lv.grid(), p, &mut idx, &mut w, CHUNK);
    // The trilinear fractions, as `locate` computes them (`floor(x)` is exact in f32).
    let mut fr = [[0f32; CHUNK]; 3];
    for a in 0..3 {
        for l in 0..lanes {
            let x = p[a][l].clamp(0.0, 1.0) * res;
            fr[a][l] = x - x.floor().min(top);
        }
    }
    let mut live = [false; CHUNK];
    for (l, v) in live[..lanes].iter_mut().enumerate() {
        *v = (0..fc).any(|f| rows[f * CHUNK + l] != 0.0);
    }
    if !lv.dense {
        for k in 0..8 {
            for l in 0..lanes {
                if live[l] {
                    let e = (idx[k * CHUNK + l] as usize).min(last) * fc;
                    assist_simd::transpose::prefetch(&table[e]);
                }
            }
        }
    }
    let mut dot = [[0f32; CHUNK]; 8];
    for (k, dk) in dot.iter_mut().enumerate() {
        for l in 0..lanes {
            if live[l] {
                let e = (idx[k * CHUNK + l] as usize).min(last) * fc;
                let mut v = 0.0;
                for f in 0..fc {
                    v += rows[f * CHUNK + l] * table[e + f];
                }
                dk[l] = v;
            }
        }
    }
    let [gx, gy, gz] = out;
    for l in 0..lanes {
        if !live[l] {
            continue;
        }
        let f = [fr[0][l], fr[1][l], fr[2][l]];
        let mut gl = [0f32; 3];
        for (k, dk) in dot.iter().enumerate() {
            let v = dk[l];
            let bit = [k & 1, (k >> 1) & 1, (k >> 2) & 1];
            let fac = [0, 1, 2].map(|a| if bit[a] == 1 { f[a] } else { 1.0 - f[a] });
            let sign = bit.map(|b| if b == 1 { v } else { -v });
            gl[0] += sign[0] * fac[1] * fac[2];
            gl[1] += fac[0] * sign[1] * fac[2];
            gl[2] += fac[0] * fac[1] * sign[2];
        }
        gx[l] += gl[0] * res;
        gy[l] += gl[1] * res;
        gz[l] += gl[2] * res;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nerfacto_levels() {
        let g = GridLayout::new(&FieldConfig::nerfacto(1));
        assert_eq!(g.levels.len(), 16);
        assert_eq!(g.levels[0].res, 16);
        assert_eq!(g.levels[15].res, 2048);
        assert!(g.levels[0].dense && !g.levels[15].dense);
        // Dense exactly while (res+1)^3 fits 2^19.
        for lv in &g.levels {
            assert_eq!(lv.dense, ((lv.res as u64 + 1).pow(3)) <= 1 << 19);
        }
    }

    #[test]
    fn optimised_corners_match_reference() {
        let mut rng = assist_core::Rng::new(6);
        for cfg in [FieldConfig::nerfacto(1), FieldConfig::object(1)] {
            let g = GridLayout::new(&cfg);
            for lv in &g.levels {
                for i in 0..500 {
                    // Include the box faces and points outside (clamped).
                    let p = if i < 8 {
                        [(i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32]
                    } else {
                        [rng.f32() * 1.2 - 0.1, rng.f32(), rng.f32()]
                    };
                    let (ri, rw) = corners(lv, p);
                    let (oi, ow) = corners_local(lv, p[0], p[1], p[2]);
                    for k in 0..8 {
                        assert_eq!(
                            ri[k],
                            oi[k] + lv.offset,
                            "level res {} point {p:?} corner {k}",
                            lv.res
                        );
                        assert!((rw[k] - ow[k]).abs() < 1e-6);
                    }
                }
            }
        }
    }

    #[test]
    fn weights_sum_to_one_and_corners_interpolate() {
        let g = GridLayout::new(&FieldConfig::object(1));
        for lv in &g.levels {
            let (_, w) = corners(lv, [0.3, 0.71, 0.05]);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        // At a grid point exactly, one corner has weight 1.
        let lv = &g.levels[0];
        let (_, w) = corners(lv, [2.0 / lv.res as f32, 0.0, 1.0]);
        assert!(w.iter().any(|&x| (x - 1.0).abs() < 1e-5));
    }

    #[test]
    fn position_gradient_matches_central_differences() {
        // φ(p) = Σ d · encode(p): its gradient against central differences, at points whose
        // trilinear fractions are away from cell faces at every level (the encoding is only
        // piecewise smooth).
        let cfg = FieldConfig {
            levels: 4,
            log2_table_size: 8,
            base_resolution: 3,
            max_resolution: 40,
            ..FieldConfig::object(1)
        };
        for features in [2usize, 4] {
            let cfg = FieldConfig {
                features_per_level: features,
                ..cfg.clone()
            };
            let g = GridLayout::new(&cfg);
            let width = cfg.encoding_rows();
            let mut rng = assist_core::Rng::new(21);
            let params: Vec<f32> = (0..g.param_count())
                .map(|_| rng.f32() * 2.0 - 1.0)
                .collect();
            let n = 200;
            let pos: Vec<Vec<f32>> = (0..3)
                .map(|_| (0..n).map(|_| 0.05 + 0.9 * rng.f32()).collect())
                .collect();
            let lay = Layout { width };
            let mut d = vec![0f32; lay.len(n)];
            // Every seventh sample has no gradient at the encoding (skipped, its own 0).
            for s in (0..n).filter(|s| s % 7 != 3) {
                for f in 0..g.levels.len() * features {
                    d[lay.at(s, f)] = rng.f32() * 2.0 - 1.0;
                }
            }
            let phi = |s: usize, p: [f32; 3]| -> f64 {
                let mut v = 0.0f64;
                for (li, lv) in g.levels.iter().enumerate() {
                    let (idx, w) = corners(lv, p);
                    for k in 0..8 {
                        for f in 0..features {
                            v += (d[lay.at(s, li * features + f)]
                                * w[k]
                                * params[idx[k] * features + f])
                                as f64;
                        }
                    }
                }
                v
            };
            let mut out = vec![vec![0f32; n]; 3];
            {
                let [a, b, c] = &mut out[..] else {
                    unreachable!()
                };
                position_grad(
                    &g,
                    &params,
                    [&pos[0], &pos[1], &pos[2]],
                    width,
                    &d,
                    [a, b, c],
                );
            }
            let h = 1e-4f32;
            let mut checked = 0;
            for s in 0..n {
                let p = [pos[0][s], pos[1][s], pos[2][s]];
                let smooth = g
                    .levels
                    .iter()
                    .all(|lv| locate(lv, p).1.iter().all(|&f| f > 0.01 && f < 0.99));
                if !smooth {
                    continue;
                }
                checked += 1;
                for a in 0..3 {
                    let (mut lo, mut hi) = (p, p);
                    lo[a] -= h;
                    hi[a] += h;
                    let num = (phi(s, hi) - phi(s, lo)) / (2.0 * h as f64);
                    let ana = out[a][s] as f64;
                    assert!(
                        (num - ana).abs() <= 2e-2 * (1.0 + num.abs()),
                        "F={features} sample {s} axis {a}: analytic {ana}, numeric {num}"
                    );
                }
            }
            assert!(checked > 20, "only {checked} smooth points");
        }
    }
}
