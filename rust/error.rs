//! The one error type of the core; `python.rs` maps it to `ValueError`.

/// Everything the core can reject. Messages name the offending item so that the Python
/// exception is actionable without a traceback into Rust.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The robot description is inconsistent or uses something the labeller cannot treat exactly.
    #[error("invalid robot model: {0}")]
    InvalidModel(String),
    /// A call's arguments (poses, counts, shapes) are unusable.
    #[error("{0}")]
    InvalidInput(String),
}

pub type Result<T> = std::result::Result<T, Error>;

pub(crate) fn invalid_model<T>(msg: impl Into<String>) -> Result<T> {
    Err(Error::InvalidModel(msg.into()))
}

pub(crate) fn invalid_input<T>(msg: impl Into<String>) -> Result<T> {
    Err(Error::InvalidInput(msg.into()))
}
