//! Metrics of edits.
//!
//! - [`clip_metrics`]: CLIP-sim and CLIP-dir over folders of renders (ClipSimilarity protocol).
//! - [`metrics`]: PSNR (optionally inside or outside a mask), SSIM, AUROC.
//! - [`ground_truth`]: scores an edited scene of a built-in benchmark scene against
//!   its ground-truth edit on the test views (docs/method.md#v2-ground-truth-metrics: target PSNR inside
//!   the target mask against the ground-truth edit, background PSNR outside it
//!   against the original, SSIM, gate AUROC against the per-Gaussian target label).
//!
//! The benchmarks that use them (the demo, the quality suite) are in `transsplat-bench`.

pub mod clip_metrics;
pub mod ground_truth;
pub mod metrics;
