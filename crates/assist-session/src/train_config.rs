//! `TrainConfig`: everything a training run is configured with, declared once. clap
//! derives the CLI's flags from it (`assist train` flattens it), serde its config files,
//! Python's keywords and the record in the trained scene; its `Default` is the parsed
//! empty command line, so a default lives in one attribute. The loss weights come from
//! the trainer's table of terms ([`assist_train::TERMS`]): one `--lambda-NAME` each.

use std::collections::BTreeMap;
use std::path::PathBuf;

use assist_train::{
    BackgroundSpace, GridResolution, Lambdas, LayoutChoice, PriorKind, TERMS, TrainOptions,
};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use serde::{Deserialize, Serialize};

/// Per-image appearance embeddings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Appearance {
    /// On for photographs (COLMAP, LLFF, `assist process`, nerfstudio captures), off for
    /// rendered images (Blender, a `transforms.json` naming its `renderer`).
    #[default]
    Auto,
    On,
    Off,
}

/// Whether and how objects learn their shadows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Shadows {
    /// `fixed` where every training view has depth (the estimate and the shadow-free
    /// region are placed by it), else `off`: without depth no shadow can be estimated, and
    /// a learned one takes in whatever stands near the object (measured in BENCHMARKS.md).
    #[default]
    Auto,
    /// Estimated from the photographs, then trained with the scene.
    On,
    /// None: shadows stay on the background.
    Off,
    /// Estimated from the photographs and kept where they show it; the rest (under the
    /// object) trains with the scene.
    Fixed,
}

impl Shadows {
    /// What `auto` means for a capture with (`depth`) or without depth maps.
    pub fn resolve(self, depth: bool) -> Shadows {
        match self {
            Shadows::Auto if depth => Shadows::Fixed,
            Shadows::Auto => Shadows::Off,
            other => other,
        }
    }
}

/// A feature switched on or off (also read from `true`/`false` in config files and
/// Python).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum OnOff {
    #[default]
    On,
    Off,
}

impl<'de> Deserialize<'de> for OnOff {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Bool(bool),
            Text(String),
        }
        match Raw::deserialize(d)? {
            Raw::Bool(true) => Ok(OnOff::On),
            Raw::Bool(false) => Ok(OnOff::Off),
            Raw::Text(t) => match t.as_str() {
                "on" => Ok(OnOff::On),
                "off" => Ok(OnOff::Off),
                other => Err(serde::de::Error::custom(format!(
                    "expected \"on\", \"off\", true or false, got {other:?}"
                ))),
            },
        }
    }
}

/// How often something happens during a run: every N iterations ("300"), or every S
/// seconds of training ("60s").
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Every {
    Steps(usize),
    Seconds(f64),
}

impl std::str::FromStr for Every {
    type Err = String;
    fn from_str(s: &str) -> Result<Every, String> {
        let t = s.trim();
        let bad = || format!("expected N iterations (300) or S seconds (60s), got {s:?}");
        if let Some(secs) = t.strip_suffix('s') {
            let v: f64 = secs.trim().parse().map_err(|_| bad())?;
            return if v.is_finite() && v > 0.0 {
                Ok(Every::Seconds(v))
            } else {
                Err(bad())
            };
        }
        match t.parse::<usize>() {
            Ok(n) if n > 0 => Ok(Every::Steps(n)),
            _ => Err(bad()),
        }
    }
}

impl std::fmt::Display for Every {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Every::Steps(n) => write!(f, "{n}"),
            Every::Seconds(s) => write!(f, "{s}s"),
        }
    }
}

impl Every {
    /// Whether it is due at this step; `last` is when it last happened (training
    /// seconds), updated when it is. A time schedule is due at the first step and then
    /// once its interval has passed.
    pub fn due(&self, iteration: usize, elapsed: f64, last: &mut Option<f64>) -> bool {
        let due = match self {
            Every::Steps(n) => iteration.is_multiple_of(*n),
            Every::Seconds(t) => last.is_none_or(|l| elapsed - l >= *t),
        };
        if due {
            *last = Some(elapsed);
        }
        due
    }
}

impl Serialize for Every {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Every::Steps(n) => s.serialize_u64(*n as u64),
            Every::Seconds(_) => s.serialize_str(&self.to_string()),
        }
    }
}

