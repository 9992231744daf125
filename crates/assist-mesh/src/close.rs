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

/// The closing of `mask` by a cube of radius `r` cells; cells beyond the grid count as
/// outside.
pub(crate) fn close(mask: &[bool], dims: [usize; 3], r: usize) -> Vec<bool> {
    if r == 0 {
        return mask.to_vec();
    }
    let grown = dilate(mask, dims, r);
    // Erosion is the dilation of the outside; the grid's border is outside.
    let mut outside: Vec<bool> = grown.iter().map(|g| !g).collect();
    for (v, o) in outside.iter_mut().enumerate() {
        let c = [v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1])];
        if (0..3).any(|a| c[a] == 0 || c[a] == dims[a] - 1) {
            *o = true;
        }
    }
    let out = dilate(&outside, dims, r);
    out.iter().zip(mask).map(|(o, m)| *m || !o).collect()
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
        let closed = close(&block, dims, 1);
        let at = |x: usize, y: usize, z: usize| closed[x + n * (y + n * z)];
        assert!(at(4, 4, 8) && at(5, 5, 8), "the 2-cell tunnel fills");
        assert!(!at(9, 9, 8) && !at(10, 10, 8), "the 6-cell tunnel stays");
        // Nothing outside the block is added, and nothing inside is removed.
        assert!(block.iter().zip(&closed).all(|(b, c)| !b || *c));
        assert!(!at(0, 0, 0) && !at(1, 8, 8) && !at(8, 8, 1));
    }
}
