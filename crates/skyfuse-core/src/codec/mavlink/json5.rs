//! The two halves of mavlink-server's JSON5: reading it (a pre-scan that turns the only
//! JSON5 it ever writes, bare `NaN` / `Infinity` / `-Infinity`, into strict JSON) and
//! writing it exactly as `json5::to_string` (json5 0.4.1) does for rust-mavlink's serde
//! form, for the text we publish on `mavlink/in`.

use super::fields::{NEG_INF, POS_INF};
use serde::ser::{self, Serialize};
use std::borrow::Cow;
use std::fmt::{self, Write as _};

// ------------------------------------------------------------------------- reading

/// Replace bare `NaN` by `null` and `±Infinity` by sentinel strings, outside string
/// literals; everything else is left to serde_json (so other JSON5 syntax, which
/// mavlink-server never writes, is an error). Borrowed when there is nothing to replace.
pub(super) fn to_strict_json(text: &str) -> Cow<'_, str> {
    let bytes = text.as_bytes();
    let mut out: Option<String> = None;
    let mut copied = 0; // bytes of `text` already handled in `out`
    let mut in_string = false;
    let mut escaped = false;
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        if in_string {
            if escaped {
                escaped = false;
            } else if b == b'\\' {
                escaped = true;
            } else if b == b'"' {
                in_string = false;
            }
            i += 1;
            continue;
        }
        // Bytes, not `&text[i..]`: outside a string `i` may sit inside a multi-byte
        // character (invalid JSON, which serde_json will reject, but must not panic).
        let rest = &bytes[i..];
        let hit = match b {
            b'"' => {
                in_string = true;
                None
            }
            b'N' if rest.starts_with(b"NaN") => Some((3, "null".to_string())),
            b'I' if rest.starts_with(b"Infinity") => Some((8, sentinel(POS_INF))),
            b'-' if rest.starts_with(b"-Infinity") => Some((9, sentinel(NEG_INF))),
            _ => None,
        };
        match hit {
            Some((len, replacement)) => {
                let o = out.get_or_insert_with(|| String::with_capacity(text.len() + 16));
                o.push_str(&text[copied..i]);
                o.push_str(&replacement);
                i += len;
                copied = i;
            }
            None => i += 1,
        }
    }
    match out {
        Some(mut o) => {
            o.push_str(&text[copied..]);
            Cow::Owned(o)
        }
        None => Cow::Borrowed(text),
    }
}

fn sentinel(s: &str) -> String {
    // A JSON string literal holding `s` (its NUL written as \u0000).
    format!("\"{}\"", s.replace('\u{0}', "\\u0000"))
}

// ------------------------------------------------------------------------- writing

/// Serialise `value` as json5 0.4.1's `to_string` would: compact, keys quoted, floats by
/// Rust's `Display` (shortest round-trip, never an exponent, `1.0` as `1`), non-finite
/// floats as bare `NaN` / `Infinity` / `-Infinity`, strings escaped as json5 escapes them.
/// One deliberate difference: bitflags (the only thing in rust-mavlink that serialises
/// through `collect_str`) lose bits that name no flag, because rust-mavlink 0.16 (what
/// mavlink-server runs) truncates them on parse while 0.21 keeps them and prints `0x..`.
pub(super) fn to_json5<T: Serialize + ?Sized>(value: &T, out: &mut String) -> Result<(), Error> {
    value.serialize(&mut Writer { out })
}

#[derive(Debug)]
pub(super) struct Error(pub String);

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Error {}

impl ser::Error for Error {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        Error(msg.to_string())
    }
}

struct Writer<'a> {
    out: &'a mut String,
}

impl Writer<'_> {
    fn display(&mut self, v: impl fmt::Display) -> Result<(), Error> {
        write!(self.out, "{v}").map_err(|e| Error(e.to_string()))
    }

    fn float(&mut self, v: impl fmt::Display, nan: bool, inf: Option<bool>) -> Result<(), Error> {
        if nan {
            self.out.push_str("NaN");
        } else if let Some(positive) = inf {
            self.out
                .push_str(if positive { "Infinity" } else { "-Infinity" });
        } else {
            self.display(v)?;
        }
        Ok(())
    }

    fn string(&mut self, s: &str) {
        self.out.push('"');
        for c in s.chars() {
            match c {
                '"' => self.out.push_str("\\\""),
                '\\' => self.out.push_str("\\\\"),
                '/' => self.out.push_str("\\/"),
                '\n' => self.out.push_str("\\n"),
                '\r' => self.out.push_str("\\r"),
                '\t' => self.out.push_str("\\t"),
                '\u{8}' => self.out.push_str("\\b"),
                '\u{c}' => self.out.push_str("\\f"),
                c => self.out.push(c),
            }
        }
        self.out.push('"');
    }
}

