//! The object an instruction edits, as a phrase for a text-grounded segmenter
//! (`edit --segment` without a phrase): "make the ball blue" → "the ball".
//!
//! Instructions to a 2D editor name the target as the object of a verb, followed by
//! what it becomes. The rules, in order, on the lower-cased words (punctuation dropped,
//! a leading "please" skipped):
//!
//! 1. A verb of change whose object is followed by a preposition: `turn`, `transform`,
//!    `convert`, `change`, `swap`, `replace`, `switch` — the object is the words up to
//!    `into`, `to`, `with`, `for` or `by` ("turn the bear into a panda" → "the bear").
//! 2. A verb whose object is followed by the new look: `make`, `paint`, `colour`,
//!    `color`, `recolour`, `recolor`, `dye`, `render` — the words up to `look`, `like`,
//!    `into`, `to`, `as`, `made`, `with`, `in`, then without the trailing words that say
//!    the look (colours and tone words such as "bright blue"), or without the last word
//!    if none of them ends it ("make the ball shiny" → "the ball").
//! 3. `give X a/an/some Y` — the words before the second determiner ("give the cat a
//!    hat" → "the cat").
//!
//! Anything else gives no phrase: the caller asks the user for one rather than segment
//! the wrong thing.

/// Colours and tone words that describe the new look and end a `make …` object.
const LOOK_WORDS: &[&str] = &[
    "red",
    "green",
    "blue",
    "yellow",
    "orange",
    "purple",
    "violet",
    "pink",
    "cyan",
    "magenta",
    "black",
    "white",
    "grey",
    "gray",
    "brown",
    "gold",
    "golden",
    "silver",
    "teal",
    "turquoise",
    "beige",
    "navy",
    "crimson",
    "bright",
    "dark",
    "light",
    "pale",
    "deep",
    "vivid",
    "transparent",
    "colourful",
    "colorful",
];

/// Verbs whose object is followed by a preposition and what the object becomes.
const CHANGE_VERBS: &[&str] = &["turn", "transform", "convert", "change", "swap", "replace", "switch"];
const CHANGE_ENDS: &[&str] = &["into", "to", "with", "for", "by"];

/// Verbs whose object is followed by its new look.
const LOOK_VERBS: &[&str] = &["make", "paint", "colour", "color", "recolour", "recolor", "dye", "render"];
const LOOK_ENDS: &[&str] = &["look", "looks", "like", "into", "to", "as", "made", "with", "in"];

const DETERMINERS: &[&str] = &["a", "an", "some"];

/// The phrase naming what `instruction` edits, or `None` when the rules of this module
/// find none.
pub fn target_phrase(instruction: &str) -> Option<String> {
    let lower = instruction.to_lowercase();
    let words: Vec<&str> = lower
        .split(|c: char| !(c.is_alphanumeric() || c == '-' || c == '\''))
        .filter(|w| !w.is_empty())
        .collect();
    let words = match words.split_first() {
        Some((&"please", rest)) => rest,
        _ => &words[..],
    };
    let (&verb, rest) = words.split_first()?;
    let object: Vec<&str> = if CHANGE_VERBS.contains(&verb) {
        let end = rest.iter().position(|w| CHANGE_ENDS.contains(w))?;
        rest[..end].to_vec()
    } else if LOOK_VERBS.contains(&verb) {
        let end = rest.iter().position(|w| LOOK_ENDS.contains(w)).unwrap_or(rest.len());
        let mut object = rest[..end].to_vec();
        let look = object.iter().rev().take_while(|w| LOOK_WORDS.contains(w)).count();
        let cut = if look > 0 || end < rest.len() { look } else { 1 };
        object.truncate(object.len().saturating_sub(cut));
        object
    } else if verb == "give" {
        // The object is the first noun phrase; the thing given starts at the next
        // determiner (skipping one the object itself may start with).
        let end = rest.iter().skip(1).position(|w| DETERMINERS.contains(w))? + 1;
        rest[..end].to_vec()
    } else {
        return None;
    };
    // A phrase of determiners alone ("make it blue": "it" is no object to segment).
    let named = object
        .iter()
        .any(|w| !["the", "a", "an", "this", "that", "it", "them", "all", "everything"].contains(w));
    named.then(|| object.join(" "))
}

#[cfg(test)]
mod tests {
    use super::target_phrase;

    #[test]
    fn instructions_name_their_target() {
        let cases = [
            ("make the ball blue", Some("the ball")),
            ("Make the red ball blue.", Some("the red ball")),
            ("make the ball bright blue", Some("the ball")),
            ("make the ball shiny", Some("the ball")),
            ("make the vase look like marble", Some("the vase")),
            ("please make the mug made of gold", Some("the mug")),
            ("turn the bear into a panda", Some("the bear")),
            ("change the mug to green", Some("the mug")),
            ("replace the cup with a teapot", Some("the cup")),
            ("paint the wooden chair red", Some("the wooden chair")),
            ("recolour the apple cyan", Some("the apple")),
            ("give the cat a hat", Some("the cat")),
            ("give a dog some sunglasses", Some("a dog")),
            ("make it blue", None),
            ("autumn", None),
            ("turn the lights", None),
            ("", None),
        ];
        for (instruction, want) in cases {
            assert_eq!(target_phrase(instruction).as_deref(), want, "{instruction:?}");
        }
    }
}
