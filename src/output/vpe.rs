//! The fused pose as MAVLink messages for PX4 / ArduPilot: pure functions, no I/O.
//!
//! Frames: the estimator works in ENU with the body in FLU (REP-103); MAVLink's
//! VISION_POSITION_ESTIMATE is NED with the body in FRD. Nothing non-finite ever leaves
//! here: a message with a NaN or Inf anywhere is an error, not a frame.

use crate::estimator::FusedPose;
use mavlink::dialects::common::{
    MavAutopilot, MavEstimatorType, MavFrame, MavMessage, MavModeFlag, MavState, MavType,
    HEARTBEAT_DATA, ODOMETRY_DATA, VISION_POSITION_ESTIMATE_DATA, VISION_SPEED_ESTIMATE_DATA,
};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum VpeError {
    #[error("estimate not valid: {0}")]
    Invalid(String),
    #[error("{field} is not finite ({value})")]
    NotFinite { field: &'static str, value: f64 },
    #[error("px4_msgs/VehicleOdometry refused: {0}")]
    Px4(String),
}

pub use crate::config::MessageSet;

/// ENU/FLU attitude → NED/FRD attitude (inverse of `frames::q_ned_frd_to_enu_flu`).
pub fn q_enu_flu_to_ned_frd(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    // q_enu_flu = A · q_ned_frd · B with A = q_enu_ned, B = q_frd_flu, so
    // q_ned_frd = A⁻¹ · q_enu_flu · B⁻¹.
    let a = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        0.0,
        std::f64::consts::FRAC_1_SQRT_2,
        std::f64::consts::FRAC_1_SQRT_2,
        0.0,
    ));
    let b = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(0.0, 1.0, 0.0, 0.0));
    a.inverse() * q * b.inverse()
}

/// ENU vector → NED vector.
pub fn enu_to_ned(v: Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v.y, v.x, -v.z)
}

/// Upper triangle, row-major, of a 6×6 matrix (MAVLink's 21-float covariance).
pub fn upper_triangle(m: &Matrix6<f64>) -> [f32; 21] {
    let mut out = [0f32; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = m[(i, j)] as f32;
            k += 1;
        }
    }
    out
}

/// Pose covariance in NED/FRD: [x y z roll pitch yaw].
pub fn pose_covariance_ned(p: &FusedPose) -> Matrix6<f64> {
    let perm = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let flu_frd = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut c = Matrix6::zeros();
    c.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(perm * p.position_cov * perm.transpose()));
    c.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(flu_frd * p.orientation_cov * flu_frd));
    c
}

fn check(field: &'static str, v: f64) -> Result<f32, VpeError> {
    let f = v as f32;
    if v.is_finite() && f.is_finite() {
        Ok(f)
    } else {
        Err(VpeError::NotFinite { field, value: v })
    }
}

fn check_all(field: &'static str, vs: &[f32]) -> Result<(), VpeError> {
    match vs.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(VpeError::NotFinite {
            field,
            value: f64::from(*v),
        }),
        None => Ok(()),
    }
}

/// Quality 0–100 for ODOMETRY from the horizontal position 1σ (100 at ≤ 1 cm, 0 at
/// `max_std_m`).
fn quality(p: &FusedPose, max_std_m: f64) -> i8 {
    let s = p.position_cov[(0, 0)].max(p.position_cov[(1, 1)]).sqrt();
    let q = 100.0 * (1.0 - ((s - 0.01) / (max_std_m - 0.01)).clamp(0.0, 1.0));
    q.round() as i8
}

/// A valid pose's position, velocity (NED) and attitude (body FRD → NED).
struct Ned {
    pos: Vector3<f64>,
    vel: Vector3<f64>,
    q: UnitQuaternion<f64>,
}

