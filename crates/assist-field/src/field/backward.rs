//! The training half of a field: the forward pass that records a [`Tape`], and the
//! backward pass that turns the gradients of density and colour into the gradient of
//! every parameter (hash-grid entries, MLP weights, appearance codes).

use rayon::prelude::*;

use super::{Field, PhaseTimes, Samples};
use crate::hashgrid::{CHUNK, Layout, encode, encode_backward, position_grad};

/// `d ← d · [x > 0]` (ReLU backward), as a product with 1 or 0 so that every lane is
/// stored: written as a choice between `d` and 0 (or as a bit mask, which the compiler
/// turns into that choice), it became AVX2 masked stores of the zeros alone, which AMD's
/// cores run many times slower than whole stores. A dropped lane becomes ±0 (its sign
/// from `d`), which adds as 0 wherever it goes.
#[inline(always)]
fn relu_mask(d: &mut [f32], x: &[f32]) {
    for (d, v) in d.iter_mut().zip(x) {
        *d *= if *v > 0.0 { 1.0 } else { 0.0 };
    }
}

/// Activations recorded by `forward_train` for `backward`. Reused across steps: buffers
/// grow to the largest batch and are not reallocated after that.
#[derive(Default)]
pub struct Tape {
    pub(super) n: usize,
    pub(super) enc: Vec<f32>,
    pub(super) d_enc: Vec<f32>,
    pub(super) act: Vec<f32>,
    /// Time spent in each phase by the calls on this tape (accumulated; reset at will).
    pub times: PhaseTimes,
    pub(super) scratch: Vec<std::sync::Mutex<Scratch>>,
    pub(super) scratch_sizes: (usize, usize, usize, usize),
    /// `enc` already holds the encoding of the samples with this [`fingerprint`] (left
    /// by training's density pass, [`Field::density_encoded`]): the next
    /// `forward_train` on them does not encode again.
    pub(super) encoded: Option<(usize, u64)>,
    /// dL/d(unit predicted normal), three per sample, from [`Field::normal_loss`]; the
    /// next backward pass adds it and clears it (empty: none).
    pub(super) d_normal: Vec<f32>,
}

/// What identifies a batch of sample positions for [`Tape::encoded`]: their count and a
/// hash of every coordinate's bits, in order (cheap beside encoding them).
pub(super) fn fingerprint(pos: [&[f32]; 3]) -> (usize, u64) {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for axis in pos {
        let mut a = 0u64;
        for (i, x) in axis.iter().enumerate() {
            a = a.wrapping_add(
                (x.to_bits() as u64 ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15))
                    .wrapping_mul(0xff51_afd7_ed55_8ccd),
            );
        }
        h = (h ^ a).wrapping_mul(0x1000_0000_01b3);
    }
    (pos[0].len(), h)
}

/// Per-thread buffers of the backward pass: the thread's MLP gradient and work rows.
#[derive(Default)]
pub(super) struct Scratch {
    pub(super) g: Vec<f32>,
    pub(super) da: Vec<f32>,
    pub(super) db: Vec<f32>,
    pub(super) xt: Vec<f32>,
    /// Σ dL/d(first colour layer pre-activation) per appearance code (`code_biases` rows).
    pub(super) code_sums: Vec<f32>,
}

impl Field {
    /// After [`backward`](Self::backward) on `tape`: the gradient of the same loss with
    /// respect to each sample's position (in the [0, 1]³ box, one slice per axis), through
    /// the hash-grid encoding (the view direction's part, through the spherical harmonics,
    /// is not included). For refining camera poses.
    pub fn position_grad(&self, s: &Samples, tape: &Tape, out: [&mut [f32]; 3]) {
        assert_eq!(
            s.len(),
            tape.n,
            "position_grad: samples differ from the tape"
        );
        let grid = &self.layout.grid;
        position_grad(
            grid,
            &self.params[..grid.param_count()],
            s.pos,
            self.config.encoding_rows(),
            &tape.d_enc,
            out,
        );
    }

