//! The inverse of the decoders: a sample as the MAVLink message that carries it (ENU/FLU,
//! SI → NED/FRD, MAVLink units), for the simulator and for round-trip tests. Unknown
//! values are written the way MAVLink marks them unknown, so decoding gives `None` back.

use super::map::{transform_cov, FRD_FLU, NED_ENU};
use crate::codec::error::EncodeError;
use crate::sample::{frames, GnssFixType, LandedState, Micros, SensorData};
use ::mavlink::dialects::common::{
    self, GpsFixType, HighresImuUpdatedFlags, MavDistanceSensor, MavEstimatorType, MavFrame,
    MavMessage, MavSensorOrientation,
};
use nalgebra::{Matrix6, Vector3};

/// The message that carries `data`, stamped `stamp_us`:
/// Imu → HIGHRES_IMU, Attitude → ATTITUDE_QUATERNION, Gnss → GPS_RAW_INT,
/// Flow → OPTICAL_FLOW_RAD when it has an integration time, else OPTICAL_FLOW,
/// Range → DISTANCE_SENSOR, Odometry → ODOMETRY (LOCAL_NED / BODY_FRD),
/// AutopilotEstimate → LOCAL_POSITION_NED, or GLOBAL_POSITION_INT without a local position,
/// Baro → SCALED_PRESSURE.
pub fn sample_to_message(stamp_us: Micros, data: &SensorData) -> Result<MavMessage, EncodeError> {
    match data {
        SensorData::Imu(imu) => {
            use HighresImuUpdatedFlags as U;
            let mut d = common::HIGHRES_IMU_DATA {
                time_usec: usec(stamp_us)?,
                ..Default::default()
            };
            let mut updated = U::empty();
            if let Some(a) = imu.accel {
                [d.xacc, d.yacc, d.zacc] = f32x3("imu.accel", frames::frd_to_flu(a))?;
                updated |= U::HIGHRES_IMU_UPDATED_XACC
                    | U::HIGHRES_IMU_UPDATED_YACC
                    | U::HIGHRES_IMU_UPDATED_ZACC;
            }
            if let Some(g) = imu.gyro {
                [d.xgyro, d.ygyro, d.zgyro] = f32x3("imu.gyro", frames::frd_to_flu(g))?;
                updated |= U::HIGHRES_IMU_UPDATED_XGYRO
                    | U::HIGHRES_IMU_UPDATED_YGYRO
                    | U::HIGHRES_IMU_UPDATED_ZGYRO;
            }
            if updated.is_empty() {
                return Err(EncodeError::Unsupported(
                    "HIGHRES_IMU needs accel or gyro".into(),
                ));
            }
            d.fields_updated = updated;
            Ok(MavMessage::HIGHRES_IMU(d))
        }
        SensorData::Attitude(att) => {
            // The ENU/FLU ↔ NED/FRD change of frames is its own inverse.
            let q = frames::q_ned_frd_to_enu_flu(att.orientation);
            // ATTITUDE_QUATERNION has no "unknown" for rates: zero when the sample has none.
            let rates = att.rates.map(frames::frd_to_flu).unwrap_or_default();
            let [rollspeed, pitchspeed, yawspeed] = f32x3("attitude.rates", rates)?;
            Ok(MavMessage::ATTITUDE_QUATERNION(
                common::ATTITUDE_QUATERNION_DATA {
                    time_boot_ms: boot_ms(stamp_us)?,
                    q1: f32_of("attitude.orientation.w", q.w)?,
                    q2: f32_of("attitude.orientation.x", q.i)?,
                    q3: f32_of("attitude.orientation.y", q.j)?,
                    q4: f32_of("attitude.orientation.z", q.k)?,
                    rollspeed,
                    pitchspeed,
                    yawspeed,
                    ..Default::default()
                },
            ))
        }
        SensorData::Gnss(g) => {
            const UNKNOWN16: u16 = u16::MAX;
            let fix_type = match g.fix {
                GnssFixType::NoFix => GpsFixType::GPS_FIX_TYPE_NO_FIX,
                GnssFixType::Fix2d => GpsFixType::GPS_FIX_TYPE_2D_FIX,
                GnssFixType::Fix3d => GpsFixType::GPS_FIX_TYPE_3D_FIX,
                GnssFixType::Dgps => GpsFixType::GPS_FIX_TYPE_DGPS,
                GnssFixType::RtkFloat => GpsFixType::GPS_FIX_TYPE_RTK_FLOAT,
                GnssFixType::RtkFixed => GpsFixType::GPS_FIX_TYPE_RTK_FIXED,
            };
            // UINT16_MAX is "unknown", so known values stop one below it.
            let known16 = |field: &str, v: Option<f64>| -> Result<u16, EncodeError> {
                match v {
                    Some(v) => int_of(field, v, 0.0, f64::from(UNKNOWN16 - 1)),
                    None => Ok(UNKNOWN16),
                }
            };
            let (vel, cog) = match g.velocity {
                Some(v) => {
                    let speed_cm = v.x.hypot(v.y) * 100.0;
                    let course = v.x.atan2(v.y).to_degrees().rem_euclid(360.0);
                    let cog = int_of::<u16>("gnss.velocity", course * 100.0, 0.0, 36000.0)?;
                    (
                        known16("gnss.velocity", Some(speed_cm))?,
                        if cog == 36000 { 0 } else { cog },
                    )
                }
                None => (UNKNOWN16, UNKNOWN16),
            };
            let (h_acc, v_acc) = match g.position_cov.as_deref() {
                Some(c) => (
                    int_of(
                        "gnss.position_cov",
                        c[(0, 0)].max(c[(1, 1)]).sqrt() * 1000.0,
                        0.0,
                        4e9,
                    )?,
                    int_of("gnss.position_cov", c[(2, 2)].sqrt() * 1000.0, 0.0, 4e9)?,
                ),
                None => (0, 0),
            };
            Ok(MavMessage::GPS_RAW_INT(common::GPS_RAW_INT_DATA {
                time_usec: usec(stamp_us)?,
                fix_type,
                lat: int_of("gnss.lat_deg", g.lat_deg * 1e7, -9e8, 9e8)?,
                lon: int_of("gnss.lon_deg", g.lon_deg * 1e7, -18e8, 18e8)?,
                alt: int_of(
                    "gnss.alt_m",
                    g.alt_m * 1000.0,
                    i32::MIN.into(),
                    i32::MAX.into(),
                )?,
                eph: known16("gnss.hdop", g.hdop.map(|d| d * 100.0))?,
                epv: known16("gnss.vdop", g.vdop.map(|d| d * 100.0))?,
                vel,
                cog,
                satellites_visible: g.satellites.map_or(u8::MAX, |s| s.min(u8::MAX - 1)),
                h_acc,
                v_acc,
                ..Default::default()
            }))
        }
        SensorData::Flow(fl) => {
            // Unknown distance is negative in both flow messages.
            let distance = fl.tof.as_ref().map_or(-1.0, |t| t.distance_m);
            match fl.integration_s {
                Some(dt) => {
                    let rate = fl.rate.unwrap_or_default();
                    let gyro = fl
                        .gyro
                        .map(|g| frames::frd_to_flu(g) * dt)
                        .unwrap_or(Vector3::repeat(f64::NAN));
                    Ok(MavMessage::OPTICAL_FLOW_RAD(
                        common::OPTICAL_FLOW_RAD_DATA {
                            time_usec: usec(stamp_us)?,
                            integration_time_us: int_of(
                                "flow.integration_s",
                                dt * 1e6,
                                0.0,
                                u32::MAX.into(),
                            )?,
                            integrated_x: f32_of("flow.rate.x", rate.x * dt)?,
                            // FLU → PX4's FRD convention (see the decoder).
                            integrated_y: f32_of("flow.rate.y", -rate.y * dt)?,
                            integrated_xgyro: f32_or_nan(gyro.x),
                            integrated_ygyro: f32_or_nan(gyro.y),
                            integrated_zgyro: f32_or_nan(gyro.z),
                            distance: f32_of("flow.tof.distance_m", distance)?,
                            quality: fl.quality,
                            ..Default::default()
                        },
                    ))
                }
                None => {
                    let [vx, vy] = fl.velocity.map(|v| [v.x, -v.y]).unwrap_or([f64::NAN; 2]);
                    let [rx, ry] = fl.rate.map(|r| [r.x, -r.y]).unwrap_or([f64::NAN; 2]);
                    Ok(MavMessage::OPTICAL_FLOW(common::OPTICAL_FLOW_DATA {
                        time_usec: usec(stamp_us)?,
                        flow_comp_m_x: f32_or_nan(vx),
                        flow_comp_m_y: f32_or_nan(vy),
                        ground_distance: f32_of("flow.tof.distance_m", distance)?,
                        quality: fl.quality,
                        flow_rate_x: f32_or_nan(rx),
                        flow_rate_y: f32_or_nan(ry),
                        ..Default::default()
                    }))
                }
            }
        }
        SensorData::Range(r) => {
            let cm = |field: &str, m: f64| int_of::<u16>(field, m * 100.0, 0.0, u16::MAX.into());
            // 0 is "unknown" (UINT8_MAX too), so a known variance is at least 1 cm².
            let covariance = match r.variance {
                Some(v) => int_of::<u8>("range.variance", (v * 1e4).max(1.0), 1.0, 254.0)?,
                None => 0,
            };
            Ok(MavMessage::DISTANCE_SENSOR(common::DISTANCE_SENSOR_DATA {
                time_boot_ms: boot_ms(stamp_us)?,
                min_distance: cm("range.min_m", r.min_m.unwrap_or(0.0))?,
                max_distance: cm("range.max_m", r.max_m.unwrap_or(0.0))?,
                current_distance: cm("range.distance_m", r.distance_m)?,
                mavtype: MavDistanceSensor::MAV_DISTANCE_SENSOR_LASER,
                orientation: orientation(r.orientation.unwrap_or(25))?,
                covariance,
                signal_quality: r.signal_quality.unwrap_or(0),
                ..Default::default()
            }))
        }
        SensorData::Odometry(o) => {
            let p = frames::ned_to_enu(o.position);
            let q = frames::q_ned_frd_to_enu_flu(o.orientation);
            let nan3 = Vector3::repeat(f64::NAN);
            let v = o.velocity.map(frames::frd_to_flu).unwrap_or(nan3);
            let w = o.angular_velocity.map(frames::frd_to_flu).unwrap_or(nan3);
            let [x, y, z] = f32x3("odometry.position", p)?;
            let [vx, vy, vz] = v.map(f32_or_nan).into();
            let [rollspeed, pitchspeed, yawspeed] = w.map(f32_or_nan).into();
            Ok(MavMessage::ODOMETRY(common::ODOMETRY_DATA {
                time_usec: usec(stamp_us)?,
                x,
                y,
                z,
                q: [
                    f32_of("odometry.orientation.w", q.w)?,
                    f32_of("odometry.orientation.x", q.i)?,
                    f32_of("odometry.orientation.y", q.j)?,
                    f32_of("odometry.orientation.z", q.k)?,
                ],
                vx,
                vy,
                vz,
                rollspeed,
                pitchspeed,
                yawspeed,
                pose_covariance: upper_triangle(
                    o.pose_cov.map(|c| transform_cov(c, NED_ENU, FRD_FLU)),
                ),
                velocity_covariance: upper_triangle(
                    o.twist_cov.map(|c| transform_cov(c, FRD_FLU, FRD_FLU)),
                ),
                frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
                child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
                reset_counter: o.reset_counter.unwrap_or(0),
                estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_UNKNOWN,
                // 0 is "unknown".
                quality: o.quality.unwrap_or(0),
            }))
        }
        SensorData::Baro(b) => Ok(MavMessage::SCALED_PRESSURE(common::SCALED_PRESSURE_DATA {
            time_boot_ms: boot_ms(stamp_us)?,
            press_abs: f32_of("baro.pressure", b.pressure_pa / 100.0)?,
            press_diff: 0.0,
            temperature: b
                .temperature_c
                .map_or(0, |t| (t * 100.0).round().clamp(-32768.0, 32767.0) as i16),
            ..Default::default()
        })),
        SensorData::VehicleState(v) => {
            use common::{MavAutopilot, MavLandedState, MavModeFlag, MavState, MavType};
            if let Some(l) = v.landed {
                return Ok(MavMessage::EXTENDED_SYS_STATE(
                    common::EXTENDED_SYS_STATE_DATA {
                        vtol_state: common::MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                        landed_state: match l {
                            LandedState::OnGround => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
                            LandedState::InAir => MavLandedState::MAV_LANDED_STATE_IN_AIR,
                            LandedState::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
                            LandedState::Landing => MavLandedState::MAV_LANDED_STATE_LANDING,
                        },
                    },
                ));
            }
            let Some(armed) = v.armed else {
                return Err(EncodeError::Unsupported(
                    "a vehicle state with neither armed nor landed".into(),
                ));
            };
            let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
            if armed {
                base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
            }
            Ok(MavMessage::HEARTBEAT(common::HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_QUADROTOR,
                autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
                base_mode,
                system_status: if armed {
                    MavState::MAV_STATE_ACTIVE
                } else {
                    MavState::MAV_STATE_STANDBY
                },
                mavlink_version: 3,
            }))
        }
        SensorData::AutopilotEstimate(e) => {
            if let Some(p) = e.local_position {
                let [x, y, z] = f32x3("autopilot_estimate.local_position", frames::ned_to_enu(p))?;
                let v = e
                    .velocity
                    .map(frames::ned_to_enu)
                    .unwrap_or(Vector3::repeat(f64::NAN));
                return Ok(MavMessage::LOCAL_POSITION_NED(
                    common::LOCAL_POSITION_NED_DATA {
                        time_boot_ms: boot_ms(stamp_us)?,
                        x,
                        y,
                        z,
                        vx: f32_or_nan(v.x),
                        vy: f32_or_nan(v.y),
                        vz: f32_or_nan(v.z),
                    },
                ));
            }
            let Some((lat, lon, alt)) = e.geodetic else {
                return Err(EncodeError::Unsupported(
                    "an autopilot estimate with neither a local nor a geodetic position".into(),
                ));
            };
            // GLOBAL_POSITION_INT has no "unknown" velocity: zero when there is none.
            let v = e.velocity.map(frames::ned_to_enu).unwrap_or_default() * 100.0;
            let i16_of =
                |field: &str, x: f64| int_of::<i16>(field, x, i16::MIN.into(), i16::MAX.into());
            // ENU yaw → NED heading (0 = north, clockwise), which the same formula gives.
            let hdg = match e.yaw {
                Some(y) => {
                    let deg = frames::yaw_ned_to_enu(y).to_degrees().rem_euclid(360.0);
                    let c = int_of::<u16>("autopilot_estimate.yaw", deg * 100.0, 0.0, 36000.0)?;
                    if c == 36000 {
                        0
                    } else {
                        c
                    }
                }
                None => u16::MAX,
            };
            Ok(MavMessage::GLOBAL_POSITION_INT(
                common::GLOBAL_POSITION_INT_DATA {
                    time_boot_ms: boot_ms(stamp_us)?,
                    lat: int_of("autopilot_estimate.lat", lat * 1e7, -9e8, 9e8)?,
                    lon: int_of("autopilot_estimate.lon", lon * 1e7, -18e8, 18e8)?,
                    alt: int_of(
                        "autopilot_estimate.alt",
                        alt * 1000.0,
                        i32::MIN.into(),
                        i32::MAX.into(),
                    )?,
                    relative_alt: 0,
                    vx: i16_of("autopilot_estimate.velocity", v.x)?,
                    vy: i16_of("autopilot_estimate.velocity", v.y)?,
                    vz: i16_of("autopilot_estimate.velocity", v.z)?,
                    hdg,
                },
            ))
        }
    }
}

