//! px4_msgs: PX4's uORB topics as ROS 2 CDR, however they reach Zenoh.
//!
//! - uXRCE-DDS through zenoh-bridge-ros2dds (`/fmu/out/...`): XCDR1, as any ROS 2 type.
//! - rmw_zenoh-style keys (PX4 ≥ 1.17's zenoh module, ROS 2 nodes on rmw_zenoh): XCDR1,
//!   the key's RIHS01 type hash naming the layout.
//! - PX4 1.16's zenoh module on user-given keys: XCDR2 alignment (8-byte values aligned
//!   to 4), and the payload is the whole serialisation buffer, so bytes follow the
//!   message ([`Px4Msg::xcdr2`]).
//!
//! Field lists are the `.msg` declaration order of PX4 v1.14, v1.15 and v1.16 (the
//! versioned 1.16 names, `msg/versioned/`, have the same fields), checked byte for byte
//! against rosbags and CycloneDDS serialising those definitions
//! (tests/py/gen_px4_vectors.py → tests/data/px4_vectors.json). Values become the rows a
//! ULog has (`q[0]` ...), and the ULog replay's mapping turns them into samples, so a
//! live topic and its log agree.

use super::wire::{self, Prim, Wire, WireFields};
use crate::codec::error::DecodeError;
use crate::sample::{Decoded, SensorKind};
use crate::uorb::MessageMapper;
use std::sync::OnceLock;

/// The px4_msgs types skyfuse reads (and VehicleOdometry, which it also writes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Px4Type {
    SensorCombined,
    VehicleAttitude,
    VehicleAngularVelocity,
    VehicleOdometry,
    SensorGps,
    VehicleAirData,
    DistanceSensor,
    VehicleOpticalFlow,
    SensorOpticalFlow,
    VehicleLandDetected,
    VehicleStatus,
    TimesyncStatus,
}

/// A PX4 release whose field layouts are known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Px4Version {
    V1_14,
    V1_15,
    V1_16,
}

impl Px4Version {
    pub const ALL: [Px4Version; 3] = [Px4Version::V1_14, Px4Version::V1_15, Px4Version::V1_16];

    pub fn as_str(self) -> &'static str {
        match self {
            Px4Version::V1_14 => "1.14",
            Px4Version::V1_15 => "1.15",
            Px4Version::V1_16 => "1.16",
        }
    }
}

/// A px4_msgs type as one input receives it: the layout, if something named it (a type
/// hash, PX4 1.16's zenoh module), else found from the payload; and the alignment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Px4Msg {
    pub ty: Px4Type,
    pub version: Option<Px4Version>,
    /// PX4 1.16's zenoh module: XCDR2 alignment and the buffer's tail after the message.
    pub xcdr2: bool,
}

impl Px4Msg {
    pub fn new(ty: Px4Type) -> Self {
        Px4Msg {
            ty,
            version: None,
            xcdr2: false,
        }
    }

    /// As PX4 1.16's zenoh module publishes it.
    pub fn px4_zenoh(ty: Px4Type) -> Self {
        Px4Msg {
            ty,
            version: Some(Px4Version::V1_16),
            xcdr2: true,
        }
    }
}

impl Px4Type {
    pub const ALL: [Px4Type; 12] = [
        Px4Type::SensorCombined,
        Px4Type::VehicleAttitude,
        Px4Type::VehicleAngularVelocity,
        Px4Type::VehicleOdometry,
        Px4Type::SensorGps,
        Px4Type::VehicleAirData,
        Px4Type::DistanceSensor,
        Px4Type::VehicleOpticalFlow,
        Px4Type::SensorOpticalFlow,
        Px4Type::VehicleLandDetected,
        Px4Type::VehicleStatus,
        Px4Type::TimesyncStatus,
    ];

