//! Finding the node a phrase names: label words with plurals, synonyms and colours, an
//! explicit rule for words no label knows, and (when available) embedding similarity.

use assist_core::{InstanceId, Scene};

/// Computes a text embedding comparable to the nodes' `embedding` (e.g. a CLIP text
/// encoder run by the caller). None: no embedding for this text.
pub trait TextEmbedder {
    fn embed(&self, text: &str) -> Option<Vec<f32>>;
}

/// By meaning, the best node must be at least this much more similar (cosine) to the
/// phrase than the runner-up. At CLIP's temperature (logit scale 100) that is a
/// zero-shot probability e² ≈ 7.4 times the runner-up's.
pub const MEANING_MARGIN: f32 = 0.02;

/// Groups of interchangeable nouns; the first word is the canonical one.
const SYNONYMS: &[&[&str]] = &[
    &["mug", "cup", "tumbler"],
    &["duck", "duckie", "ducky", "duckling", "rubber-duck"],
    &["cow", "calf", "bull"],
    &["teapot", "kettle", "pot"],
    &["brick", "block", "duplo"],
    &["box", "cube", "crate", "cuboid"],
    &["ball", "sphere", "orb"],
    &["cylinder", "tube", "can", "drum"],
    &["cone", "pyramid"],
    &["chair", "seat", "stool"],
    &["table", "desk"],
    &["sofa", "couch"],
    &["mic", "microphone"],
    &["lamp", "light"],
    &["monitor", "screen", "display"],
    &["phone", "cellphone", "smartphone"],
    &["laptop", "computer", "notebook"],
    &["bottle", "flask"],
    &["plant", "flower", "pot-plant"],
    &["figurine", "figure", "statue", "statuette", "toy"],
    &["robot", "bot"],
    &["background", "room", "backdrop", "walls"],
    &["grey", "gray"],
    &["striped", "stripy", "stripes"],
    &["checkered", "checked", "chequered", "checkerboard"],
    &["dotted", "spotted", "dots", "polka"],
];

pub const COLOURS: &[&str] = &[
    "red", "green", "blue", "yellow", "orange", "purple", "violet", "pink", "white", "black",
    "brown", "grey", "gray", "cyan", "magenta", "teal", "gold", "golden", "silver", "beige",
];

/// Singular form (a plain rule: -ies → -y, -ches/-shes/-xes/-sses → drop -es, else -s).
pub fn singular(w: &str) -> String {
    if w.len() > 4 && w.ends_with("ies") {
        return format!("{}y", &w[..w.len() - 3]);
    }
    for suf in ["ches", "shes", "xes", "sses"] {
        if w.ends_with(suf) {
            return w[..w.len() - 2].to_string();
        }
    }
    if w.len() > 3 && w.ends_with('s') && !w.ends_with("ss") && !w.ends_with("us") {
        return w[..w.len() - 1].to_string();
    }
    w.to_string()
}

/// The canonical word: singular, then the first of its synonym group.
pub fn canonical(w: &str) -> String {
    let s = singular(w);
    for g in SYNONYMS {
        if g.contains(&w) || g.contains(&s.as_str()) {
            return g[0].to_string();
        }
    }
    s
}

fn label_words(label: &str) -> Vec<String> {
    label
        .to_lowercase()
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(String::from)
        .collect()
}

/// How a phrase matched.
pub enum Found {
    One(InstanceId),
    /// A plural phrase naming several nodes.
    Many(Vec<InstanceId>),
}

/// Why a phrase names no single node.
pub enum NotFound {
    /// No label matches, and meaning did not help (why).
    Unknown(NoMeaning),
    Ambiguous(Vec<InstanceId>),
    /// By meaning, the best nodes are too close to call: each with its similarity, best
    /// first.
    TooClose(Vec<(InstanceId, f32)>),
}

/// Why a phrase could not be matched by meaning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoMeaning {
    /// Nothing could: e.g. an empty phrase.
    Nothing,
    /// No text encoder is configured.
    NoEncoder,
    /// The scene's nodes have no embeddings.
    NoEmbeddings,
    /// The encoder gave nothing for the phrase.
    NotEncoded,
}

impl NoMeaning {
    /// What to provide, for messages.
    pub fn hint(self) -> &'static str {
        match self {
            NoMeaning::Nothing => "",
            NoMeaning::NoEncoder => {
                "; to find objects by what they are, give CLIP weights (ASSIST_CLIP=DIR or --clip DIR) to a scene embedded with `assist embed`"
            }
            NoMeaning::NoEmbeddings => {
                "; to find objects by what they are, embed the scene first: `assist embed SCENE --data CAPTURE` with CLIP weights"
            }
            NoMeaning::NotEncoded => "; the text encoder could not embed the phrase",
        }
    }
}

