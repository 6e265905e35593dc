//! Tests against the real peers: zenoh-bridge-ros2dds captures (golden) and rosbags
//! (tests/data/ros_vectors.json, from tests/py/gen_ros_vectors.py), plus round trips,
//! validation, truncation and fuzzing.

use super::wire::{self, Writer};
use super::*;
use crate::sample::{
    Baro as SBaro, GnssFix, GnssFixType, Imu as SImu, Odometry as SOdometry, OpticalFlow,
    Range as SRange, Tof,
};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector2, Vector3 as V3};
use proptest::prelude::*;
use serde_json::{json, Value};

const VECTORS: &str = include_str!("../../../../../tests/data/ros_vectors.json");

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len().is_multiple_of(2), "odd hex length");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

fn vectors() -> Vec<Value> {
    let doc: Value = serde_json::from_str(VECTORS).expect("ros_vectors.json");
    doc["vectors"].as_array().expect("vectors").clone()
}

/// The real zenoh-bridge-ros2dds captures (../shared/data/bridges), or None (skipped).
fn golden(test: &str) -> Option<Vec<Value>> {
    let path = crate::shared_data::shared_data("bridges/ros2dds-samples.jsonl", test)?;
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str(l).expect("golden line"))
        .collect::<Vec<_>>()
        .into()
}

// ------------------------------------------------------------ message ⇄ JSON view

/// The message as rosbags / rclpy show it (ROS 2 field names; no `seq`).
trait AsJson {
    fn json(&self) -> Value;
}

impl AsJson for Header {
    fn json(&self) -> Value {
        json!({"stamp": {"sec": self.stamp_sec, "nanosec": self.stamp_nanosec}, "frame_id": self.frame_id})
    }
}
impl AsJson for Vector3 {
    fn json(&self) -> Value {
        json!({"x": self.x, "y": self.y, "z": self.z})
    }
}
impl AsJson for Quaternion {
    fn json(&self) -> Value {
        json!({"x": self.x, "y": self.y, "z": self.z, "w": self.w})
    }
}
impl AsJson for Pose {
    fn json(&self) -> Value {
        json!({"position": self.position.json(), "orientation": self.orientation.json()})
    }
}
impl AsJson for PoseWithCovariance {
    fn json(&self) -> Value {
        json!({"pose": self.pose.json(), "covariance": self.covariance.to_vec()})
    }
}
impl AsJson for TwistWithCovariance {
    fn json(&self) -> Value {
        json!({"twist": {"linear": self.twist.linear.json(), "angular": self.twist.angular.json()},
               "covariance": self.covariance.to_vec()})
    }
}
impl AsJson for NavSatFix {
    fn json(&self) -> Value {
        json!({"header": self.header.json(),
               "status": {"status": self.status.status, "service": self.status.service},
               "latitude": self.latitude, "longitude": self.longitude, "altitude": self.altitude,
               "position_covariance": self.position_covariance.to_vec(),
               "position_covariance_type": self.position_covariance_type})
    }
}
impl AsJson for Imu {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "orientation": self.orientation.json(),
               "orientation_covariance": self.orientation_covariance.to_vec(),
               "angular_velocity": self.angular_velocity.json(),
               "angular_velocity_covariance": self.angular_velocity_covariance.to_vec(),
               "linear_acceleration": self.linear_acceleration.json(),
               "linear_acceleration_covariance": self.linear_acceleration_covariance.to_vec()})
    }
}
impl AsJson for Range {
    fn json(&self) -> Value {
        let mut v = json!({"header": self.header.json(), "radiation_type": self.radiation_type,
               "field_of_view": f64::from(self.field_of_view),
               "min_range": f64::from(self.min_range), "max_range": f64::from(self.max_range),
               "range": f64::from(self.range)});
        if let Some(var) = self.variance {
            v["variance"] = json!(f64::from(var));
        }
        v
    }
}
impl AsJson for FluidPressure {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "fluid_pressure": self.fluid_pressure,
               "variance": self.variance})
    }
}
impl AsJson for Odometry {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "child_frame_id": self.child_frame_id,
               "pose": self.pose.json(), "twist": self.twist.json()})
    }
}
impl AsJson for PoseStamped {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "pose": self.pose.json()})
    }
}
impl AsJson for PoseWithCovarianceStamped {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "pose": self.pose.json()})
    }
}
impl AsJson for FlowTof {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "distance": f64::from(self.distance),
               "strength": self.strength, "precision": self.precision,
               "tof_status": self.tof_status, "flow_vel_x": f64::from(self.flow_vel_x),
               "flow_vel_y": f64::from(self.flow_vel_y), "flow_quality": self.flow_quality,
               "flow_status": self.flow_status})
    }
}
impl AsJson for PointStamped {
    fn json(&self) -> Value {
        json!({"header": self.header.json(), "point": self.point.json()})
    }
}

/// Exact equality of two JSON trees; numbers compare by value (an integer-valued float
/// equals the integer), never with a tolerance.
fn assert_same(path: &str, a: &Value, b: &Value) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let same = match (x.as_i64(), y.as_i64()) {
                (Some(i), Some(j)) => i == j,
                _ => x.as_f64() == y.as_f64(),
            };
            assert!(same, "{path}: {x} != {y}");
        }
        (Value::Object(x), Value::Object(y)) => {
            let mut kx: Vec<_> = x.keys().collect();
            let mut ky: Vec<_> = y.keys().collect();
            kx.sort();
            ky.sort();
            assert_eq!(kx, ky, "{path}: different fields");
            for (k, v) in x {
                assert_same(&format!("{path}.{k}"), v, &y[k]);
            }
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{path}: different lengths");
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                assert_same(&format!("{path}[{i}]"), p, q);
            }
        }
        _ => assert_eq!(a, b, "{path}"),
    }
}

// ------------------------------------------------------------ expected samples (oracle)

fn f(v: &Value) -> f64 {
    v.as_f64().expect("number")
}
fn v3(v: &Value) -> V3<f64> {
    V3::new(f(&v["x"]), f(&v["y"]), f(&v["z"]))
}
fn floats(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(f).collect()
}
fn quat(v: &Value) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        f(&v["w"]),
        f(&v["x"]),
        f(&v["y"]),
        f(&v["z"]),
    ))
}
fn stamp(v: &Value) -> Option<i64> {
    let s = &v["header"]["stamp"];
    let (sec, ns) = (
        s["sec"].as_i64().expect("sec"),
        s["nanosec"].as_i64().expect("ns"),
    );
    Some(sec * 1_000_000 + ns / 1000)
}
fn cov6_or_none(v: &Value) -> Option<Matrix6<f64>> {
    let c = floats(v);
    (c.iter().any(|&x| x != 0.0)).then(|| Matrix6::from_row_slice(&c))
}
fn pose_odometry(v: &Value, frame: &str) -> SOdometry {
    SOdometry {
        position: v3(&v["position"]),
        orientation: quat(&v["orientation"]),
        velocity: None,
        angular_velocity: None,
        pose_cov: None,
        twist_cov: None,
        frame_id: frame.to_string(),
        child_frame_id: String::new(),
        reset_counter: None,
        quality: None,
    }
}

