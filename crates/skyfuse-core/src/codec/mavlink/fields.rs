//! Typed access to one MAVLink message held as a JSON object, the form both inputs
//! share: mavlink-server's JSON (after [`super::json5`] made it strict JSON) and raw
//! frames parsed by rust-mavlink and turned into a `serde_json::Value`.
//!
//! Conventions of that object (checked against both producers, see the module tests):
//! numbers are JSON numbers; a non-finite float is `null` (both `serde_json::to_value`
//! and our JSON5 pre-scan write NaN that way; the pre-scan writes ±Infinity as the
//! sentinel strings below so the error can say which; `to_value` cannot, so a raw
//! frame's ±inf is reported as NaN); enums are `{"type": NAME}`;
//! bitmasks are `"A | B"` or, from older mavlink-server releases, `{"bits": N}`.

use crate::codec::error::DecodeError;
use serde::de::DeserializeOwned;
use serde_json::{Map, Value};

/// What the JSON5 pre-scan writes for a bare `Infinity` / `-Infinity`.
pub(super) const POS_INF: &str = "\u{0}+Infinity";
pub(super) const NEG_INF: &str = "\u{0}-Infinity";

/// One message's fields.
pub(super) struct Fields<'a> {
    /// The MAVLink message name, for error messages.
    pub name: &'static str,
    obj: &'a Map<String, Value>,
    /// The message came in a MAVLink 1 frame, which never carries extension fields
    /// (rust-mavlink fills them with zeros; they are absent, not zero).
    no_extensions: bool,
}

impl<'a> Fields<'a> {
    pub fn new(name: &'static str, obj: &'a Map<String, Value>, no_extensions: bool) -> Self {
        Fields {
            name,
            obj,
            no_extensions,
        }
    }

    fn path(&self, key: &str) -> String {
        format!("{}.{key}", self.name)
    }

    fn missing(&self, key: &str) -> DecodeError {
        DecodeError::MissingField {
            message: self.name.to_string(),
            field: key.to_string(),
        }
    }

    fn wrong(&self, key: &str, expected: &'static str) -> DecodeError {
        DecodeError::WrongType {
            message: self.name.to_string(),
            field: key.to_string(),
            expected,
        }
    }

