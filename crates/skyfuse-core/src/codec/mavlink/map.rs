//! One mapping per sensor message, MAVLink fields (NED/FRD, MAVLink units) → samples
//! (ENU/FLU, SI). Both wire forms reach these through [`Fields`], so JSON and raw
//! frames cannot disagree.
//!
//! Non-finite floats: a field the sample needs (IMU axes, attitude, positions) is a
//! `NonFinite` error naming it; a field MAVLink or the autopilots use NaN for "not
//! available" maps to `None`: covariances (first element NaN), extensions, flow-module
//! gyro (PX4 sends NaN without one), OPTICAL_FLOW metric velocity, ODOMETRY and
//! LOCAL_POSITION_NED velocities and rates (PX4 accepts NaN there), distances (also
//! negative = unknown).

use super::fields::Fields;
use crate::codec::error::{in_range, DecodeError};
use crate::sample::{
    frames, Attitude, AutopilotEstimate, GnssFix, GnssFixType, Imu, LandedState, Micros, Odometry,
    OpticalFlow, Range, SensorData, SensorKind, Tof, VehicleState,
};
use ::mavlink::dialects::common::{
    self, GpsFixType, HighresImuUpdatedFlags, MavAutopilot, MavLandedState, MavModeFlag,
    MavSensorOrientation, MavType,
};
use ::mavlink::MessageData;
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};

/// Standard gravity, m/s² per g (what ArduPilot and PX4 use for mG).
const G: f64 = 9.80665;

/// The messages that carry sensor data for us.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum SensorMsg {
    HighresImu,
    ScaledImu,
    RawImu,
    Attitude,
    AttitudeQuaternion,
    OpticalFlow,
    OpticalFlowRad,
    DistanceSensor,
    GpsRawInt,
    GlobalPositionInt,
    LocalPositionNed,
    Odometry,
    Heartbeat,
    ExtendedSysState,
    SimState,
    ScaledPressure,
    ScaledPressure2,
    ScaledPressure3,
}

impl SensorMsg {
    pub const ALL: [SensorMsg; 18] = [
        SensorMsg::HighresImu,
        SensorMsg::ScaledImu,
        SensorMsg::RawImu,
        SensorMsg::Attitude,
        SensorMsg::AttitudeQuaternion,
        SensorMsg::OpticalFlow,
        SensorMsg::OpticalFlowRad,
        SensorMsg::DistanceSensor,
        SensorMsg::GpsRawInt,
        SensorMsg::GlobalPositionInt,
        SensorMsg::LocalPositionNed,
        SensorMsg::Odometry,
        SensorMsg::Heartbeat,
        SensorMsg::ExtendedSysState,
        SensorMsg::SimState,
        SensorMsg::ScaledPressure,
        SensorMsg::ScaledPressure2,
        SensorMsg::ScaledPressure3,
    ];

    /// The kind of sample the message becomes.
    pub fn kind(self) -> SensorKind {
        use SensorMsg as M;
        match self {
            M::HighresImu | M::ScaledImu | M::RawImu => SensorKind::Imu,
            M::Attitude | M::AttitudeQuaternion => SensorKind::Attitude,
            M::OpticalFlow | M::OpticalFlowRad => SensorKind::Flow,
            M::DistanceSensor => SensorKind::Range,
            M::GpsRawInt => SensorKind::Gnss,
            M::GlobalPositionInt | M::LocalPositionNed | M::SimState => {
                SensorKind::AutopilotEstimate
            }
            M::Odometry => SensorKind::Odometry,
            M::Heartbeat | M::ExtendedSysState => SensorKind::VehicleState,
            M::ScaledPressure | M::ScaledPressure2 | M::ScaledPressure3 => SensorKind::Baro,
        }
    }

