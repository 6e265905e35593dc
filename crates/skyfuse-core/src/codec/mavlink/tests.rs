//! Golden inputs (real mavlink-server 0.9.0 captures), vectors from the real peers
//! (pymavlink frames, the reference Codec's JSON: tests/py/gen_mavlink_vectors.py),
//! error reporting, corruption and fuzzing.

use super::*;
use crate::sample::{frames, GnssFixType, SensorData};
use crate::some_or_skip;
use ::mavlink::dialects::common::{self as mc, MavMessage};
use ::mavlink::MavlinkVersion;
use nalgebra::{Matrix3, UnitQuaternion, Vector2, Vector3};
use proptest::prelude::*;
use serde_json::Value;

/// The real mavlink-server's captures (../shared/data/bridges), or None (skipped).
fn golden_file(test: &str) -> Option<&'static str> {
    static TEXT: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    TEXT.get_or_init(|| {
        let path = crate::shared_data::shared_data(
            "bridges/mavlink-server-samples.jsonl",
            "the mavlink-server golden tests",
        )?;
        Some(std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
    })
    .as_deref()
    .or_else(|| {
        crate::shared_data::skipped(test, "no mavlink-server captures (see above)");
        None
    })
}
const VECTORS: &str = include_str!("../../../../../tests/data/mavlink_vectors.json");

/// The captured payload of `label`, or None when the captures are absent (skipped).
fn golden(label: &str) -> Option<String> {
    for line in golden_file(label)?.lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        if v["message"] == label {
            return Some(v["payload"].as_str().unwrap().to_string());
        }
    }
    panic!("no golden line {label}");
}

