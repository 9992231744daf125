//! The shape of the code, checked so that it cannot drift: no source file over 600 lines
//! before its tests, no function over 150 lines outside tests (the house style in
//! ARCHITECTURE.md). A few files and functions were larger when the rule was written;
//! they are listed in `SHRINK_ONLY` with the size they had, and may only shrink.

use std::path::{Path, PathBuf};

const MAX_FILE: usize = 600;
const MAX_FN: usize = 150;

/// Files and functions larger than the rule when it was written: (path from the
/// workspace root, function name or "" for the file, the most lines it may have).
const SHRINK_ONLY: &[(&str, &str, usize)] = &[];

/// The source with comments, string and character literals blanked out (line breaks
/// kept), so that braces can be counted.
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    let keep_lines = |s: &[u8], out: &mut String| {
        for &c in s {
            if c == b'\n' {
                out.push('\n');
            }
        }
    };
    while i < b.len() {
        let rest = &b[i..];
        let ident_before = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if rest.starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if rest.starts_with(b"/*") {
            let end = find(b, i + 2, b"*/").map_or(b.len(), |j| j + 2);
            keep_lines(&b[i..end], &mut out);
            i = end;
        } else if !ident_before && (rest.starts_with(b"r#") || rest.starts_with(b"r\"")) {
            let hashes = rest[1..].iter().take_while(|c| **c == b'#').count();
            if rest.get(1 + hashes) != Some(&b'"') {
                out.push('r');
                i += 1;
                continue;
            }
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            let end = find(b, i + 2 + hashes, &close).map_or(b.len(), |j| j + close.len());
            out.push_str("\"\"");
            keep_lines(&b[i..end], &mut out);
            i = end;
        } else if b[i] == b'"' {
            let mut j = i + 1;
            while j < b.len() && b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            out.push_str("\"\"");
            keep_lines(&b[i..j.min(b.len())], &mut out);
            i = j + 1;
        } else if b[i] == b'\'' {
            // A character literal ('x', '\n', '\u{..}', '{'), not a lifetime ('a).
            let lit = if rest.get(1) == Some(&b'\\') {
                rest[2..].iter().position(|c| *c == b'\'').map(|p| p + 3)
            } else {
                let ch = src[i + 1..].chars().next().map_or(1, char::len_utf8);
                (rest.get(1 + ch) == Some(&b'\'')).then_some(2 + ch)
            };
            match lit {
                Some(n) => {
                    out.push_str("' '");
                    i += n;
                }
                None => {
                    out.push('\'');
                    i += 1;
                }
            }
        } else {
            let ch = src[i..].chars().next().expect("in bounds");
            out.push(ch);
            i += ch.len_utf8();
        }
    }
    out
}

fn find(b: &[u8], from: usize, pat: &[u8]) -> Option<usize> {
    (from..b.len().saturating_sub(pat.len() - 1)).find(|&j| b[j..].starts_with(pat))
}

/// The name of the function a line declares, if it does.
fn declared_fn(line: &str) -> Option<&str> {
    let mut words = line.split_whitespace().peekable();
    while let Some(w) = words.next() {
        match w {
            "fn" => {
                let name = words.next()?;
                let end = name
                    .find(|c: char| !(c.is_alphanumeric() || c == '_'))
                    .unwrap_or(name.len());
                return Some(&name[..end]);
            }
            "pub" | "async" | "unsafe" | "const" | "extern" | "\"\"" => {}
            w if w.starts_with("pub(") => {}
            _ => return None,
        }
    }
    None
}

struct Sizes {
    /// Lines before the file's `#[cfg(test)]`.
    file: usize,
    /// Each function outside tests: name, first line (1-based), lines.
    fns: Vec<(String, usize, usize)>,
}