/// Drop the `0x..` part bitflags 2 appends for bits that name no flag.
fn truncate_flags(text: &str) -> String {
    let names: Vec<&str> = text
        .split(" | ")
        .filter(|p| !p.is_empty() && !p.starts_with("0x"))
        .collect();
    names.join(" | ")
}

impl<'a, 'b> ser::Serializer for &'a mut Writer<'b> {
    type Ok = ();
    type Error = Error;
    type SerializeSeq = Compound<'a, 'b>;
    type SerializeTuple = Compound<'a, 'b>;
    type SerializeTupleStruct = Compound<'a, 'b>;
    type SerializeTupleVariant = Compound<'a, 'b>;
    type SerializeMap = Compound<'a, 'b>;
    type SerializeStruct = Compound<'a, 'b>;
    type SerializeStructVariant = Compound<'a, 'b>;

    fn serialize_bool(self, v: bool) -> Result<(), Error> {
        self.out.push_str(if v { "true" } else { "false" });
        Ok(())
    }
    fn serialize_i8(self, v: i8) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_i16(self, v: i16) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_i32(self, v: i32) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_i64(self, v: i64) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_u8(self, v: u8) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_u16(self, v: u16) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_u32(self, v: u32) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_u64(self, v: u64) -> Result<(), Error> {
        self.display(v)
    }
    fn serialize_f32(self, v: f32) -> Result<(), Error> {
        let inf = v.is_infinite().then_some(v > 0.0);
        self.float(v, v.is_nan(), inf)
    }
    fn serialize_f64(self, v: f64) -> Result<(), Error> {
        let inf = v.is_infinite().then_some(v > 0.0);
        self.float(v, v.is_nan(), inf)
    }
    fn serialize_char(self, v: char) -> Result<(), Error> {
        self.string(v.encode_utf8(&mut [0; 4]));
        Ok(())
    }
    fn serialize_str(self, v: &str) -> Result<(), Error> {
        self.string(v);
        Ok(())
    }
    fn serialize_bytes(self, v: &[u8]) -> Result<(), Error> {
        use ser::SerializeSeq;
        let mut seq = self.serialize_seq(Some(v.len()))?;
        for b in v {
            seq.serialize_element(b)?;
        }
        seq.end()
    }
    fn serialize_none(self) -> Result<(), Error> {
        self.out.push_str("null");
        Ok(())
    }
    fn serialize_some<T: Serialize + ?Sized>(self, value: &T) -> Result<(), Error> {
        value.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), Error> {
        self.out.push_str("null");
        Ok(())
    }
    fn serialize_unit_struct(self, _name: &'static str) -> Result<(), Error> {
        self.serialize_unit()
    }
    fn serialize_unit_variant(
        self,
        _name: &'static str,
        _index: u32,
        variant: &'static str,
    ) -> Result<(), Error> {
        self.string(variant);
        Ok(())
    }
    fn serialize_newtype_struct<T: Serialize + ?Sized>(
        self,
        _name: &'static str,
        value: &T,
    ) -> Result<(), Error> {
        value.serialize(self)
    }
    fn serialize_newtype_variant<T: Serialize + ?Sized>(
        self,
        _name: &'static str,
        _index: u32,
        variant: &'static str,
        value: &T,
    ) -> Result<(), Error> {
        self.out.push('{');
        self.string(variant);
        self.out.push(':');
        value.serialize(&mut *self)?;
        self.out.push('}');
        Ok(())
    }
    fn serialize_seq(self, _len: Option<usize>) -> Result<Compound<'a, 'b>, Error> {
        self.out.push('[');
        Ok(Compound::new(self, "]"))
    }
    fn serialize_tuple(self, len: usize) -> Result<Compound<'a, 'b>, Error> {
        self.serialize_seq(Some(len))
    }
    fn serialize_tuple_struct(
        self,
        _name: &'static str,
        len: usize,
    ) -> Result<Compound<'a, 'b>, Error> {
        self.serialize_seq(Some(len))
    }
    fn serialize_tuple_variant(
        self,
        _name: &'static str,
        _index: u32,
        variant: &'static str,
        _len: usize,
    ) -> Result<Compound<'a, 'b>, Error> {
        self.out.push('{');
        self.string(variant);
        self.out.push_str(":[");
        Ok(Compound::new(self, "]}"))
    }
    fn serialize_map(self, _len: Option<usize>) -> Result<Compound<'a, 'b>, Error> {
        self.out.push('{');
        Ok(Compound::new(self, "}"))
    }
    fn serialize_struct(self, _name: &'static str, _len: usize) -> Result<Compound<'a, 'b>, Error> {
        self.serialize_map(None)
    }
    fn serialize_struct_variant(
        self,
        _name: &'static str,
        _index: u32,
        variant: &'static str,
        _len: usize,
    ) -> Result<Compound<'a, 'b>, Error> {
        self.out.push('{');
        self.string(variant);
        self.out.push_str(":{");
        Ok(Compound::new(self, "}}"))
    }
    fn collect_str<T: fmt::Display + ?Sized>(self, value: &T) -> Result<(), Error> {
        self.string(&truncate_flags(&value.to_string()));
        Ok(())
    }
}

