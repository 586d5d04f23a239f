//! The CLIP byte-pair tokenizer. Being written.