fn golden_decoded(label: &str) -> Option<Decoded> {
    Some(
        decode_json(golden(label)?.as_bytes())
            .unwrap_or_else(|e| panic!("{label}: {e}"))
            .unwrap_or_else(|| panic!("{label}: no sample")),
    )
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn v3(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

fn assert_close(a: f64, b: f64, what: &str) {
    assert!(
        (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
        "{what}: {a} != {b}"
    );
}

fn assert_rot(q: &UnitQuaternion<f64>, m: &Matrix3<f64>, what: &str) {
    let r = q.to_rotation_matrix().into_inner();
    assert!((r - m).abs().max() < 1e-12, "{what}: {r} != {m}");
}

/// Body FRD → world NED as body FLU → world ENU, with plain matrices.
fn enu_flu(r_ned_frd: Matrix3<f64>) -> Matrix3<f64> {
    let a = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let b = Matrix3::from_diagonal(&v3(1.0, -1.0, -1.0));
    a * r_ned_frd * b
}

// ------------------------------------------------------------------------ golden

#[test]
fn golden_heartbeat_is_the_armed_state() {
    // ArduCopter's heartbeat, armed (MAV_MODE_FLAG_SAFETY_ARMED in base_mode).
    let d = decode_json(some_or_skip!(golden("HEARTBEAT")).as_bytes())
        .unwrap()
        .unwrap();
    assert_eq!(d.mav_origin, Some((1, 1)));
    assert_eq!(
        d.data,
        SensorData::VehicleState(crate::sample::VehicleState {
            armed: Some(true),
            landed: None
        })
    );
}

#[test]
fn golden_highres_imu_is_flu_specific_force() {
    let d = some_or_skip!(golden_decoded("HIGHRES_IMU"));
    assert_eq!(d.stamp_us, Some(1_700_000_000_000_000));
    assert_eq!(d.mav_origin, Some((1, 1)));
    let SensorData::Imu(imu) = d.data else {
        panic!("{:?}", d.data)
    };
    // zacc -9.8125 (FRD, level) is +9.8125 up in FLU.
    assert_eq!(imu.accel, Some(v3(0.5, 0.25, 9.8125)));
    assert_eq!(imu.gyro, Some(v3(0.0625, 0.03125, -0.015625)));
    assert_eq!(imu.orientation, None);
}

#[test]
fn golden_attitude() {
    let d = some_or_skip!(golden_decoded("ATTITUDE"));
    assert_eq!(d.stamp_us, Some(1_000_000));
    let SensorData::Attitude(a) = d.data else {
        panic!()
    };
    let r = nalgebra::Rotation3::from_euler_angles(0.125, -0.25, 1.5).into_inner();
    assert_rot(&a.orientation, &enu_flu(r), "orientation");
    assert_eq!(a.rates, Some(v3(0.0078125, 0.015625, -0.03125)));
}

#[test]
fn golden_optical_flow() {
    let d = some_or_skip!(golden_decoded("OPTICAL_FLOW"));
    let SensorData::Flow(f) = d.data else {
        panic!()
    };
    assert_eq!(f.velocity, Some(Vector2::new(0.375, 0.625)));
    // PX4's FRD y becomes FLU's: the sign changes.
    assert_eq!(f.rate, Some(Vector2::new(0.0625, 0.125)));
    assert_eq!(f.quality, 200);
    assert_eq!(f.tof.map(|t| t.distance_m), Some(1.25));
    assert_eq!(f.gyro, None);
}

#[test]
fn golden_optical_flow_rad() {
    let d = some_or_skip!(golden_decoded("OPTICAL_FLOW_RAD"));
    let SensorData::Flow(f) = d.data else {
        panic!()
    };
    let dt = 20000.0 * 1e-6;
    assert_eq!(f.integration_s, Some(dt));
    assert_eq!(f.rate, Some(Vector2::new(0.015625 / dt, 0.03125 / dt)));
    let g = f.gyro.unwrap();
    assert_close(g.x, 0.0078125 / 0.02, "gx");
    assert_close(g.y, 0.00390625 / 0.02, "gy");
    assert_close(g.z, -0.001953125 / 0.02, "gz");
    assert_eq!(f.quality, 180);
    assert_eq!(f.tof.map(|t| t.distance_m), Some(1.25));
}

#[test]
fn golden_distance_sensor() {
    let d = some_or_skip!(golden_decoded("DISTANCE_SENSOR"));
    assert_eq!(d.stamp_us, Some(1_000_000));
    let SensorData::Range(r) = d.data else {
        panic!()
    };
    assert_eq!(r.distance_m, 1.25);
    assert_eq!(r.min_m, Some(0.1));
    assert_eq!(r.max_m, Some(40.0));
    assert_eq!(r.signal_quality, Some(90));
    assert_eq!(r.variance, Some(4.0 * 1e-4));
    assert_eq!(r.orientation, Some(25));
}

#[test]
fn golden_gps_raw_int() {
    let d = some_or_skip!(golden_decoded("GPS_RAW_INT"));
    let SensorData::Gnss(g) = d.data else {
        panic!()
    };
    assert_eq!(g.lat_deg, 473977420.0 * 1e-7);
    assert_eq!(g.lon_deg, 85455940.0 * 1e-7);
    assert_eq!(g.alt_m, 488.5);
    assert_eq!(g.fix, GnssFixType::Fix3d);
    assert_eq!(
        g.position_cov.as_deref().copied(),
        Some(Matrix3::from_diagonal(&v3(0.8 * 0.8, 0.8 * 0.8, 1.2 * 1.2)))
    );
    assert_eq!(g.satellites, Some(14));
    assert_eq!(g.hdop, Some(120.0 * 0.01));
    assert_eq!(g.vdop, Some(180.0 * 0.01));
    let v = g.velocity.unwrap();
    assert_close(v.x, 1.5, "east");
    assert!(v.y.abs() < 1e-12 && v.z == 0.0, "{v}");
    // Ground speed and course only: the up component is no measurement (fusing it as
    // 0 held PX4 SIH's climbs back until the GPS was gated out).
    assert!(!g.velocity_up_known);
}

#[test]
fn golden_global_position_int() {
    let d = some_or_skip!(golden_decoded("GLOBAL_POSITION_INT"));
    let SensorData::AutopilotEstimate(e) = d.data else {
        panic!()
    };
    assert_eq!(
        e.geodetic,
        Some((473977420.0 * 1e-7, 85455940.0 * 1e-7, 488.5))
    );
    assert_eq!(e.velocity, Some(v3(-0.25, 1.5, -0.1)));
    // Heading 90° (east) is ENU yaw 0.
    assert!(e.yaw.unwrap().abs() < 1e-12);
    assert_eq!(e.local_position, None);
}

#[test]
fn golden_local_position_ned() {
    let d = some_or_skip!(golden_decoded("LOCAL_POSITION_NED"));
    let SensorData::AutopilotEstimate(e) = d.data else {
        panic!()
    };
    assert_eq!(e.local_position, Some(v3(-2.25, 1.5, 0.75)));
    assert_eq!(e.velocity, Some(v3(-0.125, 0.25, -0.0625)));
}

#[test]
fn golden_odometry_and_its_nan_covariance() {
    for (label, twist_known) in [("ODOMETRY", true), ("ODOMETRY(nan)", false)] {
        let d = some_or_skip!(golden_decoded(label));
        let SensorData::Odometry(o) = d.data else {
            panic!()
        };
        assert_eq!(o.position, v3(-2.25, 1.5, 0.75));
        assert_rot(&o.orientation, &enu_flu(Matrix3::identity()), label);
        assert_eq!(o.velocity, Some(v3(0.25, 0.125, -0.0625)));
        assert_eq!(o.angular_velocity, Some(v3(0.015625, 0.0078125, -0.03125)));
        let pose = o.pose_cov.unwrap();
        assert_eq!(
            pose,
            nalgebra::Matrix6::from_diagonal(&nalgebra::Vector6::new(
                0.03125, 0.015625, 0.0625, 0.125, 0.25, 0.5
            ))
        );
        if twist_known {
            assert_eq!(
                o.twist_cov,
                Some(nalgebra::Matrix6::from_diagonal(&nalgebra::Vector6::new(
                    0.5, 0.25, 0.125, 0.0625, 0.03125, 0.015625
                )))
            );
        } else {
            // velocity_covariance[0] is NaN: unknown.
            assert_eq!(o.twist_cov, None);
        }
        assert_eq!(o.frame_id, "MAV_FRAME_LOCAL_FRD");
        assert_eq!(o.child_frame_id, "MAV_FRAME_BODY_FRD");
        assert_eq!(o.reset_counter, Some(2));
        assert_eq!(o.quality, Some(75));
    }
}

#[test]
fn every_golden_line_decodes() {
    let mut n = 0;
    for line in some_or_skip!(golden_file("every_golden_line_decodes")).lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        let payload = v["payload"].as_str().unwrap();
        let d = decode_json(payload.as_bytes()).unwrap();
        assert!(d.is_some(), "{line}");
        n += 1;
    }
    assert_eq!(n, 11);
}

#[test]
fn legacy_bitmask_form_and_the_updated_mask() {
    let text = some_or_skip!(golden("HIGHRES_IMU"));
    let start = text.find("\"fields_updated\":\"").unwrap();
    let end = start + text[start..].find("\",").unwrap() + 2;
    let with = |v: &str| format!("{}\"fields_updated\":{v},{}", &text[..start], &text[end..]);
    let full = decode_json(text.as_bytes()).unwrap();
    // Legacy {"bits": N}: every field updated.
    assert_eq!(
        decode_json(with("{\"bits\":8191}").as_bytes()).unwrap(),
        full
    );
    // Only the gyro updated: no accel.
    for form in [
        "{\"bits\":56}".to_string(),
        "\"HIGHRES_IMU_UPDATED_XGYRO | HIGHRES_IMU_UPDATED_YGYRO | HIGHRES_IMU_UPDATED_ZGYRO\""
            .to_string(),
    ] {
        let d = decode_json(with(&form).as_bytes()).unwrap().unwrap();
        let SensorData::Imu(imu) = d.data else {
            panic!()
        };
        assert_eq!(imu.accel, None, "{form}");
        assert!(imu.gyro.is_some());
    }
    // An empty mask is a sender that ignores the field: take everything.
    assert_eq!(decode_json(with("\"\"").as_bytes()).unwrap(), full);
    // Only pressure updated: no IMU sample, the barometer alone.
    let d = decode_json(with("\"HIGHRES_IMU_UPDATED_ABS_PRESSURE\"").as_bytes())
        .unwrap()
        .unwrap();
    assert!(matches!(d.data, SensorData::Baro(_)), "{d:?}");
    // Only the gyro: no barometer either.
    let mut all = Vec::new();
    decode_json_into(with("{\"bits\":56}").as_bytes(), &mut all).unwrap();
    assert_eq!(all.len(), 1);
    assert!(matches!(
        decode_json(with("[1]").as_bytes()),
        Err(DecodeError::WrongType { .. })
    ));
}

// ------------------------------------------------------------------------ errors

#[test]
fn errors_name_message_and_field() {
    let text = some_or_skip!(golden("HIGHRES_IMU"));
    let e = decode_json(text.replace("\"xacc\":0.5,", "").as_bytes()).unwrap_err();
    assert_eq!(e.to_string(), "HIGHRES_IMU: missing field `xacc`");
    let e = decode_json(text.replace("\"xacc\":0.5", "\"xacc\":\"0.5\"").as_bytes()).unwrap_err();
    assert!(
        matches!(&e, DecodeError::WrongType { message, field, .. } if message == "HIGHRES_IMU" && field == "xacc"),
        "{e}"
    );
    let e = decode_json(text.replace("\"zacc\":-9.8125", "\"zacc\":NaN").as_bytes()).unwrap_err();
    assert!(
        matches!(&e, DecodeError::NonFinite { field, value } if field == "HIGHRES_IMU.zacc" && value.is_nan()),
        "{e}"
    );
    let e = decode_json(
        text.replace("\"zacc\":-9.8125", "\"zacc\":-Infinity")
            .as_bytes(),
    )
    .unwrap_err();
    assert_eq!(
        e,
        DecodeError::NonFinite {
            field: "HIGHRES_IMU.zacc".into(),
            value: f64::NEG_INFINITY
        }
    );
    let e = decode_json(
        text.replace("\"time_usec\":1700000000000000", "\"time_usec\":-1")
            .as_bytes(),
    )
    .unwrap_err();
    assert!(matches!(e, DecodeError::WrongType { .. }), "{e}");
    assert_eq!(decode_json(b"{\"header\":\xff}"), Err(DecodeError::NotUtf8));
    assert!(matches!(
        decode_json(b"{\"header\":"),
        Err(DecodeError::Json(_))
    ));
    assert!(matches!(
        decode_json(b"[1,2]"),
        Err(DecodeError::WrongType { .. })
    ));
    let no_header = text.replacen("\"header\"", "\"headr\"", 1);
    assert!(matches!(
        decode_json(no_header.as_bytes()),
        Err(DecodeError::MissingField { .. })
    ));
    // A message we do not know (ardupilotmega's AHRS2): valid, nothing to use.
    let ahrs2 = r#"{"header":{"system_id":1,"component_id":1,"sequence":1,"message_id":178},"message":{"type":"AHRS2","roll":NaN}}"#;
    assert_eq!(decode_json(ahrs2.as_bytes()), Ok(None));
    // A bad ODOMETRY frame id is named.
    let odo = some_or_skip!(golden("ODOMETRY")).replace("MAV_FRAME_LOCAL_FRD", "MAV_FRAME_GLOBAL");
    assert!(
        matches!(decode_json(odo.as_bytes()), Err(DecodeError::WrongType { field, .. }) if field == "frame_id")
    );
    // Older definitions' frame names are still understood.
    let odo =
        some_or_skip!(golden("ODOMETRY")).replace("MAV_FRAME_LOCAL_FRD", "MAV_FRAME_VISION_NED");
    assert!(decode_json(odo.as_bytes()).unwrap().is_some());
}

#[test]
fn a_nan_where_mavlink_means_unknown_is_none() {
    let text = some_or_skip!(golden("OPTICAL_FLOW_RAD"))
        .replace("\"integrated_xgyro\":0.0078125", "\"integrated_xgyro\":NaN")
        .replace("\"distance\":1.25", "\"distance\":NaN");
    let d = decode_json(text.as_bytes()).unwrap().unwrap();
    let SensorData::Flow(f) = d.data else {
        panic!()
    };
    assert_eq!(f.gyro, None);
    assert_eq!(f.tof, None);
    assert!(f.rate.is_some());
    let text = some_or_skip!(golden("LOCAL_POSITION_NED")).replace("\"vx\":0.25", "\"vx\":NaN");
    let d = decode_json(text.as_bytes()).unwrap().unwrap();
    let SensorData::AutopilotEstimate(e) = d.data else {
        panic!()
    };
    assert_eq!(e.velocity, None);
}

// ------------------------------------------------------------------------ vectors

struct Vector {
    v: Value,
}

impl Vector {
    fn all() -> Vec<Vector> {
        static DOC: std::sync::OnceLock<Value> = std::sync::OnceLock::new();
        let doc = DOC.get_or_init(|| serde_json::from_str(VECTORS).unwrap());
        doc["vectors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| Vector { v: v.clone() })
            .collect()
    }
    fn label(&self) -> String {
        format!(
            "{} seq {}",
            self.v["message"].as_str().unwrap(),
            self.v["sequence"]
        )
    }
    fn header(&self) -> MavHeader {
        MavHeader {
            system_id: self.v["system_id"].as_u64().unwrap() as u32,
            component_id: self.v["component_id"].as_u64().unwrap() as u8,
            sequence: self.v["sequence"].as_u64().unwrap() as u8,
        }
    }
    fn v2(&self) -> Vec<u8> {
        hex(self.v["v2_hex"].as_str().unwrap())
    }
    fn text(&self, key: &str) -> &str {
        self.v[key].as_str().unwrap()
    }
    /// The frame parsed by rust-mavlink 0.21.
    fn message(&self) -> MavMessage {
        let bytes = self.v2();
        let mut msg = None;
        frame::for_each_frame(&bytes, |f| {
            assert_eq!(f.version, MavlinkVersion::V2);
            msg = Some(MavMessage::parse(f.version, f.msg_id, f.payload).unwrap());
            Ok(())
        })
        .unwrap();
        msg.unwrap()
    }
}

/// A frame's own sample (HIGHRES_IMU's second, its barometer, is checked and dropped).
fn raw_one(bytes: &[u8]) -> Option<Decoded> {
    let mut out = Vec::new();
    decode_raw(bytes, &mut out).unwrap();
    assert!(
        out.len() <= 1 || (out.len() == 2 && matches!(out[1].data, SensorData::Baro(_))),
        "{out:?}"
    );
    out.into_iter().next()
}

fn opt_f64(v: &Value) -> Option<f64> {
    v.as_f64()
}

fn opt_vec<const N: usize>(v: &Value) -> Option<[f64; N]> {
    let a = v.as_array()?;
    assert_eq!(a.len(), N);
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(a) {
        *o = x.as_f64().unwrap();
    }
    Some(out)
}

fn check_opt<const N: usize>(got: Option<&[f64]>, want: &Value, what: &str) {
    match (got, opt_vec::<N>(want)) {
        (None, None) => {}
        (Some(g), Some(w)) => {
            for (i, (a, b)) in g.iter().zip(w.iter()).enumerate() {
                assert_close(*a, *b, &format!("{what}[{i}]"));
            }
        }
        (g, w) => panic!("{what}: {g:?} != {w:?}"),
    }
}

fn check_expected(d: &Decoded, e: &Value, label: &str) {
    assert_eq!(d.stamp_us, e["stamp_us"].as_i64(), "{label} stamp");
    let l = |what: &str| format!("{label} {what}");
    let rot = |m: &Value| Matrix3::from_row_slice(&opt_vec::<9>(m).unwrap());
    match (&d.data, e["kind"].as_str().unwrap()) {
        (SensorData::Imu(i), "imu") => {
            check_opt::<3>(
                i.accel.as_ref().map(|v| v.as_slice()),
                &e["accel"],
                &l("accel"),
            );
            check_opt::<3>(
                i.gyro.as_ref().map(|v| v.as_slice()),
                &e["gyro"],
                &l("gyro"),
            );
        }
        (SensorData::Attitude(a), "attitude") => {
            assert_rot(&a.orientation, &rot(&e["rotation"]), &l("rotation"));
            check_opt::<3>(
                a.rates.as_ref().map(|v| v.as_slice()),
                &e["rates"],
                &l("rates"),
            );
        }
        (SensorData::Flow(f), "flow") => {
            check_opt::<2>(
                f.rate.as_ref().map(|v| v.as_slice()),
                &e["rate"],
                &l("rate"),
            );
            check_opt::<3>(
                f.gyro.as_ref().map(|v| v.as_slice()),
                &e["gyro"],
                &l("gyro"),
            );
            check_opt::<2>(
                f.velocity.as_ref().map(|v| v.as_slice()),
                &e["velocity"],
                &l("velocity"),
            );
            assert_eq!(f.integration_s.is_some(), !e["integration_s"].is_null());
            if let Some(dt) = f.integration_s {
                assert_close(dt, e["integration_s"].as_f64().unwrap(), &l("dt"));
            }
            assert_eq!(u64::from(f.quality), e["quality"].as_u64().unwrap());
            assert_eq!(
                f.tof.as_ref().map(|t| t.distance_m),
                opt_f64(&e["tof_m"]),
                "{label}"
            );
        }
        (SensorData::Range(r), "range") => {
            assert_close(
                r.distance_m,
                e["distance_m"].as_f64().unwrap(),
                &l("distance"),
            );
            assert_eq!(r.min_m, opt_f64(&e["min_m"]));
            assert_eq!(r.max_m, opt_f64(&e["max_m"]));
            assert_eq!(
                r.signal_quality.map(u64::from),
                e["signal_quality"].as_u64(),
                "{label}"
            );
            check_opt::<1>(
                r.variance.as_ref().map(std::slice::from_ref),
                &e["variance"]
                    .as_f64()
                    .map_or(Value::Null, |v| serde_json::json!([v])),
                &l("variance"),
            );
            assert_eq!(r.orientation.map(u64::from), e["orientation"].as_u64());
        }
        (SensorData::Gnss(g), "gnss") => {
            assert_close(g.lat_deg, e["lat_deg"].as_f64().unwrap(), &l("lat"));
            assert_close(g.lon_deg, e["lon_deg"].as_f64().unwrap(), &l("lon"));
            assert_close(g.alt_m, e["alt_m"].as_f64().unwrap(), &l("alt"));
            assert_eq!(
                serde_json::to_value(g.fix).unwrap(),
                e["fix"],
                "{label} fix"
            );
            let diag = g.position_cov.as_deref().map(|c| c.diagonal());
            check_opt::<3>(
                diag.as_ref().map(|v| v.as_slice()),
                &e["position_cov_diag"],
                &l("cov"),
            );
            assert_eq!(g.satellites.map(u64::from), e["satellites"].as_u64());
            assert_eq!(g.hdop.is_some(), !e["hdop"].is_null());
            if let Some(h) = g.hdop {
                assert_close(h, e["hdop"].as_f64().unwrap(), &l("hdop"));
            }
            if let Some(h) = g.vdop {
                assert_close(h, e["vdop"].as_f64().unwrap(), &l("vdop"));
            }
            check_opt::<3>(
                g.velocity.as_ref().map(|v| v.as_slice()),
                &e["velocity"],
                &l("velocity"),
            );
        }
        (SensorData::AutopilotEstimate(a), "autopilot_estimate") => {
            check_opt::<3>(
                a.local_position.as_ref().map(|v| v.as_slice()),
                &e["local_position"],
                &l("local"),
            );
            let geo = a.geodetic.map(|(x, y, z)| [x, y, z]);
            check_opt::<3>(
                geo.as_ref().map(|v| v.as_slice()),
                &e["geodetic"],
                &l("geodetic"),
            );
            check_opt::<3>(
                a.velocity.as_ref().map(|v| v.as_slice()),
                &e["velocity"],
                &l("velocity"),
            );
            let yaw = a.yaw.map(|y| [y]);
            let want = e["yaw"]
                .as_f64()
                .map_or(Value::Null, |v| serde_json::json!([v]));
            check_opt::<1>(yaw.as_ref().map(|v| v.as_slice()), &want, &l("yaw"));
        }
        (SensorData::Odometry(o), "odometry") => {
            check_opt::<3>(Some(o.position.as_slice()), &e["position"], &l("position"));
            assert_rot(&o.orientation, &rot(&e["rotation"]), &l("rotation"));
            check_opt::<3>(
                o.velocity.as_ref().map(|v| v.as_slice()),
                &e["velocity"],
                &l("velocity"),
            );
            check_opt::<3>(
                o.angular_velocity.as_ref().map(|v| v.as_slice()),
                &e["angular_velocity"],
                &l("angular"),
            );
            // Row-major in the file; nalgebra is column-major, and both are symmetric.
            check_opt::<36>(
                o.pose_cov.as_ref().map(|v| v.as_slice()),
                &e["pose_cov"],
                &l("pose_cov"),
            );
            check_opt::<36>(
                o.twist_cov.as_ref().map(|v| v.as_slice()),
                &e["twist_cov"],
                &l("twist_cov"),
            );
            assert_eq!(o.frame_id, e["frame_id"].as_str().unwrap());
            assert_eq!(o.child_frame_id, e["child_frame_id"].as_str().unwrap());
            assert_eq!(
                o.reset_counter.map(u64::from),
                e["reset_counter"].as_u64(),
                "{label}"
            );
            assert_eq!(o.quality.map(i64::from), e["quality"].as_i64(), "{label}");
        }
        (got, kind) => panic!("{label}: decoded {got:?}, expected a {kind}"),
    }
}

#[test]
fn vectors_raw_and_json_decode_alike_and_as_expected() {
    let vectors = Vector::all();
    assert_eq!(vectors.len(), 20);
    for vec in &vectors {
        let label = vec.label();
        let raw = raw_one(&vec.v2());
        let json = decode_json(vec.text("json").as_bytes()).unwrap();
        let legacy = decode_json(vec.text("json_legacy").as_bytes()).unwrap();
        assert_eq!(raw, json, "{label}: raw vs JSON");
        assert_eq!(json, legacy, "{label}: JSON vs legacy JSON");
        let h = vec.header();
        // Heartbeats carry the armed state: an autopilot's decodes (base_mode bit 128),
        // a companion's (ours: MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) not.
        if vec.v["message"] == "HEARTBEAT" {
            let f = &vec.v["fields"];
            let autopilot_type =
                f["autopilot"].as_u64() != Some(8) && f["type"].as_u64() != Some(18);
            let want = autopilot_type.then(|| {
                SensorData::VehicleState(crate::sample::VehicleState {
                    armed: Some(f["base_mode"].as_u64().unwrap_or(0) & 128 != 0),
                    landed: None,
                })
            });
            assert_eq!(raw.as_ref().map(|d| d.data.clone()), want, "{label}");
            continue;
        }
        match (&raw, &vec.v["expected"]) {
            (None, Value::Null) => {}
            (Some(d), e) if !e.is_null() => {
                assert_eq!(d.mav_origin, Some((h.system_id as u8, h.component_id)));
                check_expected(d, e, &label);
            }
            (d, e) => panic!("{label}: {d:?} vs expected {e}"),
        }
        if let Some(v1) = vec.v["v1_hex"].as_str() {
            let d1 = raw_one(&hex(v1));
            match (&d1, &vec.v["expected_v1"]) {
                (None, Value::Null) => {}
                (Some(d), e) if !e.is_null() => check_expected(d, e, &format!("{label} v1")),
                (d, e) => panic!("{label} v1: {d:?} vs expected {e}"),
            }
        }
    }
}

#[test]
fn vectors_encode_byte_for_byte() {
    for vec in Vector::all() {
        let label = vec.label();
        let msg = vec.message();
        assert_eq!(
            encode_json(vec.header(), &msg).unwrap(),
            vec.text("json"),
            "{label}: encode_json"
        );
        assert_eq!(
            encode_raw_v2(vec.header(), &msg).unwrap(),
            vec.v2(),
            "{label}: encode_raw_v2"
        );
    }
}

#[test]
fn encode_json_golden_lines_byte_for_byte() {
    // The real bridge's text, rebuilt from a message rust-mavlink 0.21's serde reads out
    // of it (so 0.21 also reads 0.16's form). Not the NaN line: serde reads no f32 from
    // null; the vectors cover NaN.
    for line in some_or_skip!(golden_file("encode_json_golden_lines_byte_for_byte")).lines() {
        let v: Value = serde_json::from_str(line).unwrap();
        if v["message"] == "ODOMETRY(nan)" {
            continue;
        }
        let text = v["payload"].as_str().unwrap();
        let root: Value = serde_json::from_str(&json5::to_strict_json(text)).unwrap();
        let msg: MavMessage = serde_json::from_value(root["message"].clone()).unwrap();
        let h = &root["header"];
        let header = MavHeader {
            system_id: h["system_id"].as_u64().unwrap() as u32,
            component_id: h["component_id"].as_u64().unwrap() as u8,
            sequence: h["sequence"].as_u64().unwrap() as u8,
        };
        assert_eq!(encode_json(header, &msg).unwrap(), text, "{}", v["message"]);
    }
}

#[test]
fn encode_refuses_a_system_id_over_255() {
    let msg = MavMessage::HEARTBEAT(mc::HEARTBEAT_DATA::default());
    let header = MavHeader {
        system_id: 256,
        component_id: 197,
        sequence: 0,
    };
    assert!(matches!(
        encode_json(header, &msg),
        Err(EncodeError::OutOfRange { .. })
    ));
    assert!(matches!(
        encode_raw_v2(header, &msg),
        Err(EncodeError::OutOfRange { .. })
    ));
}

#[test]
fn encode_json_writes_nan_and_drops_unknown_flag_bits() {
    // Bit 0x4000 names no HIGHRES_IMU_UPDATED flag: 0.21 would print it as 0x4000.
    let msg = MavMessage::HIGHRES_IMU(mc::HIGHRES_IMU_DATA {
        fields_updated: mc::HighresImuUpdatedFlags::from_bits_retain(0x4001 | 0x1000),
        ..Default::default()
    });
    let text = encode_json(MavHeader::default(), &msg).unwrap();
    assert!(
        text.contains(
            "\"fields_updated\":\"HIGHRES_IMU_UPDATED_XACC | HIGHRES_IMU_UPDATED_TEMPERATURE\""
        ),
        "{text}"
    );
    let msg = MavMessage::VISION_POSITION_ESTIMATE(mc::VISION_POSITION_ESTIMATE_DATA {
        covariance: [f32::NAN; 21],
        x: f32::INFINITY,
        ..Default::default()
    });
    let text = encode_json(MavHeader::default(), &msg).unwrap();
    assert!(text.contains("\"x\":Infinity,"), "{text}");
    assert!(text.contains("\"covariance\":[NaN,NaN,"), "{text}");
}

// ------------------------------------------------------------------------ round trip

fn samples() -> Vec<(i64, SensorData)> {
    use crate::sample::*;
    let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 2.5);
    vec![
        (
            1_000_000,
            SensorData::Imu(Imu {
                gyro: Some(v3(0.0625, 0.125, -0.25)),
                accel: Some(v3(0.5, -0.25, 9.8125)),
                orientation: None,
                gyro_cov: None,
                accel_cov: None,
                orientation_cov: None,
            }),
        ),
        (
            2_000_000,
            SensorData::Attitude(Attitude {
                orientation: q,
                rates: Some(v3(0.125, -0.5, 0.25)),
            }),
        ),
        (
            3_000_000,
            SensorData::Flow(OpticalFlow {
                rate: Some(Vector2::new(0.5, -0.25)),
                gyro: None,
                velocity: None,
                integration_s: Some(0.025),
                quality: 200,
                status: None,
                tof: Some(Tof {
                    distance_m: 1.5,
                    strength: None,
                    precision: None,
                    status: None,
                }),
            }),
        ),
        (
            4_000_000,
            SensorData::Range(Range {
                distance_m: 2.5,
                min_m: Some(0.1),
                max_m: Some(12.0),
                signal_quality: Some(80),
                variance: Some(0.0004),
                orientation: Some(25),
            }),
        ),
        (
            5_000_000,
            SensorData::Odometry(Box::new(Odometry {
                position: v3(1.5, -2.0, 0.75),
                orientation: q,
                velocity: Some(v3(0.25, 0.5, -0.125)),
                angular_velocity: None,
                pose_cov: Some(nalgebra::Matrix6::from_diagonal(&nalgebra::Vector6::new(
                    0.01, 0.02, 0.03, 0.001, 0.002, 0.003,
                ))),
                twist_cov: None,
                frame_id: "MAV_FRAME_LOCAL_NED".into(),
                child_frame_id: "MAV_FRAME_BODY_FRD".into(),
                reset_counter: Some(7),
                quality: Some(-1),
            })),
        ),
        (
            7_000_000,
            SensorData::Baro(crate::sample::Baro {
                pressure_pa: 95_461.25,
                temperature_c: Some(31.5),
                variance: None,
            }),
        ),
        (
            6_000_000,
            SensorData::AutopilotEstimate(AutopilotEstimate {
                local_position: Some(v3(1.0, 2.0, 3.0)),
                geodetic: None,
                velocity: None,
                yaw: None,
            }),
        ),
    ]
}

/// SCALED_PRESSURE in hPa: a value in Pa (a sender's unit slip) is refused, naming the
/// field; SCALED_PRESSURE2 and 3 decode alike.
#[test]
fn scaled_pressure_decodes_in_hectopascal_and_refuses_pascal() {
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let ok = MavMessage::SCALED_PRESSURE2(mc::SCALED_PRESSURE2_DATA {
        time_boot_ms: 1234,
        press_abs: 1001.5,
        temperature: 2150,
        ..Default::default()
    });
    let d = raw_one(&encode_raw_v2(header, &ok).unwrap()).unwrap();
    assert_eq!(d.stamp_us, Some(1_234_000));
    let SensorData::Baro(b) = d.data else {
        panic!("{:?}", d.data)
    };
    assert!((b.pressure_pa - 100_150.0).abs() < 0.01);
    assert_eq!(b.temperature_c, Some(21.5));
    let pascal = MavMessage::SCALED_PRESSURE(mc::SCALED_PRESSURE_DATA {
        time_boot_ms: 1234,
        press_abs: 100_150.0,
        ..Default::default()
    });
    let e = decode_json(encode_json(header, &pascal).unwrap().as_bytes()).unwrap_err();
    assert!(e.to_string().contains("press_abs"), "{e}");
}

/// HIGHRES_IMU carries PX4's barometer (`abs_pressure`, hPa) beside the IMU: both come
/// out of one message, each stamped `time_usec`; a pressure the mask does not claim is
/// not repeated as a reading; PX4's Pa are read as Pa, and a claimed pressure that is
/// neither hPa nor Pa is refused as the barometer part's error while the IMU part of
/// the message is kept.
#[test]
fn highres_imu_gives_its_barometer_beside_the_imu() {
    // A zero mask with a zero pressure (a sender that fills neither) gives the IMU only.
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let msg = |abs_pressure: f32, fields_updated| {
        MavMessage::HIGHRES_IMU(mc::HIGHRES_IMU_DATA {
            time_usec: 5_000_000,
            zacc: -9.81,
            abs_pressure,
            temperature: 20.0,
            fields_updated,
            ..Default::default()
        })
    };
    let raw = |m: &MavMessage| {
        let mut out = Vec::new();
        let r = decode_raw(&encode_raw_v2(header, m).unwrap(), &mut out);
        (r, out)
    };
    let (r, out) = raw(&msg(950.0, mc::HighresImuUpdatedFlags::all()));
    r.unwrap();
    assert_eq!(out.len(), 2);
    let SensorData::Baro(b) = &out[1].data else {
        panic!("{out:?}")
    };
    assert!((b.pressure_pa - 95_000.0).abs() < 0.01);
    assert_eq!(out[1].stamp_us, Some(5_000_000));
    let (r, out) = raw(&msg(0.0, mc::HighresImuUpdatedFlags::empty()));
    r.unwrap();
    assert_eq!(out.len(), 1);
    assert!(matches!(out[0].data, SensorData::Imu(_)));
    // PX4 1.16's Pa.
    let (r, out) = raw(&msg(95_578.8, mc::HighresImuUpdatedFlags::all()));
    r.unwrap();
    let SensorData::Baro(b) = &out[1].data else {
        panic!("{out:?}")
    };
    assert!((b.pressure_pa - 95_578.8).abs() < 0.01);
    let (r, out) = raw(&msg(3_000.0, mc::HighresImuUpdatedFlags::all()));
    let e = r.unwrap_err();
    assert!(e.to_string().contains("abs_pressure"), "{e}");
    assert!(
        matches!(
            e,
            DecodeError::Part {
                kind: crate::sample::SensorKind::Baro,
                ..
            }
        ),
        "{e:?}"
    );
    assert_eq!(out.len(), 1, "the IMU part is kept: {out:?}");
    assert!(matches!(out[0].data, SensorData::Imu(_)));
    // mavlink-server's JSON of a real PX4 message: the same two samples.
    let text = some_or_skip!(golden("HIGHRES_IMU"));
    let mut all = Vec::new();
    decode_json_into(text.as_bytes(), &mut all).unwrap();
    assert_eq!(all.len(), 2, "{all:?}");
    assert!(matches!(all[0].data, SensorData::Imu(_)));
    let SensorData::Baro(b) = &all[1].data else {
        panic!("{:?}", all[1])
    };
    assert!(
        (b.pressure_pa - 101_325.0).abs() < 0.01,
        "{}",
        b.pressure_pa
    );
    assert_eq!(b.temperature_c, Some(35.5));
    assert_eq!(all[1].stamp_us, all[0].stamp_us);
    assert_eq!(all[1].mav_origin, Some((1, 1)));
}

#[test]
fn samples_round_trip_through_both_wire_forms() {
    for (stamp, data) in samples() {
        let msg = sample_to_message(stamp, &data).unwrap();
        let header = MavHeader {
            system_id: 1,
            component_id: 197,
            sequence: 9,
        };
        let raw = raw_one(&encode_raw_v2(header, &msg).unwrap()).unwrap();
        let json = decode_json(encode_json(header, &msg).unwrap().as_bytes())
            .unwrap()
            .unwrap();
        assert_eq!(raw, json);
        assert_eq!(raw.stamp_us, Some(stamp));
        assert_eq!(raw.mav_origin, Some((1, 197)));
        // f32 on the wire: compare loosely.
        let close3 = |a: Option<Vector3<f64>>, b: Option<Vector3<f64>>| match (a, b) {
            (Some(a), Some(b)) => assert!((a - b).abs().max() < 1e-6, "{a} {b}"),
            (a, b) => assert_eq!(a, b),
        };
        match (&raw.data, &data) {
            (SensorData::Imu(a), SensorData::Imu(b)) => {
                close3(a.gyro, b.gyro);
                close3(a.accel, b.accel);
            }
            (SensorData::Attitude(a), SensorData::Attitude(b)) => {
                assert!(a.orientation.angle_to(&b.orientation) < 1e-6);
                close3(a.rates, b.rates);
            }
            (SensorData::Flow(a), SensorData::Flow(b)) => {
                assert!((a.rate.unwrap() - b.rate.unwrap()).abs().max() < 1e-6);
                assert_eq!(a.gyro, None);
                assert!((a.integration_s.unwrap() - 0.025).abs() < 1e-9);
                assert_eq!(a.tof.as_ref().map(|t| t.distance_m), Some(1.5));
                assert_eq!(a.quality, b.quality);
            }
            (SensorData::Range(a), SensorData::Range(b)) => {
                assert_eq!(a.distance_m, b.distance_m);
                assert_eq!(a.signal_quality, b.signal_quality);
                assert!((a.variance.unwrap() - 0.0004).abs() < 1e-12);
                assert_eq!(a.orientation, b.orientation);
            }
            (SensorData::Odometry(a), SensorData::Odometry(b)) => {
                close3(Some(a.position), Some(b.position));
                assert!(a.orientation.angle_to(&b.orientation) < 1e-6);
                close3(a.velocity, b.velocity);
                assert_eq!(a.angular_velocity, None);
                assert!((a.pose_cov.unwrap() - b.pose_cov.unwrap()).abs().max() < 1e-8);
                assert_eq!(a.twist_cov, None);
                assert_eq!(a.reset_counter, Some(7));
                assert_eq!(a.quality, Some(-1));
            }
            (SensorData::Baro(a), SensorData::Baro(b)) => {
                // hPa as f32 on the wire: a few mPa.
                assert!((a.pressure_pa - b.pressure_pa).abs() < 0.01, "{a:?}");
                assert_eq!(a.temperature_c, b.temperature_c);
            }
            (SensorData::AutopilotEstimate(a), SensorData::AutopilotEstimate(b)) => {
                close3(a.local_position, b.local_position);
                assert_eq!(a.velocity, None);
            }
            (a, b) => panic!("{a:?} vs {b:?}"),
        }
    }
}

#[test]
fn frame_changes_are_their_own_inverse() {
    let q = UnitQuaternion::from_euler_angles(0.3, -0.7, 2.0);
    let back = frames::q_ned_frd_to_enu_flu(frames::q_ned_frd_to_enu_flu(q));
    assert!(back.angle_to(&q) < 1e-12);
}

// ------------------------------------------------------------------------ corruption

fn vector_frame(message: &str) -> Vec<u8> {
    Vector::all()
        .into_iter()
        .find(|v| v.v["message"] == message)
        .unwrap()
        .v2()
}

#[test]
fn a_bad_crc_costs_only_its_frame() {
    let a = vector_frame("SCALED_IMU");
    let mut b = vector_frame("GPS_RAW_INT");
    let c = vector_frame("ATTITUDE");
    let n = b.len();
    b[n - 1] ^= 0x55;
    let buf = [a.clone(), b, c.clone()].concat();
    let mut out = Vec::new();
    let e = decode_raw(&buf, &mut out).unwrap_err();
    assert!(e.to_string().contains("bad CRC"), "{e}");
    assert_eq!(out.len(), 2);
    assert_eq!(out[0], raw_one(&a).unwrap());
    assert_eq!(out[1], raw_one(&c).unwrap());
    // A corrupted payload byte (not only the CRC) is caught the same way.
    let mut b = vector_frame("GPS_RAW_INT");
    b[12] ^= 1;
    let mut out = Vec::new();
    assert!(decode_raw(&[b, c].concat(), &mut out).is_err());
    assert_eq!(out.len(), 1);
}

#[test]
fn truncated_frames_and_stray_bytes() {
    let a = vector_frame("SCALED_IMU");
    let c = vector_frame("ATTITUDE");
    // A truncated tail.
    let buf = [a.clone(), c[..c.len() - 3].to_vec()].concat();
    let mut out = Vec::new();
    let e = decode_raw(&buf, &mut out).unwrap_err();
    assert!(
        matches!(e, DecodeError::Truncated { offset, .. } if offset == a.len()),
        "{e}"
    );
    assert_eq!(out.len(), 1);
    // A truncated frame in front of a good one: the good one still decodes.
    let buf = [c[..5].to_vec(), a.clone()].concat();
    let mut out = Vec::new();
    assert!(decode_raw(&buf, &mut out).is_err());
    assert_eq!(out.len(), 1);
    // Bytes that are no frame.
    let buf = [b"hello".to_vec(), a.clone(), b"!".to_vec()].concat();
    let mut out = Vec::new();
    let e = decode_raw(&buf, &mut out).unwrap_err();
    assert!(e.to_string().contains("5 byte(s) at offset 0"), "{e}");
    assert_eq!(out.len(), 1);
    // Empty input: nothing, no error.
    let mut out = Vec::new();
    assert_eq!(decode_raw(&[], &mut out), Ok(()));
    assert!(out.is_empty());
}

/// A MAVLink 2 frame with any message id and payload (CRC over `extra`).
fn v2_frame(id: u32, payload: &[u8], extra: u8, incompat: u8) -> Vec<u8> {
    let idb = id.to_le_bytes();
    let mut f = vec![
        0xFD,
        payload.len() as u8,
        incompat,
        0,
        3,
        1,
        1,
        idb[0],
        idb[1],
        idb[2],
    ];
    f.extend_from_slice(payload);
    let crc = ::mavlink::calculate_crc(&f[1..], extra);
    f.extend_from_slice(&crc.to_le_bytes());
    if incompat & 1 != 0 {
        f.extend_from_slice(&[0xAA; 13]);
    }
    f
}

#[test]
fn foreign_messages_are_skipped_and_signed_frames_read() {
    let a = vector_frame("HIGHRES_IMU");
    // ardupilotmega's AHRS2 (id 178) is not in common: skipped without an error.
    let ahrs2 = v2_frame(178, &[1, 2, 3, 4, 0xFD, 6], 47, 0);
    let mut out = Vec::new();
    decode_raw(&[ahrs2.clone(), a.clone(), ahrs2].concat(), &mut out).unwrap();
    // HIGHRES_IMU's two samples: the IMU and its barometer.
    assert_eq!(out.len(), 2);
    // A signed frame (signature not checked) decodes like the unsigned one.
    let plain = raw_one(&a).unwrap();
    let len = usize::from(a[1]);
    let payload = &a[10..10 + len];
    let signed = v2_frame(105, payload, mc::HIGHRES_IMU_DATA::EXTRA_CRC, 1);
    let mut d = raw_one(&signed).unwrap();
    d.mav_origin = plain.mav_origin;
    assert_eq!(d, plain);
    // Unknown incompatibility flags: rejected.
    let mut out = Vec::new();
    assert!(decode_raw(
        &v2_frame(105, payload, mc::HIGHRES_IMU_DATA::EXTRA_CRC, 4),
        &mut out
    )
    .is_err());
    assert!(out.is_empty());
}

#[test]
fn filtered_raw_decoding_keeps_what_is_asked() {
    let buf = [
        vector_frame("HIGHRES_IMU"),
        vector_frame("SCALED_IMU"),
        vector_frame("RAW_IMU"),
    ]
    .concat();
    let mut out = Vec::new();
    decode_raw(&buf, &mut out).unwrap();
    // Three IMUs and HIGHRES_IMU's barometer.
    assert_eq!(out.len(), 4);
    let mut out = Vec::new();
    decode_raw_filtered(&buf, &|n| n == "SCALED_IMU", &mut out).unwrap();
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].stamp_us, Some(123_456_000));
}

