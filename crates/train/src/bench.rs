//! Benchmark: time per training step (placeholder, filled below).