/// Finds the node(s) `words` name in `scene`; `said` is the object as described, for
/// comparing meanings when the words do not decide.
pub fn find(
    words: &[String],
    said: &str,
    scene: &Scene,
    embedder: Option<&dyn TextEmbedder>,
) -> Result<Found, NotFound> {
    let labels: Vec<(InstanceId, Vec<String>)> = scene
        .nodes
        .iter()
        .map(|n| (n.id, label_words(&n.label)))
        .collect();
    let exact = |w: &str, lw: &[String]| lw.iter().any(|l| l == w || singular(l) == singular(w));
    let syn = |w: &str, lw: &[String]| {
        let c = canonical(w);
        lw.iter().any(|l| canonical(l) == c)
    };
    let known = |w: &str| labels.iter().any(|(_, lw)| syn(w, lw));
    let Some(head) = words.last() else {
        return Err(NotFound::Unknown(NoMeaning::Nothing));
    };
    let plural = singular(head) != *head;
    // Words no label knows are dropped (sizes, materials), except colours and the head noun:
    // "the big mug" is the mug, but "the red chair" is not the red mug.
    let kept: Vec<&String> = words
        .iter()
        .filter(|w| known(w) || COLOURS.contains(&w.as_str()) || *w == head)
        .collect();
    let mut cands: Vec<(InstanceId, usize)> = labels
        .iter()
        .filter(|(_, lw)| kept.iter().all(|w| syn(w, lw)))
        .map(|(id, lw)| (*id, kept.iter().filter(|w| exact(w, lw)).count()))
        .collect();
    if cands.is_empty() {
        return by_meaning(said, scene, embedder, None);
    }
    if cands.len() > 1 && !plural {
        let best = cands.iter().map(|c| c.1).max().unwrap_or(0);
        cands.retain(|c| c.1 == best);
        // Several nodes fit the words: meaning may still tell them apart ("the mug you
        // drink tea from"); if it cannot, they stay ambiguous.
        if cands.len() > 1 {
            let ids: Vec<InstanceId> = cands.iter().map(|c| c.0).collect();
            if let Ok(found) = by_meaning(said, scene, embedder, Some(&ids)) {
                return Ok(found);
            }
        }
    }
    match cands.as_slice() {
        [(id, _)] => Ok(Found::One(*id)),
        many if plural => Ok(Found::Many(many.iter().map(|c| c.0).collect())),
        many => Err(NotFound::Ambiguous(many.iter().map(|c| c.0).collect())),
    }
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() || a.is_empty() {
        return -1.0;
    }
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na: f32 = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb: f32 = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    dot / (na * nb).max(1e-12)
}

/// The node whose embedding is most similar to the phrase's (among `among`, else all
/// nodes with one), when it beats the runner-up by [`MEANING_MARGIN`]; a node alone
/// must reach the margin itself.
fn by_meaning(
    said: &str,
    scene: &Scene,
    embedder: Option<&dyn TextEmbedder>,
    among: Option<&[InstanceId]>,
) -> Result<Found, NotFound> {
    let embedder = embedder.ok_or(NotFound::Unknown(NoMeaning::NoEncoder))?;
    let nodes: Vec<&assist_core::SceneNode> = scene
        .nodes
        .iter()
        .filter(|n| n.embedding.is_some() && among.is_none_or(|a| a.contains(&n.id)))
        .collect();
    if nodes.is_empty() {
        return Err(NotFound::Unknown(NoMeaning::NoEmbeddings));
    }
    let q = embedder
        .embed(said)
        .ok_or(NotFound::Unknown(NoMeaning::NotEncoded))?;
    let mut sims: Vec<(InstanceId, f32)> = nodes
        .iter()
        .filter_map(|n| n.embedding.as_ref().map(|e| (n.id, cosine(&q, e))))
        .collect();
    sims.sort_by(|a, b| b.1.total_cmp(&a.1));
    let best = sims[0];
    let second = sims.get(1).map_or(0.0, |s| s.1);
    if best.1 - second >= MEANING_MARGIN {
        return Ok(Found::One(best.0));
    }
    sims.retain(|s| best.1 - s.1 < MEANING_MARGIN);
    Err(NotFound::TooClose(sims))
}
