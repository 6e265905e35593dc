//! ROS messages ⇄ skyfuse samples. ROS data is already REP-103 (ENU world, FLU body),
//! so nothing is rotated here: this is validation and unit bookkeeping only.

use super::msgs::{self, Header, NavSatStatus, RosMessage};
use super::RosType;
use crate::codec::error::{finite, in_range, DecodeError, EncodeError};
use crate::sample::{
    Baro, Decoded, GnssFix, GnssFixType, Imu, Micros, Odometry, OpticalFlow, Range, SensorData, Tof,
};
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};

// ---------------------------------------------------------------- decoding

fn fin(prefix: &str, name: &str, v: f64) -> Result<f64, DecodeError> {
    if v.is_finite() {
        Ok(v)
    } else {
        finite(&format!("{prefix}.{name}"), v)
    }
}

fn vec3(prefix: &str, v: &msgs::Vector3) -> Result<Vector3<f64>, DecodeError> {
    Ok(Vector3::new(
        fin(prefix, "x", v.x)?,
        fin(prefix, "y", v.y)?,
        fin(prefix, "z", v.z)?,
    ))
}

fn check_all_finite(field: &str, m: &[f64]) -> Result<(), DecodeError> {
    match m.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => finite(
            &format!("{field}[{i}]"),
            m.get(i).copied().unwrap_or(f64::NAN),
        )
        .map(|_| ()),
    }
}

/// A covariance; all zeros is ROS's "unknown" and becomes `None`.
fn cov3(field: &str, m: &[f64; 9]) -> Result<Option<Matrix3<f64>>, DecodeError> {
    check_all_finite(field, m)?;
    Ok((!m.iter().all(|&x| x == 0.0)).then(|| Matrix3::from_row_slice(m)))
}

fn cov6(field: &str, m: &[f64; 36]) -> Result<Option<Matrix6<f64>>, DecodeError> {
    check_all_finite(field, m)?;
    Ok((!m.iter().all(|&x| x == 0.0)).then(|| Matrix6::from_row_slice(m)))
}

/// A quaternion, normalised. All zeros (what a publisher that never set it sends) is
/// `None`; a norm far from 1 means the field is not a rotation and is rejected.
fn quaternion(
    field: &str,
    q: &msgs::Quaternion,
) -> Result<Option<UnitQuaternion<f64>>, DecodeError> {
    let (x, y, z, w) = (
        fin(field, "x", q.x)?,
        fin(field, "y", q.y)?,
        fin(field, "z", q.z)?,
        fin(field, "w", q.w)?,
    );
    let q = Quaternion::new(w, x, y, z);
    let norm = q.norm();
    if norm == 0.0 {
        return Ok(None);
    }
    if norm <= 0.5 || norm >= 2.0 {
        return Err(DecodeError::OutOfRange {
            field: field.to_string(),
            value: norm,
            reason: "quaternion norm must be close to 1",
        });
    }
    Ok(Some(UnitQuaternion::from_quaternion(q)))
}

fn required_quaternion(
    field: &str,
    q: &msgs::Quaternion,
) -> Result<UnitQuaternion<f64>, DecodeError> {
    quaternion(field, q)?.ok_or_else(|| DecodeError::OutOfRange {
        field: field.to_string(),
        value: 0.0,
        reason: "all-zero quaternion is not an orientation",
    })
}

fn decoded(header: &Header, ros1: bool, data: SensorData) -> Decoded {
    Decoded {
        stamp_us: header.stamp_us(ros1),
        mav_origin: None,
        data,
    }
}