    pub fn ros2_name(self) -> &'static str {
        match self {
            Px4Type::SensorCombined => "px4_msgs/msg/SensorCombined",
            Px4Type::VehicleAttitude => "px4_msgs/msg/VehicleAttitude",
            Px4Type::VehicleAngularVelocity => "px4_msgs/msg/VehicleAngularVelocity",
            Px4Type::VehicleOdometry => "px4_msgs/msg/VehicleOdometry",
            Px4Type::SensorGps => "px4_msgs/msg/SensorGps",
            Px4Type::VehicleAirData => "px4_msgs/msg/VehicleAirData",
            Px4Type::DistanceSensor => "px4_msgs/msg/DistanceSensor",
            Px4Type::VehicleOpticalFlow => "px4_msgs/msg/VehicleOpticalFlow",
            Px4Type::SensorOpticalFlow => "px4_msgs/msg/SensorOpticalFlow",
            Px4Type::VehicleLandDetected => "px4_msgs/msg/VehicleLandDetected",
            Px4Type::VehicleStatus => "px4_msgs/msg/VehicleStatus",
            Px4Type::TimesyncStatus => "px4_msgs/msg/TimesyncStatus",
        }
    }

    pub fn from_name(s: &str) -> Option<Px4Type> {
        Px4Type::ALL.into_iter().find(|t| t.ros2_name() == s)
    }

    /// What its messages become; `None` for TimesyncStatus, a clock offset rather than
    /// a measurement (read by the px4_msgs odometry output).
    pub fn kind(self) -> Option<SensorKind> {
        Some(match self {
            Px4Type::SensorCombined | Px4Type::VehicleAngularVelocity => SensorKind::Imu,
            Px4Type::VehicleAttitude => SensorKind::Attitude,
            Px4Type::VehicleOdometry => SensorKind::Odometry,
            Px4Type::SensorGps => SensorKind::Gnss,
            Px4Type::VehicleAirData => SensorKind::Baro,
            Px4Type::DistanceSensor => SensorKind::Range,
            Px4Type::VehicleOpticalFlow | Px4Type::SensorOpticalFlow => SensorKind::Flow,
            Px4Type::VehicleLandDetected | Px4Type::VehicleStatus => SensorKind::VehicleState,
            Px4Type::TimesyncStatus => return None,
        })
    }

    /// The uORB topic of a ULog whose mapping its messages take.
    fn log_topic(self) -> Option<&'static str> {
        Some(match self {
            Px4Type::SensorCombined => "sensor_combined",
            Px4Type::VehicleAttitude => "vehicle_attitude",
            Px4Type::VehicleAngularVelocity => "vehicle_angular_velocity",
            Px4Type::VehicleOdometry => "vehicle_visual_odometry",
            Px4Type::SensorGps => "sensor_gps",
            Px4Type::VehicleAirData => "vehicle_air_data",
            Px4Type::DistanceSensor => "distance_sensor",
            Px4Type::VehicleOpticalFlow | Px4Type::SensorOpticalFlow => "vehicle_optical_flow",
            Px4Type::VehicleLandDetected => "vehicle_land_detected",
            Px4Type::VehicleStatus => "vehicle_status",
            Px4Type::TimesyncStatus => return None,
        })
    }
}

/// A primitive of the field tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum P {
    Bool,
    U8,
    I8,
    U16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

/// One field: name, primitive, array length (1 for a scalar).
#[derive(Debug, Clone, Copy)]
pub struct Field {
    pub name: &'static str,
    pub p: P,
    pub n: usize,
}

const fn f(name: &'static str, p: P) -> Field {
    Field { name, p, n: 1 }
}

const fn a(name: &'static str, p: P, n: usize) -> Field {
    Field { name, p, n }
}

use P::*;

const SENSOR_COMBINED: &[Field] = &[
    f("timestamp", U64),
    a("gyro_rad", F32, 3),
    f("gyro_integral_dt", U32),
    f("accelerometer_timestamp_relative", I32),
    a("accelerometer_m_s2", F32, 3),
    f("accelerometer_integral_dt", U32),
    f("accelerometer_clipping", U8),
    f("gyro_clipping", U8),
    f("accel_calibration_count", U8),
    f("gyro_calibration_count", U8),
];

const VEHICLE_ATTITUDE: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    a("q", F32, 4),
    a("delta_q_reset", F32, 4),
    f("quat_reset_counter", U8),
];

const VEHICLE_ANGULAR_VELOCITY: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    a("xyz", F32, 3),
    a("xyz_derivative", F32, 3),
];

const VEHICLE_ODOMETRY: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("pose_frame", U8),
    a("position", F32, 3),
    a("q", F32, 4),
    f("velocity_frame", U8),
    a("velocity", F32, 3),
    a("angular_velocity", F32, 3),
    a("position_variance", F32, 3),
    a("orientation_variance", F32, 3),
    a("velocity_variance", F32, 3),
    f("reset_counter", U8),
    f("quality", I8),
];

const SENSOR_GPS_1_14: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("device_id", U32),
    f("lat", I32),
    f("lon", I32),
    f("alt", I32),
    f("alt_ellipsoid", I32),
    f("s_variance_m_s", F32),
    f("c_variance_rad", F32),
    f("fix_type", U8),
    f("eph", F32),
    f("epv", F32),
    f("hdop", F32),
    f("vdop", F32),
    f("noise_per_ms", I32),
    f("automatic_gain_control", U16),
    f("jamming_state", U8),
    f("jamming_indicator", I32),
    f("spoofing_state", U8),
    f("vel_m_s", F32),
    f("vel_n_m_s", F32),
    f("vel_e_m_s", F32),
    f("vel_d_m_s", F32),
    f("cog_rad", F32),
    f("vel_ned_valid", Bool),
    f("timestamp_time_relative", I32),
    f("time_utc_usec", U64),
    f("satellites_used", U8),
    f("heading", F32),
    f("heading_offset", F32),
    f("heading_accuracy", F32),
    f("rtcm_injection_rate", F32),
    f("selected_rtcm_instance", U8),
];