    /// Training forward: like `forward`, recording activations in `tape`.
    pub fn forward_train(&self, s: &Samples, tape: &mut Tape, sigma: &mut [f32], rgb: &mut [f32]) {
        self.forward_train_novel(s, None, tape, sigma, rgb)
    }

    /// [`Field::forward_train`] where samples without an image's code (`u32::MAX`) take
    /// `novel` (`None`: the average code), as [`Field::forward_at`] does.
    pub fn forward_train_novel(
        &self,
        s: &Samples,
        novel: Option<&[f32]>,
        tape: &mut Tape,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) {
        let n = s.len();
        assert!(sigma.len() >= n && rgb.len() >= 3 * n);
        let width = self.config.encoding_rows();
        let rows = self.rows();
        let nc = n.div_ceil(CHUNK);
        let enc_len = Layout { width }.len(n);
        let encoded = tape.encoded.take() == Some(fingerprint(s.pos));
        if tape.enc.len() < enc_len {
            tape.enc.resize(enc_len, 0.0);
        }
        if tape.d_enc.len() < enc_len {
            tape.d_enc.resize(enc_len, 0.0);
        }
        if tape.act.len() < nc * rows.total * CHUNK {
            tape.act.resize(nc * rows.total * CHUNK, 0.0);
        }
        tape.n = n;
        let t0 = std::time::Instant::now();
        if !encoded {
            // Lanes past the end of the last chunk are zeroed so they stay finite.
            if !n.is_multiple_of(CHUNK) {
                let last = &mut tape.enc[(nc - 1) * width * CHUNK..nc * width * CHUNK];
                last.fill(0.0);
            }
            encode(&self.layout.grid, &self.params, s.pos, width, &mut tape.enc);
        }
        let t1 = std::time::Instant::now();
        tape.times.encode_forward += (t1 - t0).as_secs_f64();
        let biases = self.code_biases_for(novel);
        let block = width * CHUNK;
        let enc = &tape.enc;
        tape.act[..nc * rows.total * CHUNK]
            .par_chunks_mut(rows.total * CHUNK)
            .zip(sigma[..n].par_chunks_mut(CHUNK))
            .zip(rgb[..3 * n].par_chunks_mut(3 * CHUNK))
            .enumerate()
            .for_each(|(c, ((act, sig), col))| {
                self.chunk_outputs(
                    s,
                    c,
                    &enc[c * block..(c + 1) * block],
                    act,
                    &rows,
                    &biases,
                    None,
                    sig,
                    col,
                )
            });
        tape.times.mlp_forward += t1.elapsed().as_secs_f64();
    }

    /// The appearance part of the first colour layer, from `sums` (per code, Σ of dL/dy
    /// over its samples): `dW_app += s codeᵀ` and `d code += W_appᵀ s`; the average code
    /// spreads its gradient evenly over every image's code.
    fn code_backward(&self, sums: &[f32], grad: &mut [f32]) {
        let (cfg, l) = (&self.config, &self.layout.color[0]);
        let (a, k0, ni) = (cfg.appearance_dim, self.code_col(), cfg.num_images);
        let avg = self.average_code();
        for (slot, sm) in sums.chunks_exact(l.out).enumerate() {
            if sm.iter().all(|&v| v == 0.0) {
                continue;
            }
            let code_at = |k: usize| {
                if slot < ni {
                    self.params[self.layout.appearance + slot * a + k]
                } else {
                    avg[k]
                }
            };
            let mut dcode = vec![0.0f32; a];
            for (o, &so) in sm.iter().enumerate() {
                let w0 = l.w + o * l.inp_pad + k0;
                for k in 0..a {
                    grad[w0 + k] += so * code_at(k);
                    dcode[k] += self.params[w0 + k] * so;
                }
            }
            if slot < ni {
                let o = self.layout.appearance + slot * a;
                grad[o..o + a]
                    .iter_mut()
                    .zip(&dcode)
                    .for_each(|(g, d)| *g += d);
            } else {
                for i in 0..ni {
                    let o = self.layout.appearance + i * a;
                    grad[o..o + a]
                        .iter_mut()
                        .zip(&dcode)
                        .for_each(|(g, d)| *g += d / ni as f32);
                }
            }
        }
    }

