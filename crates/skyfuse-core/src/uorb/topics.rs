//! Rows → samples: the column layout of each topic (found once per file by name, PX4
//! 1.12 – 1.16 variants) and the mapping of one row into a sample.

use super::*;

pub(crate) enum Mapper {
    Attitude(AttitudeCols),
    Imu(ImuCols),
    SensorCombined(Vec3Pair),
    AngularVelocity(Vec3Pair),
    Gps(GpsCols),
    Range(RangeCols),
    Flow(FlowCols),
    Vio(Box<VioCols>),
    Ekf2(Ekf2Cols),
    Ekf2FlowGyro(Vec3Pair),
    LandDetected(FlagCol),
    Armed(FlagCol),
    ArmingState(FlagCol),
    AirData(AirDataCols),
}

/// vehicle_air_data: the autopilot's barometer (PX4 1.12-1.15 name its temperature
/// `baro_temp_celcius`, 1.16 `ambient_temperature`).
pub(crate) struct AirDataCols {
    t: usize,
    pressure: usize,
    temperature: Option<usize>,
}

/// A timestamp and up to two vectors (sensor_combined: gyro, accel).
pub(crate) struct Vec3Pair {
    t: usize,
    a: [usize; 3],
    b: Option<[usize; 3]>,
}

pub(crate) struct FlagCol {
    t: usize,
    flag: usize,
}

pub(crate) struct GpsCols {
    t: usize,
    /// (lat, lon, alt): 1e-7° and mm (≤ 1.14) or degrees and metres (1.15).
    lat_lon_alt: [usize; 3],
    degrees: bool,
    fix: usize,
    eph: usize,
    epv: usize,
    vel: [usize; 3],
    vel_valid: usize,
    satellites: usize,
    hdop: usize,
    vdop: usize,
}

pub(crate) struct AttitudeCols {
    t: usize,
    q: [usize; 4],
}

pub(crate) struct ImuCols {
    t: usize,
    dang: [usize; 3],
    dvel: [usize; 3],
    dang_dt: usize,
    dvel_dt: usize,
}

pub(crate) struct RangeCols {
    t: usize,
    distance: usize,
    min: usize,
    max: usize,
    variance: usize,
    quality: usize,
    orientation: usize,
}

pub(crate) struct FlowCols {
    t: usize,
    flow: [usize; 2],
    gyro: [usize; 3],
    dt: usize,
    quality: usize,
    /// vehicle_optical_flow's module distance (NaN without one).
    distance: Option<usize>,
}

pub(crate) struct VioCols {
    t: usize,
    pos: [usize; 3],
    q: [usize; 4],
    vel: [usize; 3],
    rates: [usize; 3],
    /// `local_frame` (≤ 1.13) or `pose_frame` (≥ 1.14).
    pose_frame: usize,
    velocity_frame: usize,
    reset_counter: usize,
    /// Added to vehicle_odometry after v1.13; absent in older logs.
    quality: Option<usize>,
    cov: VioCov,
    /// The frame constants: ≤ 1.13 earth-fixed NED 0 / FRD 1, ≥ 1.14 NED 1 / FRD 2;
    /// body FRD is 3 in both.
    earth_frames: [i64; 2],
}

/// How vehicle_visual_odometry carries its uncertainty (inside a boxed `VioCols`: one
/// per topic, so the size difference of the variants costs nothing).
#[allow(clippy::large_enum_variant)]
pub(crate) enum VioCov {
    /// ≤ 1.13: 6×6 upper triangles (pose, velocity).
    Urt { pose: [usize; 21], vel: [usize; 21] },
    /// ≥ 1.14: per-axis variances.
    Var {
        pos: [usize; 3],
        att: [usize; 3],
        vel: [usize; 3],
    },
}

pub(crate) struct Ekf2Cols {
    t: usize,
    pos: [usize; 3],
    vel: [usize; 3],
    heading: usize,
    /// xy_valid, z_valid, v_xy_valid, v_z_valid.
    valid: [usize; 4],
}

/// uORB vehicle_odometry frame constants (v1.12/1.13).
const LOCAL_FRAME_NED: i64 = 0;
/// Earth-fixed FRD with an arbitrary heading: down is down, so it converts like NED.
const LOCAL_FRAME_FRD: i64 = 1;
const BODY_FRAME_FRD: i64 = 3;

