//! Finding the node a phrase names: label words with plurals, synonyms and colours, an
//! explicit rule for words no label knows, and (when available) embedding similarity.

use assist_core::{InstanceId, Scene};

/// Computes a text embedding comparable to the nodes' `embedding` (e.g. a CLIP text
/// encoder run by the caller). None: no embedding for this text.
pub trait TextEmbedder {
    fn embed(&self, text: &str) -> Option<Vec<f32>>;
}

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
    Unknown,
    Ambiguous(Vec<InstanceId>),
}

/// Finds the node(s) `words` name in `scene`.
pub fn find(
    words: &[String],
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
        return Err(NotFound::Unknown);
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
        return by_embedding(words, scene, embedder).ok_or(NotFound::Unknown);
    }
    if cands.len() > 1 && !plural {
        let best = cands.iter().map(|c| c.1).max().unwrap_or(0);
        cands.retain(|c| c.1 == best);
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

/// The node whose embedding is most similar to the phrase's, when it is clearly the best
/// (similarity ≥ 0.25 and 0.05 above the runner-up).
fn by_embedding(
    words: &[String],
    scene: &Scene,
    embedder: Option<&dyn TextEmbedder>,
) -> Option<Found> {
    let q = embedder?.embed(&words.join(" "))?;
    let mut sims: Vec<(f32, InstanceId)> = scene
        .nodes
        .iter()
        .filter_map(|n| n.embedding.as_ref().map(|e| (cosine(&q, e), n.id)))
        .collect();
    sims.sort_by(|a, b| b.0.total_cmp(&a.0));
    match sims.as_slice() {
        [(s, id)] if *s >= 0.25 => Some(Found::One(*id)),
        [(s, id), (s2, _), ..] if *s >= 0.25 && s - s2 >= 0.05 => Some(Found::One(*id)),
        _ => None,
    }
}
