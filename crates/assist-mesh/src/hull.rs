//! How opaque a node looks at each grid vertex from outside: the optical depth from the
//! grid's border to the vertex along each of the 26 grid directions (axes, face and body
//! diagonals), and the least of them. Its level set at a chosen opacity is the surface
//! the renderer shows, seen from the best direction: where the density is a gappy shell
//! around unconstrained fog (a plain, untextured object), the density's own level set is
//! full of tunnels, while the depth through the shell and fog adds up to an opaque solid.
//! A true hole (a mug's handle) stays open along the directions that see through it.

/// Per-vertex least optical depth from outside (see the module docs). `density` is in
/// the field's units, `tau_per_cell` the optical depth one grid cell of unit density
/// adds along each axis (cells are cubes in world units, the field's units may stretch
/// them). Vertices of `seal` (the support under an object) are opaque: nothing is seen
/// through the table.
pub(crate) fn least_depth(
    density: &[f32],
    seal: Option<&[bool]>,
    dims: [usize; 3],
    tau_per_cell: [f32; 3],
) -> Vec<f32> {
    let n = density.len();
    let mut least = vec![f32::INFINITY; n];
    let mut depth = vec![0.0f32; n];
    let stride = [1isize, dims[0] as isize, (dims[0] * dims[1]) as isize];
    for dz in -1i32..=1 {
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let d = [dx, dy, dz];
                if d == [0, 0, 0] {
                    continue;
                }
                let len = (0..3)
                    .map(|a| (d[a] as f32 * tau_per_cell[a]).powi(2))
                    .sum::<f32>()
                    .sqrt();
                let back = -(0..3).map(|a| d[a] as isize * stride[a]).sum::<isize>();
                sweep(density, seal, dims, d, len, back, &mut depth);
                for (l, t) in least.iter_mut().zip(&depth) {
                    *l = l.min(*t);
                }
            }
        }
    }
    least
}

/// Optical depth along direction `d` (light travelling along `d`, entering at the grid's
/// border): each vertex adds the trapezoid of its and its predecessor's density times
/// `len` to the predecessor's depth (`back` is the predecessor's index offset).
fn sweep(
    density: &[f32],
    seal: Option<&[bool]>,
    dims: [usize; 3],
    d: [i32; 3],
    len: f32,
    back: isize,
    depth: &mut [f32],
) {
    // Visit each axis in the order light travels along it.
    let order = |a: usize, i: usize| if d[a] < 0 { dims[a] - 1 - i } else { i };
    for kz in 0..dims[2] {
        let z = order(2, kz);
        for ky in 0..dims[1] {
            let y = order(1, ky);
            for kx in 0..dims[0] {
                let x = order(0, kx);
                let v = x + dims[0] * (y + dims[1] * z);
                if seal.is_some_and(|s| s[v]) {
                    depth[v] = f32::INFINITY;
                    continue;
                }
                let c = [x, y, z];
                let first =
                    (0..3).any(|a| (d[a] > 0 && c[a] == 0) || (d[a] < 0 && c[a] == dims[a] - 1));
                depth[v] = if first {
                    0.0
                } else {
                    let p = (v as isize + back) as usize;
                    depth[p] + 0.5 * (density[p] + density[v]) * len
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::least_depth;

    /// A slab of uniform density: the least depth at a vertex is its depth from the
    /// nearer face, straight in (the shortest way), by the trapezoid rule.
    #[test]
    fn depth_in_a_slab_is_taken_from_the_nearer_face_straight_in() {
        let dims = [12usize, 12, 12];
        let n = dims.iter().product();
        // Density 2 on x in 3..=8, everywhere in y and z.
        let density: Vec<f32> = (0..n)
            .map(|v| {
                if (3..=8).contains(&(v % 12)) {
                    2.0
                } else {
                    0.0
                }
            })
            .collect();
        let tau = least_depth(&density, None, dims, [0.5, 0.5, 0.5]);
        let at = |x: usize| tau[x + 12 * (6 + 12 * 6)];
        assert_eq!(at(1), 0.0);
        // Entering at x = 3 (trapezoid from x = 2: half a cell of density 2 × 0.5).
        assert!((at(3) - 0.5).abs() < 1e-6, "{}", at(3));
        assert!((at(4) - 1.5).abs() < 1e-6, "{}", at(4));
        // From the far face the same way (symmetric), and never from the sides (the
        // slab is unbounded in y and z, so those directions see it whole).
        assert!((at(8) - 0.5).abs() < 1e-6, "{}", at(8));
        assert_eq!(at(10), 0.0);
    }

    /// A sealed floor is opaque: above it, only the top and sides see in.
    #[test]
    fn nothing_is_seen_through_the_seal() {
        let dims = [8usize, 8, 8];
        let n = dims.iter().product();
        let density = vec![0.0f32; n];
        let seal: Vec<bool> = (0..n).map(|v| v / 64 < 2).collect();
        let tau = least_depth(&density, Some(&seal), dims, [1.0; 3]);
        assert!(
            tau[4 + 8 * (4 + 8 * 4)] == 0.0,
            "empty space above the seal is seen"
        );
        assert!(
            tau[4 + 8 * (4 + 8)].is_infinite(),
            "the seal itself is opaque"
        );
    }
}