/// What skyfuse must make of message `v` of type `ty`, computed from the JSON values
/// (None for output-only types).
fn expected(ty: RosType, v: &Value) -> Option<Decoded> {
    let frame = v["header"]["frame_id"].as_str().expect("frame_id");
    let data = match ty {
        RosType::Px4(_) => unreachable!("px4_msgs have their own vectors (px4_tests.rs)"),
        RosType::NavSatFix => SensorData::Gnss(GnssFix {
            lat_deg: f(&v["latitude"]),
            lon_deg: f(&v["longitude"]),
            alt_m: f(&v["altitude"]),
            fix: match v["status"]["status"].as_i64() {
                Some(-1) => GnssFixType::NoFix,
                Some(0) => GnssFixType::Fix3d,
                _ => GnssFixType::Dgps,
            },
            position_cov: (v["position_covariance_type"].as_u64() != Some(0))
                .then(|| Box::new(Matrix3::from_row_slice(&floats(&v["position_covariance"])))),
            satellites: None,
            hdop: None,
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        }),
        RosType::Imu => SensorData::Imu(SImu {
            gyro: Some(v3(&v["angular_velocity"])),
            accel: Some(v3(&v["linear_acceleration"])),
            orientation: Some(quat(&v["orientation"])),
            gyro_cov: Some(Box::new(Matrix3::from_row_slice(&floats(
                &v["angular_velocity_covariance"],
            )))),
            accel_cov: Some(Box::new(Matrix3::from_row_slice(&floats(
                &v["linear_acceleration_covariance"],
            )))),
            orientation_cov: Some(Box::new(Matrix3::from_row_slice(&floats(
                &v["orientation_covariance"],
            )))),
        }),
        RosType::Range => SensorData::Range(SRange {
            distance_m: f(&v["range"]),
            min_m: Some(f(&v["min_range"])),
            max_m: Some(f(&v["max_range"])),
            signal_quality: None,
            variance: v.get("variance").map(f),
            orientation: None,
        }),
        RosType::Odometry => {
            let mut o = pose_odometry(&v["pose"]["pose"], frame);
            o.child_frame_id = v["child_frame_id"].as_str().expect("child").to_string();
            o.pose_cov = cov6_or_none(&v["pose"]["covariance"]);
            o.twist_cov = cov6_or_none(&v["twist"]["covariance"]);
            o.velocity = Some(v3(&v["twist"]["twist"]["linear"]));
            o.angular_velocity = Some(v3(&v["twist"]["twist"]["angular"]));
            SensorData::Odometry(Box::new(o))
        }
        RosType::PoseStamped => SensorData::Odometry(Box::new(pose_odometry(&v["pose"], frame))),
        RosType::PoseWithCovarianceStamped => {
            let mut o = pose_odometry(&v["pose"]["pose"], frame);
            o.pose_cov = cov6_or_none(&v["pose"]["covariance"]);
            SensorData::Odometry(Box::new(o))
        }
        RosType::FlowTof => SensorData::Flow(OpticalFlow {
            rate: Some(Vector2::new(f(&v["flow_vel_x"]), f(&v["flow_vel_y"]))),
            gyro: None,
            velocity: None,
            integration_s: None,
            quality: v["flow_quality"].as_u64().expect("q") as u8,
            status: Some(v["flow_status"].as_u64().expect("s") as u8),
            tof: Some(Tof {
                distance_m: f(&v["distance"]),
                strength: Some(v["strength"].as_u64().expect("strength") as u8),
                precision: Some(v["precision"].as_u64().expect("precision") as u8),
                status: Some(v["tof_status"].as_u64().expect("tof_status") as u8),
            }),
        }),
        RosType::FluidPressure => SensorData::Baro(SBaro {
            pressure_pa: f(&v["fluid_pressure"]),
            temperature_c: None,
            variance: Some(f(&v["variance"])).filter(|&x| x > 0.0),
        }),
        RosType::PointStamped => return None,
    };
    Some(Decoded {
        stamp_us: stamp(v),
        mav_origin: None,
        data,
    })
}

// ------------------------------------------------------------ per-type dispatch

/// Run `check::<M>()` with the message type named `ty`.
macro_rules! with_type {
    ($ty:expr, $check:ident ( $($arg:expr),* )) => {
        match $ty {
            RosType::NavSatFix => $check::<NavSatFix>($($arg),*),
            RosType::Imu => $check::<Imu>($($arg),*),
            RosType::Range => $check::<Range>($($arg),*),
            RosType::Odometry => $check::<Odometry>($($arg),*),
            RosType::PoseStamped => $check::<PoseStamped>($($arg),*),
            RosType::PoseWithCovarianceStamped => $check::<PoseWithCovarianceStamped>($($arg),*),
            RosType::FlowTof => $check::<FlowTof>($($arg),*),
            RosType::FluidPressure => $check::<FluidPressure>($($arg),*),
            RosType::PointStamped => $check::<PointStamped>($($arg),*),
            RosType::Px4(_) => unreachable!("px4_msgs have their own vectors (px4_tests.rs)"),
        }
    };
}

fn be_cdr<M: RosMessage>(m: &M) -> Vec<u8> {
    wire::write(m, Writer::cdr(true))
}

fn ty_of(v: &Value) -> RosType {
    let name = v["type"].as_str().or(v["ros_type"].as_str()).expect("type");
    RosType::from_name(name).unwrap_or_else(|| panic!("unknown type {name}"))
}

// ------------------------------------------------------------ golden: real bridge

