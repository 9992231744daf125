//! The worker's handlers of the messages that edit, open, save or look: one method each,
//! returning what changed or why the message was refused.

use super::*;

impl Worker {
    pub(super) fn open(
        &mut self,
        name: &str,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let path = self.others.resolve(name)?;
        let other = Session::describe(&path).map_err(Refused::from)?;
        send(Outgoing::Json(ServerMsg::Other {
            scene: name.to_string(),
            nodes: other.nodes.iter().map(node_state).collect(),
        }));
        Ok(Changed::NOTHING)
    }

    pub(super) fn add_from(
        &mut self,
        name: &str,
        node: InstanceId,
        x: f64,
        y: f64,
    ) -> Result<Changed, Refused> {
        let path = self.others.resolve(name)?;
        let cam = self.camera()?;
        let at = self
            .session
            .surface(&cam, x, y)
            .map_err(Refused::from)?
            .ok_or("add: no surface under that pixel to put the node on")?;
        let other = Session::describe(&path).map_err(Refused::from)?;
        let n = other
            .nodes
            .iter()
            .find(|n| n.id == node)
            .ok_or_else(|| format!("scene {name:?} has no node {node}"))?;
        // The node rests on the surface: its centre half its height above the point.
        let up = self.session.description().up.normalize();
        let scale = self.session.description().meters_per_unit / other.meters_per_unit;
        let half = (n.half_size * n.world_from_local.scale).z / scale.max(1e-12);
        let centre = at + up * half;
        let config = ActionConfig {
            scene: Some(path.display().to_string()),
            node: Some(assist_core::NodeRef::Id(node)),
            position: Some(centre.to_array()),
            unit: Some("units".into()),
            ..ActionConfig::default()
        };
        let edits = self
            .session
            .apply_with(&[Action::new(0, Operation::Add, config)], Steps::One)
            .map_err(Refused::from)?;
        if let Some(assist_core::Edit::Add { imported }) = edits.first() {
            let id = imported.node.id;
            self.session.select(Some(id)).map_err(Refused::from)?;
            self.log.push(format!("added object {id} from {name}"));
        }
        Ok(Changed::ALL)
    }

    pub(super) fn swap_with(&mut self, name: &str, node: InstanceId) -> Result<Changed, Refused> {
        let path = self.others.resolve(name)?;
        let config = ActionConfig {
            scene: Some(path.display().to_string()),
            with: Some(assist_core::NodeRef::Id(node)),
            ..ActionConfig::default()
        };
        self.on_selected(Operation::Swap, config)
    }

    pub(super) fn camera(&self) -> Result<Camera, String> {
        self.view
            .as_ref()
            .ok_or_else(|| "no view yet: send a view message first".to_string())?
            .camera()
    }

    pub(super) fn click(&mut self, x: f64, y: f64) -> Result<Changed, Refused> {
        let cam = self.camera()?;
        let hidden: Vec<InstanceId> = self.hidden.iter().copied().collect();
        let id = if hidden.is_empty() {
            self.session.pick(&cam, x, y)
        } else {
            self.session.without(&hidden).pick(&cam, x, y)
        }
        .map_err(Refused::from)?;
        self.session.select(id).map_err(Refused::from)?;
        Ok(Changed::ALL)
    }

    pub(super) fn selected(&self) -> Result<InstanceId, String> {
        self.session
            .description()
            .selected
            .ok_or_else(|| "no object selected: click one first".to_string())
    }

    pub(super) fn on_selected(
        &mut self,
        op: Operation,
        config: ActionConfig,
    ) -> Result<Changed, Refused> {
        let id = self.selected()?;
        let action = Action::new(id, op, config);
        let before = self.session.description().clone();
        self.session
            .apply_with(&[action], Steps::One)
            .map_err(Refused::from)?;
        if op == Operation::Delete {
            self.session.select(None).map_err(Refused::from)?;
        }
        self.log.push(format!("{} object {id}", op_name(op)));
        self.note_placement(&before);
        Ok(Changed::ALL)
    }