pub fn navsatfix(m: &msgs::NavSatFix, ros1: bool) -> Result<Decoded, DecodeError> {
    let fix = match m.status.status {
        NavSatStatus::STATUS_NO_FIX => GnssFixType::NoFix,
        NavSatStatus::STATUS_FIX => GnssFixType::Fix3d,
        NavSatStatus::STATUS_SBAS_FIX | NavSatStatus::STATUS_GBAS_FIX => GnssFixType::Dgps,
        other => {
            return Err(DecodeError::OutOfRange {
                field: "NavSatFix.status.status".into(),
                value: other.into(),
                reason: "not a NavSatStatus value (-1 no fix, 0 fix, 1 SBAS, 2 GBAS)",
            })
        }
    };
    let lat_deg = in_range(
        "NavSatFix.latitude",
        m.latitude,
        -90.0,
        90.0,
        "latitude must be within [-90, 90] degrees",
    )?;
    let lon_deg = in_range(
        "NavSatFix.longitude",
        m.longitude,
        -180.0,
        180.0,
        "longitude must be within [-180, 180] degrees",
    )?;
    let alt_m = finite("NavSatFix.altitude", m.altitude)?;
    let position_cov = if m.position_covariance_type == msgs::NavSatFix::COVARIANCE_TYPE_UNKNOWN {
        None
    } else {
        check_all_finite("NavSatFix.position_covariance", &m.position_covariance)?;
        Some(Matrix3::from_row_slice(&m.position_covariance))
    };
    Ok(decoded(
        &m.header,
        ros1,
        SensorData::Gnss(GnssFix {
            lat_deg,
            lon_deg,
            alt_m,
            fix,
            position_cov: position_cov.map(Box::new),
            satellites: None,
            hdop: None,
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        }),
    ))
}

/// Covariance element 0 = -1 is sensor_msgs/Imu's "this quantity is not provided".
fn imu_provided(cov: &[f64; 9]) -> bool {
    cov[0] != -1.0
}

pub fn imu(m: &msgs::Imu, ros1: bool) -> Result<Decoded, DecodeError> {
    let (orientation, orientation_cov) = if imu_provided(&m.orientation_covariance) {
        match quaternion("Imu.orientation", &m.orientation)? {
            Some(q) => (
                Some(q),
                cov3("Imu.orientation_covariance", &m.orientation_covariance)?,
            ),
            None => (None, None),
        }
    } else {
        (None, None)
    };
    let (gyro, gyro_cov) = if imu_provided(&m.angular_velocity_covariance) {
        (
            Some(vec3("Imu.angular_velocity", &m.angular_velocity)?),
            cov3(
                "Imu.angular_velocity_covariance",
                &m.angular_velocity_covariance,
            )?,
        )
    } else {
        (None, None)
    };
    let (accel, accel_cov) = if imu_provided(&m.linear_acceleration_covariance) {
        (
            Some(vec3("Imu.linear_acceleration", &m.linear_acceleration)?),
            cov3(
                "Imu.linear_acceleration_covariance",
                &m.linear_acceleration_covariance,
            )?,
        )
    } else {
        (None, None)
    };
    Ok(decoded(
        &m.header,
        ros1,
        SensorData::Imu(Imu {
            gyro,
            accel,
            orientation,
            gyro_cov: gyro_cov.map(Box::new),
            accel_cov: accel_cov.map(Box::new),
            orientation_cov: orientation_cov.map(Box::new),
        }),
    ))
}

/// A range limit: unknown (`None`) unless a finite, non-negative number.
fn limit(v: f32) -> Option<f64> {
    let v = f64::from(v);
    (v.is_finite() && v >= 0.0).then_some(v)
}

pub fn range(m: &msgs::Range, ros1: bool) -> Result<Decoded, DecodeError> {
    const FIELD: &str = "Range.range";
    let r = f64::from(m.range);
    if r == f64::INFINITY {
        return Err(DecodeError::OutOfRange {
            field: FIELD.into(),
            value: r,
            reason: "+Inf: no target within max_range (REP-117)",
        });
    }
    if r == f64::NEG_INFINITY {
        return Err(DecodeError::OutOfRange {
            field: FIELD.into(),
            value: r,
            reason: "-Inf: target closer than min_range (REP-117)",
        });
    }
    let distance_m = in_range(FIELD, r, 0.0, f64::MAX, "a distance cannot be negative")?;
    // Jazzy: "0 is interpreted as variance unknown".
    let variance = m
        .variance
        .map(f64::from)
        .filter(|v| v.is_finite() && *v > 0.0);
    Ok(decoded(
        &m.header,
        ros1,
        SensorData::Range(Range {
            distance_m,
            min_m: limit(m.min_range),
            max_m: limit(m.max_range),
            signal_quality: None,
            variance,
            orientation: None,
        }),
    ))
}