fn check_golden<M: RosMessage + AsJson>(line: &Value) {
    let payload = unhex(line["payload_hex"].as_str().expect("payload_hex"));
    assert_eq!(payload.len() as u64, line["len"].as_u64().expect("len"));
    let ty = M::TYPE;
    let msg = M::from_cdr(&payload).expect("typed decode");
    assert_same(ty.ros2_name(), &msg.json(), &line["decoded"]);
    // Re-encoding gives the bridge's bytes up to the DDS writer's end padding.
    let ours = encode_cdr(&msg);
    assert!(ours.len() <= payload.len() && payload.len() - ours.len() < 4);
    assert_eq!(
        &payload[..ours.len()],
        &ours[..],
        "{ty}: re-encoded bytes differ"
    );
    assert!(payload[ours.len()..].iter().all(|&b| b == 0));
    let d = decode_cdr(ty, &payload).expect("decode_cdr");
    assert_eq!(Some(d), expected(ty, &line["decoded"]), "{ty}: sample");
}

#[test]
fn golden_ros2dds_captures_decode_exactly() {
    let lines = crate::some_or_skip!(golden("golden_ros2dds_captures_decode_exactly"));
    assert_eq!(lines.len(), 6);
    let mut seen = std::collections::HashSet::new();
    for line in &lines {
        let ty = ty_of(line);
        seen.insert(ty);
        with_type!(ty, check_golden(line));
    }
    assert_eq!(seen.len(), 3, "NavSatFix, Odometry and Imu");
}

#[test]
fn golden_values_spot_check() {
    // One value per message written out by hand, in case the oracle shares a mistake.
    let lines = crate::some_or_skip!(golden("golden_values_spot_check"));
    let d = decode_cdr(
        RosType::NavSatFix,
        &unhex(lines[0]["payload_hex"].as_str().unwrap()),
    );
    let SensorData::Gnss(g) = d.unwrap().data else {
        panic!("not gnss")
    };
    assert_eq!(g.lat_deg, 47.3977421);
    assert_eq!(g.position_cov.unwrap()[(2, 2)], 4.0);
    let d = decode_cdr(
        RosType::Odometry,
        &unhex(lines[2]["payload_hex"].as_str().unwrap()),
    )
    .unwrap();
    assert_eq!(d.stamp_us, Some(1_795_380_366_598_722));
    let SensorData::Odometry(o) = d.data else {
        panic!("not odometry")
    };
    assert_eq!(o.frame_id, "camera_odom_frame");
    assert_eq!(o.child_frame_id, "camera_pose_frame");
    assert_eq!(o.velocity, Some(V3::new(1.0, -0.5, 0.0)));
    assert_eq!(o.pose_cov.unwrap()[(5, 5)], 0.001);
}

// ------------------------------------------------------------ rosbags vectors

fn check_vector<M: RosMessage + AsJson + HeaderMut>(v: &Value) {
    let ty = M::TYPE;
    let values = &v["values"];
    let le = unhex(v["cdr_le"].as_str().expect("cdr_le"));
    let be = unhex(v["cdr_be"].as_str().expect("cdr_be"));
    let m = M::from_cdr(&le).expect("decode LE");
    assert_same(&format!("{ty} LE"), &m.json(), values);
    let m_be = M::from_cdr(&be).expect("decode BE");
    assert_eq!(m_be, m, "{ty}: BE and LE differ");
    assert_eq!(encode_cdr(&m), le, "{ty}: CDR LE bytes differ from rosbags");
    assert_eq!(be_cdr(&m), be, "{ty}: CDR BE bytes differ from rosbags");
    if let Some(ros1) = v["ros1"].as_str() {
        let ros1 = unhex(ros1);
        let m1 = M::from_ros1(&ros1).expect("decode ROS 1");
        assert_same(&format!("{ty} ROS 1"), &m1.json(), values);
        assert_eq!(
            u64::from(m1.clone().header_mut().seq),
            v["ros1_seq"].as_u64().unwrap()
        );
        assert_eq!(
            encode_ros1(&m1),
            ros1,
            "{ty}: ROS 1 bytes differ from rosbags"
        );
        assert_eq!(v["ros1_type"].as_str(), Some(ty.ros1_name()));
        assert_eq!(v["ros1_md5"].as_str(), Some(ty.ros1_md5()), "{ty}: md5");
        let want = expected(ty, values);
        match want {
            Some(want) => {
                assert_eq!(
                    decode_ros1(ty, &ros1).as_ref(),
                    Ok(&want),
                    "{ty}: ROS 1 sample"
                );
                assert_eq!(decode_cdr(ty, &le).as_ref(), Ok(&want), "{ty}: CDR sample");
                assert_eq!(
                    decode_cdr(ty, &be).as_ref(),
                    Ok(&want),
                    "{ty}: CDR BE sample"
                );
            }
            None => assert!(matches!(
                decode_cdr(ty, &le),
                Err(DecodeError::UnsupportedMessage(_))
            )),
        }
    } else {
        // Jazzy's Range (CDR only).
        assert_eq!(decode_cdr(ty, &le).ok(), expected(ty, values));
    }
}

/// Access to the header of any of our messages (test helper).
trait HeaderMut {
    fn header_mut(&mut self) -> &mut Header;
}
macro_rules! header_mut {
    ($($t:ty),*) => {$(impl HeaderMut for $t { fn header_mut(&mut self) -> &mut Header { &mut self.header } })*};
}
header_mut!(
    NavSatFix,
    Imu,
    Range,
    FluidPressure,
    Odometry,
    PoseStamped,
    PoseWithCovarianceStamped,
    FlowTof,
    PointStamped
);

#[test]
fn rosbags_vectors_decode_and_encode_byte_for_byte() {
    let vs = vectors();
    let mut types = std::collections::HashSet::new();
    for v in &vs {
        let ty = ty_of(v);
        types.insert(ty);
        with_type!(ty, check_vector(v));
    }
    assert_eq!(types.len(), RosType::ALL.len(), "every type has a vector");
    assert!(vs.iter().any(|v| v["store"] == "ros2_jazzy"));
}

#[test]
fn ros1_md5_matches_rosbags_for_every_type() {
    let vs = vectors();
    for ty in RosType::ALL {
        let v = vs
            .iter()
            .find(|v| v["type"] == ty.ros2_name() && v.get("ros1_md5").is_some())
            .unwrap_or_else(|| panic!("no vector for {ty}"));
        assert_eq!(v["ros1_md5"].as_str(), Some(ty.ros1_md5()), "{ty}");
        assert_eq!(v["ros1_type"].as_str(), Some(ty.ros1_name()), "{ty}");
    }
}

