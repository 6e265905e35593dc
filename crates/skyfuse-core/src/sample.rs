//! The one internal sample model every codec produces and the estimator consumes.
//!
//! Conventions (fixed here so nothing downstream has to guess):
//! - SI units: metres, seconds, radians, m/s, rad/s, m/s².
//! - World frame: local ENU (REP-103). Body frame: FLU. Codecs of NED/FRD sources
//!   (MAVLink) convert on the way in; ROS sources are taken as REP-103 already.
//! - Time: microseconds. `stamp_us` is the sensor's own clock (ROS header stamp,
//!   MAVLink `time_usec`/`time_boot_ms`), `arrival_us` the host clock when the bytes
//!   arrived. The two are kept apart because sensors disagree about epochs.
//! - Values a sensor marks as unknown (MAVLink NaN, ROS covariance type unknown) are
//!   `None`, never a sentinel number.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector2, Vector3};
use serde::Serialize;
use std::sync::Arc;

/// Microseconds.
pub type Micros = i64;

/// A decoded sensor sample with its provenance.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Config id of the input that produced it (e.g. `gps`, `t265`).
    pub source: Arc<str>,
    /// Sensor time in µs (the message's own stamp), if the message has one.
    pub stamp_us: Option<Micros>,
    /// Host time in µs at arrival.
    pub arrival_us: Micros,
    pub data: SensorData,
}

/// What a codec decodes from one message: the measurement and the message's stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    pub stamp_us: Option<Micros>,
    /// MAVLink sender (system id, component id); `None` for ROS and JSON sources.
    pub mav_origin: Option<(u8, u8)>,
    pub data: SensorData,
}

#[derive(Debug, Clone, PartialEq)]
#[allow(clippy::large_enum_variant)] // samples are moved once, through a queue
pub enum SensorData {
    Imu(Imu),
    Attitude(Attitude),
    Gnss(GnssFix),
    Flow(OpticalFlow),
    Range(Range),
    /// Boxed: with its two 6×6 covariances it is twice the size of any other sample, and
    /// samples are moved (sorted, logged, queued) by value.
    Odometry(Box<Odometry>),
    /// The autopilot's own estimate (LOCAL_POSITION_NED, GLOBAL_POSITION_INT): shown
    /// for comparison only, never fused (it would close a feedback loop through our VPE).
    AutopilotEstimate(AutopilotEstimate),
    /// The autopilot's armed and landed state (HEARTBEAT, EXTENDED_SYS_STATE; PX4's
    /// actuator_armed, vehicle_land_detected): tells the estimator the vehicle is on the
    /// ground when nothing else aids it.
    VehicleState(VehicleState),
    /// A barometer: static pressure, a height with a slowly wandering offset.
    Baro(Baro),
}

/// The sensor kinds, as named in config and the status API.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    Imu,
    Attitude,
    Gnss,
    Flow,
    Range,
    Odometry,
    AutopilotEstimate,
    VehicleState,
    Baro,
}

impl SensorData {
    pub fn kind(&self) -> SensorKind {
        match self {
            SensorData::Imu(_) => SensorKind::Imu,
            SensorData::Attitude(_) => SensorKind::Attitude,
            SensorData::Gnss(_) => SensorKind::Gnss,
            SensorData::Flow(_) => SensorKind::Flow,
            SensorData::Range(_) => SensorKind::Range,
            SensorData::Odometry(_) => SensorKind::Odometry,
            SensorData::AutopilotEstimate(_) => SensorKind::AutopilotEstimate,
            SensorData::VehicleState(_) => SensorKind::VehicleState,
            SensorData::Baro(_) => SensorKind::Baro,
        }
    }
}

