//! ROS messages over Zenoh: ROS 2 CDR (zenoh-bridge-ros2dds) and ROS 1 serialisation
//! (zenoh-plugin-ros1), both directions.
//!
//! - [`decode_cdr`] / [`decode_ros1`]: payload → validated [`Decoded`] sample.
//! - [`msgs`]: typed messages; [`encode_cdr`] / [`encode_ros1`] write them (the
//!   simulator and the outputs publish with these).
//! - [`wire`]: the two wire formats behind one field visitor, so every message lists
//!   its fields once.
//!
//! Checked against rosbags (tests/py/gen_ros_vectors.py → tests/data/ros_vectors.json)
//! byte for byte, and against real zenoh-bridge-ros2dds captures.

mod convert;
pub mod msgs;
pub mod px4;
pub mod rmw_zenoh;
pub mod wire;

#[cfg(test)]
mod px4_tests;
#[cfg(test)]
mod tests;

pub use convert::header;

pub use msgs::{
    FlowTof, FluidPressure, Header, Imu, NavSatFix, NavSatStatus, Odometry, Point, PointStamped,
    Pose, PoseStamped, PoseWithCovariance, PoseWithCovarianceStamped, Quaternion, Range,
    RosMessage, Twist, TwistWithCovariance, Vector3,
};

use crate::codec::error::{DecodeError, EncodeError};
use crate::sample::{Decoded, Micros, SensorData};

/// The ROS message types skyfuse reads (all but PointStamped) and writes; `Px4`:
/// PX4's own px4_msgs (ROS 2 only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RosType {
    NavSatFix,
    Imu,
    Range,
    Odometry,
    PoseStamped,
    PoseWithCovarianceStamped,
    FlowTof,
    FluidPressure,
    PointStamped,
    Px4(px4::Px4Msg),
}

impl RosType {
    pub const ALL: [RosType; 9] = [
        RosType::NavSatFix,
        RosType::Imu,
        RosType::Range,
        RosType::Odometry,
        RosType::PoseStamped,
        RosType::PoseWithCovarianceStamped,
        RosType::FlowTof,
        RosType::FluidPressure,
        RosType::PointStamped,
    ];

    /// The kind of sample the message becomes.
    pub fn kind(self) -> crate::sample::SensorKind {
        use crate::sample::SensorKind as K;
        match self {
            RosType::NavSatFix => K::Gnss,
            RosType::Imu => K::Imu,
            RosType::Range => K::Range,
            RosType::Odometry
            | RosType::PoseStamped
            | RosType::PoseWithCovarianceStamped
            | RosType::PointStamped => K::Odometry,
            RosType::FlowTof => K::Flow,
            RosType::FluidPressure => K::Baro,
            // TimesyncStatus is never an input's type (see `from_name`).
            RosType::Px4(m) => m.ty.kind().unwrap_or(K::VehicleState),
        }
    }

    /// Whether it is one of PX4's px4_msgs.
    pub fn px4(self) -> Option<px4::Px4Msg> {
        match self {
            RosType::Px4(m) => Some(m),
            _ => None,
        }
    }

    /// From a ROS 2 (`sensor_msgs/msg/Imu`) or ROS 1 (`sensor_msgs/Imu`) type name.
    /// px4_msgs' TimesyncStatus is a clock, not an input's type.
    pub fn from_name(s: &str) -> Option<RosType> {
        RosType::ALL
            .into_iter()
            .find(|t| t.ros2_name() == s || t.ros1_name() == s)
            .or_else(|| {
                px4::Px4Type::from_name(s)
                    .filter(|t| t.kind().is_some())
                    .map(|t| RosType::Px4(px4::Px4Msg::new(t)))
            })
    }