struct Compound<'a, 'b> {
    w: &'a mut Writer<'b>,
    first: bool,
    close: &'static str,
}

impl<'a, 'b> Compound<'a, 'b> {
    fn new(w: &'a mut Writer<'b>, close: &'static str) -> Self {
        Compound {
            w,
            first: true,
            close,
        }
    }

    fn comma(&mut self) {
        if !self.first {
            self.w.out.push(',');
        }
        self.first = false;
    }

    fn element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.comma();
        value.serialize(&mut *self.w)
    }

    fn field<T: Serialize + ?Sized>(&mut self, key: &str, value: &T) -> Result<(), Error> {
        self.comma();
        self.w.string(key);
        self.w.out.push(':');
        value.serialize(&mut *self.w)
    }

    fn finish(self) -> Result<(), Error> {
        self.w.out.push_str(self.close);
        Ok(())
    }
}

impl ser::SerializeSeq for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.element(value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeTuple for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.element(value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeTupleStruct for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_field<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.element(value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeTupleVariant for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_field<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.element(value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeMap for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_key<T: Serialize + ?Sized>(&mut self, key: &T) -> Result<(), Error> {
        self.comma();
        key.serialize(&mut *self.w)
    }
    fn serialize_value<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Error> {
        self.w.out.push(':');
        value.serialize(&mut *self.w)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeStruct for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_field<T: Serialize + ?Sized>(
        &mut self,
        key: &'static str,
        value: &T,
    ) -> Result<(), Error> {
        self.field(key, value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

impl ser::SerializeStructVariant for Compound<'_, '_> {
    type Ok = ();
    type Error = Error;
    fn serialize_field<T: Serialize + ?Sized>(
        &mut self,
        key: &'static str,
        value: &T,
    ) -> Result<(), Error> {
        self.field(key, value)
    }
    fn end(self) -> Result<(), Error> {
        self.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prescan_replaces_only_bare_words() {
        let t = r#"{"a":NaN,"b":[Infinity,-Infinity,1],"s":"NaN Infinity \" NaN","c":-1}"#;
        let j = to_strict_json(t);
        assert_eq!(
            j,
            r#"{"a":null,"b":["\u0000+Infinity","\u0000-Infinity",1],"s":"NaN Infinity \" NaN","c":-1}"#
        );
        let v: serde_json::Value = serde_json::from_str(&j).unwrap();
        assert_eq!(v["b"][0].as_str(), Some(POS_INF));
        assert_eq!(v["b"][1].as_str(), Some(NEG_INF));
        assert!(matches!(to_strict_json("{\"a\":1}"), Cow::Borrowed(_)));
        // Escaped backslash before the closing quote ends the string.
        assert_eq!(to_strict_json(r#"["\\",NaN]"#), r#"["\\",null]"#);
    }

    #[test]
    fn writes_floats_and_strings_like_json5() {
        let mut s = String::new();
        to_json5(
            &(
                1.0f32,
                0.1f32,
                -0.0f32,
                f32::NAN,
                f32::INFINITY,
                1e-7f32,
                1e20f64,
            ),
            &mut s,
        )
        .unwrap();
        assert_eq!(s, "[1,0.1,-0,NaN,Infinity,0.0000001,100000000000000000000]");
        s.clear();
        to_json5("a\"b/c\\\n\u{1}", &mut s).unwrap();
        assert_eq!(s, "\"a\\\"b\\/c\\\\\\n\u{1}\"");
        assert_eq!(truncate_flags("A | B | 0x100"), "A | B");
        assert_eq!(truncate_flags("0x100"), "");
        assert_eq!(truncate_flags(""), "");
    }
}
