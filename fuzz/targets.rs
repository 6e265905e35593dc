//! The decoders skyfuse exposes to the outside, one fuzz target each. Shared by the
//! mutation bench (`benches/fuzz.rs`, stable, in `cargo test`) and the coverage-guided
//! libFuzzer targets beside this file (`fuzz/fuzz_targets/`, `cargo fuzz run NAME`), so
//! both exercise exactly the same entry points.

use skyfuse::codec::{self, Format, RosType};

/// One decoder exposed to the outside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// ROS 2 CDR; the first byte picks the message type, so every type sees every seed.
    Ros2Cdr,
    /// ROS 1 serialisation, the type picked as for CDR.
    Ros1,
    /// mavlink-server's JSON messages.
    MavlinkJson,
    /// Raw MAVLink v1/v2 frames, several per payload.
    MavlinkRaw,
    /// skyfuse's own JSON samples (the simulator's, or any JSON publisher's).
    SkyfuseJson,
    /// The TOML configuration.
    ConfigToml,
    /// A websocket client message.
    WsClient,
    /// An MCAP file given to `skyfuse replay`.
    Mcap,
    /// An ArduPilot DataFlash log (`.bin`) given to `skyfuse replay`.
    Dataflash,
    /// The fault-control body (`POST /api/v1/sim/fault`).
    ControlBody,
    /// What the MAVLink output reads back from the autopilot (TIMESYNC), its signature
    /// check, and the clock estimate it feeds; bytes that are no frame drive the
    /// estimate directly as (tc1, ts1, arrival) triples.
    Timesync,
    /// PX4's px4_msgs; the first byte picks the type, the layout (found from the
    /// payload, or 1.14/1.15/1.16 named) and the alignment (XCDR2 in its top bit).
    Px4Msgs,
}

