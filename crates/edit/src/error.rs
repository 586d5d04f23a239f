//! The one error type of an edit; every message is one line meant for the user.

/// Errors of an edit.
#[derive(Debug, thiserror::Error)]
pub enum EditError {
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Editor(#[from] transsplat_editors::Error),
    #[error("the editor found nothing to edit: no view has attention above the support threshold")]
    NoEvidence,
    /// The solver's message is part of this one (not a separate source), so an error
    /// chain prints it once.
    #[error("transport failed: {0}")]
    Transport(transsplat_transport::Error),
    #[error("optimisation failed: {0}")]
    Train(String),
    #[error("interrupted at step {0}")]
    Interrupted(usize),
    /// A checkpoint cannot be written, read or used (the message names the file).
    #[error("{0}")]
    Checkpoint(String),
}

impl From<transsplat_transport::Error> for EditError {
    fn from(e: transsplat_transport::Error) -> Self {
        EditError::Transport(e)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn transport_errors_carry_the_message_once() {
        use std::error::Error as _;
        let inner = transsplat_transport::Error::Shape { what: "source masses", got: 1, expected: 2 };
        let e: super::EditError = inner.into();
        // An error chain printer (anyhow's `{:#}`) appends every source; the solver's
        // message is already in this one, so there must be no source.
        assert!(e.source().is_none());
        assert_eq!(e.to_string().matches("source masses has 1 entries").count(), 1, "{e}");
    }
}
