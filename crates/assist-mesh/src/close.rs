//! Morphological closing of a grid's inside region (dilation, then erosion, by a cube of
//! `2r + 1` cells): tunnels and gaps narrower than about `2r` cells fill, while the
//! region keeps its extent. A trained field's level set is full of such pinholes where
//! the views did not constrain the density; each one is a handle of the mesh (genus).

/// Whether each cell of a `dims` grid (x fastest) is within `r` cells (along each axis)
/// of a set cell of `mask`.
fn dilate(mask: &[bool], dims: [usize; 3], r: usize) -> Vec<bool> {
    let stride = [1, dims[0], dims[0] * dims[1]];
    let mut cur = mask.to_vec();
    for axis in 0..3 {
        let n = dims[axis];
        let mut next = vec![false; cur.len()];
        let (o1, o2) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let mut prefix = vec![0u32; n + 1];
        for b in 0..dims[o2] {
            for a in 0..dims[o1] {
                let base = a * stride[o1] + b * stride[o2];
                for i in 0..n {
                    prefix[i + 1] = prefix[i] + u32::from(cur[base + i * stride[axis]]);
                }
                for i in 0..n {
                    let (lo, hi) = (i.saturating_sub(r), (i + r + 1).min(n));
                    next[base + i * stride[axis]] = prefix[hi] > prefix[lo];
                }
            }
        }
        cur = next;
    }
    cur
}

/// The closing of `mask` by a cube of radius `r` cells, with what the dilated region
/// encloses filled before the erosion; cells beyond the grid count as outside.
///
/// The filling matters for trained fields: their density is high in a shell at the seen
/// surface and unconstrained inside, so the inside region is often a hollow shell with
/// pinholes, each a handle. Once the dilation has shut the pinholes, the hollow is no
/// longer reached from outside and fills; an opening wider than `2r` cells (a mug's
/// mouth) keeps it open.
///
/// Cells of `seal` (what lies under the support an object is cut at) count as solid and
/// are never outside: an object's base is never seen, so its field is open there, and
/// the seal shuts that opening as the table did.
pub(crate) fn close(mask: &[bool], seal: Option<&[bool]>, dims: [usize; 3], r: usize) -> Vec<bool> {
    if r == 0 {
        return mask.to_vec();
    }
    let solid: Vec<bool> = match seal {
        Some(seal) => mask.iter().zip(seal).map(|(m, s)| *m || *s).collect(),
        None => mask.to_vec(),
    };
    let grown = dilate(&solid, dims, r);
    // What is reached from the grid's border without crossing the dilated region.
    let outside = flood_from_border(&grown, seal, dims);
    // Erosion is the dilation of the outside.
    let out = dilate(&outside, dims, r);
    out.iter().zip(mask).map(|(o, m)| *m || !o).collect()
}

/// Cells reached from the grid's border through cells not in `wall` (faces shared; the
/// border counts as reached even where `wall` is set, as beyond it is outside, except
/// where `seal` is set).
fn flood_from_border(wall: &[bool], seal: Option<&[bool]>, dims: [usize; 3]) -> Vec<bool> {
    let stride = [1, dims[0], dims[0] * dims[1]];
    let mut reached = vec![false; wall.len()];
    let mut stack = Vec::new();
    for (v, r) in reached.iter_mut().enumerate() {
        let c = [v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1])];
        let sealed = seal.is_some_and(|s| s[v]);
        if !sealed && (0..3).any(|a| c[a] == 0 || c[a] == dims[a] - 1) {
            *r = true;
            if !wall[v] {
                stack.push(v);
            }
        }
    }
    while let Some(v) = stack.pop() {
        let c = [v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1])];
        for a in 0..3 {
            if c[a] > 0 {
                let u = v - stride[a];
                if !reached[u] && !wall[u] {
                    reached[u] = true;
                    stack.push(u);
                }
            }
            if c[a] + 1 < dims[a] {
                let u = v + stride[a];
                if !reached[u] && !wall[u] {
                    reached[u] = true;
                    stack.push(u);
                }
            }
        }
    }
    reached
}

#[cfg(test)]
mod tests {
    use super::close;

    #[test]
    fn closing_fills_narrow_tunnels_and_keeps_wide_ones() {
        let n = 16usize;
        let dims = [n; 3];
        // A block with a 2-cell and a 6-cell square tunnel along z.
        let block: Vec<bool> = (0..n * n * n)
            .map(|v| {
                let c = [v % n, v / n % n, v / (n * n)];
                let inside = c.iter().all(|&x| (2..n - 2).contains(&x));
                let narrow = (4..6).contains(&c[0]) && (4..6).contains(&c[1]);
                let wide = (7..13).contains(&c[0]) && (7..13).contains(&c[1]);
                inside && !narrow && !wide
            })
            .collect();
        let closed = close(&block, None, dims, 1);
        let at = |x: usize, y: usize, z: usize| closed[x + n * (y + n * z)];
        assert!(at(4, 4, 8) && at(5, 5, 8), "the 2-cell tunnel fills");
        assert!(!at(9, 9, 8) && !at(10, 10, 8), "the 6-cell tunnel stays");
        // Nothing outside the block is added, and nothing inside is removed.
        assert!(block.iter().zip(&closed).all(|(b, c)| !b || *c));
        assert!(!at(0, 0, 0) && !at(1, 8, 8) && !at(8, 8, 1));
    }

    /// A hollow shell: with a 2-cell pinhole its inside fills; with a 6-cell opening (a
    /// cup's mouth) it stays hollow.
    #[test]
    fn closing_fills_a_hollow_behind_a_pinhole_only() {
        let n = 20usize;
        let dims = [n; 3];
        let shell = |hole: usize| -> Vec<bool> {
            (0..n * n * n)
                .map(|v| {
                    let c = [v % n, v / n % n, v / (n * n)];
                    let outer = c.iter().all(|&x| (3..n - 3).contains(&x));
                    let inner = c.iter().all(|&x| (5..n - 5).contains(&x));
                    // The opening, through the top wall, centred.
                    let lo = n / 2 - hole / 2;
                    let opening = c[2] >= n - 5
                        && (lo..lo + hole).contains(&c[0])
                        && (lo..lo + hole).contains(&c[1]);
                    outer && !inner && !opening
                })
                .collect()
        };
        let centre = n / 2 + n * (n / 2 + n * (n / 2));
        let pin = close(&shell(2), None, dims, 1);
        assert!(pin[centre], "the hollow behind a pinhole fills");
        let cup = close(&shell(6), None, dims, 1);
        assert!(!cup[centre], "the hollow behind a wide opening stays");
        assert!(!cup[0] && !pin[0]);
        // Upside down on a table (the opening sealed), the cup's hollow fills.
        let seal: Vec<bool> = (0..n * n * n).map(|v| v / (n * n) >= n - 4).collect();
        let sealed = close(&shell(6), Some(&seal), dims, 1);
        assert!(sealed[centre], "the hollow behind a sealed opening fills");
    }
}
