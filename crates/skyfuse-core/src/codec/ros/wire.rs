//! The two ROS wire formats behind one interface, so each message lists its fields
//! once ([`WireFields::fields`]) and that one list reads and writes both formats.
//!
//! - ROS 2 CDR (XCDR1 as rmw/DDS send it): a 4-byte encapsulation header (`00 01` little-
//!   endian, `00 00` big-endian, then 2 option bytes), then every primitive aligned to its
//!   own size counted from the byte after that header; strings are a u32 length that
//!   counts the trailing NUL, the bytes, the NUL.
//! - ROS 1: packed little-endian, no alignment; strings are a u32 length (no NUL) and
//!   the bytes; `std_msgs/Header` has a `uint32 seq` before the stamp.
//!
//! Fixed-size arrays have no length prefix in either. Readers never panic: every access
//! is bounds-checked and a length is checked against what is left before anything is
//! copied.

use super::msgs::Header;
use crate::codec::error::DecodeError;
use std::convert::Infallible;

/// A fixed-size primitive of the ROS IDL.
pub trait Prim: Copy {
    const SIZE: usize;
    /// From exactly `SIZE` bytes; `None` if `b` has another length.
    fn from_bytes(b: &[u8], big_endian: bool) -> Option<Self>;
    fn put(self, out: &mut Vec<u8>, big_endian: bool);
}

macro_rules! prim {
    ($($t:ty),*) => {$(
        impl Prim for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            fn from_bytes(b: &[u8], big_endian: bool) -> Option<Self> {
                let a: [u8; std::mem::size_of::<$t>()] = b.try_into().ok()?;
                Some(if big_endian { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) })
            }
            fn put(self, out: &mut Vec<u8>, big_endian: bool) {
                if big_endian {
                    out.extend_from_slice(&self.to_be_bytes());
                } else {
                    out.extend_from_slice(&self.to_le_bytes());
                }
            }
        }
    )*};
}
prim!(u8, i8, u16, u32, i32, u64, i64, f32, f64);

/// One direction of one wire format. Implemented by [`Reader`] (fills the fields it is
/// given) and [`Writer`] (serialises them). Field names are only needed where a read can
/// fail for a reason other than running out of bytes (strings).
pub trait Wire {
    type Error;
    /// ROS 1 layout (packed, Header with seq) rather than CDR.
    fn is_ros1(&self) -> bool;
    fn prim<T: Prim>(&mut self, v: &mut T) -> Result<(), Self::Error>;
    fn string(&mut self, field: &'static str, v: &mut String) -> Result<(), Self::Error>;
    /// A `float32` that newer distros appended to a message (Jazzy's Range.variance):
    /// read if the bytes are there, written if `Some`.
    fn trailing_f32(&mut self, v: &mut Option<f32>) -> Result<(), Self::Error>;

    fn array<T: Prim, const N: usize>(&mut self, v: &mut [T; N]) -> Result<(), Self::Error> {
        for x in v.iter_mut() {
            self.prim(x)?;
        }
        Ok(())
    }

    /// `std_msgs/Header`. ROS 1: seq, time (u32 sec, u32 nsec), frame_id. ROS 2: stamp
    /// (i32 sec, u32 nanosec), frame_id. ROS 1's u32 seconds are kept bit for bit in the
    /// i32 field (same 4 bytes); [`Header::stamp_us`] reads them back as unsigned.
    fn header(&mut self, h: &mut Header) -> Result<(), Self::Error> {
        if self.is_ros1() {
            self.prim(&mut h.seq)?;
        }
        self.prim(&mut h.stamp_sec)?;
        self.prim(&mut h.stamp_nanosec)?;
        self.string("header.frame_id", &mut h.frame_id)
    }
}

/// Something made of wire fields: a message or a nested type (Vector3, Pose, ...).
pub trait WireFields {
    /// Visit every field in wire order.
    fn fields<W: Wire>(&mut self, w: &mut W) -> Result<(), W::Error>;
}

/// CDR encapsulation header bytes: representation id (2) + options (2).
const ENCAPSULATION_LEN: usize = 4;

pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    /// Where CDR alignment counts from (just after the encapsulation header).
    origin: usize,
    big_endian: bool,
    ros1: bool,
    /// Padding must be zero bytes (what writers put there): only when sniffing an
    /// unknown payload, where it tells layouts apart that otherwise both fit.
    zero_padding: bool,
    /// Largest alignment: 8 in XCDR1 (what rmw and DDS send), 4 in XCDR2 (PX4 1.16's
    /// zenoh module).
    max_align: usize,
}

