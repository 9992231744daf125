//! Tokenising an instruction: lower-case words, numbers (with units split off, number words
//! read), paths kept verbatim, and clause separators.

#[derive(Debug, Clone, PartialEq)]
pub enum Tok {
    Word(String),
    Num(f64),
    /// A path (contains `/` or ends in `.assist`), as typed.
    Path(String),
    /// `,` `;` `.` `!` `?` — ends a clause.
    Sep,
}

/// ("one" stays a word: "the new one"; the grammar reads "one degree" as a number.)
const NUMBER_WORDS: [(&str, f64); 21] = [
    ("zero", 0.0),
    ("two", 2.0),
    ("three", 3.0),
    ("four", 4.0),
    ("five", 5.0),
    ("six", 6.0),
    ("seven", 7.0),
    ("eight", 8.0),
    ("nine", 9.0),
    ("ten", 10.0),
    ("eleven", 11.0),
    ("twelve", 12.0),
    ("fifteen", 15.0),
    ("twenty", 20.0),
    ("thirty", 30.0),
    ("forty", 40.0),
    ("forty-five", 45.0),
    ("fifty", 50.0),
    ("sixty", 60.0),
    ("ninety", 90.0),
    ("hundred", 100.0),
];

/// A path without the sentence punctuation around it.
fn path_core(t: &str) -> &str {
    let mut core = t.trim_start_matches(['(', '"', '\'']);
    while let Some((idx, last)) = core.char_indices().last() {
        let before = core[..idx].chars().last();
        let strip = matches!(last, ',' | ';' | '!' | '?' | ')' | '"' | '\'')
            || (last == '.' && before.is_some_and(|b| b != '.' && b != '/'));
        if !strip {
            break;
        }
        core = &core[..idx];
    }
    core
}

fn is_path(t: &str) -> bool {
    let core = path_core(t);
    core.contains('/') || core.to_ascii_lowercase().ends_with(".assist")
}

fn parse_number(s: &str) -> Option<f64> {
    if s.is_empty() {
        return None;
    }
    let lower = s.to_ascii_lowercase();
    if matches!(lower.as_str(), "nan" | "inf" | "infinity" | "-inf" | "+inf") {
        return lower.parse().ok();
    }
    let first = s.chars().next()?;
    if !(first.is_ascii_digit() || first == '-' || first == '+' || first == '.') {
        return None;
    }
    s.parse().ok()
}

/// Splits a number with a unit glued to it (`10cm`, `90°`, `50%`, `2x`, `1.5m`).
fn split_glued(w: &str) -> Option<(f64, &str)> {
    let end = w
        .char_indices()
        .find(|&(i, c)| !(c.is_ascii_digit() || c == '.' || ((c == '-' || c == '+') && i == 0)))
        .map(|(i, _)| i)?;
    if end == 0 {
        return None;
    }
    let n: f64 = w[..end].parse().ok()?;
    let unit = &w[end..];
    let unit = match unit {
        "°" | "deg" | "degs" => "degrees",
        "%" => "percent",
        "x" | "×" => "times",
        u => u,
    };
    Some((n, unit))
}

/// Whether a whitespace-separated token starts a number (`0.2`, `-0.2`, `+.5`, `80cm`).
fn starts_number(raw: &str) -> bool {
    let t = raw.trim_start_matches(['-', '+']);
    let t = t.strip_prefix('.').unwrap_or(t);
    t.starts_with(|c: char| c.is_ascii_digit())
}

