//! skyfuse's own JSON form, for hand-written publishers (schema in the README, "JSON
//! input"). Units are SI, world ENU, body FLU, quaternions `[x, y, z, w]`, time µs.
//! Unknown fields are rejected by name so a typo is an error, not a silent default.

use super::error::{finite, in_range, DecodeError, EncodeError};
use crate::sample::*;
use nalgebra::{Matrix3, Matrix6, Quaternion, UnitQuaternion, Vector2, Vector3};
use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
enum JsonSample {
    Imu {
        stamp_us: Option<i64>,
        gyro: Option<[f64; 3]>,
        accel: Option<[f64; 3]>,
        orientation: Option<[f64; 4]>,
    },
    Attitude {
        stamp_us: Option<i64>,
        /// `[x, y, z, w]`, body FLU → world ENU.
        orientation: [f64; 4],
        rates: Option<[f64; 3]>,
    },
    Gnss {
        stamp_us: Option<i64>,
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
        #[serde(default = "default_fix")]
        fix: String,
        /// Row-major 3×3 ENU covariance, m².
        position_cov: Option<[f64; 9]>,
        satellites: Option<u8>,
        hdop: Option<f64>,
    },
    Flow {
        stamp_us: Option<i64>,
        rate: Option<[f64; 2]>,
        gyro: Option<[f64; 3]>,
        velocity: Option<[f64; 2]>,
        integration_s: Option<f64>,
        quality: u8,
        tof_m: Option<f64>,
    },
    Range {
        stamp_us: Option<i64>,
        distance_m: f64,
        min_m: Option<f64>,
        max_m: Option<f64>,
        variance: Option<f64>,
    },
    Odometry {
        stamp_us: Option<i64>,
        position: [f64; 3],
        orientation: [f64; 4],
        velocity: Option<[f64; 3]>,
        /// Row-major 6×6 pose covariance.
        pose_cov: Option<Vec<f64>>,
        #[serde(default)]
        frame_id: String,
    },
    /// A barometer: static pressure in Pa (not hPa).
    Baro {
        stamp_us: Option<i64>,
        pressure_pa: f64,
        temperature_c: Option<f64>,
        variance: Option<f64>,
    },
    /// The autopilot's view of the vehicle; either field may be left out.
    VehicleState {
        stamp_us: Option<i64>,
        armed: Option<bool>,
        /// `on_ground`, `in_air`, `takeoff` or `landing`.
        landed: Option<LandedState>,
    },
}

fn default_fix() -> String {
    "fix3d".into()
}

fn vec3(field: &str, v: [f64; 3]) -> Result<Vector3<f64>, DecodeError> {
    for (i, x) in v.iter().enumerate() {
        finite(&format!("{field}[{i}]"), *x)?;
    }
    Ok(Vector3::from(v))
}

fn quat(field: &str, q: [f64; 4]) -> Result<UnitQuaternion<f64>, DecodeError> {
    for (i, x) in q.iter().enumerate() {
        finite(&format!("{field}[{i}]"), *x)?;
    }
    let q = Quaternion::new(q[3], q[0], q[1], q[2]);
    in_range(field, q.norm(), 0.5, 2.0, "quaternion norm must be near 1")?;
    Ok(UnitQuaternion::from_quaternion(q))
}