    /// Backward: given dL/dσ and dL/drgb (interleaved) for the samples of the last
    /// `forward_train`, accumulates dL/dθ into `grad` (same layout as `params`).
    pub fn backward(
        &self,
        s: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
        grad: &mut [f32],
    ) {
        assert!(grad.len() == self.layout.total);
        self.backward_nets(s, tape, d_sigma, d_rgb, Some(grad));
        let mlp0 = self.layout.mlp_start();
        let t1 = std::time::Instant::now();
        let width = self.config.encoding_rows();
        encode_backward(
            &self.layout.grid,
            s.pos,
            width,
            &tape.d_enc,
            &mut grad[..mlp0],
        );
        tape.times.encode_backward += t1.elapsed().as_secs_f64();
    }

    /// The backward pass through the nets alone, for a loss whose parameters stay fixed:
    /// it leaves dL/d(encoding) in the tape for [`position_grad`](Self::position_grad)
    /// and computes no parameter's gradient (a camera fitted to a frozen scene).
    pub fn backward_to_encoding(
        &self,
        s: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
    ) {
        self.backward_nets(s, tape, d_sigma, d_rgb, None);
    }

    /// The nets' backward: dL/d(encoding) into the tape and, with `grad`, the nets' and
    /// appearance codes' gradient added into it.
    fn backward_nets(
        &self,
        s: &Samples,
        tape: &mut Tape,
        d_sigma: &[f32],
        d_rgb: &[f32],
        mut grad: Option<&mut [f32]>,
    ) {
        let n = tape.n;
        assert_eq!(
            s.len(),
            n,
            "backward: samples differ from the recorded forward"
        );
        let cfg = &self.config;
        let lay = &self.layout;
        let rows = self.rows();
        let width = cfg.encoding_rows();
        let block = width * CHUNK;
        let nc = n.div_ceil(CHUNK);
        let mlp0 = lay.mlp_start();
        let mlp_len = lay.total - mlp0;
        let t0 = std::time::Instant::now();
        let wts: Vec<Vec<f32>> = lay
            .density
            .iter()
            .chain(&lay.color)
            .map(|l| l.transposed(&self.params))
            .collect();
        let a = cfg.appearance_dim;
        // One scratch set per worker thread, kept in the tape across steps (no allocation
        // in the hot loop); each holds that thread's share of the MLP gradient.
        let code_rows = if a > 0 { cfg.num_images + 1 } else { 0 };
        let sizes = (
            mlp_len,
            rows.total * CHUNK,
            CHUNK * self.max_inputs(),
            code_rows * lay.color[0].out,
        );
        ensure_scratch(tape, sizes);
        let chunk = ChunkBackward {
            field: self,
            s,
            wts: &wts,
            act: &tape.act,
            enc: &tape.enc,
            rows: &rows,
            d_sigma,
            d_rgb,
            d_normal: if tape.d_normal.len() >= 3 * n {
                &tape.d_normal
            } else {
                &[]
            },
            n,
            block,
            mlp0,
            k0: self.product_cols(),
        };
        let scratch = &tape.scratch;
        // The chunks are split into one contiguous run per scratch set, each run summed in
        // chunk order into its own set, and the sets summed in order below: the gradient is
        // the same bits on every run with the same thread count (a set per whichever thread
        // took a chunk made training differ from run to run). Chunks cost the same, so the
        // static split balances.
        let per = nc.div_ceil(scratch.len()).max(1);
        tape.d_enc[..nc * block]
            .par_chunks_mut(per * block)
            .enumerate()
            .for_each(|(slot, d_run)| {
                let mut guard = scratch[slot].lock().unwrap_or_else(|p| p.into_inner());
                assist_simd::simd(
                    #[inline(always)]
                    || {
                        let end = ((slot + 1) * per).min(nc);
                        for (k, d_enc) in d_run.chunks_mut(block).enumerate() {
                            let c = slot * per + k;
                            if c + 1 < end {
                                chunk.prefetch(c + 1);
                            }
                            chunk.run(c, d_enc, &mut guard);
                        }
                    },
                );
            });
        tape.d_normal.clear();
        let mut sums = vec![0.0f32; sizes.3];
        for sc in scratch {
            let mut sc = sc.lock().unwrap_or_else(|p| p.into_inner());
            match grad.as_deref_mut() {
                Some(grad) => {
                    for (g, m) in grad[mlp0..].iter_mut().zip(sc.g.iter_mut()) {
                        *g += *m;
                        *m = 0.0;
                    }
                }
                None => sc.g.fill(0.0),
            }
            for (t, m) in sums.iter_mut().zip(sc.code_sums.iter_mut()) {
                *t += *m;
                *m = 0.0;
            }
        }
        if a > 0
            && let Some(grad) = grad
        {
            self.code_backward(&sums, grad);
        }
        tape.times.mlp_backward += t0.elapsed().as_secs_f64();
    }
}