impl SensorData {
    /// Every number finite and within physical bounds: the last check before fusion
    /// (codecs check on decode; offline runs and the simulator's faults come here).
    pub fn validate(&self) -> Result<(), String> {
        fn f(name: &str, v: f64) -> Result<(), String> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("{name} is {v}"))
            }
        }
        fn all<'a>(name: &str, it: impl IntoIterator<Item = &'a f64>) -> Result<(), String> {
            it.into_iter().try_for_each(|v| f(name, *v))
        }
        match self {
            SensorData::Imu(m) => {
                all("gyro", m.gyro.iter().flat_map(|v| v.iter()))?;
                all("accel", m.accel.iter().flat_map(|v| v.iter()))?;
                all(
                    "orientation",
                    m.orientation.iter().flat_map(|q| q.coords.iter()),
                )
            }
            SensorData::Attitude(m) => {
                all("orientation", m.orientation.coords.iter())?;
                all("rates", m.rates.iter().flat_map(|v| v.iter()))
            }
            SensorData::Gnss(m) => {
                f("latitude", m.lat_deg)?;
                f("longitude", m.lon_deg)?;
                f("altitude", m.alt_m)?;
                if m.lat_deg.abs() > 90.0 || m.lon_deg.abs() > 180.0 {
                    return Err(format!(
                        "position ({}, {}) is not on Earth",
                        m.lat_deg, m.lon_deg
                    ));
                }
                all(
                    "position covariance",
                    m.position_cov.iter().flat_map(|c| c.iter()),
                )?;
                all("velocity", m.velocity.iter().flat_map(|v| v.iter()))
            }
            SensorData::Flow(m) => {
                all("flow rate", m.rate.iter().flat_map(|v| v.iter()))?;
                all("flow gyro", m.gyro.iter().flat_map(|v| v.iter()))?;
                all("flow velocity", m.velocity.iter().flat_map(|v| v.iter()))?;
                if let Some(t) = &m.tof {
                    f("tof distance", t.distance_m)?;
                }
                Ok(())
            }
            SensorData::Range(m) => {
                f("range", m.distance_m)?;
                if m.distance_m < 0.0 {
                    return Err(format!("range {} m is negative", m.distance_m));
                }
                Ok(())
            }
            SensorData::Odometry(m) => {
                all("odometry position", m.position.iter())?;
                all("odometry orientation", m.orientation.coords.iter())?;
                all(
                    "odometry velocity",
                    m.velocity.iter().flat_map(|v| v.iter()),
                )
            }
            SensorData::AutopilotEstimate(m) => all(
                "local position",
                m.local_position.iter().flat_map(|v| v.iter()),
            ),
            SensorData::VehicleState(_) => Ok(()),
            SensorData::Baro(m) => {
                f("pressure", m.pressure_pa)?;
                if !(BARO_MIN_PA..=BARO_MAX_PA).contains(&m.pressure_pa) {
                    return Err(format!(
                        "pressure {} Pa is not an air pressure on Earth ({BARO_MIN_PA}-{BARO_MAX_PA} Pa): wrong units?",
                        m.pressure_pa
                    ));
                }
                if let Some(t) = m.temperature_c {
                    f("temperature", t)?;
                }
                Ok(())
            }
        }
    }
}

impl SensorKind {
    pub const ALL: [SensorKind; 9] = [
        SensorKind::Imu,
        SensorKind::Attitude,
        SensorKind::Gnss,
        SensorKind::Flow,
        SensorKind::Range,
        SensorKind::Odometry,
        SensorKind::AutopilotEstimate,
        SensorKind::VehicleState,
        SensorKind::Baro,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            SensorKind::Imu => "imu",
            SensorKind::Attitude => "attitude",
            SensorKind::Gnss => "gnss",
            SensorKind::Flow => "flow",
            SensorKind::Range => "range",
            SensorKind::Odometry => "odometry",
            SensorKind::AutopilotEstimate => "autopilot_estimate",
            SensorKind::VehicleState => "vehicle_state",
            SensorKind::Baro => "baro",
        }
    }
}

