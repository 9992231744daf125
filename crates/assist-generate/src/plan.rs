//! A sample's rearrangement: which own objects are deleted, kept or moved, which library
//! objects are added, each placed by draws of yaw, scale and a support cell clear of the
//! others, then expressed as actions and applied to a fork of the base scene.

use assist_core::action::{AxisSpec, NodeRef};
use assist_core::{Action, ActionConfig, DVec3, Operation, Rng};
use assist_session::Session;

use crate::place::{self, Posed, Reject, Shape};
use crate::sample::GaveUp;
use crate::{Base, GenError, Generator, Result};

/// An accepted draw (pose, yaw, scale, support height, occupied box) or the rejections by
/// reason.
type Drawn = std::result::Result<(Posed, f64, f64, f64, assist_core::Obb), Vec<(String, u32)>>;

/// A placed object.
pub(crate) struct Placed {
    pub id: u16,
    /// `None` for the scene's own object, `Some(k)` for library entry k.
    pub library: Option<usize>,
    pub yaw_deg: f64,
    pub scale: f64,
    pub centre: DVec3,
    pub support: f64,
}

/// The drawn rearrangement of one sample.
pub(crate) struct Plan {
    pub index: u64,
    pub base: usize,
    pub actions: Vec<Action>,
    pub placed: Vec<Placed>,
    pub deleted: Vec<u16>,
    pub gave_up: Vec<GaveUp>,
    pub draws: u32,
    pub rejected: u32,
    /// Every rejected draw of the sample, by reason.
    pub rejections: std::collections::BTreeMap<Reject, u32>,
    pub rng: Rng,
}

fn action(id: u16, op: Operation, config: ActionConfig) -> Action {
    Action {
        instance_id: id,
        operation: op,
        config,
    }
}

impl Generator {
    /// Draws sample `index`'s rearrangement (no rendering).
    pub(crate) fn plan(&self, index: u64) -> Result<Plan> {
        let spec = &self.spec;
        let mut rng = Rng::stream(spec.seed, index);
        let bi = rng.below(self.bases.len() as u64) as usize;
        let base = &self.bases[bi];
        let scene = base.session.description();
        let mpu = scene.meters_per_unit;
        let p = &spec.placement;
        let mut own: Vec<_> = scene.nodes.iter().filter(|n| !n.is_background()).collect();
        own.sort_by_key(|n| n.id);
        let mut deleted = Vec::new();
        let mut moving = Vec::new();
        let mut staying = Vec::new();
        for n in &own {
            let keep = rng.f64() < spec.objects.keep;
            let mv = rng.f64() < spec.objects.move_;
            if !keep {
                deleted.push(n.id);
            } else if mv && base.shapes.get(&n.field).is_some_and(|s| s.is_some()) {
                moving.push(*n);
            } else {
                staying.push(*n);
            }
        }
        let counts: Vec<u32> = spec
            .library
            .iter()
            .map(|l| l.min + rng.below((l.max - l.min) as u64 + 1) as u32)
            .collect();
        let shape_of =
            |n: &assist_core::SceneNode| base.shapes.get(&n.field).and_then(|s| s.as_ref());
        let gap = p.gap_m / mpu;
        let mut obstacles: Vec<(u16, assist_core::Obb)> = Vec::new();
        for n in &staying {
            if let Some(s) = shape_of(n) {
                obstacles.push((n.id, Posed::of(n).occupied_box(s)));
            }
        }
        let mut plan = Plan {
            index,
            base: bi,
            actions: Vec::new(),
            placed: Vec::new(),
            deleted,
            gave_up: Vec::new(),
            draws: 0,
            rejected: 0,
            rejections: Default::default(),
            rng: Rng::new(0),
        };
        for n in &moving {
            let shape = shape_of(n).expect("moving objects have shapes");
            match self.draw(base, &mut rng, &mut plan, Posed::of(n), shape, &obstacles) {
                Ok((posed, yaw, s, support, b)) => {
                    obstacles.push((n.id, b));
                    plan.placed.push(Placed {
                        id: n.id,
                        library: None,
                        yaw_deg: yaw,
                        scale: s,
                        centre: posed.pose.translation,
                        support,
                    });
                }
                Err(reasons) => {
                    let b = Posed::of(n).occupied_box(shape);
                    let taken = obstacles
                        .iter()
                        .any(|(_, o)| place::boxes_overlap(&b, o, gap));
                    let outcome = if taken {
                        plan.deleted.push(n.id);
                        "deleted (its place was taken)"
                    } else {
                        obstacles.push((n.id, b));
                        "stays"
                    };
                    plan.gave_up.push(GaveUp {
                        what: format!("move {} {:?}", n.id, n.label),
                        tries: p.tries,
                        reasons,
                        outcome: outcome.into(),
                    });
                }
            }
        }
        let mut next_id = scene.nodes.iter().map(|n| n.id).max().unwrap_or(0) + 1;
        for (k, &count) in counts.iter().enumerate() {
            let lib = &base.library[k];
            for _ in 0..count {
                let Some(shape) = &lib.shape else {
                    plan.gave_up.push(GaveUp {
                        what: format!("add library[{k}] {:?}", lib.label),
                        tries: 0,
                        reasons: vec![("its field has no occupied cell".into(), 1)],
                        outcome: "not added".into(),
                    });
                    continue;
                };
                match self.draw(
                    base,
                    &mut rng,
                    &mut plan,
                    Posed::of(&lib.node),
                    shape,
                    &obstacles,
                ) {
                    Ok((posed, yaw, s, support, b)) => {
                        obstacles.push((next_id, b));
                        plan.placed.push(Placed {
                            id: next_id,
                            library: Some(k),
                            yaw_deg: yaw,
                            scale: s,
                            centre: posed.pose.translation,
                            support,
                        });
                        next_id += 1;
                    }
                    Err(reasons) => plan.gave_up.push(GaveUp {
                        what: format!("add library[{k}] {:?}", lib.label),
                        tries: p.tries,
                        reasons,
                        outcome: "not added".into(),
                    }),
                }
            }
        }
        plan.actions = plan_actions(&mut plan, base);
        plan.rng = rng;
        Ok(plan)
    }

