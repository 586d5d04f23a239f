//! One error type for every reader and writer in this crate: it always names the file.

use std::path::{Path, PathBuf};

/// An I/O or format error tied to the file it came from.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file exists but its contents are wrong (bad header, truncated, NaN, ...).
    #[error("{}: {msg}", path.display())]
    Format { path: PathBuf, msg: String },
    /// The operating system refused (missing file, permission, disk full, ...).
    ///
    /// The I/O error is part of the message and deliberately not an error `source`:
    /// chains printed with `{:#}` (the CLI) would otherwise repeat it.
    #[error("{}: {err}", path.display())]
    Io { path: PathBuf, err: std::io::Error },
}

impl Error {
    /// A format error for `path`.
    pub fn format(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Format { path: path.as_ref().to_path_buf(), msg: msg.into() }
    }
    /// An I/O error for `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), err: source }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The CLI prints error chains with `{:#}`; an I/O error must appear once.
    #[test]
    fn io_error_is_reported_once_in_a_chain() {
        let e = Error::io("a/b.ply", std::io::Error::from(std::io::ErrorKind::NotFound));
        let chained = format!("{:#}", anyhow_like(&e));
        assert_eq!(chained, "a/b.ply: entity not found");
    }

    /// What `anyhow`'s `{:#}` prints: the message and every source's message.
    fn anyhow_like(e: &(dyn std::error::Error + 'static)) -> String {
        let mut s = e.to_string();
        let mut cur = e.source();
        while let Some(c) = cur {
            s.push_str(&format!(": {c}"));
            cur = c.source();
        }
        s
    }
}