use ::mavlink::MessageData;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut out = Vec::new();
        let _ = decode_raw(&bytes, &mut out);
        let _ = decode_json(&bytes);
    }

    #[test]
    fn mutated_frames_never_panic(i in 0usize..20, pos in 0usize..300, byte in any::<u8>(), cut in 0usize..300) {
        let mut f = Vector::all().into_iter().nth(i).unwrap().v2();
        let n = f.len();
        f[pos % n] = byte;
        f.truncate(cut.max(1));
        let mut out = Vec::new();
        let _ = decode_raw(&f, &mut out);
        // Random frames with the right framing but random payloads.
    }

    #[test]
    fn random_payloads_with_good_crc_never_panic(id in prop::sample::select(vec![24u32, 26, 27, 30, 31, 32, 33, 100, 105, 106, 132, 331]), payload in proptest::collection::vec(any::<u8>(), 0..255)) {
        let extra = MavMessage::extra_crc(id);
        let mut out = Vec::new();
        let _ = decode_raw(&v2_frame(id, &payload, extra, 0), &mut out);
    }

    #[test]
    fn mutated_json_never_panics(i in 0usize..20, pos in 0usize..2000, ch in any::<char>(), cut in 0usize..2000) {
        let v = Vector::all().into_iter().nth(i).unwrap();
        let mut t: Vec<char> = v.text("json").chars().collect();
        let n = t.len();
        t[pos % n] = ch;
        t.truncate(cut.max(1));
        let s: String = t.into_iter().collect();
        let _ = decode_json(s.as_bytes());
    }
}