/// 1.15 and 1.16: degrees and metres in float64, two RTCM fields at the end.
const SENSOR_GPS_1_15: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("device_id", U32),
    f("latitude_deg", F64),
    f("longitude_deg", F64),
    f("altitude_msl_m", F64),
    f("altitude_ellipsoid_m", F64),
    f("s_variance_m_s", F32),
    f("c_variance_rad", F32),
    f("fix_type", U8),
    f("eph", F32),
    f("epv", F32),
    f("hdop", F32),
    f("vdop", F32),
    f("noise_per_ms", I32),
    f("automatic_gain_control", U16),
    f("jamming_state", U8),
    f("jamming_indicator", I32),
    f("spoofing_state", U8),
    f("vel_m_s", F32),
    f("vel_n_m_s", F32),
    f("vel_e_m_s", F32),
    f("vel_d_m_s", F32),
    f("cog_rad", F32),
    f("vel_ned_valid", Bool),
    f("timestamp_time_relative", I32),
    f("time_utc_usec", U64),
    f("satellites_used", U8),
    f("heading", F32),
    f("heading_offset", F32),
    f("heading_accuracy", F32),
    f("rtcm_injection_rate", F32),
    f("selected_rtcm_instance", U8),
    f("rtcm_crc_failed", Bool),
    f("rtcm_msg_used", U8),
];

const VEHICLE_AIR_DATA_1_14: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("baro_device_id", U32),
    f("baro_alt_meter", F32),
    f("baro_temp_celcius", F32),
    f("baro_pressure_pa", F32),
    f("rho", F32),
    f("calibration_count", U8),
];

const VEHICLE_AIR_DATA_1_15: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("baro_device_id", U32),
    f("baro_alt_meter", F32),
    f("baro_temp_celcius", F32),
    f("baro_pressure_pa", F32),
    f("rho", F32),
    f("eas2tas", F32),
    f("calibration_count", U8),
];

const VEHICLE_AIR_DATA_1_16: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("baro_device_id", U32),
    f("baro_alt_meter", F32),
    f("baro_pressure_pa", F32),
    f("ambient_temperature", F32),
    f("temperature_source", U8),
    f("rho", F32),
    f("calibration_count", U8),
];

const DISTANCE_SENSOR_1_14: &[Field] = &[
    f("timestamp", U64),
    f("device_id", U32),
    f("min_distance", F32),
    f("max_distance", F32),
    f("current_distance", F32),
    f("variance", F32),
    f("signal_quality", I8),
    f("type", U8),
    f("h_fov", F32),
    f("v_fov", F32),
    a("q", F32, 4),
    f("orientation", U8),
];

const DISTANCE_SENSOR_1_16: &[Field] = &[
    f("timestamp", U64),
    f("device_id", U32),
    f("min_distance", F32),
    f("max_distance", F32),
    f("current_distance", F32),
    f("variance", F32),
    f("signal_quality", I8),
    f("type", U8),
    f("h_fov", F32),
    f("v_fov", F32),
    a("q", F32, 4),
    f("orientation", U8),
    f("mode", U8),
];

const VEHICLE_OPTICAL_FLOW: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("device_id", U32),
    a("pixel_flow", F32, 2),
    a("delta_angle", F32, 3),
    f("distance_m", F32),
    f("integration_timespan_us", U32),
    f("quality", U8),
    f("max_flow_rate", F32),
    f("min_ground_distance", F32),
    f("max_ground_distance", F32),
];

const SENSOR_OPTICAL_FLOW: &[Field] = &[
    f("timestamp", U64),
    f("timestamp_sample", U64),
    f("device_id", U32),
    a("pixel_flow", F32, 2),
    a("delta_angle", F32, 3),
    f("delta_angle_available", Bool),
    f("distance_m", F32),
    f("distance_available", Bool),
    f("integration_timespan_us", U32),
    f("quality", U8),
    f("error_count", U32),
    f("max_flow_rate", F32),
    f("min_ground_distance", F32),
    f("max_ground_distance", F32),
    f("mode", U8),
];

const VEHICLE_LAND_DETECTED: &[Field] = &[
    f("timestamp", U64),
    f("freefall", Bool),
    f("ground_contact", Bool),
    f("maybe_landed", Bool),
    f("landed", Bool),
    f("in_ground_effect", Bool),
    f("in_descend", Bool),
    f("has_low_throttle", Bool),
    f("vertical_movement", Bool),
    f("horizontal_movement", Bool),
    f("rotational_movement", Bool),
    f("close_to_ground_or_skipped_check", Bool),
    f("at_rest", Bool),
];

const VEHICLE_STATUS_1_14: &[Field] = &[
    f("timestamp", U64),
    f("armed_time", U64),
    f("takeoff_time", U64),
    f("arming_state", U8),
    f("latest_arming_reason", U8),
    f("latest_disarming_reason", U8),
    f("nav_state_timestamp", U64),
    f("nav_state_user_intention", U8),
    f("nav_state", U8),
    f("failure_detector_status", U16),
    f("hil_state", U8),
    f("vehicle_type", U8),
    f("failsafe", Bool),
    f("failsafe_and_user_took_over", Bool),
    f("gcs_connection_lost", Bool),
    f("gcs_connection_lost_counter", U8),
    f("high_latency_data_link_lost", Bool),
    f("is_vtol", Bool),
    f("is_vtol_tailsitter", Bool),
    f("in_transition_mode", Bool),
    f("in_transition_to_fw", Bool),
    f("system_type", U8),
    f("system_id", U8),
    f("component_id", U8),
    f("safety_button_available", Bool),
    f("safety_off", Bool),
    f("power_input_valid", Bool),
    f("usb_connected", Bool),
    f("open_drone_id_system_present", Bool),
    f("open_drone_id_system_healthy", Bool),
    f("parachute_system_present", Bool),
    f("parachute_system_healthy", Bool),
    f("avoidance_system_required", Bool),
    f("avoidance_system_valid", Bool),
    f("rc_calibration_in_progress", Bool),
    f("calibration_enabled", Bool),
    f("pre_flight_checks_pass", Bool),
];