/// How far below 0 a distance may round and still be 0 (on the ground).
const RANGE_ROUNDING_M: f64 = 0.01;

/// NED → ENU (and FRD → FLU below) as matrices, for covariances.
fn ned_to_enu_matrix() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

fn frd_to_flu_matrix() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// `c` transformed by the block-diagonal map `J = diag(a, b)`: J c Jᵀ block by block
/// (a 200 Hz camera's two covariances per row made a 6×6 triple product of mostly
/// zeros a tenth of reading its ULog).
fn transform_cov6(c: Matrix6<f64>, a: Matrix3<f64>, b: Matrix3<f64>) -> Matrix6<f64> {
    let block = |r: usize, col: usize| c.fixed_view::<3, 3>(r, col).into_owned();
    let mut out = Matrix6::zeros();
    for (r, col, left, right) in [
        (0, 0, &a, &a),
        (0, 3, &a, &b),
        (3, 0, &b, &a),
        (3, 3, &b, &b),
    ] {
        out.fixed_view_mut::<3, 3>(r, col)
            .copy_from(&(left * block(r, col) * right.transpose()));
    }
    out
}

impl Mapper {
    /// The column the sample's time comes from.
    pub(crate) fn time_column(&self) -> usize {
        match self {
            Mapper::Attitude(c) => c.t,
            Mapper::Imu(c) => c.t,
            Mapper::SensorCombined(c) | Mapper::AngularVelocity(c) | Mapper::Ekf2FlowGyro(c) => c.t,
            Mapper::Gps(c) => c.t,
            Mapper::Range(c) => c.t,
            Mapper::Flow(c) => c.t,
            Mapper::Vio(c) => c.t,
            Mapper::Ekf2(c) => c.t,
            Mapper::LandDetected(c) | Mapper::Armed(c) | Mapper::ArmingState(c) => c.t,
            Mapper::AirData(c) => c.t,
        }
    }

    pub(crate) fn new(kind: Kind, file: &Path, header: &[String]) -> Result<Self, Px4LogError> {
        Self::with_columns(kind, file, header).map(|(m, _)| m)
    }

    /// The columns a mapper of `kind` reads from `header` (true at their index): the
    /// rest need not be kept.
    pub(crate) fn columns_read(kind: Kind, file: &Path, header: &[String]) -> Option<Vec<bool>> {
        Self::with_columns(kind, file, header)
            .ok()
            .map(|(_, read)| read)
    }

    fn with_columns(
        kind: Kind,
        file: &Path,
        header: &[String],
    ) -> Result<(Self, Vec<bool>), Px4LogError> {
        let h = Cols::new(file, header);
        let mapper = Self::from_cols(kind, &h)?;
        Ok((mapper, h.read.into_inner()))
    }

