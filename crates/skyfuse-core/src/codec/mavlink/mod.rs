//! MAVLink in both forms skyfuse meets it on Zenoh:
//! - mavlink-server's JSON (`zenoh://` endpoint, keys `mavlink/<sys>/<comp>/<NAME>` and
//!   `mavlink/out`): rust-mavlink **0.16**'s serde form written by `json5::to_string`
//!   (see DESIGN.md "Inputs"), current and pre-0.16 (`{"bits":N}`, char[] as bytes) forms;
//! - raw MAVLink v1/v2 frames (`zenohraw://`, other bridges), CRC-checked.
//!
//! Both decode through one path: a message becomes a JSON object (JSON text after a
//! JSON5 pre-scan; a frame through rust-mavlink 0.21 and `serde_json::to_value`, whose
//! form matches 0.16's for everything read here, see the tests) and one mapping per
//! message turns it into a sample, NED/FRD → ENU/FLU, MAVLink units → SI.
//!
//! Needs rust-mavlink's `mav2-message-extensions` feature: without it 0.21 drops every
//! extension field (ODOMETRY `reset_counter`/`quality`, GPS_RAW_INT `h_acc`, OPTICAL_FLOW
//! `flow_rate_*`, VISION_POSITION_ESTIMATE `covariance`/`reset_counter`, ...), both when
//! parsing frames and when encoding.

mod fields;
mod frame;
mod json5;
mod map;
mod to_message;

pub use to_message::sample_to_message;

use crate::codec::error::{DecodeError, EncodeError};
use crate::sample::Decoded;
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::{MAVLinkV2MessageRaw, MavHeader, Message};
use fields::Fields;
use map::SensorMsg;
use serde_json::{Map, Value};

/// One mavlink-server JSON payload (`{"header":{...},"message":{"type":"NAME",...}}`):
/// its first sample. `Ok(None)` for valid messages that carry no sensor data we use
/// (HEARTBEAT, and any name we do not know: mavlink-server forwards every dialect's
/// messages). [`decode_json_into`] gives every sample (HIGHRES_IMU's barometer too).
pub fn decode_json(payload: &[u8]) -> Result<Option<Decoded>, DecodeError> {
    let mut out = Vec::with_capacity(2);
    decode_json_into(payload, &mut out)?;
    Ok(out.into_iter().next())
}

/// One mavlink-server JSON payload → every sample it carries, pushed to `out`: one, or
/// two for a HIGHRES_IMU with a pressure (an IMU and a barometer). Samples decoded
/// before an error are kept in `out`.
pub fn decode_json_into(payload: &[u8], out: &mut Vec<Decoded>) -> Result<(), DecodeError> {
    const WHAT: &str = "mavlink-server JSON";
    let text = std::str::from_utf8(payload).map_err(|_| DecodeError::NotUtf8)?;
    let strict = json5::to_strict_json(text);
    let root: Value =
        serde_json::from_str(&strict).map_err(|e| DecodeError::Json(e.to_string()))?;
    let wrong = |field: &str, expected: &'static str| DecodeError::WrongType {
        message: WHAT.to_string(),
        field: field.to_string(),
        expected,
    };
    let missing = |field: &str| DecodeError::MissingField {
        message: WHAT.to_string(),
        field: field.to_string(),
    };
    let root = root
        .as_object()
        .ok_or_else(|| wrong("(root)", "an object"))?;
    let header = root
        .get("header")
        .ok_or_else(|| missing("header"))?
        .as_object()
        .ok_or_else(|| wrong("header", "an object"))?;
    let id = |field: &str| -> Result<u8, DecodeError> {
        let v = header.get(field).ok_or_else(|| missing(field))?;
        v.as_u64()
            .and_then(|n| u8::try_from(n).ok())
            .ok_or_else(|| wrong(field, "an integer 0..=255"))
    };
    let origin = (id("system_id")?, id("component_id")?);
    let message = root
        .get("message")
        .ok_or_else(|| missing("message"))?
        .as_object()
        .ok_or_else(|| wrong("message", "an object"))?;
    let name = message
        .get("type")
        .ok_or_else(|| missing("message.type"))?
        .as_str()
        .ok_or_else(|| wrong("message.type", "a message name"))?;
    let Some(sensor) = SensorMsg::from_name(name) else {
        return Ok(());
    };
    map_message(sensor, message, false, origin, out)
}

/// Raw MAVLink v1/v2 bytes: one or more whole frames, CRC-checked against the common
/// dialect. Good frames are decoded and pushed to `out`; a bad frame (CRC, truncation,
/// stray bytes) costs only itself: the scan goes on and the first error is returned.
/// Messages outside the common dialect (ardupilotmega's on an ArduPilot link) are skipped.
pub fn decode_raw(payload: &[u8], out: &mut Vec<Decoded>) -> Result<(), DecodeError> {
    decode_raw_filtered(payload, &|_| true, out)
}

