//! ArduPilot DataFlash framing: what the log reader (`replay::dataflash`) and the
//! simulator's writer (`sim::dataflash`) agree on. Each record is `A3 95 <type>` and
//! its fields packed little-endian; FMT records (type 128, 89 bytes) define the others.

/// The two bytes every record starts with.
pub const HEAD1: u8 = 0xA3;
pub const HEAD2: u8 = 0x95;
/// The FMT record's own type and length (fixed: the format has to start somewhere).
pub const FMT_TYPE: u8 = 0x80;
pub const FMT_LEN: usize = 89;

/// Byte size of one field of DataFlash type `c`; `None` for a character ArduPilot
/// does not write.
pub fn field_size(c: u8) -> Option<usize> {
    Some(match c {
        b'b' | b'B' | b'M' => 1,
        b'h' | b'H' | b'c' | b'C' | b'g' => 2,
        b'i' | b'I' | b'e' | b'E' | b'f' | b'L' | b'n' => 4,
        b'q' | b'Q' | b'd' => 8,
        b'N' => 16,
        b'Z' | b'a' => 64,
        _ => return None,
    })
}