impl<'a> Reader<'a> {
    /// The same reader, aligning 8-byte values to 4 as XCDR2 does.
    pub fn xcdr2(mut self) -> Self {
        self.max_align = 4;
        self
    }

    /// The same reader, refusing non-zero padding.
    pub fn zero_padding(mut self) -> Self {
        self.zero_padding = true;
        self
    }

    /// A CDR reader after checking the encapsulation header (plain CDR only: ROS 2 does
    /// not use parameter lists or XCDR2 for these types).
    pub fn cdr(payload: &'a [u8]) -> Result<Self, DecodeError> {
        let head = payload
            .get(..ENCAPSULATION_LEN)
            .ok_or(DecodeError::Truncated {
                needed: ENCAPSULATION_LEN,
                offset: 0,
                len: payload.len(),
            })?;
        let big_endian = match head {
            [0x00, 0x01, _, _] => false,
            [0x00, 0x00, _, _] => true,
            [a, b, ..] => return Err(DecodeError::BadEncapsulation([*a, *b])),
            _ => return Err(DecodeError::BadEncapsulation([0, 0])),
        };
        Ok(Reader {
            buf: payload,
            pos: ENCAPSULATION_LEN,
            origin: ENCAPSULATION_LEN,
            big_endian,
            ros1: false,
            zero_padding: false,
            max_align: 8,
        })
    }

    pub fn ros1(payload: &'a [u8]) -> Self {
        Reader {
            buf: payload,
            pos: 0,
            origin: 0,
            big_endian: false,
            ros1: true,
            zero_padding: false,
            max_align: 8,
        }
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    fn truncated(&self, needed: usize) -> DecodeError {
        DecodeError::Truncated {
            needed,
            offset: self.pos,
            len: self.buf.len(),
        }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        let end = self.pos.checked_add(n).ok_or_else(|| self.truncated(n))?;
        let s = self
            .buf
            .get(self.pos..end)
            .ok_or_else(|| self.truncated(n))?;
        self.pos = end;
        Ok(s)
    }

    /// Padding needed before a CDR primitive of `size` bytes (none in ROS 1).
    fn padding(&self, size: usize) -> usize {
        if self.ros1 || size <= 1 {
            return 0;
        }
        let size = size.min(self.max_align);
        let rel = self.pos.saturating_sub(self.origin);
        (size - rel % size) % size
    }

    fn align(&mut self, size: usize) -> Result<(), DecodeError> {
        let pad = self.padding(size);
        let strict = self.zero_padding;
        let at = self.pos;
        match self.take(pad)? {
            bytes if strict && bytes.iter().any(|&b| b != 0) => Err(DecodeError::BadLength {
                field: format!("(padding at byte {at})"),
                len: pad,
            }),
            _ => Ok(()),
        }
    }
}

impl Wire for Reader<'_> {
    type Error = DecodeError;

    fn is_ros1(&self) -> bool {
        self.ros1
    }

    fn prim<T: Prim>(&mut self, v: &mut T) -> Result<(), DecodeError> {
        self.align(T::SIZE)?;
        let b = self.take(T::SIZE)?;
        *v = T::from_bytes(b, self.big_endian).ok_or_else(|| self.truncated(T::SIZE))?;
        Ok(())
    }

    fn string(&mut self, field: &'static str, v: &mut String) -> Result<(), DecodeError> {
        let mut len = 0u32;
        self.prim(&mut len)?;
        let len = usize::try_from(len).map_err(|_| DecodeError::BadLength {
            field: field.to_string(),
            len: usize::MAX,
        })?;
        // Checked before copying, so a hostile length cannot make us allocate.
        if len > self.remaining() {
            return Err(DecodeError::BadLength {
                field: field.to_string(),
                len,
            });
        }
        let bytes = self.take(len)?;
        let text = if self.ros1 {
            bytes
        } else {
            match bytes.split_last() {
                Some((0, text)) => text,
                // A zero length is not valid CDR, but some writers send it for "".
                None => &[],
                Some(_) => {
                    return Err(DecodeError::BadString {
                        field: field.to_string(),
                    })
                }
            }
        };
        *v = std::str::from_utf8(text)
            .map_err(|_| DecodeError::BadString {
                field: field.to_string(),
            })?
            .to_string();
        Ok(())
    }