/// The pose in the autopilot's frames, or why it is not to be sent.
fn ned(p: &FusedPose) -> Result<Ned, VpeError> {
    if !p.valid {
        return Err(VpeError::Invalid(
            p.invalid_reason
                .clone()
                .unwrap_or_else(|| "not valid".into()),
        ));
    }
    Ok(Ned {
        pos: enu_to_ned(p.position),
        vel: enu_to_ned(p.velocity),
        q: q_enu_flu_to_ned_frd(p.orientation),
    })
}

/// The messages for one output tick. `time_us` is the MAVLink timestamp to send.
pub fn pose_messages(
    p: &FusedPose,
    time_us: u64,
    set: MessageSet,
    max_std_m: f64,
) -> Result<Vec<MavMessage>, VpeError> {
    let Ned { pos, vel, q } = ned(p)?;
    let (roll, pitch, yaw) = q.euler_angles();
    let cov = upper_triangle(&pose_covariance_ned(p));
    check_all("pose covariance", &cov)?;
    let (x, y, z) = (check("x", pos.x)?, check("y", pos.y)?, check("z", pos.z)?);
    let (roll, pitch, yaw) = (
        check("roll", roll)?,
        check("pitch", pitch)?,
        check("yaw", yaw)?,
    );
    let (vx, vy, vz) = (
        check("vx", vel.x)?,
        check("vy", vel.y)?,
        check("vz", vel.z)?,
    );
    let perm = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let vcov3 = perm * p.velocity_cov * perm.transpose();
    let mut vcov9 = [0f32; 9];
    for i in 0..3 {
        for j in 0..3 {
            vcov9[i * 3 + j] = vcov3[(i, j)] as f32;
        }
    }
    check_all("velocity covariance", &vcov9)?;
    let mut out = Vec::with_capacity(3);
    if set.vision_position_estimate {
        out.push(MavMessage::VISION_POSITION_ESTIMATE(
            VISION_POSITION_ESTIMATE_DATA {
                usec: time_us,
                x,
                y,
                z,
                roll,
                pitch,
                yaw,
                covariance: cov,
                reset_counter: p.reset_counter,
            },
        ));
    }
    if set.vision_speed_estimate {
        out.push(MavMessage::VISION_SPEED_ESTIMATE(
            VISION_SPEED_ESTIMATE_DATA {
                usec: time_us,
                x: vx,
                y: vy,
                z: vz,
                covariance: vcov9,
                reset_counter: p.reset_counter,
            },
        ));
    }
    if set.odometry {
        // Velocity in the body (FRD) frame, as child_frame_id says.
        let v_body = q.inverse() * vel;
        let w_body = p
            .angular_velocity
            .map(|w| Vector3::new(w.x, -w.y, -w.z))
            .unwrap_or_else(Vector3::zeros);
        let mut vel_cov6 = Matrix6::zeros();
        let r = q.inverse().to_rotation_matrix();
        vel_cov6
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(r.matrix() * vcov3 * r.matrix().transpose()));
        let vel_cov = upper_triangle(&vel_cov6);
        check_all("velocity covariance", &vel_cov)?;
        out.push(MavMessage::ODOMETRY(ODOMETRY_DATA {
            time_usec: time_us,
            x,
            y,
            z,
            q: [
                check("q.w", q.w)?,
                check("q.x", q.i)?,
                check("q.y", q.j)?,
                check("q.z", q.k)?,
            ],
            vx: check("odometry vx", v_body.x)?,
            vy: check("odometry vy", v_body.y)?,
            vz: check("odometry vz", v_body.z)?,
            rollspeed: check("rollspeed", w_body.x)?,
            pitchspeed: check("pitchspeed", w_body.y)?,
            yawspeed: check("yawspeed", w_body.z)?,
            pose_covariance: cov,
            velocity_covariance: vel_cov,
            frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
            child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
            reset_counter: p.reset_counter,
            estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
            quality: quality(p, max_std_m),
        }));
    }
    Ok(out)
}