/// Decode one JSON sample.
pub fn decode(payload: &[u8]) -> Result<Decoded, DecodeError> {
    let s: JsonSample =
        serde_json::from_slice(payload).map_err(|e| DecodeError::Json(e.to_string()))?;
    let (stamp_us, data) = match s {
        JsonSample::Baro {
            stamp_us,
            pressure_pa,
            temperature_c,
            variance,
        } => {
            finite("pressure_pa", pressure_pa)?;
            in_range(
                "pressure_pa",
                pressure_pa,
                crate::sample::BARO_MIN_PA,
                crate::sample::BARO_MAX_PA,
                "an air pressure in Pa (hPa times 100)",
            )?;
            (
                stamp_us,
                SensorData::Baro(crate::sample::Baro {
                    pressure_pa,
                    temperature_c: temperature_c.filter(|t| t.is_finite()),
                    variance: variance.filter(|v| v.is_finite() && *v > 0.0),
                }),
            )
        }
        JsonSample::VehicleState {
            stamp_us,
            armed,
            landed,
        } => (
            stamp_us,
            SensorData::VehicleState(VehicleState { armed, landed }),
        ),
        JsonSample::Imu {
            stamp_us,
            gyro,
            accel,
            orientation,
        } => (
            stamp_us,
            SensorData::Imu(Imu {
                gyro: gyro.map(|g| vec3("imu.gyro", g)).transpose()?,
                accel: accel.map(|a| vec3("imu.accel", a)).transpose()?,
                orientation: orientation
                    .map(|q| quat("imu.orientation", q))
                    .transpose()?,
                gyro_cov: None,
                accel_cov: None,
                orientation_cov: None,
            }),
        ),
        JsonSample::Attitude {
            stamp_us,
            orientation,
            rates,
        } => (
            stamp_us,
            SensorData::Attitude(Attitude {
                orientation: quat("attitude.orientation", orientation)?,
                rates: rates.map(|r| vec3("attitude.rates", r)).transpose()?,
            }),
        ),
        JsonSample::Gnss {
            stamp_us,
            lat_deg,
            lon_deg,
            alt_m,
            fix,
            position_cov,
            satellites,
            hdop,
        } => {
            let fix = match fix.as_str() {
                "no_fix" => GnssFixType::NoFix,
                "fix2d" => GnssFixType::Fix2d,
                "fix3d" => GnssFixType::Fix3d,
                "dgps" => GnssFixType::Dgps,
                "rtk_float" => GnssFixType::RtkFloat,
                "rtk_fixed" => GnssFixType::RtkFixed,
                other => {
                    return Err(DecodeError::Json(format!(
                        "gnss.fix: unknown fix type {other:?} (no_fix, fix2d, fix3d, dgps, rtk_float, rtk_fixed)"
                    )))
                }
            };
            let cov = match position_cov {
                Some(c) => {
                    for (i, x) in c.iter().enumerate() {
                        finite(&format!("gnss.position_cov[{i}]"), *x)?;
                    }
                    Some(Matrix3::from_row_slice(&c))
                }
                None => None,
            };
            (
                stamp_us,
                SensorData::Gnss(GnssFix {
                    lat_deg: in_range("gnss.lat_deg", lat_deg, -90.0, 90.0, "latitude")?,
                    lon_deg: in_range("gnss.lon_deg", lon_deg, -180.0, 180.0, "longitude")?,
                    alt_m: in_range("gnss.alt_m", alt_m, -1000.0, 100_000.0, "altitude")?,
                    fix,
                    position_cov: cov.map(Box::new),
                    satellites,
                    hdop: hdop.map(|h| finite("gnss.hdop", h)).transpose()?,
                    vdop: None,
                    velocity: None,
                    velocity_up_known: false,
                }),
            )
        }
        JsonSample::Flow {
            stamp_us,
            rate,
            gyro,
            velocity,
            integration_s,
            quality,
            tof_m,
        } => (
            stamp_us,
            SensorData::Flow(OpticalFlow {
                rate: rate
                    .map(|r| vec3("flow.rate", [r[0], r[1], 0.0]).map(|v| v.xy()))
                    .transpose()?,
                gyro: gyro.map(|g| vec3("flow.gyro", g)).transpose()?,
                velocity: velocity
                    .map(|v| {
                        vec3("flow.velocity", [v[0], v[1], 0.0]).map(|v| Vector2::new(v.x, v.y))
                    })
                    .transpose()?,
                integration_s: integration_s
                    .map(|t| in_range("flow.integration_s", t, 0.0, 10.0, "seconds"))
                    .transpose()?,
                quality,
                status: None,
                tof: tof_m
                    .map(|d| {
                        in_range("flow.tof_m", d, 0.0, 1000.0, "metres").map(|d| Tof {
                            distance_m: d,
                            strength: None,
                            precision: None,
                            status: None,
                        })
                    })
                    .transpose()?,
            }),
        ),
        JsonSample::Range {
            stamp_us,
            distance_m,
            min_m,
            max_m,
            variance,
        } => (
            stamp_us,
            SensorData::Range(Range {
                distance_m: in_range("range.distance_m", distance_m, 0.0, 1000.0, "metres")?,
                min_m: min_m.map(|m| finite("range.min_m", m)).transpose()?,
                max_m: max_m.map(|m| finite("range.max_m", m)).transpose()?,
                signal_quality: None,
                variance: variance.map(|v| finite("range.variance", v)).transpose()?,
                orientation: None,
            }),
        ),
        JsonSample::Odometry {
            stamp_us,
            position,
            orientation,
            velocity,
            pose_cov,
            frame_id,
        } => {
            let pose_cov = match pose_cov {
                Some(c) if c.len() == 36 => {
                    for (i, x) in c.iter().enumerate() {
                        finite(&format!("odometry.pose_cov[{i}]"), *x)?;
                    }
                    Some(Matrix6::from_row_slice(&c))
                }
                Some(c) => {
                    return Err(DecodeError::BadLength {
                        field: "odometry.pose_cov (needs 36 values)".into(),
                        len: c.len(),
                    })
                }
                None => None,
            };
            (
                stamp_us,
                SensorData::Odometry(Box::new(Odometry {
                    position: vec3("odometry.position", position)?,
                    orientation: quat("odometry.orientation", orientation)?,
                    velocity: velocity.map(|v| vec3("odometry.velocity", v)).transpose()?,
                    angular_velocity: None,
                    pose_cov,
                    twist_cov: None,
                    frame_id,
                    child_frame_id: String::new(),
                    reset_counter: None,
                    quality: None,
                })),
            )
        }
    };
    if let Some(t) = stamp_us {
        in_range("stamp_us", t as f64, 0.0, 1e17, "must be µs, non-negative")?;
    }
    Ok(Decoded {
        stamp_us,
        mav_origin: None,
        data,
    })
}