impl<'de> Deserialize<'de> for Every {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Steps(u64),
            Text(String),
        }
        let text = match Raw::deserialize(d)? {
            Raw::Steps(n) => n.to_string(),
            Raw::Text(t) => t,
        };
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// Fewest samples a training step may take.
pub const MIN_BATCH_SAMPLES: usize = 1 << 10;
/// Most samples a training step may take (2²⁴: about 2 GB of activations).
pub const MAX_BATCH_SAMPLES: usize = 1 << 24;
/// Held-out views measured during and after training.
pub const DEFAULT_EVAL_VIEWS: usize = 4;

const RUN: &str = "Run";
const SAMPLING: &str = "Data and sampling";
const PRIOR: &str = "Background prior";
const MODEL: &str = "Scene model";
const HELD_OUT: &str = "Held-out views";
const WEIGHTS: &str = "Loss weights";

fn prior_parser() -> impl TypedValueParser<Value = PriorKind> {
    PossibleValuesParser::new(["multi-view", "push-pull", "exemplar", "none"])
        .map(|s| PriorKind::parse(&s).expect("one of the possible values"))
}

fn grid_resolution_parser(s: &str) -> std::result::Result<GridResolution, String> {
    GridResolution::parse(s).ok_or_else(|| format!("expected a number of cells or auto, got {s:?}"))
}

fn layout_parser() -> impl TypedValueParser<Value = LayoutChoice> {
    PossibleValuesParser::new(["auto", "facing", "walk-around"])
        .map(|s| LayoutChoice::parse(&s).expect("one of the possible values"))
}

fn background_parser() -> impl TypedValueParser<Value = BackgroundSpace> {
    PossibleValuesParser::new(["auto", "box", "contracted"])
        .map(|s| BackgroundSpace::parse(&s).expect("one of the possible values"))
}

