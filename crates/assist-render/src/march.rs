//! Marching a batch of world rays through every node: each ray is moved into the node's
//! canonical space, clipped to its box (or to its contracted shell) and marched through its
//! occupancy grid, a few rays at a time, into the node's [`NodeSamples`].

use assist_core::geometry::{Aabb, intersect_local_box};
use assist_core::{DVec3, NodeSpace, Ray, Rng, SceneNode};
use assist_field::contraction::{FAR_RADIUS, contract_to_unit};
use assist_field::{ConeRay, ContractedRay, Marching};
use rayon::prelude::*;

use assist_scene::{NeuralScene, NodeField};

use crate::proposal::{ProposalRecord, resample};
use crate::sample::{NodeSamples, RayBatch, SampleOptions, Traced};
use assist_field::Proposal;

const BLOCK: usize = 256;

/// Samples every node of `scene` along every ray of `rays` into `out` (buffers reused).
/// With `opts.keep_proposal`, the coarse samples of the node a proposal samples are kept
/// in `out.proposal` for its loss.
pub fn sample_rays(scene: &NeuralScene, rays: &RayBatch, opts: &SampleOptions, out: &mut Traced) {
    let n_nodes = scene.scene.nodes.len();
    out.rays = rays.len();
    out.nodes.resize_with(n_nodes, NodeSamples::default);
    let mut record = out.proposal.take().unwrap_or_default();
    out.proposal = None;
    for (k, ns) in out.nodes.iter_mut().enumerate() {
        let keep = opts.keep_proposal && scene.field_of(k).proposal.is_some();
        sample_node(scene, k, rays, opts, ns, keep.then_some(&mut record));
        if keep && out.proposal.is_none() {
            out.proposal = Some(std::mem::take(&mut record));
        }
    }
}

/// Samples node `k` of `scene` along every ray of `rays` into `ns` (its buffers reused).
pub fn sample_rays_node(
    scene: &NeuralScene,
    k: usize,
    rays: &RayBatch,
    opts: &SampleOptions,
    ns: &mut NodeSamples,
) {
    sample_node(scene, k, rays, opts, ns, None);
}

/// [`sample_rays_node`], the coarse samples kept in `record` where a proposal draws the
/// node's samples.
fn sample_node(
    scene: &NeuralScene,
    k: usize,
    rays: &RayBatch,
    opts: &SampleOptions,
    ns: &mut NodeSamples,
    record: Option<&mut ProposalRecord>,
) {
    ns.node = k;
    ns.clear();
    let keep = record.is_some();
    let blocks: Vec<(NodeSamples, ProposalRecord)> = (0..rays.len().div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            // Compiled for the CPU's SIMD level: the marching's floors and ceilings become
            // single instructions instead of library calls (the same values). A
            // `WithSimd` body with an `#[inline(always)]` `run`, not a closure: a closure
            // this large is not inlined into the dispatched variants and would stay at
            // the baseline instruction set.
            assist_simd::dispatch(SampleBlock {
                scene,
                k,
                rays,
                opts,
                range: b * BLOCK..((b + 1) * BLOCK).min(rays.len()),
                keep,
            })
        })
        .collect();
    let (blocks, records): (Vec<NodeSamples>, Vec<ProposalRecord>) = blocks.into_iter().unzip();
    ns.append_all(&blocks);
    if let Some(rec) = record {
        rec.node = k;
        rec.append_all(&records);
    }
}

/// The samples of node `k` along rays `range` (block-local starts, no trailing end).
struct SampleBlock<'a> {
    scene: &'a NeuralScene,
    k: usize,
    rays: &'a RayBatch,
    opts: &'a SampleOptions,
    range: std::ops::Range<usize>,
    /// Keep a proposal's coarse samples.
    keep: bool,
}