    /// Every type name an input may give.
    pub fn input_names() -> Vec<&'static str> {
        RosType::ALL
            .iter()
            .filter(|t| **t != RosType::PointStamped)
            .map(|t| t.ros2_name())
            .chain(
                px4::Px4Type::ALL
                    .iter()
                    .filter(|t| t.kind().is_some())
                    .map(|t| t.ros2_name()),
            )
            .collect()
    }

    /// The same type (a px4_msgs layout or alignment aside).
    pub fn same_type(self, other: RosType) -> bool {
        self.ros2_name() == other.ros2_name()
    }

    pub fn ros2_name(self) -> &'static str {
        match self {
            RosType::NavSatFix => "sensor_msgs/msg/NavSatFix",
            RosType::Imu => "sensor_msgs/msg/Imu",
            RosType::Range => "sensor_msgs/msg/Range",
            RosType::Odometry => "nav_msgs/msg/Odometry",
            RosType::PoseStamped => "geometry_msgs/msg/PoseStamped",
            RosType::PoseWithCovarianceStamped => "geometry_msgs/msg/PoseWithCovarianceStamped",
            RosType::FlowTof => "skyfuse_msgs/msg/FlowTof",
            RosType::FluidPressure => "sensor_msgs/msg/FluidPressure",
            RosType::PointStamped => "geometry_msgs/msg/PointStamped",
            RosType::Px4(m) => m.ty.ros2_name(),
        }
    }

    /// (px4_msgs has no ROS 1 form: its ROS 2 name, which no ROS 1 key carries; config
    /// refuses it for ros1 inputs.)
    pub fn ros1_name(self) -> &'static str {
        match self {
            RosType::NavSatFix => "sensor_msgs/NavSatFix",
            RosType::Imu => "sensor_msgs/Imu",
            RosType::Range => "sensor_msgs/Range",
            RosType::Odometry => "nav_msgs/Odometry",
            RosType::PoseStamped => "geometry_msgs/PoseStamped",
            RosType::PoseWithCovarianceStamped => "geometry_msgs/PoseWithCovarianceStamped",
            RosType::FlowTof => "skyfuse_msgs/FlowTof",
            RosType::FluidPressure => "sensor_msgs/FluidPressure",
            RosType::PointStamped => "geometry_msgs/PointStamped",
            RosType::Px4(m) => m.ty.ros2_name(),
        }
    }

    /// The ROS 1 md5sum (genmsg: md5 of the definition with comments stripped and each
    /// nested type replaced by its own md5), as zenoh-plugin-ros1 puts it in its keys.
    /// The noetic values, checked against rosbags' `generate_msgdef` in the tests;
    /// FlowTof's is that of `msg/FlowTof.msg`.
    pub fn ros1_md5(self) -> &'static str {
        match self {
            RosType::NavSatFix => "2d3a8cd499b9b4a0249fb98fd05cfa48",
            RosType::Imu => "6a62c6daae103f4ff57a132d6f95cec2",
            RosType::Range => "c005c34273dc426c67a020a87bc24148",
            RosType::Odometry => "cd5e73d190d741a2f92e81eda573aca7",
            RosType::PoseStamped => "d3812c3cbc69362b77dc0b19b345f8f5",
            RosType::PoseWithCovarianceStamped => "953b798c0f514ff060a53a3498ce6246",
            RosType::FlowTof => "ecea7b08f378954af00280e435488252",
            RosType::FluidPressure => "804dc5cea1c5306d6a2eb80b9833befe",
            RosType::PointStamped => "c63aecb41bfdfd6b7e1fac37c7cbe7bf",
            RosType::Px4(_) => "",
        }
    }
}

impl std::fmt::Display for RosType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.ros2_name())
    }
}

// Serde form: the ROS 2 name; either name form is accepted, so configs can use ROS 1
// spelling too.
impl serde::Serialize for RosType {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.ros2_name())
    }
}

impl<'de> serde::Deserialize<'de> for RosType {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        RosType::from_name(&s).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "unknown ROS message type `{s}` (supported: {})",
                RosType::input_names().join(", ")
            ))
        })
    }
}

