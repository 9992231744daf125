//! Relighting a moved object ([`assist_render::relight`]): no change where it was
//! photographed, a face turned from the lamp darkened by the hand-computed ratio of its
//! irradiances, a face turned towards it brightened, and the lattice interpolated.

use assist_core::{DQuat, DVec3, ShadowCast, Similarity3};
use assist_field::OccupancyGrid;
use assist_render::relight::{RelightGrid, relight_grid};

/// A unit box (half size 1) whose half `x < 0` is solid: its face at `x = 0` looks
/// along +x.
fn half_block(res: u32) -> OccupancyGrid {
    let mut g = OccupancyGrid::new(res);
    let r = res as usize;
    g.density = (0..r * r * r)
        .map(|k| if k % r < r / 2 { 200.0 } else { 0.0 })
        .collect();
    g
}

fn turned(deg: f64) -> Similarity3 {
    Similarity3::new(
        DQuat::from_rotation_z(deg.to_radians()),
        DVec3::ZERO,
        DVec3::ONE,
    )
    .unwrap()
}

/// The lattice point just outside the face, midway across it.
fn on_face(g: &RelightGrid) -> usize {
    let n = g.res;
    let (x, y, z) = (n / 2 + 1, n / 2, n / 2);
    x + n * (y + n * z)
}

const S: f32 = 0.5;

fn cast() -> ShadowCast {
    ShadowCast {
        pose: Similarity3::default(),
        strength: [S, 0.0, 1.0],
    }
}

#[test]
fn an_object_where_it_was_photographed_keeps_its_colours() {
    let occ = half_block(32);
    let lamp = [DVec3::new(30.0, 0.0, 30.0)];
    let g = relight_grid(
        &occ,
        DVec3::ONE,
        &Similarity3::default(),
        &cast(),
        &lamp,
        DVec3::Z,
    );
    assert!(g.factors.iter().all(|&f| f == 1.0));
}

#[test]
fn a_face_turned_from_the_lamp_darkens_by_its_irradiance_ratio() {
    let occ = half_block(32);
    // A distant lamp 45° above the face's direction.
    let lamp = [DVec3::new(30.0, 0.0, 30.0)];
    let g = relight_grid(&occ, DVec3::ONE, &turned(180.0), &cast(), &lamp, DVec3::Z);
    let k = on_face(&g);
    // Learned: the face (normal +x, horizontal) sees the lamp as an upward surface does,
    // cos 45° each, so its key term is 1 and its ambient (1 + 0)/1.5. Turned: the lamp
    // is behind it, key 0.
    let amb = 1.0 / 1.5;
    for (c, s) in cast().strength.into_iter().enumerate() {
        let then = (1.0 - s) * amb + s;
        let now = (1.0 - s) * amb;
        let want = (now / then).max(0.05);
        let got = g.factors[3 * k + c];
        assert!(
            (got - want).abs() < 0.03 * want.max(0.1),
            "channel {c}: {got} vs {want}"
        );
    }
}

#[test]
fn a_face_turned_towards_the_lamp_brightens() {
    let occ = half_block(32);
    // The lamp behind the face where it was photographed (on −x, 45° up).
    let lamp = [DVec3::new(-30.0, 0.0, 30.0)];
    let g = relight_grid(&occ, DVec3::ONE, &turned(180.0), &cast(), &lamp, DVec3::Z);
    let k = on_face(&g);
    let amb = 1.0 / 1.5;
    let want = ((1.0 - S) * amb + S) / ((1.0 - S) * amb);
    let got = g.factors[3 * k];
    assert!((got - want).abs() < 0.03 * want, "{got} vs {want}");
    // All key light in the third channel: nothing lit it before; the factor is capped.
    assert_eq!(g.factors[3 * k + 2], 8.0);
    // Far from any surface the density has no gradient: no change.
    let far = g.res - 1 + g.res * (g.res / 2 + g.res * (g.res / 2));
    assert_eq!(&g.factors[3 * far..3 * far + 3], &[1.0; 3]);
}

#[test]
fn factors_are_interpolated_between_lattice_points() {
    let n = 3;
    let factors = (0..n * n * n)
        .flat_map(|k| {
            let x = (k % n) as f32;
            [x, 2.0 * x, 1.0]
        })
        .collect();
    let g = RelightGrid { res: n, factors };
    assert_eq!(g.at([0.0, 0.3, 0.7]), [0.0, 0.0, 1.0]);
    assert_eq!(g.at([1.0, 0.5, 0.5]), [2.0, 4.0, 1.0]);
    let f = g.at([0.25, 0.9, 0.1]);
    assert!(
        (f[0] - 0.5).abs() < 1e-6 && (f[1] - 1.0).abs() < 1e-6,
        "{f:?}"
    );
    // sRGB in, sRGB out: a factor of 1 changes nothing, and a factor is applied in
    // linear light.
    let pos = [vec![0.5, 0.0], vec![0.5, 0.5], vec![0.5, 0.5]];
    let mut rgb = vec![0.5, 0.2, 0.8, 0.5, 0.5, 0.5];
    g.apply(&pos, &mut rgb);
    let lin = |v: f32| ((v + 0.055) / 1.055).powf(2.4);
    let srgb = |v: f32| 1.055 * v.powf(1.0 / 2.4) - 0.055;
    assert!((rgb[0] - srgb(lin(0.5))).abs() < 1e-5);
    assert!((rgb[1] - srgb(2.0 * lin(0.2))).abs() < 1e-5, "{}", rgb[1]);
    assert!((rgb[2] - 0.8).abs() < 1e-5);
    assert_eq!(&rgb[3..5], &[0.0, 0.0]);
}

#[test]
fn the_key_lights_share_is_fitted_from_shading() {
    use assist_render::relight::fit_share;
    // A checkered albedo (uncorrelated with the light) under 30% ambient, 70% key light
    // in the first channel, all ambient in the second, all key in the third.
    let rows: Vec<(f32, f32, [f32; 3])> = (0..400)
        .map(|i| {
            let a = 0.4 + 0.6 * ((i * 7) % 11) as f32 / 10.0;
            let k = ((i * 13) % 17) as f32 / 16.0 * 1.2;
            let rho = if (i / 3) % 2 == 0 { 0.5 } else { 0.3 };
            (a, k, [rho * (0.3 * a + 0.7 * k), rho * a, rho * k])
        })
        .collect();
    let s = fit_share(&rows).unwrap();
    assert!((s[0] - 0.7).abs() < 0.03, "{s:?}");
    assert!(s[1] < 0.03 && s[2] > 0.97, "{s:?}");
    // A key term that does not vary cannot be told from the ambient one.
    let flat: Vec<(f32, f32, [f32; 3])> = (0..100).map(|_| (1.0, 0.5, [0.3; 3])).collect();
    assert_eq!(fit_share(&flat), None);
    // Nothing lit.
    let dark: Vec<(f32, f32, [f32; 3])> = rows.iter().map(|r| (r.0, r.1, [0.0; 3])).collect();
    assert_eq!(fit_share(&dark), None);
}