/// Smallest variance sent to PX4: px4-ros2-interface-lib refuses 0, and EKF2 raises
/// any variance to its own noise floor (`EKF2_EVP_NOISE` ...) anyway.
const PX4_MIN_VARIANCE: f64 = 1e-6;

/// The fused pose as px4_msgs/VehicleOdometry for `fmu/in/vehicle_visual_odometry`:
/// NED position and velocity, body FRD → NED quaternion, body FRD rates, per-axis
/// variances, the reset counter, a quality of 1–100; `timestamp` 0 (PX4 stamps it at
/// arrival) and `timestamp_sample` as given (see `[output] px4_clock`). An invalid
/// pose, a non-finite value, or a message px4-ros2-interface-lib would refuse is an
/// error, never a message.
pub fn px4_vehicle_odometry(
    p: &FusedPose,
    timestamp_sample_us: u64,
    max_std_m: f64,
) -> Result<crate::codec::ros::px4::VehicleOdometry, VpeError> {
    use crate::codec::ros::px4;
    let Ned { pos, vel, q } = ned(p)?;
    let cov = pose_covariance_ned(p);
    let perm = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let vcov = perm * p.velocity_cov * perm.transpose();
    let var = |field: &'static str, v: f64| check(field, v.max(PX4_MIN_VARIANCE));
    let w = p.angular_velocity.map(|w| Vector3::new(w.x, -w.y, -w.z));
    let m = px4::VehicleOdometry {
        timestamp: 0,
        timestamp_sample: timestamp_sample_us,
        pose_frame: px4::POSE_FRAME_NED,
        position: [check("x", pos.x)?, check("y", pos.y)?, check("z", pos.z)?],
        q: [
            check("q.w", q.w)?,
            check("q.x", q.i)?,
            check("q.y", q.j)?,
            check("q.z", q.k)?,
        ],
        velocity_frame: px4::VELOCITY_FRAME_NED,
        velocity: [
            check("vx", vel.x)?,
            check("vy", vel.y)?,
            check("vz", vel.z)?,
        ],
        // Unknown rates are NaN, as the interface library sends them.
        angular_velocity: match w {
            Some(w) => [
                check("rollspeed", w.x)?,
                check("pitchspeed", w.y)?,
                check("yawspeed", w.z)?,
            ],
            None => [f32::NAN; 3],
        },
        position_variance: [
            var("position variance x", cov[(0, 0)])?,
            var("position variance y", cov[(1, 1)])?,
            var("position variance z", cov[(2, 2)])?,
        ],
        orientation_variance: [
            var("roll variance", cov[(3, 3)])?,
            var("pitch variance", cov[(4, 4)])?,
            var("yaw variance", cov[(5, 5)])?,
        ],
        velocity_variance: [
            var("velocity variance x", vcov[(0, 0)])?,
            var("velocity variance y", vcov[(1, 1)])?,
            var("velocity variance z", vcov[(2, 2)])?,
        ],
        reset_counter: p.reset_counter,
        quality: quality(p, max_std_m).max(1),
    };
    m.check().map_err(VpeError::Px4)?;
    Ok(m)
}

