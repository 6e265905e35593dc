//! Typed ROS messages, field for field as the `.msg` definitions (ROS 2 names). Each
//! lists its fields once in [`WireFields::fields`]; that list reads and writes both CDR
//! and ROS 1 (see [`super::wire`]).

use super::wire::{Wire, WireFields};
use super::RosType;
use crate::codec::error::DecodeError;

/// A complete ROS message of one [`RosType`]: readable from and writable to both wire
/// formats.
pub trait RosMessage: WireFields + Default + Clone + std::fmt::Debug + PartialEq {
    const TYPE: RosType;

    /// Decode from CDR bytes including the 4-byte encapsulation header (either endianness).
    fn from_cdr(payload: &[u8]) -> Result<Self, DecodeError> {
        super::wire::Reader::cdr(payload)
            .and_then(super::wire::read)
            .map_err(qualify::<Self>)
    }

    /// Decode from ROS 1 serialised bytes (no length prefix).
    fn from_ros1(payload: &[u8]) -> Result<Self, DecodeError> {
        super::wire::read(super::wire::Reader::ros1(payload)).map_err(qualify::<Self>)
    }

    /// Little-endian CDR with the encapsulation header `00 01 00 00`.
    fn to_cdr(&self) -> Vec<u8> {
        super::wire::write(self, super::wire::Writer::cdr(false))
    }

    /// ROS 1 serialised bytes (no length prefix).
    fn to_ros1(&self) -> Vec<u8> {
        super::wire::write(self, super::wire::Writer::ros1())
    }
}

/// Wire errors name fields relative to the message (`header.frame_id`); put the message
/// type in front, as the other codecs' errors have it.
fn qualify<M: RosMessage>(e: DecodeError) -> DecodeError {
    let name = M::TYPE.ros2_name().rsplit('/').next().unwrap_or_default();
    match e {
        DecodeError::BadString { field } => DecodeError::BadString {
            field: format!("{name}.{field}"),
        },
        DecodeError::BadLength { field, len } => DecodeError::BadLength {
            field: format!("{name}.{field}"),
            len,
        },
        other => other,
    }
}

/// `std_msgs/Header`. `seq` exists on the ROS 1 wire only (ignored when writing CDR).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Header {
    /// Seconds. ROS 2: int32. ROS 1: uint32, stored here bit for bit (use
    /// [`Header::stamp_us`], which knows the difference).
    pub stamp_sec: i32,
    pub stamp_nanosec: u32,
    pub frame_id: String,
    pub seq: u32,
}

impl Header {
    /// The stamp in µs (`sec·10⁶ + nanosec/1000`), `None` when it is zero: ROS code
    /// leaves the stamp unset as 0, which is "no stamp", not 1970.
    pub fn stamp_us(&self, ros1: bool) -> Option<i64> {
        let sec = if ros1 {
            i64::from(self.stamp_sec as u32)
        } else {
            i64::from(self.stamp_sec)
        };
        if sec == 0 && self.stamp_nanosec == 0 {
            return None;
        }
        Some(sec * 1_000_000 + i64::from(self.stamp_nanosec / 1000))
    }
}

macro_rules! fields {
    ($ty:ty, |$s:ident, $w:ident| $body:block) => {
        impl WireFields for $ty {
            fn fields<W: Wire>(&mut self, $w: &mut W) -> Result<(), W::Error> {
                let $s = self;
                $body
                Ok(())
            }
        }
    };
}

macro_rules! message {
    ($ty:ty, $rt:ident) => {
        impl RosMessage for $ty {
            const TYPE: RosType = RosType::$rt;
        }
    };
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}
fields!(Vector3, |s, w| {
    w.prim(&mut s.x)?;
    w.prim(&mut s.y)?;
    w.prim(&mut s.z)?;
});

/// `geometry_msgs/Point` (same layout as Vector3, a position rather than a direction).
pub type Point = Vector3;