const VEHICLE_STATUS_1_15: &[Field] = &[
    f("timestamp", U64),
    f("armed_time", U64),
    f("takeoff_time", U64),
    f("arming_state", U8),
    f("latest_arming_reason", U8),
    f("latest_disarming_reason", U8),
    f("nav_state_timestamp", U64),
    f("nav_state_user_intention", U8),
    f("nav_state", U8),
    f("executor_in_charge", U8),
    f("valid_nav_states_mask", U32),
    f("can_set_nav_states_mask", U32),
    f("failure_detector_status", U16),
    f("hil_state", U8),
    f("vehicle_type", U8),
    f("failsafe", Bool),
    f("failsafe_and_user_took_over", Bool),
    f("failsafe_defer_state", U8),
    f("gcs_connection_lost", Bool),
    f("gcs_connection_lost_counter", U8),
    f("high_latency_data_link_lost", Bool),
    f("is_vtol", Bool),
    f("is_vtol_tailsitter", Bool),
    f("in_transition_mode", Bool),
    f("in_transition_to_fw", Bool),
    f("system_type", U8),
    f("system_id", U8),
    f("component_id", U8),
    f("safety_button_available", Bool),
    f("safety_off", Bool),
    f("power_input_valid", Bool),
    f("usb_connected", Bool),
    f("open_drone_id_system_present", Bool),
    f("open_drone_id_system_healthy", Bool),
    f("parachute_system_present", Bool),
    f("parachute_system_healthy", Bool),
    f("avoidance_system_required", Bool),
    f("avoidance_system_valid", Bool),
    f("rc_calibration_in_progress", Bool),
    f("calibration_enabled", Bool),
    f("pre_flight_checks_pass", Bool),
];

/// 1.16 (`VehicleStatus` version 1): 1.15 without the two avoidance fields.
const VEHICLE_STATUS_1_16: &[Field] = &[
    f("timestamp", U64),
    f("armed_time", U64),
    f("takeoff_time", U64),
    f("arming_state", U8),
    f("latest_arming_reason", U8),
    f("latest_disarming_reason", U8),
    f("nav_state_timestamp", U64),
    f("nav_state_user_intention", U8),
    f("nav_state", U8),
    f("executor_in_charge", U8),
    f("valid_nav_states_mask", U32),
    f("can_set_nav_states_mask", U32),
    f("failure_detector_status", U16),
    f("hil_state", U8),
    f("vehicle_type", U8),
    f("failsafe", Bool),
    f("failsafe_and_user_took_over", Bool),
    f("failsafe_defer_state", U8),
    f("gcs_connection_lost", Bool),
    f("gcs_connection_lost_counter", U8),
    f("high_latency_data_link_lost", Bool),
    f("is_vtol", Bool),
    f("is_vtol_tailsitter", Bool),
    f("in_transition_mode", Bool),
    f("in_transition_to_fw", Bool),
    f("system_type", U8),
    f("system_id", U8),
    f("component_id", U8),
    f("safety_button_available", Bool),
    f("safety_off", Bool),
    f("power_input_valid", Bool),
    f("usb_connected", Bool),
    f("open_drone_id_system_present", Bool),
    f("open_drone_id_system_healthy", Bool),
    f("parachute_system_present", Bool),
    f("parachute_system_healthy", Bool),
    f("rc_calibration_in_progress", Bool),
    f("calibration_enabled", Bool),
    f("pre_flight_checks_pass", Bool),
];

const TIMESYNC_STATUS: &[Field] = &[
    f("timestamp", U64),
    f("source_protocol", U8),
    f("remote_timestamp", U64),
    f("observed_offset", I64),
    f("estimated_offset", I64),
    f("round_trip_time", U32),
];