/// A barometer. `fluid_pressure` is Pa by the message's definition; a value in hPa (a
/// publisher's unit slip, 1013 for sea level) is refused, naming the field.
pub fn fluid_pressure(m: &msgs::FluidPressure, ros1: bool) -> Result<Decoded, DecodeError> {
    let pressure_pa = in_range(
        "FluidPressure.fluid_pressure",
        m.fluid_pressure,
        crate::sample::BARO_MIN_PA,
        crate::sample::BARO_MAX_PA,
        "not an air pressure in Pa (hPa sent as Pa?)",
    )?;
    let variance = finite("FluidPressure.variance", m.variance)?;
    Ok(decoded(
        &m.header,
        ros1,
        SensorData::Baro(Baro {
            pressure_pa,
            temperature_c: None,
            // 0 is "unknown".
            variance: (variance > 0.0).then_some(variance),
        }),
    ))
}

fn odometry_from_pose(
    prefix: &str,
    header: &Header,
    pose: &msgs::Pose,
) -> Result<Odometry, DecodeError> {
    Ok(Odometry {
        position: vec3(&format!("{prefix}.position"), &pose.position)?,
        orientation: required_quaternion(&format!("{prefix}.orientation"), &pose.orientation)?,
        velocity: None,
        angular_velocity: None,
        pose_cov: None,
        twist_cov: None,
        frame_id: header.frame_id.clone(),
        child_frame_id: String::new(),
        reset_counter: None,
        quality: None,
    })
}

pub fn odometry(m: &msgs::Odometry, ros1: bool) -> Result<Decoded, DecodeError> {
    let mut o = odometry_from_pose("Odometry.pose.pose", &m.header, &m.pose.pose)?;
    o.pose_cov = cov6("Odometry.pose.covariance", &m.pose.covariance)?;
    o.twist_cov = cov6("Odometry.twist.covariance", &m.twist.covariance)?;
    let linear = vec3("Odometry.twist.twist.linear", &m.twist.twist.linear)?;
    let angular = vec3("Odometry.twist.twist.angular", &m.twist.twist.angular)?;
    // A pose-only source fills the twist with zeros and no covariance; taking that as
    // "standing still" would feed the filter a false zero velocity. A real velocity
    // estimate is never exactly zero on all axes.
    let unmeasured = |v: &Vector3<f64>| o.twist_cov.is_none() && *v == Vector3::zeros();
    o.velocity = (!unmeasured(&linear)).then_some(linear);
    o.angular_velocity = (!unmeasured(&angular)).then_some(angular);
    o.child_frame_id = m.child_frame_id.clone();
    Ok(decoded(&m.header, ros1, SensorData::Odometry(Box::new(o))))
}

pub fn pose_stamped(m: &msgs::PoseStamped, ros1: bool) -> Result<Decoded, DecodeError> {
    let o = odometry_from_pose("PoseStamped.pose", &m.header, &m.pose)?;
    Ok(decoded(&m.header, ros1, SensorData::Odometry(Box::new(o))))
}

pub fn pose_with_covariance_stamped(
    m: &msgs::PoseWithCovarianceStamped,
    ros1: bool,
) -> Result<Decoded, DecodeError> {
    let mut o = odometry_from_pose(
        "PoseWithCovarianceStamped.pose.pose",
        &m.header,
        &m.pose.pose,
    )?;
    o.pose_cov = cov6(
        "PoseWithCovarianceStamped.pose.covariance",
        &m.pose.covariance,
    )?;
    Ok(decoded(&m.header, ros1, SensorData::Odometry(Box::new(o))))
}

pub fn flow_tof(m: &msgs::FlowTof, ros1: bool) -> Result<Decoded, DecodeError> {
    let rate = Vector2::new(
        finite("FlowTof.flow_vel_x", m.flow_vel_x.into())?,
        finite("FlowTof.flow_vel_y", m.flow_vel_y.into())?,
    );
    let distance = f64::from(m.distance);
    // NaN is the module's "no ToF reading": the flow is still good.
    let tof = if distance.is_nan() {
        None
    } else {
        Some(Tof {
            distance_m: in_range(
                "FlowTof.distance",
                distance,
                0.0,
                f64::MAX,
                "a distance cannot be negative or infinite",
            )?,
            strength: Some(m.strength),
            precision: Some(m.precision),
            status: Some(m.tof_status),
        })
    };
    Ok(decoded(
        &m.header,
        ros1,
        SensorData::Flow(OpticalFlow {
            rate: Some(rate),
            gyro: None,
            velocity: None,
            integration_s: None,
            quality: m.flow_quality,
            status: Some(m.flow_status),
            tof,
        }),
    ))
}