pub fn tokenize(text: &str) -> Vec<Tok> {
    let mut out = Vec::new();
    let raws: Vec<&str> = text.split_whitespace().collect();
    for (r, raw) in raws.iter().copied().enumerate() {
        // A number's trailing comma before another number separates coordinates
        // ("at 0.1, -0.2, 0.8"), not clauses.
        let list_comma = raws.get(r + 1).is_some_and(|n| starts_number(n));
        if is_path(raw) {
            let core = path_core(raw);
            out.push(Tok::Path(core.to_string()));
            let tail = &raw[raw.find(core).map_or(raw.len(), |i| i + core.len())..];
            if tail.contains([',', ';', '.', '!', '?']) {
                out.push(Tok::Sep);
            }
            continue;
        }
        let lower = raw.to_lowercase();
        // Separate punctuation; keep '.' inside numbers and '-' inside words / as a sign.
        let mut piece = String::new();
        let chars: Vec<char> = lower.chars().collect();
        let mut pieces: Vec<Option<String>> = Vec::new(); // None = separator
        let mut skip = false;
        for (i, &c) in chars.iter().enumerate() {
            if std::mem::take(&mut skip) {
                continue;
            }
            // A negation is kept as a word of its own: "don't" → "do not", "can't" → "can
            // not", "won't" → "will not" (the grammar refuses it, naming "not").
            if c == '\'' && chars.get(i + 1) == Some(&'t') && piece.ends_with('n') {
                let base = match piece.as_str() {
                    "can" => "can".to_string(),
                    "won" => "will".to_string(),
                    p => p[..p.len() - 1].to_string(),
                };
                piece.clear();
                if !base.is_empty() {
                    pieces.push(Some(base));
                }
                pieces.push(Some("not".into()));
                skip = true;
                continue;
            }
            let next_digit = chars.get(i + 1).is_some_and(|d| d.is_ascii_digit());
            let prev_digit = i > 0 && chars[i - 1].is_ascii_digit();
            match c {
                ',' if prev_digit && next_digit => piece.push('.'),
                ',' if prev_digit && i + 1 == chars.len() && list_comma => {
                    pieces.push(Some(std::mem::take(&mut piece)));
                }
                '.' if next_digit && (prev_digit || piece.is_empty() || piece == "-") => {
                    piece.push('.')
                }
                ',' | ';' | '.' | '!' | '?' | ':' => {
                    if !piece.is_empty() {
                        pieces.push(Some(std::mem::take(&mut piece)));
                    }
                    pieces.push(None);
                }
                '(' | ')' | '[' | ']' | '"' | '\'' | '`' | '{' | '}' | '#' => {
                    if c == '\'' && i > 0 && chars.get(i + 1) == Some(&'s') {
                        // possessive: "the duck's" → "the duck"
                        if !piece.is_empty() {
                            pieces.push(Some(std::mem::take(&mut piece)));
                        }
                        continue;
                    }
                    if !piece.is_empty() {
                        pieces.push(Some(std::mem::take(&mut piece)));
                    }
                }
                _ => piece.push(c),
            }
        }
        if !piece.is_empty() {
            pieces.push(Some(piece));
        }
        for p in pieces {
            match p {
                None => {
                    if out.last() != Some(&Tok::Sep) {
                        out.push(Tok::Sep)
                    }
                }
                Some(w) => push_word(&mut out, &w),
            }
        }
    }
    // A lone "s" left by a possessive is dropped.
    out.retain(|t| t != &Tok::Word("s".into()));
    out
}

fn push_word(out: &mut Vec<Tok>, w: &str) {
    if let Some(axis) = w.strip_prefix('-').or_else(|| w.strip_prefix('+'))
        && matches!(axis, "x" | "y" | "z")
    {
        out.push(Tok::Word(w.to_string()));
        return;
    }
    if let Some(n) = parse_number(w) {
        out.push(Tok::Num(n));
        return;
    }
    let w = w.trim_matches('-');
    if w.is_empty() {
        return;
    }
    if let Some(n) = parse_number(w) {
        out.push(Tok::Num(n));
        return;
    }
    if let Some((_, n)) = NUMBER_WORDS.iter().find(|(k, _)| *k == w) {
        out.push(Tok::Num(*n));
        return;
    }
    if let Some((n, unit)) = split_glued(w) {
        out.push(Tok::Num(n));
        push_word(out, unit);
        return;
    }
    let joined = match w {
        "counter-clockwise" | "anti-clockwise" | "counterclockwise" | "anticlockwise" | "ccw" => {
            Some("counterclockwise")
        }
        "clockwise" | "cw" => Some("clockwise"),
        "°" | "º" => Some("degrees"),
        "%" => Some("percent"),
        "×" => Some("times"),
        _ => None,
    };
    if let Some(j) = joined {
        out.push(Tok::Word(j.into()));
        return;
    }
    // "x-axis" → "x" "axis"; "-x" stays; "duplo-style" → "duplo" "style".
    if w.contains('-') {
        for part in w.split('-').filter(|p| !p.is_empty()) {
            push_word(out, part);
        }
        return;
    }
    out.push(Tok::Word(w.to_string()));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(t: &str) -> Vec<Tok> {
        tokenize(t)
    }

    #[test]
    fn numbers_units_and_paths() {
        use Tok::*;
        assert_eq!(
            words("Move the duck 10cm, then rotate it 90° (see ../other.assist)."),
            vec![
                Word("move".into()),
                Word("the".into()),
                Word("duck".into()),
                Num(10.0),
                Word("cm".into()),
                Sep,
                Word("then".into()),
                Word("rotate".into()),
                Word("it".into()),
                Num(90.0),
                Word("degrees".into()),
                Word("see".into()),
                Path("../other.assist".into()),
                Sep,
            ]
        );
        assert_eq!(
            words("-0.5 x-axis"),
            vec![Num(-0.5), Word("x".into()), Word("axis".into())]
        );
        assert_eq!(
            words("along -x"),
            vec![Word("along".into()), Word("-x".into())]
        );
        assert_eq!(
            words("2x 50%"),
            vec![
                Num(2.0),
                Word("times".into()),
                Num(50.0),
                Word("percent".into())
            ]
        );
        assert!(matches!(words("NaN")[0], Num(n) if n.is_nan()));
    }
}