/// Makes the tape's scratch sets (one per worker thread) the sizes asked for, keeping
/// them when they already are.
fn ensure_scratch(tape: &mut Tape, sizes: (usize, usize, usize, usize)) {
    let threads = rayon::current_num_threads().max(1);
    if tape.scratch.len() != threads || tape.scratch_sizes != sizes {
        tape.scratch = (0..threads)
            .map(|_| {
                std::sync::Mutex::new(Scratch {
                    g: vec![0.0; sizes.0],
                    da: vec![0.0; sizes.1],
                    db: vec![0.0; sizes.1],
                    xt: vec![0.0; sizes.2],
                    code_sums: vec![0.0; sizes.3],
                })
            })
            .collect();
        tape.scratch_sizes = sizes;
    }
}

/// The MLP backward of one chunk of samples, with what every chunk reads: the
/// forward's record, the transposed weights, the loss's gradients of density and colour.
struct ChunkBackward<'a> {
    field: &'a Field,
    s: &'a Samples<'a>,
    wts: &'a [Vec<f32>],
    act: &'a [f32],
    enc: &'a [f32],
    rows: &'a super::layout::Rows,
    d_sigma: &'a [f32],
    d_rgb: &'a [f32],
    /// dL/d(unit predicted normal), three per sample, or empty.
    d_normal: &'a [f32],
    n: usize,
    block: usize,
    mlp0: usize,
    /// The first colour layer's product columns (geometry + SH).
    k0: usize,
}