impl Target {
    pub const ALL: [Target; 12] = [
        Target::Ros2Cdr,
        Target::Ros1,
        Target::MavlinkJson,
        Target::MavlinkRaw,
        Target::SkyfuseJson,
        Target::ConfigToml,
        Target::WsClient,
        Target::Mcap,
        Target::Dataflash,
        Target::ControlBody,
        Target::Timesync,
        Target::Px4Msgs,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Target::Ros2Cdr => "ros2_cdr",
            Target::Ros1 => "ros1",
            Target::MavlinkJson => "mavlink_json",
            Target::MavlinkRaw => "mavlink_raw",
            Target::SkyfuseJson => "skyfuse_json",
            Target::ConfigToml => "config_toml",
            Target::WsClient => "ws_client",
            Target::Mcap => "mcap",
            Target::Dataflash => "dataflash",
            Target::ControlBody => "control_body",
            Target::Timesync => "timesync",
            Target::Px4Msgs => "px4_msgs",
        }
    }

    /// Decodes `bytes` as skyfuse would; true when they are accepted.
    pub fn decode(self, bytes: &[u8]) -> bool {
        let mut out = vec![];
        match self {
            Target::Ros2Cdr | Target::Ros1 => {
                let Some((&i, rest)) = bytes.split_first() else {
                    return false;
                };
                let format = if self == Target::Ros2Cdr {
                    Format::Ros2
                } else {
                    Format::Ros1
                };
                let ty = RosType::ALL[usize::from(i) % RosType::ALL.len()];
                if self == Target::Ros2Cdr {
                    // The same bytes as an rmw_zenoh attachment and a key's type chunk.
                    let _ = codec::ros::rmw_zenoh::Attachment::parse(rest);
                    if let Ok(text) = std::str::from_utf8(rest) {
                        let _ = codec::ros::rmw_zenoh::type_of_key(text);
                    }
                }
                codec::decode(format, Some(ty), rest, &mut out).is_ok()
            }
            Target::MavlinkJson => {
                codec::decode(Format::MavlinkJson, None, bytes, &mut out).is_ok()
            }
            Target::MavlinkRaw => codec::decode(Format::MavlinkRaw, None, bytes, &mut out).is_ok(),
            Target::SkyfuseJson => codec::decode(Format::Json, None, bytes, &mut out).is_ok(),
            Target::ConfigToml => std::str::from_utf8(bytes)
                .is_ok_and(|s| skyfuse::config::Config::from_toml_str(s, "fuzz").is_ok()),
            Target::WsClient => {
                serde_json::from_slice::<skyfuse::protocol::ClientMessage>(bytes).is_ok()
            }
            Target::Mcap => skyfuse::replay::mcap::parse(bytes, &mut |_, _| {}).is_ok(),
            Target::Dataflash => {
                let log = skyfuse::replay::dataflash::parse(bytes, &mut |_, _| {});
                !log.samples.is_empty()
            }
            Target::ControlBody => {
                serde_json::from_slice::<skyfuse::sim::faults::FaultRequest>(bytes).is_ok()
            }
            Target::Timesync => {
                let mut ts = skyfuse::output::timesync::TimeSync::default();
                let frames = codec::mavlink::timesyncs(bytes);
                let signing = codec::mavlink::signing_data([7; 32], 1, false);
                for (i, t) in frames.iter().enumerate() {
                    let _ = codec::mavlink::signature_ok(&t.frame, &signing);
                    let t = &t.data;
                    ts.on_message(t.tc1, t.ts1, t.ts1.wrapping_add(i as i64 * 1_000_000));
                }
                let word = |c: &[u8]| i64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
                for c in bytes.chunks_exact(24) {
                    ts.on_message(word(&c[..8]), word(&c[8..16]), word(&c[16..]));
                    let _ = ts.remote_ns(word(&c[16..]));
                }
                let _ = ts.status();
                // The same bytes as a stream cut at every 7th byte (TCP, serial): the
                // same TIMESYNCs, never more than one frame held back.
                let mut stream = codec::mavlink::StreamTimesyncs::default();
                let streamed: usize = bytes.chunks(7).map(|c| stream.push(c).len()).sum();
                assert!(
                    streamed <= frames.len() + 1,
                    "{streamed} > {}",
                    frames.len()
                );
                !frames.is_empty()
            }
            Target::Px4Msgs => {
                use codec::ros::px4::{self, Px4Msg, Px4Type, Px4Version};
                let Some((&i, rest)) = bytes.split_first() else {
                    return false;
                };
                let n = Px4Type::ALL.len();
                let low = usize::from(i & 0x7f);
                let ty = Px4Type::ALL[low % n];
                let version = match (low / n) % 4 {
                    0 => None,
                    v => Px4Version::ALL.get(v - 1).copied(),
                };
                let msg = Px4Msg {
                    ty,
                    version,
                    xcdr2: i & 0x80 != 0,
                };
                // The same bytes as a key's type hash, TimesyncStatus and the odometry
                // skyfuse writes (read back and checked).
                if let Ok(text) = std::str::from_utf8(rest) {
                    let _ = px4::version_of_hash(ty, text);
                }
                let _ = px4::decode_timesync_status(rest, msg.xcdr2);
                if let Ok(o) = px4::VehicleOdometry::from_cdr(rest) {
                    let _ = o.check();
                }
                px4::decode(msg, rest).is_ok_and(|d| d.is_some())
            }
        }
    }

    /// The prefix byte that makes [`Target::decode`] read the rest as px4_msgs `ty` in
    /// `version` (`None`: found from the payload), XCDR2 if `xcdr2`.
    pub fn px4_byte(
        ty: codec::ros::px4::Px4Type,
        version: Option<codec::ros::px4::Px4Version>,
        xcdr2: bool,
    ) -> u8 {
        use codec::ros::px4::{Px4Type, Px4Version};
        let t = Px4Type::ALL.iter().position(|x| *x == ty).unwrap_or(0);
        let v = version.map_or(0, |v| {
            1 + Px4Version::ALL.iter().position(|x| *x == v).unwrap_or(0)
        });
        (t + Px4Type::ALL.len() * v) as u8 | if xcdr2 { 0x80 } else { 0 }
    }

    /// The prefix byte that makes [`Target::decode`] read the rest as `ty` (ROS targets).
    pub fn ros_type_byte(ty: RosType) -> u8 {
        RosType::ALL.iter().position(|x| *x == ty).unwrap_or(0) as u8
    }
}
