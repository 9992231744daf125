//! Tests of the hash-grid kernels: every dispatched variant against the scalar reference.
use super::*;

pub(super) fn levels() -> Vec<GridLevel> {
    vec![
        GridLevel {
            res: 16,
            size: 17 * 17 * 17,
            dense: true,
        },
        GridLevel {
            res: 1,
            size: 8,
            dense: true,
        },
        GridLevel {
            res: 79,
            size: 1 << 19,
            dense: true,
        },
        GridLevel {
            res: 2048,
            size: 1 << 19,
            dense: false,
        },
        GridLevel {
            res: 300,
            size: 1 << 12,
            dense: false,
        },
    ]
}

/// A level's table of two features, smooth in the entry index.
fn table(lv: &GridLevel) -> Vec<[f32; 2]> {
    (0..lv.size)
        .map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos()])
        .collect()
}

pub(super) fn positions(n: usize, seed: u64) -> [Vec<f32>; 3] {
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32 / (1u64 << 24) as f32) * 1.4 - 0.2
    };
    let mut p = [vec![0f32; n], vec![0f32; n], vec![0f32; n]];
    for l in 0..n {
        for a in 0..3 {
            p[a][l] = next();
        }
    }
    // Faces, corners, NaN and infinities among the lanes.
    let special = [0.0, 1.0, f32::NAN, f32::INFINITY, -f32::INFINITY, 0.5];
    for (l, &v) in special.iter().enumerate().take(n) {
        p[l % 3][l] = v;
    }
    p
}

/// Every level of SIMD against the scalar reference: indices equal, weights and
/// interpolated features within rounding, over lane counts that leave tails.
#[test]
fn simd_matches_scalar() {
    let mut failures = Vec::new();
    for level in [Level::Avx2, Level::Avx512] {
        if !level.supported() {
            eprintln!("!!! SKIP grid level {}: this CPU lacks it", level.name());
            continue;
        }
        for lv in levels() {
            let table = table(&lv);
            for n in [1usize, 7, 16, 37, 64] {
                let p = positions(n, n as u64 + lv.res as u64);
                let pos = [&p[0][..], &p[1][..], &p[2][..]];
                let stride = n + 3;
                let (mut ri, mut rw) = (vec![0u32; 8 * stride], vec![0f32; 8 * stride]);
                let (mut si, mut sw) = (ri.clone(), rw.clone());
                corners(Level::Scalar, &lv, pos, &mut ri, &mut rw, stride);
                corners(level, &lv, pos, &mut si, &mut sw, stride);
                if ri != si || rw.iter().zip(&sw).any(|(a, b)| (a - b).abs() > 1e-6) {
                    failures.push(format!("{} corners res {} n {n}", level.name(), lv.res));
                }
                let (mut r0, mut r1) = (vec![0f32; n], vec![0f32; n]);
                let (mut s0, mut s1) = (vec![0f32; n], vec![0f32; n]);
                interp2(Level::Scalar, &lv, &table, pos, &mut r0, &mut r1);
                interp2(level, &lv, &table, pos, &mut s0, &mut s1);
                let worst = r0
                    .iter()
                    .zip(&s0)
                    .chain(r1.iter().zip(&s1))
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f32, f32::max);
                if worst > 1e-5 || r0.iter().chain(&r1).any(|v| !v.is_finite()) {
                    failures.push(format!(
                        "{} interp2 res {} n {n}: max err {worst}",
                        level.name(),
                        lv.res
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The reference's hash and dense indexing, spelled out for a few corners.
#[test]
fn reference_indices() {
    let dense = GridLevel {
        res: 4,
        size: 125,
        dense: true,
    };
    let (i, w) = corners_one(&dense, 0.3, 0.6, 0.9);
    // cells (1, 2, 3) with fractions (0.2, 0.4, 0.6) of a 5-point-per-axis grid.
    assert_eq!(i[0], 1 + 2 * 5 + 3 * 25);
    assert_eq!(i[7], 2 + 3 * 5 + 4 * 25);
    assert!((w[7] - 0.2 * 0.4 * 0.6).abs() < 1e-6);
    assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    let hashed = GridLevel {
        res: 100,
        size: 1 << 10,
        dense: false,
    };
    let (i, _) = corners_one(&hashed, 0.505, 0.0, 1.0);
    let (cx, cy, cz) = (50u32, 0u32, 99u32);
    let h = |x: u32, y: u32, z: u32| (x ^ y.wrapping_mul(PRIME_Y) ^ z.wrapping_mul(PRIME_Z)) & 1023;
    assert_eq!(i[0], h(cx, cy, cz));
    assert_eq!(i[5], h(cx + 1, cy, cz + 1));
    // NaN lands on the low corner.
    let (i, w) = corners_one(&dense, f32::NAN, 0.0, 0.0);
    assert_eq!(i[0], 0);
    assert!((w[0] - 1.0).abs() < 1e-6);
}

/// A position's interpolation is the same bits wherever it falls in a batch, the lanes
/// left over below a vector's width included (they run on a padded copy), at every level,
/// from f32 and from packed tables: rendering queried in rounds gives a whole query's bits.
#[test]
fn a_position_is_the_same_bits_in_any_batch() {
    for level in [Level::Scalar, Level::Avx2, Level::Avx512] {
        if !level.supported() {
            eprintln!("!!! SKIP grid level {}: this CPU lacks it", level.name());
            continue;
        }
        for lv in levels() {
            let table = table(&lv);
            let packed = super::packed::pack(&table);
            let p = positions(37, 5 + lv.res as u64);
            let run = |r: std::ops::Range<usize>, from_packed: bool| {
                let pos = [&p[0][r.clone()], &p[1][r.clone()], &p[2][r.clone()]];
                let (mut o0, mut o1) = (vec![0f32; r.len()], vec![0f32; r.len()]);
                match from_packed {
                    true => super::packed::interp2_bf16(level, &lv, &packed, pos, &mut o0, &mut o1),
                    false => interp2(level, &lv, &table, pos, &mut o0, &mut o1),
                }
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                (bits(&o0), bits(&o1))
            };
            for from_packed in [false, true] {
                let whole = run(0..37, from_packed);
                for r in [0..3, 5..37, 30..37, 9..25, 36..37] {
                    let part = run(r.clone(), from_packed);
                    assert_eq!(
                        (&part.0[..], &part.1[..]),
                        (&whole.0[r.clone()], &whole.1[r.clone()]),
                        "{} res {} {r:?} packed {from_packed}",
                        level.name(),
                        lv.res
                    );
                }
            }
        }
    }
}
