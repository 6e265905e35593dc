//! The flight recorder (MCAP files) and the Foxglove live view (Foxglove WebSocket), on
//! one set of Foxglove SDK channels.
//!
//! The data path never waits for either. Taps ([`crate::tap`]: [`Tap::input`],
//! [`Tap::pose`], …) put an item on a bounded queue with `try_send` (a full queue drops
//! the item and counts it), and one thread, `skyfuse-record`, logs the items to the SDK's channels. The SDK fans
//! them out to its sinks: the MCAP writer of the recorder (files rotated at a size or
//! age, see [`writer`]) and the WebSocket server (bounded per-client queues of its own).
//!
//! Channels: every input exactly as it arrived (topic = the Zenoh key, the payload's
//! bytes, log time = arrival; ROS 2 CDR with its `ros2msg` schema so Foxglove decodes
//! it), every input decoded (`/skyfuse/input/<id>`, JSON), the fused pose
//! (`/skyfuse/pose` foxglove.PoseInFrame, `/tf` foxglove.FrameTransform map → base_link,
//! `/skyfuse/location` foxglove.LocationFix once a GNSS origin exists, `/skyfuse/pose_json`
//! as on Zenoh), the VISION_POSITION_ESTIMATE frames sent (`/skyfuse/mavlink_out`),
//! health, events and the debug series. `skyfuse replay FILE.mcap` feeds the recorded
//! inputs back through ingest ([`replay`]).

pub mod replay;
pub mod ros2msg;
pub mod writer;

use serde::Serialize;

pub use crate::tap::{Tap, TapItem, TapStats};
pub use writer::{spawn, RecordError};

/// Channel metadata keys of a recorded input (read back by [`replay`]).
pub const META_INPUT: &str = "skyfuse.input";
pub const META_FORMAT: &str = "skyfuse.format";
pub const META_ROS_TYPE: &str = "skyfuse.ros_type";
/// Channel metadata of skyfuse's own outputs on input-like channels (ROS 2 CDR).
pub const META_OUTPUT: &str = "skyfuse.output";
/// Topics of the outputs.
pub const TOPIC_POSE: &str = "/skyfuse/pose";
pub const TOPIC_POSE_JSON: &str = "/skyfuse/pose_json";
pub const TOPIC_TF: &str = "/tf";
pub const TOPIC_LOCATION: &str = "/skyfuse/location";
pub const TOPIC_MAVLINK_OUT: &str = "/skyfuse/mavlink_out";
pub const TOPIC_HEALTH: &str = "/skyfuse/health";
pub const TOPIC_EVENTS: &str = "/skyfuse/events";
pub const TOPIC_DEBUG: &str = "/skyfuse/debug";
pub const TOPIC_INPUT_PREFIX: &str = "/skyfuse/input/";
/// Message encoding of raw MAVLink v2 frames (no schema: the frame names its message).
pub const MAVLINK_ENCODING: &str = "mavlink2";

/// The MCAP message encoding of an input format's payloads (what the recorder writes
/// and what replay routes back to inputs of that format).
pub fn channel_encoding(format: crate::codec::Format) -> &'static str {
    use crate::codec::Format;
    match format {
        Format::Ros2 => "cdr",
        Format::Ros1 => "ros1",
        Format::MavlinkJson | Format::Json => "json",
        Format::MavlinkRaw => MAVLINK_ENCODING,
    }
}

/// A name as it may stand in a file name or an input id: ASCII letters and digits, the
/// rest `_` (`camera/odom/sample` → `camera_odom_sample`).
pub fn name_safe(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

/// The recorder's part of `/api/v1/status`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RecorderStatus {
    /// Recording to MCAP files.
    pub recording: bool,
    pub dir: Option<String>,
    pub file: Option<String>,
    pub files: u64,
    pub bytes: u64,
    pub messages: u64,
    /// Items lost to a full queue (the data path never waits for the recorder).
    pub dropped: u64,
    pub error: Option<String>,
    /// The Foxglove WebSocket server's address, when it runs.
    pub foxglove: Option<String>,
    pub foxglove_clients: u64,
}