// ---------------------------------------------------------------- encoding

/// Frame ids for samples that carry none (the seed's and mavros' defaults).
const GPS_FRAME: &str = "gps";
const IMU_FRAME: &str = "base_link";
const RANGE_FRAME: &str = "rangefinder";
const FLOW_FRAME: &str = "flow";
const BARO_FRAME: &str = "barometer";

fn efin(field: &str, v: f64) -> Result<f64, EncodeError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(EncodeError::NonFinite {
            field: field.to_string(),
            value: v,
        })
    }
}

/// A finite value that fits a float32 field.
fn ef32(field: &str, v: f64) -> Result<f32, EncodeError> {
    let v = efin(field, v)?;
    if v.abs() > f64::from(f32::MAX) {
        return Err(EncodeError::OutOfRange {
            field: field.to_string(),
            value: v,
        });
    }
    Ok(v as f32)
}

/// An optional value in a float32 field; NaN marks "unknown" on the wire.
fn ef32_opt(field: &str, v: Option<f64>) -> Result<f32, EncodeError> {
    v.map_or(Ok(f32::NAN), |v| ef32(field, v))
}

fn evec3(field: &str, v: &Vector3<f64>) -> Result<msgs::Vector3, EncodeError> {
    Ok(msgs::Vector3 {
        x: efin(&format!("{field}.x"), v.x)?,
        y: efin(&format!("{field}.y"), v.y)?,
        z: efin(&format!("{field}.z"), v.z)?,
    })
}

fn equat(field: &str, q: &UnitQuaternion<f64>) -> Result<msgs::Quaternion, EncodeError> {
    Ok(msgs::Quaternion {
        x: efin(&format!("{field}.x"), q.i)?,
        y: efin(&format!("{field}.y"), q.j)?,
        z: efin(&format!("{field}.z"), q.k)?,
        w: efin(&format!("{field}.w"), q.w)?,
    })
}

/// A covariance for the wire from its row-major elements ([`cov3_rows`]), zeros
/// ("unknown") when absent.
fn ecov<const N: usize>(field: &str, m: Option<&[f64]>) -> Result<[f64; N], EncodeError> {
    let mut out = [0.0; N];
    let Some(m) = m else { return Ok(out) };
    for (i, (o, x)) in out.iter_mut().zip(m).enumerate() {
        *o = efin(&format!("{field}[{i}]"), *x)?;
    }
    Ok(out)
}

/// Row-major elements (nalgebra stores column-major; ROS covariances are row-major).
fn cov3_rows(m: &Option<Matrix3<f64>>) -> Option<Vec<f64>> {
    m.map(|m| m.transpose().as_slice().to_vec())
}

fn cov6_rows(m: &Option<Matrix6<f64>>) -> Option<Vec<f64>> {
    m.map(|m| m.transpose().as_slice().to_vec())
}

/// A ROS header at `stamp_us` (µs since the epoch): an error, never a wrapped stamp,
/// beyond what ROS time holds (ROS 2 signed 32-bit seconds, ROS 1 unsigned).
pub fn header(stamp_us: Micros, frame_id: &str, ros1: bool) -> Result<Header, EncodeError> {
    let sec = stamp_us.div_euclid(1_000_000);
    let nanosec = (stamp_us.rem_euclid(1_000_000) * 1000) as u32;
    // ROS 1 time is unsigned seconds, ROS 2 signed 32-bit; kept bit for bit in i32.
    let stamp_sec = if ros1 {
        u32::try_from(sec).ok().map(|s| s as i32)
    } else {
        i32::try_from(sec).ok()
    };
    let stamp_sec = stamp_sec.ok_or(EncodeError::OutOfRange {
        field: "Header.stamp".into(),
        value: stamp_us as f64,
    })?;
    Ok(Header {
        stamp_sec,
        stamp_nanosec: nanosec,
        frame_id: frame_id.to_string(),
        seq: 0,
    })
}

