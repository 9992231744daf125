//! Eigenvalues and eigenvectors of small symmetric matrices by cyclic Jacobi rotations:
//! exact to rounding, with no pivoting to get wrong, and fast enough for the 3×3 and 4×4
//! matrices geometry needs (an up direction, Horn's rotation fit).

/// Eigenvalues, largest first, and their unit eigenvectors (`vectors[k]` belongs to
/// `values[k]`) of the symmetric `N`×`N` matrix `a` (rows; only symmetric input is
/// meaningful). Non-finite input gives non-finite output, never a panic.
pub fn symmetric_eigen<const N: usize>(mut a: [[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut v = [[0.0f64; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..64 {
        let (mut off, mut diag) = (0.0, 0.0);
        for (i, row) in a.iter().enumerate() {
            for (j, x) in row.iter().enumerate() {
                if i == j {
                    diag += x * x;
                } else {
                    off += x * x;
                }
            }
        }
        // Finished once what is left off the diagonal is rounding (or nothing is finite).
        if off.is_nan() || off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                // The rotation in the (p, q) plane that zeroes a[p][q] (the smaller angle).
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
                for k in 0..N {
                    let (pk, qk) = (a[p][k], a[q][k]);
                    a[p][k] = c * pk - s * qk;
                    a[q][k] = s * pk + c * qk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    // Column k of `v` is the eigenvector of a[k][k].
    let mut order = [0usize; N];
    for (i, o) in order.iter_mut().enumerate() {
        *o = i;
    }
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = order.map(|k| a[k][k]);
    let vectors = order.map(|k| {
        let e: [f64; N] = std::array::from_fn(|i| v[i][k]);
        let n = e.iter().map(|x| x * x).sum::<f64>().sqrt();
        e.map(|x| x / n)
    });
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q diag(λ) Qᵀ for an orthonormal Q built by Gram–Schmidt from fixed rows.
    fn with_spectrum<const N: usize>(lambda: [f64; N], seed: u64) -> [[f64; N]; N] {
        let mut rng = crate::Rng::new(seed);
        let mut q = [[0.0f64; N]; N];
        for i in 0..N {
            let mut r: [f64; N] = std::array::from_fn(|_| rng.f64() - 0.5);
            for prev in q.iter().take(i) {
                let d: f64 = r.iter().zip(prev).map(|(a, b)| a * b).sum();
                for (x, p) in r.iter_mut().zip(prev) {
                    *x -= d * p;
                }
            }
            let n = r.iter().map(|x| x * x).sum::<f64>().sqrt();
            q[i] = r.map(|x| x / n);
        }
        std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..N).map(|k| q[k][i] * lambda[k] * q[k][j]).sum())
        })
    }

    fn check<const N: usize>(lambda: [f64; N], seed: u64) {
        let a = with_spectrum(lambda, seed);
        let (values, vectors) = symmetric_eigen(a);
        let mut want = lambda;
        want.sort_by(|x, y| y.total_cmp(x));
        for (w, g) in want.iter().zip(values) {
            assert!((w - g).abs() < 1e-12, "{values:?} against {want:?}");
        }
        for (l, v) in values.iter().zip(vectors) {
            for (i, row) in a.iter().enumerate() {
                let av: f64 = row.iter().zip(v).map(|(x, y)| x * y).sum();
                assert!((av - l * v[i]).abs() < 1e-12, "A v ≠ λ v for λ = {l}");
            }
        }
    }

    #[test]
    fn decomposes_symmetric_matrices_of_several_sizes() {
        check([0.2, 3.0, -1.0], 1);
        check([4.0, -2.0, 0.5, 1.5], 2);
        // Repeated eigenvalues: any basis of the shared space will do, each must be one.
        check([1.0, 1.0, -3.0, 7.0, 0.0], 3);
    }

    #[test]
    fn a_diagonal_matrix_is_its_own_answer_and_nan_does_not_panic() {
        let (values, vectors) = symmetric_eigen([[2.0, 0.0], [0.0, 5.0]]);
        assert_eq!(values, [5.0, 2.0]);
        assert_eq!(vectors, [[0.0, 1.0], [1.0, 0.0]]);
        let (values, _) = symmetric_eigen([[f64::NAN, 1.0], [1.0, 0.0]]);
        assert!(values.iter().any(|v| v.is_nan()));
    }
}