impl ChunkBackward<'_> {
    /// The predicted normal's rows of dL/d(density net output) in `db`, from the SH
    /// rows of dL/d(colour input) in `dcin` and the normal loss's gradient.
    #[inline(always)]
    fn normal_backward(&self, c0: usize, lanes: usize, m: &[f32], dcin: &[f32], db: &mut [f32]) {
        let cfg = &self.field.config;
        let (geo, shw) = (cfg.geo_features, cfg.sh_width());
        let nr = 1 + geo;
        for l in 0..lanes {
            let i = c0 + l;
            let d = [self.s.dir[0][i], self.s.dir[1][i], self.s.dir[2][i]];
            let (n, _) = super::reflect::unit_normal(m, l);
            let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
            let r: [f32; 3] = std::array::from_fn(|a| d[a] - 2.0 * dn * n[a]);
            let mut g = [0.0f32; 16];
            for (k, gk) in g.iter_mut().enumerate().take(shw) {
                *gk = dcin[(geo + k) * CHUNK + l];
            }
            let dr = crate::sh::sh_vjp(cfg.sh_degree, r[0], r[1], r[2], &g);
            let extra = match self.d_normal.get(3 * i..3 * i + 3) {
                Some(e) => [e[0], e[1], e[2]],
                None => [0.0; 3],
            };
            let dm = super::reflect::reflected_backward(m, l, d, dr, extra);
            for a in 0..3 {
                db[(nr + a) * CHUNK + l] = dm[a];
            }
        }
    }

    /// Asks for chunk `c`'s record (its activations and encoding) ahead of its turn: the
    /// forward left it in memory, and read on demand each of its rows waits there.
    #[inline(always)]
    fn prefetch(&self, c: usize) {
        let per = self.rows.total * CHUNK;
        super::prefetch_all(&self.act[c * per..(c + 1) * per]);
        super::prefetch_all(&self.enc[c * self.block..(c + 1) * self.block]);
    }

    /// Chunk `c`: its MLP gradient summed into the scratch set `sc`, its gradient of the
    /// encoding written to `d_enc`. Inlined into the SIMD-dispatched loop.
    #[inline(always)]
    fn run(&self, c: usize, d_enc: &mut [f32], sc: &mut Scratch) {
        let lay = &self.field.layout;
        let (rows, mlp0, k0) = (self.rows, self.mlp0, self.k0);
        let (geo, a) = (
            self.field.config.geo_features,
            self.field.config.appearance_dim,
        );
        let (d_sigma, d_rgb, n) = (self.d_sigma, self.d_rgb, self.n);
        let Scratch {
            g,
            da: da_buf,
            db: db_buf,
            xt,
            code_sums,
        } = sc;
        let (g, xt) = (g.as_mut_slice(), xt.as_mut_slice());
        let (mut da, mut db) = (da_buf.as_mut_slice(), db_buf.as_mut_slice());
        let act = &self.act[c * rows.total * CHUNK..(c + 1) * rows.total * CHUNK];
        let row = |r: usize, k: usize| &act[r * CHUNK..(r + k) * CHUNK];
        let c0 = c * CHUNK;
        let lanes = CHUNK.min(n - c0);
        // dL/d(rgb pre-activation) into `da` (3 rows).
        da[..3 * CHUNK].fill(0.0);
        for l in 0..lanes {
            for k in 0..3 {
                let y = act[(rows.rgb + k) * CHUNK + l];
                da[k * CHUNK + l] = d_rgb[3 * (c0 + l) + k] * y * (1.0 - y);
            }
        }
        // Colour layers, last to first; `da` holds dL/d(pre-activation).
        let nl = lay.color.len();
        for li in (1..nl).rev() {
            let l = &lay.color[li];
            let x = row(rows.color[li - 1], l.inp_pad);
            l.backward(
                &self.wts[2 + li],
                x,
                &da[..l.out * CHUNK],
                g,
                mlp0,
                Some(&mut db[..l.inp_pad * CHUNK]),
                xt,
                l.inp_pad,
            );
            relu_mask(&mut db[..l.inp_pad * CHUNK], x);
            std::mem::swap(&mut da, &mut db);
        }
        // First colour layer: the product's columns (geometry + SH), dx for the
        // geometry rows only (SH has no parameters), and the appearance part
        // summed per code: Σ dy over a code's lanes gives both its weight
        // gradient and its code gradient (after the loop over chunks).
        let l0 = &lay.color[0];
        let reflect = self.field.config.reflect;
        // With a reflected direction, dx for the SH rows too (they depend on the normal).
        let dx_rows = if reflect {
            k0
        } else {
            crate::mlp::pad16(geo).min(l0.inp_pad)
        };
        l0.backward(
            &self.wts[2],
            row(rows.cin, l0.inp_pad),
            &da[..l0.out * CHUNK],
            g,
            mlp0,
            // (16 rows rather than the 15 geometry ones: the fast kernel.)
            Some(&mut db[..dx_rows * CHUNK]),
            xt,
            k0,
        );
        if a > 0 {
            let mut slots = [0u32; CHUNK];
            let dy = &da[..l0.out * CHUNK];
            if self.field.chunk_slots(self.s, c0, &mut slots) {
                let sum = &mut code_sums[slots[0] as usize * l0.out..][..l0.out];
                for (o, r) in dy.chunks_exact(CHUNK).enumerate() {
                    sum[o] += crate::mlp::row_sum(&r[..lanes]);
                }
            } else {
                add_code_sums(dy, &slots[..lanes], l0.out, code_sums);
            }
        }
        std::mem::swap(&mut da, &mut db);
        // dL/d(density net output) into `db`: row 0 from σ, rows 1.. from geo.
        let d2 = &lay.density[1];
        db[..d2.out * CHUNK].fill(0.0);
        for l in 0..lanes {
            let sig = act[rows.sigma * CHUNK + l];
            db[l] = d_sigma[c0 + l] * sig;
        }
        db[CHUNK..(1 + geo) * CHUNK].copy_from_slice(&da[..geo * CHUNK]);
        if reflect {
            self.normal_backward(c0, lanes, row(self.field.normal_row(rows.dens), 3), da, db);
        }
        let hid = row(rows.hidden, d2.inp_pad);
        d2.backward(
            &self.wts[1],
            hid,
            &db[..d2.out * CHUNK],
            g,
            mlp0,
            Some(&mut da[..d2.inp_pad * CHUNK]),
            xt,
            d2.inp_pad,
        );
        relu_mask(&mut da[..d2.inp_pad * CHUNK], hid);
        let d1 = &lay.density[0];
        d1.backward(
            &self.wts[0],
            &self.enc[c * self.block..(c + 1) * self.block],
            &da[..d1.out * CHUNK],
            g,
            mlp0,
            Some(d_enc),
            xt,
            d1.inp_pad,
        );
    }
}