    fn from_cols(kind: Kind, h: &Cols<'_>) -> Result<Self, Px4LogError> {
        let t = h.get("timestamp")?;
        Ok(match kind {
            Kind::Attitude => Mapper::Attitude(AttitudeCols {
                t,
                q: h.list(["states[0]", "states[1]", "states[2]", "states[3]"])?,
            }),
            Kind::VehicleAttitude => Mapper::Attitude(AttitudeCols { t, q: h.arr("q")? }),
            Kind::Imu => Mapper::Imu(ImuCols {
                t,
                dang: h.arr("delta_angle")?,
                dvel: h.arr("delta_velocity")?,
                dang_dt: h.get("delta_angle_dt")?,
                dvel_dt: h.get("delta_velocity_dt")?,
            }),
            Kind::SensorCombined => Mapper::SensorCombined(Vec3Pair {
                t,
                a: h.arr("gyro_rad")?,
                b: Some(h.arr("accelerometer_m_s2")?),
            }),
            Kind::AngularVelocity => Mapper::AngularVelocity(Vec3Pair {
                t,
                a: h.arr("xyz")?,
                b: None,
            }),
            Kind::Gps => {
                let degrees = h.opt("latitude_deg").is_some();
                Mapper::Gps(GpsCols {
                    t,
                    lat_lon_alt: if degrees {
                        h.list(["latitude_deg", "longitude_deg", "altitude_msl_m"])?
                    } else {
                        h.list(["lat", "lon", "alt"])?
                    },
                    degrees,
                    fix: h.get("fix_type")?,
                    eph: h.get("eph")?,
                    epv: h.get("epv")?,
                    vel: h.list(["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"])?,
                    vel_valid: h.get("vel_ned_valid")?,
                    satellites: h.get("satellites_used")?,
                    hdop: h.get("hdop")?,
                    vdop: h.get("vdop")?,
                })
            }
            Kind::AirData => Mapper::AirData(AirDataCols {
                t,
                pressure: h.get("baro_pressure_pa")?,
                temperature: h
                    .opt("baro_temp_celcius")
                    .or_else(|| h.opt("ambient_temperature")),
            }),
            Kind::Range => Mapper::Range(RangeCols {
                t,
                distance: h.get("current_distance")?,
                min: h.get("min_distance")?,
                max: h.get("max_distance")?,
                // One value, a variance, whatever older logs called it.
                variance: h.get_renamed("variance", "covariance")?,
                quality: h.get("signal_quality")?,
                orientation: h.get("orientation")?,
            }),
            Kind::Flow => Mapper::Flow(FlowCols {
                t,
                flow: h.list(["pixel_flow_x_integral", "pixel_flow_y_integral"])?,
                gyro: h.list([
                    "gyro_x_rate_integral",
                    "gyro_y_rate_integral",
                    "gyro_z_rate_integral",
                ])?,
                dt: h.get("integration_timespan")?,
                quality: h.get("quality")?,
                distance: None,
            }),
            Kind::VehicleFlow => Mapper::Flow(FlowCols {
                t,
                flow: h.arr("pixel_flow")?,
                gyro: h.arr("delta_angle")?,
                dt: h.get("integration_timespan_us")?,
                quality: h.get("quality")?,
                distance: h.opt("distance_m"),
            }),
            Kind::Vio if h.opt("local_frame").is_some() => Mapper::Vio(Box::new(VioCols {
                t,
                pos: h.list(["x", "y", "z"])?,
                q: h.arr("q")?,
                vel: h.list(["vx", "vy", "vz"])?,
                rates: h.list(["rollspeed", "pitchspeed", "yawspeed"])?,
                pose_frame: h.get("local_frame")?,
                velocity_frame: h.get("velocity_frame")?,
                reset_counter: h.get("reset_counter")?,
                quality: h.opt("quality"),
                cov: VioCov::Urt {
                    pose: h.arr("pose_covariance")?,
                    vel: h.arr("velocity_covariance")?,
                },
                earth_frames: [LOCAL_FRAME_NED, LOCAL_FRAME_FRD],
            })),
            Kind::Vio => Mapper::Vio(Box::new(VioCols {
                t,
                pos: h.arr("position")?,
                q: h.arr("q")?,
                vel: h.arr("velocity")?,
                rates: h.arr("angular_velocity")?,
                pose_frame: h.get("pose_frame")?,
                velocity_frame: h.get("velocity_frame")?,
                reset_counter: h.get("reset_counter")?,
                quality: Some(h.get("quality")?),
                cov: VioCov::Var {
                    pos: h.arr("position_variance")?,
                    att: h.arr("orientation_variance")?,
                    vel: h.arr("velocity_variance")?,
                },
                earth_frames: [1, 2],
            })),
            Kind::Ekf2 => Mapper::Ekf2(Ekf2Cols {
                t,
                pos: h.list(["x", "y", "z"])?,
                vel: h.list(["vx", "vy", "vz"])?,
                heading: h.get_renamed("heading", "yaw")?,
                valid: h.list(["xy_valid", "z_valid", "v_xy_valid", "v_z_valid"])?,
            }),
            Kind::Ekf2FlowGyro => Mapper::Ekf2FlowGyro(Vec3Pair {
                t: h.get("timestamp_sample")?,
                a: h.arr("gyro_rate_integral")?,
                b: None,
            }),
            Kind::LandDetected => Mapper::LandDetected(FlagCol {
                t,
                flag: h.get("landed")?,
            }),
            Kind::Armed => Mapper::Armed(FlagCol {
                t,
                flag: h.get("armed")?,
            }),
            Kind::ArmingState => Mapper::ArmingState(FlagCol {
                t,
                flag: h.get("arming_state")?,
            }),
        })
    }