impl std::fmt::Display for SensorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Lowest and highest static pressure a barometer on a vehicle reads, Pa (about 18 km
/// up; a deep mine): outside, the units are wrong (hPa sent as Pa, or the reverse).
pub const BARO_MIN_PA: f64 = 7_000.0;
pub const BARO_MAX_PA: f64 = 120_000.0;

/// A barometer reading.
#[derive(Debug, Clone, PartialEq)]
pub struct Baro {
    /// Static pressure, Pa.
    pub pressure_pa: f64,
    /// The sensor's temperature, °C, where reported.
    pub temperature_c: Option<f64>,
    /// Variance of the pressure, Pa², where reported (ROS FluidPressure).
    pub variance: Option<f64>,
}

impl Baro {
    /// Pressure altitude, m (ISA troposphere: 288.15 K, 6.5 K/km, 101 325 Pa), as PX4
    /// and ArduPilot compute it; only its changes matter to the estimator.
    pub fn altitude_m(&self) -> f64 {
        44_330.769 * (1.0 - (self.pressure_pa / 101_325.0).powf(0.190_263))
    }
}

/// Inertial measurement, body FLU.
#[derive(Debug, Clone, PartialEq)]
pub struct Imu {
    /// Angular rate, rad/s.
    pub gyro: Option<Vector3<f64>>,
    /// Specific force, m/s² (reads about +9.81 on z when level and still).
    pub accel: Option<Vector3<f64>>,
    /// Orientation body FLU → world ENU, where the message carries one.
    pub orientation: Option<UnitQuaternion<f64>>,
    /// Covariances, where the message has them (ROS; never MAVLink or PX4 logs): boxed,
    /// so that an IMU sample, the most frequent of all, is a third of its size without.
    pub gyro_cov: Option<Box<Matrix3<f64>>>,
    pub accel_cov: Option<Box<Matrix3<f64>>>,
    pub orientation_cov: Option<Box<Matrix3<f64>>>,
}

impl Imu {
    /// Rates and specific force only, no orientation or covariances (MAVLink's IMU
    /// messages, PX4's vehicle_imu).
    pub fn from_rates(gyro: Option<Vector3<f64>>, accel: Option<Vector3<f64>>) -> Self {
        Imu {
            gyro,
            accel,
            orientation: None,
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        }
    }
}

/// Attitude from the autopilot: body FLU → world ENU.
#[derive(Debug, Clone, PartialEq)]
pub struct Attitude {
    pub orientation: UnitQuaternion<f64>,
    /// Body rates, rad/s, FLU.
    pub rates: Option<Vector3<f64>>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GnssFixType {
    NoFix,
    Fix2d,
    Fix3d,
    /// SBAS/DGPS/GBAS augmented fix.
    Dgps,
    RtkFloat,
    RtkFixed,
}

/// A GNSS position fix, WGS-84.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssFix {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Altitude in metres (ellipsoid for NavSatFix, MSL for GPS_RAW_INT; used relatively).
    pub alt_m: f64,
    pub fix: GnssFixType,
    /// Position covariance in ENU, m², if the message reports one (boxed: a sample of
    /// every kind is as large as its largest kind).
    pub position_cov: Option<Box<Matrix3<f64>>>,
    pub satellites: Option<u8>,
    pub hdop: Option<f64>,
    pub vdop: Option<f64>,
    /// Ground velocity in ENU, m/s, where the message has it.
    pub velocity: Option<Vector3<f64>>,
    /// `velocity`'s up component was measured. GPS_RAW_INT carries ground speed and
    /// course only: its up is no measurement (a climb is not a level flight).
    pub velocity_up_known: bool,
}

/// Optical flow, optionally with the module's own ToF height.
#[derive(Debug, Clone, PartialEq)]
pub struct OpticalFlow {
    /// Angular flow rate about body x and y, rad/s, NOT rotation-compensated
    /// (OPTICAL_FLOW_RAD integrated_x/y ÷ dt, OPTICAL_FLOW flow_rate_x/y, the seed's
    /// flow_vel_x/y). Axes body FLU, a right-handed rotation counts positive, so a
    /// downward camera at height d sees rate = ω_xy + (v_y, −v_x)/d. PX4 sends FRD
    /// axes: its y changes sign on the way in (checked on a real PX4 flight against
    /// its visual odometry, `replay::px4log`).
    pub rate: Option<Vector2<f64>>,
    /// The flow sensor's own gyro over the same interval, rad/s, body FLU.
    pub gyro: Option<Vector3<f64>>,
    /// Metric ground velocity in body x/y, m/s, when the sensor already computed it
    /// (OPTICAL_FLOW flow_comp_m_x/y).
    pub velocity: Option<Vector2<f64>>,
    /// Integration interval, s.
    pub integration_s: Option<f64>,
    /// 0 (bad) .. 255 (best).
    pub quality: u8,
    /// Sensor status byte, where sent (the seed's flow_status).
    pub status: Option<u8>,
    /// The module's own height reading, if it has one.
    pub tof: Option<Tof>,
}

/// A time-of-flight height reading carried by a flow module (the seed's message).
#[derive(Debug, Clone, PartialEq)]
pub struct Tof {
    pub distance_m: f64,
    pub strength: Option<u8>,
    pub precision: Option<u8>,
    pub status: Option<u8>,
}

/// A range finder reading (downward unless `orientation` says otherwise).
#[derive(Debug, Clone, PartialEq)]
pub struct Range {
    pub distance_m: f64,
    pub min_m: Option<f64>,
    pub max_m: Option<f64>,
    /// Signal quality 0..100 where the sensor reports it (MAVLink convention).
    pub signal_quality: Option<u8>,
    /// Variance, m², where reported.
    pub variance: Option<f64>,
    /// MAVLink MAV_SENSOR_ORIENTATION (25 = PITCH_270 = downward); `None` for ROS.
    pub orientation: Option<u8>,
}

/// A pose (and maybe twist) from visual odometry or another pose source, in the
/// source's own world frame (ENU-like) with the body in FLU.
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    pub position: Vector3<f64>,
    pub orientation: UnitQuaternion<f64>,
    /// Linear velocity, m/s, in the child (body) frame as nav_msgs/Odometry defines it.
    pub velocity: Option<Vector3<f64>>,
    pub angular_velocity: Option<Vector3<f64>>,
    /// 6×6 pose covariance (x, y, z, rot x, rot y, rot z).
    pub pose_cov: Option<Matrix6<f64>>,
    pub twist_cov: Option<Matrix6<f64>>,
    pub frame_id: String,
    pub child_frame_id: String,
    /// Reset counter from the source (MAVLink ODOMETRY), if it has one.
    pub reset_counter: Option<u8>,
    /// Quality in percent (MAVLink ODOMETRY; -1 = failed), if reported.
    pub quality: Option<i8>,
}