/// What a MAVLink message name is to skyfuse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageKind {
    /// A message skyfuse reads, as samples of these kinds (HIGHRES_IMU: IMU and
    /// barometer).
    Read(&'static [crate::sample::SensorKind]),
    /// A message of the dialect skyfuse does not read.
    NotRead,
    /// No MAVLink message at all (a typo in a key).
    Unknown,
}

/// What a MAVLink message named `name` becomes.
pub fn message_kind(name: &str) -> MessageKind {
    if let Some(m) = map::SensorMsg::ALL.iter().find(|m| m.name() == name) {
        return MessageKind::Read(m.kinds());
    }
    match <MavMessage as ::mavlink::Message>::message_id_from_name(name) {
        Some(_) => MessageKind::NotRead,
        None => MessageKind::Unknown,
    }
}

/// The messages skyfuse reads as samples of `kind`.
pub fn messages_of_kind(kind: crate::sample::SensorKind) -> Vec<&'static str> {
    map::SensorMsg::ALL
        .iter()
        .filter(|m| m.kinds().contains(&kind))
        .map(|m| m.name())
        .collect()
}

/// The message skyfuse reads whose name is nearest `name` (at most 3 edits), for a
/// typo's hint.
pub fn closest_message(name: &str) -> Option<&'static str> {
    map::SensorMsg::ALL
        .iter()
        .map(|m| (crate::codec::edit_distance(name, m.name()), m.name()))
        .filter(|(d, _)| *d <= 3)
        .min()
        .map(|(_, n)| n)
}

/// [`decode_raw`] keeping only the messages whose name `keep` accepts: a raw stream
/// carries every message, and an input usually wants one (HIGHRES_IMU, not also
/// SCALED_IMU and RAW_IMU of other IMUs), as a JSON input picks one by key.
pub fn decode_raw_filtered(
    payload: &[u8],
    keep: &dyn Fn(&str) -> bool,
    out: &mut Vec<Decoded>,
) -> Result<(), DecodeError> {
    frame::for_each_frame(payload, |fr| {
        let Some(sensor) = SensorMsg::from_id(fr.msg_id) else {
            return Ok(());
        };
        if !keep(sensor.name()) {
            return Ok(());
        }
        let msg = MavMessage::parse(fr.version, fr.msg_id, fr.payload)
            .map_err(|e| DecodeError::Mavlink(format!("{}: {e}", sensor.name())))?;
        let value = serde_json::to_value(&msg)
            .map_err(|e| DecodeError::Mavlink(format!("{}: {e}", sensor.name())))?;
        let obj = value.as_object().ok_or_else(|| {
            DecodeError::Mavlink(format!("{}: not a struct in serde form", sensor.name()))
        })?;
        let v1 = fr.version == ::mavlink::MavlinkVersion::V1;
        map_message(sensor, obj, v1, (fr.system_id, fr.component_id), out)
    })
}

/// A TIMESYNC read back from a link, with its whole frame (a signature check reads it).
#[derive(Debug, Clone, PartialEq)]
pub struct ReadTimesync {
    pub data: ::mavlink::dialects::common::TIMESYNC_DATA,
    pub frame: Vec<u8>,
}

/// The TIMESYNC messages in raw MAVLink bytes (CRC-checked frames; anything else is
/// skipped): what the output's links read back from the autopilot.
pub fn timesyncs(payload: &[u8]) -> Vec<ReadTimesync> {
    use ::mavlink::MessageData;
    let mut out = Vec::new();
    let _ = frame::for_each_frame(payload, |fr| {
        if fr.msg_id == ::mavlink::dialects::common::TIMESYNC_DATA::ID {
            if let Ok(MavMessage::TIMESYNC(data)) =
                MavMessage::parse(fr.version, fr.msg_id, fr.payload)
            {
                out.push(ReadTimesync {
                    data,
                    frame: fr.bytes.to_vec(),
                });
            }
        }
        Ok(())
    });
    out
}

/// TIMESYNCs from a byte stream (TCP, serial), where reads cut frames anywhere: the
/// cut-off tail of one read waits for the next. Holds at most one frame's bytes.
#[derive(Debug, Default)]
pub struct StreamTimesyncs {
    pending: Vec<u8>,
}

impl StreamTimesyncs {
    pub fn push(&mut self, bytes: &[u8]) -> Vec<ReadTimesync> {
        self.pending.extend_from_slice(bytes);
        let complete = frame::complete_len(&self.pending);
        let out = timesyncs(&self.pending[..complete]);
        self.pending.drain(..complete);
        // A cut-off frame is shorter than the largest one; more is junk that looked
        // like a start.
        if self.pending.len() > ::mavlink::consts::MAX_FRAME_SIZE {
            self.pending.clear();
        }
        out
    }
}

