//! A job's output folder: the one output rule, then staging.
//!
//! The rule ([`transsplat_scene::atomic::check_output`]): an output may not be an
//! input, contain one, or lie inside an input folder. The folder is written into a
//! hidden staging folder beside it and replaces the output only on [`Output::commit`];
//! any failure, full disk or signal leaves the output as it was. An existing output
//! must be empty or hold the job's marker file (an earlier output of the same job).
//! Errors name the path the user gave, never the staging name.

use std::path::{Path, PathBuf};
use transsplat_scene::atomic::{check_output, StagedDir};

/// An output folder being written.
#[derive(Debug)]
pub struct Output {
    staged: StagedDir,
    /// The output as the user gave it.
    pub path: PathBuf,
}

impl Output {
    /// Checks `path` against `inputs` (as given and as resolved; both may be listed)
    /// and starts staging it. `marker` is the file that marks a finished output.
    pub fn begin(path: &Path, inputs: &[&Path], marker: &str) -> Result<Output, transsplat_scene::Error> {
        check_output(path, inputs)?;
        let staged = StagedDir::begin(path, marker)?;
        Ok(Output { staged, path: path.to_path_buf() })
    }

    /// The staging folder to write into.
    pub fn dir(&self) -> &Path {
        self.staged.path()
    }

    /// Runs `write` on the staging folder; a failure names the output's path.
    pub fn write<T>(
        &self,
        write: impl FnOnce(&Path) -> Result<T, transsplat_scene::Error>,
    ) -> Result<T, transsplat_scene::Error> {
        write(self.staged.path()).map_err(|e| self.staged.user_error(e))
    }

    /// `error` with a path inside the staging folder renamed to the same path inside
    /// the output.
    pub fn user_error(&self, error: transsplat_scene::Error) -> transsplat_scene::Error {
        self.staged.user_error(error)
    }

    /// Replaces the output with the staged folder; returns the output's path.
    pub fn commit(self) -> Result<PathBuf, transsplat_scene::Error> {
        self.staged.commit()
    }
}