impl assist_simd::WithSimd for SampleBlock<'_> {
    type Output = (NodeSamples, ProposalRecord);
    #[inline(always)]
    fn run(self) -> (NodeSamples, ProposalRecord) {
        let mut local = NodeSamples::default();
        let mut record = ProposalRecord::default();
        local.start.reserve(self.range.len() + 1);
        // Looked up once per block, not per ray.
        let node = &self.scene.scene.nodes[self.k];
        let at = (
            node,
            self.scene.field_of(self.k),
            node.local_aabb(),
            Sphere::around(node),
        );
        // LANES rays marched at once (the same samples as one at a time).
        let (rays, opts, k) = (self.rays, self.opts, self.k);
        if let (NodeSpace::Contracted, Some(p)) = (at.1.space, &at.1.proposal) {
            let none = ContractedRay::none();
            let keep = self.keep.then_some(&mut record);
            let drawn = Drawn {
                proposal: p,
                opts,
                k,
                keep,
            };
            proposal_lanes(at.1, none, self.range, rays, &mut local, drawn, |r| {
                contracted_march(at, r, k, rays, opts)
            });
        } else if at.1.space == NodeSpace::Contracted {
            let none = ContractedRay::none();
            march_lanes(at.1, none, self.range, rays, &mut local, |r| {
                contracted_march(at, r, k, rays, opts)
            });
        } else {
            let none = ConeRay::none();
            march_lanes(at.1, none, self.range, rays, &mut local, |r| {
                bounded_march(at, r, k, rays, opts)
            });
        }
        (local, record)
    }
}

/// Rays marched together through a node's grid (see
/// [`assist_field::OccupancyGrid::march_each`]).
const LANES: usize = 4;

/// Marches `range`'s rays through `nf`'s grid, LANES at a time, appending each ray's
/// samples to `local` in order; `setup(r)` is ray `r`'s march and placement, or none
/// where it misses the node.
#[inline(always)]
fn march_lanes<R: Marching + Copy>(
    nf: &NodeField,
    none: R,
    range: std::ops::Range<usize>,
    rays: &RayBatch,
    local: &mut NodeSamples,
    setup: impl Fn(usize) -> Option<(R, Placed)>,
) {
    march_rays(nf, none, range, setup, |r, steps, placed| {
        local.start.push(local.t.len() as u32);
        if let Some(p) = placed {
            p.push(steps, rays.image[r], local);
        }
    });
}

/// Marches `range`'s rays through `nf`'s grid, LANES at a time, handing each ray's steps
/// and placement (none where it misses the node) to `each`, in order.
#[inline(always)]
fn march_rays<R: Marching + Copy>(
    nf: &NodeField,
    none: R,
    range: std::ops::Range<usize>,
    setup: impl Fn(usize) -> Option<(R, Placed)>,
    mut each: impl FnMut(usize, &[assist_field::Step], Option<Placed>),
) {
    let mut lanes: [Vec<assist_field::Step>; LANES] = Default::default();
    let end = range.end;
    for first in range.step_by(LANES) {
        let n = LANES.min(end - first);
        let mut marches = [none; LANES];
        let mut placed = [None; LANES];
        for i in 0..n {
            if let Some((m, p)) = setup(first + i) {
                marches[i] = m;
                placed[i] = Some(p);
            }
        }
        lanes.iter_mut().for_each(Vec::clear);
        nf.occupancy.march_each(&mut marches, &mut lanes);
        for i in 0..n {
            each(first + i, &lanes[i], placed[i]);
        }
    }
}

/// How a proposal draws a node's samples in [`proposal_lanes`].
struct Drawn<'a> {
    proposal: &'a Proposal,
    opts: &'a SampleOptions,
    /// The node's index (for the rays' random streams).
    k: usize,
    /// Where the coarse samples are kept (training).
    keep: Option<&'a mut ProposalRecord>,
}