    /// Every kind of sample the message can become: its own, and HIGHRES_IMU's
    /// barometer ([`decode_second`]).
    pub fn kinds(self) -> &'static [SensorKind] {
        use SensorKind as K;
        if self == SensorMsg::HighresImu {
            return &[K::Imu, K::Baro];
        }
        match self.kind() {
            K::Imu => &[K::Imu],
            K::Attitude => &[K::Attitude],
            K::Gnss => &[K::Gnss],
            K::Flow => &[K::Flow],
            K::Range => &[K::Range],
            K::Odometry => &[K::Odometry],
            K::AutopilotEstimate => &[K::AutopilotEstimate],
            K::VehicleState => &[K::VehicleState],
            K::Baro => &[K::Baro],
        }
    }

    /// (name, id) from rust-mavlink's definitions, so no number is typed twice.
    fn meta(self) -> (&'static str, u32) {
        fn m<D: MessageData>() -> (&'static str, u32) {
            (D::NAME, D::ID)
        }
        match self {
            SensorMsg::HighresImu => m::<common::HIGHRES_IMU_DATA>(),
            SensorMsg::ScaledImu => m::<common::SCALED_IMU_DATA>(),
            SensorMsg::RawImu => m::<common::RAW_IMU_DATA>(),
            SensorMsg::Attitude => m::<common::ATTITUDE_DATA>(),
            SensorMsg::AttitudeQuaternion => m::<common::ATTITUDE_QUATERNION_DATA>(),
            SensorMsg::OpticalFlow => m::<common::OPTICAL_FLOW_DATA>(),
            SensorMsg::OpticalFlowRad => m::<common::OPTICAL_FLOW_RAD_DATA>(),
            SensorMsg::DistanceSensor => m::<common::DISTANCE_SENSOR_DATA>(),
            SensorMsg::GpsRawInt => m::<common::GPS_RAW_INT_DATA>(),
            SensorMsg::GlobalPositionInt => m::<common::GLOBAL_POSITION_INT_DATA>(),
            SensorMsg::LocalPositionNed => m::<common::LOCAL_POSITION_NED_DATA>(),
            SensorMsg::Odometry => m::<common::ODOMETRY_DATA>(),
            SensorMsg::Heartbeat => m::<common::HEARTBEAT_DATA>(),
            SensorMsg::ExtendedSysState => m::<common::EXTENDED_SYS_STATE_DATA>(),
            SensorMsg::SimState => m::<common::SIM_STATE_DATA>(),
            SensorMsg::ScaledPressure => m::<common::SCALED_PRESSURE_DATA>(),
            SensorMsg::ScaledPressure2 => m::<common::SCALED_PRESSURE2_DATA>(),
            SensorMsg::ScaledPressure3 => m::<common::SCALED_PRESSURE3_DATA>(),
        }
    }

    pub fn name(self) -> &'static str {
        self.meta().0
    }

    pub fn from_name(name: &str) -> Option<SensorMsg> {
        SensorMsg::ALL.into_iter().find(|s| s.name() == name)
    }

    pub fn from_id(id: u32) -> Option<SensorMsg> {
        SensorMsg::ALL.into_iter().find(|s| s.meta().1 == id)
    }
}

/// A decoded message: its own stamp and the sample; `None` when it holds nothing usable.
pub(super) type Mapped = Option<(Option<Micros>, SensorData)>;

pub(super) fn decode(sensor: SensorMsg, f: &Fields) -> Result<Mapped, DecodeError> {
    match sensor {
        SensorMsg::HighresImu => highres_imu(f),
        SensorMsg::ScaledImu => {
            let stamp = boot_ms(f)?;
            scaled_imu(f, stamp)
        }
        // RAW_IMU is "raw sensor units", a scale only the sender knows. ArduPilot, the
        // one autopilot that streams it, fills it exactly like SCALED_IMU (mG, mrad/s),
        // so it is decoded with that scale; a sender with true raw counts needs its own.
        SensorMsg::RawImu => {
            let stamp = usec(f, "time_usec")?;
            scaled_imu(f, stamp)
        }
        SensorMsg::Attitude => attitude(f),
        SensorMsg::AttitudeQuaternion => attitude_quaternion(f),
        SensorMsg::OpticalFlow => optical_flow(f),
        SensorMsg::OpticalFlowRad => optical_flow_rad(f),
        SensorMsg::DistanceSensor => distance_sensor(f),
        SensorMsg::GpsRawInt => gps_raw_int(f),
        SensorMsg::GlobalPositionInt => global_position_int(f),
        SensorMsg::LocalPositionNed => local_position_ned(f),
        SensorMsg::Odometry => odometry(f),
        SensorMsg::Heartbeat => heartbeat(f),
        SensorMsg::ExtendedSysState => extended_sys_state(f),
        SensorMsg::SimState => sim_state(f),
        SensorMsg::ScaledPressure | SensorMsg::ScaledPressure2 | SensorMsg::ScaledPressure3 => {
            scaled_pressure(f)
        }
    }
}

/// The second sample a message carries beside its own: HIGHRES_IMU's barometer.
pub(super) fn decode_second(sensor: SensorMsg, f: &Fields) -> Result<Mapped, DecodeError> {
    match sensor {
        SensorMsg::HighresImu => highres_imu_pressure(f),
        _ => Ok(None),
    }
}

