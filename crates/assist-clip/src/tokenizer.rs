//! CLIP's byte-level BPE tokenizer, as OpenAI's and open_clip's `SimpleTokenizer`: text
//! cleaned (HTML entities, runs of white space) and lower-cased, split by CLIP's pattern,
//! each piece's UTF-8 bytes mapped to printable characters and merged by rank. The merges
//! come from open_clip's `bpe_simple_vocab_16e6.txt.gz` or Hugging Face's `merges.txt`;
//! the vocabulary is built from them as the reference does (bytes, bytes + `</w>`, merges,
//! then start and end of text).
//!
//! Not applied: ftfy's repair of mis-decoded text (mojibake), which the reference runs first.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use regex::Regex;

use crate::ClipError;

pub struct Tokenizer {
    encoder: HashMap<String, u32>,
    ranks: HashMap<(String, String), u32>,
    byte_char: [char; 256],
    pattern: Regex,
    pub sot: u32,
    pub eot: u32,
    pub context_length: usize,
}

/// GPT-2's reversible map from bytes to printable characters, in the reference's order
/// (printable bytes first, then the others): the first 256 entries of the vocabulary.
pub(crate) fn byte_chars() -> Vec<(u8, char)> {
    let mut printable: Vec<u32> = (u32::from('!')..=u32::from('~'))
        .chain(0xA1..=0xAC)
        .chain(0xAE..=0xFF)
        .collect();
    let mut chars = printable.clone();
    let mut n = 0;
    for b in 0..256u32 {
        if !printable.contains(&b) {
            printable.push(b);
            chars.push(256 + n);
            n += 1;
        }
    }
    printable
        .iter()
        .zip(&chars)
        .map(|(b, c)| (*b as u8, char::from_u32(*c).unwrap_or('\0')))
        .collect()
}

/// [`byte_chars`] indexed by byte.
fn bytes_to_unicode() -> [char; 256] {
    let mut out = ['\0'; 256];
    for (b, c) in byte_chars() {
        out[b as usize] = c;
    }
    out
}

fn unescape_html(s: &str) -> String {
    // The entities a caption is likely to hold; the reference runs Python's full
    // html.unescape twice.
    let mut t = s.to_string();
    for _ in 0..2 {
        t = t
            .replace("&quot;", "\"")
            .replace("&#39;", "'")
            .replace("&apos;", "'")
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&nbsp;", "\u{a0}")
            .replace("&amp;", "&");
    }
    t
}

impl Tokenizer {
    /// Reads the merges from `file` (`.gz` as open_clip ships it, or plain text as
    /// `merges.txt`), for a model with `vocab_size` tokens and `context_length` positions.
    pub fn from_file(
        file: &Path,
        vocab_size: usize,
        context_length: usize,
    ) -> Result<Tokenizer, ClipError> {
        let io = |e: std::io::Error| ClipError::Io {
            file: file.to_path_buf(),
            source: e,
        };
        let raw = std::fs::read(file).map_err(io)?;
        let text = if raw.starts_with(&[0x1f, 0x8b]) {
            let mut s = String::new();
            flate2::read::GzDecoder::new(&raw[..])
                .read_to_string(&mut s)
                .map_err(|e| ClipError::Vocab {
                    file: file.to_path_buf(),
                    message: format!("not a readable gzip of UTF-8 text: {e}"),
                })?;
            s
        } else {
            String::from_utf8(raw).map_err(|_| ClipError::Vocab {
                file: file.to_path_buf(),
                message: "not UTF-8 text".into(),
            })?
        };
        Self::from_merges(&text, vocab_size, context_length, file)
    }

    fn from_merges(
        text: &str,
        vocab_size: usize,
        context_length: usize,
        file: &Path,
    ) -> Result<Tokenizer, ClipError> {
        let needed = vocab_size
            .checked_sub(512 + 2)
            .ok_or_else(|| ClipError::Vocab {
                file: file.to_path_buf(),
                message: format!("the model has only {vocab_size} tokens (a CLIP BPE needs > 514)"),
            })?;
        // First line is a header ("#version: …").
        let merges: Vec<(String, String)> = text
            .split('\n')
            .skip(1)
            .take(needed)
            .filter_map(|l| {
                let mut it = l.split_whitespace();
                Some((it.next()?.to_string(), it.next()?.to_string()))
            })
            .collect();
        if merges.len() != needed {
            return Err(ClipError::Vocab {
                file: file.to_path_buf(),
                message: format!(
                    "{} merges, but the model's {vocab_size}-token embedding needs {needed}",
                    merges.len()
                ),
            });
        }
        let byte_char = bytes_to_unicode();
        let order = byte_chars();
        let mut vocab: Vec<String> = order.iter().map(|(_, c)| c.to_string()).collect();
        vocab.extend(order.iter().map(|(_, c)| format!("{c}</w>")));
        vocab.extend(merges.iter().map(|(a, b)| format!("{a}{b}")));
        vocab.push("<start_of_text>".into());
        vocab.push("<end_of_text>".into());
        let encoder: HashMap<String, u32> = vocab
            .into_iter()
            .enumerate()
            .map(|(i, v)| (v, i as u32))
            .collect();
        let ranks = merges
            .into_iter()
            .enumerate()
            .map(|(i, m)| (m, i as u32))
            .collect();
        let pattern = Regex::new(
            r"(?i)<start_of_text>|<end_of_text>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+",
        )
        .map_err(|e| ClipError::Vocab {
            file: PathBuf::from(file),
            message: e.to_string(),
        })?;
        Ok(Tokenizer {
            encoder,
            ranks,
            byte_char,
            pattern,
            sot: (vocab_size - 2) as u32,
            eot: (vocab_size - 1) as u32,
            context_length,
        })
    }

