//! Marching tetrahedra over a scalar grid: every cube is split into the six tetrahedra
//! around its main diagonal (Kuhn's triangulation, which neighbouring cubes agree on at
//! their shared faces), and each tetrahedron cut by the level set gives one triangle or
//! two. Unlike marching cubes there are no ambiguous cases, and vertices are shared by
//! the grid edge they lie on, so a level set that does not touch the grid's border comes
//! out closed (every edge in exactly two triangles) and consistently oriented.

use std::collections::HashMap;

/// A scalar field sampled at the vertices of a regular grid (x fastest).
pub struct Grid<'a> {
    pub dims: [usize; 3],
    pub values: &'a [f32],
}

impl Grid<'_> {
    #[inline]
    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }
    fn coords(&self, v: usize) -> [usize; 3] {
        let (nx, ny) = (self.dims[0], self.dims[1]);
        [v % nx, (v / nx) % ny, v / (nx * ny)]
    }
}

/// A triangle soup with shared vertices, in grid coordinates (vertex `(i, j, k)` at
/// `[i, j, k]`); triangles wind counter-clockwise seen from the side where the values are
/// below the level (the outside of `value ≥ level`).
#[derive(Debug, Clone, Default)]
pub struct Surface {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// The six tetrahedra of a cube, as corner indices (bit 0 = +x, bit 1 = +y, bit 2 = +z):
/// for each order of the axes, the path 0 → +a → +a+b → 7.
const TETS: [[usize; 4]; 6] = {
    const AXES: [[usize; 3]; 6] = [
        [1, 2, 4],
        [1, 4, 2],
        [2, 1, 4],
        [2, 4, 1],
        [4, 1, 2],
        [4, 2, 1],
    ];
    let mut t = [[0usize; 4]; 6];
    let mut n = 0;
    while n < 6 {
        let [a, b, _] = AXES[n];
        t[n] = [0, a, a | b, 7];
        n += 1;
    }
    t
};

/// Extracts the surface `value = level` from `grid`; points with `value ≥ level` are
/// inside. Non-finite values count as outside.
pub fn extract(grid: &Grid, level: f32) -> Surface {
    let [nx, ny, nz] = grid.dims;
    let mut out = Surface::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return out;
    }
    let inside = |v: f32| v >= level;
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    let mut corner = [0usize; 8];
    let mut val = [0f32; 8];
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let mut count = 0;
                for c in 0..8 {
                    let v = grid.index(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1));
                    corner[c] = v;
                    val[c] = grid.values[v];
                    count += usize::from(inside(val[c]));
                }
                if count == 0 || count == 8 {
                    continue;
                }
                for t in &TETS {
                    let ids = t.map(|c| corner[c]);
                    let vs = t.map(|c| val[c]);
                    tet(grid, &ids, &vs, level, &mut edges, &mut out);
                }
            }
        }
    }
    out
}

/// Point where the level crosses the edge between grid vertices `a` and `b` (one inside,
/// one outside), shared by every tetrahedron that has that edge.
fn edge_vertex(
    grid: &Grid,
    (a, fa): (usize, f32),
    (b, fb): (usize, f32),
    level: f32,
    edges: &mut HashMap<(u32, u32), u32>,
    out: &mut Surface,
) -> u32 {
    let key = (a.min(b) as u32, a.max(b) as u32);
    *edges.entry(key).or_insert_with(|| {
        let fa = if fa.is_finite() { fa } else { level - 1e6 };
        let fb = if fb.is_finite() { fb } else { level - 1e6 };
        let t = ((level - fa) / (fb - fa)).clamp(1e-3, 1.0 - 1e-3);
        let (pa, pb) = (grid.coords(a), grid.coords(b));
        let p = [0, 1, 2].map(|d| pa[d] as f32 + t * (pb[d] as f32 - pa[d] as f32));
        out.positions.push(p);
        (out.positions.len() - 1) as u32
    })
}

