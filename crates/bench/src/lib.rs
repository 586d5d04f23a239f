//! Every benchmark of transsplat, off the production path: no front but the CLI's
//! `bench` and `demo` commands depends on this crate.
//!
//! - [`raster`]: forward, binning, backward and splat-back timings (`bench raster`).
//! - [`transport`]: the transport solver on view-like random problems (`bench transport`).
//! - [`train`]: time per training step against forward + backward alone (`bench train`).
//! - [`models`], [`ip2p`]: CLIP, CLIPSeg, DINOv2 and InstructPix2Pix at real sizes with random
//!   weights (`bench models`).
//! - [`edit`]: a whole edit timed by stage at a stated real size (`bench edit`).
//! - [`demo`]: the built-in benchmark: a scene, the simulated editor, TransSplat and
//!   every baseline and ablation scored against the ground truth (`transsplat demo`).
//! - [`trained`]: a built-in scene trained from its own renders (`demo --trained N`).
//! - [`quality`]: the ground-truth suite over many demo cases (`bench quality`).
//! - [`timing`]: best-of-N timing.

pub mod capture;
pub mod configs;
pub mod demo;
pub mod edit;
pub mod ip2p;
pub mod models;
pub mod quality;
pub mod raster;
pub mod timing;
pub mod train;
pub mod trained;
pub mod transport;
