//! The CLIP byte-pair tokenizer, with its vocabulary bundled (nothing is read or fetched
//! at run time).
//!
//! The vocabulary is OpenAI's `bpe_simple_vocab_16e6` (the one every CLIP text encoder,
//! Stable Diffusion's and InstructPix2Pix's included, was trained with): the 48 894 merges
//! actually used are stored gzip-compressed in `assets/clip_bpe_merges.txt.gz` and the
//! 49 408-entry vocabulary is derived from them in the canonical order (256 byte symbols,
//! the same with the end-of-word mark `</w>`, one token per merge, then
//! `<|startoftext|>` = 49406 and `<|endoftext|>` = 49407).
//!
//! Text is prepared the way the reference, transformers' `CLIPTokenizer` (the
//! `tokenizers`-backed class of transformers 5), prepares it, and parity with it is tested
//! on a few hundred prompts (`tests/tokenizer_parity.rs`):
//!
//! 1. the literal special tokens `<|startoftext|>` / `<|endoftext|>` are cut out of the raw
//!    text first and map to their ids;
//! 2. each remaining segment is normalised: Unicode NFC, every run of whitespace becomes
//!    one space, lower case;
//! 3. it is split into words by the CLIP pattern (special-token spellings, the
//!    contractions `'s 't 're 've 'm 'll 'd`, runs of letters, single digits, runs of
//!    anything else but whitespace); a word spelling a special token (e.g. written in upper
//!    case, so not caught in step 1) is split further by the GPT-2 byte-level pattern
//!    (`<|`, the letters, `|>`), as the byte-level pre-tokenizer does;
//! 4. each word's UTF-8 bytes become the GPT-2 byte symbols, `</w>` marks the last one,
//!    and the merges are applied, lowest rank first.
//!
//! Decision on text cleaning: transformers 5 does no `ftfy` repair and no HTML unescaping
//! (OpenAI's original `clip.tokenize` does both); we follow transformers, the reference the
//! InstructPix2Pix pipeline loads. The two differ only on mojibake and HTML entities.

use std::collections::HashMap;
use std::io::Read;

use regex::Regex;
use unicode_normalization::UnicodeNormalization;

/// Id of `<|startoftext|>`.
pub const START_OF_TEXT: u32 = 49406;
/// Id of `<|endoftext|>` (also the padding id of the CLIP checkpoints this project uses).
pub const END_OF_TEXT: u32 = 49407;
/// Context length of every CLIP text encoder.
pub const CONTEXT_LENGTH: usize = 77;

const MERGES_GZ: &[u8] = include_bytes!("../assets/clip_bpe_merges.txt.gz");
const SPECIALS: [(&str, u32); 2] = [("<|startoftext|>", START_OF_TEXT), ("<|endoftext|>", END_OF_TEXT)];

/// The CLIP tokenizer.
pub struct ClipTokenizer {
    /// Token string to id.
    vocab: HashMap<String, u32>,
    /// Merge rank of a pair of adjacent symbols.
    ranks: HashMap<(String, String), u32>,
    /// GPT-2's byte-to-symbol map.
    byte_symbol: [char; 256],
    words: Regex,
    byte_level: Regex,
    whitespace: Regex,
}

/// GPT-2's reversible map from bytes to printable characters: printable Latin-1 bytes map
/// to themselves, the others to U+0100 upwards in byte order.
fn bytes_to_symbols() -> [char; 256] {
    let printable =
        |b: u32| (0x21..=0x7e).contains(&b) || (0xa1..=0xac).contains(&b) || (0xae..=0xff).contains(&b);
    let mut map = ['\0'; 256];
    let mut next = 256u32;
    for b in 0..256u32 {
        map[b as usize] = if printable(b) {
            char::from_u32(b).unwrap_or('\0')
        } else {
            next += 1;
            char::from_u32(next - 1).unwrap_or('\0')
        };
    }
    map
}

impl ClipTokenizer {
    /// The tokenizer with the bundled CLIP vocabulary.
    pub fn bundled() -> Self {
        let mut text = String::new();
        // The asset is compiled in and checked by the tests; failing to inflate it is a
        // build defect, not bad input.
        flate2::read::GzDecoder::new(MERGES_GZ)
            .read_to_string(&mut text)
            .expect("bundled CLIP merges are valid gzip");
        let merges: Vec<(String, String)> = text
            .lines()
            .filter_map(|l| l.split_once(' ').map(|(a, b)| (a.to_string(), b.to_string())))
            .collect();

        let byte_symbol = bytes_to_symbols();
        // Canonical order: byte symbols in GPT-2 order (printable ones first).
        let mut order: Vec<char> = byte_symbol.iter().copied().filter(|&c| (c as u32) < 256).collect();
        order.extend(byte_symbol.iter().copied().filter(|&c| (c as u32) >= 256));
        let mut tokens: Vec<String> = order.iter().map(|c| c.to_string()).collect();
        tokens.extend(order.iter().map(|c| format!("{c}</w>")));
        tokens.extend(merges.iter().map(|(a, b)| format!("{a}{b}")));
        tokens.extend(SPECIALS.iter().map(|(s, _)| s.to_string()));
        let vocab = tokens.into_iter().enumerate().map(|(i, t)| (t, i as u32)).collect();
        let ranks = merges.into_iter().enumerate().map(|(i, m)| (m, i as u32)).collect();

        let words = Regex::new(
            r"<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+",
        )
        .expect("valid pattern");
        let byte_level = Regex::new(r"'s|'t|'re|'ve|'m|'ll|'d| ?\p{L}+| ?\p{N}+| ?[^\s\p{L}\p{N}]+|\s+")
            .expect("valid pattern");
        let whitespace = Regex::new(r"\s+").expect("valid pattern");
        Self { vocab, ranks, byte_symbol, words, byte_level, whitespace }
    }