/// Signing state for one link: its key, its link id, and whether unsigned frames read
/// back are taken (rust-mavlink's `SigningData`; outgoing frames are signed).
pub fn signing_data(key: [u8; 32], link_id: u8, allow_unsigned: bool) -> ::mavlink::SigningData {
    ::mavlink::SigningData::from_config(::mavlink::SigningConfig::new(
        key,
        link_id,
        true,
        allow_unsigned,
    ))
}

/// The MAVLink signing clock at Unix time `unix_us`: 10 µs units since 2015-01-01
/// 00:00 UTC (SETUP_SIGNING's `initial_timestamp`, a signature's timestamp).
pub fn signing_timestamp(unix_us: i64) -> u64 {
    const EPOCH_2015_US: i64 = 1_420_070_400_000_000;
    (unix_us.saturating_sub(EPOCH_2015_US).max(0) / 10) as u64
}

/// MAVLink 2 signing (rust-mavlink's): a frame of `msg` signed with `signing` (its key,
/// link id and timestamp).
pub fn encode_raw_v2_signed(
    header: MavHeader,
    msg: &MavMessage,
    signing: &::mavlink::SigningData,
) -> Result<Vec<u8>, EncodeError> {
    check_header(&header)?;
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.serialize_message_for_signing(header, msg);
    signing.sign_message(&mut raw);
    Ok(raw.raw_bytes().to_vec())
}

/// Whether a frame (as [`timesyncs`] gives it) carries a signature `signing` accepts:
/// key, link stream and a timestamp newer than the stream's last. Unsigned and
/// MAVLink 1 frames do not (with `allow_unsigned` off).
pub fn signature_ok(frame: &[u8], signing: &::mavlink::SigningData) -> bool {
    if frame.first() != Some(&0xFD) || frame.len() > ::mavlink::consts::MAX_FRAME_SIZE {
        return false;
    }
    let mut buf = [0u8; ::mavlink::consts::MAX_FRAME_SIZE];
    buf[..frame.len()].copy_from_slice(frame);
    signing.verify_signature(&MAVLinkV2MessageRaw::from_bytes_unparsed(buf))
}

/// The message's samples to `out`: its own, then a second one some messages carry
/// (HIGHRES_IMU's pressure).
fn map_message(
    sensor: SensorMsg,
    message: &Map<String, Value>,
    v1: bool,
    origin: (u8, u8),
    out: &mut Vec<Decoded>,
) -> Result<(), DecodeError> {
    let fields = Fields::new(sensor.name(), message, v1);
    let mut push = |mapped: map::Mapped| {
        if let Some((stamp_us, data)) = mapped {
            out.push(Decoded {
                stamp_us,
                mav_origin: Some(origin),
                data,
            });
        }
    };
    push(map::decode(sensor, &fields)?);
    // A bad second part costs only itself: its error names its kind, so ingest charges
    // the input of that kind and keeps the first part for the other.
    let second = map::decode_second(sensor, &fields).map_err(|e| DecodeError::Part {
        kind: sensor.kinds().get(1).copied().unwrap_or(sensor.kind()),
        error: Box::new(e),
    })?;
    push(second);
    Ok(())
}

fn check_header(header: &MavHeader) -> Result<u8, EncodeError> {
    // mavlink-server reads the id as u8, and a MAVLink 2 frame with a larger one needs
    // rust-mavlink's non-standard 32-bit system id flag that autopilots reject.
    u8::try_from(header.system_id).map_err(|_| EncodeError::OutOfRange {
        field: "header.system_id".into(),
        value: f64::from(header.system_id),
    })
}

/// mavlink-server's exact JSON text for `msg` (to publish on `mavlink/in`): header
/// `{system_id, component_id, sequence, message_id}` and the message in rust-mavlink
/// 0.16's serde form as `json5::to_string` writes it (fields in wire order, extensions
/// last, `type` as `mavtype`, enums `{"type":NAME}`, bitmasks `"A | B"`, floats shortest
/// with `1.0` as `1`, NaN bare).
pub fn encode_json(header: MavHeader, msg: &MavMessage) -> Result<String, EncodeError> {
    let system_id = check_header(&header)?;
    let mut out = String::with_capacity(256);
    out.push_str(&format!(
        "{{\"header\":{{\"system_id\":{system_id},\"component_id\":{},\"sequence\":{},\"message_id\":{}}},\"message\":",
        header.component_id,
        header.sequence,
        msg.message_id()
    ));
    json5::to_json5(msg, &mut out)
        .map_err(|e| EncodeError::Mavlink(format!("{}: {e}", msg.message_name())))?;
    out.push('}');
    Ok(out)
}

/// `msg` as one MAVLink 2 frame (unsigned, payload zero-truncated as the spec requires).
pub fn encode_raw_v2(header: MavHeader, msg: &MavMessage) -> Result<Vec<u8>, EncodeError> {
    check_header(&header)?;
    let mut raw = MAVLinkV2MessageRaw::new();
    raw.serialize_message(header, msg);
    Ok(raw.raw_bytes().to_vec())
}

#[cfg(test)]
mod tests;