/// HIGHRES_IMU's `abs_pressure` and `temperature` (°C) → a barometer, when
/// `fields_updated` says the pressure is new (PX4 sets the bit only with a new baro
/// reading, so an IMU at 250 Hz does not repeat a 50 Hz barometer). A zero mask is a
/// sender that ignores the field: its pressure is taken only when it is one. The
/// MAVLink spec says hPa; PX4 1.14–1.16 put Pa there (`baro_pressure_pa`, measured from
/// v1.16 SITL: 95578). Air pressure in hPa and in Pa do not overlap (70–1200 and
/// 7000–120000), so either is read; anything else is refused.
fn highres_imu_pressure(f: &Fields) -> Result<Mapped, DecodeError> {
    use HighresImuUpdatedFlags as U;
    let bit = u64::from(U::HIGHRES_IMU_UPDATED_ABS_PRESSURE.bits());
    let updated = f.flags("fields_updated", |n| {
        U::from_name(n).map(|b| u64::from(b.bits()))
    })?;
    let value = f.f32_any("abs_pressure")?;
    let hpa_range = crate::sample::BARO_MIN_PA / 100.0..=crate::sample::BARO_MAX_PA / 100.0;
    let pa_range = crate::sample::BARO_MIN_PA..=crate::sample::BARO_MAX_PA;
    let air = hpa_range.contains(&value) || pa_range.contains(&value);
    match updated {
        Some(b) if b != 0 && b & bit == 0 => return Ok(None),
        Some(b) if b != 0 => {}
        // Mask zero or absent: no claim, so a zero or garbage pressure is no error.
        _ if !air => return Ok(None),
        _ => {}
    }
    if !air {
        return Err(DecodeError::OutOfRange {
            field: "abs_pressure".into(),
            value,
            reason: "not an air pressure in hPa (the spec) nor in Pa (PX4)",
        });
    }
    let pressure_pa = if pa_range.contains(&value) {
        value
    } else {
        value * 100.0
    };
    let temperature_c = f.f32_any("temperature")?;
    let stamp = usec(f, "time_usec")?;
    Ok(Some((
        stamp,
        SensorData::Baro(crate::sample::Baro {
            pressure_pa,
            temperature_c: temperature_c.is_finite().then_some(temperature_c),
            variance: None,
        }),
    )))
}

/// SCALED_PRESSURE(2/3) → a barometer: `press_abs` hPa, `temperature` cdegC.
fn scaled_pressure(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let hpa = crate::codec::error::in_range(
        "press_abs",
        f.f32("press_abs")?,
        crate::sample::BARO_MIN_PA / 100.0,
        crate::sample::BARO_MAX_PA / 100.0,
        "not an air pressure in hPa",
    )?;
    let pressure_pa = hpa * 100.0;
    let temperature_c = f.int("temperature", i16::MIN.into(), i16::MAX.into())? as f64 / 100.0;
    Ok(Some((
        stamp,
        SensorData::Baro(crate::sample::Baro {
            pressure_pa,
            temperature_c: Some(temperature_c),
            variance: None,
        }),
    )))
}

/// HEARTBEAT of an autopilot → armed. Heartbeats of anything else on the link (ground
/// stations, cameras, companions like us) say nothing about the vehicle: `None`.
fn heartbeat(f: &Fields) -> Result<Mapped, DecodeError> {
    let autopilot: MavAutopilot =
        f.enum_value("autopilot", "a MAV_AUTOPILOT entry {\"type\": NAME}")?;
    let mavtype: MavType = f.enum_value("mavtype", "a MAV_TYPE entry {\"type\": NAME}")?;
    let not_a_vehicle = matches!(
        mavtype,
        MavType::MAV_TYPE_GCS
            | MavType::MAV_TYPE_ONBOARD_CONTROLLER
            | MavType::MAV_TYPE_GIMBAL
            | MavType::MAV_TYPE_CAMERA
            | MavType::MAV_TYPE_ADSB
            | MavType::MAV_TYPE_ANTENNA_TRACKER
    );
    if autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID || not_a_vehicle {
        return Ok(None);
    }
    let armed_bit = u64::from(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED.bits());
    let Some(mode) = f.flags("base_mode", |n| {
        MavModeFlag::from_name(n).map(|b| u64::from(b.bits()))
    })?
    else {
        // A flag name we do not know: the armed bit cannot be read safely.
        return Ok(None);
    };
    Ok(Some((
        None,
        SensorData::VehicleState(VehicleState {
            armed: Some(mode & armed_bit != 0),
            landed: None,
        }),
    )))
}