/// Encode a sample in skyfuse JSON (the inverse of [`decode`]).
pub fn encode(stamp_us: i64, data: &SensorData) -> Result<String, EncodeError> {
    use serde_json::json;
    let q = |q: &UnitQuaternion<f64>| [q.i, q.j, q.k, q.w];
    let v = match data {
        SensorData::Imu(i) => json!({
            "kind": "imu", "stamp_us": stamp_us,
            "gyro": i.gyro.map(|g| [g.x, g.y, g.z]),
            "accel": i.accel.map(|a| [a.x, a.y, a.z]),
            "orientation": i.orientation.as_ref().map(q),
        }),
        SensorData::Attitude(a) => json!({
            "kind": "attitude", "stamp_us": stamp_us,
            "orientation": q(&a.orientation),
            "rates": a.rates.map(|r| [r.x, r.y, r.z]),
        }),
        SensorData::Gnss(g) => json!({
            "kind": "gnss", "stamp_us": stamp_us,
            "lat_deg": g.lat_deg, "lon_deg": g.lon_deg, "alt_m": g.alt_m,
            "fix": serde_json::to_value(g.fix).unwrap_or(serde_json::Value::Null),
            "position_cov": g.position_cov.as_ref().map(|c| c.transpose().as_slice().to_vec()),
            "satellites": g.satellites, "hdop": g.hdop,
        }),
        SensorData::Flow(f) => json!({
            "kind": "flow", "stamp_us": stamp_us,
            "rate": f.rate.map(|r| [r.x, r.y]),
            "gyro": f.gyro.map(|g| [g.x, g.y, g.z]),
            "velocity": f.velocity.map(|v| [v.x, v.y]),
            "integration_s": f.integration_s,
            "quality": f.quality,
            "tof_m": f.tof.as_ref().map(|t| t.distance_m),
        }),
        SensorData::Range(r) => json!({
            "kind": "range", "stamp_us": stamp_us,
            "distance_m": r.distance_m, "min_m": r.min_m, "max_m": r.max_m, "variance": r.variance,
        }),
        SensorData::Odometry(o) => json!({
            "kind": "odometry", "stamp_us": stamp_us,
            "position": [o.position.x, o.position.y, o.position.z],
            "orientation": q(&o.orientation),
            "velocity": o.velocity.map(|v| [v.x, v.y, v.z]),
            "pose_cov": o.pose_cov.map(|c| c.transpose().as_slice().to_vec()),
            "frame_id": o.frame_id,
        }),
        SensorData::VehicleState(v) => json!({
            "kind": "vehicle_state", "stamp_us": stamp_us,
            "armed": v.armed, "landed": v.landed,
        }),
        SensorData::Baro(b) => json!({
            "kind": "baro", "stamp_us": stamp_us,
            "pressure_pa": b.pressure_pa, "temperature_c": b.temperature_c, "variance": b.variance,
        }),
        SensorData::AutopilotEstimate(_) => {
            return Err(EncodeError::Unsupported(
                "the autopilot's estimate has no skyfuse JSON form".into(),
            ))
        }
    };
    // serde_json writes NaN as null, which would silently change the meaning: refuse.
    let mut bad = None;
    find_non_finite(&v, "", &mut bad);
    if let Some(field) = bad {
        return Err(EncodeError::NonFinite {
            field,
            value: f64::NAN,
        });
    }
    // Optional fields that are absent are left out rather than written as null.
    let v = match v {
        serde_json::Value::Object(m) => {
            serde_json::Value::Object(m.into_iter().filter(|(_, v)| !v.is_null()).collect())
        }
        other => other,
    };
    Ok(v.to_string())
}