fn gnss_msg(h: Header, g: &GnssFix) -> Result<msgs::NavSatFix, EncodeError> {
    let status = match g.fix {
        GnssFixType::NoFix => NavSatStatus::STATUS_NO_FIX,
        GnssFixType::Fix2d | GnssFixType::Fix3d => NavSatStatus::STATUS_FIX,
        // Ground-based augmentation: DGPS and RTK base stations.
        GnssFixType::Dgps | GnssFixType::RtkFloat | GnssFixType::RtkFixed => {
            NavSatStatus::STATUS_GBAS_FIX
        }
    };
    let position_covariance_type = match g.position_cov.as_deref() {
        None => msgs::NavSatFix::COVARIANCE_TYPE_UNKNOWN,
        Some(c) if *c == Matrix3::from_diagonal(&c.diagonal()) => {
            msgs::NavSatFix::COVARIANCE_TYPE_DIAGONAL_KNOWN
        }
        Some(_) => msgs::NavSatFix::COVARIANCE_TYPE_KNOWN,
    };
    Ok(msgs::NavSatFix {
        header: h,
        status: NavSatStatus {
            status,
            service: NavSatStatus::SERVICE_GPS,
        },
        latitude: efin("NavSatFix.latitude", g.lat_deg)?,
        longitude: efin("NavSatFix.longitude", g.lon_deg)?,
        altitude: efin("NavSatFix.altitude", g.alt_m)?,
        position_covariance: ecov(
            "NavSatFix.position_covariance",
            cov3_rows(&g.position_cov.as_deref().copied()).as_deref(),
        )?,
        position_covariance_type,
    })
}

/// sensor_msgs/Imu's "not provided": covariance element 0 = -1.
const NOT_PROVIDED: [f64; 9] = [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];

fn imu_msg(h: Header, i: &Imu) -> Result<msgs::Imu, EncodeError> {
    let mut m = msgs::Imu {
        header: h,
        // Zeros, not identity, so a reader that ignores the covariance flag still
        // cannot mistake it for a level attitude.
        orientation: msgs::Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        },
        orientation_covariance: NOT_PROVIDED,
        angular_velocity_covariance: NOT_PROVIDED,
        linear_acceleration_covariance: NOT_PROVIDED,
        ..Default::default()
    };
    if let Some(q) = &i.orientation {
        m.orientation = equat("Imu.orientation", q)?;
        m.orientation_covariance = ecov(
            "Imu.orientation_covariance",
            cov3_rows(&i.orientation_cov.as_deref().copied()).as_deref(),
        )?;
    }
    if let Some(g) = &i.gyro {
        m.angular_velocity = evec3("Imu.angular_velocity", g)?;
        m.angular_velocity_covariance = ecov(
            "Imu.angular_velocity_covariance",
            cov3_rows(&i.gyro_cov.as_deref().copied()).as_deref(),
        )?;
    }
    if let Some(a) = &i.accel {
        m.linear_acceleration = evec3("Imu.linear_acceleration", a)?;
        m.linear_acceleration_covariance = ecov(
            "Imu.linear_acceleration_covariance",
            cov3_rows(&i.accel_cov.as_deref().copied()).as_deref(),
        )?;
    }
    Ok(m)
}

fn range_msg(h: Header, r: &Range) -> Result<msgs::Range, EncodeError> {
    Ok(msgs::Range {
        header: h,
        radiation_type: msgs::Range::INFRARED,
        field_of_view: 0.0,
        min_range: ef32_opt("Range.min_range", r.min_m)?,
        max_range: ef32_opt("Range.max_range", r.max_m)?,
        range: ef32("Range.range", r.distance_m)?,
        // Humble's layout (no variance), which the bridged ROS 2 graph expects.
        variance: None,
    })
}

fn pose(prefix: &str, o: &Odometry) -> Result<msgs::Pose, EncodeError> {
    Ok(msgs::Pose {
        position: evec3(&format!("{prefix}.position"), &o.position)?,
        orientation: equat(&format!("{prefix}.orientation"), &o.orientation)?,
    })
}

fn odometry_msg(h: Header, o: &Odometry) -> Result<msgs::Odometry, EncodeError> {
    // Absent velocities go out as zeros with zero covariance, which `odometry` above
    // reads back as absent.
    let zero = Vector3::zeros();
    Ok(msgs::Odometry {
        header: h,
        child_frame_id: o.child_frame_id.clone(),
        pose: msgs::PoseWithCovariance {
            pose: pose("Odometry.pose.pose", o)?,
            covariance: ecov(
                "Odometry.pose.covariance",
                cov6_rows(&o.pose_cov).as_deref(),
            )?,
        },
        twist: msgs::TwistWithCovariance {
            twist: msgs::Twist {
                linear: evec3(
                    "Odometry.twist.twist.linear",
                    o.velocity.as_ref().unwrap_or(&zero),
                )?,
                angular: evec3(
                    "Odometry.twist.twist.angular",
                    o.angular_velocity.as_ref().unwrap_or(&zero),
                )?,
            },
            covariance: ecov(
                "Odometry.twist.covariance",
                cov6_rows(&o.twist_cov).as_deref(),
            )?,
        },
    })
}