/// EXTENDED_SYS_STATE → landed state (`None` when the autopilot does not know it).
fn extended_sys_state(f: &Fields) -> Result<Mapped, DecodeError> {
    let landed: MavLandedState =
        f.enum_value("landed_state", "a MAV_LANDED_STATE entry {\"type\": NAME}")?;
    let landed = match landed {
        MavLandedState::MAV_LANDED_STATE_UNDEFINED => return Ok(None),
        MavLandedState::MAV_LANDED_STATE_ON_GROUND => LandedState::OnGround,
        MavLandedState::MAV_LANDED_STATE_IN_AIR => LandedState::InAir,
        MavLandedState::MAV_LANDED_STATE_TAKEOFF => LandedState::Takeoff,
        MavLandedState::MAV_LANDED_STATE_LANDING => LandedState::Landing,
    };
    Ok(Some((
        None,
        SensorData::VehicleState(VehicleState {
            armed: None,
            landed: Some(landed),
        }),
    )))
}

// ------------------------------------------------------------------------ helpers

/// A `time_usec`; 0 is "no time" (ArduPilot's GPS_RAW_INT before its first fix), so the
/// sample is timed by its arrival rather than starting a clock at zero.
fn usec(f: &Fields, key: &str) -> Result<Option<Micros>, DecodeError> {
    let t = f.uint(key, u64::MAX)?;
    if t == 0 {
        return Ok(None);
    }
    Micros::try_from(t)
        .map(Some)
        .map_err(|_| DecodeError::OutOfRange {
            field: format!("{}.{key}", f.name),
            value: t as f64,
            reason: "timestamp beyond i64 microseconds",
        })
}

fn boot_ms(f: &Fields) -> Result<Option<Micros>, DecodeError> {
    Ok(Some(
        f.uint("time_boot_ms", u32::MAX.into())? as Micros * 1000,
    ))
}

fn vec3(f: &Fields, [x, y, z]: [&str; 3]) -> Result<Vector3<f64>, DecodeError> {
    Ok(Vector3::new(f.f32(x)?, f.f32(y)?, f.f32(z)?))
}