fn find_non_finite(v: &serde_json::Value, path: &str, bad: &mut Option<String>) {
    match v {
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                if x.is_null() {
                    *bad = Some(format!("{path}[{i}]"));
                }
                find_non_finite(x, &format!("{path}[{i}]"), bad);
            }
        }
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                find_non_finite(x, k, bad);
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_every_kind() {
        let cases = [
            r#"{"kind":"imu","stamp_us":5,"gyro":[0.1,0,0],"accel":[0,0,9.81],"orientation":[0,0,0,1]}"#,
            r#"{"kind":"attitude","orientation":[0,0,0.7071068,0.7071068],"rates":[0,0,0.1]}"#,
            r#"{"kind":"gnss","lat_deg":47.4,"lon_deg":8.5,"alt_m":488,"position_cov":[1,0,0,0,1,0,0,0,4],"satellites":12}"#,
            r#"{"kind":"flow","rate":[0.1,-0.2],"quality":200,"tof_m":1.5}"#,
            r#"{"kind":"range","distance_m":2.5,"min_m":0.1,"max_m":8}"#,
            r#"{"kind":"odometry","position":[1,2,3],"orientation":[0,0,0,1],"velocity":[0.5,0,0]}"#,
        ];
        let kinds = [
            SensorKind::Imu,
            SensorKind::Attitude,
            SensorKind::Gnss,
            SensorKind::Flow,
            SensorKind::Range,
            SensorKind::Odometry,
        ];
        for (c, k) in cases.iter().zip(kinds) {
            let d = decode(c.as_bytes()).unwrap_or_else(|e| panic!("{c}: {e}"));
            assert_eq!(d.data.kind(), k);
        }
        let d = decode(cases[2].as_bytes()).expect("gnss");
        let SensorData::Gnss(g) = d.data else {
            panic!("not gnss")
        };
        assert_eq!((g.lat_deg, g.satellites), (47.4, Some(12)));
        assert_eq!(g.position_cov.map(|c| c[(2, 2)]), Some(4.0));
    }

    #[test]
    fn encode_round_trips_and_refuses_nan() {
        let cases = [
            r#"{"kind":"imu","stamp_us":5,"gyro":[0.1,0,0],"accel":[0,0,9.81],"orientation":[0,0,0,1]}"#,
            r#"{"kind":"gnss","lat_deg":47.4,"lon_deg":8.5,"alt_m":488,"position_cov":[1,0.5,0,0.5,2,0,0,0,4],"satellites":12}"#,
            r#"{"kind":"flow","rate":[0.1,-0.2],"quality":200,"tof_m":1.5}"#,
            r#"{"kind":"odometry","position":[1,2,3],"orientation":[0,0,0,1],"velocity":[0.5,0,0]}"#,
        ];
        for c in cases {
            let d = decode(c.as_bytes()).expect("decode");
            let text = encode(d.stamp_us.unwrap_or(0), &d.data).expect("encode");
            let again = decode(text.as_bytes()).unwrap_or_else(|e| panic!("{text}: {e}"));
            assert_eq!(again.data, d.data, "{text}");
        }
        let mut d = decode(cases[0].as_bytes()).expect("decode");
        if let SensorData::Imu(i) = &mut d.data {
            i.gyro = Some(Vector3::new(f64::NAN, 0.0, 0.0));
        }
        let e = encode(0, &d.data).unwrap_err();
        assert!(e.to_string().contains("gyro[0]"), "{e}");
    }

    #[test]
    fn errors_name_the_field() {
        let e = decode(br#"{"kind":"gnss","lat_deg":95,"lon_deg":8,"alt_m":0}"#).unwrap_err();
        assert!(e.to_string().contains("gnss.lat_deg"), "{e}");
        let e = decode(br#"{"kind":"imu","gyr":[0,0,0]}"#).unwrap_err();
        assert!(e.to_string().contains("gyr"), "{e}");
        let e = decode(br#"{"kind":"imu","gyro":[NaN,0,0]}"#).unwrap_err();
        assert_eq!(e.kind(), "json");
        let e = decode(br#"{"kind":"attitude","orientation":[0,0,0,0]}"#).unwrap_err();
        assert!(e.to_string().contains("attitude.orientation"), "{e}");
        let e = decode(br#"{"kind":"teleport"}"#).unwrap_err();
        assert!(e.to_string().contains("teleport"), "{e}");
    }
}
