//! Checkpoints of the long jobs (training, editing): a folder `OUT.checkpoint` beside
//! the output, written every N steps and on Ctrl-C, removed once the output is
//! committed; `resume` continues from it (docs/cli.md, Checkpoints).

use crate::SessionError;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_train::{Checkpointer, Control};

/// How a job checkpoints.
#[derive(Clone, Debug, Default)]
pub struct Checkpoints {
    /// Steps between checkpoints (`None`: the job's default; 0: none).
    pub every: Option<u64>,
    /// Continue from this checkpoint folder (or a file in it).
    pub resume: Option<PathBuf>,
    /// Stop as if interrupted once this many steps are done (deterministic tests).
    pub stop_after: Option<u64>,
    /// Stop as if interrupted once the 2D editor has finished this many views
    /// (deterministic tests of a stop during the edits).
    pub stop_after_views: Option<usize>,
}

/// The folder inside a checkpoint folder where the 2D editor's finished views are kept
/// (`crate::editor_views`).
pub const EDITOR_VIEWS_DIR: &str = "editor-views";

/// How many finished views the checkpoint folder `dir` keeps.
pub fn kept_view_files(dir: &Path) -> usize {
    std::fs::read_dir(dir.join(EDITOR_VIEWS_DIR))
        .map_or(0, |d| d.flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".edit")).count())
}

/// The checkpoint folder of an output folder: `OUT.checkpoint` beside it.
pub fn checkpoint_dir(out: &Path) -> PathBuf {
    let abs = std::path::absolute(out).unwrap_or_else(|_| out.to_path_buf());
    let name = abs.file_name().map_or("out".into(), |n| n.to_string_lossy().into_owned());
    abs.with_file_name(format!("{name}.checkpoint"))
}

impl Checkpoints {
    /// The loop control: `cancel` (Ctrl-C), the checkpointer (`file` is the
    /// checkpoint's name in the folder) and the test stop. Refuses to start afresh over
    /// an earlier run's checkpoint, and to resume from a folder without one.
    pub fn control<'a>(
        &self,
        out: &Path,
        default_every: u64,
        file: &str,
        cancel: Option<&'a AtomicBool>,
    ) -> Result<Control<'a>, SessionError> {
        let every = self.every.unwrap_or(default_every);
        let dir = match &self.resume {
            // The checkpoint file itself names its folder too.
            Some(p) if p.is_file() => p.parent().map_or(PathBuf::from("."), Path::to_path_buf),
            Some(p) => p.clone(),
            None => checkpoint_dir(out),
        };
        // Views the 2D editor finished before a stop count as a checkpoint too.
        let has = dir.join(file).is_file() || kept_view_files(&dir) > 0;
        match &self.resume {
            Some(_) if !has => {
                return Err(SessionError::Input(format!(
                    "{}: no checkpoint ({file}) to resume from",
                    dir.display()
                )))
            }
            None if has => {
                return Err(SessionError::Input(format!(
                    "{}: holds a checkpoint of an earlier run; continue it with --resume {}, or delete the \
                     folder to start over",
                    dir.display(),
                    dir.display()
                )))
            }
            _ => {}
        }
        let checkpoint = (every > 0 || self.resume.is_some()).then(|| Checkpointer::new(dir, every));
        Ok(Control { cancel, checkpoint, stop_after: self.stop_after, resume: self.resume.is_some() })
    }
}

/// The error after a stop at `step`: nothing was written to `out`, where the checkpoint
/// is and the exact command line that continues the run.
pub fn interrupted(step: u64, control: &Control, out: &Path) -> SessionError {
    let message = match control.checkpoint.as_ref().filter(|c| c.last.is_some()) {
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
    };
    SessionError::Interrupted { step, message }
}

/// The error after a failure inside the loop: nothing was written to `out`, and where
/// the last checkpoint is.
pub fn failed(what: impl std::fmt::Display, control: &Control, out: &Path) -> SessionError {
    SessionError::Failed(format!("{what}; no scene was written to {}; {}", out.display(), control.note()))
}

/// This process's command line with `--resume DIR` (replacing any earlier
/// `--resume` and dropping the test stops), quoted for a POSIX shell.
pub fn resume_command(dir: &Path) -> String {
    let mut args: Vec<String> = Vec::new();
    let mut it = std::env::args();
    while let Some(a) = it.next() {
        if ["--resume", "--stop-after", "--stop-after-views"].contains(&a.as_str()) {
            it.next();
        } else if !["--resume=", "--stop-after=", "--stop-after-views="].iter().any(|p| a.starts_with(p)) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_quote_leaves_plain_words_and_quotes_the_rest() {
        assert_eq!(shell_quote("--out=a/b.c"), "--out=a/b.c");
        assert_eq!(shell_quote("make it blue"), "'make it blue'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert_eq!(shell_quote(""), "''");
    }

    #[test]
    fn a_fresh_start_over_an_earlier_checkpoint_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let ck = checkpoint_dir(&out);
        assert_eq!(ck.file_name().unwrap(), "out.checkpoint");
        std::fs::create_dir_all(&ck).unwrap();
        std::fs::write(ck.join("state.bin"), b"").unwrap();
        let fresh = Checkpoints::default().control(&out, 10, "state.bin", None);
        assert!(fresh.is_err_and(|e| e.to_string().contains("--resume")));
        let resumed = Checkpoints { resume: Some(ck.clone()), ..Default::default() }.control(
            &out,
            10,
            "state.bin",
            None,
        );
        assert!(resumed.is_ok_and(|c| c.resume && c.checkpoint.is_some()));
        let missing = Checkpoints { resume: Some(dir.path().into()), ..Default::default() };
        assert!(missing.control(&out, 10, "state.bin", None).is_err());
    }
}