/// [`march_lanes`] for a node whose samples a proposal draws: every ray of `range` is
/// marched (its steps the coarse samples), the proposal queried at them all at once, and
/// each ray's samples drawn from its weights ([`crate::proposal::resample`]).
#[inline(always)]
fn proposal_lanes<R: Marching + Copy>(
    nf: &NodeField,
    none: R,
    range: std::ops::Range<usize>,
    rays: &RayBatch,
    local: &mut NodeSamples,
    drawn: Drawn,
    setup: impl Fn(usize) -> Option<(R, Placed)>,
) {
    let mut steps: Vec<assist_field::Step> = Vec::new();
    let mut start: Vec<u32> = vec![0];
    let mut placed: Vec<Option<Placed>> = Vec::with_capacity(range.len());
    march_rays(nf, none, range.clone(), setup, |_, s, p| {
        steps.extend_from_slice(s);
        start.push(steps.len() as u32);
        placed.push(p);
    });
    // The coarse samples' positions and intervals, and the proposal's densities there.
    let mut pos: [Vec<f32>; 3] = std::array::from_fn(|_| Vec::with_capacity(steps.len()));
    let mut delta = Vec::with_capacity(steps.len());
    for (i, p) in placed.iter().enumerate() {
        let Some(p) = p else { continue };
        for s in &steps[start[i] as usize..start[i + 1] as usize] {
            let u = p.unit_at(s.t);
            for a in 0..3 {
                pos[a].push(u[a]);
            }
            delta.push(s.dt * p.per_unit);
        }
    }
    let mut sigma = vec![0.0f32; steps.len()];
    let at = [&pos[0][..], &pos[1][..], &pos[2][..]];
    // The encoding's buffer is kept per thread: a block's is a few hundred kilobytes.
    thread_local! {
        static ENCODING: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    ENCODING.with_borrow_mut(|enc| drawn.proposal.field.density(at, &mut sigma, enc));
    let (mut w, mut fine, mut spans) = (Vec::new(), Vec::new(), Vec::new());
    for (i, r) in range.enumerate() {
        local.start.push(local.t.len() as u32);
        let Some(p) = placed[i] else { continue };
        let c = start[i] as usize..start[i + 1] as usize;
        w.resize(c.len(), 0.0);
        crate::proposal::weights(&sigma[c.clone()], &delta[c.clone()], &mut w);
        fine.clear();
        let mut rng = drawn
            .opts
            .jitter
            .then(|| Rng::stream(drawn.opts.seed ^ DRAW_STREAM, (r * 1024 + drawn.k) as u64));
        let n = drawn_samples(drawn.proposal.samples, drawn.opts);
        resample(&steps[c], &w, n, rng.as_mut(), &mut fine, &mut spans);
        p.push(&fine, rays.image[r], local);
    }
    if let Some(rec) = drawn.keep {
        rec.pos = pos;
        rec.delta = delta;
        rec.sigma = sigma;
        rec.steps = steps;
        rec.start = start;
        rec.spans = spans;
    }
}

/// How many samples a proposal draws on each ray: its own count divided by the step
/// scale (so `render --quality draft` draws half, as it marches half), at least one and
/// at most `max_per_node`.
pub(crate) fn drawn_samples(samples: usize, opts: &SampleOptions) -> usize {
    let scaled = (samples as f32 / opts.step_scale.max(f32::MIN_POSITIVE)).round();
    (scaled as usize).clamp(1, opts.max_per_node.max(1))
}

/// How much longer a proposal's coarse march steps than the node's own march: its
/// samples only place the drawn ones, and the proposal's query and training scale with
/// them (chosen by measurement: BENCHMARKS.md).
pub const COARSE_STEP_SCALE: f32 = 4.0;

/// Mixed into the seed of the streams that draw a proposal's samples, so they are not
/// the marches' own.
const DRAW_STREAM: u64 = 0x5DEE_CE66_D1CE_4E5B;

/// Ray `r` of `rays` in world space.
#[inline(always)]
fn world_ray(rays: &RayBatch, r: usize) -> Ray {
    Ray {
        origin: DVec3::from(rays.origin[r].map(f64::from)),
        dir: DVec3::from(rays.dir[r].map(f64::from)),
    }
}

/// Ray `r`'s march through bounded node `k` (none when it misses the box), and where its
/// steps' samples go.
#[inline(always)]
fn bounded_march(
    (node, nf, aabb, sphere): (&SceneNode, &NodeField, Aabb, Sphere),
    r: usize,
    k: usize,
    rays: &RayBatch,
    opts: &SampleOptions,
) -> Option<(ConeRay, Placed)> {
    let ray = world_ray(rays, r);
    if sphere.missed_by(&ray) {
        return None;
    }
    let hit = intersect_local_box(
        &ray,
        &node.world_from_local,
        &aabb,
        rays.near as f64,
        f64::INFINITY,
    )?;
    let size = node.half_size * 2.0;
    let o = (hit.local_ray.origin / size + 0.5).as_vec3().to_array();
    let d = (hit.local_ray.dir / size).as_vec3().to_array();
    let march = ConeRay::new(
        o,
        d,
        hit.local_t_in as f32,
        hit.local_t_out as f32,
        nf.step * opts.step_scale,
        nf.cone * opts.step_scale,
        ray_jitter(opts, r, k),
        opts.max_per_node,
    );
    let placed = Placed {
        o,
        d,
        contracted: false,
        dir: hit.local_ray.dir.as_vec3().to_array(),
        world_per_local: (1.0 / hit.local_per_world) as f32,
        per_unit: 1.0 / nf.unit,
    };
    Some((march, placed))
}

/// Where a march's steps lie: the ray in [0, 1]³ box coordinates (bounded) or in box
/// units mapped by the contraction, its canonical direction, and the scales from its
/// parameter to world distance and box diagonals.
#[derive(Clone, Copy)]
struct Placed {
    o: [f32; 3],
    d: [f32; 3],
    contracted: bool,
    dir: [f32; 3],
    world_per_local: f32,
    per_unit: f32,
}

impl Placed {
    /// The position in [0, 1]³ at parameter `t`.
    #[inline(always)]
    fn unit_at(&self, t: f32) -> [f32; 3] {
        let (o, d) = (self.o, self.d);
        let u = [0, 1, 2].map(|a| o[a] + d[a] * t);
        if self.contracted {
            contract_to_unit(u)
        } else {
            u.map(|v| v.clamp(0.0, 1.0))
        }
    }

    #[inline(always)]
    fn push(&self, steps: &[assist_field::Step], image: u32, out: &mut NodeSamples) {
        let (o, d) = (self.o, self.d);
        let (dir, scale, per_unit) = (self.dir, self.world_per_local, self.per_unit);
        if self.contracted {
            let to_unit = |t: f32| contract_to_unit([0, 1, 2].map(|a| o[a] + d[a] * t));
            push_samples(out, steps, to_unit, dir, image, scale, per_unit);
        } else {
            let to_unit = |t: f32| [0, 1, 2].map(|a| (o[a] + d[a] * t).clamp(0.0, 1.0));
            push_samples(out, steps, to_unit, dir, image, scale, per_unit);
        }
    }
}

/// A world sphere holding a node's box, slightly grown: a ray whose line passes outside it
/// misses the box, known without taking the ray into the box's frame.
#[derive(Clone, Copy)]
struct Sphere {
    centre: DVec3,
    radius_sq: f64,
}

impl Sphere {
    fn around(node: &SceneNode) -> Sphere {
        let r = (node.world_from_local.scale * node.half_size).length();
        // Grown far beyond any rounding of the box test.
        let r = r * (1.0 + 1e-6) + 1e-9;
        Sphere {
            centre: node.world_from_local.translation,
            radius_sq: r * r,
        }
    }

    #[inline(always)]
    fn missed_by(&self, ray: &Ray) -> bool {
        let oc = self.centre - ray.origin;
        let along = oc.dot(ray.dir);
        oc.length_squared() - along * along / ray.dir.length_squared() > self.radius_sq
    }
}

/// The first sample's offset within its step: random when training, the middle otherwise.
#[inline(always)]
fn ray_jitter(opts: &SampleOptions, r: usize, k: usize) -> f32 {
    if opts.jitter {
        Rng::stream(opts.seed, (r * 1024 + k) as u64).f32()
    } else {
        0.5
    }
}

/// Appends the marched `steps` of one ray: positions in [0, 1]³ from `to_unit(t)`, the
/// canonical direction, world distance `t · world_per_local` and the interval in box
/// diagonals `dt · per_unit`.
#[inline(always)]
fn push_samples(
    out: &mut NodeSamples,
    steps: &[assist_field::Step],
    to_unit: impl Fn(f32) -> [f32; 3],
    dir: [f32; 3],
    image: u32,
    world_per_local: f32,
    per_unit: f32,
) {
    for s in steps {
        let p = to_unit(s.t);
        for a in 0..3 {
            out.pos[a].push(p[a]);
            out.dir[a].push(dir[a]);
        }
        out.image.push(image);
        out.t.push(s.t * world_per_local);
        out.dt.push(s.dt * per_unit);
    }
}

/// Ray `r`'s march through contracted node `k`: from the near plane to [`FAR_RADIUS`] box
/// half-sizes, the box linearly and beyond it in contracted space (none when the ray
/// starts in the far shell).
#[inline(always)]
fn contracted_march(
    (node, nf, _, _): (&SceneNode, &NodeField, Aabb, Sphere),
    r: usize,
    k: usize,
    rays: &RayBatch,
    opts: &SampleOptions,
) -> Option<(ContractedRay, Placed)> {
    let ray = world_ray(rays, r);
    let o_local = node.world_from_local.local_from_world_point(ray.origin);
    let d_world_local = node.world_from_local.local_from_world_vector(ray.dir);
    let local_per_world = d_world_local.length();
    if local_per_world <= 0.0 || !local_per_world.is_finite() {
        return None;
    }
    let d_unit = d_world_local / local_per_world;
    let half = node.half_size;
    let o = (o_local / half).as_vec3().to_array();
    let d = (d_unit / half).as_vec3().to_array();
    // Where the ray leaves the box grown FAR_RADIUS times (a ray starting outside it is
    // in the far shell already: nothing to sample).
    let (t_in, t_out) = assist_core::Aabb::from_half_size(half * FAR_RADIUS as f64).intersect(
        o_local,
        d_unit,
        rays.near as f64 * local_per_world,
        f64::INFINITY,
    )?;
    let scale = opts.step_scale
        * if nf.proposal.is_some() {
            COARSE_STEP_SCALE
        } else {
            1.0
        };
    let march = ContractedRay::new(
        o,
        d,
        t_in as f32,
        t_out as f32,
        nf.step * scale,
        nf.cone * scale,
        nf.contracted_step * scale,
        ray_jitter(opts, r, k),
        opts.max_per_node,
    );
    let placed = Placed {
        o,
        d,
        contracted: true,
        dir: d_unit.as_vec3().to_array(),
        world_per_local: (1.0 / local_per_world) as f32,
        per_unit: 1.0 / nf.unit,
    };
    Some((march, placed))
}

#[cfg(test)]
mod tests {
    use super::*;
    use assist_core::{DQuat, Similarity3};

    /// The sphere test never turns away a ray the box test lets in, and turns away most
    /// rays that pass far from the box.
    #[test]
    fn a_ray_the_sphere_turns_away_misses_the_box() {
        let mut rng = Rng::new(5);
        let mut u = |a: f64, b: f64| a + (b - a) * rng.f32() as f64;
        let (mut hits, mut skipped) = (0, 0);
        for _ in 0..20_000 {
            let mut node = SceneNode {
                id: 1,
                label: "box".into(),
                embedding: None,
                class: None,
                field: "f".into(),
                half_size: DVec3::new(u(0.05, 0.4), u(0.05, 0.4), u(0.05, 0.4)),
                world_from_local: Similarity3::IDENTITY,
                space: NodeSpace::Box,
                cast: None,
            };
            let axis = DVec3::new(u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0)).normalize();
            node.world_from_local = Similarity3::new(
                DQuat::from_axis_angle(axis, u(0.0, 6.3)),
                DVec3::new(u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0)),
                DVec3::new(u(0.5, 2.0), u(0.5, 2.0), u(0.5, 2.0)),
            )
            .unwrap();
            // Every other ray passes just inside one of the box's corners, in any
            // direction (the rays that graze the sphere); the others aim near the box.
            let ray = if u(0.0, 1.0) < 0.5 {
                let h = node.half_size * 0.999;
                let corner = DVec3::new(
                    h.x * u(-1.0, 1.0).signum(),
                    h.y * u(-1.0, 1.0).signum(),
                    h.z * u(-1.0, 1.0).signum(),
                );
                let at = node.world_from_local.transform_point(corner);
                let d = DVec3::new(u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0)).normalize();
                Ray {
                    origin: at - d * 4.0,
                    dir: d.as_vec3().as_dvec3(),
                }
            } else {
                let origin = DVec3::new(u(-3.0, 3.0), u(-3.0, 3.0), u(-3.0, 3.0));
                let aim = node.world_from_local.translation
                    + DVec3::new(u(-0.8, 0.8), u(-0.8, 0.8), u(-0.8, 0.8));
                let dir = (aim - origin).normalize().as_vec3().as_dvec3();
                Ray { origin, dir }
            };
            let hit = intersect_local_box(
                &ray,
                &node.world_from_local,
                &node.local_aabb(),
                0.0,
                f64::INFINITY,
            );
            let missed = Sphere::around(&node).missed_by(&ray);
            if hit.is_some() {
                hits += 1;
                assert!(!missed, "{ray:?} hits {node:?}");
            } else if missed {
                skipped += 1;
            }
        }
        assert!(
            hits > 2_000 && skipped > 2_000,
            "{hits} hits, {skipped} skipped"
        );
    }

    /// A proposal draws its own count at the default scale, half at a draft's, and
    /// never none or more than the cap.
    #[test]
    fn drawn_samples_follow_the_step_scale() {
        let at = |step_scale: f32, max_per_node: usize| SampleOptions {
            step_scale,
            max_per_node,
            ..SampleOptions::default()
        };
        assert_eq!(drawn_samples(24, &at(1.0, 1024)), 24);
        assert_eq!(drawn_samples(24, &at(2.0, 1024)), 12);
        assert_eq!(drawn_samples(24, &at(1.5, 1024)), 16);
        assert_eq!(drawn_samples(24, &at(0.5, 1024)), 48);
        assert_eq!(drawn_samples(24, &at(1.0, 10)), 10);
        assert_eq!(drawn_samples(1, &at(16.0, 1024)), 1);
    }
}
