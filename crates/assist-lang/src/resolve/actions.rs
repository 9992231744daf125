//! The actions of each command: one function per kind of operation (import, swap, the
//! operations on objects of this scene), then each action validated against the scene as
//! the previous ones left it and applied to it.

use super::*;

/// Resolves raw commands against `scene`; every action is validated in order.
/// `taken_fields` are field keys an imported node must not take (see
/// [`Action::validate`]).
pub fn resolve(
    cmds: &[RawCommand],
    scene: &Scene,
    opts: &ParseOptions,
    sources: &mut dyn SceneSource,
    taken_fields: &BTreeSet<String>,
) -> Result<Resolved, LangError> {
    let mut taken = taken_fields.clone();
    let mut st = State {
        scene: scene.clone(),
        last: opts.last.into_iter().collect(),
        created: None,
    };
    let mut out = Resolved::default();
    for cmd in cmds {
        let mut named: Vec<InstanceId> = Vec::new();
        let quantified = cmd.targets.iter().any(|r| matches!(r, ObjectRef::All(_)));
        if matches!(cmd.op, Operation::Add | Operation::Swap)
            && (quantified || !cmd.excluded.is_empty())
        {
            return Err(clause_err(
                cmd,
                "objects",
                format!("{} takes named objects, not 'all' or 'except'", cmd.op),
            ));
        }
        let actions = match cmd.op {
            Operation::Add => add_actions(cmd, sources, opts)?,
            Operation::Swap => vec![swap_action(cmd, &st, sources, opts, &mut named)?],
            op if cmd.params.relation.is_some() => {
                let ids = st.targets(cmd, opts.embedder)?;
                let [id] = ids.as_slice() else {
                    return Err(clause_err(
                        cmd,
                        "objects",
                        format!(
                            "place one object at a time relative to another ({} named)",
                            ids.len()
                        ),
                    ));
                };
                named = vec![*id];
                vec![Action::new(*id, op, relations::place(*id, cmd, &st, opts)?)]
            }
            op => {
                let ids = st.targets(cmd, opts.embedder)?;
                if !cmd.partners.is_empty() {
                    return Err(clause_err(
                        cmd,
                        "with",
                        format!("{op} takes no second object"),
                    ));
                }
                named = ids.clone();
                let mut actions = Vec::new();
                for id in ids {
                    actions.extend(object_actions(op, id, cmd, &st, opts)?);
                }
                actions
            }
        };
        let created = install(cmd, actions, &mut st, sources, &mut taken, &mut out)?;
        if let Some(c) = created {
            st.created = Some(c);
            st.last = vec![c];
        } else if !named.is_empty() {
            st.last = named
                .into_iter()
                .filter(|id| st.scene.node(*id).is_some())
                .collect();
        }
    }
    Ok(out)
}

/// The scene at `path` that a clause imports from (its error names the clause).
fn source_scene(
    cmd: &RawCommand,
    sources: &mut dyn SceneSource,
    path: &str,
) -> Result<Scene, LangError> {
    sources
        .load_scene(path)
        .map_err(|message| LangError::Action {
            clause: cmd.text.clone(),
            source: assist_core::ActionError::Source {
                path: path.to_string(),
                message,
            },
        })
}

/// "add the mic from ../other.assist [at x, y, z]": one action per object named there.
fn add_actions(
    cmd: &RawCommand,
    sources: &mut dyn SceneSource,
    opts: &ParseOptions,
) -> Result<Vec<Action>, LangError> {
    let p = &cmd.params;
    let path = p.path.clone().ok_or_else(|| {
        clause_err(
            cmd,
            "scene",
            "add what from where? e.g. 'add the mic from ../other.assist'",
        )
    })?;
    let src = source_scene(cmd, sources, &path)?;
    let which = match cmd.targets.as_slice() {
        [ObjectRef::Phrase(w)] => phrase_in(w, &src, opts.embedder)?,
        [ObjectRef::Id(i)] => vec![*i],
        _ => {
            return Err(clause_err(
                cmd,
                "object",
                "name one object of the other scene to add",
            ));
        }
    };
    let mut actions = Vec::new();
    for src_id in which {
        let mut c = ActionConfig {
            scene: Some(path.clone()),
            node: Some(NodeRef::Id(src_id)),
            ..Default::default()
        };
        if let Some((pos, u)) = p.position {
            c.position = Some(pos);
            c.unit = Some(unit_name(u, cmd)?);
        }
        actions.push(Action::new(0, Operation::Add, c));
    }
    Ok(actions)
}

/// "swap the mug with the duck [from ../other.assist]": the objects of this scene it names
/// are added to `named`.
fn swap_action(
    cmd: &RawCommand,
    st: &State,
    sources: &mut dyn SceneSource,
    opts: &ParseOptions,
    named: &mut Vec<InstanceId>,
) -> Result<Action, LangError> {
    let p = &cmd.params;
    let mut refs: Vec<&ObjectRef> = cmd.targets.iter().chain(&cmd.partners).collect();
    if refs.len() != 2 {
        return Err(clause_err(
            cmd,
            "objects",
            format!("swap needs two objects, got {}", refs.len()),
        ));
    }
    let b_ref = refs.pop().expect("two");
    let a = one(st, refs[0], cmd, opts)?;
    let c = if let Some(path) = &p.path {
        let src = source_scene(cmd, sources, path)?;
        let b = match b_ref {
            ObjectRef::Phrase(w) => single(phrase_in(w, &src, opts.embedder)?, w, &src)?,
            ObjectRef::Id(i) => *i,
            _ => {
                return Err(clause_err(cmd, "object", "name the other scene's object"));
            }
        };
        ActionConfig {
            with: Some(NodeRef::Id(b)),
            scene: Some(path.clone()),
            new_id: Some(st.scene.fresh_id()),
            ..Default::default()
        }
    } else {
        let b = one(st, b_ref, cmd, opts)?;
        named.push(b);
        ActionConfig {
            with: Some(NodeRef::Id(b)),
            ..Default::default()
        }
    };
    named.insert(0, a);
    Ok(Action::new(a, Operation::Swap, c))
}

