//! Scene contraction for unbounded backgrounds (mip-NeRF 360, as nerfacto uses it with the
//! L∞ norm): a point `u` of the node's box, scaled so the box is [−1, 1]³, maps to
//!
//! ```text
//! c(u) = u                          if ‖u‖∞ ≤ 1
//! c(u) = (2 − 1/‖u‖∞) · u / ‖u‖∞    otherwise
//! ```
//!
//! so the box (the inner region, where cameras and the main content are) is kept linearly
//! and everything beyond it — walls, windows, far scenery — is squeezed into the shell
//! 1 < ‖c‖∞ < 2. The field and its occupancy grid then live in [0, 1]³ = (c + 2) / 4.
//!
//! Marching a contracted node uses steps that follow the contraction: inside the box the
//! usual smallest step (growing with distance as a cone), outside a step of about half an
//! occupancy cell *in contracted space*, i.e. a world step growing with ‖u‖², so a ray
//! from the box to infinity costs a bounded number of samples (≈ `res / 2`).

/// Farthest a contracted march goes, in box half-sizes (‖u‖∞): c = 2 − 1/R, the last
/// thousandth of the shell, stands for everything farther.
pub const FAR_RADIUS: f32 = 1000.0;

/// Maps a point in box units (the box is [−1, 1]³) into [0, 1]³ through the contraction.
#[inline]
pub fn contract_to_unit(u: [f32; 3]) -> [f32; 3] {
    let r = u[0].abs().max(u[1].abs()).max(u[2].abs());
    let s = if r <= 1.0 { 1.0 } else { (2.0 - 1.0 / r) / r };
    u.map(|v| (v * s + 2.0) * 0.25)
}

/// Inverse of [`contract_to_unit`] (for points strictly inside the outer shell).
#[inline]
pub fn uncontract_from_unit(p: [f32; 3]) -> [f32; 3] {
    let c = p.map(|v| v * 4.0 - 2.0);
    let rc = c[0].abs().max(c[1].abs()).max(c[2].abs());
    if rc <= 1.0 {
        return c;
    }
    // ‖u‖ = 1 / (2 − ‖c‖).
    let r = 1.0 / (2.0 - rc).max(1e-6);
    c.map(|v| v * r / rc)
}

/// World step (in box units) that advances `dc` in contracted space from box radius
/// `r = ‖u‖∞` along a radial ray (`c = 2 − 1/r` there): `1/r − 1/(r + dr) = dc`, so
/// `dr = r² dc / (1 − r dc)`; infinite once less than `dc` is left before the shell's edge
/// (the last step stands for everything farther). 0 inside the box.
#[inline]
pub fn outer_step(r: f32, dc: f32) -> f32 {
    if r <= 1.0 {
        0.0
    } else if r * dc >= 1.0 {
        f32::INFINITY
    } else {
        r * r * dc / (1.0 - r * dc)
    }
}

/// How much longer than the smallest step a march through the occupancy cell with centre
/// `p` (in [0, 1]³) is, at least 1: the factor by which the cell's density is weighted
/// before it is compared with the occupancy threshold, so that "occupied" means the same
/// opacity per step everywhere. `half_extent` is the largest half-size of the box in the
/// march's units, `min_step` the smallest step, `dc` the contracted step.
#[inline]
pub fn cell_step_factor(p: [f32; 3], half_extent: f32, min_step: f32, dc: f32) -> f32 {
    let u = uncontract_from_unit(p);
    let r = u[0].abs().max(u[1].abs()).max(u[2].abs());
    (outer_step(r, dc) * half_extent / min_step).clamp(1.0, 1e9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_box_is_kept_and_infinity_reaches_the_shell() {
        // Inside the box: linear.
        let p = contract_to_unit([0.5, -1.0, 0.25]);
        let want = [0.625, 0.25, 0.5625];
        for a in 0..3 {
            assert!((p[a] - want[a]).abs() < 1e-6, "{p:?}");
        }
        // On the face and far away: continuous, and bounded by the shell.
        let f = contract_to_unit([1.0 + 1e-6, 0.3, 0.0]);
        assert!((f[0] - 0.75).abs() < 1e-5);
        let far = contract_to_unit([1e9, 3.0, -1e9]);
        assert!(far.iter().all(|&v| (0.0..=1.0).contains(&v)));
        assert!((far[0] - 1.0).abs() < 1e-6 && far[2].abs() < 1e-6);
        // Monotone along a ray leaving the box.
        let mut last = 0.0;
        for k in 0..200 {
            let t = 0.5 * 1.05f32.powi(k);
            let c = contract_to_unit([t, 0.2 * t, 0.1]);
            assert!(c[0] >= last);
            last = c[0];
        }
    }

    #[test]
    fn uncontract_inverts_contract() {
        let mut rng = assist_core::Rng::new(3);
        for _ in 0..1000 {
            let s = [0.3f32, 3.0, 50.0][rng.below(3) as usize];
            let u = [0; 3].map(|_| (rng.f32() * 2.0 - 1.0) * s);
            let back = uncontract_from_unit(contract_to_unit(u));
            for a in 0..3 {
                assert!(
                    (back[a] - u[a]).abs() <= 1e-3 * (1.0 + u[a].abs() * s),
                    "{u:?} -> {back:?}"
                );
            }
        }
    }

    #[test]
    fn outer_steps_advance_the_same_contracted_distance() {
        // A radial ray: each step advances about dc in contracted space, wherever it is.
        let dc = 1.0 / 64.0;
        for r0 in [1.5f32, 4.0, 20.0, 50.0] {
            let dr = outer_step(r0, dc);
            let c0 = contract_to_unit([r0, 0.0, 0.0])[0] * 4.0 - 2.0;
            let c1 = contract_to_unit([r0 + dr, 0.0, 0.0])[0] * 4.0 - 2.0;
            let got = c1 - c0;
            assert!((got - dc).abs() < 1e-3 * dc + 1e-6, "r {r0}: {got} vs {dc}");
        }
        assert_eq!(outer_step(0.7, dc), 0.0);
        // Less than dc left before the edge of the shell: one step to infinity.
        assert_eq!(outer_step(64.0, dc), f32::INFINITY);
    }
}
