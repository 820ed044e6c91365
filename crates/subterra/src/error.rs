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
        /// The parser's message, with the field, line and column where it stopped (one line).
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
        Self::InvalidConfig { field: field.into(), reason: reason.into(), value: short_number(value.to_string()) }
    }

    /// The same error with the argument `from` (any of them) called `to`: a binding whose
    /// parameter has another name (`stamp` for the core's `stamp_s`) names its own.
    pub fn renamed(self, from: &[&str], to: &str) -> Self {
        match self {
            Self::InvalidInput { argument, reason } if from.contains(&argument.as_str()) => Self::InvalidInput { argument: to.into(), reason },
            other => other,
        }
    }

    /// The same config error with its field moved into `section` (a config nested in another
    /// names the field as the outer file spells it): the field's own prefix `own` (`astar.`,
    /// or `""` for a config whose fields have none) is replaced by `section.`.
    pub fn in_section(self, own: &str, section: &str) -> Self {
        match self {
            Self::InvalidConfig { field, reason, value } => {
                let rest = field.strip_prefix(own).unwrap_or(&field);
                Self::InvalidConfig { field: format!("{section}.{rest}"), reason, value }
            }
            other => other,
        }
    }

    /// Shorthand for [`Error::InvalidInput`].
    pub fn input(argument: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidInput { argument: argument.into(), reason: reason.into() }
    }
}

/// A number printed in full (`f64`'s `Display` never uses an exponent: 1e-310 has 310 digits)
/// in scientific notation instead; anything else unchanged.
fn short_number(text: String) -> String {
    match text.parse::<f64>() {
        Ok(x) if text.len() > 24 => format!("{x:e}"),
        _ => text,
    }
}

/// Parses a TOML document into `T`. An error is one line naming the field, the line and the
/// column, and what was wrong: `filter.particles (line 19, column 13): invalid value: integer
/// `-5`, expected usize`.
pub fn parse_toml<T: serde::de::DeserializeOwned>(text: &str) -> Result<T> {
    parse_toml_located(text).map_err(|(at, message)| Error::ConfigParse { message: format!("{at}: {message}") })
}

/// [`parse_toml`] with the error as (where, what): where is `field (line L, column C)`, or
/// `line L, column C` for a syntax error; what is the parser's message on one line.
pub fn parse_toml_located<T: serde::de::DeserializeOwned>(text: &str) -> std::result::Result<T, (String, String)> {
    let de = toml::Deserializer::parse(text).map_err(|e| toml_error_parts(text, &e, ""))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        toml_error_parts(text, e.inner(), &path)
    })
}

fn toml_error_parts(text: &str, e: &toml::de::Error, path: &str) -> (String, String) {
    let at = e.span().map(|span| {
        let (line, column) = line_column(text, span.start);
        format!("line {line}, column {column}")
    });
    let field = (!path.is_empty() && path != ".").then(|| path.to_string());
    let at = match (field, at) {
        (Some(f), Some(a)) => format!("{f} ({a})"),
        (Some(f), None) => f,
        (None, Some(a)) => a,
        (None, None) => "toml".to_string(),
    };
    (at, e.message().split_whitespace().collect::<Vec<_>>().join(" "))
}

/// The 1-based line and column (in characters) of byte `offset` in `text`.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let before = &text[..end];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
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
