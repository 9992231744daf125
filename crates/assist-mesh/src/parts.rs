//! Connected parts of a mesh: what marching a trained field gives besides the object's
//! outer surface — closed bubbles inside it (cavities, wound inward: negative volume) and
//! small floaters of density left in the box — is dropped, keeping the parts whose
//! enclosed volume is at least a share of the largest.

use crate::NodeMesh;

fn find(parent: &mut [u32], mut v: u32) -> u32 {
    while parent[v as usize] != v {
        let p = parent[parent[v as usize] as usize];
        parent[v as usize] = p;
        v = p;
    }
    v
}

/// The shape of a mesh's surface: how many pieces, its Euler characteristic
/// (vertices − edges + faces, over the vertices the triangles use) and, for a closed
/// mesh, its genus: the number of handles (tunnels through it) of all its pieces
/// together, `(2 × components − χ) / 2` (a ball or a box: 0; a mug: 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Topology {
    pub components: usize,
    pub euler: i64,
    /// `None` for a mesh that is not closed (its genus is not defined).
    pub genus: Option<i64>,
}

impl NodeMesh {
    /// See [`Topology`].
    pub fn topology(&self) -> Topology {
        let mut used = vec![false; self.positions.len()];
        let mut edges = std::collections::HashSet::new();
        for t in &self.triangles {
            for e in 0..3 {
                used[t[e] as usize] = true;
                let (a, b) = (t[e], t[(e + 1) % 3]);
                edges.insert((a.min(b), a.max(b)));
            }
        }
        let v = used.iter().filter(|u| **u).count() as i64;
        let euler = v - edges.len() as i64 + self.triangles.len() as i64;
        let components = self.parts().len();
        let genus = (self.is_closed() && !self.triangles.is_empty())
            .then(|| (2 * components as i64 - euler) / 2);
        Topology {
            components,
            euler,
            genus,
        }
    }

    /// Parts (sets of triangles joined by shared vertices) as lists of triangle indices,
    /// with each part's signed enclosed volume (positive for an outward-wound closed part).
    pub fn parts(&self) -> Vec<(Vec<usize>, f64)> {
        let mut parent: Vec<u32> = (0..self.positions.len() as u32).collect();
        for t in &self.triangles {
            let a = find(&mut parent, t[0]);
            for &v in &t[1..] {
                let b = find(&mut parent, v);
                if a != b {
                    parent[b as usize] = a;
                }
            }
        }
        let mut by_root: std::collections::HashMap<u32, usize> = Default::default();
        let mut parts: Vec<(Vec<usize>, f64)> = Vec::new();
        for (k, t) in self.triangles.iter().enumerate() {
            let r = find(&mut parent, t[0]);
            let i = *by_root.entry(r).or_insert_with(|| {
                parts.push((Vec::new(), 0.0));
                parts.len() - 1
            });
            let [a, b, c] = t.map(|v| self.positions[v as usize]);
            let vol = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0;
            parts[i].0.push(k);
            parts[i].1 += vol;
        }
        parts
    }

    /// Keeps the parts that enclose at least `min_share` of the largest part's volume
    /// (cavities and floaters go); returns how many parts were dropped. Vertices no
    /// triangle uses any more are removed.
    pub fn keep_main_parts(&mut self, min_share: f64) -> usize {
        let parts = self.parts();
        let largest = parts.iter().map(|p| p.1).fold(0.0f64, f64::max);
        let keep: Vec<&(Vec<usize>, f64)> = parts
            .iter()
            .filter(|p| p.1 > 0.0 && p.1 >= min_share * largest)
            .collect();
        let dropped = parts.len() - keep.len();
        if dropped == 0 {
            return 0;
        }
        let mut tris: Vec<usize> = keep.iter().flat_map(|p| p.0.iter().copied()).collect();
        tris.sort_unstable();
        let mut map = vec![u32::MAX; self.positions.len()];
        let (mut pos, mut nor, mut col) = (Vec::new(), Vec::new(), Vec::new());
        let mut triangles = Vec::with_capacity(tris.len());
        for k in tris {
            let t = self.triangles[k].map(|v| {
                let m = &mut map[v as usize];
                if *m == u32::MAX {
                    *m = pos.len() as u32;
                    pos.push(self.positions[v as usize]);
                    nor.push(self.normals[v as usize]);
                    col.push(self.colors[v as usize]);
                }
                *m
            });
            triangles.push(t);
        }
        self.positions = pos;
        self.normals = nor;
        self.colors = col;
        self.triangles = triangles;
        dropped
    }
}