/// The fields of `ty` in PX4 `version`, in wire order.
pub fn fields(ty: Px4Type, version: Px4Version) -> &'static [Field] {
    use Px4Version::*;
    match ty {
        Px4Type::SensorCombined => SENSOR_COMBINED,
        Px4Type::VehicleAttitude => VEHICLE_ATTITUDE,
        Px4Type::VehicleAngularVelocity => VEHICLE_ANGULAR_VELOCITY,
        Px4Type::VehicleOdometry => VEHICLE_ODOMETRY,
        Px4Type::SensorGps if version == V1_14 => SENSOR_GPS_1_14,
        Px4Type::SensorGps => SENSOR_GPS_1_15,
        Px4Type::VehicleAirData => match version {
            V1_14 => VEHICLE_AIR_DATA_1_14,
            V1_15 => VEHICLE_AIR_DATA_1_15,
            V1_16 => VEHICLE_AIR_DATA_1_16,
        },
        Px4Type::DistanceSensor if version == V1_16 => DISTANCE_SENSOR_1_16,
        Px4Type::DistanceSensor => DISTANCE_SENSOR_1_14,
        Px4Type::VehicleOpticalFlow => VEHICLE_OPTICAL_FLOW,
        Px4Type::SensorOpticalFlow => SENSOR_OPTICAL_FLOW,
        Px4Type::VehicleLandDetected => VEHICLE_LAND_DETECTED,
        Px4Type::VehicleStatus => match version {
            V1_14 => VEHICLE_STATUS_1_14,
            V1_15 => VEHICLE_STATUS_1_15,
            V1_16 => VEHICLE_STATUS_1_16,
        },
        Px4Type::TimesyncStatus => TIMESYNC_STATUS,
    }
}

/// The columns (in [`header`] order) of field `name`, found from the table: no names
/// built per message.
fn columns(fields: &[Field], name: &str) -> Option<std::ops::Range<usize>> {
    let mut start = 0;
    for f in fields {
        if f.name == name {
            return Some(start..start + f.n);
        }
        start += f.n;
    }
    None
}

/// Column names as a ULog has them: `q[0]` ... for arrays.
pub fn header(fields: &[Field]) -> Vec<String> {
    fields
        .iter()
        .flat_map(|f| {
            (0..f.n).map(move |i| {
                if f.n == 1 {
                    f.name.to_string()
                } else {
                    format!("{}[{i}]", f.name)
                }
            })
        })
        .collect()
}

/// The `.msg` text of the fields (constants and comments left out): the schema of an
/// MCAP recording of the topic.
pub fn definition(ty: Px4Type, version: Px4Version) -> String {
    fields(ty, version)
        .iter()
        .map(|f| {
            let p = match f.p {
                Bool => "bool",
                U8 => "uint8",
                I8 => "int8",
                U16 => "uint16",
                U32 => "uint32",
                I32 => "int32",
                U64 => "uint64",
                I64 => "int64",
                F32 => "float32",
                F64 => "float64",
            };
            match f.n {
                1 => format!("{p} {}\n", f.name),
                n => format!("{p}[{n}] {}\n", f.name),
            }
        })
        .collect()
}

/// The RIHS01 type hashes (REP 2011, rosidl's type description hash) of the px4_msgs
/// definitions: what rmw_zenoh keys and PX4 ≥ 1.17's zenoh module carry. Computed from
/// each release's `.msg` files (tests/py/gen_px4_vectors.py recomputes and checks them);
/// constants do not enter a hash, so a type unchanged since 1.14 has one. VehicleStatus
/// 1.16's matches PX4's own zenoh documentation.
const TYPE_HASHES: &[(Px4Type, &[Px4Version], &str)] = &[
    (
        Px4Type::SensorCombined,
        &Px4Version::ALL,
        "e8bb561edb3106315085519255a844e4420677c58bb5dece8f7e3005f9e91d4c",
    ),
    (
        Px4Type::VehicleAttitude,
        &Px4Version::ALL,
        "9af74ac6c01335f3a8612e3579d4eaa89a9d81550d933ed057f5d6252dc7e50c",
    ),
    (
        Px4Type::VehicleAngularVelocity,
        &Px4Version::ALL,
        "a9085b1ed1b428c4e7a6c7f5564f3c0b026de1c5791c3362dd1982092a7699da",
    ),
    (
        Px4Type::VehicleOdometry,
        &Px4Version::ALL,
        "4295b96ad312084aa35c84bdcec65ba2f57eb4f6a293d57d52d95acbe99ff817",
    ),
    (
        Px4Type::SensorGps,
        &[Px4Version::V1_14],
        "87df2d73ca9fbbd0607bdc3133c84433b09c58c635178dcd12c9b9fbff0ddcba",
    ),
    (
        Px4Type::SensorGps,
        &[Px4Version::V1_15, Px4Version::V1_16],
        "ee66c86474c0b31c6fc77453a139b217818a067e29d6837df7075e18fce827d7",
    ),
    (
        Px4Type::VehicleAirData,
        &[Px4Version::V1_14],
        "1f6f54224413e3955051d4cd682fbe1ccf9394ca97ae7754dfa4d53c452f2df8",
    ),
    (
        Px4Type::VehicleAirData,
        &[Px4Version::V1_15],
        "d0f92b40c3c2f253585943ea482d7359b36edad9cbd4b2d89ee46f264643f898",
    ),
    (
        Px4Type::VehicleAirData,
        &[Px4Version::V1_16],
        "099633ed6533a15304fa229913b12d1ee5e98ede1f8db726bdd419c4cc80efc2",
    ),
    (
        Px4Type::DistanceSensor,
        &[Px4Version::V1_14, Px4Version::V1_15],
        "68fda9f7cbef9479d4bf17008cb26bf5fa369261eb0f41b62edd06b8008bea62",
    ),
    (
        Px4Type::DistanceSensor,
        &[Px4Version::V1_16],
        "a8457d649dbcc726dce2558cf8a5732dc0b74d518bdb5e89248c0c515e8f80f5",
    ),
    (
        Px4Type::VehicleOpticalFlow,
        &Px4Version::ALL,
        "e579c73b4a86395a8c210bbb66389be0a2255f27db3dd2b2af7b7a12172c9737",
    ),
    (
        Px4Type::SensorOpticalFlow,
        &Px4Version::ALL,
        "25177fb9630317cd454c4f4e0281d8585eca7843fb74b23c978b73569f3a3a57",
    ),
    (
        Px4Type::VehicleLandDetected,
        &Px4Version::ALL,
        "ced22fc1699e2a3746a1fa86aa4b5463b42f5b9c97e7913063365a04d8324901",
    ),
    (
        Px4Type::VehicleStatus,
        &[Px4Version::V1_14],
        "be57906101209edfecd0a71169752e171ea6584b463aad21e5fa19d6999c6ef0",
    ),
    (
        Px4Type::VehicleStatus,
        &[Px4Version::V1_15],
        "cea1c125c9ecf78934ef9829ab070231fb3cd1b7cc502abcb66740363d1426c0",
    ),
    (
        Px4Type::VehicleStatus,
        &[Px4Version::V1_16],
        "828bddbb7d4c2aa6ad93757955f6893be1ec5d8f11885ec7715bcdd76b5226c9",
    ),
    (
        Px4Type::TimesyncStatus,
        &Px4Version::ALL,
        "e41cb05a033818ad8025bcc7b2a06ab536cb2f93f9d1f31362c2f9bcc641f161",
    ),
];