/// Everything a training run is configured with. `data` and `out` have no default; every
/// other field's default is the one `assist train` uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(default)]
pub struct TrainConfig {
    /// The dataset (any supported format).
    #[arg(skip)]
    pub data: PathBuf,
    /// The scene directory written (`NAME.assist`).
    #[arg(skip)]
    pub out: PathBuf,
    /// Iterations to train in all (a resumed run continues up to this count); --max-time
    /// may end the run first [default: 5000, or no limit when --max-time is given].
    #[arg(long, help_heading = RUN, value_name = "N")]
    pub iters: Option<usize>,
    /// Stop after this many seconds (the learning-rate schedule then runs on time). With
    /// --resume, this many seconds more than the scene was trained already.
    #[arg(long, help_heading = RUN, value_name = "SECONDS")]
    pub max_time: Option<f64>,
    /// Learning rate of the first step; it decays exponentially to --lr-end over the run
    /// (its iterations or its time).
    #[arg(long, help_heading = RUN, value_name = "LR", default_value_t = TrainOptions::default().lr_start)]
    pub lr_start: f32,
    /// Learning rate of the last step [default: 3e-3 where the background is unbounded
    /// (contracted: captures without depth), else 1e-3].
    #[arg(long, help_heading = RUN, value_name = "LR")]
    pub lr_end: Option<f32>,
    /// Seed of every random draw (ray batches, initial weights): the same seed, data and
    /// flags give the same scene, bit for bit, on a machine with as many cores.
    #[arg(long, help_heading = RUN, default_value_t = 0)]
    pub seed: u64,
    /// Seconds between checkpoints (written atomically to --out).
    #[arg(long, help_heading = RUN, value_name = "SECONDS", default_value_t = 120.0)]
    pub checkpoint_every: f64,
    /// Continue training the scene in --out (from its last checkpoint). Refused when the
    /// dataset differs from the one it was trained on, unless --force.
    #[arg(long, help_heading = RUN)]
    pub resume: bool,
    /// Replace --out if assist wrote it (a folder assist did not write is never replaced);
    /// with --resume, continue on a different dataset.
    #[arg(long, help_heading = RUN)]
    pub force: bool,
    /// Train on images N times smaller (from images_N/ folders beside the images where
    /// they exist, else reduced on loading); `eval` then defaults to the same.
    #[arg(long, help_heading = SAMPLING, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downscale: u32,
    /// Samples per training step (the ray count adapts).
    #[arg(long, help_heading = SAMPLING, value_name = "N",
          default_value_t = TrainOptions::default().batch_samples)]
    pub batch_samples: usize,
    /// Every node's marching steps times this while training (1: as rendered; 2: about
    /// half the samples per ray, so each step holds about twice the rays). Renders keep
    /// their own steps (`render --quality`).
    #[arg(long, help_heading = SAMPLING, value_name = "X",
          default_value_t = TrainOptions::default().step_scale)]
    pub step_scale: f32,
    /// Draw an unbounded background's samples (captures without depth) from a proposal
    /// field trained with it, N per ray, instead of at every step of its march (0: off).
    /// The proposal is saved with the scene, and renders draw from it too [default: 24
    /// where the background is unbounded (contracted: captures without depth) and the
    /// fields train on the CPU, else 0].
    #[arg(long, help_heading = SAMPLING, value_name = "N")]
    pub proposal: Option<usize>,
    /// Drop each node's samples behind the point where its transmittance falls below this,
    /// found by a density-only pass before the forward and backward passes (0 = keep all;
    /// a transmittance in [0, 1)). Nodes with fewer than 32 samples per ray are kept whole
    /// [default: 1e-4 where the background is unbounded (contracted: captures without
    /// depth) and the fields train on the CPU, else 0].
    #[arg(long, help_heading = SAMPLING, value_name = "T")]
    pub prune_eps: Option<f32>,
    /// The least share of each batch's rays on or next to objects, so that small objects
    /// get enough rays: rays are drawn from the objects' pixels only as far as a uniform
    /// draw over all pixels falls short of it (none where objects fill this share of the
    /// views, as in a walk-around).
    #[arg(long, help_heading = SAMPLING, value_name = "SHARE",
          default_value_t = TrainOptions::default().object_ray_fraction)]
    pub object_rays: f64,
    /// Object boxes overriding the dataset's and the carved ones, used as given (a JSON file
    /// as `assist dataset boxes DATA --json` writes: {"instances": [{"id" or "label", "bbox":
    /// {"center", "size", "rotation"}}]}).
    #[arg(long, help_heading = SAMPLING, value_name = "FILE")]
    pub boxes: Option<PathBuf>,
    /// Train the capture as nobody labelled it: one background node, the dataset's
    /// instance masks, `masks/` folder and object boxes ignored (objects are made later,
    /// from clicks or boxes; or to compare with a labelled run).
    #[arg(long, help_heading = SAMPLING)]
    pub no_objects: bool,
    /// Instance masks made elsewhere (e.g. by `assist dataset masks`), replacing the
    /// dataset's own: one per image named like it; an `instances.json` in the folder
    /// names the objects and gives their boxes.
    #[arg(long, help_heading = SAMPLING, value_name = "DIR")]
    pub masks: Option<PathBuf>,
    /// Background prior under the objects: multi-view (from the other views that see it,
    /// where the dataset has depth; push-pull elsewhere, except in an unbounded
    /// walk-around, whose other views see it themselves), push-pull, exemplar, or none
    /// (none also sets the background's prior weights to 0 unless --prior-dir gives files).
    #[arg(long, help_heading = PRIOR, default_value = "multi-view", value_parser = prior_parser())]
    pub prior: PriorKind,
    /// Background priors made elsewhere (the paper's inpainting path): a folder with, per
    /// training image, that view with its objects inpainted (NAME.png or .jpg, the image's
    /// size), and optionally depth/NAME.npy (float32, any scale) or depth/NAME.png. They
    /// replace the built-in fill; images without one keep it.
    #[arg(long, help_heading = PRIOR, value_name = "DIR")]
    pub prior_dir: Option<PathBuf>,
    /// Per-image appearance embeddings (auto: on for real captures, COLMAP and LLFF). A
    /// view from elsewhere takes the blend of the codes of the three training views taken
    /// nearest to its camera.
    #[arg(long, help_heading = MODEL, value_enum, default_value_t = Appearance::Auto)]
    pub appearance: Appearance,
    /// The background node's space: contracted (a box kept linearly, all space beyond it
    /// contracted into a shell, for unbounded real captures), box, or auto (contracted
    /// unless the training views have depth maps, which bound the scene).
    #[arg(long, help_heading = MODEL, default_value = "auto", value_parser = background_parser())]
    pub background: BackgroundSpace,
    /// How the cameras stand around what they look at: facing one way, all around it
    /// (walk-around: no azimuth gap of 180° or more around the point their axes meet), or
    /// auto (read from the training poses). A walk-around whose background is unbounded
    /// takes --grid-resolution auto, --grid-decay 1e-6 and --lambda-distortion 0.002
    /// unless they are given, with or without objects (measured in BENCHMARKS.md).
    #[arg(long, help_heading = MODEL, default_value = "auto", value_parser = layout_parser())]
    pub layout: LayoutChoice,
    /// The background's finest hash-grid resolution: cells across its field's cube (the
    /// box, or a contracted background's box and shell), or auto: about one cell per pixel
    /// of the training images at the median depth of what they see (2048 to 8192)
    /// [default: auto for an unbounded walk-around (--layout), else
    /// Nerfacto's 2048].
    #[arg(long, help_heading = MODEL, value_name = "CELLS|auto",
          value_parser = grid_resolution_parser)]
    pub grid_resolution: Option<GridResolution>,
    /// Objects' colour from the view direction mirrored about a surface normal their
    /// density net predicts (Ref-NeRF), held to their density's own normal by
    /// --lambda-normal: meant for shiny objects, whose reflections then follow one
    /// direction shared by the whole surface. Objects only; not on --device gpu.
    #[arg(long, help_heading = MODEL, value_enum, default_value_t = OnOff::Off)]
    pub reflect: OnOff,
    /// Pull every hash-table entry a step touches toward zero by this much (L2, added to its
    /// gradient; 0: off), so that what few views constrain does not keep what they put
    /// there [default: 1e-6 for an unbounded walk-around (--layout), else
    /// 0].
    #[arg(long, help_heading = MODEL, value_name = "L")]
    pub grid_decay: Option<f32>,
    /// Draw this share of the rays (those not drawn for objects) where the colour error
    /// is high, from a running map of each view's error per 16×16-pixel tile, each ray
    /// weighted so that every pixel still counts as much as under a uniform draw (0: all
    /// uniform; at most 0.9) [default: 0.5 where the background is unbounded (contracted:
    /// captures without depth), else 0]. Measured in BENCHMARKS.md.
    #[arg(long, help_heading = MODEL, value_name = "SHARE")]
    pub error_rays: Option<f64>,
    /// Refine the training views' camera poses with the scene: each view learns a small
    /// translation and rotation (held-out views keep their poses).
    #[arg(long, help_heading = MODEL)]
    pub refine_poses: bool,
    /// Learn each object's shadow on the background: the background then learns the
    /// surface without the objects, and a moved or deleted object takes its shadow along.
    /// Only scenes with objects are affected.
    #[arg(long, help_heading = MODEL, value_enum, default_value_t = Shadows::Auto)]
    pub shadows: Shadows,
    /// Start each object's shadow from the photographs (the darkening around it,
    /// photograph over the shadow-free prior) instead of no shadow.
    #[arg(long, help_heading = MODEL, value_enum, default_value_t = OnOff::On)]
    pub shadow_estimate: OnOff,
    /// What objects hide of the background learns only from the background's prior: its
    /// samples whose transmittance through the objects in front of them is below this get
    /// no gradient from the photographs (0 = off; a transmittance in [0, 1]).
    #[arg(long, help_heading = MODEL, value_name = "T",
          default_value_t = TrainOptions::default().hidden_stop)]
    pub hidden_stop: f32,
    /// Measure held-out views (the dataset's test split, else val) every N iterations
    /// ("300") or every S seconds ("60s"), and at the end: their PSNR and SSIM go to the
    /// log and the progress line, and the first view beside its render to
    /// NAME.preview.png beside --out. The time counts in the run's.
    #[arg(long, help_heading = HELD_OUT, value_name = "N|Ss")]
    pub eval_every: Option<Every>,
    /// Held-out views measured, evenly spread over the split, during the run and at its
    /// end (0 = none).
    #[arg(long, help_heading = HELD_OUT, value_name = "N", default_value_t = DEFAULT_EVAL_VIEWS)]
    pub eval_views: usize,
    #[command(flatten)]
    #[serde(flatten)]
    pub lambdas: LambdaOverrides,
    /// Testing aid: poison a parameter with NaN at this iteration.
    #[arg(long, hide = true)]
    #[serde(skip)]
    pub poison_at: Option<usize>,
}