#[test]
fn jazzy_range_variance_is_read_and_humble_range_has_none() {
    let vs = vectors();
    let jazzy = vs.iter().find(|v| v["store"] == "ros2_jazzy").unwrap();
    let humble = vs
        .iter()
        .find(|v| v["type"] == "sensor_msgs/msg/Range" && v["store"] == "ros2_humble")
        .unwrap();
    let j = Range::from_cdr(&unhex(jazzy["cdr_le"].as_str().unwrap())).unwrap();
    assert_eq!(j.variance, Some(0.015625));
    let h = Range::from_cdr(&unhex(humble["cdr_le"].as_str().unwrap())).unwrap();
    assert_eq!(h.variance, None);
    let h1 = Range::from_ros1(&unhex(humble["ros1"].as_str().unwrap())).unwrap();
    assert_eq!(h1.variance, None);
    let d = decode_cdr(RosType::Range, &unhex(jazzy["cdr_le"].as_str().unwrap())).unwrap();
    let SensorData::Range(r) = d.data else {
        panic!()
    };
    assert_eq!(r.variance, Some(0.015625));
}

// ------------------------------------------------------------ names and serde

#[test]
fn type_names_both_forms_and_serde() {
    for ty in RosType::ALL {
        assert_eq!(RosType::from_name(ty.ros2_name()), Some(ty));
        assert_eq!(RosType::from_name(ty.ros1_name()), Some(ty));
        assert_eq!(ty.ros1_name(), ty.ros2_name().replace("/msg/", "/"));
        let s = serde_json::to_string(&ty).unwrap();
        assert_eq!(s, format!("\"{}\"", ty.ros2_name()));
        let back: RosType = serde_json::from_str(&format!("\"{}\"", ty.ros1_name())).unwrap();
        assert_eq!(back, ty);
    }
    assert_eq!(RosType::from_name("sensor_msgs/msg/Foo"), None);
    assert_eq!(RosType::from_name("Imu"), None);
    let err = serde_json::from_str::<RosType>("\"std_msgs/msg/String\"").unwrap_err();
    assert!(err.to_string().contains("std_msgs/msg/String"), "{err}");
}

// ------------------------------------------------------------ round trips

fn header(frame: &str) -> Header {
    Header {
        stamp_sec: 1_712_345_678,
        stamp_nanosec: 987_654_321,
        frame_id: frame.into(),
        seq: 77,
    }
}

fn roundtrip<M: RosMessage>(m: M) {
    let cdr = encode_cdr(&m);
    assert_eq!(&cdr[..4], &[0, 1, 0, 0]);
    // seq is not on the ROS 2 wire: compare CDR results with each other.
    let back = M::from_cdr(&cdr).unwrap();
    assert_eq!(M::from_cdr(&be_cdr(&m)).unwrap(), back, "BE");
    assert_eq!(encode_cdr(&back), cdr);
    let r1 = encode_ros1(&m);
    assert_eq!(M::from_ros1(&r1).unwrap(), m, "ROS 1");
}

#[test]
fn typed_roundtrip_every_type_both_formats() {
    let q = Quaternion {
        x: 0.1,
        y: 0.2,
        z: 0.3,
        w: 0.927,
    };
    let p = Vector3 {
        x: 1.0,
        y: -2.0,
        z: 3.5,
    };
    let cov: [f64; 36] = std::array::from_fn(|i| i as f64 * 0.5);
    roundtrip(NavSatFix {
        header: header("gps"),
        status: NavSatStatus {
            status: -1,
            service: 15,
        },
        latitude: -33.9,
        longitude: 151.2,
        altitude: 12.5,
        position_covariance: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0],
        position_covariance_type: 1,
    });
    roundtrip(Imu {
        header: header("i"),
        orientation: q,
        orientation_covariance: [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5],
        angular_velocity: p,
        angular_velocity_covariance: [0.1; 9],
        linear_acceleration: p,
        linear_acceleration_covariance: [0.2; 9],
    });
    for variance in [None, Some(0.25)] {
        roundtrip(Range {
            header: header("range12"),
            radiation_type: 0,
            field_of_view: 0.5,
            min_range: 0.1,
            max_range: f32::INFINITY,
            range: 2.5,
            variance,
        });
    }
    roundtrip(Odometry {
        header: header("odom"),
        child_frame_id: "base_link".into(),
        pose: PoseWithCovariance {
            pose: Pose {
                position: p,
                orientation: q,
            },
            covariance: cov,
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: p,
                angular: p,
            },
            covariance: cov,
        },
    });
    roundtrip(PoseStamped {
        header: header(""),
        pose: Pose {
            position: p,
            orientation: q,
        },
    });
    roundtrip(PoseWithCovarianceStamped {
        header: header("ααα"),
        pose: PoseWithCovariance {
            pose: Pose {
                position: p,
                orientation: q,
            },
            covariance: cov,
        },
    });
    roundtrip(FlowTof {
        header: header("flow"),
        distance: 1.5,
        strength: 1,
        precision: 2,
        tof_status: 3,
        flow_vel_x: -0.5,
        flow_vel_y: 0.25,
        flow_quality: 255,
        flow_status: 4,
    });
    roundtrip(PointStamped {
        header: header("fused"),
        point: p,
    });
}

fn sample_roundtrip(ty: RosType, stamp_us: i64, data: SensorData) {
    for ros1 in [false, true] {
        let bytes = if ros1 {
            encode_sample_ros1(ty, stamp_us, &data)
        } else {
            encode_sample_cdr(ty, stamp_us, &data)
        }
        .unwrap_or_else(|e| panic!("{ty}: {e}"));
        let d = if ros1 {
            decode_ros1(ty, &bytes)
        } else {
            decode_cdr(ty, &bytes)
        }
        .unwrap_or_else(|e| panic!("{ty} ros1={ros1}: {e}"));
        assert_eq!(d.stamp_us, Some(stamp_us), "{ty} ros1={ros1}");
        assert_eq!(d.mav_origin, None);
        assert_eq!(d.data, data, "{ty} ros1={ros1}");
    }
}

fn odo(velocity: bool) -> SOdometry {
    SOdometry {
        position: V3::new(1.5, -2.25, 0.75),
        orientation: UnitQuaternion::from_euler_angles(0.1, -0.2, 1.3),
        velocity: velocity.then(|| V3::new(0.5, 0.25, -0.125)),
        angular_velocity: velocity.then(|| V3::new(0.0, 0.0, 0.3)),
        pose_cov: velocity.then(|| Matrix6::from_fn(|r, c| (r * 6 + c) as f64)),
        twist_cov: velocity.then(|| Matrix6::from_diagonal_element(0.02)),
        frame_id: "camera_odom_frame".into(),
        child_frame_id: if velocity {
            "camera_pose_frame".into()
        } else {
            String::new()
        },
        reset_counter: None,
        quality: None,
    }
}

