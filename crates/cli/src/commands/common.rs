//! Loading inputs and preparing outputs, shared by the commands.

use anyhow::Result;
use std::path::{Path, PathBuf};

use transsplat_scene::{formats, spz, Camera, Gaussians};
use transsplat_session::{inputs, Checkpoints, Output};

/// Options shared by every command that reads a scene.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene: a 3DGS PLY (INRIA or PlayCanvas compressed), an .spz, .glb or .sog file, or
    /// an INRIA output folder (newest iteration is used).
    #[arg(long)]
    pub scene: PathBuf,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
    /// Axes of an .spz scene: rub (Niantic's documented convention, splat-transform
    /// 2.x) or rdf (the PLY's axes unconverted: splat-transform 3.x, Niantic's
    /// ply_to_spz). Also the axes of any .spz this command writes.
    #[arg(long, value_parser = spz::Axes::parse, default_value = "rub")]
    pub spz_axes: spz::Axes,
}

/// Writing options of the commands that write scenes (`convert`, `edit --format`).
#[derive(clap::Args, Debug, Clone)]
pub struct SpzWriteArgs {
    /// SPZ version written: 4 (zstd streams, the reference's current default) or 3 (gzip).
    #[arg(long, value_parser = spz::Options::parse_version, default_value = "4")]
    pub spz_version: u32,
}

/// Reads and checks the scene (the session layer's [`inputs::load_scene`]); returns it
/// with the file it came from.
pub fn load_scene(args: &SceneArgs) -> Result<(Gaussians, PathBuf)> {
    let options = formats::ReadOptions { drop_invalid: args.drop_invalid, spz_axes: args.spz_axes };
    Ok(inputs::load_scene(&args.scene, &options)?)
}

/// Loads cameras from `--cameras`, or from beside the scene when it is an INRIA folder
/// (the session layer's [`inputs::load_cameras`]).
pub fn load_cameras(cameras_arg: Option<&Path>, scene: &Path) -> Result<(Vec<Camera>, PathBuf)> {
    Ok(inputs::load_cameras(cameras_arg, scene)?)
}

pub use transsplat_scene::atomic::check_output;

/// Begins a folder output through the session layer's [`Output`]: the one output rule
/// ([`check_output`]), then a staging folder beside `out` that replaces it only on
/// commit; errors name `out`. An existing `out` must be empty or hold `marker` (an
/// earlier output of the same command).
pub fn staged_output(out: &Path, inputs: &[&Path], marker: &str) -> Result<Output> {
    Ok(Output::begin(out, inputs, marker)?)
}

/// Parses a finite number (a flag value; NaN and infinities are refused).
pub fn finite_f32(s: &str) -> Result<f32, String> {
    finite_f64(s).map(|v| v as f32).and_then(|v| {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("{s:?} is out of range"))
        }
    })
}

/// Parses a finite number (a flag value; NaN and infinities are refused).
pub fn finite_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("expected a finite number, got {s:?}")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// Parses `R,G,B` with components in [0, 1].
pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> =
        s.split(',').map(|c| c.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [r, g, b] if v.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)) => Ok([r, g, b]),
        _ => Err(format!("expected R,G,B with three numbers in [0, 1], got {s:?}")),
    }
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
/// The bar of an edit's steps, hidden until [`show_steps`]: the 2D editor draws its own
/// bar before the steps begin.
pub fn steps_bar(len: u64) -> indicatif::ProgressBar {
    let pb = progress(len, "edit");
    pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    pb
}

/// Shows a [`steps_bar`] once the editor is done, its clock and ETA from now.
pub fn show_steps(pb: &indicatif::ProgressBar) {
    pb.reset_elapsed();
    pb.reset_eta();
    pb.set_draw_target(indicatif::ProgressDrawTarget::stderr());
}

pub fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:>10} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// Checkpoint options of the long commands (`train`, `edit`).
#[derive(clap::Args, Debug, Clone)]
pub struct CheckpointArgs {
    /// Write a checkpoint every N steps into the folder OUT.checkpoint beside the output
    /// (default 500 for train, 100 for edit; 0 = no checkpoints). Ctrl-C writes one too.
    #[arg(long, value_name = "N")]
    pub checkpoint_every: Option<u64>,
    /// Continue an interrupted run from its checkpoint folder (or a file in it); give
    /// the same other options (settings and inputs are checked against the checkpoint).
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// Stop as if interrupted once this many steps are done (deterministic tests).
    #[arg(long, hide = true)]
    pub stop_after: Option<u64>,
    /// Stop as if interrupted once the 2D editor has finished this many views (tests).
    #[arg(long, hide = true)]
    pub stop_after_views: Option<usize>,
}

impl CheckpointArgs {
    /// The session layer's description of these flags.
    pub fn spec(&self) -> Checkpoints {
        Checkpoints {
            every: self.checkpoint_every,
            resume: self.resume.clone(),
            stop_after: self.stop_after,
            stop_after_views: self.stop_after_views,
        }
    }
}