/// `geometry_msgs/Quaternion`. Default is the identity, as in ROS 2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}
impl Default for Quaternion {
    fn default() -> Self {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}
fields!(Quaternion, |s, w| {
    w.prim(&mut s.x)?;
    w.prim(&mut s.y)?;
    w.prim(&mut s.z)?;
    w.prim(&mut s.w)?;
});

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}
fields!(Pose, |s, w| {
    s.position.fields(w)?;
    s.orientation.fields(w)?;
});

/// `geometry_msgs/PoseWithCovariance`: covariance 6×6 row-major (x, y, z, rot x, rot y,
/// rot z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: [f64; 36],
}
impl Default for PoseWithCovariance {
    fn default() -> Self {
        PoseWithCovariance {
            pose: Pose::default(),
            covariance: [0.0; 36],
        }
    }
}
fields!(PoseWithCovariance, |s, w| {
    s.pose.fields(w)?;
    w.array(&mut s.covariance)?;
});

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}
fields!(Twist, |s, w| {
    s.linear.fields(w)?;
    s.angular.fields(w)?;
});

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: [f64; 36],
}
impl Default for TwistWithCovariance {
    fn default() -> Self {
        TwistWithCovariance {
            twist: Twist::default(),
            covariance: [0.0; 36],
        }
    }
}
fields!(TwistWithCovariance, |s, w| {
    s.twist.fields(w)?;
    w.array(&mut s.covariance)?;
});

/// `sensor_msgs/NavSatStatus`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NavSatStatus {
    /// -1 no fix, 0 fix, 1 SBAS fix, 2 GBAS fix.
    pub status: i8,
    /// Bit mask: 1 GPS, 2 GLONASS, 4 COMPASS, 8 GALILEO.
    pub service: u16,
}
impl NavSatStatus {
    pub const STATUS_NO_FIX: i8 = -1;
    pub const STATUS_FIX: i8 = 0;
    pub const STATUS_SBAS_FIX: i8 = 1;
    pub const STATUS_GBAS_FIX: i8 = 2;
    pub const SERVICE_GPS: u16 = 1;
}
fields!(NavSatStatus, |s, w| {
    w.prim(&mut s.status)?;
    w.prim(&mut s.service)?;
});

/// `sensor_msgs/NavSatFix`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NavSatFix {
    pub header: Header,
    pub status: NavSatStatus,
    pub latitude: f64,
    pub longitude: f64,
    pub altitude: f64,
    /// ENU, m², row-major (REP-145).
    pub position_covariance: [f64; 9],
    /// 0 unknown, 1 approximated, 2 diagonal known, 3 known.
    pub position_covariance_type: u8,
}
impl NavSatFix {
    pub const COVARIANCE_TYPE_UNKNOWN: u8 = 0;
    pub const COVARIANCE_TYPE_APPROXIMATED: u8 = 1;
    pub const COVARIANCE_TYPE_DIAGONAL_KNOWN: u8 = 2;
    pub const COVARIANCE_TYPE_KNOWN: u8 = 3;
}
fields!(NavSatFix, |s, w| {
    w.header(&mut s.header)?;
    s.status.fields(w)?;
    w.prim(&mut s.latitude)?;
    w.prim(&mut s.longitude)?;
    w.prim(&mut s.altitude)?;
    w.array(&mut s.position_covariance)?;
    w.prim(&mut s.position_covariance_type)?;
});
message!(NavSatFix, NavSatFix);

/// `sensor_msgs/Imu`. A covariance whose element 0 is -1 marks that quantity as not
/// provided; all zeros means "covariance unknown".
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Imu {
    pub header: Header,
    pub orientation: Quaternion,
    pub orientation_covariance: [f64; 9],
    pub angular_velocity: Vector3,
    pub angular_velocity_covariance: [f64; 9],
    pub linear_acceleration: Vector3,
    pub linear_acceleration_covariance: [f64; 9],
}
fields!(Imu, |s, w| {
    w.header(&mut s.header)?;
    s.orientation.fields(w)?;
    w.array(&mut s.orientation_covariance)?;
    s.angular_velocity.fields(w)?;
    w.array(&mut s.angular_velocity_covariance)?;
    s.linear_acceleration.fields(w)?;
    w.array(&mut s.linear_acceleration_covariance)?;
});
message!(Imu, Imu);