/// The `RIHS01_…` hash of `ty` in `version`.
pub fn type_hash(ty: Px4Type, version: Px4Version) -> String {
    let hex = TYPE_HASHES
        .iter()
        .find(|(t, vs, _)| *t == ty && vs.contains(&version))
        .map_or("", |(_, _, h)| h);
    format!("RIHS01_{hex}")
}

/// What a key's type hash says about the layout: `Ok(Some(v))` a known release,
/// `Ok(None)` no hash to go by (Humble's `TypeHashNotSupported`, a bridge key), an
/// error for a hash of no known release (a newer PX4 whose fields moved: decoding it by
/// an older list would give wrong numbers, not an error).
pub fn version_of_hash(ty: Px4Type, hash: &str) -> Result<Option<Px4Version>, DecodeError> {
    let Some(hex) = hash.strip_prefix("RIHS01_") else {
        return Ok(None);
    };
    match TYPE_HASHES.iter().find(|(t, _, h)| *t == ty && *h == hex) {
        // The newest release with it: its layout is the same in all of them.
        Some((_, vs, _)) => Ok(vs.iter().max().copied()),
        None => Err(DecodeError::UnsupportedMessage(format!(
            "{} with type hash {hash}: not the layout of PX4 1.14, 1.15 or 1.16 (a later release?)",
            ty.ros2_name()
        ))),
    }
}

/// The layout of an XCDR1 message of `ty` whose body (after the 4-byte header) is
/// `body` long, where nothing named it: every layout change from 1.14 to 1.16 changed
/// the length, except VehicleAirData 1.15 → 1.16, where the float at byte 24 is a
/// temperature in 1.15 and the pressure in Pa in 1.16.
fn detect_version(ty: Px4Type, body: &[u8]) -> Px4Version {
    use Px4Version::*;
    let len = body.len();
    match ty {
        Px4Type::SensorGps if len < 159 => V1_14,
        Px4Type::SensorGps => V1_15,
        Px4Type::VehicleAirData if len < 41 => V1_14,
        Px4Type::VehicleAirData => {
            let at24 = body
                .get(24..28)
                .and_then(|b| <[u8; 4]>::try_from(b).ok())
                .map_or(f32::NAN, f32::from_le_bytes);
            if (crate::sample::BARO_MIN_PA..=crate::sample::BARO_MAX_PA).contains(&f64::from(at24))
            {
                V1_16
            } else {
                V1_15
            }
        }
        Px4Type::DistanceSensor if len >= 58 => V1_16,
        Px4Type::DistanceSensor => V1_14,
        Px4Type::VehicleStatus if len < 80 => V1_14,
        Px4Type::VehicleStatus if len < 82 => V1_16,
        Px4Type::VehicleStatus => V1_15,
        _ => V1_16,
    }
}

fn read_prim<T: Prim + Default + Into<f64>>(r: &mut wire::Reader<'_>) -> Result<f64, DecodeError> {
    let mut v = T::default();
    r.prim(&mut v)?;
    Ok(v.into())
}

