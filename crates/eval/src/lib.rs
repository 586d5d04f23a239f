//! Evaluation of edits.
//!
//! - [`bench_edit`]: a whole edit timed by stage at a stated real size (`bench edit`).
//! - [`clip_metrics`]: CLIP-sim and CLIP-dir over folders of renders (ClipSimilarity protocol).
//! - [`metrics`]: PSNR (optionally inside or outside a mask), SSIM, AUROC.
//! - [`ground_truth`]: scores an edited scene of a built-in benchmark scene against
//!   its ground-truth edit on the test views (docs/method.md#v2-ground-truth-metrics: target PSNR inside
//!   the target mask against the ground-truth edit, background PSNR outside it
//!   against the original, SSIM, gate AUROC against the per-Gaussian target label).
//! - [`trained`]: a built-in scene trained from its own renders (`demo --trained N`).
//! - [`quality`]: the ground-truth suite over many demo cases (`bench quality`).
//! - [`demo`]: the built-in benchmark: a scene, the simulated editor, TransSplat and
//!   every baseline and ablation, `metrics.json` and `report.html`.

pub mod bench_edit;
pub mod clip_metrics;
pub mod demo;
pub mod ground_truth;
pub mod metrics;
pub mod quality;
pub mod trained;