    fn bpe(&self, token: &str) -> Vec<String> {
        let chars: Vec<char> = token.chars().collect();
        let mut word: Vec<String> = chars.iter().map(|c| c.to_string()).collect();
        if let Some(last) = word.last_mut() {
            last.push_str("</w>");
        }
        while word.len() > 1 {
            let best = word
                .windows(2)
                .enumerate()
                .filter_map(|(i, w)| {
                    self.ranks
                        .get(&(w[0].clone(), w[1].clone()))
                        .map(|r| (*r, i))
                })
                .min();
            let Some((_, at)) = best else { break };
            // Merge every occurrence of this pair, left to right.
            let (first, second) = (word[at].clone(), word[at + 1].clone());
            let mut merged = Vec::with_capacity(word.len());
            let mut i = 0;
            while i < word.len() {
                if i + 1 < word.len() && word[i] == first && word[i + 1] == second {
                    merged.push(format!("{first}{second}"));
                    i += 2;
                } else {
                    merged.push(word[i].clone());
                    i += 1;
                }
            }
            word = merged;
        }
        word
    }

    /// The tokens of `text` without start/end markers.
    pub fn encode(&self, text: &str) -> Vec<u32> {
        let cleaned = unescape_html(text);
        let cleaned = cleaned.split_whitespace().collect::<Vec<_>>().join(" ");
        let lower = cleaned.to_lowercase();
        let mut out = Vec::new();
        for m in self.pattern.find_iter(&lower) {
            let mapped: String = m
                .as_str()
                .bytes()
                .map(|b| self.byte_char[b as usize])
                .collect();
            for piece in self.bpe(&mapped) {
                if let Some(id) = self.encoder.get(&piece) {
                    out.push(*id);
                }
            }
        }
        out
    }

    /// `[sot] + tokens + [eot]`, cut to the context (the last kept token becomes the end
    /// marker) and padded with zeros, as the reference's `tokenize`.
    pub fn tokenize(&self, text: &str) -> Vec<u32> {
        let mut t = vec![self.sot];
        t.extend(self.encode(text));
        t.push(self.eot);
        if t.len() > self.context_length {
            t.truncate(self.context_length);
            if let Some(l) = t.last_mut() {
                *l = self.eot;
            }
        }
        t.resize(self.context_length, 0);
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny merge table over the bytes of "low", "lower", "newest".
    fn tiny() -> Tokenizer {
        let merges = "#version: test\nl o\nlo w</w>\nlo w\ne r</w>\nn e\nne w\n";
        // 6 merges → 512 + 6 + 2 tokens.
        Tokenizer::from_merges(merges, 520, 8, Path::new("tiny.txt")).unwrap()
    }

    #[test]
    fn byte_map_is_a_bijection_onto_printables() {
        let m = bytes_to_unicode();
        let mut seen: Vec<char> = m.to_vec();
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), 256);
        assert_eq!(m[b'a' as usize], 'a');
        assert_eq!(m[b' ' as usize], 'Ġ');
        // The vocabulary lists printable bytes first ('!' is token 0, 'a' token 64).
        let t = tiny();
        assert_eq!(t.encoder["!"], 0);
        assert_eq!(t.encoder["a"], 64);
        assert_eq!(t.encoder["a</w>"], 256 + 64);
    }

    #[test]
    fn merges_apply_by_rank_and_words_end_with_w() {
        let t = tiny();
        let id = |s: &str| t.encoder[s];
        assert_eq!(t.encode("low"), vec![id("low</w>")]);
        assert_eq!(t.encode("Lower"), vec![id("low"), id("er</w>")]);
        // "ne w</w>" has no merge ("ne w" only merges inside a word).
        assert_eq!(t.encode("new"), vec![id("ne"), id("w</w>")]);
        // Punctuation is its own piece; white space separates words.
        assert_eq!(
            t.encode("  low,low "),
            vec![id("low</w>"), id(",</w>"), id("low</w>")]
        );
    }

    #[test]
    fn tokenize_frames_cuts_and_pads() {
        let t = tiny();
        let v = t.tokenize("low low");
        assert_eq!(v.len(), 8);
        assert_eq!(v[0], 518);
        assert_eq!(v[3], 519);
        assert_eq!(&v[4..], &[0, 0, 0, 0]);
        let long = t.tokenize("low low low low low low low low low");
        assert_eq!(long.len(), 8);
        assert_eq!(long[7], t.eot);
    }

    #[test]
    fn too_few_merges_is_an_error_naming_the_file() {
        let e = Tokenizer::from_merges("#v\na b\n", 49408, 77, Path::new("m.txt"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("m.txt") && e.contains("48894"), "{e}");
    }
}