    pub(crate) fn map(&self, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
        match self {
            Mapper::Attitude(c) => attitude(c, r),
            Mapper::Imu(c) => imu(c, r),
            Mapper::SensorCombined(c) => sensor_combined(c, r),
            Mapper::AngularVelocity(c) | Mapper::Ekf2FlowGyro(c) => {
                // Kept raw (FRD): the post-processing that attaches them converts.
                let t = r.stamp(c.t)?;
                let g = r.vec3(c.a)?;
                if !g.iter().all(|v| v.is_finite()) {
                    return Err(r.unusable(c.a[0], "not finite"));
                }
                let g = match self {
                    Mapper::AngularVelocity(_) => frames::frd_to_flu(g),
                    _ => g,
                };
                Ok((t, SensorData::Imu(Imu::from_rates(Some(g), None))))
            }
            Mapper::Gps(c) => gps(c, r),
            Mapper::AirData(c) => air_data(c, r),
            Mapper::Range(c) => range(c, r),
            Mapper::Flow(c) => flow(c, r),
            Mapper::Vio(c) => vio(c, r),
            Mapper::Ekf2(c) => ekf2(c, r),
            Mapper::LandDetected(c) => {
                let landed = r.int(c.flag, 0, 1, "0 or 1")? == 1;
                Ok((
                    r.stamp(c.t)?,
                    SensorData::VehicleState(VehicleState {
                        armed: None,
                        landed: Some(if landed {
                            LandedState::OnGround
                        } else {
                            LandedState::InAir
                        }),
                    }),
                ))
            }
            Mapper::Armed(c) => Ok((
                r.stamp(c.t)?,
                SensorData::VehicleState(VehicleState {
                    armed: Some(r.int(c.flag, 0, 1, "0 or 1")? == 1),
                    landed: None,
                }),
            )),
            // ARMING_STATE_ARMED is 2 in every version (1.14's STANDBY and 1.15's
            // DISARMED are 1).
            Mapper::ArmingState(c) => Ok((
                r.stamp(c.t)?,
                SensorData::VehicleState(VehicleState {
                    armed: Some(r.int(c.flag, 0, 255, "an integer 0..=255")? == 2),
                    landed: None,
                }),
            )),
        }
    }
}

/// sensor_combined: gyro (rad/s) and specific force (m/s²), FRD → FLU.
fn sensor_combined(c: &Vec3Pair, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
    let g = r.vec3(c.a)?;
    let a = match c.b {
        Some(b) => r.vec3(b)?,
        None => Vector3::repeat(f64::NAN),
    };
    let gyro = finite(&g).then(|| frames::frd_to_flu(g));
    let accel = finite(&a).then(|| frames::frd_to_flu(a));
    if gyro.is_none() && accel.is_none() {
        return Err(r.unusable(c.a[0], "neither gyro nor accel finite"));
    }
    Ok((t, SensorData::Imu(Imu::from_rates(gyro, accel))))
}

/// sensor_gps / vehicle_gps_position: fix, position, velocity (NED → ENU), accuracy.
fn gps(c: &GpsCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let [la, lo, al] = c.lat_lon_alt;
    let (lat, lon, alt) = if c.degrees {
        (r.f64(la)?, r.f64(lo)?, r.f64(al)?)
    } else {
        (r.f64(la)? * 1e-7, r.f64(lo)? * 1e-7, r.f64(al)? * 1e-3)
    };
    if !(lat.is_finite() && lon.is_finite() && alt.is_finite())
        || lat.abs() > 90.0
        || lon.abs() > 180.0
    {
        return Err(r.unusable(la, "position not on Earth"));
    }
    // PX4's fix_type: 0-1 none, 2 2D, 3 3D, 4 SBAS, 5 RTK float, 6 RTK fixed, 8 extrapolated.
    let fix = match r.int(c.fix, 0, 255, "an integer 0..=255")? {
        2 => GnssFixType::Fix2d,
        3 | 8 => GnssFixType::Fix3d,
        4 => GnssFixType::Dgps,
        5 => GnssFixType::RtkFloat,
        6 => GnssFixType::RtkFixed,
        _ => GnssFixType::NoFix,
    };
    let (eph, epv) = (r.f64(c.eph)?, r.f64(c.epv)?);
    let position_cov = (eph.is_finite() && epv.is_finite() && eph > 0.0 && epv > 0.0)
        .then(|| Matrix3::from_diagonal(&Vector3::new(eph * eph, eph * eph, epv * epv)));
    let vel = r.vec3(c.vel)?;
    let velocity = (r.int(c.vel_valid, 0, 1, "0 or 1")? == 1 && vel.iter().all(|v| v.is_finite()))
        .then(|| frames::ned_to_enu(vel));
    let dop = |col: usize| -> Result<Option<f64>, Px4LogError> {
        let v = r.f64(col)?;
        Ok((v.is_finite() && v > 0.0).then_some(v))
    };
    Ok((
        t,
        SensorData::Gnss(GnssFix {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            fix,
            position_cov: position_cov.map(Box::new),
            satellites: Some(r.u8(c.satellites)?),
            hdop: dop(c.hdop)?,
            vdop: dop(c.vdop)?,
            velocity,
            velocity_up_known: true,
        }),
    ))
}