    /// Size of the vocabulary (49 408).
    pub fn vocab_size(&self) -> usize {
        self.vocab.len()
    }

    /// Token ids of `text`, between `<|startoftext|>` and `<|endoftext|>`, untruncated.
    pub fn encode(&self, text: &str) -> Vec<u32> {
        let mut ids = vec![START_OF_TEXT];
        let mut rest = text;
        while !rest.is_empty() {
            // The earliest special token in the raw text, if any.
            let next = SPECIALS
                .iter()
                .filter_map(|&(s, id)| rest.find(s).map(|at| (at, s.len(), id)))
                .min_by_key(|&(at, _, _)| at);
            match next {
                Some((at, len, id)) => {
                    self.encode_segment(&rest[..at], &mut ids);
                    ids.push(id);
                    rest = &rest[at + len..];
                }
                None => {
                    self.encode_segment(rest, &mut ids);
                    rest = "";
                }
            }
        }
        ids.push(END_OF_TEXT);
        ids
    }

    /// Token ids of `text` exactly `max_len` long (77 for CLIP): truncated so that
    /// `<|endoftext|>` stays last, then padded with `pad_id` (transformers'
    /// `truncation=True, padding="max_length"`).
    pub fn encode_padded(&self, text: &str, max_len: usize, pad_id: u32) -> Vec<u32> {
        let mut ids = self.encode(text);
        if ids.len() > max_len {
            ids.truncate(max_len.saturating_sub(1));
            if max_len > 0 {
                ids.push(END_OF_TEXT);
            }
        }
        ids.resize(max_len, pad_id);
        ids
    }

    fn encode_segment(&self, raw: &str, ids: &mut Vec<u32>) {
        let nfc: String = raw.nfc().collect();
        let spaced = self.whitespace.replace_all(&nfc, " ");
        let lower: String = spaced.chars().flat_map(char::to_lowercase).collect();
        for word in self.words.find_iter(&lower) {
            for piece in self.byte_level.find_iter(word.as_str()) {
                self.bpe(piece.as_str(), ids);
            }
        }
    }

    /// Byte-pair encoding of one word (classic CLIP/GPT-2 loop: merge every occurrence of
    /// the lowest-ranked adjacent pair until none is in the merge table).
    fn bpe(&self, word: &str, ids: &mut Vec<u32>) {
        let mut symbols: Vec<String> =
            word.bytes().map(|b| self.byte_symbol[b as usize].to_string()).collect();
        if let Some(last) = symbols.last_mut() {
            last.push_str("</w>");
        }
        loop {
            let best = symbols
                .windows(2)
                .filter_map(|w| self.ranks.get(&(w[0].clone(), w[1].clone())).copied())
                .min();
            let Some(rank) = best else { break };
            let mut merged = Vec::with_capacity(symbols.len());
            let mut i = 0;
            while i < symbols.len() {
                if i + 1 < symbols.len()
                    && self.ranks.get(&(symbols[i].clone(), symbols[i + 1].clone())) == Some(&rank)
                {
                    merged.push(format!("{}{}", symbols[i], symbols[i + 1]));
                    i += 2;
                } else {
                    merged.push(std::mem::take(&mut symbols[i]));
                    i += 1;
                }
            }
            symbols = merged;
        }
        // Every byte symbol (with or without `</w>`) and every merge result is in the
        // vocabulary, so the lookup cannot miss.
        ids.extend(symbols.iter().filter_map(|s| self.vocab.get(s).copied()));
    }
}

impl std::fmt::Debug for ClipTokenizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClipTokenizer").field("vocab_size", &self.vocab.len()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vocabulary_has_the_canonical_size_and_specials() {
        let t = ClipTokenizer::bundled();
        assert_eq!(t.vocab_size(), 49408);
        assert_eq!(t.vocab["<|startoftext|>"], START_OF_TEXT);
        assert_eq!(t.vocab["!"], 0);
        assert_eq!(t.vocab["!</w>"], 256);
    }

    #[test]
    fn padding_keeps_the_end_token_last() {
        let t = ClipTokenizer::bundled();
        let long = "a ".repeat(200);
        let ids = t.encode_padded(&long, 77, END_OF_TEXT);
        assert_eq!(ids.len(), 77);
        assert_eq!(ids[0], START_OF_TEXT);
        assert_eq!(ids[76], END_OF_TEXT);
        assert_eq!(ids[75], ids[1]);
        let short = t.encode_padded("hi", 10, 0);
        assert_eq!(&short[3..], &[0; 7]);
        assert_eq!(short[2], END_OF_TEXT);
    }
}
