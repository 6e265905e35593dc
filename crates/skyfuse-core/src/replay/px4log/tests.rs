//! The PX4 log reader against the real flights in ../shared/data (skipped, saying so,
//! when absent) and constructed files.

use super::*;
use crate::sample::{GnssFixType, Odometry};
use crate::some_or_skip;
use nalgebra::Quaternion;
use std::collections::BTreeMap;

/// The real indoor flight (CSV export) and the real GPS ULog, in ../shared/data.
const FLOW_VIO: &str = "px4-flow-vio-7c824ee5";
const GPS_ULOG: &str = "px4-gps-fmuv5/roboto_test_fmuv5_gps.ulg";

/// The real flight's directory, or None (the test says it is skipped).
fn data_dir(test: &str) -> Option<PathBuf> {
    crate::shared_data::shared_data(FLOW_VIO, test)
}

/// The real flight as read, or None when its data is absent.
fn real_or_skip(test: &str) -> Option<&'static Px4Log> {
    static LOG: std::sync::OnceLock<Px4Log> = std::sync::OnceLock::new();
    let dir = data_dir(test)?;
    Some(LOG.get_or_init(|| match read_dir(&dir) {
        Ok(log) => log,
        Err(e) => panic!("reading {}: {e}", dir.display()),
    }))
}

/// `real!(test)`: the real flight, or return from the test (skipped) when absent.
macro_rules! real {
    ($test:expr) => {
        match real_or_skip($test) {
            Some(log) => log,
            None => return,
        }
    };
}

fn first_of<'a>(log: &'a Px4Log, source: &str) -> &'a Sample {
    match log.samples.iter().find(|s| &*s.source == source) {
        Some(s) => s,
        None => panic!("no sample from {source}"),
    }
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// A scratch directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("px4log-test-{}-{tag}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn write(&self, name: &str, text: &str) {
        std::fs::write(self.0.join(name), text).unwrap();
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn real_flight_topics_and_row_counts() {
    let log = real!("real_flight_topics_and_row_counts");
    let got: BTreeMap<&str, (&str, usize, usize)> = log
        .topics
        .iter()
        .map(|t| (t.name.as_str(), (t.source.as_str(), t.rows, t.skipped)))
        .collect();
    let want = BTreeMap::from([
        ("actuator_armed_0", ("armed", 616, 0)),
        ("distance_sensor_0", ("range", 14982, 0)),
        ("distance_sensor_1", ("range_1", 11849, 0)),
        ("estimator_optical_flow_vel_0", (EKF2_FLOW_GYRO, 17683, 0)),
        ("estimator_states_0", ("attitude_states", 308, 0)),
        ("optical_flow_0", ("flow", 17666, 0)),
        ("optical_flow_1", ("flow_1", 14438, 0)),
        ("vehicle_imu_0", ("vehicle_imu", 615, 0)),
        ("vehicle_air_data_0", ("baro", 3551, 0)),
        ("vehicle_imu_1", ("vehicle_imu_1", 615, 0)),
        ("vehicle_land_detected_0", ("land_detected", 311, 0)),
        ("vehicle_local_position_0", ("ekf2", 3077, 0)),
        ("vehicle_visual_odometry_0", ("vio", 8978, 0)),
    ]);
    assert_eq!(got, want);
    let total: usize = log.topics.iter().map(TopicSummary::samples).sum();
    assert_eq!(total, 72528 + 616 + 311 + 17683 + 3551);
    // EKF2's flow gyro rows go into the flow samples; one `attitude` per EKF2
    // heading (vehicle_local_position rows), the stand-in for vehicle_attitude,
    // replaces the 308 EKF2 quaternions it takes its tilt from.
    assert_eq!(log.samples.len(), total - 17683 + 3077 - 308);
    assert!(!log
        .samples
        .iter()
        .any(|s| s.source.as_ref() == "attitude_states"));
    assert!(log.samples.iter().any(|s| s.source.as_ref() == "imu"));
    assert_eq!(log.stand_ins.len(), 3, "{:?}", log.stand_ins);
    let missing: Vec<&str> = log
        .missing
        .iter()
        .map(|m| m.split(':').next().unwrap_or(""))
        .collect();
    assert_eq!(missing, ["attitude", "GNSS"]);
}

#[test]
fn real_flight_is_time_ordered_and_offline_stamped() {
    let log = real!("real_flight_is_time_ordered_and_offline_stamped");
    assert!(log
        .samples
        .windows(2)
        .all(|w| w[0].stamp_us <= w[1].stamp_us));
    assert!(log.samples.iter().all(|s| s.stamp_us == Some(s.arrival_us)));
    let first = log.samples.first().and_then(|s| s.stamp_us);
    let last = log.samples.last().and_then(|s| s.stamp_us);
    assert_eq!(first, Some(1_009_456)); // actuator_armed's first row
    assert_eq!(last, Some(308_978_366)); // distance_sensor_0's last row
}

