//! Codec errors, split by direction as rust-mavlink does: [`DecodeError`] for bytes
//! coming in, [`EncodeError`] for bytes going out. Messages name the thing at fault
//! (message type and field) because they end up in `/api/v1/status` `last_error`.

use thiserror::Error;

/// What a payload that is not CDR looks like, from its first two bytes: the hint a
/// user needs when a JSON publisher is wired to a ROS 2 input.
fn looks_like(head: &[u8; 2]) -> &'static str {
    match head {
        [b'{', b'"' | b' ' | b'\n' | b'}'] | [b'[', _] => {
            ": it looks like JSON (a JSON publisher's input is format = \"json\" or \"mavlink-json\")"
        }
        _ => "",
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum DecodeError {
    #[error("payload truncated: needed {needed} bytes at offset {offset}, payload has {len}")]
    Truncated {
        needed: usize,
        offset: usize,
        len: usize,
    },
    #[error(
        "bad CDR encapsulation header {head:02x?} (expected 00 01 little-endian or 00 00 big-endian){hint}",
        head = .0,
        hint = looks_like(.0)
    )]
    BadEncapsulation([u8; 2]),
    #[error("{field}: string is not valid UTF-8 or not NUL-terminated")]
    BadString { field: String },
    #[error("{field}: sequence length {len} exceeds the payload")]
    BadLength { field: String, len: usize },
    #[error("{message}: {len} bytes after the message (a longer layout than the one read)")]
    TrailingBytes { message: String, len: usize },
    /// Decoded, but no sample can be made of it (a position not on Earth, no
    /// integration time), the field named.
    #[error("{0}")]
    Unusable(String),
    #[error("{field} is {value} (NaN/Inf not allowed)")]
    NonFinite { field: String, value: f64 },
    #[error("{field} = {value} is out of range: {reason}")]
    OutOfRange {
        field: String,
        value: f64,
        reason: &'static str,
    },
    #[error("invalid JSON: {0}")]
    Json(String),
    #[error("{message}: missing field `{field}`")]
    MissingField { message: String, field: String },
    #[error("{message}: field `{field}` has the wrong type (expected {expected})")]
    WrongType {
        message: String,
        field: String,
        expected: &'static str,
    },
    #[error("unsupported message `{0}`")]
    UnsupportedMessage(String),
    #[error("MAVLink frame rejected: {0}")]
    Mavlink(String),
    #[error("input has a ROS format but no ROS message type")]
    NoRosType,
    #[error("payload is not UTF-8 text")]
    NotUtf8,
    /// The second part of a message that carries two samples (HIGHRES_IMU's pressure
    /// beside its IMU) is bad: an error for the input of that kind only.
    #[error("{kind} part: {error}")]
    Part {
        kind: crate::sample::SensorKind,
        error: Box<DecodeError>,
    },
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum EncodeError {
    #[error("{field} is {value}: refusing to encode a non-finite value")]
    NonFinite { field: String, value: f64 },
    #[error("{field} = {value} does not fit the wire type")]
    OutOfRange { field: String, value: f64 },
    #[error("MAVLink serialisation failed: {0}")]
    Mavlink(String),
    #[error("cannot encode: {0}")]
    Unsupported(String),
}

impl DecodeError {
    /// A short machine-readable kind for counters and logs.
    pub fn kind(&self) -> &'static str {
        match self {
            DecodeError::Truncated { .. } => "truncated",
            DecodeError::BadEncapsulation(_) => "bad_encapsulation",
            DecodeError::BadString { .. } => "bad_string",
            DecodeError::BadLength { .. } => "bad_length",
            DecodeError::TrailingBytes { .. } => "trailing_bytes",
            DecodeError::Unusable(_) => "unusable",
            DecodeError::NonFinite { .. } => "non_finite",
            DecodeError::OutOfRange { .. } => "out_of_range",
            DecodeError::Json(_) => "json",
            DecodeError::MissingField { .. } => "missing_field",
            DecodeError::WrongType { .. } => "wrong_type",
            DecodeError::UnsupportedMessage(_) => "unsupported_message",
            DecodeError::Mavlink(_) => "mavlink",
            DecodeError::NoRosType => "no_ros_type",
            DecodeError::NotUtf8 => "not_utf8",
            DecodeError::Part { error, .. } => error.kind(),
        }
    }
}

/// Checks shared by all codecs: a required float must be finite.
pub fn finite(field: &str, value: f64) -> Result<f64, DecodeError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(DecodeError::NonFinite {
            field: field.to_string(),
            value,
        })
    }
}

/// A required float must be finite and inside `[lo, hi]`.
pub fn in_range(
    field: &str,
    value: f64,
    lo: f64,
    hi: f64,
    reason: &'static str,
) -> Result<f64, DecodeError> {
    let v = finite(field, value)?;
    if v < lo || v > hi {
        return Err(DecodeError::OutOfRange {
            field: field.to_string(),
            value: v,
            reason,
        });
    }
    Ok(v)
}