fn usec(stamp_us: Micros) -> Result<u64, EncodeError> {
    u64::try_from(stamp_us).map_err(|_| EncodeError::OutOfRange {
        field: "stamp_us".into(),
        value: stamp_us as f64,
    })
}

fn boot_ms(stamp_us: Micros) -> Result<u32, EncodeError> {
    u32::try_from(stamp_us.div_euclid(1000)).map_err(|_| EncodeError::OutOfRange {
        field: "stamp_us (as time_boot_ms)".into(),
        value: stamp_us as f64,
    })
}

fn f32_of(field: &str, v: f64) -> Result<f32, EncodeError> {
    if !v.is_finite() {
        return Err(EncodeError::NonFinite {
            field: field.into(),
            value: v,
        });
    }
    let x = v as f32;
    if !x.is_finite() {
        return Err(EncodeError::OutOfRange {
            field: field.into(),
            value: v,
        });
    }
    Ok(x)
}

/// For fields where NaN means "unknown": any value, NaN passed through.
fn f32_or_nan(v: f64) -> f32 {
    v as f32
}

fn f32x3(field: &str, v: Vector3<f64>) -> Result<[f32; 3], EncodeError> {
    Ok([
        f32_of(&format!("{field}.x"), v.x)?,
        f32_of(&format!("{field}.y"), v.y)?,
        f32_of(&format!("{field}.z"), v.z)?,
    ])
}