#[test]
fn first_vio_row_converts_ned_frd_to_enu_flu() {
    let s = first_of(real!("first_vio_row_converts_ned_frd_to_enu_flu"), "vio");
    assert_eq!(s.stamp_us, Some(2_760_553));
    let SensorData::Odometry(o) = &s.data else {
        panic!("vio is not odometry: {:?}", s.data)
    };
    // NED (0.048492964, -0.02906012, -0.099466674) → ENU.
    let p = o.position;
    assert!(
        close(p.x, -0.02906012, 1e-7) && close(p.y, 0.048492964, 1e-7),
        "{p}"
    );
    assert!(close(p.z, 0.099466674, 1e-7), "{p}");
    // q ≈ identity in NED/FRD: facing north, so body x → ENU +y, body z → up.
    let fwd = o.orientation * Vector3::x();
    let up = o.orientation * Vector3::z();
    assert!(fwd.y > 0.999 && up.z > 0.999, "{fwd} {up}");
    let q_ned = UnitQuaternion::from_quaternion(Quaternion::new(
        0.9999507,
        0.007620548,
        0.006365071,
        -7.955756e-05,
    ));
    assert!(o.orientation.angle_to(&frames::q_ned_frd_to_enu_flu(q_ned)) < 1e-9);
    // velocity_frame 3 = body FRD: y and z change sign.
    let v = o.velocity.unwrap_or_else(|| panic!("no velocity"));
    assert!((v - Vector3::new(0.001767282, -0.00012230266, -0.0012259282)).norm() < 1e-9);
    let w = o.angular_velocity.unwrap_or_else(|| panic!("no rates"));
    assert!((w - Vector3::new(-0.0002890111, 0.00017851277, -0.003386891)).norm() < 1e-9);
    assert_eq!(o.pose_cov, None); // all NaN in this log
    assert_eq!(o.twist_cov, None);
    assert_eq!(o.reset_counter, Some(0));
    assert_eq!(o.quality, None);
    assert_eq!(o.frame_id, "px4_vio_odom");
    assert_eq!(o.child_frame_id, "px4_vio_body");
}

#[test]
fn vio_velocity_matches_its_position_derivative() {
    // velocity_frame 3 is body FRD: rotated to the world it must be d(position)/dt.
    let odo: Vec<(f64, &Odometry)> = real!("vio_velocity_matches_its_position_derivative")
        .samples
        .iter()
        .filter_map(|s| match (&s.data, s.stamp_us) {
            (SensorData::Odometry(o), Some(t)) => Some((t as f64 * 1e-6, &**o)),
            _ => None,
        })
        .filter(|(t, _)| (215.0..300.0).contains(t))
        .collect();
    let (mut err, mut mag) = (0.0, 0.0);
    for w in odo.windows(3) {
        let ((t0, a), (_, b), (t2, c)) = (w[0], w[1], w[2]);
        let diff = (c.position - a.position) / (t2 - t0);
        let v = b.orientation * b.velocity.unwrap_or_else(|| panic!("no velocity"));
        err += (diff - v).norm_squared();
        mag += v.norm_squared();
    }
    assert!(err < 0.05 * mag, "residual {err} of {mag}");
}

#[test]
fn first_flow_row_of_instance_1() {
    let s = first_of(real!("first_flow_row_of_instance_1"), "flow_1");
    assert_eq!(s.stamp_us, Some(71_402_222));
    let SensorData::Flow(f) = &s.data else {
        panic!("not flow: {:?}", s.data)
    };
    let dt = 23451e-6;
    assert_eq!(f.integration_s, Some(dt));
    let r = f.rate.unwrap_or_else(|| panic!("no rate"));
    // FRD (x, y) → FLU (x, −y).
    assert!(
        close(r.x, -3.496911e-10 / dt, 1e-15) && close(r.y, -0.004 / dt, 1e-12),
        "{r}"
    );
    assert_eq!(f.gyro, None); // NaN x/y in the log: the module has no gyro
    assert_eq!(f.quality, 78);
    assert_eq!(f.tof, None);
}

#[test]
fn flow_sign_matches_vio_motion_in_the_sample_convention() {
    // sample.rs / the estimator: rate = ω + (v_y, −v_x)/d, body FLU. Fit
    // rate = a·ω + b·(translation term) per axis, with VIO's body velocity and rates
    // and the range finder while airborne: both coefficients must come out positive
    // (b near 1). PX4's FRD y axis left unconverted would make both negative on y.
    // VIO's roll rate is noisy, hence the loose bound on a.
    let log = real!("flow_sign_matches_vio_motion_in_the_sample_convention");
    let series = |src: &str| -> Vec<(i64, &'static SensorData)> {
        log.samples
            .iter()
            .filter(|s| &*s.source == src)
            .filter_map(|s| s.stamp_us.map(|t| (t, &s.data)))
            .collect()
    };
    fn nearest<'a>(v: &[(i64, &'a SensorData)], t: i64) -> &'a SensorData {
        let i = v.partition_point(|(ts, _)| *ts < t).min(v.len() - 1);
        v[i].1
    }
    let vio = series("vio");
    let range = series("range");
    for src in ["flow", "flow_1"] {
        // Normal equations of the 2-parameter fit, per axis: [ww wd; wd dd]·(a, b) = (wy, dy).
        let mut m = [[0.0; 5]; 2];
        let mut n = 0;
        for (t, d) in series(src) {
            if !(215_000_000..305_000_000).contains(&t) {
                continue;
            }
            let (SensorData::Flow(f), SensorData::Odometry(o), SensorData::Range(r)) =
                (d, nearest(&vio, t), nearest(&range, t))
            else {
                panic!("wrong sample kinds");
            };
            let (Some(rate), Some(v), Some(w)) = (f.rate, o.velocity, o.angular_velocity) else {
                continue;
            };
            if r.distance_m < 0.5 {
                continue;
            }
            let trans = [v.y / r.distance_m, -v.x / r.distance_m];
            for ax in 0..2 {
                let (wa, da, ya) = (w[ax], trans[ax], rate[ax]);
                for (k, x) in [wa * wa, wa * da, da * da, wa * ya, da * ya]
                    .iter()
                    .enumerate()
                {
                    m[ax][k] += x;
                }
            }
            n += 1;
        }
        assert!(n > 3000, "{src}: {n} samples");
        for (ax, [ww, wd, dd, wy, dy]) in m.iter().copied().enumerate() {
            let det = ww * dd - wd * wd;
            let a = (wy * dd - wd * dy) / det;
            let b = (ww * dy - wd * wy) / det;
            println!("{src} axis {ax}: n {n} a {a:.3} b {b:.3}");
            assert!(
                a > 0.1 && a < 1.3,
                "{src} axis {ax}: rotation coefficient {a}"
            );
            assert!(
                b > 0.8 && b < 1.25,
                "{src} axis {ax}: translation coefficient {b}"
            );
        }
    }
}