    /// One object: up to `tries` draws of yaw, scale and a seen support cell of `base`,
    /// clear of `obstacles`.
    fn draw(
        &self,
        base: &Base,
        rng: &mut Rng,
        plan: &mut Plan,
        start: Posed,
        shape: &Shape,
        obstacles: &[(u16, assist_core::Obb)],
    ) -> Drawn {
        let p = &self.spec.placement;
        let scene = base.session.description();
        let up = scene.up.normalize();
        let mpu = scene.meters_per_unit;
        let gap = p.gap_m / mpu;
        let mut why: std::collections::BTreeMap<Reject, u32> = Default::default();
        for _ in 0..p.tries {
            plan.draws += 1;
            let yaw = rng.range(p.yaw_deg[0], p.yaw_deg[1]);
            let s = rng.range(p.scale[0], p.scale[1]);
            let sup = &base.support;
            let cell = sup.allowed[rng.below(sup.allowed.len() as u64) as usize];
            let c = sup.cell_center(cell)
                + assist_core::DVec2::new(rng.f64() - 0.5, rng.f64() - 0.5) * sup.cell;
            let mut cand = start;
            cand.pose.rotation = place::yawed(start.pose.rotation, up, yaw);
            cand.pose.scale = start.pose.scale * s;
            let h = sup.frame.height(start.pose.translation);
            cand.pose.translation = sup.frame.point(c, h);
            let r =
                place::rest(&cand, shape, sup, p.flatness_m / mpu).and_then(|(posed, support)| {
                    let b = posed.occupied_box(shape);
                    if obstacles
                        .iter()
                        .any(|(_, o)| place::boxes_overlap(&b, o, gap))
                    {
                        Err(Reject::Overlap)
                    } else {
                        Ok((posed, support, b))
                    }
                });
            match r {
                Ok((posed, support, b)) => return Ok((posed, yaw, s, support, b)),
                Err(e) => {
                    plan.rejected += 1;
                    *why.entry(e).or_default() += 1;
                    *plan.rejections.entry(e).or_default() += 1;
                }
            }
        }
        Err(why
            .into_iter()
            .map(|(r, k)| (r.name().to_string(), k))
            .collect())
    }

    /// The sample's scene: a fork of its base with the plan's actions applied.
    pub(crate) fn apply(&self, plan: &Plan) -> Result<Session> {
        let mut s = self.bases[plan.base].session.fork();
        s.apply(&plan.actions).map_err(|e| GenError::Sample {
            index: plan.index,
            message: format!("applying its actions: {e}"),
        })?;
        Ok(s)
    }
}

/// The rearrangement as actions, lengths in metres: deletions (sorted), then per placed
/// object its import, turn, scale and move.
fn plan_actions(plan: &mut Plan, base: &Base) -> Vec<Action> {
    let scene = base.session.description();
    // Lengths are written in metres, as a reader of actions.jsonl expects; the sample
    // applies these very actions, so a replay stays bit for bit.
    let mpu = scene.meters_per_unit;
    let mut actions = Vec::new();
    plan.deleted.sort();
    for &id in &plan.deleted {
        actions.push(action(id, Operation::Delete, ActionConfig::default()));
    }
    for pl in &plan.placed {
        if let Some(k) = pl.library {
            let lib = &base.library[k];
            actions.push(action(
                pl.id,
                Operation::Add,
                ActionConfig {
                    scene: Some(lib.scene.clone()),
                    node: Some(NodeRef::Id(lib.id)),
                    position: Some((pl.centre * mpu).to_array()),
                    unit: Some("m".into()),
                    ..Default::default()
                },
            ));
        }
        actions.push(action(
            pl.id,
            Operation::Rotate,
            ActionConfig {
                axis: Some(AxisSpec::Name("up".into())),
                degrees: Some(pl.yaw_deg),
                ..Default::default()
            },
        ));
        if pl.scale != 1.0 {
            actions.push(action(
                pl.id,
                Operation::Scale,
                ActionConfig {
                    factor: Some(pl.scale),
                    ..Default::default()
                },
            ));
        }
        if pl.library.is_none() {
            let now = scene
                .node(pl.id)
                .expect("own node")
                .world_from_local
                .translation;
            actions.push(action(
                pl.id,
                Operation::Translate,
                ActionConfig {
                    vector: Some(((pl.centre - now) * mpu).to_array()),
                    unit: Some("m".into()),
                    ..Default::default()
                },
            ));
        }
    }
    actions
}
