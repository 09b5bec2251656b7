//! The error type of an evaluation.

/// Errors of an evaluation; each says what and where.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Options or data that cannot be evaluated.
    #[error("evaluation: {0}")]
    Invalid(String),
    /// Dataset I/O failed.
    #[error(transparent)]
    Sim(#[from] dynaserve_sim::SimError),
    /// A learned model failed or rejected its input.
    #[error(transparent)]
    Model(#[from] dynaserve_model::ModelError),
    /// A predictor returned something unusable.
    #[error("predictor {predictor}, scene {scene}: {message}")]
    Predictor {
        /// Predictor name.
        predictor: String,
        /// Scene index in evaluation order.
        scene: usize,
        /// What was wrong.
        message: String,
    },
}