#[test]
fn first_range_rows() {
    let log = real!("first_range_rows");
    let SensorData::Range(r) = &first_of(log, "range").data else {
        panic!("not range")
    };
    assert!(close(r.distance_m, 0.0670166, 1e-9));
    assert_eq!((r.min_m, r.max_m), (Some(0.3), Some(200.0)));
    assert_eq!(r.signal_quality, Some(1)); // PX4 0 = invalid = MAVLink 1
    assert_eq!(r.variance, None);
    assert_eq!(r.orientation, Some(25));
    let SensorData::Range(r) = &first_of(log, "range_1").data else {
        panic!("not range")
    };
    // min = max = 0 in this driver's messages: unset, not a zero window.
    assert_eq!((r.min_m, r.max_m), (None, None));
}

/// EKF2's quaternions of the real log as read, before the stand-in replaces them.
fn real_quaternions(data: &Path) -> &'static Px4Log {
    static RAW: std::sync::OnceLock<Px4Log> = std::sync::OnceLock::new();
    RAW.get_or_init(|| {
        let dir = TempDir::new("quaternions");
        let name = "estimator_states_0.csv";
        if let Err(e) = std::fs::copy(data.join(name), dir.0.join(name)) {
            panic!("copying {name}: {e}");
        }
        match read_dir(&dir.0) {
            Ok(log) => log,
            Err(e) => panic!("reading {name}: {e}"),
        }
    })
}

#[test]
fn attitude_and_ekf2_heading_agree() {
    let log = real!("attitude_and_ekf2_heading_agree");
    let data = some_or_skip!(data_dir("attitude_and_ekf2_heading_agree"));
    let s = first_of(real_quaternions(&data), "attitude_states");
    assert_eq!(s.stamp_us, Some(1_692_866));
    let SensorData::Attitude(a) = &s.data else {
        panic!("not attitude")
    };
    let q_ned = UnitQuaternion::from_quaternion(Quaternion::new(
        0.9903907,
        0.0006691864,
        0.0056023533,
        0.13818274,
    ));
    assert!(a.orientation.angle_to(&frames::q_ned_frd_to_enu_flu(q_ned)) < 1e-9);
    let SensorData::AutopilotEstimate(e) = &first_of(log, "ekf2").data else {
        panic!("not ekf2")
    };
    // The first rows precede the flow fix: no valid xy yet, but a heading.
    assert_eq!(e.local_position, None);
    assert_eq!(e.velocity, None);
    let yaw = e.yaw.unwrap_or_else(|| panic!("no yaw"));
    assert!(close(yaw, frames::yaw_ned_to_enu(0.27689523), 1e-9));
    // EKF2's quaternion and its heading name the same yaw (0.277 rad NED).
    assert!(close(a.orientation.euler_angles().2, yaw, 0.01), "{yaw}");
    // The 10 Hz `attitude` stand-in is that heading, tilted as the quaternion
    // nearest in time.
    let stand_in = first_of(log, "attitude");
    let SensorData::Attitude(h) = &stand_in.data else {
        panic!("not attitude")
    };
    assert!(close(yaw_of(&h.orientation), yaw, 1e-9));
    let t = stand_in.stamp_us.unwrap_or_default();
    let nearest = real_quaternions(&data)
        .samples
        .iter()
        .min_by_key(|s| (s.stamp_us.unwrap_or_default() - t).abs())
        .map(|s| &s.data);
    let Some(SensorData::Attitude(q)) = nearest else {
        panic!("no quaternion")
    };
    let level = |q: &UnitQuaternion<f64>| {
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -yaw_of(q)) * q
    };
    assert!(level(&h.orientation).angle_to(&level(&q.orientation)) < 1e-9);
    assert!(level(&h.orientation).angle() > 1e-3, "tilted, not level");
}

#[test]
fn the_attitude_stand_in_is_tilted_when_the_vehicle_is() {
    // 54–64 s of the log the vehicle is held on its side (EKF2's quaternion: 75–78°
    // of tilt; the range finder reads the far wall, 2.6–4.3 m). A level stand-in
    // would let those readings through as heights.
    let tilt = |s: &Sample| match &s.data {
        SensorData::Attitude(a) => (a.orientation * Vector3::z()).angle(&Vector3::z()),
        _ => f64::NAN,
    };
    let held: Vec<f64> = real!("the_attitude_stand_in_is_tilted_when_the_vehicle_is")
        .samples
        .iter()
        .filter(|s| s.source.as_ref() == "attitude")
        .filter(|s| {
            s.stamp_us
                .is_some_and(|t| (56_000_000..63_000_000).contains(&t))
        })
        .map(tilt)
        .collect();
    assert!(held.len() > 60, "{}", held.len());
    assert!(held.iter().all(|t| t.to_degrees() > 70.0), "{held:?}");
    let before = real!("the_attitude_stand_in_is_tilted_when_the_vehicle_is")
        .samples
        .iter()
        .filter(|s| s.source.as_ref() == "attitude")
        .find(|s| s.stamp_us.is_some_and(|t| t > 40_000_000))
        .map(tilt);
    assert!(before.is_some_and(|t| t.to_degrees() < 3.0), "{before:?}");
}