    fn trailing_f32(&mut self, v: &mut Option<f32>) -> Result<(), DecodeError> {
        // An older message simply ends here; a DDS writer may also pad the end to a
        // multiple of 4, which is fewer than the 4 bytes a float needs after alignment.
        let pad = self.padding(4);
        if self.remaining() >= pad + 4 {
            let mut x = 0f32;
            self.prim(&mut x)?;
            *v = Some(x);
        } else {
            *v = None;
        }
        Ok(())
    }
}

pub struct Writer {
    buf: Vec<u8>,
    origin: usize,
    big_endian: bool,
    ros1: bool,
}

impl Writer {
    /// CDR with its encapsulation header (options zero, no end padding: as rosbags and
    /// zenoh-bridge-ros2dds' own publishers write it; readers take the length from the
    /// sample, not from the options).
    pub fn cdr(big_endian: bool) -> Self {
        let buf = vec![0x00, if big_endian { 0x00 } else { 0x01 }, 0x00, 0x00];
        Writer {
            buf,
            origin: ENCAPSULATION_LEN,
            big_endian,
            ros1: false,
        }
    }

    pub fn ros1() -> Self {
        Writer {
            buf: Vec::new(),
            origin: 0,
            big_endian: false,
            ros1: true,
        }
    }

    pub fn finish(self) -> Vec<u8> {
        self.buf
    }

    fn align(&mut self, size: usize) {
        if self.ros1 || size <= 1 {
            return;
        }
        let rel = self.buf.len().saturating_sub(self.origin);
        let pad = (size - rel % size) % size;
        self.buf.resize(self.buf.len() + pad, 0);
    }
}

impl Wire for Writer {
    type Error = Infallible;

    fn is_ros1(&self) -> bool {
        self.ros1
    }

    fn prim<T: Prim>(&mut self, v: &mut T) -> Result<(), Infallible> {
        self.align(T::SIZE);
        v.put(&mut self.buf, self.big_endian);
        Ok(())
    }

    fn string(&mut self, _field: &'static str, v: &mut String) -> Result<(), Infallible> {
        let bytes = v.as_bytes();
        let with_nul = if self.ros1 { 0 } else { 1 };
        // Lengths beyond u32 cannot be expressed on either wire; a frame id that long is
        // not a real input, so saturate rather than make encoding fallible.
        let mut len = u32::try_from(bytes.len() + with_nul).unwrap_or(u32::MAX);
        self.prim(&mut len)?;
        self.buf.extend_from_slice(bytes);
        if !self.ros1 {
            self.buf.push(0);
        }
        Ok(())
    }

    fn trailing_f32(&mut self, v: &mut Option<f32>) -> Result<(), Infallible> {
        if let Some(x) = v {
            self.prim(x)?;
        }
        Ok(())
    }
}

/// Read a whole `M` from a reader (trailing bytes, such as DDS end padding, are ignored).
pub fn read<M: WireFields + Default>(mut r: Reader<'_>) -> Result<M, DecodeError> {
    let mut m = M::default();
    m.fields(&mut r)?;
    Ok(m)
}

/// Read a whole message: as [`read`], and an error when more than the end padding of a
/// DDS writer (under 4 bytes) is left, so a shorter type does not read a longer one's
/// prefix (what sniffing a payload of unknown type needs).
pub fn read_whole<M: WireFields + Default>(mut r: Reader<'_>) -> Result<M, DecodeError> {
    let mut m = M::default();
    m.fields(&mut r)?;
    let tail = r.buf.get(r.pos..).unwrap_or_default();
    if tail.len() > 3 || (r.zero_padding && tail.iter().any(|&b| b != 0)) {
        return Err(DecodeError::BadLength {
            field: "(end)".into(),
            len: r.remaining(),
        });
    }
    Ok(m)
}

/// Write `m` with `w` and return the bytes.
pub fn write<M: WireFields + Clone>(m: &M, mut w: Writer) -> Vec<u8> {
    // The visitor takes `&mut` so the same field list can fill a message when reading;
    // writing only reads the fields, on a copy.
    let mut m = m.clone();
    match m.fields(&mut w) {
        Ok(()) => w.finish(),
        Err(never) => match never {},
    }
}
