//! The predicted-normal term of objects whose colour follows the reflected view direction
//! ([`FieldConfig::reflect`](assist_field::FieldConfig)): after the forward pass, each
//! such node's predicted normals are held to its density's own, each sample weighed by
//! its share of its ray within the node; the gradient waits in the node's tape for the
//! backward pass.

use super::Trainer;

impl Trainer {
    /// The term's value (per ray, unweighted) over the batch; its gradient, weighted by
    /// `Lambdas::normal`, left in the tapes of the nodes it applies to.
    pub(super) fn normal_loss(&mut self) -> f64 {
        let lam = self.opts.lambdas.normal;
        let n_rays = self.targets.len().max(1) as f32;
        let mut total = 0.0f64;
        for (ns, tape) in self.traced.nodes.iter().zip(self.tapes.iter_mut()) {
            let node = &self.scene.scene.nodes[ns.node];
            let field = &self.scene.fields[&node.field].field;
            if lam <= 0.0 || !field.config.reflect || ns.is_empty() {
                continue;
            }
            let samples = ns.samples();
            let h = node.half_size.as_vec3().to_array();
            let mut targets = vec![0.0f32; 3 * ns.len()];
            field.density_normals(&samples, tape, h, &mut targets);
            let mut weights = vec![0.0f32; ns.len()];
            for r in 0..ns.start.len().saturating_sub(1) {
                let mut trans = 1.0f32;
                for j in ns.range(r) {
                    let alpha = 1.0 - (-ns.sigma[j] * ns.dt[j]).exp();
                    weights[j] = trans * alpha * lam / n_rays;
                    trans *= 1.0 - alpha;
                }
            }
            total += field.normal_loss(tape, &targets, &weights) / f64::from(lam);
        }
        total
    }
}