#[test]
fn imu_reads_gravity_up_in_flu() {
    let SensorData::Imu(i) = &first_of(real!("imu_reads_gravity_up_in_flu"), "imu").data else {
        panic!("not imu")
    };
    let a = i.accel.unwrap_or_else(|| panic!("no accel"));
    assert!(close(a.z, 0.038694493 / 3954e-6, 1e-9), "{a}");
    assert!(close(a.z, 9.79, 0.05), "{a}");
    assert!(i.gyro.is_some_and(|g| g.norm() < 0.01));
}

#[test]
fn progress_reaches_the_total() {
    let data = some_or_skip!(data_dir("progress_reaches_the_total"));
    let mut calls = Vec::new();
    let log = read_dir_with_progress(&data, &mut |d, t| calls.push((d, t)));
    assert!(log.is_ok());
    assert!(calls.len() > 5, "{} calls", calls.len());
    assert!(calls
        .windows(2)
        .all(|w| w[0].0 <= w[1].0 && w[0].1 == w[1].1));
    let (done, total) = calls[calls.len() - 1];
    assert_eq!(done, total);
    let known: u64 = real!("progress_reaches_the_total")
        .topics
        .iter()
        .filter_map(|t| std::fs::metadata(data.join(format!("{}.csv", t.name))).ok())
        .map(|m| m.len())
        .sum();
    assert_eq!(total, known);
}

const FLOW_HEADER: &str = "timestamp,pixel_flow_x_integral,pixel_flow_y_integral,gyro_x_rate_integral,gyro_y_rate_integral,gyro_z_rate_integral,integration_timespan,quality\n";