/// The actions of an operation on object `id` of this scene.
fn object_actions(
    op: Operation,
    id: InstanceId,
    cmd: &RawCommand,
    st: &State,
    opts: &ParseOptions,
) -> Result<Vec<Action>, LangError> {
    let p = &cmd.params;
    let c = match op {
        Operation::Select | Operation::Delete => ActionConfig::default(),
        Operation::Translate => match p.position {
            Some((pos, u)) => {
                let m = unit_metres(u);
                let node = st.scene.node(id).expect("resolved");
                let target = DVec3::from_array(pos) * m / st.scene.meters_per_unit;
                // Written in metres, as every other length of a resolved instruction.
                let v = (target - node.world_from_local.translation) * st.scene.meters_per_unit;
                ActionConfig {
                    vector: Some(v.to_array()),
                    unit: Some("m".into()),
                    ..Default::default()
                }
            }
            None => offset(cmd, st, opts)?.ok_or_else(|| {
                clause_err(
                    cmd,
                    "distance",
                    "how far and which way? e.g. '10 cm along x' or '5 cm left'",
                )
            })?,
        },
        Operation::Rotate => ActionConfig {
            angle: Some(angle(cmd)?),
            unit: Some("deg".into()),
            axis: p.axis.clone().map(assist_core::AxisSpec::Name),
            frame: p.frame_object.then(|| "object".into()),
            ..Default::default()
        },
        Operation::Scale => {
            let center = match st.scene.node(id) {
                Some(n) if !opts.scale_about_center && !n.is_background() => {
                    Some(resting_point(n, st.scene.up).to_array())
                }
                _ => None,
            };
            ActionConfig {
                factor: Some(factor(cmd)?),
                axis: p.axis.clone().map(assist_core::AxisSpec::Name),
                frame: p.frame_object.then(|| "object".into()),
                center,
                ..Default::default()
            }
        }
        Operation::Replicate => return replicate_actions(id, cmd, st, opts),
        Operation::Add | Operation::Swap => unreachable!("resolved by their own functions"),
    };
    Ok(vec![Action::new(id, op, c)])
}

/// "duplicate the mug [and move the copy 10 cm left]", "make 3 copies of the mug".
fn replicate_actions(
    id: InstanceId,
    cmd: &RawCommand,
    st: &State,
    opts: &ParseOptions,
) -> Result<Vec<Action>, LangError> {
    let p = &cmd.params;
    let op = Operation::Replicate;
    // "make 3 copies of the mug", "duplicate the duck 3 times", "twice": a bare count.
    let bare_count = matches!(p.quantities.as_slice(), [(_, None | Some(Unit::Times))])
        && p.direction.is_none()
        && p.axis.is_none();
    let placed = if bare_count {
        None
    } else {
        offset(cmd, st, opts)?
    };
    let count = match (&placed, p.quantities.as_slice()) {
        (None, [(n, None | Some(Unit::Times))]) if n.fract() == 0.0 && *n >= 1.0 && *n <= 100.0 => {
            *n as usize
        }
        (None, [(n, _)]) => {
            return Err(clause_err(
                cmd,
                "count",
                format!("expected a number of copies from 1 to 100, got {n}"),
            ));
        }
        _ => 1,
    };
    let mut actions = Vec::with_capacity(count);
    for _ in 0..count {
        let mut c = placed.clone().unwrap_or_default();
        c.axis = None;
        if let Some(cfg) = &placed
            && cfg.axis.is_some()
        {
            let dir =
                assist_core::action::axis_direction(cfg.axis.as_ref().expect("axis"), st.scene.up)
                    .map_err(|m| clause_err(cmd, "axis", m))?;
            c.vector = Some((dir * cfg.distance.unwrap_or(0.0)).to_array());
            c.distance = None;
            c.frame = None;
        }
        actions.push(Action::new(id, op, c));
    }
    Ok(actions)
}

/// Validates each action against the scene as it stands and applies it, recording the
/// action, its edit and the scene after it in `out`; returns the node the last creating
/// action made.
fn install(
    cmd: &RawCommand,
    actions: Vec<Action>,
    st: &mut State,
    sources: &mut dyn SceneSource,
    taken: &mut BTreeSet<String>,
    out: &mut Resolved,
) -> Result<Option<InstanceId>, LangError> {
    let mut created = None;
    for mut a in actions {
        match a.operation {
            Operation::Replicate => a.config.new_id = Some(st.scene.fresh_id()),
            Operation::Add => a.instance_id = st.scene.fresh_id(),
            _ => {}
        }
        let edit = a
            .validate(&st.scene, sources, taken)
            .map_err(|source| LangError::Action {
                clause: cmd.text.clone(),
                source,
            })?;
        assist_core::edit::apply(&mut st.scene, &edit).map_err(|source| LangError::Action {
            clause: cmd.text.clone(),
            source,
        })?;
        if let Some(c) = edit.created() {
            created = Some(c);
        }
        if let assist_core::Edit::Add { imported } | assist_core::Edit::SwapIn { imported, .. } =
            &edit
        {
            taken.insert(imported.node.field.clone());
        }
        out.actions.push(a);
        out.edits.push(edit);
        out.scenes.push(st.scene.clone());
    }
    Ok(created)
}