fn decode_with(ty: RosType, payload: &[u8], ros1: bool) -> Result<Decoded, DecodeError> {
    fn read<M: RosMessage>(payload: &[u8], ros1: bool) -> Result<M, DecodeError> {
        if ros1 {
            M::from_ros1(payload)
        } else {
            M::from_cdr(payload)
        }
    }
    match ty {
        RosType::NavSatFix => convert::navsatfix(&read(payload, ros1)?, ros1),
        RosType::Imu => convert::imu(&read(payload, ros1)?, ros1),
        RosType::Range => convert::range(&read(payload, ros1)?, ros1),
        RosType::Odometry => convert::odometry(&read(payload, ros1)?, ros1),
        RosType::PoseStamped => convert::pose_stamped(&read(payload, ros1)?, ros1),
        RosType::PoseWithCovarianceStamped => {
            convert::pose_with_covariance_stamped(&read(payload, ros1)?, ros1)
        }
        RosType::FlowTof => convert::flow_tof(&read(payload, ros1)?, ros1),
        RosType::FluidPressure => convert::fluid_pressure(&read(payload, ros1)?, ros1),
        RosType::PointStamped => Err(DecodeError::UnsupportedMessage(format!(
            "{} (skyfuse only publishes it)",
            ty.ros2_name()
        ))),
        RosType::Px4(_) if ros1 => Err(DecodeError::UnsupportedMessage(format!(
            "{} has no ROS 1 form",
            ty.ros2_name()
        ))),
        RosType::Px4(m) => px4::decode(m, payload)?.ok_or_else(|| {
            DecodeError::UnsupportedMessage(format!("{} is no sensor sample", ty.ros2_name()))
        }),
    }
}

/// Decode a ROS 2 message as zenoh-bridge-ros2dds delivers it: CDR with the 4-byte
/// encapsulation header, little- or big-endian.
pub fn decode_cdr(ty: RosType, payload: &[u8]) -> Result<Decoded, DecodeError> {
    decode_with(ty, payload, false)
}

/// Decode a ROS 1 serialised message as zenoh-plugin-ros1 delivers it (no length prefix).
pub fn decode_ros1(ty: RosType, payload: &[u8]) -> Result<Decoded, DecodeError> {
    decode_with(ty, payload, true)
}

/// The types skyfuse reads that a CDR payload decodes as, whole (nothing but end
/// padding left, every padding byte zero) and valid: the candidates for a topic whose type no bridge announces.
/// Usually one; several when the bytes happen to fit more than one layout.
pub fn cdr_types(payload: &[u8]) -> Vec<RosType> {
    fn whole<M: RosMessage>(p: &[u8]) -> bool {
        wire::Reader::cdr(p)
            .map(wire::Reader::zero_padding)
            .and_then(wire::read_whole::<M>)
            .is_ok()
    }
    RosType::ALL
        .into_iter()
        .filter(|&t| {
            let fits = match t {
                RosType::NavSatFix => whole::<NavSatFix>(payload),
                RosType::Imu => whole::<Imu>(payload),
                RosType::Range => whole::<Range>(payload),
                RosType::Odometry => whole::<Odometry>(payload),
                RosType::PoseStamped => whole::<PoseStamped>(payload),
                RosType::PoseWithCovarianceStamped => whole::<PoseWithCovarianceStamped>(payload),
                RosType::FlowTof => whole::<FlowTof>(payload),
                RosType::FluidPressure => whole::<FluidPressure>(payload),
                // Only published by skyfuse; px4_msgs are told by their keys, not sniffed.
                RosType::PointStamped | RosType::Px4(_) => false,
            };
            fits && decode_cdr(t, payload).is_ok()
        })
        .collect()
}

/// Little-endian CDR with the encapsulation header `00 01 00 00`.
pub fn encode_cdr<M: RosMessage>(msg: &M) -> Vec<u8> {
    msg.to_cdr()
}

/// ROS 1 serialisation (no length prefix), as zenoh-plugin-ros1 expects on its keys.
pub fn encode_ros1<M: RosMessage>(msg: &M) -> Vec<u8> {
    msg.to_ros1()
}

/// A sample as CDR message `ty` stamped `stamp_us` (the inverse of [`decode_cdr`] up to
/// what the message cannot carry).
pub fn encode_sample_cdr(
    ty: RosType,
    stamp_us: Micros,
    data: &SensorData,
) -> Result<Vec<u8>, EncodeError> {
    convert::encode_sample(ty, stamp_us, data, false)
}

/// A sample as ROS 1 message `ty` stamped `stamp_us`.
pub fn encode_sample_ros1(
    ty: RosType,
    stamp_us: Micros,
    data: &SensorData,
) -> Result<Vec<u8>, EncodeError> {
    convert::encode_sample(ty, stamp_us, data, true)
}