/// `sensor_msgs/Range`. `variance` is Jazzy's trailing field (absent up to Iron and in
/// ROS 1); written only when `Some`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Range {
    pub header: Header,
    /// 0 ultrasound, 1 infrared.
    pub radiation_type: u8,
    pub field_of_view: f32,
    pub min_range: f32,
    pub max_range: f32,
    /// m; +Inf = nothing within max_range, -Inf = closer than min_range (REP-117).
    pub range: f32,
    pub variance: Option<f32>,
}
impl Range {
    pub const ULTRASOUND: u8 = 0;
    pub const INFRARED: u8 = 1;
}
fields!(Range, |s, w| {
    w.header(&mut s.header)?;
    w.prim(&mut s.radiation_type)?;
    w.prim(&mut s.field_of_view)?;
    w.prim(&mut s.min_range)?;
    w.prim(&mut s.max_range)?;
    w.prim(&mut s.range)?;
    w.trailing_f32(&mut s.variance)?;
});
message!(Range, Range);

/// `sensor_msgs/FluidPressure`: a barometer's static pressure.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FluidPressure {
    pub header: Header,
    /// Absolute pressure, Pa (not hPa).
    pub fluid_pressure: f64,
    /// Pa²; 0 is "unknown".
    pub variance: f64,
}
fields!(FluidPressure, |s, w| {
    w.header(&mut s.header)?;
    w.prim(&mut s.fluid_pressure)?;
    w.prim(&mut s.variance)?;
});
message!(FluidPressure, FluidPressure);

/// `nav_msgs/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}
fields!(Odometry, |s, w| {
    w.header(&mut s.header)?;
    w.string("child_frame_id", &mut s.child_frame_id)?;
    s.pose.fields(w)?;
    s.twist.fields(w)?;
});
message!(Odometry, Odometry);

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}
fields!(PoseStamped, |s, w| {
    w.header(&mut s.header)?;
    s.pose.fields(w)?;
});
message!(PoseStamped, PoseStamped);

/// `geometry_msgs/PoseWithCovarianceStamped`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseWithCovarianceStamped {
    pub header: Header,
    pub pose: PoseWithCovariance,
}
fields!(PoseWithCovarianceStamped, |s, w| {
    w.header(&mut s.header)?;
    s.pose.fields(w)?;
});
message!(PoseWithCovarianceStamped, PoseWithCovarianceStamped);

/// `skyfuse_msgs/FlowTof` (`msg/FlowTof.msg`): the seed's optical flow + ToF module.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlowTof {
    pub header: Header,
    /// ToF height, m (NaN = no reading).
    pub distance: f32,
    pub strength: u8,
    pub precision: u8,
    pub tof_status: u8,
    /// Angular flow rate about body x, rad/s, not rotation-compensated.
    pub flow_vel_x: f32,
    /// Angular flow rate about body y, rad/s, not rotation-compensated.
    pub flow_vel_y: f32,
    pub flow_quality: u8,
    pub flow_status: u8,
}
fields!(FlowTof, |s, w| {
    w.header(&mut s.header)?;
    w.prim(&mut s.distance)?;
    w.prim(&mut s.strength)?;
    w.prim(&mut s.precision)?;
    w.prim(&mut s.tof_status)?;
    w.prim(&mut s.flow_vel_x)?;
    w.prim(&mut s.flow_vel_y)?;
    w.prim(&mut s.flow_quality)?;
    w.prim(&mut s.flow_status)?;
});
message!(FlowTof, FlowTof);

/// `geometry_msgs/PointStamped` (what skyfuse publishes its debug series as).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointStamped {
    pub header: Header,
    pub point: Point,
}
fields!(PointStamped, |s, w| {
    w.header(&mut s.header)?;
    s.point.fields(w)?;
});
message!(PointStamped, PointStamped);