/// The values of one message, in [`header`] order, and the layout read.
pub fn read_values(msg: Px4Msg, payload: &[u8]) -> Result<(Px4Version, Vec<f64>), DecodeError> {
    let mut r = wire::Reader::cdr(payload)?;
    if msg.xcdr2 {
        r = r.xcdr2();
    }
    let body = payload.get(4..).unwrap_or_default();
    let version = msg.version.unwrap_or_else(|| detect_version(msg.ty, body));
    let fields = fields(msg.ty, version);
    let mut out = Vec::with_capacity(fields.iter().map(|f| f.n).sum());
    for field in fields {
        for _ in 0..field.n {
            out.push(match field.p {
                Bool | U8 => read_prim::<u8>(&mut r)?,
                I8 => read_prim::<i8>(&mut r)?,
                U16 => read_prim::<u16>(&mut r)?,
                U32 => read_prim::<u32>(&mut r)?,
                I32 => read_prim::<i32>(&mut r)?,
                // Microsecond stamps: exact in an f64 for 285 years of uptime.
                U64 => {
                    let mut v = 0u64;
                    r.prim(&mut v)?;
                    v as f64
                }
                I64 => {
                    let mut v = 0i64;
                    r.prim(&mut v)?;
                    v as f64
                }
                F32 => read_prim::<f32>(&mut r)?,
                F64 => read_prim::<f64>(&mut r)?,
            });
        }
    }
    // XCDR1 writers pad the end to 4 at most: more left over is a longer layout (a
    // later release) read by an older list. Where the layout was named (a type hash,
    // PX4's zenoh module, which sends its whole buffer) the tail says nothing.
    if msg.version.is_none() && r.remaining() > 3 {
        return Err(DecodeError::TrailingBytes {
            message: format!("{} (PX4 {} layout)", msg.ty.ros2_name(), version.as_str()),
            len: r.remaining(),
        });
    }
    Ok((version, out))
}

/// One mapping per type and layout, built on first use.
fn mapper(ty: Px4Type, version: Px4Version) -> Option<&'static Result<MessageMapper, String>> {
    type Mappers = Vec<((Px4Type, Px4Version), Result<MessageMapper, String>)>;
    static MAPPERS: OnceLock<Mappers> = OnceLock::new();
    let all = MAPPERS.get_or_init(|| {
        Px4Type::ALL
            .into_iter()
            .flat_map(|t| Px4Version::ALL.into_iter().map(move |v| (t, v)))
            .filter_map(|(t, v)| {
                let topic = t.log_topic()?;
                let m = MessageMapper::new(topic, header(fields(t, v)), t.ros2_name())
                    .map_err(|e| e.to_string());
                Some(((t, v), m))
            })
            .collect()
    });
    all.iter()
        .find(|(k, _)| *k == (ty, version))
        .map(|(_, m)| m)
}

/// Decode one px4_msgs message into a sample: its `timestamp` (PX4's clock, or the
/// uXRCE-DDS agent's when PX4 shifts it) and the data in skyfuse's conventions.
/// TimesyncStatus gives no sample (`Ok(None)`).
pub fn decode(msg: Px4Msg, payload: &[u8]) -> Result<Option<Decoded>, DecodeError> {
    let (version, mut values) = read_values(msg, payload)?;
    if msg.ty == Px4Type::SensorOpticalFlow {
        // The log mapping reads NaN as "not there"; this message has flags instead.
        let clear_unless = |values: &mut [f64], flag: &str, field: &str| {
            let (Some(f), Some(cols)) = (
                columns(SENSOR_OPTICAL_FLOW, flag),
                columns(SENSOR_OPTICAL_FLOW, field),
            ) else {
                return;
            };
            if values.get(f.start) == Some(&0.0) {
                for v in values.get_mut(cols).into_iter().flatten() {
                    *v = f64::NAN;
                }
            }
        };
        clear_unless(&mut values, "delta_angle_available", "delta_angle");
        clear_unless(&mut values, "distance_available", "distance_m");
    }
    let Some(m) = mapper(msg.ty, version) else {
        return Ok(None);
    };
    let m = m
        .as_ref()
        .map_err(|e| DecodeError::UnsupportedMessage(e.clone()))?;
    let (stamp_us, data) = m.map(&values).map_err(|e| {
        // "px4_msgs/msg/SensorGps:1:4: `lat`: ..." without the log's line and column.
        let text = e.to_string();
        let mut parts = text.splitn(4, ':');
        let (name, _line, _col, rest) = (parts.next(), parts.next(), parts.next(), parts.next());
        DecodeError::Unusable(match (name, rest) {
            (Some(n), Some(r)) => format!("{n} (PX4 {}):{r}", version.as_str()),
            _ => text,
        })
    })?;
    data.validate()
        .map_err(|e| DecodeError::Unusable(format!("{}: {e}", msg.ty.ros2_name())))?;
    Ok(Some(Decoded {
        stamp_us: Some(stamp_us),
        mav_origin: None,
        data,
    }))
}

/// A TimesyncStatus: PX4's clock minus the remote's (the uXRCE-DDS agent's or the
/// MAVLink peer's), µs, filtered; and the round trip, µs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimesyncStatus {
    pub timestamp_us: u64,
    pub source_protocol: u8,
    pub estimated_offset_us: i64,
    pub round_trip_us: u32,
}

