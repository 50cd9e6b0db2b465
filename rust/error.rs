//! The one error type of the core; `bindings/errors.rs` maps it to `profrobot.errors`' classes
//! (`ModelError`, `InputError`: ValueErrors and ProfrobotErrors).

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
    /// The narrow phase could not decide a candidate pair in some pose (parry has no query for
    /// the pair's shapes). Never turned into "free" (nor into "in contact"): the call fails,
    /// naming the pose and the pair (`collide::Undecided`). A model the core cannot label
    /// exactly, so Python sees a `ModelError`.
    #[error("cannot label exactly: {0}")]
    Undecided(String),
    /// The call was stopped before it finished (`cancel::request`, Ctrl-C in Python): nothing
    /// it computed is returned.
    #[error("interrupted")]
    Interrupted,
}

pub type Result<T> = std::result::Result<T, Error>;

pub(crate) fn invalid_model<T>(msg: impl Into<String>) -> Result<T> {
    Err(Error::InvalidModel(msg.into()))
}

pub(crate) fn invalid_input<T>(msg: impl Into<String>) -> Result<T> {
    Err(Error::InvalidInput(msg.into()))
}