#[test]
fn sample_roundtrip_every_decodable_type_both_formats() {
    let t = 1_700_000_000_123_456;
    let full_cov = Matrix3::new(1.0, 0.1, 0.2, 0.1, 2.0, 0.3, 0.2, 0.3, 4.0);
    for (fix, cov) in [
        (GnssFixType::Fix3d, Some(full_cov)),
        (GnssFixType::NoFix, None),
        (GnssFixType::Dgps, Some(Matrix3::from_diagonal_element(2.0))),
    ] {
        sample_roundtrip(
            RosType::NavSatFix,
            t,
            SensorData::Gnss(GnssFix {
                lat_deg: 47.25,
                lon_deg: -8.5,
                alt_m: 400.0,
                fix,
                position_cov: cov.map(Box::new),
                satellites: None,
                hdop: None,
                vdop: None,
                velocity: None,
                velocity_up_known: false,
            }),
        );
    }
    for full in [true, false] {
        sample_roundtrip(
            RosType::Imu,
            t,
            SensorData::Imu(SImu {
                gyro: Some(V3::new(0.01, -0.02, 0.03)),
                accel: full.then(|| V3::new(0.1, 0.2, 9.8)),
                orientation: full.then(|| UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3)),
                gyro_cov: full.then(|| Box::new(Matrix3::from_diagonal_element(1e-4))),
                accel_cov: None,
                orientation_cov: full.then(|| Box::new(full_cov)),
            }),
        );
    }
    for limits in [true, false] {
        sample_roundtrip(
            RosType::Range,
            t,
            SensorData::Range(SRange {
                distance_m: 3.5,
                min_m: limits.then_some(0.25),
                max_m: limits.then_some(40.0),
                signal_quality: None,
                variance: None,
                orientation: None,
            }),
        );
    }
    for variance in [Some(36.0), None] {
        sample_roundtrip(
            RosType::FluidPressure,
            t,
            SensorData::Baro(SBaro {
                pressure_pa: 97_123.5,
                temperature_c: None,
                variance,
            }),
        );
    }
    for v in [true, false] {
        sample_roundtrip(RosType::Odometry, t, SensorData::Odometry(Box::new(odo(v))));
    }
    sample_roundtrip(
        RosType::PoseStamped,
        t,
        SensorData::Odometry(Box::new(odo(false))),
    );
    let mut pwc = odo(false);
    pwc.pose_cov = Some(Matrix6::from_diagonal_element(0.5));
    sample_roundtrip(
        RosType::PoseWithCovarianceStamped,
        t,
        SensorData::Odometry(Box::new(pwc)),
    );
    for tof in [true, false] {
        sample_roundtrip(
            RosType::FlowTof,
            t,
            SensorData::Flow(OpticalFlow {
                rate: Some(Vector2::new(-0.25, 0.125)),
                gyro: None,
                velocity: None,
                integration_s: None,
                quality: 200,
                status: Some(1),
                tof: tof.then_some(Tof {
                    distance_m: 1.25,
                    strength: Some(90),
                    precision: Some(3),
                    status: Some(0),
                }),
            }),
        );
    }
}

#[test]
fn encode_sample_point_stamped_and_errors() {
    let t = 1_700_000_000_000_000;
    let bytes = encode_sample_cdr(
        RosType::PointStamped,
        t,
        &SensorData::Odometry(Box::new(odo(false))),
    )
    .unwrap();
    let p = PointStamped::from_cdr(&bytes).unwrap();
    assert_eq!((p.point.x, p.point.y, p.point.z), (1.5, -2.25, 0.75));
    assert_eq!(p.header.frame_id, "camera_odom_frame");
    assert_eq!(
        (p.header.stamp_sec, p.header.stamp_nanosec),
        (1_700_000_000, 0)
    );
    // Wrong sample kind for the type.
    let e = encode_sample_cdr(RosType::Imu, t, &SensorData::Odometry(Box::new(odo(false))))
        .unwrap_err();
    assert!(matches!(e, EncodeError::Unsupported(_)), "{e}");
    // Stamps the wire cannot hold.
    let data = SensorData::Odometry(Box::new(odo(false)));
    let e = encode_sample_cdr(
        RosType::Odometry,
        (i64::from(i32::MAX) + 1) * 1_000_000,
        &data,
    )
    .unwrap_err();
    assert!(matches!(e, EncodeError::OutOfRange { .. }), "{e}");
    assert!(encode_sample_ros1(RosType::Odometry, -1, &data).is_err());
    // Non-finite values name the field.
    let mut o = odo(true);
    o.position.y = f64::NAN;
    let e =
        encode_sample_ros1(RosType::Odometry, t, &SensorData::Odometry(Box::new(o))).unwrap_err();
    assert!(
        e.to_string().contains("Odometry.pose.pose.position.y"),
        "{e}"
    );
    // A flow sample without a rate cannot be a FlowTof.
    let flow = SensorData::Flow(OpticalFlow {
        rate: None,
        gyro: None,
        velocity: Some(Vector2::new(1.0, 2.0)),
        integration_s: None,
        quality: 1,
        status: None,
        tof: None,
    });
    assert!(encode_sample_cdr(RosType::FlowTof, t, &flow).is_err());
}

#[test]
fn ros1_stamps_after_2038_and_negative_ros2_stamps() {
    // ROS 1 time is unsigned: 2040 must come back as 2040, not 1904.
    let t = 2_208_988_800_000_001; // 2040-01-01T00:00:00.000001Z
    let data = SensorData::Odometry(Box::new(odo(false)));
    let b = encode_sample_ros1(RosType::PoseStamped, t, &data).unwrap();
    assert_eq!(
        decode_ros1(RosType::PoseStamped, &b).unwrap().stamp_us,
        Some(t)
    );
    // ROS 2 time is signed; before the epoch is representable.
    let b = encode_sample_cdr(RosType::PoseStamped, -1_500_000, &data).unwrap();
    let m = PoseStamped::from_cdr(&b).unwrap();
    assert_eq!(
        (m.header.stamp_sec, m.header.stamp_nanosec),
        (-2, 500_000_000)
    );
    assert_eq!(
        decode_cdr(RosType::PoseStamped, &b).unwrap().stamp_us,
        Some(-1_500_000)
    );
}

#[test]
fn zero_stamp_means_no_stamp() {
    let m = PoseStamped {
        header: Header::default(),
        pose: Pose::default(),
    };
    assert_eq!(
        decode_cdr(RosType::PoseStamped, &encode_cdr(&m))
            .unwrap()
            .stamp_us,
        None
    );
    assert_eq!(
        decode_ros1(RosType::PoseStamped, &encode_ros1(&m))
            .unwrap()
            .stamp_us,
        None
    );
}