pub fn decode_timesync_status(payload: &[u8], xcdr2: bool) -> Result<TimesyncStatus, DecodeError> {
    let msg = Px4Msg {
        ty: Px4Type::TimesyncStatus,
        version: Some(Px4Version::V1_16),
        xcdr2,
    };
    let (_, v) = read_values(msg, payload)?;
    let get = |i: usize| v.get(i).copied().unwrap_or(0.0);
    Ok(TimesyncStatus {
        timestamp_us: get(0) as u64,
        source_protocol: get(1) as u8,
        estimated_offset_us: get(4) as i64,
        round_trip_us: get(5) as u32,
    })
}

/// `px4_msgs/msg/VehicleOdometry` (1.14 – 1.17: one layout, the same in XCDR1 and
/// XCDR2), what PX4 reads on `/fmu/in/vehicle_visual_odometry`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VehicleOdometry {
    pub timestamp: u64,
    pub timestamp_sample: u64,
    pub pose_frame: u8,
    pub position: [f32; 3],
    /// Body FRD → `pose_frame`, Hamilton (w, x, y, z).
    pub q: [f32; 4],
    pub velocity_frame: u8,
    pub velocity: [f32; 3],
    pub angular_velocity: [f32; 3],
    pub position_variance: [f32; 3],
    pub orientation_variance: [f32; 3],
    pub velocity_variance: [f32; 3],
    pub reset_counter: u8,
    pub quality: i8,
}

pub const POSE_FRAME_NED: u8 = 1;
pub const POSE_FRAME_FRD: u8 = 2;
pub const VELOCITY_FRAME_NED: u8 = 1;
pub const VELOCITY_FRAME_FRD: u8 = 2;
pub const VELOCITY_FRAME_BODY_FRD: u8 = 3;

impl WireFields for VehicleOdometry {
    fn fields<W: Wire>(&mut self, w: &mut W) -> Result<(), W::Error> {
        w.prim(&mut self.timestamp)?;
        w.prim(&mut self.timestamp_sample)?;
        w.prim(&mut self.pose_frame)?;
        w.array(&mut self.position)?;
        w.array(&mut self.q)?;
        w.prim(&mut self.velocity_frame)?;
        w.array(&mut self.velocity)?;
        w.array(&mut self.angular_velocity)?;
        w.array(&mut self.position_variance)?;
        w.array(&mut self.orientation_variance)?;
        w.array(&mut self.velocity_variance)?;
        w.prim(&mut self.reset_counter)?;
        w.prim(&mut self.quality)
    }
}

impl VehicleOdometry {
    pub fn to_cdr(&self) -> Vec<u8> {
        wire::write(self, wire::Writer::cdr(false))
    }

    pub fn from_cdr(payload: &[u8]) -> Result<Self, DecodeError> {
        wire::read(wire::Reader::cdr(payload)?)
    }

    /// The checks px4-ros2-interface-lib makes before it publishes on
    /// `fmu/in/vehicle_visual_odometry` (`LocalPositionMeasurementInterface::update`),
    /// and EKF2's on the quaternion: what is set is finite, with a variance > 0, in a
    /// known frame; `timestamp_sample` is not 0; the quaternion is unit.
    pub fn check(&self) -> Result<(), String> {
        let set = |v: &[f32]| v.iter().all(|x| !x.is_nan());
        let position = set(&self.position);
        let velocity = set(&self.velocity);
        let attitude = set(&self.q);
        if !position && !velocity && !attitude {
            return Err("measurement values are all empty".into());
        }
        let positive = |v: &[f32]| v.iter().all(|x| *x > 0.0);
        for (is_set, var, what) in [
            (position, &self.position_variance, "position"),
            (velocity, &self.velocity_variance, "velocity"),
            (attitude, &self.orientation_variance, "orientation"),
        ] {
            if is_set && !positive(var) {
                return Err(format!("{what} variance {var:?} is not > 0"));
            }
        }
        if position && !(self.pose_frame == POSE_FRAME_NED || self.pose_frame == POSE_FRAME_FRD) {
            return Err(format!("unknown pose_frame {}", self.pose_frame));
        }
        if velocity && !(1..=3).contains(&self.velocity_frame) {
            return Err(format!("unknown velocity_frame {}", self.velocity_frame));
        }
        for (v, what) in [
            (&self.position[..], "position"),
            (&self.velocity[..], "velocity"),
            (&self.q[..], "q"),
        ] {
            if v.iter().any(|x| x.is_nan()) && !v.iter().all(|x| x.is_nan()) {
                return Err(format!("{what} {v:?} is partly NaN"));
            }
            if v.iter().any(|x| x.is_infinite()) {
                return Err(format!("{what} {v:?} is not finite"));
            }
        }
        if self.timestamp_sample == 0 {
            return Err("timestamp_sample is 0".into());
        }
        if attitude {
            let n = self
                .q
                .iter()
                .map(|x| f64::from(*x).powi(2))
                .sum::<f64>()
                .sqrt();
            if (n - 1.0).abs() > 1e-5 || self.q.iter().any(|x| x.abs() > 1.0 + 1e-5) {
                return Err(format!(
                    "q {:?} is not a unit quaternion (norm {n})",
                    self.q
                ));
            }
        }
        Ok(())
    }
}