/// `v` rounded to an integer type, within `[lo, hi]`.
fn int_of<T: TryFrom<i64>>(field: &str, v: f64, lo: f64, hi: f64) -> Result<T, EncodeError> {
    if !v.is_finite() {
        return Err(EncodeError::NonFinite {
            field: field.into(),
            value: v,
        });
    }
    let r = v.round();
    let out_of_range = || EncodeError::OutOfRange {
        field: field.into(),
        value: v,
    };
    if r < lo || r > hi {
        return Err(out_of_range());
    }
    T::try_from(r as i64).map_err(|_| out_of_range())
}

/// Range-finder orientations by MAV_SENSOR_ORIENTATION value: the directions
/// DISTANCE_SENSOR documents (rust-mavlink has no public number → enum conversion).
fn orientation(v: u8) -> Result<MavSensorOrientation, EncodeError> {
    use MavSensorOrientation as O;
    Ok(match v {
        0 => O::MAV_SENSOR_ROTATION_NONE,
        2 => O::MAV_SENSOR_ROTATION_YAW_90,
        4 => O::MAV_SENSOR_ROTATION_YAW_180,
        6 => O::MAV_SENSOR_ROTATION_YAW_270,
        12 => O::MAV_SENSOR_ROTATION_PITCH_180,
        24 => O::MAV_SENSOR_ROTATION_PITCH_90,
        25 => O::MAV_SENSOR_ROTATION_PITCH_270,
        100 => O::MAV_SENSOR_ROTATION_CUSTOM,
        _ => {
            return Err(EncodeError::OutOfRange {
                field: "range.orientation (not a range-finder direction)".into(),
                value: f64::from(v),
            })
        }
    })
}

/// Row-major upper triangle; unknown = NaN in the first element (MAVLink's convention).
fn upper_triangle(c: Option<Matrix6<f64>>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    match c {
        Some(c) => {
            let mut slots = out.iter_mut();
            for r in 0..6 {
                for col in r..6 {
                    if let Some(s) = slots.next() {
                        *s = c[(r, col)] as f32;
                    }
                }
            }
        }
        None => {
            if let Some(first) = out.first_mut() {
                *first = f32::NAN;
            }
        }
    }
    out
}