// ------------------------------------------------------------ big-endian by hand

#[test]
fn big_endian_cdr_hand_built() {
    // skyfuse_msgs/FlowTof, CDR big-endian, every offset written out.
    let mut b = vec![0x00, 0x00, 0x00, 0x00]; // CDR_BE, options
    b.extend(1_700_000_001i32.to_be_bytes()); // 0: stamp.sec
    b.extend(250_000_000u32.to_be_bytes()); // 4: stamp.nanosec
    b.extend(5u32.to_be_bytes()); // 8: frame_id length incl. NUL
    b.extend(b"flow\0"); // 12..17
    b.extend([0, 0, 0]); // 17: pad to 20 for float32
    b.extend(1.5f32.to_be_bytes()); // 20: distance
    b.extend([7, 8, 9]); // 24: strength, precision, tof_status
    b.push(0); // 27: pad to 28
    b.extend((-0.25f32).to_be_bytes()); // 28: flow_vel_x
    b.extend(0.75f32.to_be_bytes()); // 32: flow_vel_y
    b.extend([128, 2]); // 36: flow_quality, flow_status
    let m = FlowTof::from_cdr(&b).unwrap();
    assert_eq!(
        m,
        FlowTof {
            header: Header {
                stamp_sec: 1_700_000_001,
                stamp_nanosec: 250_000_000,
                frame_id: "flow".into(),
                seq: 0
            },
            distance: 1.5,
            strength: 7,
            precision: 8,
            tof_status: 9,
            flow_vel_x: -0.25,
            flow_vel_y: 0.75,
            flow_quality: 128,
            flow_status: 2,
        }
    );
    assert_eq!(be_cdr(&m), b);
    let d = decode_cdr(RosType::FlowTof, &b).unwrap();
    assert_eq!(d.stamp_us, Some(1_700_000_001_250_000));
    let SensorData::Flow(fl) = d.data else {
        panic!()
    };
    assert_eq!(fl.rate, Some(Vector2::new(-0.25, 0.75)));
    assert_eq!(fl.tof.unwrap().distance_m, 1.5);

    // NavSatFix BE: 8-byte alignment counted from after the encapsulation header.
    let mut b = vec![0x00, 0x00, 0x00, 0x00];
    b.extend(10i32.to_be_bytes());
    b.extend(20u32.to_be_bytes());
    b.extend(2u32.to_be_bytes()); // frame_id "g"
    b.extend(b"g\0"); // ends at 14
    b.push(0xff); // 14: status -1
    b.push(0); // 15: pad for u16
    b.extend(1u16.to_be_bytes()); // 16: service
    b.extend([0; 6]); // 18: pad to 24
    for x in [10.0f64, 20.0, 30.0] {
        b.extend(x.to_be_bytes());
    }
    for i in 0..9 {
        b.extend((i as f64).to_be_bytes());
    }
    b.push(0); // covariance type unknown
    let m = NavSatFix::from_cdr(&b).unwrap();
    assert_eq!(m.status.status, -1);
    assert_eq!(m.status.service, 1);
    assert_eq!((m.latitude, m.longitude, m.altitude), (10.0, 20.0, 30.0));
    assert_eq!(m.position_covariance[8], 8.0);
    let SensorData::Gnss(g) = decode_cdr(RosType::NavSatFix, &b).unwrap().data else {
        panic!()
    };
    assert_eq!((g.fix, g.position_cov), (GnssFixType::NoFix, None));
}

// ------------------------------------------------------------ malformed input

fn all_payloads() -> Vec<(RosType, bool, Vec<u8>)> {
    let mut out = Vec::new();
    for v in vectors() {
        let ty = ty_of(&v);
        for key in ["cdr_le", "cdr_be"] {
            out.push((ty, false, unhex(v[key].as_str().unwrap())));
        }
        if let Some(r) = v["ros1"].as_str() {
            out.push((ty, true, unhex(r)));
        }
    }
    // The vectors always; the real bridge's captures when they are there.
    for line in golden("all_payloads (its real-bridge captures)").unwrap_or_default() {
        out.push((
            ty_of(&line),
            false,
            unhex(line["payload_hex"].as_str().unwrap()),
        ));
    }
    out
}

fn typed_decode<M: RosMessage>(ros1: bool, b: &[u8]) -> bool {
    if ros1 {
        M::from_ros1(b).is_ok()
    } else {
        M::from_cdr(b).is_ok()
    }
}

#[test]
fn truncated_payloads_are_errors_at_every_length() {
    for (ty, ros1, full) in all_payloads() {
        // A DDS writer pads the end to 4 bytes, and Jazzy's Range without its trailing
        // variance is a valid Humble Range: those prefixes may decode.
        let min_ok = match (ty, ros1) {
            (RosType::Range, _) => full.len().min(if ros1 { 43 } else { 44 }),
            _ => full.len() - full.iter().rev().take(3).take_while(|&&b| b == 0).count(),
        };
        for n in 0..full.len() {
            let b = &full[..n];
            let res = if ros1 {
                decode_ros1(ty, b)
            } else {
                decode_cdr(ty, b)
            };
            let typed = with_type!(ty, typed_decode(ros1, b));
            if n < min_ok {
                assert!(
                    !typed,
                    "{ty} ros1={ros1}: {n} of {} bytes decoded",
                    full.len()
                );
                assert!(res.is_err(), "{ty} ros1={ros1}: {n} bytes gave a sample");
            }
        }
    }
}

#[test]
fn truncation_error_says_where() {
    let e = decode_ros1(RosType::FlowTof, &[1, 0, 0, 0, 2, 0]).unwrap_err();
    assert_eq!(
        e,
        DecodeError::Truncated {
            needed: 4,
            offset: 4,
            len: 6
        }
    );
    assert!(matches!(
        decode_cdr(RosType::Imu, &[0, 1]),
        Err(DecodeError::Truncated { .. })
    ));
}