/// `sums[slot[l]][o] += dy[o][l]` for every lane `l` (in lane order) and output `o`: a
/// chunk whose samples come from several images. A ray's samples are adjacent and share
/// an image, so the lanes go by runs of one slot, each output's sum held in a register
/// over its run: the same additions in the same order as lane by lane through memory,
/// without each addition waiting on the store before it.
#[inline(always)]
fn add_code_sums(dy: &[f32], slots: &[u32], out: usize, sums: &mut [f32]) {
    for (slot, run) in crate::mlp::slot_runs(slots) {
        let sum = &mut sums[slot as usize * out..][..out];
        for (o, acc) in sum.iter_mut().enumerate() {
            *acc = dy[o * CHUNK + run.start..o * CHUNK + run.end]
                .iter()
                .fold(*acc, |a, &v| a + v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ReLU's backward keeps a lane's gradient where the activation is positive and
    /// zeroes it elsewhere (0, negative, NaN), at every length the vector loop may split.
    #[test]
    fn relu_mask_keeps_the_active_lanes_only() {
        for n in [0, 1, 7, 8, 31, 64, 67] {
            let x: Vec<f32> = (0..n)
                .map(|i| match i % 4 {
                    0 => 1.5 + i as f32,
                    1 => -0.25,
                    2 => 0.0,
                    _ => f32::NAN,
                })
                .collect();
            let mut d: Vec<f32> = (0..n).map(|i| i as f32 - 3.5).collect();
            relu_mask(&mut d, &x);
            for i in 0..n {
                let want = if i % 4 == 0 { i as f32 - 3.5 } else { 0.0 };
                assert_eq!(d[i], want, "lane {i} of {n}");
            }
        }
    }

    /// The run-wise sums are the lane-by-lane sums bit for bit, whatever the runs (one
    /// slot, alternating slots, a slot coming back after another).
    #[test]
    fn code_sums_by_runs_equal_lane_by_lane() {
        let out = 5;
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let dy: Vec<f32> = (0..out * CHUNK)
            .map(|_| (next() % 20_001) as f32 * 1e-4 - 1.0)
            .collect();
        let cases: [Vec<u32>; 4] = [
            vec![2; CHUNK],
            (0..CHUNK as u32).map(|l| l % 2).collect(),
            (0..CHUNK as u32)
                .map(|l| [0, 0, 1, 1, 1, 0, 3][l as usize % 7])
                .collect(),
            (0..40).map(|l| (l / 9) as u32).collect(),
        ];
        for slots in cases {
            let start: Vec<f32> = (0..5 * out).map(|i| i as f32 * 0.37).collect();
            let mut want = start.clone();
            for o in 0..out {
                for (l, &sl) in slots.iter().enumerate() {
                    want[sl as usize * out + o] += dy[o * CHUNK + l];
                }
            }
            let mut got = start;
            add_code_sums(&dy, &slots, out, &mut got);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "slots {slots:?}");
        }
    }
}
