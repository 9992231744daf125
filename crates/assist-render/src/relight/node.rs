//! The relighting of one node's queried samples, as a render applies it.

use assist_scene::NeuralScene;

/// Node `node`'s colours shaded by the scene's light where the node stands now, when the
/// scene relights and the node stands elsewhere than where it was photographed
/// ([`super`]).
pub(crate) fn relight_node(scene: &NeuralScene, node: usize, pos: &[Vec<f32>; 3], rgb: &mut [f32]) {
    let s = &scene.scene;
    let n = &s.nodes[node];
    if let (true, Some(light), Some(cast)) = (s.relight, &s.light, &n.cast)
        && cast.pose != n.world_from_local
        && !rgb.is_empty()
    {
        let lights = crate::light::light_points(light, s.up);
        let nf = scene.field_of(node);
        // The key light's share as the object's own shading shows it, else as its shadow
        // does.
        let colour = |pos: &[[f32; 3]], dirs: &[[f32; 3]]| {
            let axis = |v: &[[f32; 3]], a: usize| v.iter().map(|p| p[a]).collect::<Vec<f32>>();
            let (p, d) = (
                [0, 1, 2].map(|a| axis(pos, a)),
                [0, 1, 2].map(|a| axis(dirs, a)),
            );
            let image = vec![u32::MAX; pos.len()];
            let samples = assist_field::Samples {
                pos: [&p[0], &p[1], &p[2]],
                dir: [&d[0], &d[1], &d[2]],
                image: &image,
            };
            let (mut sigma, mut rgb) = (vec![0.0; pos.len()], vec![0.0; 3 * pos.len()]);
            nf.field.forward(&samples, &mut sigma, &mut rgb);
            rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
        };
        let strength = super::strength_cached(
            &n.field,
            &nf.occupancy,
            n.half_size,
            &cast.pose,
            &lights,
            s.up,
            colour,
        )
        .unwrap_or(cast.strength);
        let cast = assist_core::ShadowCast {
            pose: cast.pose,
            strength,
        };
        let grid = super::relight_cached(
            &n.field,
            &nf.occupancy,
            n.half_size,
            &n.world_from_local,
            &cast,
            &lights,
            s.up,
        );
        grid.apply(pos, rgb);
    }
}