fn flow_msg(h: Header, f: &OpticalFlow) -> Result<msgs::FlowTof, EncodeError> {
    let rate = f.rate.ok_or_else(|| {
        EncodeError::Unsupported("FlowTof needs a flow rate; this flow sample has none".into())
    })?;
    let tof = f.tof.as_ref();
    Ok(msgs::FlowTof {
        header: h,
        distance: ef32_opt("FlowTof.distance", tof.map(|t| t.distance_m))?,
        strength: tof.and_then(|t| t.strength).unwrap_or(0),
        precision: tof.and_then(|t| t.precision).unwrap_or(0),
        tof_status: tof.and_then(|t| t.status).unwrap_or(0),
        flow_vel_x: ef32("FlowTof.flow_vel_x", rate.x)?,
        flow_vel_y: ef32("FlowTof.flow_vel_y", rate.y)?,
        flow_quality: f.quality,
        flow_status: f.status.unwrap_or(0),
    })
}

fn emit<M: RosMessage>(m: &M, ros1: bool) -> Vec<u8> {
    if ros1 {
        m.to_ros1()
    } else {
        m.to_cdr()
    }
}

/// A sample as message type `ty` (what the simulator publishes).
pub fn encode_sample(
    ty: RosType,
    stamp_us: Micros,
    data: &SensorData,
    ros1: bool,
) -> Result<Vec<u8>, EncodeError> {
    let hdr = |frame: &str| header(stamp_us, frame, ros1);
    Ok(match (ty, data) {
        (RosType::NavSatFix, SensorData::Gnss(g)) => emit(&gnss_msg(hdr(GPS_FRAME)?, g)?, ros1),
        (RosType::Imu, SensorData::Imu(i)) => emit(&imu_msg(hdr(IMU_FRAME)?, i)?, ros1),
        (RosType::Range, SensorData::Range(r)) => emit(&range_msg(hdr(RANGE_FRAME)?, r)?, ros1),
        (RosType::FlowTof, SensorData::Flow(f)) => emit(&flow_msg(hdr(FLOW_FRAME)?, f)?, ros1),
        (RosType::FluidPressure, SensorData::Baro(b)) => emit(
            &msgs::FluidPressure {
                header: hdr(BARO_FRAME)?,
                fluid_pressure: efin("FluidPressure.fluid_pressure", b.pressure_pa)?,
                variance: efin("FluidPressure.variance", b.variance.unwrap_or(0.0))?,
            },
            ros1,
        ),
        (RosType::Odometry, SensorData::Odometry(o)) => {
            emit(&odometry_msg(hdr(&o.frame_id)?, o)?, ros1)
        }
        (RosType::PoseStamped, SensorData::Odometry(o)) => emit(
            &msgs::PoseStamped {
                header: hdr(&o.frame_id)?,
                pose: pose("PoseStamped.pose", o)?,
            },
            ros1,
        ),
        (RosType::PoseWithCovarianceStamped, SensorData::Odometry(o)) => emit(
            &msgs::PoseWithCovarianceStamped {
                header: hdr(&o.frame_id)?,
                pose: msgs::PoseWithCovariance {
                    pose: pose("PoseWithCovarianceStamped.pose.pose", o)?,
                    covariance: ecov(
                        "PoseWithCovarianceStamped.pose.covariance",
                        cov6_rows(&o.pose_cov).as_deref(),
                    )?,
                },
            },
            ros1,
        ),
        (RosType::PointStamped, SensorData::Odometry(o)) => emit(
            &msgs::PointStamped {
                header: hdr(&o.frame_id)?,
                point: evec3("PointStamped.point", &o.position)?,
            },
            ros1,
        ),
        (ty, data) => {
            return Err(EncodeError::Unsupported(format!(
                "a {} sample cannot be sent as {}",
                data.kind(),
                ty.ros2_name()
            )))
        }
    })
}
