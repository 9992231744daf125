//! `SplitJob`: new object nodes cut out of a scene trained without masks (issue 41).
//! The objects come from boxes or clicks ([`Targets`]); a masks folder is derived for
//! every image of the scene's dataset (the scene's existing objects kept); each new node's
//! field starts from what the background holds in its box ([`assist_train::distil`]);
//! then the scene is fine-tuned with those masks — the background learns what lay behind
//! the objects from the multi-view prior, as in a training run with masks. The split is
//! one step of the scene's history: undo brings back the scene before it, weights and
//! all (every field the fine-tune changes gets a new key; the old ones stay for undo).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use assist_core::{Obb, SceneNode};
use assist_data::{LoadOptions, Split};
use assist_train::{ClearReport, DistilOptions, DistilReport, KeptHistory};

use super::targets::Objects;
use super::{MaskProgress, MasksWritten, SplitBox};
use crate::{NeuralScene, Result, Session, SessionError, TrainConfig, TrainEvent, TrainJob};
use crate::{TrainOutcome, request};

/// What a split is asked for: clap derives `assist scene split`'s flags from it.
#[derive(Debug, Clone, clap::Args)]
pub struct SplitConfig {
    /// The scene (trained without masks: `assist train DATA --no-objects`, or one with
    /// some objects already).
    pub scene: PathBuf,
    /// The scene written, with the new objects.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub objects: Objects,
    /// The dataset (default: the one the scene was trained on, as it records).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Fine-tune steps [default: 2000, or no limit when --max-time is given].
    #[arg(long, value_name = "N")]
    pub iters: Option<usize>,
    /// Stop the fine-tune after this many seconds.
    #[arg(long, value_name = "SECONDS")]
    pub max_time: Option<f64>,
    /// The fine-tune's learning rate at its first step, decaying to --lr-end (default:
    /// those the scene was trained with; measured in BENCHMARKS.md).
    #[arg(long, value_name = "LR", requires = "lr_end")]
    pub lr_start: Option<f32>,
    /// The fine-tune's learning rate at its last step.
    #[arg(long, value_name = "LR", requires = "lr_start")]
    pub lr_end: Option<f32>,
    /// Make the nodes without the fine-tune (continue with `assist train DATA --out OUT
    /// --resume --masks MASKS`); needs --masks-out.
    #[arg(long)]
    pub no_train: bool,
    /// Keep the derived masks in this folder (as `assist dataset masks` writes them).
    #[arg(long, value_name = "DIR")]
    pub masks_out: Option<PathBuf>,
    /// Replace --out (and --masks-out) if assist wrote them.
    #[arg(long)]
    pub force: bool,
}

impl SplitConfig {
    /// A split of `scene` into `out` with every other setting at its default.
    pub fn new(scene: PathBuf, out: PathBuf, objects: Objects) -> Self {
        SplitConfig {
            scene,
            out,
            objects,
            data: None,
            iters: None,
            max_time: None,
            lr_start: None,
            lr_end: None,
            no_train: false,
            masks_out: None,
            force: false,
        }
    }
}

/// Fine-tune steps of a split by default.
pub const SPLIT_ITERS: usize = 2000;

/// What a split tells as it goes.
#[derive(Debug)]
pub enum SplitEvent {
    /// A click's object found: its box.
    Clicked {
        click: String,
        obb: Obb,
    },
    Masks(MaskProgress),
    MasksDone(MasksWritten),
    /// A new node's field started from the background's.
    Distilled {
        id: u16,
        label: String,
        report: DistilReport,
    },
    /// The background emptied inside the new objects (above their supports).
    Cleared(ClearReport),
    Train(TrainEvent),
    Saved {
        path: PathBuf,
    },
}

/// What a split made.
#[derive(Debug)]
pub struct SplitOutcome {
    pub objects: Vec<SplitBox>,
    pub masks: MasksWritten,
    /// The fine-tune (`None` with `no_train`).
    pub trained: Option<TrainOutcome>,
    pub out: PathBuf,
}