/// Three floats that may be unknown: `Some` only when all are finite.
fn vec3_opt(f: &Fields, [x, y, z]: [&str; 3]) -> Result<Option<Vector3<f64>>, DecodeError> {
    let v = Vector3::new(f.f32_any(x)?, f.f32_any(y)?, f.f32_any(z)?);
    Ok(all_finite(v.as_slice()).then_some(v))
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// A `w, x, y, z` quaternion that must be finite and near unit length.
fn quat(f: &Fields, what: &str, wxyz: [f64; 4]) -> Result<UnitQuaternion<f64>, DecodeError> {
    for (i, x) in wxyz.iter().enumerate() {
        if !x.is_finite() {
            return Err(DecodeError::NonFinite {
                field: format!("{}.{what}[{i}]", f.name),
                value: *x,
            });
        }
    }
    let [w, x, y, z] = wxyz;
    let q = Quaternion::new(w, x, y, z);
    in_range(
        &format!("{}.{what}", f.name),
        q.norm(),
        0.5,
        2.0,
        "quaternion norm must be near 1",
    )?;
    Ok(UnitQuaternion::from_quaternion(q))
}

fn int_of(f: &Fields, key: &str, min: i64, max: i64) -> Result<f64, DecodeError> {
    Ok(f.int(key, min, max)? as f64)
}

fn i16_of(f: &Fields, key: &str) -> Result<f64, DecodeError> {
    int_of(f, key, i16::MIN.into(), i16::MAX.into())
}

fn lat_lon(f: &Fields) -> Result<(f64, f64), DecodeError> {
    let lat = int_of(f, "lat", i32::MIN.into(), i32::MAX.into())? * 1e-7;
    let lon = int_of(f, "lon", i32::MIN.into(), i32::MAX.into())? * 1e-7;
    on_earth(f, lat, lon)
}

/// Latitude and longitude (degrees) within their ranges, or an error naming the field.
fn on_earth(f: &Fields, lat: f64, lon: f64) -> Result<(f64, f64), DecodeError> {
    in_range(
        &format!("{}.lat", f.name),
        lat,
        -90.0,
        90.0,
        "latitude beyond ±90°",
    )?;
    in_range(
        &format!("{}.lon", f.name),
        lon,
        -180.0,
        180.0,
        "longitude beyond ±180°",
    )?;
    Ok((lat, lon))
}

fn tof(distance_m: f64) -> Option<Tof> {
    (distance_m.is_finite() && distance_m > 0.0).then_some(Tof {
        distance_m,
        strength: None,
        precision: None,
        status: None,
    })
}

fn imu(gyro: Option<Vector3<f64>>, accel: Option<Vector3<f64>>) -> SensorData {
    SensorData::Imu(Imu::from_rates(gyro, accel))
}

// ------------------------------------------------------------------------ messages

fn highres_imu(f: &Fields) -> Result<Mapped, DecodeError> {
    use HighresImuUpdatedFlags as U;
    let stamp = usec(f, "time_usec")?;
    let acc_bits = u64::from(
        (U::HIGHRES_IMU_UPDATED_XACC | U::HIGHRES_IMU_UPDATED_YACC | U::HIGHRES_IMU_UPDATED_ZACC)
            .bits(),
    );
    let gyro_bits = u64::from(
        (U::HIGHRES_IMU_UPDATED_XGYRO
            | U::HIGHRES_IMU_UPDATED_YGYRO
            | U::HIGHRES_IMU_UPDATED_ZGYRO)
            .bits(),
    );
    let updated = f.flags("fields_updated", |n| {
        U::from_name(n).map(|b| u64::from(b.bits()))
    })?;
    // A zero mask is what senders that ignore the field send: take every field then.
    let has = |mask: u64| updated.is_none_or(|b| b == 0 || b & mask == mask);
    // MAVLink accel is FRD specific force (zacc ≈ -9.81 level); FLU flips y and z.
    let accel = if has(acc_bits) {
        Some(frames::frd_to_flu(vec3(f, ["xacc", "yacc", "zacc"])?))
    } else {
        None
    };
    let gyro = if has(gyro_bits) {
        Some(frames::frd_to_flu(vec3(f, ["xgyro", "ygyro", "zgyro"])?))
    } else {
        None
    };
    if accel.is_none() && gyro.is_none() {
        return Ok(None);
    }
    Ok(Some((stamp, imu(gyro, accel))))
}

fn scaled_imu(f: &Fields, stamp: Option<Micros>) -> Result<Mapped, DecodeError> {
    let mg = G * 1e-3;
    let accel = Vector3::new(
        i16_of(f, "xacc")? * mg,
        i16_of(f, "yacc")? * mg,
        i16_of(f, "zacc")? * mg,
    );
    let gyro = Vector3::new(
        i16_of(f, "xgyro")? * 1e-3,
        i16_of(f, "ygyro")? * 1e-3,
        i16_of(f, "zgyro")? * 1e-3,
    );
    Ok(Some((
        stamp,
        imu(
            Some(frames::frd_to_flu(gyro)),
            Some(frames::frd_to_flu(accel)),
        ),
    )))
}

fn attitude(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let rpy = vec3(f, ["roll", "pitch", "yaw"])?;
    let rates = vec3(f, ["rollspeed", "pitchspeed", "yawspeed"])?;
    Ok(Some((
        stamp,
        SensorData::Attitude(Attitude {
            orientation: frames::euler_ned_to_enu_flu(rpy.x, rpy.y, rpy.z),
            rates: Some(frames::frd_to_flu(rates)),
        }),
    )))
}

fn attitude_quaternion(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let wxyz = [
        f.f32_any("q1")?,
        f.f32_any("q2")?,
        f.f32_any("q3")?,
        f.f32_any("q4")?,
    ];
    let q = quat(f, "q1..q4", wxyz)?;
    let rates = vec3(f, ["rollspeed", "pitchspeed", "yawspeed"])?;
    Ok(Some((
        stamp,
        SensorData::Attitude(Attitude {
            orientation: frames::q_ned_frd_to_enu_flu(q),
            rates: Some(frames::frd_to_flu(rates)),
        }),
    )))
}

fn optical_flow(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = usec(f, "time_usec")?;
    // NaN here (no distance to scale by) means no metric velocity.
    let vx = f.f32_any("flow_comp_m_x")?;
    let vy = f.f32_any("flow_comp_m_y")?;
    let ground = f.f32_any("ground_distance")?;
    let quality = f.uint("quality", u8::MAX.into())? as u8;
    // The rate extension is absent from MAVLink 1 frames and old senders.
    // PX4's sensor convention (FRD axes, right-handed rotation positive) to the
    // sample's FLU: y changes sign (see `OpticalFlow::rate`).
    let rate = match (f.ext_f32("flow_rate_x")?, f.ext_f32("flow_rate_y")?) {
        (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Some(Vector2::new(x, -y)),
        _ => None,
    };
    Ok(Some((
        stamp,
        SensorData::Flow(OpticalFlow {
            rate,
            gyro: None,
            // Sensor axes are body FRD: y (right) becomes -y (left).
            velocity: (vx.is_finite() && vy.is_finite()).then_some(Vector2::new(vx, -vy)),
            integration_s: None,
            quality,
            status: None,
            tof: tof(ground),
        }),
    )))
}

fn optical_flow_rad(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = usec(f, "time_usec")?;
    let dt_us = f.uint("integration_time_us", u32::MAX.into())?;
    let ix = f.f32("integrated_x")?;
    let iy = f.f32("integrated_y")?;
    let gyro = vec3_opt(
        f,
        ["integrated_xgyro", "integrated_ygyro", "integrated_zgyro"],
    )?;
    let distance = f.f32_any("distance")?;
    let quality = f.uint("quality", u8::MAX.into())? as u8;
    // Without an integration time there is no rate (nothing to divide by).
    let dt = (dt_us > 0).then_some(dt_us as f64 * 1e-6);
    Ok(Some((
        stamp,
        SensorData::Flow(OpticalFlow {
            // PX4's convention (FRD axes, right-handed rotation positive) to the
            // sample's FLU: y changes sign, as the gyro's does.
            rate: dt.map(|dt| Vector2::new(ix / dt, -iy / dt)),
            gyro: dt.and_then(|dt| gyro.map(|g| frames::frd_to_flu(g / dt))),
            velocity: None,
            integration_s: dt,
            quality,
            status: None,
            tof: tof(distance),
        }),
    )))
}

fn distance_sensor(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let cm = |key: &str| -> Result<f64, DecodeError> {
        Ok(f.uint(key, u16::MAX.into())? as f64 / 100.0)
    };
    let orientation: MavSensorOrientation = f.enum_value(
        "orientation",
        "a MAV_SENSOR_ORIENTATION entry {\"type\": NAME}",
    )?;
    // 0 and UINT8_MAX both mean "unknown" (the spec moved from one to the other).
    let covariance = f.uint("covariance", u8::MAX.into())?;
    let variance =
        (covariance != 0 && covariance != u64::from(u8::MAX)).then_some(covariance as f64 * 1e-4);
    let signal_quality = f
        .ext_uint("signal_quality", u8::MAX.into())?
        .filter(|&q| q != 0)
        .map(|q| q as u8);
    Ok(Some((
        stamp,
        SensorData::Range(Range {
            distance_m: cm("current_distance")?,
            min_m: Some(cm("min_distance")?),
            max_m: Some(cm("max_distance")?),
            signal_quality,
            variance,
            orientation: u8::try_from(orientation as u32).ok(),
        }),
    )))
}

fn gps_raw_int(f: &Fields) -> Result<Mapped, DecodeError> {
    const UNKNOWN16: u64 = u16::MAX as u64;
    let stamp = usec(f, "time_usec")?;
    let fix =
        match f.enum_value::<GpsFixType>("fix_type", "a GPS_FIX_TYPE entry {\"type\": NAME}")? {
            GpsFixType::GPS_FIX_TYPE_NO_GPS | GpsFixType::GPS_FIX_TYPE_NO_FIX => GnssFixType::NoFix,
            GpsFixType::GPS_FIX_TYPE_2D_FIX => GnssFixType::Fix2d,
            // STATIC is a surveyed base station: a plain 3D position.
            GpsFixType::GPS_FIX_TYPE_3D_FIX | GpsFixType::GPS_FIX_TYPE_STATIC => GnssFixType::Fix3d,
            // PPP is corrections-augmented like DGPS.
            GpsFixType::GPS_FIX_TYPE_DGPS | GpsFixType::GPS_FIX_TYPE_PPP => GnssFixType::Dgps,
            GpsFixType::GPS_FIX_TYPE_RTK_FLOAT => GnssFixType::RtkFloat,
            GpsFixType::GPS_FIX_TYPE_RTK_FIXED => GnssFixType::RtkFixed,
        };
    let (lat_deg, lon_deg) = lat_lon(f)?;
    let alt_m = int_of(f, "alt", i32::MIN.into(), i32::MAX.into())? / 1000.0;
    let dop = |key: &str| -> Result<Option<f64>, DecodeError> {
        let v = f.uint(key, UNKNOWN16)?;
        Ok((v != UNKNOWN16).then_some(v as f64 * 0.01))
    };
    let hdop = dop("eph")?;
    let vdop = dop("epv")?;
    let vel = f.uint("vel", UNKNOWN16)?;
    let cog = f.uint("cog", UNKNOWN16)?;
    // Course over ground is from north, clockwise; GPS_RAW_INT has no vertical speed.
    let velocity = (vel != UNKNOWN16 && cog != UNKNOWN16).then(|| {
        let speed = vel as f64 / 100.0;
        let course = (cog as f64 / 100.0).to_radians();
        Vector3::new(speed * course.sin(), speed * course.cos(), 0.0)
    });
    let satellites = f.uint("satellites_visible", u8::MAX.into())?;
    let h_acc = f.ext_uint("h_acc", u32::MAX.into())?;
    let v_acc = f.ext_uint("v_acc", u32::MAX.into())?;
    let position_cov = match (h_acc, v_acc) {
        (Some(h), Some(v)) if h > 0 && v > 0 => {
            let (h, v) = (h as f64 / 1000.0, v as f64 / 1000.0);
            Some(Matrix3::from_diagonal(&Vector3::new(h * h, h * h, v * v)))
        }
        _ => None,
    };
    Ok(Some((
        stamp,
        SensorData::Gnss(GnssFix {
            lat_deg,
            lon_deg,
            alt_m,
            fix,
            position_cov: position_cov.map(Box::new),
            satellites: (satellites != u64::from(u8::MAX)).then_some(satellites as u8),
            hdop,
            vdop,
            velocity,
            velocity_up_known: false,
        }),
    )))
}

fn global_position_int(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let (lat, lon) = lat_lon(f)?;
    let alt = int_of(f, "alt", i32::MIN.into(), i32::MAX.into())? / 1000.0;
    let v_ned = Vector3::new(i16_of(f, "vx")?, i16_of(f, "vy")?, i16_of(f, "vz")?) / 100.0;
    let hdg = f.uint("hdg", u16::MAX.into())?;
    let yaw = (hdg != u64::from(u16::MAX))
        .then(|| frames::yaw_ned_to_enu((hdg as f64 / 100.0).to_radians()));
    Ok(Some((
        stamp,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position: None,
            geodetic: Some((lat, lon, alt)),
            velocity: Some(frames::ned_to_enu(v_ned)),
            yaw,
        }),
    )))
}

