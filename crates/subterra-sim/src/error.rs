//! Errors of the simulator. Every variant names the field or argument at fault.

use thiserror::Error;

/// An error of the simulator.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SimError {
    /// A world description is malformed or holds an invalid value.
    #[error("world: {field}: {reason}")]
    InvalidWorld {
        /// Where: `cylinder[3].radius`, `heightfield.heights`, or `line 12, column 5` for parse errors.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A sensor, noise or vehicle parameter is invalid.
    #[error("config field `{field}` is invalid: {reason} (got {value})")]
    InvalidConfig {
        /// Dotted path of the field.
        field: String,
        /// What it must satisfy.
        reason: String,
        /// The offending value as text.
        value: String,
    },
    /// An input value is invalid (NaN pose, wrong length, ...).
    #[error("argument `{argument}` is invalid: {reason}")]
    InvalidInput {
        /// The argument.
        argument: String,
        /// What is wrong.
        reason: String,
    },
    /// An unknown scenario, preset or model name.
    #[error("unknown {what} `{name}`; known: {known}")]
    Unknown {
        /// What kind of name (scenario, sensor preset, ...).
        what: String,
        /// The name asked for.
        name: String,
        /// The known names, comma separated.
        known: String,
    },
    /// An error of the onboard stack (camera, frames).
    #[error(transparent)]
    Core(#[from] subterra::Error),
}

impl SimError {
    /// Shorthand for [`SimError::InvalidWorld`].
    pub fn world(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidWorld { field: field.into(), reason: reason.into() }
    }
    /// Shorthand for [`SimError::InvalidConfig`].
    pub fn config(field: impl Into<String>, reason: impl Into<String>, value: impl ToString) -> Self {
        Self::InvalidConfig { field: field.into(), reason: reason.into(), value: value.to_string() }
    }
    /// The same error with the argument `from` called `to` (a binding whose parameter has
    /// another name: `dt` for the simulator's `dt_s`).
    pub fn renamed(self, from: &str, to: &str) -> Self {
        match self {
            Self::InvalidInput { argument, reason } if argument == from => Self::InvalidInput { argument: to.into(), reason },
            other => other,
        }
    }
    /// Shorthand for [`SimError::InvalidInput`].
    pub fn input(argument: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidInput { argument: argument.into(), reason: reason.into() }
    }
}

/// Result type of the simulator.
pub type SimResult<T> = std::result::Result<T, SimError>;