#[test]
fn bad_encapsulation_and_strings() {
    let mut good = encode_cdr(&PointStamped {
        header: header("abc"),
        point: Vector3::default(),
    });
    assert!(PointStamped::from_cdr(&good).is_ok());
    for rep in [[0x00, 0x03], [0x00, 0x07], [0x01, 0x01]] {
        let mut b = good.clone();
        b[..2].copy_from_slice(&rep);
        assert_eq!(
            PointStamped::from_cdr(&b),
            Err(DecodeError::BadEncapsulation(rep))
        );
    }
    // JSON sent to a ROS 2 input (issue 35, item 8): the error says what it looks like.
    let e = PointStamped::from_cdr(br#"{"x": 1.0, "y": 2.0, "z": 0.5}"#).unwrap_err();
    let said = e.to_string();
    assert!(
        said.contains("7b, 22") && said.contains("looks like JSON"),
        "{said}"
    );
    assert!(!DecodeError::BadEncapsulation([0, 3])
        .to_string()
        .contains("JSON"));
    // Encapsulation 0..4, stamp 4..12, length 12..16, "abc\0" 16..20: no NUL terminator.
    good[19] = b'd';
    assert_eq!(
        PointStamped::from_cdr(&good),
        Err(DecodeError::BadString {
            field: "PointStamped.header.frame_id".into()
        })
    );
    // Invalid UTF-8.
    good[19] = 0;
    good[17] = 0xff;
    assert!(matches!(
        PointStamped::from_cdr(&good),
        Err(DecodeError::BadString { .. })
    ));
    // A length far beyond the payload is refused before anything is allocated.
    let mut b = encode_cdr(&PointStamped::default());
    b[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(
        PointStamped::from_cdr(&b),
        Err(DecodeError::BadLength {
            field: "PointStamped.header.frame_id".into(),
            len: u32::MAX as usize
        })
    );
    let mut b = encode_ros1(&Odometry::default());
    // ROS 1: seq(4) stamp(8) frame_id len at 12, "" → child_frame_id len at 16.
    b[16..20].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
    assert!(matches!(
        Odometry::from_ros1(&b),
        Err(DecodeError::BadLength { field, .. }) if field == "Odometry.child_frame_id"
    ));
    // A zero-length CDR string (not valid CDR, but sent by some writers) reads as "".
    let mut b = vec![0, 1, 0, 0];
    b.extend([0u8; 8]);
    b.extend([0u8; 4]); // frame_id length 0
    b.extend([0u8; 4 + 24]); // pad to 8, point
    assert_eq!(PointStamped::from_cdr(&b).unwrap().header.frame_id, "");
}

// ------------------------------------------------------------ validation

fn vector_msg<M: RosMessage>() -> M {
    let v = vectors()
        .into_iter()
        .find(|v| v["type"] == M::TYPE.ros2_name() && v["store"] == "ros2_humble")
        .expect("vector");
    M::from_cdr(&unhex(v["cdr_le"].as_str().unwrap())).unwrap()
}

/// Decode `m` both ways and expect the same error from each.
fn decode_err<M: RosMessage>(m: &M) -> DecodeError {
    let a = decode_cdr(M::TYPE, &encode_cdr(m)).expect_err("CDR accepted it");
    let b = decode_ros1(M::TYPE, &encode_ros1(m)).expect_err("ROS 1 accepted it");
    // NaN != NaN, so compare the text.
    assert_eq!(a.to_string(), b.to_string());
    a
}

fn non_finite_field(e: &DecodeError) -> &str {
    match e {
        DecodeError::NonFinite { field, .. } => field,
        other => panic!("expected NonFinite, got {other}"),
    }
}

fn out_of_range(e: &DecodeError) -> (&str, &'static str) {
    match e {
        DecodeError::OutOfRange { field, reason, .. } => (field, reason),
        other => panic!("expected OutOfRange, got {other}"),
    }
}

#[test]
fn nan_fields_are_rejected_naming_the_field() {
    let mut m: NavSatFix = vector_msg();
    m.latitude = f64::NAN;
    assert_eq!(non_finite_field(&decode_err(&m)), "NavSatFix.latitude");
    let mut m: NavSatFix = vector_msg();
    m.altitude = f64::INFINITY;
    assert_eq!(non_finite_field(&decode_err(&m)), "NavSatFix.altitude");
    let mut m: NavSatFix = vector_msg();
    m.position_covariance[4] = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "NavSatFix.position_covariance[4]"
    );

    let mut m: Imu = vector_msg();
    m.angular_velocity.y = f64::NAN;
    assert_eq!(non_finite_field(&decode_err(&m)), "Imu.angular_velocity.y");
    let mut m: Imu = vector_msg();
    m.orientation.w = f64::NAN;
    assert_eq!(non_finite_field(&decode_err(&m)), "Imu.orientation.w");
    let mut m: Imu = vector_msg();
    m.linear_acceleration_covariance[8] = f64::NEG_INFINITY;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "Imu.linear_acceleration_covariance[8]"
    );

    let mut m: Odometry = vector_msg();
    m.pose.pose.position.x = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "Odometry.pose.pose.position.x"
    );
    let mut m: Odometry = vector_msg();
    m.twist.twist.angular.z = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "Odometry.twist.twist.angular.z"
    );
    let mut m: Odometry = vector_msg();
    m.twist.covariance[35] = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "Odometry.twist.covariance[35]"
    );

    let mut m: PoseStamped = vector_msg();
    m.pose.orientation.z = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "PoseStamped.pose.orientation.z"
    );
    let mut m: PoseWithCovarianceStamped = vector_msg();
    m.pose.pose.position.z = f64::NAN;
    assert_eq!(
        non_finite_field(&decode_err(&m)),
        "PoseWithCovarianceStamped.pose.pose.position.z"
    );

    let mut m: FlowTof = vector_msg();
    m.flow_vel_x = f32::NAN;
    assert_eq!(non_finite_field(&decode_err(&m)), "FlowTof.flow_vel_x");
    let mut m: FlowTof = vector_msg();
    m.flow_vel_y = f32::INFINITY;
    assert_eq!(non_finite_field(&decode_err(&m)), "FlowTof.flow_vel_y");

    let mut m: Range = vector_msg();
    m.range = f32::NAN;
    assert_eq!(non_finite_field(&decode_err(&m)), "Range.range");
}