impl Default for TrainConfig {
    /// The configuration of `assist train` given no flags.
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Empty {
            #[command(flatten)]
            config: TrainConfig,
        }
        <Empty as clap::Parser>::try_parse_from(["train"])
            .expect("every flag has a default or is optional")
            .config
    }
}

/// A run's step budget: `iters` when given, else none when the run is timed, else
/// `default` (`train` and `scene split` alike).
pub fn step_limit(iters: Option<usize>, max_time: Option<f64>, default: usize) -> usize {
    match (iters, max_time) {
        (Some(n), _) => n,
        (None, Some(_)) => usize::MAX,
        (None, None) => default,
    }
}

impl TrainConfig {
    /// The iteration budget: --iters, else none when the run is timed, else the default.
    pub fn iters_limit(&self) -> usize {
        step_limit(self.iters, self.max_time, TrainOptions::default().iters)
    }

    /// Whether objects learn shadows on a capture with (`depth`) or without depth maps.
    pub fn learns_shadows(&self, depth: bool) -> bool {
        self.shadows.resolve(depth) != Shadows::Off
    }

    /// What this configuration is recorded as in the scene it trains: every option but
    /// the paths and the run's switches (`force`, `resume`).
    pub fn record(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        if let Some(m) = v.as_object_mut() {
            for k in ["data", "out", "force", "resume"] {
                m.remove(k);
            }
        }
        v
    }
}