/// SIM_STATE, a simulator's true state (ArduPilot SITL): kept beside the estimates for
/// scoring, never fused. Position from `lat_int`/`lon_int` (1e-7°) where sent, else the
/// lower-precision `lat`/`lon` (degrees); attitude from the quaternion (FRD → NED).
fn sim_state(f: &Fields) -> Result<Mapped, DecodeError> {
    let int = |k: &str| f.ext_int(k, i32::MIN.into(), i32::MAX.into());
    let (lat, lon) = match (int("lat_int")?, int("lon_int")?) {
        (Some(a), Some(o)) if a != 0 || o != 0 => (a as f64 * 1e-7, o as f64 * 1e-7),
        _ => (f.f32("lat")?, f.f32("lon")?),
    };
    let (lat, lon) = on_earth(f, lat, lon)?;
    let alt = f.f32("alt")?;
    let q = quat(
        f,
        "q",
        [f.f32("q1")?, f.f32("q2")?, f.f32("q3")?, f.f32("q4")?],
    )?;
    let yaw = frames::q_ned_frd_to_enu_flu(q).euler_angles().2;
    let v_ned = vec3_opt(f, ["vn", "ve", "vd"])?;
    Ok(Some((
        None,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position: None,
            geodetic: Some((lat, lon, alt)),
            velocity: v_ned.map(frames::ned_to_enu),
            yaw: Some(yaw),
        }),
    )))
}

