//! Loading inputs and preparing outputs, shared by the commands.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_scene::atomic::StagedDir;
use transsplat_scene::{cameras, formats, ply, scene_paths, Camera, Gaussians};
use transsplat_train::{Checkpointer, Control};

/// Options shared by every command that reads a scene.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene: a 3DGS PLY (INRIA or PlayCanvas compressed), an .spz file, or an INRIA
    /// output folder (newest iteration is used).
    #[arg(long)]
    pub scene: PathBuf,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
}

/// Reads and checks the scene; returns it with the PLY path it came from.
pub fn load_scene(args: &SceneArgs) -> Result<(Gaussians, PathBuf)> {
    let path = scene_paths::resolve_scene(&args.scene)?;
    let (g, dropped) = formats::read_with(&path, &ply::ReadOptions { drop_invalid: args.drop_invalid })?;
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} Gaussians with NaN or infinite parameters", path.display());
    }
    if g.is_empty() {
        bail!("{}: the scene has no Gaussians", path.display());
    }
    tracing::info!("{}: {} Gaussians, SH degree {}", path.display(), g.len(), g.sh_degree);
    Ok((g, path))
}

/// Loads cameras from `--cameras`, or from beside the scene when it is an INRIA folder.
pub fn load_cameras(cameras_arg: Option<&Path>, scene: &Path) -> Result<(Vec<Camera>, PathBuf)> {
    let path = match cameras_arg {
        Some(p) => p.to_path_buf(),
        None => scene_paths::resolve_cameras_for(scene)
            .context("no --cameras given and none found beside the scene")?,
    };
    let cams = cameras::load(&path)?;
    if cams.is_empty() {
        bail!("{}: no cameras", path.display());
    }
    let mut stems = std::collections::HashSet::new();
    for c in &cams {
        if !stems.insert(c.stem()) {
            bail!(
                "{}: two cameras share the image name {:?}; outputs would overwrite each other",
                path.display(),
                c.stem()
            );
        }
    }
    Ok((cams, path))
}

pub use transsplat_scene::atomic::check_output;

/// Begins a folder output: the one output rule ([`check_output`]), then a staging
/// folder beside `out` that replaces it only on commit. Nothing appears at `out` until
/// the command completes; any failure, full disk or signal leaves `out` as it was. An
/// existing `out` must be empty or hold `marker` (an earlier output of the same command).
pub fn staged_output(out: &Path, inputs: &[&Path], marker: &str) -> Result<StagedDir> {
    check_output(out, inputs)?;
    Ok(StagedDir::begin(out, marker)?)
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
}

/// The checkpoint folder of an output folder: `OUT.checkpoint` beside it.
pub fn checkpoint_dir(out: &Path) -> PathBuf {
    let abs = std::path::absolute(out).unwrap_or_else(|_| out.to_path_buf());
    let name = abs.file_name().map_or("out".into(), |n| n.to_string_lossy().into_owned());
    abs.with_file_name(format!("{name}.checkpoint"))
}

impl CheckpointArgs {
    /// The loop control: Ctrl-C, the checkpointer (`file` is the checkpoint's name in
    /// the folder) and the test stop. Refuses to start afresh over an earlier run's
    /// checkpoint, and to resume from a folder without one.
    pub fn control<'a>(
        &self,
        out: &Path,
        default_every: u64,
        file: &str,
        cancel: &'a AtomicBool,
    ) -> Result<Control<'a>> {
        let every = self.checkpoint_every.unwrap_or(default_every);
        let dir = match &self.resume {
            // The checkpoint file itself names its folder too.
            Some(p) if p.is_file() => p.parent().map_or(PathBuf::from("."), Path::to_path_buf),
            Some(p) => p.clone(),
            None => checkpoint_dir(out),
        };
        let has = dir.join(file).is_file();
        match &self.resume {
            Some(_) if !has => bail!("{}: no checkpoint ({file}) to resume from", dir.display()),
            None if has => bail!(
                "{}: holds a checkpoint of an earlier run; continue it with --resume {}, or delete the folder \
                 to start over",
                dir.display(),
                dir.display()
            ),
            _ => {}
        }
        let checkpoint = (every > 0 || self.resume.is_some()).then(|| Checkpointer::new(dir, every));
        Ok(Control {
            cancel: Some(cancel),
            checkpoint,
            stop_after: self.stop_after,
            resume: self.resume.is_some(),
        })
    }

    /// The message after a stop at `step`: where the checkpoint is and the exact
    /// command line that continues the run.
    pub fn interrupted(&self, step: u64, control: &Control, out: &Path) -> String {
        match control.checkpoint.as_ref().filter(|c| c.last.is_some()) {
            Some(ck) => format!(
                "interrupted after step {step}; nothing was written to {}; checkpoint in {}; continue with: {}",
                out.display(),
                ck.dir.display(),
                resume_command(&ck.dir)
            ),
            None => format!(
                "interrupted after step {step}; nothing was written to {} (checkpoints are off)",
                out.display()
            ),
        }
    }
}

/// This process's command line with `--resume DIR` (replacing any earlier
/// `--resume` and dropping `--stop-after`), quoted for a POSIX shell.
pub fn resume_command(dir: &Path) -> String {
    let mut args: Vec<String> = Vec::new();
    let mut it = std::env::args();
    while let Some(a) = it.next() {
        if a == "--resume" || a == "--stop-after" {
            it.next();
        } else if !(a.starts_with("--resume=") || a.starts_with("--stop-after=")) {
            args.push(a);
        }
    }
    args.push("--resume".into());
    args.push(dir.display().to_string());
    args.iter().map(|a| shell_quote(a)).collect::<Vec<_>>().join(" ")
}

fn shell_quote(a: &str) -> String {
    let plain = !a.is_empty() && a.chars().all(|c| c.is_ascii_alphanumeric() || "_-./,:=@%+".contains(c));
    if plain {
        a.to_string()
    } else {
        format!("'{}'", a.replace('\'', "'\\''"))
    }
}