#[cfg(test)]
mod tests {
    use crate::tetra::{Grid, extract};
    use crate::{MeshFrame, NodeMesh};

    /// A shell (a ball of radius 8 with a cavity of radius 4) and a small floater.
    #[test]
    fn the_genus_counts_handles() {
        use crate::tetra::{Grid, extract};
        // A solid block, and the same block with a square hole through it (a ring).
        let n = 12usize;
        let field = |hole: bool| -> Vec<f32> {
            (0..n * n * n)
                .map(|v| {
                    let c = [v % n, v / n % n, v / (n * n)];
                    let inside = c.iter().all(|&x| (2..n - 2).contains(&x));
                    let in_hole = hole && (5..7).contains(&c[0]) && (5..7).contains(&c[1]);
                    if inside && !in_hole { 1.0 } else { -1.0 }
                })
                .collect()
        };
        for (hole, genus) in [(false, 0), (true, 1)] {
            let values = field(hole);
            let s = extract(
                &Grid {
                    dims: [n; 3],
                    values: &values,
                },
                0.0,
            );
            let m = NodeMesh {
                id: 1,
                label: "block".into(),
                frame: crate::MeshFrame::Node,
                normals: vec![[0.0; 3]; s.positions.len()],
                colors: vec![[0.0; 3]; s.positions.len()],
                positions: s.positions.iter().map(|p| p.map(f64::from)).collect(),
                triangles: s.triangles,
            };
            let t = m.topology();
            assert_eq!((t.components, t.genus), (1, Some(genus)), "{t:?}");
        }
    }

    #[test]
    fn cavities_and_floaters_are_dropped_and_the_shell_kept() {
        let n = 30usize;
        let mut v = Vec::new();
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let d = |c: [f32; 3]| {
                        ((i as f32 - c[0]).powi(2)
                            + (j as f32 - c[1]).powi(2)
                            + (k as f32 - c[2]).powi(2))
                        .sqrt()
                    };
                    let r = d([12.0; 3]);
                    let shell = (8.0 - r).min(r - 4.0);
                    let floater = 1.5 - d([25.0, 25.0, 25.0]);
                    v.push(shell.max(floater));
                }
            }
        }
        let s = extract(
            &Grid {
                dims: [n; 3],
                values: &v,
            },
            0.0,
        );
        let mut m = NodeMesh {
            id: 1,
            label: "ball".into(),
            frame: MeshFrame::Node,
            positions: s.positions.iter().map(|p| p.map(f64::from)).collect(),
            normals: vec![[0.0; 3]; s.positions.len()],
            colors: vec![[0.5; 3]; s.positions.len()],
            triangles: s.triangles,
        };
        let parts = m.parts();
        assert_eq!(parts.len(), 3);
        assert_eq!(
            parts.iter().filter(|p| p.1 < 0.0).count(),
            1,
            "the cavity is wound inward"
        );
        let before = m.mass_properties(1.0).volume;
        assert_eq!(m.keep_main_parts(0.05), 2);
        assert!(m.is_closed());
        let after = m.mass_properties(1.0).volume;
        let ball = 4.0 / 3.0 * std::f64::consts::PI * 512.0;
        assert!((after - ball).abs() / ball < 0.03, "{after} against {ball}");
        assert!(after > before);
        assert!(
            m.triangles
                .iter()
                .flatten()
                .all(|&v| (v as usize) < m.positions.len())
        );
    }
}