pub struct SplitJob {
    pub config: SplitConfig,
    cancel: Arc<AtomicBool>,
}

impl SplitJob {
    pub fn new(config: SplitConfig) -> Self {
        SplitJob {
            config,
            cancel: Arc::new(AtomicBool::new(false)),
        }
    }

    /// A handle that stops the split when set: before the fine-tune no scene is written
    /// (the run ends with [`SessionError::Cancelled`]; `masks_out` stays only once its
    /// masks are complete); during it, the scene fine-tuned so far is saved, as a
    /// training run does.
    pub fn cancel_handle(&self) -> Arc<AtomicBool> {
        self.cancel.clone()
    }

    /// The job stopped by `flag` instead of its own handle (a front end's stop flag,
    /// shared with what it watches).
    pub fn with_cancel(mut self, flag: Arc<AtomicBool>) -> Self {
        self.cancel = flag;
        self
    }

    fn check_cancelled(&self) -> Result<()> {
        if self.cancel.load(Ordering::SeqCst) {
            return Err(SessionError::Cancelled);
        }
        Ok(())
    }

    /// Checks the outputs before any work: `out` (a scene) and `masks_out` are replaced
    /// only with `force` and only when assist wrote them, never an input.
    fn check_outputs(&self, data: &Path) -> Result<()> {
        let c = &self.config;
        assist_fs::check_replaceable_as(&c.out, c.force, assist_fs::Kind::Scene)
            .map_err(SessionError::Output)?;
        assist_fs::check_not_input(&c.out, &[c.scene.as_path(), data])
            .map_err(SessionError::Output)?;
        if let Some(m) = &c.masks_out {
            assist_fs::check_replaceable(m, c.force).map_err(SessionError::Output)?;
            assist_fs::check_not_input(m, &[c.scene.as_path(), data, c.out.as_path()])
                .map_err(SessionError::Output)?;
        }
        if c.no_train && c.masks_out.is_none() {
            return Err(request(
                "no_train",
                "the fine-tune left for later (`assist train DATA --out OUT --resume --masks DIR`) needs the masks: give a folder to keep them in (masks_out)".into(),
            ));
        }
        Ok(())
    }

    /// Splits the scene saved at `config.scene`.
    pub fn run(&self, on: impl FnMut(SplitEvent)) -> Result<SplitOutcome> {
        let session = Session::open(&self.config.scene)?;
        self.run_on(&session, on)
    }

