//! The scene file formats and the one place that picks between them: the INRIA PLY
//! ([`crate::ply`]), the PlayCanvas compressed PLY ([`crate::ply::compressed`]),
//! Niantic's SPZ ([`crate::spz`]), glTF binary with `KHR_gaussian_splatting`
//! ([`crate::gltf`]) and PlayCanvas SOG ([`crate::sog`]). Reading recognises the
//! format from the file's first bytes; writing takes it from the name (`.spz`,
//! `.compressed.ply`, `.ply`, `.glb`, `.sog`) or a flag.

use crate::{atomic, gltf, ply, sog, spz, Error, Gaussians, Result};
use std::path::Path;

/// A scene file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFormat {
    /// The INRIA 3DGS PLY: float32, every parameter, extra properties kept.
    Ply,
    /// PlayCanvas / SuperSplat compressed PLY: about 16 bytes a Gaussian plus 1 byte per
    /// higher SH coefficient, 256-Gaussian chunks.
    CompressedPly,
    /// Niantic SPZ (version 4, zstd, by default; 3, gzip).
    Spz,
    /// glTF 2.0 binary with the Khronos `KHR_gaussian_splatting` extension: float32
    /// attributes, glTF's axes.
    Glb,
    /// PlayCanvas SOG: lossless WebP textures and codebooks in a zip bundle, about 5 to
    /// 10 bytes a Gaussian.
    Sog,
}

impl SceneFormat {
    /// Every format, for messages.
    pub const ALL: [SceneFormat; 5] =
        [SceneFormat::Ply, SceneFormat::CompressedPly, SceneFormat::Spz, SceneFormat::Glb, SceneFormat::Sog];

    /// The format's flag name.
    pub fn name(self) -> &'static str {
        match self {
            SceneFormat::Ply => "ply",
            SceneFormat::CompressedPly => "compressed-ply",
            SceneFormat::Spz => "spz",
            SceneFormat::Glb => "glb",
            SceneFormat::Sog => "sog",
        }
    }

    /// The file name ending written for the format.
    pub fn extension(self) -> &'static str {
        match self {
            SceneFormat::Ply => ".ply",
            SceneFormat::CompressedPly => ".compressed.ply",
            SceneFormat::Spz => ".spz",
            SceneFormat::Glb => ".glb",
            SceneFormat::Sog => ".sog",
        }
    }

    /// The format of a flag value ([`SceneFormat::name`]).
    pub fn parse(s: &str) -> std::result::Result<Self, String> {
        Self::ALL.into_iter().find(|f| f.name() == s).ok_or_else(|| {
            format!("unknown scene format {s:?}; expected one of: {}", Self::ALL.map(Self::name).join(", "))
        })
    }

    /// The format a file name asks for, from its ending.
    pub fn of_path(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_str()?.to_ascii_lowercase();
        // The longer ending first: `.compressed.ply` also ends in `.ply`.
        let mut all = Self::ALL;
        all.sort_by_key(|f| std::cmp::Reverse(f.extension().len()));
        all.into_iter().find(|f| name.ends_with(f.extension()))
    }
}

/// How scene files are read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file (PLY).
    pub drop_invalid: bool,
    /// The axes of SPZ files ([`spz::Axes`]).
    pub spz_axes: spz::Axes,
}

/// How scene files are written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// SPZ's version and axes.
    pub spz: spz::Options,
}

/// Reads a scene in any format (recognised by content); returns it with the number of
/// Gaussians dropped for NaN or infinite values (only with `drop_invalid`).
pub fn read_with(path: &Path, options: &ReadOptions) -> Result<(Gaussians, usize)> {
    let bytes = atomic::read(path)?;
    if spz::looks_like(&bytes) {
        // Every SPZ value is decoded from bytes into a finite number: nothing to drop.
        return Ok((spz::parse_with(&bytes, path, options.spz_axes)?, 0));
    }
    if sog::looks_like(&bytes) {
        return screen_invalid(sog::parse(&bytes, path)?, path, options.drop_invalid);
    }
    if gltf::looks_like(&bytes) {
        return screen_invalid(gltf::parse(&bytes, path)?, path, options.drop_invalid);
    }
    ply::parse_with(&bytes, path, &ply::ReadOptions { drop_invalid: options.drop_invalid })
}

/// Drops the Gaussians with a NaN or infinite parameter (or an all-zero rotation) when
/// `drop` is set, else refuses the first one, naming it.
fn screen_invalid(mut g: Gaussians, path: &Path, drop: bool) -> Result<(Gaussians, usize)> {
    if drop {
        let keep: Vec<bool> = (0..g.len()).map(|i| g.non_finite_at(i).is_none()).collect();
        let dropped = keep.iter().filter(|k| !**k).count();
        g.retain(&keep);
        return Ok((g, dropped));
    }
    match g.first_non_finite() {
        Some((i, what)) => Err(Error::format(
            path,
            format!("Gaussian {i} has an invalid {what} (use --drop-invalid to skip such Gaussians)"),
        )),
        None => Ok((g, 0)),
    }
}

/// Reads a scene in any format.
pub fn read(path: &Path) -> Result<Gaussians> {
    read_with(path, &ReadOptions::default()).map(|(g, _)| g)
}

/// Writes a scene atomically in `format` (refusing NaN or infinite parameters). The
/// compressed formats reorder the Gaussians (Morton order); every format but the PLY
/// drops extra properties.
pub fn write(path: &Path, g: &Gaussians, format: SceneFormat) -> Result<()> {
    write_with(path, g, format, &WriteOptions::default())
}

/// [`write`] with the formats' options.
pub fn write_with(path: &Path, g: &Gaussians, format: SceneFormat, options: &WriteOptions) -> Result<()> {
    match format {
        SceneFormat::Ply => ply::write(path, g),
        SceneFormat::Spz => spz::write_with(path, g, &options.spz),
        SceneFormat::CompressedPly => ply::compressed::write(path, g),
        SceneFormat::Glb => gltf::write(path, g),
        SceneFormat::Sog => sog::write(path, g),
    }
}