/// The autopilot's own position estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct AutopilotEstimate {
    /// Local ENU position, m (LOCAL_POSITION_NED converted).
    pub local_position: Option<Vector3<f64>>,
    /// Geodetic position (GLOBAL_POSITION_INT): lat, lon in degrees, alt in metres MSL.
    pub geodetic: Option<(f64, f64, f64)>,
    /// Velocity ENU, m/s.
    pub velocity: Option<Vector3<f64>>,
    /// Heading, rad, ENU yaw (0 = east, counter-clockwise), where given.
    pub yaw: Option<f64>,
}

/// MAV_LANDED_STATE, as PX4 and ArduPilot report it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LandedState {
    OnGround,
    InAir,
    Takeoff,
    Landing,
}

/// What the autopilot says of the vehicle as a whole. Either part may be unknown (a
/// HEARTBEAT has only `armed`, EXTENDED_SYS_STATE only `landed`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VehicleState {
    pub armed: Option<bool>,
    pub landed: Option<LandedState>,
}

/// Frame conversion helpers used by codecs of NED/FRD sources.
pub mod frames {
    use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

    /// NED vector → ENU vector.
    pub fn ned_to_enu(v: Vector3<f64>) -> Vector3<f64> {
        Vector3::new(v.y, v.x, -v.z)
    }

    /// FRD vector → FLU vector.
    pub fn frd_to_flu(v: Vector3<f64>) -> Vector3<f64> {
        Vector3::new(v.x, -v.y, -v.z)
    }

    /// A covariance in NED axes → ENU axes (the same permutation, applied on both sides).
    pub fn ned_to_enu_cov(c: Matrix3<f64>) -> Matrix3<f64> {
        let p = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
        p * c * p.transpose()
    }

    /// Attitude body FRD → world NED (MAVLink) to body FLU → world ENU (ROS).
    pub fn q_ned_frd_to_enu_flu(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        // q_enu_flu = q_enu_ned * q_ned_frd * q_frd_flu
        let q_enu_ned = UnitQuaternion::from_quaternion(Quaternion::new(
            0.0,
            std::f64::consts::FRAC_1_SQRT_2,
            std::f64::consts::FRAC_1_SQRT_2,
            0.0,
        ));
        let q_frd_flu = UnitQuaternion::from_quaternion(Quaternion::new(0.0, 1.0, 0.0, 0.0));
        q_enu_ned * q * q_frd_flu
    }

    /// Euler angles (roll, pitch, yaw; FRD in NED, as MAVLink ATTITUDE) → ENU/FLU quaternion.
    pub fn euler_ned_to_enu_flu(roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
        q_ned_frd_to_enu_flu(UnitQuaternion::from_euler_angles(roll, pitch, yaw))
    }

    /// NED yaw (0 = north, clockwise) → ENU yaw (0 = east, counter-clockwise).
    pub fn yaw_ned_to_enu(yaw: f64) -> f64 {
        let y = std::f64::consts::FRAC_PI_2 - yaw;
        (y + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn level_north_facing_ned_is_yaw_90_in_enu() {
            let q = euler_ned_to_enu_flu(0.0, 0.0, 0.0);
            // Body x (forward) points north = ENU +y.
            let fwd = q * Vector3::x();
            assert!((fwd - Vector3::y()).norm() < 1e-12, "{fwd}");
            // Body z (FLU up) points up.
            let up = q * Vector3::z();
            assert!((up - Vector3::z()).norm() < 1e-12, "{up}");
            assert!((q.euler_angles().2 - yaw_ned_to_enu(0.0)).abs() < 1e-12);
        }

        #[test]
        fn east_facing_with_roll_right() {
            // Yaw 90° in NED = facing east; roll right 0.3 rad (right wing down).
            let q = euler_ned_to_enu_flu(0.3, 0.0, std::f64::consts::FRAC_PI_2);
            let fwd = q * Vector3::x();
            assert!((fwd - Vector3::x()).norm() < 1e-12, "{fwd}");
            // Body left (FLU +y) points north and slightly up when rolled right.
            let left = q * Vector3::y();
            assert!(left.y > 0.9 && left.z > 0.2, "{left}");
        }

        #[test]
        fn covariance_permutation_swaps_north_and_east() {
            let c = Matrix3::from_diagonal(&Vector3::new(1.0, 2.0, 3.0));
            let e = ned_to_enu_cov(c);
            assert_eq!(e, Matrix3::from_diagonal(&Vector3::new(2.0, 1.0, 3.0)));
        }
    }
}