    /// Objects the last edit left inside one another or floating, as warnings in the log
    /// (as `assist edit` warns).
    pub(super) fn note_placement(&mut self, before: &assist_core::Scene) {
        let after = self.session.description().clone();
        let (problems, _) = self.session.placement_problems(before, &after);
        for p in problems.iter().take(5) {
            self.log.push(format!("warning: {p}"));
        }
        if problems.len() > 5 {
            self.log
                .push(format!("warning: … and {} more", problems.len() - 5));
        }
    }

    /// A drag: each move undoes the previous preview and applies the new amount; commit
    /// keeps it as one undo step; cancel undoes it.
    pub(super) fn drag(
        &mut self,
        op: DragOp,
        axis: &str,
        amount: f64,
        (dx, dy): (f64, f64),
        phase: DragPhase,
    ) -> Result<Changed, Refused> {
        let id = self.selected()?;
        let applied = self.drag.as_ref().is_some_and(|d| d.applied);
        if applied {
            self.session.undo();
        }
        self.drag = None;
        if phase == DragPhase::Cancel {
            return Ok(Changed::ALL);
        }
        let config = self.drag_config(op, axis, amount, (dx, dy), id)?;
        let before = self.session.description().clone();
        let operation = match op {
            DragOp::Translate => Operation::Translate,
            DragOp::Rotate => Operation::Rotate,
            DragOp::Scale => Operation::Scale,
        };
        self.session
            .apply_with(&[Action::new(id, operation, config)], Steps::One)
            .map_err(Refused::from)?;
        if phase == DragPhase::Commit {
            self.log.push(format!("{} object {id}", op_name(operation)));
            self.note_placement(&before);
        } else {
            self.drag = Some(Drag { applied: true });
        }
        Ok(Changed {
            frame: true,
            state: phase == DragPhase::Commit,
        })
    }

    pub(super) fn drag_config(
        &self,
        op: DragOp,
        axis: &str,
        amount: f64,
        (dx, dy): (f64, f64),
        id: InstanceId,
    ) -> Result<ActionConfig, String> {
        let mut c = ActionConfig::default();
        if !(amount.is_finite() && dx.is_finite() && dy.is_finite()) {
            return Err("drag: expected finite amounts".into());
        }
        match (op, axis) {
            (DragOp::Translate, "view") => {
                // Pixels → world at the object's depth, in the image plane.
                let cam = self.camera()?;
                let node = self
                    .session
                    .node(id)
                    .ok_or_else(|| format!("no node {id}"))?;
                let centre = node.world_from_local.translation;
                let depth = (centre - cam.pose.center())
                    .dot(cam.pose.forward())
                    .max(1e-3);
                let m = cam.pose.to_matrix();
                let right = m.x_axis.truncate();
                let up = m.y_axis.truncate();
                let v: DVec3 = (right * dx - up * dy) * depth / cam.intrinsics.fx;
                c.vector = Some(v.to_array());
                c.unit = Some("units".into());
            }
            (_, "x" | "y" | "z" | "-x" | "-y" | "-z") => {
                c.axis = Some(AxisSpec::Name(axis.to_string()));
                match op {
                    DragOp::Translate => {
                        c.distance = Some(amount);
                        c.unit = Some("m".into());
                    }
                    DragOp::Rotate => c.degrees = Some(amount),
                    DragOp::Scale => c.factor = Some(amount),
                }
            }
            (DragOp::Scale, "all") => c.factor = Some(amount),
            _ => {
                return Err(format!(
                    "drag.axis: expected x, y, z, -x, -y, -z (or view for translate, all for scale), got {axis:?}"
                ));
            }
        }
        Ok(c)
    }

    pub(super) fn text(
        &mut self,
        text: &str,
        dry_run: bool,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let cam = self.camera().ok();
        let resolved = self
            .session
            .resolve(text, cam.as_ref())
            .map_err(Refused::from)?;
        let actions = resolved
            .actions
            .iter()
            .map(|a| serde_json::to_value(a).unwrap_or(serde_json::Value::Null))
            .collect();
        if !dry_run {
            let before = self.session.description().clone();
            self.session
                .install(resolved, Steps::One, Some(text.to_string()))
                .map_err(Refused::from)?;
            self.log.push(text.to_string());
            self.note_placement(&before);
        }
        send(Outgoing::Json(ServerMsg::Resolved {
            text: text.to_string(),
            actions,
            applied: !dry_run,
        }));
        Ok(Changed {
            frame: !dry_run,
            state: !dry_run,
        })
    }