fn local_position_ned(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = boot_ms(f)?;
    let p = vec3(f, ["x", "y", "z"])?;
    let v = vec3_opt(f, ["vx", "vy", "vz"])?;
    Ok(Some((
        stamp,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position: Some(frames::ned_to_enu(p)),
            geodetic: None,
            velocity: v.map(frames::ned_to_enu),
            yaw: None,
        }),
    )))
}

// ------------------------------------------------------------------------ ODOMETRY

/// Axes of an ODOMETRY frame. NED-like world frames carry an FRD body, ENU-like an FLU one.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Axes {
    WorldNed,
    WorldEnu,
    BodyFrd,
    BodyFlu,
}

/// By name, so that both the names of current definitions (`MAV_FRAME_RESERVED_16`) and
/// of older ones (`MAV_FRAME_VISION_NED`, still what some senders' tools print) work.
fn frame_axes(name: &str) -> Option<Axes> {
    Some(match name.strip_prefix("MAV_FRAME_")? {
        "LOCAL_NED" | "LOCAL_FRD" | "LOCAL_OFFSET_NED" | "MOCAP_NED" | "VISION_NED"
        | "ESTIM_NED" | "RESERVED_14" | "RESERVED_16" | "RESERVED_18" => Axes::WorldNed,
        "LOCAL_ENU" | "LOCAL_FLU" | "MOCAP_ENU" | "VISION_ENU" | "ESTIM_ENU" | "RESERVED_15"
        | "RESERVED_17" | "RESERVED_19" => Axes::WorldEnu,
        // BODY_NED and BODY_OFFSET_NED mean body FRD for velocities (common.xml).
        "BODY_FRD" | "BODY_NED" | "BODY_OFFSET_NED" => Axes::BodyFrd,
        "BODY_FLU" | "RESERVED_13" => Axes::BodyFlu,
        _ => return None,
    })
}

