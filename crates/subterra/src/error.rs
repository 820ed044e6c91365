//! The errors of the onboard stack.
//!
//! Every variant names the offending argument or field and carries the values that
//! were expected and received, so that a message can be acted on without a debugger.
//! "No obstacle" or "no path within the risk budget" are outcomes, never errors.

use thiserror::Error;

/// An error of the onboard stack.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum Error {
    /// A configuration field has a value outside its valid range.
    #[error("config field `{field}` is invalid: {reason} (got {value})")]
    InvalidConfig {
        /// Dotted path of the field, e.g. `grid.depth_bin_m`.
        field: String,
        /// What the field must satisfy.
        reason: String,
        /// The offending value, as text.
        value: String,
    },
    /// A configuration could not be parsed.
    #[error("config could not be parsed: {message}")]
    ConfigParse {
        /// The parser's message, with the line and column where it stopped.
        message: String,
    },
    /// A named preset does not exist.
    #[error("unknown preset `{name}`; known presets: {known}")]
    UnknownPreset {
        /// The name asked for.
        name: String,
        /// The names that exist, comma separated.
        known: String,
    },
    /// An image does not have the shape the camera model expects.
    #[error("argument `{argument}` has shape (height={got_height}, width={got_width}) but the camera is (height={expected_height}, width={expected_width})")]
    ImageShapeMismatch {
        /// Name of the argument.
        argument: String,
        /// Expected rows.
        expected_height: u32,
        /// Expected columns.
        expected_width: u32,
        /// Rows received.
        got_height: u32,
        /// Columns received.
        got_width: u32,
    },
    /// An input value is invalid (NaN, empty, wrong length, ...).
    #[error("argument `{argument}` is invalid: {reason}")]
    InvalidInput {
        /// Name of the argument.
        argument: String,
        /// What is wrong with it.
        reason: String,
    },
}

impl Error {
    /// Shorthand for [`Error::InvalidConfig`].
    pub fn config(field: impl Into<String>, reason: impl Into<String>, value: impl ToString) -> Self {
        Self::InvalidConfig { field: field.into(), reason: reason.into(), value: value.to_string() }
    }

    /// Shorthand for [`Error::InvalidInput`].
    pub fn input(argument: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidInput { argument: argument.into(), reason: reason.into() }
    }
}

/// Result type of the onboard stack.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Checks that `value` is finite and strictly positive.
pub(crate) fn require_positive(field: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::config(field, "must be finite and > 0", value))
    }
}

/// Checks that `value` is finite and not negative.
pub(crate) fn require_non_negative(field: &str, value: f64) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(Error::config(field, "must be finite and >= 0", value))
    }
}
