//! Scene and camera I/O for transsplat.
//!
//! - [`Gaussians`]: the 3DGS scene as a struct of arrays, read and written as the
//!   INRIA 3DGS PLY ([`ply`]).
//! - [`Camera`]: pinhole cameras in the OpenCV convention, read from INRIA
//!   `cameras.json`, COLMAP `sparse/0` and nerfstudio / Blender `transforms.json`
//!   ([`cameras`]).
//! - [`formats`]: the scene formats (INRIA PLY, compressed PLY, SPZ, glTF, SOG) and the
//!   one place that picks between them.
//! - [`npy`]: numpy `.npy` arrays (float32 in and out).
//! - [`image`]: PNG and JPEG images as float RGB in [0, 1].
//! - [`scene_paths`]: finding the scene and cameras in an INRIA 3DGS output folder.
//! - [`atomic`]: write-to-temporary-then-rename for every output.
//! - [`fingerprint`]: content fingerprints of scenes and views (content-named files).
//! - [`archive`]: named little-endian arrays with a checksum (checkpoints).
//! - [`resample`]: separable resampling of interleaved images by per-axis taps.
//! - [`cpu`]: run-time CPU feature detection, shared by the crates above this one.
//!
//! Every error names the file it is about ([`Error`]).

pub mod archive;
pub mod atomic;
pub mod camera;
pub mod cameras;
pub mod cpu;
pub mod error;
pub mod fingerprint;
pub mod formats;
pub mod gaussians;
pub mod gltf;
pub mod image;
pub mod npy;
pub mod ply;
pub mod resample;
pub mod rng;
pub mod scene_paths;
pub mod sog;
pub mod spz;

pub use camera::Camera;
pub use error::{Error, Result};
pub use gaussians::{opacity_logit_of_byte, sh_coeffs, sigmoid, Extra, Gaussians, SH_C0};