pub(super) const NED_ENU: Matrix3<f64> = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
pub(super) const FRD_FLU: Matrix3<f64> =
    Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);

/// The 21-float row-major upper triangle; `None` when any entry is unknown (NaN).
fn upper_triangle(v: &[f64; 21]) -> Option<Matrix6<f64>> {
    if !all_finite(v) {
        return None;
    }
    let mut m = Matrix6::zeros();
    let mut it = v.iter();
    for r in 0..6 {
        for c in r..6 {
            let x = *it.next()?;
            m[(r, c)] = x;
            m[(c, r)] = x;
        }
    }
    Some(m)
}

/// `a c aᵀ` with `a` block-diagonal (linear block, angular block).
pub(super) fn transform_cov(c: Matrix6<f64>, lin: Matrix3<f64>, ang: Matrix3<f64>) -> Matrix6<f64> {
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&lin);
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&ang);
    a * c * a.transpose()
}

fn odometry(f: &Fields) -> Result<Mapped, DecodeError> {
    let stamp = usec(f, "time_usec")?;
    let frame = f.enum_name("frame_id")?;
    let child = f.enum_name("child_frame_id")?;
    let unsupported = |key: &str| DecodeError::WrongType {
        message: f.name.to_string(),
        field: key.to_string(),
        expected: "a local MAV_FRAME (LOCAL_NED, LOCAL_FRD, LOCAL_ENU, LOCAL_FLU, BODY_FRD, ...)",
    };
    let world = match frame_axes(frame) {
        Some(a @ (Axes::WorldNed | Axes::WorldEnu)) => a,
        _ => return Err(unsupported("frame_id")),
    };
    let twist_axes = frame_axes(child).ok_or_else(|| unsupported("child_frame_id"))?;
    let ned = world == Axes::WorldNed;

    let p = vec3(f, ["x", "y", "z"])?;
    let q = quat(f, "q", f.f32_array::<4>("q")?)?;
    let (position, orientation) = if ned {
        (frames::ned_to_enu(p), frames::q_ned_frd_to_enu_flu(q))
    } else {
        (p, q)
    };
    // Twist into the body FLU frame (nav_msgs' child frame): a = how to map vectors.
    let to_body = orientation.inverse().to_rotation_matrix().into_inner();
    let lin = match twist_axes {
        Axes::BodyFrd => FRD_FLU,
        Axes::BodyFlu => Matrix3::identity(),
        Axes::WorldNed => to_body * NED_ENU,
        Axes::WorldEnu => to_body,
    };
    // Body rates are in the body convention of the world (FRD under NED) unless the
    // twist frame names the body explicitly.
    let ang = match twist_axes {
        Axes::BodyFrd => FRD_FLU,
        Axes::BodyFlu => Matrix3::identity(),
        Axes::WorldNed | Axes::WorldEnu if ned => FRD_FLU,
        Axes::WorldNed | Axes::WorldEnu => Matrix3::identity(),
    };
    let velocity = vec3_opt(f, ["vx", "vy", "vz"])?.map(|v| lin * v);
    let angular_velocity = vec3_opt(f, ["rollspeed", "pitchspeed", "yawspeed"])?.map(|w| ang * w);

    let (pose_lin, pose_ang) = if ned {
        (NED_ENU, FRD_FLU)
    } else {
        (Matrix3::identity(), Matrix3::identity())
    };
    let pose_cov = upper_triangle(&f.f32_array::<21>("pose_covariance")?)
        .map(|c| transform_cov(c, pose_lin, pose_ang));
    let twist_cov = upper_triangle(&f.f32_array::<21>("velocity_covariance")?)
        .map(|c| transform_cov(c, lin, ang));

    let reset_counter = f
        .ext_uint("reset_counter", u8::MAX.into())?
        .map(|r| r as u8);
    // 0 = unknown/unset; -1 = failed is kept.
    let quality = f
        .ext_int("quality", i8::MIN.into(), i8::MAX.into())?
        .filter(|&q| q != 0)
        .map(|q| q as i8);
    Ok(Some((
        stamp,
        SensorData::Odometry(Box::new(Odometry {
            position,
            orientation,
            velocity,
            angular_velocity,
            pose_cov,
            twist_cov,
            frame_id: frame.to_string(),
            child_frame_id: child.to_string(),
            reset_counter,
            quality,
        })),
    )))
}