#[test]
fn the_signing_clock_counts_10_us_from_2015() {
    // 2015-01-01 00:00:00 UTC, one second later, and before it (never negative).
    assert_eq!(signing_timestamp(1_420_070_400_000_000), 0);
    assert_eq!(signing_timestamp(1_420_070_401_000_000), 100_000);
    assert_eq!(signing_timestamp(0), 0);
    // pymavlink's MAVLink_signing: int((time.time() - 1420070400) * 100000).
    assert_eq!(signing_timestamp(1_764_000_000_123_450), 34_392_960_012_345);
}

#[test]
fn timesyncs_from_a_stream_cut_anywhere_are_all_found() {
    use ::mavlink::dialects::common::TIMESYNC_DATA;
    let header = |seq| MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: seq,
    };
    // Three TIMESYNCs with a HEARTBEAT and junk (a stray STX among them) between.
    let mut stream = Vec::new();
    for i in 0..3u8 {
        let m = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 1_000 + i64::from(i),
            target_system: 0,
            target_component: 0,
        });
        stream.extend(encode_raw_v2(header(i), &m).unwrap());
        stream.extend([0x00, 0xFD, 0x42]);
        stream.extend(
            encode_raw_v2(
                header(i),
                &MavMessage::HEARTBEAT(::mavlink::dialects::common::HEARTBEAT_DATA::default()),
            )
            .unwrap(),
        );
    }
    let want: Vec<i64> = vec![1_000, 1_001, 1_002];
    // Every single cut, and reads of every size.
    for cut in 0..=stream.len() {
        let mut s = StreamTimesyncs::default();
        let mut got: Vec<i64> = s.push(&stream[..cut]).iter().map(|t| t.data.ts1).collect();
        got.extend(s.push(&stream[cut..]).iter().map(|t| t.data.ts1));
        assert_eq!(got, want, "cut at {cut}");
    }
    for size in 1..40 {
        let mut s = StreamTimesyncs::default();
        let got: Vec<i64> = stream
            .chunks(size)
            .flat_map(|c| s.push(c))
            .map(|t| t.data.ts1)
            .collect();
        assert_eq!(got, want, "reads of {size}");
    }
    // Junk that never completes a frame stays bounded.
    let mut s = StreamTimesyncs::default();
    for _ in 0..1_000 {
        assert!(s.push(&[0xFD, 0x40]).is_empty());
    }
    assert!(s.pending.len() <= ::mavlink::consts::MAX_FRAME_SIZE);
}
