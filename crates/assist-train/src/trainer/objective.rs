//! The training objective of one ray: every term's value and, when asked, the gradient of
//! the weighted total with respect to the composited outputs, written once. The gradient
//! is taken inside the compositing pass; the values are summed after it for the log.

use assist_render::{CompositeGrad, RayOutputs};

use super::rays::Target;
use super::{Lambdas, Terms};
use crate::losses;

/// What the terms of a batch depend on besides the ray.
pub(super) struct Objective<'a> {
    pub(super) lam: Lambdas,
    /// Rays in the batch: every term is a mean over them.
    pub(super) n_rays: f32,
    /// Scene extent: depths and distortion are measured in it.
    pub(super) extent: f32,
    /// Node index of the background.
    pub(super) background: Option<usize>,
    /// The depth prior has unknown scale: the paper's affine-mapped squared error.
    pub(super) depth_affine: bool,
    pub(super) depth_wq: [f32; 2],
    /// Per node index: an object (not the background).
    pub(super) is_object: &'a [bool],
}

/// Unweighted values of one ray's terms (background terms already carry the prior's
/// confidence), and its part of the gradient of the depth prior's scale and shift.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct RayTerms {
    pub(super) terms: Terms<f32>,
    pub(super) d_depth_wq: [f32; 2],
}

impl std::ops::Deref for RayTerms {
    type Target = Terms<f32>;
    fn deref(&self) -> &Terms<f32> {
        &self.terms
    }
}

impl std::ops::DerefMut for RayTerms {
    fn deref_mut(&mut self) -> &mut Terms<f32> {
        &mut self.terms
    }
}

