//! Mass properties of a closed, outward-oriented triangle mesh of uniform density: volume,
//! centre of mass and inertia tensor about it, summed over the signed tetrahedra the
//! triangles span with the origin (each tetrahedron's second moment is
//! `V/20 · (Σ xᵢxᵢᵀ + s sᵀ)`, `s` the sum of its three vertices).

use serde::Serialize;

/// Mass properties for density 1 unless scaled (`mass` = volume × density).
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct MassProperties {
    pub volume: f64,
    pub mass: f64,
    pub center: [f64; 3],
    /// Inertia tensor about `center` (row-major, symmetric), in mass × length².
    pub inertia: [[f64; 3]; 3],
}

/// Mass properties of the mesh `positions`/`triangles` with `density` (mass per unit
/// volume). A mesh that is not closed gives meaningless values; a negative volume means
/// inward orientation.
pub fn mass_properties(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    density: f64,
) -> MassProperties {
    let mut vol = 0.0;
    let mut first = [0.0f64; 3];
    let mut second = [[0.0f64; 3]; 3];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let v = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))
            / 6.0;
        vol += v;
        let s = [0, 1, 2].map(|d| a[d] + b[d] + c[d]);
        for d in 0..3 {
            first[d] += v * s[d] / 4.0;
        }
        for r in 0..3 {
            for q in 0..3 {
                second[r][q] += v / 20.0 * (a[r] * a[q] + b[r] * b[q] + c[r] * c[q] + s[r] * s[q]);
            }
        }
    }
    let center = if vol.abs() > 0.0 {
        first.map(|f| f / vol)
    } else {
        [0.0; 3]
    };
    // Second moment about the centre, then the inertia tensor tr(C)·I − C.
    let mut c = second;
    for r in 0..3 {
        for q in 0..3 {
            c[r][q] = (c[r][q] - vol * center[r] * center[q]) * density;
        }
    }
    let tr = c[0][0] + c[1][1] + c[2][2];
    let mut inertia = [[0.0; 3]; 3];
    for r in 0..3 {
        for q in 0..3 {
            inertia[r][q] = if r == q { tr } else { 0.0 } - c[r][q];
        }
    }
    MassProperties {
        volume: vol,
        mass: vol * density,
        center,
        inertia,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box [0, a]×[0, b]×[0, c] as 12 outward triangles.
    fn cuboid(a: f64, b: f64, c: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let p = (0..8)
            .map(|i| {
                [
                    a * (i & 1) as f64,
                    b * (i >> 1 & 1) as f64,
                    c * (i >> 2 & 1) as f64,
                ]
            })
            .collect();
        let quads = [
            [0, 2, 3, 1], // z = 0, normal −z
            [4, 5, 7, 6], // z = c
            [0, 1, 5, 4], // y = 0
            [2, 6, 7, 3], // y = b
            [0, 4, 6, 2], // x = 0
            [1, 3, 7, 5], // x = a
        ];
        let t = quads
            .iter()
            .flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (p, t)
    }

    #[test]
    fn a_box_has_its_textbook_mass_properties() {
        let (a, b, c) = (1.0, 2.0, 3.0);
        let (p, t) = cuboid(a, b, c);
        let m = mass_properties(&p, &t, 500.0);
        assert!((m.volume - 6.0).abs() < 1e-12);
        assert!((m.mass - 3000.0).abs() < 1e-9);
        for (got, want) in m.center.iter().zip([0.5, 1.0, 1.5]) {
            assert!((got - want).abs() < 1e-12);
        }
        let want = [
            m.mass / 12.0 * (b * b + c * c),
            m.mass / 12.0 * (a * a + c * c),
            m.mass / 12.0 * (a * a + b * b),
        ];
        for r in 0..3 {
            for q in 0..3 {
                let w = if r == q { want[r] } else { 0.0 };
                assert!(
                    (m.inertia[r][q] - w).abs() < 1e-9,
                    "I[{r}][{q}] = {}",
                    m.inertia[r][q]
                );
            }
        }
    }

    #[test]
    fn moving_the_mesh_moves_the_centre_and_not_the_inertia() {
        let (p, t) = cuboid(1.0, 1.0, 2.0);
        let shifted: Vec<_> = p
            .iter()
            .map(|v| [v[0] + 5.0, v[1] - 2.0, v[2] + 0.5])
            .collect();
        let (m0, m1) = (
            mass_properties(&p, &t, 1.0),
            mass_properties(&shifted, &t, 1.0),
        );
        assert!((m1.center[0] - m0.center[0] - 5.0).abs() < 1e-12);
        for r in 0..3 {
            for q in 0..3 {
                assert!((m1.inertia[r][q] - m0.inertia[r][q]).abs() < 1e-9);
            }
        }
    }
}