/// EKF2's quaternion (body FRD → NED), standing in for the autopilot attitude a
/// companion computer would receive. estimator_states has no body rates, and is logged
/// at only 1 Hz in this export.
fn attitude(c: &AttitudeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let q = r
        .quat(c.q)?
        .ok_or_else(|| r.unusable(c.q[0], "quaternion not finite or zero"))?;
    Ok((
        t,
        SensorData::Attitude(Attitude {
            orientation: frames::q_ned_frd_to_enu_flu(q),
            rates: None,
        }),
    ))
}

/// vehicle_imu: delta angle/velocity over their dt (µs), FRD → FLU. NOTE: ulog exports
/// log this topic at only 2–20 Hz (here ~2 Hz), far too slow to drive the prediction;
/// it is useful as a bias and gravity check only.
fn imu(c: &ImuCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let per_s = |d: Vector3<f64>, dt_col: usize| -> Result<Option<Vector3<f64>>, Px4LogError> {
        let dt = r.int(dt_col, 0, u32::MAX.into(), "an interval in µs")? as f64 * 1e-6;
        Ok((dt > 0.0 && d.iter().all(|v| v.is_finite())).then(|| frames::frd_to_flu(d / dt)))
    };
    let gyro = per_s(r.vec3(c.dang)?, c.dang_dt)?;
    let accel = per_s(r.vec3(c.dvel)?, c.dvel_dt)?;
    if gyro.is_none() && accel.is_none() {
        return Err(r.unusable(c.dang_dt, "no finite delta with a non-zero dt"));
    }
    Ok((t, SensorData::Imu(Imu::from_rates(gyro, accel))))
}

fn range(c: &RangeCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let distance_m = r.finite(c.distance, "distance not finite")?;
    // A height above ground computed, not measured, rounds to just below 0 on the
    // ground (PX4 SIH: -0.00015 m): that is 0. Anything more negative is no distance.
    let distance_m = match distance_m {
        d if d >= 0.0 => d,
        d if d > -RANGE_ROUNDING_M => 0.0,
        _ => return Err(r.unusable(c.distance, "negative distance")),
    };
    let (min, max) = (r.f64(c.min)?, r.f64(c.max)?);
    // Some drivers leave both limits 0: that is "not set", not a zero-width window.
    let limits =
        (min.is_finite() && max.is_finite() && min >= 0.0 && max > min).then_some((min, max));
    let variance = r.f64(c.variance)?;
    // PX4: -1 unknown, 0 invalid, 1..100 percent. The sample follows MAVLink (0 unknown,
    // 1 invalid), and this is the mapping PX4's own DISTANCE_SENSOR stream applies.
    let signal_quality = match r.int(c.quality, i8::MIN.into(), 100, "an integer -128..=100")? {
        q if q < 0 => None,
        0 => Some(1),
        q => Some(q as u8),
    };
    Ok((
        t,
        SensorData::Range(Range {
            distance_m,
            min_m: limits.map(|l| l.0),
            max_m: limits.map(|l| l.1),
            signal_quality,
            variance: (variance.is_finite() && variance > 0.0).then_some(variance),
            orientation: Some(r.u8(c.orientation)?),
        }),
    ))
}

/// vehicle_air_data → a barometer (Pa, °C).
fn air_data(c: &AirDataCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let pressure_pa = r.finite(c.pressure, "pressure not finite")?;
    if !(crate::sample::BARO_MIN_PA..=crate::sample::BARO_MAX_PA).contains(&pressure_pa) {
        return Err(r.unusable(c.pressure, "not an air pressure in Pa"));
    }
    let temperature = match c.temperature {
        Some(col) => r.f64(col)?,
        None => f64::NAN,
    };
    Ok((
        t,
        SensorData::Baro(crate::sample::Baro {
            pressure_pa,
            temperature_c: temperature.is_finite().then_some(temperature),
            variance: None,
        }),
    ))
}

