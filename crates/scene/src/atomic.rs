//! Outputs are written to a temporary name beside the target and renamed when
//! complete, so an interrupted run never leaves a half-written file.

use crate::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// Writes a file atomically: `fill` writes into a buffered temporary file which is
/// flushed, synced and renamed onto `path`. On error the temporary file is removed.
pub fn write_with(path: &Path, fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let tmp = temp_path(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    Ok(())
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// Reads a whole file, naming it in the error.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// `p` made absolute with every existing part resolved (links, `..`), so paths that
/// do not exist yet compare with the inputs they might overwrite.
fn resolved(p: &Path) -> PathBuf {
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut existing = abs.as_path();
    let mut rest = Vec::new();
    while !existing.exists() {
        let (Some(parent), Some(name)) = (existing.parent(), existing.file_name()) else { return abs };
        rest.push(name.to_os_string());
        existing = parent;
    }
    let mut out = existing.canonicalize().unwrap_or_else(|_| existing.to_path_buf());
    out.extend(rest.iter().rev());
    out
}

/// The one rule for every command's output, file or folder: refused (naming both paths)
/// when it is an input, contains an input, or lies inside an input folder (a dataset
/// given as a folder) or the `images` folder of a dataset beside an input file.
/// `inputs` are the paths as given and as resolved (both may be listed).
pub fn check_output(out: &Path, inputs: &[&Path]) -> Result<()> {
    let o = resolved(out);
    for input in inputs {
        let i = resolved(input);
        let images = i.parent().map(|d| d.join("images"));
        let why = if o == i {
            "is the input"
        } else if i.starts_with(&o) {
            "contains the input"
        } else if i.is_dir() && o.starts_with(&i) {
            "lies inside the input folder"
        } else if images.is_some_and(|d| d.is_dir() && o.starts_with(&d)) {
            "lies inside the images folder of the dataset of"
        } else {
            continue;
        };
        return Err(Error::format(
            out,
            format!(
                "the output {why} {}; choose another output so no input can be overwritten",
                input.display()
            ),
        ));
    }
    Ok(())
}

/// Staging folders of this process not yet committed or dropped, for [`remove_staged`].
static STAGED: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Removes every staging folder of this process: for a hard exit (a second Ctrl-C or
/// SIGTERM) that skips the destructors.
pub fn remove_staged() {
    let staged = std::mem::take(&mut *STAGED.lock().unwrap_or_else(|e| e.into_inner()));
    for temp in staged {
        let _ = std::fs::remove_dir_all(&temp);
    }
}

/// Removes `.{name}.partial-<pid>` folders in `parent` left by processes of this
/// machine that no longer run (killed without a chance to clean up). Linux only: where
/// `/proc` is absent nothing is removed.
fn remove_abandoned(parent: &Path, name: &str) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let prefix = format!(".{name}.partial-");
    let Ok(entries) = std::fs::read_dir(parent) else { return };
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = file.strip_prefix(&prefix).and_then(|p| p.parse::<u32>().ok()) else { continue };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            tracing::info!("removing {} left by an ended run", e.path().display());
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// A folder written as a whole: files go into a hidden temporary folder beside the
/// target, which replaces the target only in [`StagedDir::commit`]. Dropping it
/// without committing removes the temporary folder, so an interrupted run leaves
/// the target as it was; [`remove_staged`] does the same for a hard exit, and a
/// later run removes the temporary folders of runs that were killed.
#[derive(Debug)]
pub struct StagedDir {
    target: PathBuf,
    temp: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Starts writing `target`. An existing `target` must be an empty folder, or a
    /// folder holding `marker` (a file an earlier run of the same command wrote),
    /// which is then replaced on commit; anything else is refused.
    pub fn begin(target: &Path, marker: &str) -> Result<Self> {
        if target.exists() {
            let ok = target.is_dir()
                && (target.join(marker).is_file()
                    || std::fs::read_dir(target).map(|mut d| d.next().is_none()).unwrap_or(false));
            if !ok {
                return Err(Error::format(
                    target,
                    format!("output folder exists and was not written by this command (no {marker}); choose another"),
                ));
            }
        }
        let name =
            target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
        let parent = target.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        remove_abandoned(parent, &name);
        let temp = parent.join(format!(".{name}.partial-{}", std::process::id()));
        // Errors name the output the user gave, not the hidden staging folder.
        if temp.exists() {
            std::fs::remove_dir_all(&temp).map_err(|e| Error::io(target, e))?;
        }
        std::fs::create_dir_all(&temp).map_err(|e| Error::io(target, e))?;
        STAGED.lock().unwrap_or_else(|e| e.into_inner()).push(temp.clone());
        Ok(StagedDir { target: target.to_path_buf(), temp, committed: false })
    }

    /// The temporary folder to write into.
    pub fn path(&self) -> &Path {
        &self.temp
    }

    /// `error` with a path inside the staging folder renamed to the same path inside
    /// the target: a failure while writing names the output the user gave (`OUT/x.png`),
    /// not the hidden staging name.
    pub fn user_error(&self, error: Error) -> Error {
        let Ok(rest) = error.path().strip_prefix(&self.temp) else { return error };
        let path = self.target.join(rest);
        match error {
            Error::Format { msg, .. } => Error::Format { path, msg },
            Error::Io { err, .. } => Error::Io { path, err },
        }
    }

    /// Replaces the target with the written folder.
    pub fn commit(mut self) -> Result<PathBuf> {
        if self.target.exists() {
            let old = self.temp.with_extension("old");
            std::fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e))?;
            std::fs::rename(&self.temp, &self.target).map_err(|e| Error::io(&self.target, e))?;
            let _ = std::fs::remove_dir_all(&old);
        } else {
            std::fs::rename(&self.temp, &self.target).map_err(|e| Error::io(&self.target, e))?;
        }
        self.committed = true;
        Ok(self.target.clone())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.temp);
        }
        STAGED.lock().unwrap_or_else(|e| e.into_inner()).retain(|t| t != &self.temp);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`remove_staged`] removes every staging folder of the process, so the tests that
    /// stage folders run one at a time (CI once saw one test's `remove_staged` remove
    /// the other's folder while it was being committed).
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

    #[test]
    fn staged_errors_name_the_users_output_not_the_staging_folder() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let s = StagedDir::begin(&target, "done.json").unwrap();
        let inside = s.path().join("renders/a.png");
        let e = s.user_error(Error::format(&inside, "disk full"));
        assert_eq!(e.path(), target.join("renders/a.png"));
        assert_eq!(e.to_string(), format!("{}: disk full", target.join("renders/a.png").display()));
        // Errors about other files are left alone.
        let other = dir.path().join("input.ply");
        assert_eq!(s.user_error(Error::format(&other, "bad")).path(), other);
    }

    #[test]
    fn staged_dir_replaces_only_its_own_output_and_cleans_up() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let s = StagedDir::begin(&target, "done.json").unwrap();
        std::fs::write(s.path().join("done.json"), b"1").unwrap();
        s.commit().unwrap();
        assert!(target.join("done.json").is_file());
        // A second run replaces it.
        let s = StagedDir::begin(&target, "done.json").unwrap();
        std::fs::write(s.path().join("done.json"), b"2").unwrap();
        std::fs::write(s.path().join("x"), b"").unwrap();
        s.commit().unwrap();
        assert_eq!(std::fs::read(target.join("done.json")).unwrap(), b"2");
        // Dropped without commit: nothing changes, no temporary folder left.
        let s = StagedDir::begin(&target, "done.json").unwrap();
        let temp = s.path().to_path_buf();
        drop(s);
        assert!(!temp.exists() && target.join("x").exists());
        // A foreign folder is refused.
        let foreign = dir.path().join("foreign");
        std::fs::create_dir(&foreign).unwrap();
        std::fs::write(foreign.join("precious"), b"").unwrap();
        assert!(StagedDir::begin(&foreign, "done.json").is_err());
    }

    #[test]
    fn hard_exits_and_killed_runs_leave_no_staging_folder() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let s = StagedDir::begin(&target, "done.json").unwrap();
        let temp = s.path().to_path_buf();
        remove_staged();
        assert!(!temp.exists());
        std::mem::forget(s);
        // A folder of a process that no longer runs is removed by the next run; one of
        // a running process (this one, another target) is left alone.
        let dead = dir.path().join(".out.partial-4294967294");
        let mine = dir.path().join(format!(".other.partial-{}", std::process::id()));
        std::fs::create_dir_all(&dead).unwrap();
        std::fs::create_dir_all(&mine).unwrap();
        let s = StagedDir::begin(&target, "done.json").unwrap();
        assert_eq!(!dead.exists(), Path::new("/proc/self").exists());
        assert!(mine.exists());
        drop(s);
    }
}