/// Loss weights the user sets, by term name; a term not set keeps the rule's value (see
/// [`lambdas`]). One flag `--lambda-NAME` and one key `lambda_NAME` per settable term of
/// [`assist_train::TERMS`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LambdaOverrides(BTreeMap<&'static str, f32>);

impl LambdaOverrides {
    /// The weight set for the term called `name`.
    pub fn get(&self, name: &str) -> Option<f32> {
        self.0.get(name).copied()
    }

    /// Sets the weight of the term called `name`; `Err` names the terms there are.
    pub fn set(&mut self, name: &str, weight: f32) -> Result<(), String> {
        match settable().find(|t| t.name == name) {
            Some(t) => {
                self.0.insert(t.name, weight);
                Ok(())
            }
            None => Err(format!(
                "no loss term called {name:?} (terms: {})",
                settable().map(|t| t.name).collect::<Vec<_>>().join(", ")
            )),
        }
    }

    /// The weights set, as (term name, weight).
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, f32)> + '_ {
        self.0.iter().map(|(k, v)| (*k, *v))
    }
}

fn settable() -> impl Iterator<Item = &'static assist_train::TermInfo> {
    TERMS.iter().filter(|t| t.settable)
}

/// The flag's id and key: `lambda_NAME`.
pub fn lambda_key(term: &str) -> String {
    format!("lambda_{term}")
}

impl clap::FromArgMatches for LambdaOverrides {
    fn from_arg_matches(m: &clap::ArgMatches) -> Result<Self, clap::Error> {
        let mut o = LambdaOverrides::default();
        o.update_from_arg_matches(m)?;
        Ok(o)
    }

    fn update_from_arg_matches(&mut self, m: &clap::ArgMatches) -> Result<(), clap::Error> {
        for t in settable() {
            if let Ok(Some(v)) = m.try_get_one::<f32>(&lambda_key(t.name)) {
                self.0.insert(t.name, *v);
            }
        }
        Ok(())
    }
}

impl clap::Args for LambdaOverrides {
    fn augment_args(mut cmd: clap::Command) -> clap::Command {
        for t in settable() {
            cmd = cmd.arg(
                clap::Arg::new(lambda_key(t.name))
                    .long(lambda_key(t.name).replace('_', "-"))
                    .value_name("W")
                    .value_parser(clap::value_parser!(f32))
                    .help_heading(WEIGHTS)
                    .help(format!(
                        "{} [default: {}]",
                        t.help.trim_end_matches('.'),
                        t.default
                    )),
            );
        }
        cmd
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

impl Serialize for LambdaOverrides {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(None)?;
        for t in settable() {
            m.serialize_entry(&lambda_key(t.name), &self.get(t.name))?;
        }
        m.end()
    }
}

impl<'de> Deserialize<'de> for LambdaOverrides {
    /// From `lambda_NAME` keys (null keeps the rule's value); any other key is refused,
    /// which, flattened into [`TrainConfig`], refuses the options it does not know.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let raw = BTreeMap::<String, Option<f32>>::deserialize(d)?;
        let mut o = LambdaOverrides::default();
        for (k, v) in raw {
            let term = k
                .strip_prefix("lambda_")
                .and_then(|n| settable().find(|t| t.name == n));
            let Some(term) = term else {
                return Err(serde::de::Error::custom(format!("unknown option {k:?}")));
            };
            if let Some(v) = v {
                o.0.insert(term.name, v);
            }
        }
        Ok(o)
    }
}