    /// Splits `session`'s scene as it is now (with its history; a viewer's, edits and
    /// all); `config.scene` is where it was read from.
    pub fn run_on(
        &self,
        session: &Session,
        mut on: impl FnMut(SplitEvent),
    ) -> Result<SplitOutcome> {
        let c = &self.config;
        let info = session.info().clone();
        let data = match &c.data {
            Some(d) => d.clone(),
            None => info
                .get("dataset")
                .and_then(|d| d.as_str())
                .map(PathBuf::from)
                .ok_or_else(|| {
                    request(
                        "data",
                        format!(
                            "{} does not record the dataset it was trained on: give the dataset",
                            c.scene.join("scene.json").display()
                        ),
                    )
                })?,
        };
        self.check_outputs(&data)?;
        // A SAM checkpoint is read before any work: a wrong file fails at once.
        let sam = c
            .objects
            .sam
            .as_deref()
            .map(super::sam::SamRefine::load)
            .transpose()?;
        let _lock = assist_fs::lock(&c.out, &format!("assist scene split {}", c.scene.display()))
            .map_err(SessionError::Output)?;
        let ds = assist_data::load(&data, &LoadOptions::default()).map_err(SessionError::Data)?;
        let up = session.description().up;
        let targets = c.objects.targets(up)?;
        let first = session.description().fresh_id();
        let objects = targets.resolve(
            session,
            &ds,
            first,
            c.objects.render_downscale,
            |click, obb| {
                on(SplitEvent::Clicked {
                    click: click.to_string(),
                    obb: *obb,
                })
            },
        )?;
        self.check_cancelled()?;
        // The masks: kept in `masks_out`, or in a temporary folder beside `out`.
        let (masks_dir, staging) = match &c.masks_out {
            Some(m) => {
                let st = assist_fs::Staging::begin(m, "scene split masks")
                    .map_err(SessionError::Output)?;
                (st.dir().to_path_buf(), Some(st))
            }
            None => (temp_beside(&c.out)?, None),
        };
        let _cleanup = staging.is_none().then(|| RemoveOnDrop(masks_dir.clone()));
        let masks = session.write_masks(
            &ds,
            &objects,
            &masks_dir,
            c.objects.render_downscale,
            true,
            sam.as_ref(),
            |p| on(SplitEvent::Masks(p)),
        )?;
        on(SplitEvent::MasksDone(masks.clone()));
        self.check_cancelled()?;
        let masks_dir = match staging {
            Some(st) => {
                st.commit().map_err(SessionError::Output)?;
                c.masks_out.clone().unwrap_or(masks_dir)
            }
            None => masks_dir,
        };
        let (scene, kept) =
            self.split_scene(session, &ds, &objects, &masks.support_bases, &mut on)?;
        let mut record: TrainConfig = info
            .get("train_config")
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .unwrap_or_default();
        record.data = data.clone();
        record.out = c.out.clone();
        record.masks = Some(masks_dir.clone());
        record.no_objects = false;
        record.boxes = None;
        record.resume = false;
        record.force = c.force;
        record.iters = Some(crate::train_config::step_limit(
            c.iters,
            c.max_time,
            SPLIT_ITERS,
        ));
        record.max_time = c.max_time;
        if let Some((start, end)) = c.lr_start.zip(c.lr_end) {
            (record.lr_start, record.lr_end) = (start, Some(end));
        }
        record.eval_every = None;
        let trained = if c.no_train {
            let mut info = info.clone();
            info["iteration"] = 0.into();
            info["elapsed_seconds"] = 0.0.into();
            info["train_config"] = record.record();
            kept.save(&c.out, &scene, info)?;
            None
        } else {
            self.check_cancelled()?;
            let mut job = TrainJob::new(record).starting_from(scene, kept);
            job.cancel = self.cancel.clone();
            if c.masks_out.is_none() {
                // The temporary masks are gone after the run: not recorded as its masks.
                job.masks_recorded = false;
            }
            Some(job.run(|e| on(SplitEvent::Train(e.clone())))?)
        };
        on(SplitEvent::Saved {
            path: c.out.clone(),
        });
        Ok(SplitOutcome {
            objects,
            masks,
            trained,
            out: c.out.clone(),
        })
    }