/// The EKF origin and home for an autopilot with no GNSS (ArduPilot's non-GPS
/// navigation, as vision_to_mavros sets them): SET_GPS_GLOBAL_ORIGIN and
/// SET_HOME_POSITION at the configured origin (lat, lon in degrees, alt in metres MSL),
/// home at the local origin facing north. Out-of-range values are an error, never a frame.
/// The messages are deprecated in favour of MAV_CMD_DO_SET_GLOBAL_ORIGIN (2025) and
/// MAV_CMD_DO_SET_HOME, but they are what ArduPilot 4.6 and PX4 act on today.
#[allow(deprecated)]
pub fn origin_messages(
    origin: [f64; 3],
    target_system: u8,
    time_usec: u64,
) -> Result<[MavMessage; 2], VpeError> {
    let [lat, lon, alt] = origin;
    let ok = lat.is_finite()
        && lon.is_finite()
        && alt.is_finite()
        && lat.abs() <= 90.0
        && lon.abs() <= 180.0
        && alt.abs() < 1.0e6;
    if !ok {
        return Err(VpeError::Invalid(format!(
            "EKF origin ({lat}, {lon}, {alt}) is not a place on Earth"
        )));
    }
    let (lat, lon, alt) = (
        (lat * 1e7).round() as i32,
        (lon * 1e7).round() as i32,
        (alt * 1e3).round() as i32,
    );
    Ok([
        MavMessage::SET_GPS_GLOBAL_ORIGIN(mavlink::dialects::common::SET_GPS_GLOBAL_ORIGIN_DATA {
            latitude: lat,
            longitude: lon,
            altitude: alt,
            target_system,
            time_usec,
        }),
        MavMessage::SET_HOME_POSITION(mavlink::dialects::common::SET_HOME_POSITION_DATA {
            latitude: lat,
            longitude: lon,
            altitude: alt,
            q: [1.0, 0.0, 0.0, 0.0],
            target_system,
            time_usec,
            ..Default::default()
        }),
    ])
}