impl Objective<'_> {
    /// The terms of ray `o` against its target `t`; with `grads`, adds the gradient of
    /// `Σ λ·term / n_rays` to the ray's and each node's output gradients.
    pub(super) fn ray(
        &self,
        t: &Target,
        o: &RayOutputs,
        mut grads: Option<(&mut CompositeGrad, &mut [CompositeGrad])>,
    ) -> RayTerms {
        let (lam, n) = (self.lam, self.n_rays / t.weight);
        let (c, per) = (o.composite, o.nodes);
        let mut terms = RayTerms::default();
        let (v, d) = losses::rgb(c.rgb, t.rgb);
        terms.comp_rgb = v;
        // Already in scene extents (`Traced::distortion_unit`).
        terms.distortion = o.distortion;
        if let Some((g, _)) = grads.as_mut() {
            g.rgb = d.map(|v| lam.comp_rgb * v / n);
            g.distortion = lam.distortion / n;
        }
        if t.surface.is_some() && lam.empty > 0.0 {
            // Every node's opacity in front of the surface the depth map sees.
            for (k, pk) in per.iter().enumerate() {
                let (v, d) = losses::opacity(pk.front, 0.0);
                terms.empty += v;
                if let Some((_, gn)) = grads.as_mut() {
                    gn[k].front += lam.empty * d / n;
                }
            }
        }
        if t.masked {
            for (k, pk) in per.iter().enumerate() {
                if !self.is_object[k] {
                    continue;
                }
                let m = if t.mask_node == k as u32 { 1.0 } else { 0.0 };
                let (v, d) = losses::opacity(pk.opacity, m);
                terms.obj_acc += v;
                let gk = grads.as_mut().map(|(_, gn)| &mut gn[k]);
                let Some(gk) = gk else {
                    if m > 0.0 {
                        terms.obj_rgb += losses::premultiplied_rgb(pk.rgb, pk.opacity, t.rgb).0;
                        terms.obj_share += losses::share(o.share[k]).0;
                    }
                    continue;
                };
                gk.opacity += lam.obj_acc * d / n;
                if m > 0.0 {
                    let (v, dc, d_o) = losses::premultiplied_rgb(pk.rgb, pk.opacity, t.rgb);
                    terms.obj_rgb += v;
                    for ch in 0..3 {
                        gk.rgb[ch] += lam.obj_rgb * dc[ch] / n;
                    }
                    gk.opacity += lam.obj_rgb * d_o / n;
                    let (v, d) = losses::share(o.share[k]);
                    terms.obj_share += v;
                    gk.share += lam.obj_share * d / n;
                }
            }
        }
        let Some(b) = self.background else {
            return terms;
        };
        let pw = t.prior_weight;
        let pb = &per[b];
        if let Some(inp) = t.inpaint {
            // The premultiplied colour term is also met by a background left transparent
            // behind objects, which renders as whatever lies past it once they move;
            // `bg_opacity` asks the background to be opaque past the prior's depth (its
            // opacity there, `beyond`, is measured from where the trainer set
            // `Traced::beyond`; without a prior depth it is 0 and the term is left out).
            let (v, dc, d_o) = losses::premultiplied_rgb(pb.rgb, pb.opacity, inp);
            let rw = t.rgb_weight;
            terms.bg_rgb = rw * v;
            let behind = t.depth.is_some() && lam.bg_opacity > 0.0;
            let (vo, dob) = if behind {
                losses::opacity(pb.beyond, 1.0)
            } else {
                (0.0, 0.0)
            };
            terms.bg_opacity = pw * vo;
            // On an object's pixels, the background's opacity in front of where `beyond`
            // starts: what it holds there lies inside the object that hides the prior's
            // surface. (Elsewhere a bounded background paints what lies outside its box
            // in front of it.)
            let placed = t
                .depth
                .and_then(|d| super::step::prior_depth(d, self.depth_affine, self.depth_wq));
            let on_object = self.is_object.get(t.mask_node as usize) == Some(&true);
            let (vc, dfront) = if on_object && placed.is_some() && lam.bg_clear > 0.0 {
                losses::opacity(pb.opacity - pb.beyond, 0.0)
            } else {
                (0.0, 0.0)
            };
            terms.bg_clear = pw * vc;
            if let Some((_, gn)) = grads.as_mut() {
                for ch in 0..3 {
                    gn[b].rgb[ch] += rw * lam.bg_rgb * dc[ch] / n;
                }
                gn[b].opacity += rw * lam.bg_rgb * d_o / n;
                gn[b].beyond += pw * lam.bg_opacity * dob / n;
                let g = pw * lam.bg_clear * dfront / n;
                gn[b].opacity += g;
                gn[b].beyond -= g;
            }
        }
        if let Some(d) = t.depth {
            if self.depth_affine {
                let (v, gd, gab) = losses::affine_depth(pb.depth, self.extent, self.depth_wq, d);
                terms.bg_depth = pw * v;
                terms.d_depth_wq = gab.map(|g| pw * lam.bg_depth * g / n);
                if let Some((_, gn)) = grads.as_mut() {
                    gn[b].depth += pw * lam.bg_depth * gd / n;
                }
            } else {
                let (v, gd, gs) = losses::depth_moment(pb.depth, pb.depth_sq, self.extent, d);
                terms.bg_depth = pw * v;
                if let Some((_, gn)) = grads.as_mut() {
                    gn[b].depth += pw * lam.bg_depth * gd / n;
                    gn[b].depth_sq += pw * lam.bg_depth * gs / n;
                }
            }
        }
        terms
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_render::Composite;

    /// `Σ λ·term / n` from the values alone.
    fn total(obj: &Objective, t: &Target, o: &RayOutputs) -> f64 {
        let v = obj.ray(t, o, None);
        let l = obj.lam;
        (v.comp_rgb
            + l.obj_acc * v.obj_acc
            + l.obj_rgb * v.obj_rgb
            + l.obj_share * v.obj_share
            + l.distortion * v.distortion
            + l.bg_rgb * v.bg_rgb
            + l.bg_opacity * v.bg_opacity
            + l.bg_clear * v.bg_clear
            + l.bg_depth * v.bg_depth
            + l.empty * v.empty) as f64
            / obj.n_rays as f64
    }

    fn comp(rgb: [f32; 3], depth: f32, opacity: f32, depth_sq: f32) -> Composite {
        Composite {
            rgb,
            depth,
            opacity,
            depth_sq,
            beyond: 0.8 * opacity,
            front: 0.3 * opacity,
        }
    }

    /// Every output the objective reads, as a mutable f32.
    fn outputs_mut<'a>(
        c: &'a mut Composite,
        nodes: &'a mut [Composite],
        share: &'a mut [f32],
        dist: &'a mut f32,
    ) -> Vec<(&'static str, usize, &'a mut f32)> {
        let mut v: Vec<(&'static str, usize, &'a mut f32)> = Vec::new();
        for x in c.rgb.iter_mut() {
            v.push(("rgb", usize::MAX, x));
        }
        v.push(("distortion", usize::MAX, dist));
        for (k, n) in nodes.iter_mut().enumerate() {
            let Composite {
                rgb,
                depth,
                opacity,
                depth_sq,
                beyond,
                front,
            } = n;
            for x in rgb.iter_mut() {
                v.push(("rgb", k, x));
            }
            v.push(("depth", k, depth));
            v.push(("opacity", k, opacity));
            v.push(("depth_sq", k, depth_sq));
            v.push(("beyond", k, beyond));
            v.push(("front", k, front));
        }
        for (k, s) in share.iter_mut().enumerate() {
            v.push(("share", k, s));
        }
        v
    }

    fn analytic(g: &CompositeGrad, gn: &[CompositeGrad], what: &str, k: usize, ch: usize) -> f32 {
        let g = if k == usize::MAX { g } else { &gn[k] };
        match what {
            "rgb" => g.rgb[ch],
            "distortion" => g.distortion,
            "depth" => g.depth,
            "opacity" => g.opacity,
            "depth_sq" => g.depth_sq,
            "beyond" => g.beyond,
            "front" => g.front,
            _ => g.share,
        }
    }

    #[test]
    fn gradients_match_central_differences() {
        // Node 0 the background, nodes 1 and 2 objects; the ray's mask names node 1.
        let is_object = [false, true, true];
        for depth_affine in [false, true] {
            let obj = Objective {
                lam: Lambdas {
                    distortion: 0.3,
                    bg_opacity: 0.4,
                    bg_clear: 0.6,
                    empty: 0.7,
                    ..Lambdas::default()
                },
                n_rays: 4.0,
                extent: 2.5,
                background: Some(0),
                depth_affine,
                depth_wq: [1.3, 0.1],
                is_object: &is_object,
            };
            let t = Target {
                rgb: [0.2, 0.6, 0.9],
                mask_node: 1,
                masked: true,
                inpaint: Some([0.4, 0.3, 0.2]),
                depth: Some(0.7),
                prior_weight: 0.8,
                rgb_weight: 0.3,
                surface: Some(1.1),
                pixel: 0,
                weight: 1.0,
            };
            let mut c = comp([0.3, 0.5, 0.7], 1.2, 0.95, 1.9);
            let mut nodes = [
                comp([0.25, 0.2, 0.1], 1.6, 0.6, 2.9),
                comp([0.1, 0.3, 0.5], 1.1, 0.7, 1.4),
                comp([0.05, 0.02, 0.1], 0.9, 0.2, 0.9),
            ];
            let mut share = [0.3f32, 0.6, 0.1];
            let mut dist = 0.4f32;
            let mk = |c: &Composite, n: &[Composite], s: &[f32], d: f32| {
                let (c, n, s) = (*c, n.to_vec(), s.to_vec());
                (c, n, s, d)
            };
            let (c0, n0, s0, d0) = mk(&c, &nodes, &share, dist);
            let o = RayOutputs {
                ray: 0,
                composite: &c0,
                nodes: &n0,
                share: &s0,
                distortion: d0,
            };
            let mut g = CompositeGrad::default();
            let mut gn = vec![CompositeGrad::default(); 3];
            obj.ray(&t, &o, Some((&mut g, &mut gn)));
            let count = outputs_mut(&mut c, &mut nodes, &mut share, &mut dist).len();
            let mut checked = 0;
            for j in 0..count {
                let h = 1e-3f32;
                let eval = |delta: f32| {
                    let (mut c1, mut n1, mut s1, mut d1) = mk(&c, &nodes, &share, dist);
                    let mut outs = outputs_mut(&mut c1, &mut n1, &mut s1, &mut d1);
                    *outs[j].2 += delta;
                    drop(outs);
                    let o = RayOutputs {
                        ray: 0,
                        composite: &c1,
                        nodes: &n1,
                        share: &s1,
                        distortion: d1,
                    };
                    total(&obj, &t, &o)
                };
                let numeric = (eval(h) - eval(-h)) / (2.0 * h as f64);
                let (what, k) = {
                    let outs = outputs_mut(&mut c, &mut nodes, &mut share, &mut dist);
                    (outs[j].0, outs[j].1)
                };
                // The channel of an rgb entry: entries come in runs of three.
                let ch = {
                    let outs = outputs_mut(&mut c, &mut nodes, &mut share, &mut dist);
                    outs[..j]
                        .iter()
                        .rev()
                        .take_while(|e| e.0 == "rgb" && e.1 == k)
                        .count()
                };
                let a = analytic(&g, &gn, what, k, ch) as f64;
                assert!(
                    (a - numeric).abs() <= 1e-3 * numeric.abs().max(1.0) + 2e-4,
                    "affine {depth_affine}: d/d {what}[{k}] ch {ch}: analytic {a}, numeric {numeric}"
                );
                checked += usize::from(numeric.abs() > 1e-4);
            }
            assert!(checked >= 12, "only {checked} outputs had a gradient");
        }
    }
}