/// The loss weights of a run: the table's defaults, the background-prior terms off when
/// there is no prior at all, the distortion term on for an unbounded walk-around
/// (`walk_around`, [`assist_train::WalkAroundDefaults`]), then the user's values.
pub fn lambdas(c: &TrainConfig, dataset_inpaint: bool, walk_around: bool) -> Lambdas {
    let mut l = Lambdas::default();
    if walk_around {
        l.distortion = assist_train::WalkAroundDefaults::DISTORTION;
    }
    if c.prior == PriorKind::None && !dataset_inpaint {
        l.bg_rgb = 0.0;
        l.bg_depth = 0.0;
    }
    for (name, v) in c.lambdas.iter() {
        if let Some(slot) = l.get_mut(name) {
            *slot = v;
        }
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_through_serde_and_clap() {
        let d = TrainConfig::default();
        assert_eq!(d.iters, None);
        assert_eq!(d.iters_limit(), TrainOptions::default().iters);
        let timed = TrainConfig {
            max_time: Some(60.0),
            ..TrainConfig::default()
        };
        assert_eq!(timed.iters_limit(), usize::MAX);
        assert_eq!(d.shadows, Shadows::Auto);
        assert_eq!(d.shadows.resolve(true), Shadows::Fixed);
        assert_eq!(d.shadows.resolve(false), Shadows::Off);
        assert_eq!(d.prior, PriorKind::MultiView);
        let v = serde_json::to_value(&d).unwrap();
        assert!(v.get("lambda_obj_share").is_some(), "{v}");
        assert!(v.get("lambda_comp_rgb").is_none(), "{v}");
        let back: TrainConfig = serde_json::from_value(v).unwrap();
        assert_eq!(back, d);
        let e = serde_json::from_value::<TrainConfig>(serde_json::json!({"colour": 1}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("colour"), "{e}");
        let c: TrainConfig = serde_json::from_value(serde_json::json!({
            "lambda_obj_share": 0.3, "shadows": "on", "shadow_estimate": false
        }))
        .unwrap();
        assert_eq!(c.lambdas.get("obj_share"), Some(0.3));
        assert_eq!((c.shadows, c.shadow_estimate), (Shadows::On, OnOff::Off));
        assert_eq!(lambdas(&c, false, false).obj_share, 0.3);
    }

    /// The numbers `--layout`'s help and the flags' defaults name are the walk-around's.
    #[test]
    fn the_help_names_the_walk_around_defaults() {
        use assist_train::WalkAroundDefaults as W;
        use clap::Args;
        let cmd = TrainConfig::augment_args(clap::Command::new("train"));
        let help = |id: &str| {
            let a = cmd.get_arguments().find(|a| a.get_id() == id).unwrap();
            a.get_help().unwrap().to_string()
        };
        let layout = help("layout");
        for want in [
            format!("--grid-resolution {}", W::GRID_RESOLUTION),
            format!("--grid-decay {:e}", W::GRID_DECAY),
            format!("--lambda-distortion {}", W::DISTORTION),
        ] {
            assert!(layout.contains(&want), "{want:?} in {layout:?}");
        }
        let tail = "for an unbounded walk-around";
        for (id, want) in [
            (
                "grid_resolution",
                format!("default: {} {tail}", W::GRID_RESOLUTION),
            ),
            ("grid_decay", format!("default: {:e} {tail}", W::GRID_DECAY)),
            (
                "lambda_distortion",
                format!("{} (Nerfacto's) {tail}", W::DISTORTION),
            ),
        ] {
            let h = help(id);
            assert!(h.contains(&want), "{want:?} in {h:?}");
        }
        // And the choice resolves as named.
        assert_eq!(
            LayoutChoice::parse("walk-around"),
            Some(LayoutChoice::WalkAround)
        );
        assert_eq!(TrainConfig::default().layout, LayoutChoice::Auto);
        assert_eq!(
            (
                TrainConfig::default().grid_decay,
                TrainConfig::default().grid_resolution
            ),
            (None, None)
        );
    }
}
