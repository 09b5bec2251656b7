//! Errors of the model crate.

/// Everything that can go wrong when preparing, stepping, saving or loading a model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The caller's scene, state or request is invalid; the message names the field.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A checkpoint directory is missing, corrupted or does not match the architecture.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
    /// An internal invariant failed (a bug, not a user error).
    #[error("internal error: {0}")]
    Internal(String),
    /// The model cannot do what was asked (e.g. gradients from an ensemble); the message
    /// says what and why.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The request's deadline passed before the work was done.
    #[error("deadline exceeded: {0}")]
    DeadlineExceeded(String),
    /// A tensor operation failed.
    #[error("tensor error: {0}")]
    Candle(#[from] candle_core::Error),
    /// A file could not be read or written.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}