#[test]
fn out_of_range_values() {
    let mut m: NavSatFix = vector_msg();
    m.latitude = 90.5;
    assert_eq!(out_of_range(&decode_err(&m)).0, "NavSatFix.latitude");
    let mut m: NavSatFix = vector_msg();
    m.longitude = -180.25;
    assert_eq!(out_of_range(&decode_err(&m)).0, "NavSatFix.longitude");
    let mut m: NavSatFix = vector_msg();
    m.status.status = 3;
    assert_eq!(out_of_range(&decode_err(&m)).0, "NavSatFix.status.status");

    // REP-117: ±Inf are "out of range" readings, said as such.
    let mut m: Range = vector_msg();
    m.range = f32::INFINITY;
    let e = decode_err(&m);
    let (field, reason) = out_of_range(&e);
    assert_eq!(field, "Range.range");
    assert!(reason.contains("max_range"), "{reason}");
    m.range = f32::NEG_INFINITY;
    let e = decode_err(&m);
    assert!(out_of_range(&e).1.contains("min_range"));
    m.range = -0.5;
    assert_eq!(out_of_range(&decode_err(&m)).0, "Range.range");

    // Quaternions: far from unit norm is not a rotation; near is normalised.
    let mut m: Odometry = vector_msg();
    m.pose.pose.orientation = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 2.5,
    };
    assert_eq!(
        out_of_range(&decode_err(&m)).0,
        "Odometry.pose.pose.orientation"
    );
    m.pose.pose.orientation.w = 0.0;
    assert!(out_of_range(&decode_err(&m)).1.contains("zero"));
    m.pose.pose.orientation.w = 1.2;
    let SensorData::Odometry(o) = decode_cdr(RosType::Odometry, &encode_cdr(&m)).unwrap().data
    else {
        panic!()
    };
    assert_eq!(o.orientation, UnitQuaternion::identity());

    let mut m: FlowTof = vector_msg();
    m.distance = -1.0;
    assert_eq!(out_of_range(&decode_err(&m)).0, "FlowTof.distance");
    m.distance = f32::INFINITY;
    assert_eq!(non_finite_field(&decode_err(&m)), "FlowTof.distance");
}

#[test]
fn ros_conventions_for_unknown_values() {
    let decode = |m: &Imu| match decode_cdr(RosType::Imu, &encode_cdr(m)).unwrap().data {
        SensorData::Imu(i) => i,
        _ => panic!(),
    };
    // Covariance element 0 = -1: that quantity is not provided.
    let mut m: Imu = vector_msg();
    m.orientation_covariance[0] = -1.0;
    m.angular_velocity_covariance[0] = -1.0;
    let i = decode(&m);
    assert_eq!(
        (i.orientation, i.orientation_cov, i.gyro, i.gyro_cov),
        (None, None, None, None)
    );
    assert!(i.accel.is_some() && i.accel_cov.is_some());
    m.linear_acceleration_covariance[0] = -1.0;
    assert_eq!(decode(&m).accel, None);
    // All-zero orientation: none. All-zero covariance: unknown.
    let mut m: Imu = vector_msg();
    m.orientation = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 0.0,
    };
    m.angular_velocity_covariance = [0.0; 9];
    let i = decode(&m);
    assert_eq!(
        (i.orientation, i.orientation_cov, i.gyro_cov),
        (None, None, None)
    );
    assert!(i.gyro.is_some());
    // Orientation with norm 3 is rejected, not silently normalised.
    let mut m: Imu = vector_msg();
    m.orientation.w = 3.0;
    assert_eq!(out_of_range(&decode_err(&m)).0, "Imu.orientation");

    // NavSatFix: status mapping and covariance type unknown.
    for (status, fix) in [
        (-1, GnssFixType::NoFix),
        (0, GnssFixType::Fix3d),
        (1, GnssFixType::Dgps),
        (2, GnssFixType::Dgps),
    ] {
        let mut m: NavSatFix = vector_msg();
        m.status.status = status;
        m.position_covariance_type = 0;
        let SensorData::Gnss(g) = decode_ros1(RosType::NavSatFix, &encode_ros1(&m))
            .unwrap()
            .data
        else {
            panic!()
        };
        assert_eq!((g.fix, g.position_cov), (fix, None));
    }

    // Range: unknown limits and Jazzy's "variance 0 = unknown".
    let mut m: Range = vector_msg();
    m.min_range = f32::NAN;
    m.max_range = f32::INFINITY;
    m.variance = Some(0.0);
    let SensorData::Range(r) = decode_cdr(RosType::Range, &encode_cdr(&m)).unwrap().data else {
        panic!()
    };
    assert_eq!((r.min_m, r.max_m, r.variance), (None, None, None));

    // FlowTof: NaN distance = no ToF reading; the flow still counts.
    let mut m: FlowTof = vector_msg();
    m.distance = f32::NAN;
    let SensorData::Flow(fl) = decode_cdr(RosType::FlowTof, &encode_cdr(&m)).unwrap().data else {
        panic!()
    };
    assert_eq!(fl.tof, None);
    assert_eq!(fl.rate, Some(Vector2::new(-0.21875, 0.4375)));

    // Odometry with a zero twist and no twist covariance: velocity not measured.
    let mut m: Odometry = vector_msg();
    m.twist = TwistWithCovariance::default();
    let SensorData::Odometry(o) = decode_cdr(RosType::Odometry, &encode_cdr(&m)).unwrap().data
    else {
        panic!()
    };
    assert_eq!(
        (o.velocity, o.angular_velocity, o.twist_cov),
        (None, None, None)
    );
    assert!(o.pose_cov.is_some());
}

#[test]
fn point_stamped_is_output_only() {
    let b = encode_cdr(&PointStamped::default());
    assert!(matches!(
        decode_cdr(RosType::PointStamped, &b),
        Err(DecodeError::UnsupportedMessage(_))
    ));
    assert!(matches!(
        decode_ros1(
            RosType::PointStamped,
            &encode_ros1(&PointStamped::default())
        ),
        Err(DecodeError::UnsupportedMessage(_))
    ));
}

// ------------------------------------------------------------ fuzz

fn decode_all(bytes: &[u8]) {
    for ty in RosType::ALL {
        let _ = decode_cdr(ty, bytes);
        let _ = decode_ros1(ty, bytes);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..800)) {
        decode_all(&bytes);
    }

    #[test]
    fn arbitrary_bytes_after_a_valid_header_never_panic(
        le in any::<bool>(),
        body in proptest::collection::vec(any::<u8>(), 0..800),
    ) {
        let mut b = vec![0, u8::from(le), 0, 0];
        b.extend(body);
        decode_all(&b);
    }

    #[test]
    fn mutated_real_payloads_never_panic(
        pick in any::<proptest::sample::Index>(),
        edits in proptest::collection::vec((any::<proptest::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<proptest::sample::Index>(),
    ) {
        let all = all_payloads();
        let (_, _, mut b) = all[pick.index(all.len())].clone();
        for (at, byte) in edits {
            let i = at.index(b.len());
            b[i] = byte;
        }
        let n = cut.index(b.len() + 1);
        decode_all(&b[..n]);
        decode_all(&b);
    }
}