/// HEARTBEAT of an onboard component: healthy (`ACTIVE`) while the estimate is valid,
/// `CRITICAL` while it is not (so a ground station shows why VPE stopped).
pub fn heartbeat(estimate_valid: bool) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: if estimate_valid {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_CRITICAL
        },
        mavlink_version: 3,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::frames;

    fn pose() -> FusedPose {
        FusedPose {
            time_us: 1_000_000,
            // 1 m east, 2 m north, 3 m up.
            position: Vector3::new(1.0, 2.0, 3.0),
            velocity: Vector3::new(0.5, 0.0, 0.0),
            // Facing north (ENU yaw 90°).
            orientation: UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            angular_velocity: None,
            position_cov: Matrix3::from_diagonal(&Vector3::new(0.01, 0.04, 0.09)),
            velocity_cov: Matrix3::identity() * 0.01,
            orientation_cov: Matrix3::identity() * 1e-4,
            sources: vec!["t265".into()],
            reset_counter: 3,
            valid: true,
            invalid_reason: None,
            origin: None,
            protection: Default::default(),
        }
    }

    const ALL: MessageSet = MessageSet {
        vision_position_estimate: true,
        vision_speed_estimate: true,
        odometry: true,
    };

    #[test]
    fn px4_odometry_is_ned_frd_and_passes_the_interface_library_checks() {
        let m = px4_vehicle_odometry(&pose(), 123_456, 5.0).expect("valid pose");
        // North 2, east 1, down -3; facing north: the identity in NED/FRD.
        assert_eq!(m.position, [2.0, 1.0, -3.0]);
        assert!((m.q[0].abs() - 1.0).abs() < 1e-6, "{:?}", m.q);
        assert_eq!(m.velocity, [0.0, 0.5, 0.0]);
        assert_eq!((m.pose_frame, m.velocity_frame), (1, 1));
        assert_eq!(m.position_variance, [0.04, 0.01, 0.09]);
        assert_eq!((m.timestamp, m.timestamp_sample), (0, 123_456));
        assert_eq!(m.reset_counter, 3);
        assert!((1..=100).contains(&m.quality));
        // No rates known: NaN, as the interface library leaves them.
        assert!(m.angular_velocity.iter().all(|w| w.is_nan()));
        assert_eq!(m.check(), Ok(()));
        // A zero variance goes out as the smallest positive one; never 0.
        let mut p = pose();
        p.orientation_cov = Matrix3::zeros();
        let m = px4_vehicle_odometry(&p, 1, 5.0).expect("valid pose");
        assert!(m.orientation_variance.iter().all(|v| *v > 0.0));
        // Nothing invalid, nothing non-finite, no timestamp_sample 0.
        let mut p = pose();
        p.valid = false;
        assert!(matches!(
            px4_vehicle_odometry(&p, 1, 5.0),
            Err(VpeError::Invalid(_))
        ));
        let mut p = pose();
        p.velocity.y = f64::NAN;
        assert!(matches!(
            px4_vehicle_odometry(&p, 1, 5.0),
            Err(VpeError::NotFinite { .. })
        ));
        assert!(matches!(
            px4_vehicle_odometry(&pose(), 0, 5.0),
            Err(VpeError::Px4(_))
        ));
    }

    #[test]
    fn ned_frames_and_signs() {
        let msgs = pose_messages(&pose(), 42, ALL, 5.0).expect("valid pose");
        let MavMessage::VISION_POSITION_ESTIMATE(v) = &msgs[0] else {
            panic!("first is VPE")
        };
        // North 2, east 1, down -3.
        assert_eq!((v.x, v.y, v.z), (2.0, 1.0, -3.0));
        // Facing north = NED yaw 0.
        assert!(v.yaw.abs() < 1e-6, "yaw {}", v.yaw);
        assert!(v.roll.abs() < 1e-6 && v.pitch.abs() < 1e-6);
        // Covariance: x (north) var is the ENU y var; z var stays.
        assert!((v.covariance[0] - 0.04).abs() < 1e-7);
        assert!((v.covariance[6] - 0.01).abs() < 1e-7);
        assert!((v.covariance[11] - 0.09).abs() < 1e-7);
        assert_eq!(v.reset_counter, 3);
        assert_eq!(v.usec, 42);
        let MavMessage::VISION_SPEED_ESTIMATE(s) = &msgs[1] else {
            panic!("second is VSE")
        };
        // Moving east: NED y positive.
        assert_eq!((s.x, s.y, s.z), (0.0, 0.5, 0.0));
        let MavMessage::ODOMETRY(o) = &msgs[2] else {
            panic!("third is ODOMETRY")
        };
        // Facing north, moving east: body FRD velocity is to the right (+y).
        assert!((o.vy - 0.5).abs() < 1e-6 && o.vx.abs() < 1e-6, "{o:?}");
    }

    #[test]
    fn roll_right_is_positive_in_frd() {
        let mut p = pose();
        // FLU: rolling right (left side up) is a positive rotation about body x, as
        // it is in FRD (right side down).
        p.orientation = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2)
            * UnitQuaternion::from_euler_angles(0.2, 0.0, 0.0);
        let msgs = pose_messages(&p, 0, ALL, 5.0).expect("valid");
        let MavMessage::VISION_POSITION_ESTIMATE(v) = &msgs[0] else {
            panic!()
        };
        assert!((v.roll - 0.2).abs() < 1e-6, "roll {}", v.roll);
        // And the left wing is up: body +y (FLU) has a positive world z.
        assert!((p.orientation * Vector3::y()).z > 0.1);
    }

    #[test]
    fn nothing_non_finite_or_invalid_is_ever_built() {
        let mut p = pose();
        p.position.x = f64::NAN;
        assert!(matches!(
            pose_messages(&p, 0, ALL, 5.0),
            Err(VpeError::NotFinite { .. })
        ));
        let mut p = pose();
        p.position_cov[(0, 0)] = f64::INFINITY;
        assert!(pose_messages(&p, 0, ALL, 5.0).is_err());
        let mut p = pose();
        // Finite in f64 but not in f32.
        p.position.z = 1e300;
        assert!(pose_messages(&p, 0, ALL, 5.0).is_err());
        let mut p = pose();
        p.valid = false;
        p.invalid_reason = Some("no position source".into());
        assert_eq!(
            pose_messages(&p, 0, ALL, 5.0),
            Err(VpeError::Invalid("no position source".into()))
        );
    }

    #[test]
    fn attitude_round_trips_through_the_frame_change() {
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        let back = frames::q_ned_frd_to_enu_flu(q_enu_flu_to_ned_frd(q));
        assert!(back.angle_to(&q) < 1e-12);
    }
}