#[test]
fn malformed_rows_are_skipped_with_the_first_error_kept() {
    let dir = TempDir::new("malformed");
    dir.write(
        "optical_flow_0.csv",
        &format!(
            "{FLOW_HEADER}\
             1000,0.01,0.02,nan,nan,0.0,20000,100\n\
             2000,0.01,0.02,nan,nan,20000,100\n\
             3000,0.01,abc,nan,nan,0.0,20000,100\n\
             4000,0.01,0.02,nan,nan,0.0,0,100\n\
             5000,0.01,0.02,0.001,0.002,0.003,20000,300\n\
             6000,inf,0.02,0.001,0.002,0.003,20000,100\n\
             7000,0.01,0.02,0.001,0.002,0.003,20000,100\r\n\
             \n"
        ),
    );
    dir.write("cpuload_0.csv", "timestamp,load\n1,0.5\n");
    let log = match read_dir(&dir.0) {
        Ok(l) => l,
        Err(e) => panic!("{e}"),
    };
    assert_eq!(log.topics.len(), 1);
    let t = &log.topics[0];
    assert_eq!((t.rows, t.skipped, t.samples()), (7, 5, 2));
    assert_eq!(t.span_us, Some((1000, 7000)));
    let e = t.first_error.as_ref().unwrap_or_else(|| panic!("no error"));
    assert!(
        matches!(
            e,
            Px4LogError::ColumnCount {
                line: 3,
                column: 8,
                expected: 8,
                found: 7,
                ..
            }
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(msg.contains("optical_flow_0.csv:3:8"), "{msg}");
    // The row with a gyro keeps it, in FLU.
    let SensorData::Flow(f) = &log.samples[1].data else {
        panic!("not flow")
    };
    let g = f.gyro.unwrap_or_else(|| panic!("no gyro"));
    assert!((g - Vector3::new(0.05, -0.1, -0.15)).norm() < 1e-12, "{g}");
}

#[test]
fn each_bad_row_names_its_line_and_column() {
    let dir = TempDir::new("each");
    let rows = [
        (
            "1000,0.01,abc,nan,nan,0.0,20000,100",
            "optical_flow_0.csv:2:3",
        ),
        ("1000,0.01,0.02,nan,nan,0.0,0,100", "optical_flow_0.csv:2:7"),
        (
            "1000,0.01,0.02,nan,nan,0.0,20000,300",
            "optical_flow_0.csv:2:8",
        ),
        (
            "-5,0.01,0.02,nan,nan,0.0,20000,100",
            "optical_flow_0.csv:2:1",
        ),
        (
            "1000,nan,0.02,nan,nan,0.0,20000,100",
            "optical_flow_0.csv:2:2",
        ),
    ];
    for (row, want) in rows {
        dir.write("optical_flow_0.csv", &format!("{FLOW_HEADER}{row}\n"));
        let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
        let msg = log.topics[0]
            .first_error
            .as_ref()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(msg.contains(want), "{row}: {msg}");
    }
}

#[test]
fn missing_column_and_empty_file_fail_the_read() {
    let dir = TempDir::new("missing");
    dir.write(
        "distance_sensor_0.csv",
        "timestamp,current_distance,min_distance,max_distance,variance,orientation\n1,1.0,0.1,10,0,25\n",
    );
    match read_dir(&dir.0) {
        Err(e @ Px4LogError::MissingColumn { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("distance_sensor_0.csv:1") && msg.contains("signal_quality"),
                "{msg}"
            );
        }
        other => panic!("{other:?}"),
    }
    dir.write("distance_sensor_0.csv", "");
    assert!(matches!(
        read_dir(&dir.0),
        Err(Px4LogError::NoHeader { .. })
    ));
}

/// PX4 before v1.11 logged the range finder's variance as `covariance`: such a log
/// reads (a real one: px4-ulog-rs's esc_status_log fixture, refused whole before).
#[test]
fn a_pre_1_11_distance_sensor_reads_its_covariance_as_the_variance() {
    let dir = TempDir::new("v110");
    dir.write(
        "distance_sensor_0.csv",
        "timestamp,current_distance,min_distance,max_distance,covariance,signal_quality,orientation\n1,1.5,0.1,10,0.0004,100,25\n",
    );
    let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
    let SensorData::Range(r) = &first_of(&log, "range").data else {
        panic!("not range")
    };
    assert!(close(r.distance_m, 1.5, 1e-9));
    assert!(
        r.variance.is_some_and(|v| close(v, 0.0004, 1e-9)),
        "{:?}",
        r.variance
    );
}

#[test]
fn px4_1_14_and_1_15_layouts_read() {
    // PX4 1.14/1.15 field names (vehicle_optical_flow, the renumbered
    // vehicle_odometry frames with variances, sensor_gps in degrees), hand-built rows.
    let dir = TempDir::new("v115");
    dir.write(
        "sensor_combined_0.csv",
        "timestamp,gyro_rad[0],gyro_rad[1],gyro_rad[2],gyro_integral_dt,accelerometer_timestamp_relative,accelerometer_m_s2[0],accelerometer_m_s2[1],accelerometer_m_s2[2],accelerometer_integral_dt\n\
         1000,0.1,0.2,0.3,4000,0,0.5,0.0,-9.8,4000\n",
    );
    dir.write(
        "vehicle_attitude_0.csv",
        "timestamp,timestamp_sample,q[0],q[1],q[2],q[3],delta_q_reset[0],delta_q_reset[1],delta_q_reset[2],delta_q_reset[3],quat_reset_counter\n\
         2000,1990,1,0,0,0,1,0,0,0,0\n",
    );
    dir.write(
        "vehicle_angular_velocity_0.csv",
        "timestamp,timestamp_sample,xyz[0],xyz[1],xyz[2]\n2001,1995,0.0,0.0,0.5\n",
    );
    dir.write(
        "sensor_gps_0.csv",
        "timestamp,latitude_deg,longitude_deg,altitude_msl_m,fix_type,eph,epv,vel_n_m_s,vel_e_m_s,vel_d_m_s,vel_ned_valid,satellites_used,hdop,vdop\n\
         3000,47.3977419,8.5455938,488.1,3,0.8,1.2,1.0,2.0,0.5,1,14,0.7,1.1\n",
    );
    dir.write(
        "vehicle_optical_flow_0.csv",
        "timestamp,timestamp_sample,device_id,pixel_flow[0],pixel_flow[1],delta_angle[0],delta_angle[1],delta_angle[2],distance_m,integration_timespan_us,quality,max_flow_rate,min_ground_distance,max_ground_distance\n\
         4000,3990,1,0.002,0.004,0.001,0.002,0.0,1.5,20000,150,8,0.1,5\n",
    );
    dir.write(
        "vehicle_visual_odometry_0.csv",
        "timestamp,timestamp_sample,pose_frame,position[0],position[1],position[2],q[0],q[1],q[2],q[3],velocity_frame,velocity[0],velocity[1],velocity[2],angular_velocity[0],angular_velocity[1],angular_velocity[2],position_variance[0],position_variance[1],position_variance[2],orientation_variance[0],orientation_variance[1],orientation_variance[2],velocity_variance[0],velocity_variance[1],velocity_variance[2],reset_counter,quality\n\
         5000,4990,1,1.0,2.0,-3.0,1,0,0,0,1,0.5,0,0,nan,nan,nan,0.01,0.02,0.03,0.001,0.001,0.002,0.1,0.1,0.2,4,90\n",
    );
    let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
    assert!(log.stand_ins.is_empty(), "{:?}", log.stand_ins);
    let get = |src: &str| {
        log.samples
            .iter()
            .find(|s| s.source.as_ref() == src)
            .map(|s| s.data.clone())
            .unwrap_or_else(|| panic!("no {src}"))
    };
    let SensorData::Imu(i) = get("imu") else {
        panic!("imu")
    };
    assert_eq!(i.gyro, Some(Vector3::new(0.1, -0.2, -0.3)));
    assert_eq!(i.accel, Some(Vector3::new(0.5, 0.0, 9.8)));
    // The attitude got its rates (FRD yaw rate 0.5 → FLU −0.5).
    let SensorData::Attitude(a) = get("attitude") else {
        panic!("attitude")
    };
    assert_eq!(a.rates, Some(Vector3::new(0.0, 0.0, -0.5)));
    assert!(!log
        .samples
        .iter()
        .any(|s| s.source.as_ref() == "angular_velocity"));
    let SensorData::Gnss(g) = get("gps") else {
        panic!("gps")
    };
    assert!(close(g.lat_deg, 47.3977419, 1e-9) && close(g.alt_m, 488.1, 1e-9));
    assert_eq!(g.fix, GnssFixType::Fix3d);
    assert_eq!(g.velocity, Some(Vector3::new(2.0, 1.0, -0.5)));
    assert_eq!(g.satellites, Some(14));
    let SensorData::Flow(f) = get("flow") else {
        panic!("flow")
    };
    let r = f.rate.unwrap_or_else(|| panic!("rate"));
    assert!(close(r.x, 0.1, 1e-12) && close(r.y, -0.2, 1e-12), "{r}");
    assert_eq!(f.tof.map(|t| t.distance_m), Some(1.5));
    let SensorData::Odometry(o) = get("vio") else {
        panic!("vio")
    };
    assert_eq!(o.position, Vector3::new(2.0, 1.0, 3.0));
    let cov = o.pose_cov.unwrap_or_else(|| panic!("pose cov"));
    // NED variances (0.01, 0.02, 0.03) → ENU (0.02, 0.01, 0.03).
    assert!(close(cov[(0, 0)], 0.02, 1e-12) && close(cov[(1, 1)], 0.01, 1e-12));
    // Facing north, 0.5 m/s north in NED → 0.5 m/s forward in the body.
    let v = o.velocity.unwrap_or_else(|| panic!("velocity"));
    assert!((v - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-12, "{v}");
    assert_eq!((o.reset_counter, o.quality), (Some(4), Some(90)));
    assert!(o.angular_velocity.is_none());
    // Range finder, land detector, barometer.
    assert_eq!(log.missing.len(), 3, "{:?}", log.missing);
}

#[test]
fn the_real_ulog_reads_directly() {
    let path = some_or_skip!(crate::shared_data::shared_data(
        GPS_ULOG,
        "the_real_ulog_reads_directly"
    ));
    let log = read_ulog_with_progress(&path, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
    let count = |src: &str| {
        log.samples
            .iter()
            .filter(|s| s.source.as_ref() == src)
            .count()
    };
    // sensor_combined at ~194 Hz for 9 s, GPS at 2 Hz, EKF2 at 10 Hz.
    assert_eq!(count("imu"), 1737);
    assert!(
        count("gps") >= 10 && count("ekf2") > 80,
        "{} {}",
        count("gps"),
        count("ekf2")
    );
    assert!(count("attitude") > 100);
    assert!(log.stand_ins.is_empty(), "{:?}", log.stand_ins);
    let SensorData::Imu(i) = &log
        .samples
        .iter()
        .find(|s| s.source.as_ref() == "imu")
        .map(|s| &s.data)
        .unwrap_or_else(|| panic!("imu"))
    else {
        panic!("imu")
    };
    let a = i.accel.unwrap_or_else(|| panic!("accel"));
    assert!(close(a.norm(), 9.8, 0.3), "{a}");
    let SensorData::Gnss(g) = &log
        .samples
        .iter()
        .find(|s| s.source.as_ref() == "gps")
        .map(|s| &s.data)
        .unwrap_or_else(|| panic!("gps"))
    else {
        panic!("gps")
    };
    assert!(
        g.lat_deg.abs() > 1.0 && g.lat_deg.abs() <= 90.0,
        "{}",
        g.lat_deg
    );
    // A truncated or foreign file is an error that names it, never a panic.
    let dir = TempDir::new("badulog");
    dir.write("x.ulg", "ULog\u{1}\u{12}5 not really a log");
    let e = read_ulog_with_progress(&dir.0.join("x.ulg"), &mut |_, _| {});
    assert!(e.is_err());
}

/// The real ULog cut short at many places and with bytes changed at random: every read
/// ends in samples or an error that names the file, never a panic; a cut log keeps what
/// came before the cut.
#[test]
fn a_damaged_ulog_is_read_as_far_as_it_goes_or_refused() {
    let path = some_or_skip!(crate::shared_data::shared_data(
        GPS_ULOG,
        "a_damaged_ulog_is_read_as_far_as_it_goes_or_refused"
    ));
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{e}"));
    let whole = read_ulog_with_progress(&path, &mut |_, _| {})
        .unwrap_or_else(|e| panic!("{e}"))
        .samples
        .len();
    let dir = TempDir::new("damaged-ulog");
    let file = dir.0.join("d.ulg");
    let mut x: u64 = 0x2545_f491_4f6c_dd1d;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let (mut read, mut refused) = (0, 0);
    for round in 0..120 {
        let mut b = bytes.clone();
        if round % 2 == 0 {
            b.truncate((next() % bytes.len() as u64) as usize);
        } else {
            for _ in 0..1 + next() % 8 {
                let at = (next() % b.len() as u64) as usize;
                b[at] = next() as u8;
            }
        }
        std::fs::write(&file, &b).unwrap_or_else(|e| panic!("{e}"));
        match read_ulog_with_progress(&file, &mut |_, _| {}) {
            Ok(log) => {
                read += 1;
                if round % 2 == 0 {
                    assert!(log.samples.len() <= whole, "round {round}");
                }
            }
            Err(e) => {
                refused += 1;
                assert!(e.to_string().contains("d.ulg"), "{e}");
            }
        }
    }
    assert!(read > 30 && refused > 0, "read {read}, refused {refused}");
}

#[test]
fn a_directory_without_known_topics_says_what_it_looked_for() {
    let dir = TempDir::new("none");
    dir.write("vehicle_local_position_setpoint_0.csv", "timestamp\n1\n");
    dir.write("vehicle_imu_status_0.csv", "timestamp\n1\n");
    let e = match read_dir(&dir.0) {
        Err(e) => e,
        Ok(l) => panic!("read {:?}", l.topics),
    };
    let msg = e.to_string();
    assert!(msg.contains("optical_flow_<i>.csv"), "{msg}");
    assert!(msg.contains("vehicle_visual_odometry_<i>.csv"), "{msg}");
    assert!(matches!(
        read_dir(&dir.0.join("nope")),
        Err(Px4LogError::ListDir { .. })
    ));
}

#[test]
fn equal_stamps_keep_topic_order() {
    let dir = TempDir::new("ties");
    dir.write(
        "optical_flow_0.csv",
        &format!("{FLOW_HEADER}5,0,0,nan,nan,nan,1000,1\n"),
    );
    dir.write(
        "distance_sensor_0.csv",
        "timestamp,current_distance,min_distance,max_distance,variance,signal_quality,orientation\n5,1.0,0.1,10,0.01,-1,25\n3,1.0,0,0,0,50,25\n",
    );
    let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
    let order: Vec<(&str, Option<i64>)> = log
        .samples
        .iter()
        .map(|s| (&*s.source, s.stamp_us))
        .collect();
    assert_eq!(
        order,
        [("range", Some(3)), ("range", Some(5)), ("flow", Some(5))]
    );
    let SensorData::Range(r) = &log.samples[1].data else {
        panic!("not range")
    };
    assert_eq!(
        (r.signal_quality, r.variance, r.min_m),
        (None, Some(0.01), Some(0.1))
    );
    let SensorData::Range(r) = &log.samples[0].data else {
        panic!("not range")
    };
    assert_eq!((r.signal_quality, r.min_m, r.max_m), (Some(50), None, None));
}

#[test]
fn vio_covariances_and_world_frame_velocity_convert() {
    let dir = TempDir::new("vio");
    let mut header = vec!["timestamp".to_string()];
    header.extend(["x", "y", "z"].map(String::from));
    header.extend((0..4).map(|i| format!("q[{i}]")));
    header.extend((0..21).map(|i| format!("pose_covariance[{i}]")));
    header.extend(["vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed"].map(String::from));
    header.extend((0..21).map(|i| format!("velocity_covariance[{i}]")));
    header.extend(["local_frame", "velocity_frame", "reset_counter", "quality"].map(String::from));
    // Yaw 90° in NED (facing east), diagonal covariances 1..6 in NED order.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let mut row = vec!["10".to_string(), "1".into(), "2".into(), "3".into()];
    row.extend([h, 0.0, 0.0, h].map(|v| v.to_string()));
    let diag = |k: usize| -> Option<f64> {
        [0, 6, 11, 15, 18, 20]
            .iter()
            .position(|&d| d == k)
            .map(|i| i as f64 + 1.0)
    };
    row.extend((0..21).map(|k| diag(k).unwrap_or(0.0).to_string()));
    // Velocity 1 m/s north, in the local frame.
    row.extend(["1", "0", "0", "0.1", "0.2", "0.3"].map(String::from));
    row.extend((0..21).map(|k| diag(k).unwrap_or(0.0).to_string()));
    row.extend(["0", "0", "7", "-1"].map(String::from));
    dir.write(
        "vehicle_visual_odometry_0.csv",
        &format!("{}\n{}\n", header.join(","), row.join(",")),
    );
    let log = read_dir(&dir.0).unwrap_or_else(|e| panic!("{e}"));
    let SensorData::Odometry(o) = &log.samples[0].data else {
        panic!("{:?}", log.topics[0].first_error)
    };
    assert!((o.position - Vector3::new(2.0, 1.0, -3.0)).norm() < 1e-12);
    // Facing east: body x is ENU +x.
    assert!((o.orientation * Vector3::x() - Vector3::x()).norm() < 1e-9);
    // North (ENU +y) is to the body's left (FLU +y).
    let v = o.velocity.unwrap_or_else(|| panic!("no velocity"));
    assert!((v - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-9, "{v}");
    let pc = o.pose_cov.unwrap_or_else(|| panic!("no pose cov"));
    let d: Vec<f64> = (0..6).map(|i| pc[(i, i)]).collect();
    // NED x,y,z,rx,ry,rz = 1..6 → ENU order (y, x, z) in both blocks.
    assert_eq!(d, [2.0, 1.0, 3.0, 5.0, 4.0, 6.0]);
    let tc = o.twist_cov.unwrap_or_else(|| panic!("no twist cov"));
    // World N/E variances 1, 2 seen from an east-facing body: forward = east (2),
    // left = north (1); angular FRD→FLU keeps the variances.
    let d: Vec<f64> = (0..6).map(|i| (tc[(i, i)] * 1e9).round() / 1e9).collect();
    assert_eq!(d, [2.0, 1.0, 3.0, 4.0, 5.0, 6.0]);
    assert_eq!((o.reset_counter, o.quality), (Some(7), Some(-1)));
}

/// A streamed ULog's samples, as a replay gets them.
fn streamed_samples(path: &Path) -> (Vec<Sample>, UlogSamples) {
    let UlogRead::Streamed(log) =
        read_ulog_for_replay(path, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"))
    else {
        panic!("{} was read whole, not streamed", path.display());
    };
    let mut samples = Vec::new();
    crate::offline::SampleSource::for_each(&log, &mut |s| samples.push(s.clone()));
    (samples, log)
}

/// A ULog streamed gives the samples it gives read whole, one for one in the same
/// order, with its joins made as they pass (the real log: the attitude's rates from
/// vehicle_angular_velocity); the same topic summaries and sentences; and the same
/// samples on a second pass (a replay surveys, then fuses).
#[test]
fn a_streamed_ulog_gives_the_samples_it_gives_read_whole() {
    // The real log when it is there (the simulated one always).
    let real = crate::shared_data::shared_data(
        GPS_ULOG,
        "a_streamed_ulog_gives_the_samples_it_gives_read_whole (its real-log half)",
    );
    let dir = TempDir::new("streamed");
    let simulated = dir.0.join("sim.ulg");
    let streams = crate::sim::sensors::with_imu_rate(crate::sim::sensors::DEMO_STREAMS, 1000.0);
    let events = crate::sim::Simulator::new(&streams, 3, 20.0);
    let file = File::create(&simulated).unwrap_or_else(|e| panic!("{e}"));
    crate::sim::ulog::write_flight(events, file).unwrap_or_else(|e| panic!("{e}"));
    for path in real.iter().cloned().chain([simulated]) {
        let whole =
            read_ulog_with_progress(&path, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
        let (samples, log) = streamed_samples(&path);
        assert_eq!(samples.len(), whole.samples.len(), "{}", path.display());
        assert!(
            samples == whole.samples,
            "{}: the samples differ",
            path.display()
        );
        let mut again = Vec::new();
        crate::offline::SampleSource::for_each(&log, &mut |s| again.push(s.clone()));
        assert!(
            again == samples,
            "{}: a second pass differs",
            path.display()
        );
        let brief = |t: &[TopicSummary]| {
            t.iter()
                .map(|t| {
                    format!(
                        "{} {} {} {} {:?}",
                        t.name, t.source, t.rows, t.skipped, t.span_us
                    )
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(
            brief(&log.take_topics()),
            brief(&whole.topics),
            "{}",
            path.display()
        );
        assert_eq!(log.stand_ins(), whole.stand_ins);
        assert_eq!(log.missing, whole.missing);
        // A survey reads it topic by topic, unmerged, and sees what the merged pass does.
        assert_eq!(
            crate::offline::SampleSurvey::of(&log),
            crate::offline::SampleSurvey::in_sequence(&log),
            "{}",
            path.display()
        );
    }
    // The real log's attitude got its rates from vehicle_angular_velocity.
    let Some(real) = real else { return };
    let (samples, _) = streamed_samples(&real);
    assert!(samples
        .iter()
        .any(|s| matches!(&s.data, SensorData::Attitude(a) if a.rates.is_some())));
}

/// A ULog cut in the middle of a message is said to be cut short, where; the whole one
/// is not (issue 35: a cut log replayed as a complete, shorter flight without a word).
#[test]
fn a_ulog_cut_in_a_message_is_said_to_be() {
    let dir = TempDir::new("cut");
    let whole = dir.0.join("whole.ulg");
    let events = crate::sim::Simulator::new(crate::sim::sensors::DEMO_STREAMS, 2, 5.0);
    let file = File::create(&whole).unwrap_or_else(|e| panic!("{e}"));
    crate::sim::ulog::write_flight(events, file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(ulog_cut_short(&whole).ok(), Some(None));
    let bytes = std::fs::read(&whole).unwrap_or_else(|e| panic!("{e}"));
    let cut = dir.0.join("cut.ulg");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap_or_else(|e| panic!("{e}"));
    let at = ulog_cut_short(&cut).ok().flatten().expect("cut short");
    assert!(at > 16 && at <= (bytes.len() * 2 / 3) as u64, "{at}");
    // The parser itself reads the cut file without a word: hence the walk.
    assert!(read_ulog_with_progress(&cut, &mut |_, _| {}).is_ok());
}

/// A ULog topic keeps only the fields its mapper reads (PX4 1.14's sensor_combined, in
/// message order); a topic the mapper cannot read keeps them all, for its error.
#[test]
fn a_ulog_topic_keeps_the_fields_its_mapper_reads() {
    let names: Vec<String> = [
        "timestamp",
        "gyro_rad[0]",
        "gyro_rad[1]",
        "gyro_rad[2]",
        "gyro_integral_dt",
        "accelerometer_timestamp_relative",
        "accelerometer_m_s2[0]",
        "accelerometer_m_s2[1]",
        "accelerometer_m_s2[2]",
        "accelerometer_integral_dt",
        "accelerometer_clipping",
        "gyro_clipping",
        "accel_calibration_count",
        "gyro_calibration_count",
    ]
    .map(String::from)
    .to_vec();
    let file = Path::new("flight.ulg");
    let keep = fields_read(Kind::SensorCombined, file, &names);
    let kept: Vec<&str> = names
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(n, _)| n.as_str())
        .collect();
    for n in [
        "timestamp",
        "gyro_rad[0]",
        "gyro_rad[2]",
        "accelerometer_m_s2[1]",
    ] {
        assert!(kept.contains(&n), "{n} dropped: {kept:?}");
    }
    for n in ["accelerometer_clipping", "gyro_calibration_count"] {
        assert!(!kept.contains(&n), "{n} kept: {kept:?}");
    }
    let no_gyro: Vec<String> = names
        .iter()
        .filter(|n| !n.starts_with("gyro_rad"))
        .cloned()
        .collect();
    assert!(fields_read(Kind::SensorCombined, file, &no_gyro)
        .iter()
        .all(|k| *k));
}

#[test]
#[ignore = "timing; run with --ignored --nocapture"]
fn time_real_read() {
    let t0 = std::time::Instant::now();
    let data = some_or_skip!(data_dir("time_real_read"));
    let log = read_dir(&data).unwrap_or_else(|e| panic!("{e}"));
    let dt = t0.elapsed();
    println!("read {} samples in {dt:?}", log.samples.len());
    for t in &log.topics {
        println!(
            "{:28} {:9} rows {:6} skipped {:3} span {:?}",
            t.name, t.source, t.rows, t.skipped, t.span_us
        );
    }
}
