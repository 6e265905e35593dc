//! Finding MAVLink v1/v2 frames in a byte buffer, CRC-checked against the common
//! dialect. Written here rather than using rust-mavlink's reader because that reader
//! skips bad frames silently, and we must report them (and keep going).

use crate::codec::error::DecodeError;
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::{calculate_crc, MavlinkVersion, Message};

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
/// MAVLink 2 incompatibility flag: the frame carries a 13-byte signature.
const IFLAG_SIGNED: u8 = 0x01;
const SIGNATURE_LEN: usize = 13;

/// One CRC-valid frame of a message the common dialect knows.
#[derive(Debug, Clone, Copy)]
pub(super) struct Frame<'a> {
    pub version: MavlinkVersion,
    pub msg_id: u32,
    pub system_id: u8,
    pub component_id: u8,
    pub payload: &'a [u8],
    /// The whole frame, signature included (what a signature check reads).
    pub bytes: &'a [u8],
}

enum Candidate<'a> {
    /// A good frame and its length.
    Frame(Frame<'a>, usize),
    /// A well-formed frame of a message the dialect does not define (ardupilotmega's
    /// AHRS2 and friends on an ArduPilot link): its CRC cannot be checked, skip it.
    Foreign(usize),
    /// Not a frame here (bad CRC, truncated, unknown flags): retry one byte on.
    Bad(DecodeError),
}

/// Call `each` for every good frame in `buf`, in order. A bad frame, a truncated tail,
/// bytes between frames and errors from `each` do not stop the scan; the first such
/// error is returned at the end.
pub(super) fn for_each_frame<'a>(
    buf: &'a [u8],
    mut each: impl FnMut(Frame<'a>) -> Result<(), DecodeError>,
) -> Result<(), DecodeError> {
    let mut first_error: Option<DecodeError> = None;
    let mut note = |e: DecodeError| {
        if first_error.is_none() {
            first_error = Some(e);
        }
    };
    let mut pos = 0;
    // Start of a run of bytes that belong to no frame, and whether it follows a bad
    // candidate (then it is that candidate's remains, already reported).
    let mut junk_start: Option<usize> = None;
    let mut after_bad = false;
    while let Some(&b) = buf.get(pos) {
        if b != STX_V1 && b != STX_V2 {
            junk_start.get_or_insert(pos);
            pos += 1;
            continue;
        }
        let candidate = candidate(buf, pos);
        if !matches!(candidate, Candidate::Bad(_)) {
            if let Some(start) = junk_start.take() {
                if !after_bad {
                    note(junk(start, pos));
                }
            }
            after_bad = false;
        }
        match candidate {
            Candidate::Frame(frame, len) => {
                if let Err(e) = each(frame) {
                    note(e);
                }
                pos += len;
            }
            Candidate::Foreign(len) => pos += len,
            Candidate::Bad(e) => {
                if let Some(start) = junk_start.take() {
                    if !after_bad {
                        note(junk(start, pos));
                    }
                }
                note(e);
                after_bad = true;
                junk_start = Some(pos);
                pos += 1;
            }
        }
    }
    if let Some(start) = junk_start {
        if !after_bad {
            note(junk(start, buf.len()));
        }
    }
    first_error.map_or(Ok(()), Err)
}

/// Where the complete part of a stream's bytes ends: the offset of a frame cut off by
/// the end of `buf` (its rest is still to come, on a TCP or serial link), else
/// `buf.len()`. Scans as [`for_each_frame`] does, so a STX inside a frame is no start.
pub(super) fn complete_len(buf: &[u8]) -> usize {
    let mut pos = 0;
    while let Some(&b) = buf.get(pos) {
        if b != STX_V1 && b != STX_V2 {
            pos += 1;
            continue;
        }
        match candidate(buf, pos) {
            Candidate::Frame(_, len) | Candidate::Foreign(len) => pos += len,
            Candidate::Bad(DecodeError::Truncated { .. }) => return pos,
            Candidate::Bad(_) => pos += 1,
        }
    }
    buf.len()
}

fn junk(start: usize, end: usize) -> DecodeError {
    DecodeError::Mavlink(format!(
        "{} byte(s) at offset {start} are not a MAVLink frame",
        end - start
    ))
}

fn candidate(buf: &[u8], pos: usize) -> Candidate<'_> {
    let rest = buf.get(pos..).unwrap_or_default();
    let v2 = rest.first() == Some(&STX_V2);
    // STX, len, then v1: seq sys comp id | v2: incompat compat seq sys comp id id id.
    let header_len = if v2 { 10 } else { 6 };
    let truncated = |needed: usize| {
        Candidate::Bad(DecodeError::Truncated {
            needed,
            offset: pos,
            len: buf.len(),
        })
    };
    let Some(header) = rest.get(..header_len) else {
        return truncated(header_len);
    };
    let byte = |i: usize| header.get(i).copied().unwrap_or_default();
    let payload_len = usize::from(byte(1));
    let (version, msg_id, system_id, component_id, signature_len) = if v2 {
        let incompat = byte(2);
        if incompat & !IFLAG_SIGNED != 0 {
            return Candidate::Bad(DecodeError::Mavlink(format!(
                "MAVLink 2 frame at offset {pos} has unsupported incompatibility flags {incompat:#04x}"
            )));
        }
        let id = u32::from_le_bytes([byte(7), byte(8), byte(9), 0]);
        let sig = if incompat & IFLAG_SIGNED != 0 {
            SIGNATURE_LEN
        } else {
            0
        };
        (MavlinkVersion::V2, id, byte(5), byte(6), sig)
    } else {
        (MavlinkVersion::V1, u32::from(byte(5)), byte(3), byte(4), 0)
    };
    let crc_end = header_len + payload_len;
    let frame_len = crc_end + 2 + signature_len;
    let (Some(crc_input), Some(crc_bytes), Some(payload)) = (
        rest.get(1..crc_end),
        rest.get(crc_end..crc_end + 2),
        rest.get(header_len..crc_end),
    ) else {
        return truncated(frame_len);
    };
    if rest.len() < frame_len {
        return truncated(frame_len);
    }
    let expected = u16::from_le_bytes([
        crc_bytes.first().copied().unwrap_or_default(),
        crc_bytes.get(1).copied().unwrap_or_default(),
    ]);
    // The dialect's CRC_EXTRA is 0 for ids it does not define, so check those by name.
    let crc_ok = calculate_crc(crc_input, MavMessage::extra_crc(msg_id)) == expected;
    if crc_ok || MavMessage::default_message_from_id(msg_id).is_some() {
        if !crc_ok {
            return Candidate::Bad(DecodeError::Mavlink(format!(
                "MAVLink {} frame at offset {pos} (message id {msg_id}): bad CRC",
                if v2 { 2 } else { 1 }
            )));
        }
        return Candidate::Frame(
            Frame {
                version,
                msg_id,
                system_id,
                component_id,
                payload,
                bytes: rest.get(..frame_len).unwrap_or_default(),
            },
            frame_len,
        );
    }
    // A message we do not know: believe its length only if another frame (or the end of
    // the buffer) follows, otherwise it was a stray STX byte.
    match rest.get(frame_len) {
        None | Some(&STX_V1) | Some(&STX_V2) => Candidate::Foreign(frame_len),
        Some(_) => Candidate::Bad(DecodeError::Mavlink(format!(
            "no MAVLink frame at offset {pos} (unknown message id {msg_id} and no frame after it)"
        ))),
    }
}