fn measure(src: &str) -> Sizes {
    let code = code_only(src);
    let lines: Vec<&str> = code.lines().collect();
    let file = lines
        .iter()
        .position(|l| l.trim() == "#[cfg(test)]")
        .unwrap_or(lines.len());
    let mut fns = Vec::new();
    for (k, line) in lines[..file].iter().enumerate() {
        let Some(name) = declared_fn(line) else {
            continue;
        };
        let mut depth = 0i64;
        let mut opened = false;
        let mut end = None;
        'scan: for (j, l) in lines.iter().enumerate().skip(k) {
            for c in l.chars() {
                match c {
                    '{' => {
                        depth += 1;
                        opened = true;
                    }
                    '}' => depth -= 1,
                    ';' if !opened => break 'scan,
                    _ => {}
                }
                if opened && depth == 0 {
                    end = Some(j);
                    break 'scan;
                }
            }
        }
        if let Some(end) = end {
            fns.push((name.to_string(), k + 1, end - k + 1));
        }
    }
    Sizes { file, fns }
}

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        let name = e.file_name();
        let name = name.to_string_lossy();
        if p.is_dir() {
            if !matches!(
                name.as_ref(),
                "target" | "node_modules" | "tests" | "benches"
            ) {
                sources(&p, out);
            }
        } else if name.ends_with(".rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_file_or_function_grows_past_the_house_limits() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut files = Vec::new();
    sources(&root.join("crates"), &mut files);
    files.sort();
    assert!(files.len() > 50, "found only {} sources", files.len());
    let mut errors = Vec::new();
    // What each SHRINK_ONLY entry measures now.
    let mut listed = vec![None; SHRINK_ONLY.len()];
    for path in &files {
        let rel = path
            .strip_prefix(&root)
            .unwrap_or(path)
            .to_string_lossy()
            .replace('\\', "/");
        let src = std::fs::read_to_string(path).expect("readable source");
        let s = measure(&src);
        let mut allowed = |name: &str, size: usize, default: usize| match SHRINK_ONLY
            .iter()
            .position(|(f, n, _)| *f == rel && *n == name)
        {
            Some(i) => {
                listed[i] = Some((size, default));
                SHRINK_ONLY[i].2
            }
            None => default,
        };
        let max = allowed("", s.file, MAX_FILE);
        if s.file > max {
            errors.push(format!(
                "{rel}: {} lines before its tests (at most {max}): split it along its seams",
                s.file
            ));
        }
        for (name, line, n) in &s.fns {
            let max = allowed(name, *n, MAX_FN);
            if *n > max {
                errors.push(format!(
                    "{rel}:{line}: fn {name} has {n} lines (at most {max}): split it"
                ));
            }
        }
    }
    for (i, now) in listed.iter().enumerate() {
        if now.is_none_or(|(size, limit)| size <= limit) {
            let (f, n, _) = SHRINK_ONLY[i];
            errors.push(format!(
                "SHRINK_ONLY lists {f} {n:?}, which is gone or within the limit now: remove the entry"
            ));
        }
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

#[test]
fn the_measure_counts_what_it_should() {
    let src = "fn a() {\n    let s = \"}\";\n    let c = '{';\n    // }\n}\n\
               pub(crate) fn b<'a>(x: &'a str) -> &'a str {\n    /* { */ x\n}\n\
               fn c();\n#[cfg(test)]\nmod tests {\n    fn d() {}\n}\n";
    let s = measure(src);
    assert_eq!(s.file, 9);
    let got: Vec<(&str, usize, usize)> =
        s.fns.iter().map(|(n, l, c)| (n.as_str(), *l, *c)).collect();
    assert_eq!(got, vec![("a", 1, 5), ("b", 6, 3)]);
}

/// The internal dependencies a row of ARCHITECTURE.md's crate table names in its last
/// column (short names; text in parentheses is about other crates).
fn table_deps(root: &Path) -> Vec<(String, Vec<String>)> {
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let mut rows = Vec::new();
    for line in text.lines().filter(|l| l.starts_with("| `assist")) {
        let cells: Vec<&str> = line.trim_matches('|').split(" | ").collect();
        let name = cells[0].trim().trim_matches('`').to_string();
        let mut last = cells.last().expect("cells").to_string();
        while let (Some(a), Some(b)) = (last.find('('), last.rfind(')')) {
            if b < a {
                break;
            }
            last.replace_range(a..=b, "");
        }
        let mut deps: Vec<String> = last
            .split([',', ' '])
            .map(str::trim)
            .filter(|w| !w.is_empty() && *w != "—")
            .map(|w| format!("assist-{w}"))
            .collect();
        deps.sort();
        rows.push((name, deps));
    }
    rows
}

#[test]
fn the_architecture_table_matches_cargo_metadata() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(&root)
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let table = table_deps(&root);
    let mut errors = Vec::new();
    for pkg in meta["packages"].as_array().expect("packages") {
        let name = pkg["name"].as_str().expect("name");
        let mut deps: Vec<String> = pkg["dependencies"]
            .as_array()
            .expect("dependencies")
            .iter()
            .filter(|d| d["kind"].is_null() && d["path"].is_string())
            .map(|d| d["name"].as_str().expect("name").to_string())
            .collect();
        deps.sort();
        deps.dedup();
        match table.iter().find(|(n, _)| n == name) {
            None => errors.push(format!(
                "{name} has no row in ARCHITECTURE.md's crate table"
            )),
            Some((_, listed)) if *listed != deps => errors.push(format!(
                "{name}: ARCHITECTURE.md says it depends on {listed:?}, Cargo.toml on {deps:?}"
            )),
            Some(_) => {}
        }
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}