    /// The stamp of the scene on disk when the session was read (see [`disk_stamp`]).
    pub fn with_disk_stamp(mut self, stamp: Option<u64>) -> Self {
        self.disk = stamp;
        self
    }

    /// A flag the socket sets when the client goes: a frame in progress stops.
    /// The dataset new objects are split with (else the one the scene records).
    pub fn with_data(mut self, data: Option<PathBuf>) -> Self {
        self.data = data;
        self
    }

    /// The flag the socket sets on `stop`: a split under way stops.
    pub fn with_stop_flag(mut self, stop: std::sync::Arc<std::sync::atomic::AtomicBool>) -> Self {
        self.stop = stop;
        self
    }

    pub fn with_gone_flag(mut self, gone: std::sync::Arc<std::sync::atomic::AtomicBool>) -> Self {
        self.gone = Some(gone);
        self
    }

    pub(super) fn save(
        &mut self,
        path: Option<&str>,
        force: bool,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let target = match path {
            None => self.scene_path.clone(),
            Some(p) => {
                let ok = !p.is_empty()
                    && !p.contains(['/', '\\'])
                    && !p.starts_with('.')
                    && p.chars().all(|c| !c.is_control());
                if !ok {
                    return Err(format!(
                        "save.path: expected a NAME (or NAME.assist) beside the scene (no folders), got {p:?}"
                    )
                    .into());
                }
                let name = if p.ends_with(".assist") {
                    p.to_string()
                } else {
                    format!("{p}.assist")
                };
                self.scene_path
                    .parent()
                    .unwrap_or(Path::new("."))
                    .join(name)
            }
        };
        // Saving over the opened scene is what "save" means; "save as" never replaces
        // anything, whatever the message asks (`force` is read only for the former).
        let over_own = target == self.scene_path;
        let _ = force;
        let force = over_own;
        if !over_own && std::fs::symlink_metadata(&target).is_ok() {
            return Err(format!(
                "save as: {} already exists; save as never replaces a scene (choose another name)",
                target.display()
            )
            .into());
        }
        // Held across the check and the write, so no other process saves in between.
        let _lock = assist_fs::lock(&target, "assist view").map_err(Refused::from)?;
        if over_own && disk_stamp(&target) != self.disk {
            return Err(format!(
                "save: {} was changed by another program since this viewer opened it; save under another name (save as) to keep both",
                target.display()
            ).into());
        }
        self.session.save(&target, force).map_err(Refused::from)?;
        if over_own {
            self.disk = disk_stamp(&target);
        }
        self.log.push(format!("saved {}", target.display()));
        send(Outgoing::Json(ServerMsg::Saved {
            path: target.display().to_string(),
        }));
        Ok(Changed::STATE)
    }

    /// Writes the current view through the dataset writer into `NAME-view-K/` beside the
    /// scene (the first K not taken).
    pub(super) fn save_view(
        &mut self,
        send: &impl Fn(Outgoing) -> bool,
    ) -> Result<Changed, Refused> {
        let cam = self.camera()?;
        let frame = self
            .session
            .render(&cam, &RenderRequest::default())
            .map_err(Refused::from)?;
        let parent = self.scene_path.parent().unwrap_or(Path::new("."));
        let stem = self
            .scene_path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        let dir = (1..10_000)
            .map(|k| parent.join(format!("{stem}-view-{k}")))
            .find(|d| !d.exists())
            .ok_or("save view: no free folder name")?;
        let cfg = self.session.writer_config(vec![
            WriterOutput::Rgb,
            WriterOutput::Depth,
            WriterOutput::Panoptic,
        ]);
        let w = DatasetWriter::create(&dir, cfg, false).map_err(Refused::from)?;
        let view = ViewImages {
            width: frame.width,
            height: frame.height,
            rgb: &frame.rgb,
            depth: &frame.depth,
            panoptic: &frame.panoptic,
            ..Default::default()
        };
        w.write(0, "view", &cam, &view).map_err(Refused::from)?;
        w.finish().map_err(Refused::from)?;
        self.log.push(format!("view saved in {}", dir.display()));
        send(Outgoing::Json(ServerMsg::Saved {
            path: dir.display().to_string(),
        }));
        Ok(Changed::STATE)
    }
}