    fn get(&self, key: &str) -> Result<&'a Value, DecodeError> {
        self.obj.get(key).ok_or_else(|| self.missing(key))
    }

    fn get_ext(&self, key: &str) -> Option<&'a Value> {
        if self.no_extensions {
            None
        } else {
            self.obj.get(key)
        }
    }

    /// A float field as sent, NaN/±inf included (required: present).
    pub fn f32_any(&self, key: &str) -> Result<f64, DecodeError> {
        self.float_value(key, self.get(key)?)
    }

    /// A required float field that must be finite.
    pub fn f32(&self, key: &str) -> Result<f64, DecodeError> {
        let v = self.f32_any(key)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(DecodeError::NonFinite {
                field: self.path(key),
                value: v,
            })
        }
    }

    /// An extension float field: `None` when absent; the value may be non-finite.
    pub fn ext_f32(&self, key: &str) -> Result<Option<f64>, DecodeError> {
        self.get_ext(key)
            .map(|v| self.float_value(key, v))
            .transpose()
    }

    /// A required `float[N]` field, elements as sent (NaN included).
    pub fn f32_array<const N: usize>(&self, key: &str) -> Result<[f64; N], DecodeError> {
        self.float_array(key, self.get(key)?)
    }

    fn float_array<const N: usize>(&self, key: &str, v: &Value) -> Result<[f64; N], DecodeError> {
        const EXPECTED: &str = "an array of numbers of the field's length";
        let items = v.as_array().ok_or_else(|| self.wrong(key, EXPECTED))?;
        if items.len() != N {
            return Err(self.wrong(key, EXPECTED));
        }
        let mut out = [0.0; N];
        for (slot, item) in out.iter_mut().zip(items) {
            *slot = self.float_value(key, item)?;
        }
        Ok(out)
    }

    /// MAVLink floats are f32 on the wire. JSON text holds their shortest decimal form,
    /// which parses to a slightly different f64; rounding through f32 gives back the
    /// exact value, so the JSON and raw paths decode to identical numbers.
    fn float_value(&self, key: &str, v: &Value) -> Result<f64, DecodeError> {
        match v {
            Value::Number(n) => n
                .as_f64()
                .map(|x| f64::from(x as f32))
                .ok_or_else(|| self.wrong(key, "a number")),
            Value::Null => Ok(f64::NAN),
            Value::String(s) if s == POS_INF => Ok(f64::INFINITY),
            Value::String(s) if s == NEG_INF => Ok(f64::NEG_INFINITY),
            _ => Err(self.wrong(key, "a number")),
        }
    }

    /// A required unsigned integer field no larger than `max` (the wire type's range).
    pub fn uint(&self, key: &str, max: u64) -> Result<u64, DecodeError> {
        self.uint_value(key, self.get(key)?, max)
    }

    /// An extension unsigned integer field.
    pub fn ext_uint(&self, key: &str, max: u64) -> Result<Option<u64>, DecodeError> {
        self.get_ext(key)
            .map(|v| self.uint_value(key, v, max))
            .transpose()
    }

    fn uint_value(&self, key: &str, v: &Value, max: u64) -> Result<u64, DecodeError> {
        let n = v
            .as_u64()
            .ok_or_else(|| self.wrong(key, "an unsigned integer"))?;
        if n > max {
            return Err(DecodeError::OutOfRange {
                field: self.path(key),
                value: n as f64,
                reason: "larger than the field's wire type",
            });
        }
        Ok(n)
    }

    /// A required signed integer field within `[min, max]` (the wire type's range).
    pub fn int(&self, key: &str, min: i64, max: i64) -> Result<i64, DecodeError> {
        self.int_value(key, self.get(key)?, min, max)
    }

    /// An extension signed integer field.
    pub fn ext_int(&self, key: &str, min: i64, max: i64) -> Result<Option<i64>, DecodeError> {
        self.get_ext(key)
            .map(|v| self.int_value(key, v, min, max))
            .transpose()
    }

    fn int_value(&self, key: &str, v: &Value, min: i64, max: i64) -> Result<i64, DecodeError> {
        let n = v.as_i64().ok_or_else(|| self.wrong(key, "an integer"))?;
        if n < min || n > max {
            return Err(DecodeError::OutOfRange {
                field: self.path(key),
                value: n as f64,
                reason: "outside the field's wire type",
            });
        }
        Ok(n)
    }

    /// A required enum field `{"type": NAME}`: the entry's name.
    pub fn enum_name(&self, key: &str) -> Result<&'a str, DecodeError> {
        const EXPECTED: &str = "an enum entry {\"type\": NAME}";
        let v = self.get(key)?;
        v.as_object()
            .and_then(|o| o.get("type"))
            .and_then(Value::as_str)
            .ok_or_else(|| self.wrong(key, EXPECTED))
    }

    /// A required enum field read as rust-mavlink's enum type `T` (by entry name).
    pub fn enum_value<T: DeserializeOwned>(
        &self,
        key: &str,
        expected: &'static str,
    ) -> Result<T, DecodeError> {
        // Validate the shape first so a wrong shape and an unknown name both name the field.
        self.enum_name(key)?;
        T::deserialize(self.get(key)?).map_err(|_| self.wrong(key, expected))
    }

    /// A required bitmask field, `None` when it holds names we cannot resolve (only
    /// rust-mavlink's text form has names; unknown names mean newer definitions).
    /// `resolve` maps a flag name to its bits.
    pub fn flags(
        &self,
        key: &str,
        resolve: impl Fn(&str) -> Option<u64>,
    ) -> Result<Option<u64>, DecodeError> {
        const EXPECTED: &str = "a bitmask (\"A | B\" or {\"bits\": N})";
        match self.get(key)? {
            Value::String(s) => {
                let mut bits = 0u64;
                for part in s.split('|').map(str::trim).filter(|p| !p.is_empty()) {
                    let b = match part.strip_prefix("0x") {
                        Some(hex) => u64::from_str_radix(hex, 16).ok(),
                        None => resolve(part),
                    };
                    match b {
                        Some(b) => bits |= b,
                        None => return Ok(None),
                    }
                }
                Ok(Some(bits))
            }
            Value::Object(o) => o
                .get("bits")
                .and_then(Value::as_u64)
                .map(Some)
                .ok_or_else(|| self.wrong(key, EXPECTED)),
            // A bare number is what a hand-written publisher would send; accept it.
            Value::Number(n) => n
                .as_u64()
                .map(Some)
                .ok_or_else(|| self.wrong(key, EXPECTED)),
            _ => Err(self.wrong(key, EXPECTED)),
        }
    }
}
