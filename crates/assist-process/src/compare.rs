//! How well processed poses match known ones: the similarity (scale, rotation,
//! translation) that best maps one set of camera centres onto the other, in the least
//! squares sense (Horn's closed form with unit quaternions), and the distances left.

use assist_core::{DQuat, DVec3};

/// A similarity `p ↦ scale · rotation · p + translation`.
#[derive(Debug, Clone, Copy)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Similarity {
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.rotation * p * self.scale + self.translation
    }
}

/// The similarity that best maps `from[i]` onto `to[i]` (at least 3 points, not all on a
/// line); `None` when they are degenerate.
pub fn fit_similarity(from: &[DVec3], to: &[DVec3]) -> Option<Similarity> {
    let n = from.len();
    if n < 3 || n != to.len() {
        return None;
    }
    let ca = from.iter().sum::<DVec3>() / n as f64;
    let cb = to.iter().sum::<DVec3>() / n as f64;
    // Cross-covariance M = Σ a bᵀ of the centred points.
    let mut m = [[0.0f64; 3]; 3];
    let (mut sa, mut sb) = (0.0, 0.0);
    for (a, b) in from.iter().zip(to) {
        let (a, b) = (*a - ca, *b - cb);
        sa += a.length_squared();
        sb += b.length_squared();
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += a[i] * b[j];
            }
        }
    }
    if sa < 1e-24 || sb < 1e-24 {
        return None;
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = m;
    // Horn's symmetric 4×4 matrix; its top eigenvector is the rotation (w, x, y, z).
    let k = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let q = top_eigenvector(k)?;
    let rotation = DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    // Scale: Σ b·(R a) / Σ |a|².
    let dot: f64 = from
        .iter()
        .zip(to)
        .map(|(a, b)| (*b - cb).dot(rotation * (*a - ca)))
        .sum();
    let scale = dot / sa;
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    Some(Similarity {
        scale,
        rotation,
        translation: cb - rotation * ca * scale,
    })
}

/// The eigenvector of the largest eigenvalue of a symmetric 4×4 matrix; `None` when it
/// is not finite.
fn top_eigenvector(a: [[f64; 4]; 4]) -> Option<[f64; 4]> {
    let (_, vectors) = assist_core::eigen::symmetric_eigen(a);
    let e = vectors[0];
    e.iter().all(|x| x.is_finite()).then_some(e)
}

/// Distances between `to[i]` and `from[i]` mapped by the best similarity.
pub fn residuals(from: &[DVec3], to: &[DVec3]) -> Option<Vec<f64>> {
    let s = fit_similarity(from, to)?;
    Some(
        from.iter()
            .zip(to)
            .map(|(a, b)| s.apply(*a).distance(*b))
            .collect(),
    )
}

/// Processed poses against a dataset's own, frames matched by image file name.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PoseReport {
    /// Frames of the given dataset, and how many the processed one posed.
    pub frames: usize,
    pub matched: usize,
    /// Camera-centre distances after the best similarity, in the given dataset's units.
    pub mean_error: f64,
    pub max_error: f64,
    /// The given scene's extent: the diagonal of its bounds (cameras and content).
    pub extent: f64,
    /// `max_error / extent`, `mean_error / extent`.
    pub max_share: f64,
    pub mean_share: f64,
    /// The scale the similarity applied (given units per processed unit).
    pub scale: f64,
}

/// Compares `processed` cameras with `given` ones (see [`PoseReport`]); `None` when
/// fewer than 3 frames match or their centres are degenerate.
pub fn compare_poses(
    processed: &assist_data::Dataset,
    given: &assist_data::Dataset,
) -> Option<PoseReport> {
    let file = |p: &std::path::Path| p.file_name().map(|n| n.to_owned());
    let mut from = Vec::new();
    let mut to = Vec::new();
    for g in &given.frames {
        if let Some(p) = processed
            .frames
            .iter()
            .find(|p| file(&p.image_path) == file(&g.image_path))
        {
            from.push(p.camera.pose.center());
            to.push(g.camera.pose.center());
        }
    }
    let fit = fit_similarity(&from, &to)?;
    let errors: Vec<f64> = from
        .iter()
        .zip(&to)
        .map(|(a, b)| fit.apply(*a).distance(*b))
        .collect();
    let extent = (given.bounds.max - given.bounds.min).length();
    let mean_error = errors.iter().sum::<f64>() / errors.len() as f64;
    let max_error = errors.iter().cloned().fold(0.0, f64::max);
    Some(PoseReport {
        frames: given.frames.len(),
        matched: from.len(),
        mean_error,
        max_error,
        extent,
        max_share: max_error / extent,
        mean_share: mean_error / extent,
        scale: fit.scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_similarity_is_recovered_exactly() {
        let pts: Vec<DVec3> = (0..12)
            .map(|k| {
                let a = k as f64 * 0.7;
                DVec3::new(a.cos() * 2.0, a.sin(), 0.3 * k as f64 - 1.0)
            })
            .collect();
        let truth = Similarity {
            scale: 3.5,
            rotation: DQuat::from_rotation_x(2.0) * DQuat::from_rotation_z(-1.1),
            translation: DVec3::new(4.0, -1.0, 0.5),
        };
        let moved: Vec<DVec3> = pts.iter().map(|p| truth.apply(*p)).collect();
        let fit = fit_similarity(&pts, &moved).unwrap();
        assert!((fit.scale - 3.5).abs() < 1e-9, "{}", fit.scale);
        assert!(fit.rotation.angle_between(truth.rotation) < 1e-9);
        assert!(fit.translation.distance(truth.translation) < 1e-9);
        let r = residuals(&pts, &moved).unwrap();
        assert!(r.iter().all(|d| *d < 1e-9));
        // Collinear or too few points: no fit.
        let line: Vec<DVec3> = (0..5).map(|k| DVec3::X * k as f64).collect();
        assert!(fit_similarity(&line[..2], &line[..2]).is_none());
    }
}
