//! Codecs: pure functions from bytes to [`Decoded`] samples (and back, for what we
//! publish). No I/O here; the Zenoh and MAVLink adapters only move bytes.
//!
//! | format        | module            | what produces it                                   |
//! |---------------|-------------------|----------------------------------------------------|
//! | `ros2`        | [`ros`] (CDR)     | zenoh-bridge-ros2dds / zenoh-plugin-ros2dds        |
//! | `ros1`        | [`ros`] (ROS 1)   | zenoh-plugin-ros1 / zenoh-bridge-ros1              |
//! | `mavlink-json`| [`mavlink`]       | bluerobotics mavlink-server `zenoh://` endpoint    |
//! | `mavlink-raw` | [`mavlink`]       | mavlink-server `zenohraw://`, any raw bridge       |
//! | `json`        | [`json`]          | hand-written publishers (schema in the README)     |
//!
//! [`dataflash`] holds the framing of ArduPilot's log files, shared by their reader
//! (`replay`) and the simulator's writer. [`sniff`] tells what an unknown payload is.

pub mod dataflash;
pub mod error;
pub mod json;
pub mod mavlink;
pub mod ros;
pub mod sniff;

pub use error::{DecodeError, EncodeError};

use crate::sample::Decoded;
use serde::{Deserialize, Serialize};

/// Wire format of an input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Format {
    Ros2,
    Ros1,
    MavlinkJson,
    MavlinkRaw,
    Json,
}

impl Format {
    pub fn as_str(self) -> &'static str {
        match self {
            Format::Ros2 => "ros2",
            Format::Ros1 => "ros1",
            Format::MavlinkJson => "mavlink-json",
            Format::MavlinkRaw => "mavlink-raw",
            Format::Json => "json",
        }
    }

    /// Whether the format needs a ROS message type to decode.
    pub fn needs_ros_type(self) -> bool {
        matches!(self, Format::Ros2 | Format::Ros1)
    }
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

pub use ros::RosType;

/// Decode one Zenoh payload of `format`. Good samples are pushed to `out`; for a
/// payload holding several MAVLink frames a bad frame costs only itself (the good
/// ones are still pushed and the first error is returned). Messages that are valid
/// but carry no sensor data we use (a HEARTBEAT) push nothing and return `Ok`.
pub fn decode(
    format: Format,
    ros_type: Option<RosType>,
    payload: &[u8],
    out: &mut Vec<Decoded>,
) -> Result<(), DecodeError> {
    match format {
        Format::Ros2 | Format::Ros1 => {
            let ty = ros_type.ok_or(DecodeError::NoRosType)?;
            if let (Format::Ros2, RosType::Px4(m)) = (format, ty) {
                // TimesyncStatus: valid, no sample.
                out.extend(ros::px4::decode(m, payload)?);
                return Ok(());
            }
            let d = if format == Format::Ros2 {
                ros::decode_cdr(ty, payload)?
            } else {
                ros::decode_ros1(ty, payload)?
            };
            out.push(d);
            Ok(())
        }
        Format::MavlinkJson => mavlink::decode_json_into(payload, out),
        Format::MavlinkRaw => mavlink::decode_raw(payload, out),
        Format::Json => {
            out.push(json::decode(payload)?);
            Ok(())
        }
    }
}

/// The MAVLink identity and sequence number stamped on an encoded MAVLink message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MavIdentity {
    pub system_id: u8,
    pub component_id: u8,
    pub sequence: u8,
}

/// An encoded sample ready for Zenoh.
#[derive(Debug, Clone, PartialEq)]
pub struct Encoded {
    pub payload: Vec<u8>,
    /// For MAVLink: the message name (mavlink-server keys end with it).
    pub mavlink_name: Option<&'static str>,
}

/// Encode a sample in `format`: the inverse of [`decode`], used by the simulator (and by
/// tests, to round-trip). `stamp_us` is written as the message's own stamp.
pub fn encode_sample(
    format: Format,
    ros_type: Option<RosType>,
    stamp_us: crate::sample::Micros,
    data: &crate::sample::SensorData,
    mav: MavIdentity,
) -> Result<Encoded, EncodeError> {
    let header = ::mavlink::MavHeader {
        system_id: mav.system_id.into(),
        component_id: mav.component_id,
        sequence: mav.sequence,
    };
    match format {
        Format::Ros2 | Format::Ros1 => {
            let ty = ros_type
                .ok_or_else(|| EncodeError::Unsupported("ROS format without a ROS type".into()))?;
            let payload = if format == Format::Ros2 {
                ros::encode_sample_cdr(ty, stamp_us, data)?
            } else {
                ros::encode_sample_ros1(ty, stamp_us, data)?
            };
            Ok(Encoded {
                payload,
                mavlink_name: None,
            })
        }
        Format::MavlinkJson | Format::MavlinkRaw => {
            let msg = mavlink::sample_to_message(stamp_us, data)?;
            let name = ::mavlink::Message::message_name(&msg);
            let payload = if format == Format::MavlinkJson {
                mavlink::encode_json(header, &msg)?.into_bytes()
            } else {
                mavlink::encode_raw_v2(header, &msg)?
            };
            Ok(Encoded {
                payload,
                mavlink_name: Some(name),
            })
        }
        Format::Json => Ok(Encoded {
            payload: json::encode(stamp_us, data)?.into_bytes(),
            mavlink_name: None,
        }),
    }
}

/// Levenshtein distance in characters: how far a typo is from a name (hints for keys
/// and message names).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}
