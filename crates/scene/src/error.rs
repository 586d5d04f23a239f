//! One error type for every reader and writer in this crate: it always names the file.

use std::path::{Path, PathBuf};

/// An I/O or format error tied to the file it came from.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file exists but its contents are wrong (bad header, truncated, NaN, ...).
    #[error("{}: {msg}", path.display())]
    Format { path: PathBuf, msg: String },
    /// The operating system refused (missing file, permission, disk full, ...).
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    /// A format error for `path`.
    pub fn format(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Format { path: path.as_ref().to_path_buf(), msg: msg.into() }
    }
    /// An I/O error for `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), source }
    }
    /// The file this error is about.
    pub fn path(&self) -> &Path {
        match self {
            Error::Format { path, .. } | Error::Io { path, .. } => path,
        }
    }
}

/// Result with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