/// optical_flow: PX4 integrates flow and gyro in the sensor's (rotated to body) FRD
/// axes, a right-handed rotation about an axis counting positive, so that
/// flow = ω + (−v_y, v_x)/d in FRD. The sample's convention (sample.rs, the simulator,
/// the estimator) is the same sign rule in FLU axes, rate = ω + (v_y, −v_x)/d: y of both
/// the flow and the gyro changes sign. Checked on the real flight against VIO (tests).
/// A row without an integration time has no rate and is skipped; a NaN gyro (modules
/// without one) becomes `None`.
fn flow(c: &FlowCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let dt_us = r.int(c.dt, 0, u32::MAX.into(), "an interval in µs")?;
    if dt_us == 0 {
        return Err(r.unusable(c.dt, "integration_timespan is 0: no rate"));
    }
    let dt = dt_us as f64 * 1e-6;
    let fx = r.finite(c.flow[0], "flow integral not finite")?;
    let fy = r.finite(c.flow[1], "flow integral not finite")?;
    let g = r.vec3(c.gyro)?;
    Ok((
        t,
        SensorData::Flow(OpticalFlow {
            rate: Some(Vector2::new(fx / dt, -fy / dt)),
            gyro: g
                .iter()
                .all(|v| v.is_finite())
                .then(|| frames::frd_to_flu(g / dt)),
            velocity: None,
            integration_s: Some(dt),
            quality: r.u8(c.quality)?,
            status: None,
            // optical_flow's ground_distance_m is 0 without a module ToF (not read);
            // vehicle_optical_flow's distance_m is NaN without one. The range finder is
            // its own topic.
            tof: match c.distance {
                Some(col) => {
                    let d = r.f64(col)?;
                    (d.is_finite() && d > 0.0).then_some(Tof {
                        distance_m: d,
                        strength: None,
                        precision: None,
                        status: None,
                    })
                }
                None => None,
            },
        }),
    ))
}

/// vehicle_visual_odometry, both layouts: pose in an earth-fixed NED frame (or FRD with
/// an arbitrary heading, which converts the same way), body FRD; velocity in
/// `velocity_frame`, turned into body FLU as nav_msgs/Odometry has it; covariances as
/// 6×6 upper triangles (≤ 1.13) or per-axis variances (≥ 1.14).
fn vio(c: &VioCols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let pose_frame = r.int(c.pose_frame, 0, 255, "a frame constant")?;
    if !c.earth_frames.contains(&pose_frame) {
        return Err(r.unusable(c.pose_frame, "pose frame is neither NED nor FRD"));
    }
    let pos = r.vec3(c.pos)?;
    if !pos.iter().all(|v| v.is_finite()) {
        return Err(r.unusable(c.pos[0], "position not finite"));
    }
    let q_ned = r
        .quat(c.q)?
        .ok_or_else(|| r.unusable(c.q[0], "quaternion not finite or zero"))?;
    let q = frames::q_ned_frd_to_enu_flu(q_ned);
    let p = ned_to_enu_matrix();
    let f = frd_to_flu_matrix();
    // The linear map from the message's velocity to body FLU, if its frame is known.
    let vel_map = match r.int(c.velocity_frame, 0, 255, "a frame constant")? {
        v if c.earth_frames.contains(&v) => Some(q.to_rotation_matrix().matrix().transpose() * p),
        BODY_FRAME_FRD => Some(f),
        _ => None,
    };
    let vel = r.vec3(c.vel)?;
    let velocity = vel_map
        .filter(|_| vel.iter().all(|v| v.is_finite()))
        .map(|m| m * vel);
    let rates = r.vec3(c.rates)?;
    let angular_velocity = rates
        .iter()
        .all(|v| v.is_finite())
        .then(|| frames::frd_to_flu(rates));
    let (pose_cov, vel_cov) = match &c.cov {
        VioCov::Urt { pose, vel } => (r.urt6(pose)?, r.urt6(vel)?),
        VioCov::Var { pos, att, vel } => (
            diag6(r.vec3(*pos)?, r.vec3(*att)?),
            diag6(r.vec3(*vel)?, Vector3::zeros()),
        ),
    };
    let pose_cov = pose_cov.map(|cov| transform_cov6(cov, p, p));
    let twist_cov = match (vel_map, vel_cov) {
        (Some(m), Some(cov)) => Some(transform_cov6(cov, m, f)),
        _ => None,
    };
    let quality = match c.quality {
        Some(col) => {
            Some(r.int(col, i8::MIN.into(), i8::MAX.into(), "an integer -128..=127")? as i8)
        }
        None => None,
    };
    Ok((
        t,
        SensorData::Odometry(Box::new(Odometry {
            position: frames::ned_to_enu(pos),
            orientation: q,
            velocity,
            angular_velocity,
            pose_cov,
            twist_cov,
            frame_id: "px4_vio_odom".to_string(),
            child_frame_id: "px4_vio_body".to_string(),
            reset_counter: Some(r.u8(c.reset_counter)?),
            quality,
        })),
    ))
}