fn tet(
    grid: &Grid,
    ids: &[usize; 4],
    vs: &[f32; 4],
    level: f32,
    edges: &mut HashMap<(u32, u32), u32>,
    out: &mut Surface,
) {
    let ins: Vec<usize> = (0..4).filter(|&c| vs[c] >= level).collect();
    let outs: Vec<usize> = (0..4).filter(|&c| vs[c] < level).collect();
    if ins.is_empty() || outs.is_empty() {
        return;
    }
    // Direction from inside to outside, to orient the triangles.
    let centroid = |set: &[usize]| {
        let mut c = [0f32; 3];
        for &s in set {
            let p = grid.coords(ids[s]);
            for d in 0..3 {
                c[d] += p[d] as f32 / set.len() as f32;
            }
        }
        c
    };
    let (ci, co) = (centroid(&ins), centroid(&outs));
    let outward = [co[0] - ci[0], co[1] - ci[1], co[2] - ci[2]];
    let mut e =
        |a: usize, b: usize| edge_vertex(grid, (ids[a], vs[a]), (ids[b], vs[b]), level, edges, out);
    let tris: Vec<[u32; 3]> = match (ins.len(), outs.len()) {
        (1, 3) => vec![[e(ins[0], outs[0]), e(ins[0], outs[1]), e(ins[0], outs[2])]],
        (3, 1) => vec![[e(ins[0], outs[0]), e(ins[1], outs[0]), e(ins[2], outs[0])]],
        _ => {
            // Two in (a, b), two out (c, d): the cut is the quad ac, bc, bd, ad.
            let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
            let q = [e(a, c), e(b, c), e(b, d), e(a, d)];
            vec![[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
        }
    };
    for mut t in tris {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            continue;
        }
        let p = t.map(|v| out.positions[v as usize]);
        let u = [0, 1, 2].map(|d| p[1][d] - p[0][d]);
        let w = [0, 1, 2].map(|d| p[2][d] - p[0][d]);
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        if n[0] * outward[0] + n[1] * outward[1] + n[2] * outward[2] < 0.0 {
            t.swap(1, 2);
        }
        out.triangles.push(t);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::collections::HashMap;

    /// `r − distance` from the grid's centre, on an n³ grid (a ball of radius `r` cells).
    pub(crate) fn sphere(n: usize, r: f32) -> (Vec<f32>, [usize; 3]) {
        let c = (n - 1) as f32 / 2.0;
        let mut v = Vec::with_capacity(n * n * n);
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let d =
                        ((i as f32 - c).powi(2) + (j as f32 - c).powi(2) + (k as f32 - c).powi(2))
                            .sqrt();
                    v.push(r - d);
                }
            }
        }
        (v, [n, n, n])
    }

    /// Every undirected edge is used by exactly two triangles, once in each direction:
    /// closed and consistently oriented.
    pub(crate) fn closed_and_oriented(tris: &[[u32; 3]]) -> Result<(), String> {
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for t in tris {
            for e in 0..3 {
                *directed.entry((t[e], t[(e + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &directed {
            if n != 1 {
                return Err(format!("edge {a}→{b} used {n} times in one direction"));
            }
            if directed.get(&(b, a)) != Some(&1) {
                return Err(format!("edge {a}→{b} has no opposite"));
            }
        }
        Ok(())
    }

    #[test]
    fn a_sphere_comes_out_closed_oriented_and_on_the_level_set() {
        let (v, dims) = sphere(24, 8.3);
        let s = extract(&Grid { dims, values: &v }, 0.0);
        assert!(s.triangles.len() > 500);
        closed_and_oriented(&s.triangles).unwrap();
        let c = 11.5f32;
        let mut vol = 0.0f64;
        for t in &s.triangles {
            let p = t.map(|i| s.positions[i as usize].map(|x| (x - c) as f64));
            vol += (p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1])
                - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
                + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]))
                / 6.0;
        }
        // Outward orientation: the signed volume is positive and near the sphere's.
        let want = 4.0 / 3.0 * std::f64::consts::PI * 8.3f64.powi(3);
        assert!(
            (vol - want).abs() / want < 0.03,
            "volume {vol} against {want}"
        );
        for p in &s.positions {
            let d = p.iter().map(|x| (x - c).powi(2)).sum::<f32>().sqrt();
            // Linear interpolation of a distance along a diagonal edge errs by < 0.1 cell.
            assert!((d - 8.3).abs() < 0.1, "vertex at radius {d}");
        }
    }

    #[test]
    fn a_solid_touching_the_border_is_open_and_nothing_inside_gives_nothing() {
        let v = vec![1.0f32; 27];
        assert!(
            extract(
                &Grid {
                    dims: [3, 3, 3],
                    values: &v
                },
                0.5
            )
            .triangles
            .is_empty()
        );
        let mut v = vec![0.0f32; 27];
        v[13] = 1.0; // the centre vertex alone: a small closed diamond
        let s = extract(
            &Grid {
                dims: [3, 3, 3],
                values: &v,
            },
            0.5,
        );
        closed_and_oriented(&s.triangles).unwrap();
        v[0] = 1.0; // a corner vertex on the border: cut open there
        let s = extract(
            &Grid {
                dims: [3, 3, 3],
                values: &v,
            },
            0.5,
        );
        assert!(closed_and_oriented(&s.triangles).is_err());
    }

    #[test]
    fn non_finite_values_are_outside() {
        let mut v = vec![f32::NEG_INFINITY; 27];
        v[13] = 1.0;
        let s = extract(
            &Grid {
                dims: [3, 3, 3],
                values: &v,
            },
            0.0,
        );
        closed_and_oriented(&s.triangles).unwrap();
        assert!(s.positions.iter().flatten().all(|x| x.is_finite()));
    }
}