    /// The scene with the new nodes (fields distilled from the background's) and every
    /// existing field under a new key, and the history that undoes the split.
    fn split_scene(
        &self,
        session: &Session,
        ds: &assist_data::Dataset,
        objects: &[SplitBox],
        support_bases: &[f64],
        on: &mut impl FnMut(SplitEvent),
    ) -> Result<(NeuralScene, KeptHistory)> {
        let before = session.scene();
        let bg = before
            .scene
            .nodes
            .iter()
            .position(|n| n.is_background())
            .ok_or_else(|| request("scene", "the scene has no background node to split".into()))?;
        let mut taken = session.history().field_keys();
        taken.extend(before.fields.keys().cloned());
        // `stem` itself when free (a new object), else `stem-splitK`.
        let mut fresh = |stem: &str, new: bool| {
            let base = stem.split("-split").next().unwrap_or(stem).to_string();
            let key = (new && !taken.contains(&base))
                .then(|| base.clone())
                .or_else(|| {
                    (1..)
                        .map(|k| format!("{base}-split{k}"))
                        .find(|k| !taken.contains(k))
                })
                .unwrap_or_default();
            taken.insert(key.clone());
            key
        };
        let mut scene = before.clone();
        // Every field the fine-tune changes gets a new key; the old ones stay for undo.
        let renames: std::collections::BTreeMap<String, String> = before
            .scene
            .nodes
            .iter()
            .map(|n| n.field.clone())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .map(|k| {
                let new = fresh(&k, false);
                (k, new)
            })
            .collect();
        for n in &mut scene.scene.nodes {
            n.field = renames[&n.field].clone();
        }
        scene.fields = renames
            .iter()
            .map(|(old, new)| (new.clone(), before.fields[old].clone()))
            .collect();
        let bg_field = &before.fields[&before.scene.nodes[bg].field].field;
        let opts = assist_train::SetupOptions {
            appearance: bg_field.config.appearance_dim > 0,
            ..Default::default()
        };
        let eyes: Vec<_> = ds
            .frames
            .iter()
            .filter(|f| f.split == Split::Train)
            .map(|f| f.camera.pose.center())
            .collect();
        // An object is what its box holds above its support's layer.
        let up = session.description().up;
        let owns =
            |b: &Obb, base: f64, p| super::support::height_in(b, up, p).is_some_and(|h| h > base);
        for (b, &base) in objects.iter().zip(support_bases) {
            let key = fresh(&format!("object-{}", b.id), true);
            let node = SceneNode::from_obb(b.id, &b.label, &key, &b.obb);
            // No masks yet: the object default table.
            let table = assist_train::object_table_log2(&[], b.id);
            let mut nf =
                assist_train::object_field(&opts, bg_field.config.num_images, &node, table)?;
            // The support stays the background's alone (copied, it would show twice).
            let owned = |p| owns(&b.obb, base, p);
            let report = assist_train::distil(
                before,
                bg,
                &node,
                &mut nf,
                owned,
                &eyes,
                &DistilOptions {
                    seed: b.id as u64,
                    ..Default::default()
                },
            );
            on(SplitEvent::Distilled {
                id: b.id,
                label: b.label.clone(),
                report,
            });
            self.check_cancelled()?;
            scene.fields.insert(key, Arc::new(nf));
            scene.scene.nodes.push(node);
        }
        // The objects' fields took over what the background held in their boxes above
        // their supports' layers; left there too, it would stay behind as a ghost (the
        // whole object) once they move.
        let boxes: Vec<Obb> = objects.iter().map(|b| b.obb).collect();
        let owned = |p| {
            boxes
                .iter()
                .zip(support_bases)
                .any(|(b, &base)| owns(b, base, p))
        };
        let report = assist_train::clear(
            &mut scene,
            bg,
            &boxes,
            owned,
            &eyes,
            &DistilOptions::clearing(),
        );
        on(SplitEvent::Cleared(report));
        self.check_cancelled()?;
        scene.scene.selected = None;
        scene.scene.register_classes();
        let mut history = session.history().clone();
        let labels: Vec<&str> = objects.iter().map(|b| b.label.as_str()).collect();
        history.record(
            before.scene.clone(),
            Some(format!("split: {}", labels.join(", "))),
            Vec::new(),
        );
        let mut kept = KeptHistory {
            history,
            fields: before.fields.clone(),
        };
        kept.fields.retain(|k, _| !scene.fields.contains_key(k));
        Ok((scene, kept))
    }
}

/// A new folder beside `out` for the split's temporary masks.
fn temp_beside(out: &Path) -> Result<PathBuf> {
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = out.file_name().unwrap_or_default().to_string_lossy();
    let dir = parent.join(format!(".{name}.split-masks-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)
        .map_err(|e| request("out", format!("cannot create {}: {e}", dir.display())))?;
    Ok(dir)
}

/// Removes a temporary folder when dropped.
struct RemoveOnDrop(PathBuf);

impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