/// A 6×6 diagonal covariance from two per-axis variance triples; `None` unless all are
/// finite and non-negative.
fn diag6(a: Vector3<f64>, b: Vector3<f64>) -> Option<Matrix6<f64>> {
    a.iter()
        .chain(b.iter())
        .all(|v| v.is_finite() && *v >= 0.0)
        .then(|| {
            let mut m = Matrix6::zeros();
            for i in 0..3 {
                m[(i, i)] = a[i];
                m[(i + 3, i + 3)] = b[i];
            }
            m
        })
}

/// vehicle_local_position: position and velocity only where PX4 flags them valid (PX4's
/// own LOCAL_POSITION_NED stream holds back invalid ones too); heading where finite. No
/// geodetic position: an indoor log has no reference (ref_lat/lon NaN).
fn ekf2(c: &Ekf2Cols, r: &Row<'_>) -> Result<(Micros, SensorData), Px4LogError> {
    let t = r.stamp(c.t)?;
    let flag = |col: usize| -> Result<bool, Px4LogError> { Ok(r.int(col, 0, 1, "0 or 1")? == 1) };
    let [xy, z, vxy, vz] = c.valid;
    let pos = r.vec3(c.pos)?;
    let vel = r.vec3(c.vel)?;
    let finite = |v: &Vector3<f64>| v.iter().all(|x| x.is_finite());
    let local_position = (flag(xy)? && flag(z)? && finite(&pos)).then(|| frames::ned_to_enu(pos));
    let velocity = (flag(vxy)? && flag(vz)? && finite(&vel)).then(|| frames::ned_to_enu(vel));
    let heading = r.f64(c.heading)?;
    let yaw = heading.is_finite().then(|| frames::yaw_ned_to_enu(heading));
    if local_position.is_none() && velocity.is_none() && yaw.is_none() {
        return Err(r.unusable(c.heading, "no valid position, velocity or heading"));
    }
    Ok((
        t,
        SensorData::AutopilotEstimate(AutopilotEstimate {
            local_position,
            geodetic: None,
            velocity,
            yaw,
        }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Block by block, the transform is the dense J c Jᵀ (a rotation and a sign flip,
    /// over a full covariance).
    #[test]
    fn a_block_diagonal_transform_is_the_dense_product() {
        let c = Matrix6::from_fn(|i, j| 1.0 / (1.0 + i as f64 + j as f64) + (i * j) as f64 * 0.01);
        let a = *nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 1.1).matrix();
        let b = frd_to_flu_matrix();
        let mut jm = Matrix6::zeros();
        jm.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
        jm.fixed_view_mut::<3, 3>(3, 3).copy_from(&b);
        let dense = jm * c * jm.transpose();
        let blocks = transform_cov6(c, a, b);
        assert!((blocks - dense).amax() < 1e-15, "{blocks} {dense}");
        // A permutation with signs (NED → ENU) moves entries exactly.
        let p = ned_to_enu_matrix();
        let mut jp = Matrix6::zeros();
        jp.fixed_view_mut::<3, 3>(0, 0).copy_from(&p);
        jp.fixed_view_mut::<3, 3>(3, 3).copy_from(&p);
        assert_eq!(transform_cov6(c, p, p), jp * c * jp.transpose());
    }
}
