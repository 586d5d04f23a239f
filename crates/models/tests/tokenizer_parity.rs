//! The bundled CLIP tokenizer against transformers' `CLIPTokenizer` on a few hundred
//! varied prompts (case, punctuation, digits, accents composed and decomposed, scripts,
//! emoji, whitespace, literal special tokens, over-long). Fixture written by
//! `tools/model_fixtures_clip.py`.

use transsplat_models::tokenizer::{ClipTokenizer, END_OF_TEXT};

#[derive(serde::Deserialize)]
struct Fixture {
    prompts: Vec<String>,
    ids: Vec<Vec<u32>>,
    padded_77: Vec<Vec<u32>>,
}

fn fixture() -> Fixture {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/tokenizer/prompts.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn ids_match_transformers_on_every_prompt() {
    let f = fixture();
    assert!(f.prompts.len() >= 300);
    let t = ClipTokenizer::bundled();
    let mut failures = Vec::new();
    for (p, want) in f.prompts.iter().zip(&f.ids) {
        let got = t.encode(p);
        if &got != want {
            failures.push(format!("{p:?}\n  got  {got:?}\n  want {want:?}"));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} prompts differ:\n{}",
        failures.len(),
        f.prompts.len(),
        failures.join("\n")
    );
}

#[test]
fn padded_ids_match_transformers_truncation_and_padding() {
    let f = fixture();
    let t = ClipTokenizer::bundled();
    let mut truncated = 0;
    for (p, want) in f.prompts.iter().zip(&f.padded_77) {
        assert_eq!(&t.encode_padded(p, 77, END_OF_TEXT), want, "{p:?}");
        truncated += usize::from(t.encode(p).len() > 77);
    }
    assert!(truncated >= 2, "the fixture must exercise truncation");
}
