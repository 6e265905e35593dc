//! px4_msgs against bytes made by real tooling from PX4's own definitions
//! (tests/data/px4_vectors.json from tests/py/gen_px4_vectors.py: rosbags and
//! CycloneDDS, PX4 v1.14.0, v1.15.0, v1.16.0).

use super::px4::*;
use crate::codec::DecodeError;
use crate::sample::{LandedState, SensorData};
use serde_json::Value;

const VECTORS: &str = include_str!("../../../../../tests/data/px4_vectors.json");

struct Vector {
    ty: Px4Type,
    version: Px4Version,
    order: Vec<String>,
    fields: serde_json::Map<String, Value>,
    xcdr1: Vec<u8>,
    px4_zenoh: Option<Vec<u8>>,
    rihs01: String,
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

fn vectors() -> Vec<Vector> {
    let doc: Value = serde_json::from_str(VECTORS).expect("px4_vectors.json");
    doc["vectors"]
        .as_array()
        .expect("vectors")
        .iter()
        .map(|v| Vector {
            ty: Px4Type::from_name(v["type"].as_str().unwrap()).expect("known type"),
            version: match v["version"].as_str().unwrap() {
                "1.14" => Px4Version::V1_14,
                "1.15" => Px4Version::V1_15,
                "1.16" => Px4Version::V1_16,
                other => panic!("version {other}"),
            },
            order: v["order"]
                .as_array()
                .unwrap()
                .iter()
                .map(|n| n.as_str().unwrap().to_string())
                .collect(),
            fields: v["fields"].as_object().unwrap().clone(),
            xcdr1: hex(v["xcdr1"].as_str().unwrap()),
            px4_zenoh: v["px4_zenoh_1_16"].as_str().map(hex),
            rihs01: v["rihs01"].as_str().unwrap().to_string(),
        })
        .collect()
}

/// The vector's values flattened in header order (arrays element by element).
fn expected(v: &Vector) -> Vec<f64> {
    let num = |x: &Value| match x {
        Value::String(s) if s == "NaN" => f64::NAN,
        x => x.as_f64().unwrap(),
    };
    v.order
        .iter()
        .flat_map(|name| match &v.fields[name] {
            Value::Array(a) => a.iter().map(num).collect::<Vec<_>>(),
            x => vec![num(x)],
        })
        .collect()
}

/// Equal as the wire holds them: f32 fields compared as f32, NaN equal to NaN.
fn same(a: f64, b: f64) -> bool {
    (a.is_nan() && b.is_nan()) || a == b || (a as f32) == (b as f32)
}

fn assert_values(v: &Vector, got: &[f64], how: &str) {
    let want = expected(v);
    let names = header(fields(v.ty, v.version));
    assert_eq!(
        got.len(),
        want.len(),
        "{:?} {:?} {how}: count",
        v.ty,
        v.version
    );
    for ((g, w), n) in got.iter().zip(&want).zip(&names) {
        assert!(
            same(*g, *w),
            "{:?} {:?} {how}: {n} = {g}, want {w}",
            v.ty,
            v.version
        );
    }
}

#[test]
fn there_is_a_vector_for_every_type_and_release() {
    let vs = vectors();
    assert_eq!(vs.len(), Px4Type::ALL.len() * Px4Version::ALL.len());
}

#[test]
fn the_field_tables_are_the_definitions_of_each_release() {
    for v in vectors() {
        let names: Vec<&str> = fields(v.ty, v.version).iter().map(|f| f.name).collect();
        assert_eq!(names, v.order, "{:?} {:?}", v.ty, v.version);
        // The `.msg` text we write for recordings lists the same fields.
        let def = definition(v.ty, v.version);
        assert_eq!(def.lines().count(), v.order.len());
    }
}

#[test]
fn every_xcdr1_vector_decodes_with_its_layout_found_from_the_payload() {
    for v in vectors() {
        let (version, got) = read_values(Px4Msg::new(v.ty), &v.xcdr1).expect("decodes");
        // Types whose layout never changed read the same by any list.
        if fields(v.ty, version).len() != fields(v.ty, v.version).len()
            || !std::ptr::eq(fields(v.ty, version), fields(v.ty, v.version))
        {
            panic!("{:?}: {:?} found, vector is {:?}", v.ty, version, v.version);
        }
        assert_values(&v, &got, "xcdr1");
        // DDS writers pad the end to a multiple of 4: still the same message.
        let mut padded = v.xcdr1.clone();
        padded.resize(4 + (v.xcdr1.len() - 4).div_ceil(4) * 4, 0);
        let (pv, got) = read_values(Px4Msg::new(v.ty), &padded).expect("padded decodes");
        if v.ty == Px4Type::DistanceSensor && v.version != Px4Version::V1_16 {
            // 1.16 only appended `mode`: 1.14's padding reads as mode 0 (unknown), and
            // every field before it is the same.
            assert_eq!(pv, Px4Version::V1_16);
            assert_values(&v, &got[..got.len() - 1], "padded");
            continue;
        }
        assert!(
            std::ptr::eq(fields(v.ty, pv), fields(v.ty, v.version)),
            "{:?} padded",
            v.ty
        );
        assert_values(&v, &got, "padded");
    }
}

#[test]
fn the_type_hash_names_the_layout() {
    for v in vectors() {
        assert_eq!(
            type_hash(v.ty, v.version),
            v.rihs01,
            "{:?} {:?}",
            v.ty,
            v.version
        );
        let named = version_of_hash(v.ty, &v.rihs01)
            .expect("known")
            .expect("a release");
        assert!(std::ptr::eq(fields(v.ty, named), fields(v.ty, v.version)));
        let m = Px4Msg {
            ty: v.ty,
            version: Some(named),
            xcdr2: false,
        };
        assert_values(&v, &read_values(m, &v.xcdr1).expect("decodes").1, "by hash");
    }
    // No hash (Humble's rmw_zenoh): found from the payload.
    assert_eq!(
        version_of_hash(Px4Type::SensorGps, "TypeHashNotSupported"),
        Ok(None)
    );
    // A hash of no known release (PX4 1.17's SensorGps moved its fields): refused.
    let later = "RIHS01_0b0f92e680bbcad0c9d0e651868c0443b9d38fb8d50c21d4a8a532d3e90cf21a";
    let e = version_of_hash(Px4Type::SensorGps, later).unwrap_err();
    assert!(e.to_string().contains("not the layout of PX4 1.14"), "{e}");
}

#[test]
fn px4_1_16_zenoh_payloads_decode_with_xcdr2_alignment_and_their_tail() {
    let mut seen = 0;
    for v in vectors() {
        let Some(p) = &v.px4_zenoh else { continue };
        seen += 1;
        let (_, got) = read_values(Px4Msg::px4_zenoh(v.ty), p).expect("decodes");
        assert_values(&v, &got, "px4 zenoh");
    }
    assert_eq!(seen, Px4Type::ALL.len());
    // Where XCDR1 and XCDR2 differ (an 8-byte value after a 4-byte one), reading one
    // as the other gives other numbers: the transport must be said.
    let gps = vectors()
        .into_iter()
        .find(|v| v.ty == Px4Type::SensorGps && v.version == Px4Version::V1_16)
        .unwrap();
    let (_, wrong) = read_values(
        Px4Msg {
            ty: Px4Type::SensorGps,
            version: Some(Px4Version::V1_16),
            xcdr2: true,
        },
        &gps.xcdr1,
    )
    .unwrap();
    assert!(!same(wrong[3], 47.397742), "latitude read {}", wrong[3]);
}

fn decode_vector(ty: Px4Type, version: Px4Version) -> SensorData {
    let v = vectors()
        .into_iter()
        .find(|v| v.ty == ty && v.version == version)
        .unwrap();
    let d = decode(Px4Msg::new(ty), &v.xcdr1)
        .unwrap_or_else(|e| panic!("{ty:?} {version:?}: {e}"))
        .expect("a sample");
    assert_eq!(
        d.stamp_us,
        Some(120_500_000),
        "{ty:?}: the message's timestamp"
    );
    d.data
}

#[test]
fn samples_come_out_in_enu_flu_and_si_units_in_every_release() {
    for version in Px4Version::ALL {
        let SensorData::Imu(imu) = decode_vector(Px4Type::SensorCombined, version) else {
            panic!("imu")
        };
        let (g, a) = (imu.gyro.unwrap(), imu.accel.unwrap());
        assert!(
            (g - nalgebra::Vector3::new(0.01, 0.02, -0.03)).norm() < 1e-6,
            "{g}"
        );
        assert!(
            (a - nalgebra::Vector3::new(0.1, 0.2, 9.81)).norm() < 1e-5,
            "{a}"
        );

        let SensorData::Gnss(fix) = decode_vector(Px4Type::SensorGps, version) else {
            panic!("gnss")
        };
        assert!((fix.lat_deg - 47.397742).abs() < 1e-7 && (fix.lon_deg - 8.545594).abs() < 1e-7);
        assert!((fix.alt_m - 490.0).abs() < 1e-3, "{}", fix.alt_m);
        let vel = fix.velocity.unwrap();
        assert!(
            (vel - nalgebra::Vector3::new(0.25, 0.5, 0.125)).norm() < 1e-6,
            "{vel}"
        );
        assert_eq!(fix.satellites, Some(12));

        // 1.15 and 1.16 have the same length and other fields at byte 24.
        let SensorData::Baro(b) = decode_vector(Px4Type::VehicleAirData, version) else {
            panic!("baro")
        };
        assert_eq!(b.pressure_pa, 95578.0, "{version:?}");
        assert_eq!(b.temperature_c, Some(21.5), "{version:?}");

        let SensorData::Range(r) = decode_vector(Px4Type::DistanceSensor, version) else {
            panic!("range")
        };
        assert!((r.distance_m - 2.05).abs() < 1e-6 && r.orientation == Some(25));
        assert_eq!(r.signal_quality, Some(90));

        let SensorData::Odometry(o) = decode_vector(Px4Type::VehicleOdometry, version) else {
            panic!("odometry")
        };
        // NED (1.5, -2.25, -2) → ENU (-2.25, 1.5, 2); yaw 30° from north → 60° from east.
        assert!((o.position - nalgebra::Vector3::new(-2.25, 1.5, 2.0)).norm() < 1e-6);
        let yaw = crate::estimator::attitude::yaw_of(&o.orientation);
        assert!((yaw - 60f64.to_radians()).abs() < 1e-5, "{yaw}");
        assert_eq!((o.reset_counter, o.quality), (Some(3), Some(80)));
        let pc = o.pose_cov.unwrap();
        assert!((pc[(0, 0)] - 0.01).abs() < 1e-7 && (pc[(2, 2)] - 0.04).abs() < 1e-7);

        let SensorData::Flow(fl) = decode_vector(Px4Type::VehicleOpticalFlow, version) else {
            panic!("flow")
        };
        assert!((fl.rate.unwrap().x - 0.1).abs() < 1e-6, "{:?}", fl.rate);
        assert!(fl.tof.is_some());
        // SensorOpticalFlow says its distance is not there: no ToF, though the field
        // holds a number.
        let SensorData::Flow(fl) = decode_vector(Px4Type::SensorOpticalFlow, version) else {
            panic!("flow")
        };
        assert!(fl.tof.is_none() && fl.gyro.is_some());

        let SensorData::VehicleState(s) = decode_vector(Px4Type::VehicleStatus, version) else {
            panic!("status")
        };
        assert_eq!(s.armed, Some(true));
        let SensorData::VehicleState(s) = decode_vector(Px4Type::VehicleLandDetected, version)
        else {
            panic!("land")
        };
        assert_eq!(s.landed, Some(LandedState::InAir));
        assert!(matches!(
            decode_vector(Px4Type::VehicleAttitude, version),
            SensorData::Attitude(_)
        ));
        assert!(matches!(
            decode_vector(Px4Type::VehicleAngularVelocity, version),
            SensorData::Imu(_)
        ));
    }
}

#[test]
fn timesync_status_gives_the_offset_and_no_sample() {
    for v in vectors()
        .into_iter()
        .filter(|v| v.ty == Px4Type::TimesyncStatus)
    {
        assert_eq!(decode(Px4Msg::new(v.ty), &v.xcdr1), Ok(None));
        let t = decode_timesync_status(&v.xcdr1, false).unwrap();
        assert_eq!(t.estimated_offset_us, -1_789_999_879_500_000);
        assert_eq!((t.source_protocol, t.round_trip_us), (2, 850));
        if let Some(p) = &v.px4_zenoh {
            assert_eq!(decode_timesync_status(p, true).unwrap(), t);
        }
    }
}

#[test]
fn vehicle_odometry_writes_what_rosbags_writes() {
    for v in vectors()
        .into_iter()
        .filter(|v| v.ty == Px4Type::VehicleOdometry)
    {
        let m = VehicleOdometry::from_cdr(&v.xcdr1).unwrap();
        assert_eq!(m.to_cdr(), v.xcdr1, "{:?}", v.version);
        assert_eq!(m.reset_counter, 3);
        assert_eq!(m.check(), Ok(()));
    }
}

#[test]
fn vehicle_odometry_check_refuses_what_the_interface_library_refuses() {
    let good = VehicleOdometry::from_cdr(&vectors()[3].xcdr1).unwrap();
    assert_eq!(good.check(), Ok(()));
    let nan = f32::NAN;
    type Change = Box<dyn Fn(&mut VehicleOdometry)>;
    let cases: Vec<(&str, Change)> = vec![
        (
            "all empty",
            Box::new(move |m| {
                m.position = [nan; 3];
                m.velocity = [nan; 3];
                m.q = [nan; 4];
            }),
        ),
        ("variance", Box::new(|m| m.position_variance[2] = 0.0)),
        ("variance", Box::new(move |m| m.velocity_variance[0] = nan)),
        ("pose_frame", Box::new(|m| m.pose_frame = 0)),
        ("velocity_frame", Box::new(|m| m.velocity_frame = 7)),
        ("partly NaN", Box::new(move |m| m.position[1] = nan)),
        ("not finite", Box::new(|m| m.velocity[1] = f32::INFINITY)),
        ("timestamp_sample", Box::new(|m| m.timestamp_sample = 0)),
        ("unit", Box::new(|m| m.q = [0.9, 0.0, 0.0, 0.1])),
    ];
    for (want, change) in cases {
        let mut m = good.clone();
        change(&mut m);
        let e = m.check().unwrap_err();
        assert!(e.contains(want), "{want}: {e}");
    }
    // Unset parts need no variance: a position-only message passes.
    let mut m = good.clone();
    m.velocity = [nan; 3];
    m.velocity_variance = [nan; 3];
    m.q = [nan; 4];
    m.orientation_variance = [nan; 3];
    assert_eq!(m.check(), Ok(()));
}

/// PX4 SIH's range finder on the ground reads -0.00015 m (a height computed, rounded):
/// that is 0, not a bad message; a distance well below 0 still is one.
#[test]
fn a_distance_rounded_below_zero_on_the_ground_is_zero() {
    let v = vectors()
        .into_iter()
        .find(|v| v.ty == Px4Type::DistanceSensor && v.version == Px4Version::V1_16)
        .unwrap();
    // current_distance is the float at body offset 20.
    let with = |d: f32| {
        let mut b = v.xcdr1.clone();
        b[24..28].copy_from_slice(&d.to_le_bytes());
        decode(Px4Msg::new(Px4Type::DistanceSensor), &b)
    };
    let Ok(Some(d)) = with(-0.000_152_587_89) else {
        panic!("refused")
    };
    let SensorData::Range(r) = d.data else {
        panic!("range")
    };
    assert_eq!(r.distance_m, 0.0);
    let e = with(-0.5).unwrap_err();
    assert!(e.to_string().contains("negative distance"), "{e}");
}

#[test]
fn bad_payloads_are_errors_never_panics() {
    for v in vectors() {
        for cut in [0, 3, 4, 10, v.xcdr1.len() - 1] {
            if cut + 3 >= v.xcdr1.len() {
                continue;
            }
            let r = decode(Px4Msg::new(v.ty), &v.xcdr1[..cut]);
            assert!(r.is_err(), "{:?} cut at {cut}", v.ty);
        }
        // Longer than any known layout (a later release read by an older list).
        let mut long = v.xcdr1.clone();
        long.resize(4 + (v.xcdr1.len() - 4).div_ceil(4) * 4 + 8, 0);
        if v.ty != Px4Type::SensorGps && v.ty != Px4Type::VehicleStatus {
            assert!(
                matches!(
                    read_values(Px4Msg::new(v.ty), &long),
                    Err(DecodeError::TrailingBytes { .. })
                ),
                "{:?} {:?}",
                v.ty,
                v.version
            );
        }
    }
    // A NaN position in odometry is refused with the field named.
    let v = vectors()
        .into_iter()
        .find(|v| v.ty == Px4Type::VehicleOdometry)
        .unwrap();
    let mut m = VehicleOdometry::from_cdr(&v.xcdr1).unwrap();
    m.position[0] = f32::NAN;
    let e = decode(Px4Msg::new(Px4Type::VehicleOdometry), &m.to_cdr()).unwrap_err();
    assert!(e.to_string().contains("position"), "{e}");
}
