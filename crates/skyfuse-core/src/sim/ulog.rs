//! A simulated flight written as a PX4 ULog: the topics [`crate::replay::px4log`] reads,
//! in PX4 1.14–1.15 layouts, in the binary format PX4's logger writes (file header,
//! flag bits, one format definition and subscription per topic, then data messages in
//! publication order). A log of any length and IMU rate, with a known truth, for replay
//! benchmarks and for checking the ULog path end to end.
//!
//! Conventions inverted from the reader: ENU/FLU → NED/FRD, flow and its gyro as
//! integrals over the integration time, `timestamp` = the measurement time (µs since
//! boot; the simulator's start is at [`BOOT_OFFSET_US`]).

use super::SimEvent;
use crate::sample::{frames, GnssFixType, SensorData};
use nalgebra::{UnitQuaternion, Vector3};
use std::io::{self, Write};

/// The simulator's time 0 in the log's clock (PX4 logs start some seconds after boot).
pub const BOOT_OFFSET_US: u64 = 10_000_000;

/// A topic the writer can log: its name and its ULog format (fields packed in order,
/// little-endian, no padding).
struct Topic {
    name: &'static str,
    format: &'static str,
}

const SENSOR_COMBINED: Topic = Topic {
    name: "sensor_combined",
    format: "uint64_t timestamp;float[3] gyro_rad;uint32_t gyro_integral_dt;\
             int32_t accelerometer_timestamp_relative;float[3] accelerometer_m_s2;\
             uint32_t accelerometer_integral_dt;uint8_t accelerometer_clipping;\
             uint8_t gyro_clipping;uint8_t accel_calibration_count;\
             uint8_t gyro_calibration_count;",
};
const VEHICLE_ATTITUDE: Topic = Topic {
    name: "vehicle_attitude",
    format: "uint64_t timestamp;uint64_t timestamp_sample;float[4] q;float[4] delta_q_reset;\
             uint8_t quat_reset_counter;",
};
const VEHICLE_ODOMETRY: Topic = Topic {
    name: "vehicle_visual_odometry",
    format: "uint64_t timestamp;uint64_t timestamp_sample;float[3] position;float[4] q;\
             float[3] velocity;float[3] angular_velocity;float[3] position_variance;\
             float[3] orientation_variance;float[3] velocity_variance;uint8_t pose_frame;\
             uint8_t velocity_frame;uint8_t reset_counter;int8_t quality;",
};
const VEHICLE_OPTICAL_FLOW: Topic = Topic {
    name: "vehicle_optical_flow",
    format: "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;\
             float[2] pixel_flow;float[3] delta_angle;float distance_m;\
             uint32_t integration_timespan_us;uint8_t quality;float max_flow_rate;\
             float min_ground_distance;float max_ground_distance;",
};
const DISTANCE_SENSOR: Topic = Topic {
    name: "distance_sensor",
    format: "uint64_t timestamp;uint32_t device_id;float min_distance;float max_distance;\
             float current_distance;float variance;float h_fov;float v_fov;float[4] q;\
             int8_t signal_quality;uint8_t type;uint8_t orientation;",
};
const SENSOR_GPS: Topic = Topic {
    name: "sensor_gps",
    format: "uint64_t timestamp;uint64_t timestamp_sample;double latitude_deg;\
             double longitude_deg;double altitude_msl_m;uint8_t fix_type;float eph;float epv;\
             float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;bool vel_ned_valid;\
             uint8_t satellites_used;float hdop;float vdop;",
};

/// vehicle_odometry's frame constants (PX4 1.14).
const POSE_FRAME_NED: u8 = 1;
const VELOCITY_FRAME_BODY_FRD: u8 = 3;

/// What was written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UlogSummary {
    pub messages: u64,
    pub bytes: u64,
    /// Samples of a kind the writer has no topic for (none from the simulator's streams).
    pub skipped: u64,
}

/// Writes ULog messages to `out`.
pub struct UlogWriter<W: Write> {
    out: W,
    /// The data message being encoded (reused).
    buf: Vec<u8>,
    summary: UlogSummary,
}

const TOPICS: [&Topic; 6] = [
    &SENSOR_COMBINED,
    &VEHICLE_ATTITUDE,
    &VEHICLE_ODOMETRY,
    &VEHICLE_OPTICAL_FLOW,
    &DISTANCE_SENSOR,
    &SENSOR_GPS,
];

impl<W: Write> UlogWriter<W> {
    /// Writes the file header, the flag bits, and every topic's format and subscription.
    pub fn new(mut out: W) -> io::Result<Self> {
        let mut header = Vec::with_capacity(16);
        header.extend_from_slice(b"ULog\x01\x12\x35");
        header.push(1); // version
        header.extend_from_slice(&BOOT_OFFSET_US.to_le_bytes());
        out.write_all(&header)?;
        let mut w = Self {
            out,
            buf: Vec::with_capacity(256),
            summary: UlogSummary {
                bytes: 16,
                ..UlogSummary::default()
            },
        };
        // 'B': compat and incompat flags all clear, no appended data.
        w.message(b'B', &[0u8; 40])?;
        for t in TOPICS {
            let format = format!("{}:{}", t.name, t.format);
            w.message(b'F', format.as_bytes())?;
        }
        for (id, t) in TOPICS.iter().enumerate() {
            let mut a = vec![0u8]; // multi_id
            a.extend_from_slice(&(id as u16).to_le_bytes());
            a.extend_from_slice(t.name.as_bytes());
            w.message(b'A', &a)?;
        }
        Ok(w)
    }

    fn message(&mut self, kind: u8, payload: &[u8]) -> io::Result<()> {
        let len = u16::try_from(payload.len())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "ULog message > 64 KiB"))?;
        self.out.write_all(&len.to_le_bytes())?;
        self.out.write_all(&[kind])?;
        self.out.write_all(payload)?;
        self.summary.bytes += 3 + payload.len() as u64;
        Ok(())
    }

    /// Logs one simulated measurement at `t_us` (µs since the simulator's start).
    pub fn sample(&mut self, t_us: u64, data: &SensorData) -> io::Result<()> {
        let t = t_us + BOOT_OFFSET_US;
        let mut b = std::mem::take(&mut self.buf);
        b.clear();
        // The message id (the topic's index in TOPICS) goes first, once it is known.
        b.extend_from_slice(&[0, 0]);
        let topic = match data {
            SensorData::Imu(imu) => {
                let (Some(g), Some(a)) = (imu.gyro, imu.accel) else {
                    return self.skip(b);
                };
                put_u64(&mut b, t);
                put_v3(&mut b, frames::frd_to_flu(g));
                put_u32(&mut b, 1000);
                b.extend_from_slice(&0i32.to_le_bytes());
                put_v3(&mut b, frames::frd_to_flu(a));
                put_u32(&mut b, 1000);
                b.extend_from_slice(&[0, 0, 1, 1]);
                &SENSOR_COMBINED
            }
            SensorData::Attitude(att) => {
                put_u64(&mut b, t);
                put_u64(&mut b, t);
                put_q(&mut b, frames::q_ned_frd_to_enu_flu(att.orientation));
                put_f32s(&mut b, &[1.0, 0.0, 0.0, 0.0]);
                b.push(0);
                &VEHICLE_ATTITUDE
            }
            SensorData::Odometry(o) => {
                // The same 180° rotations take ENU/FLU back to NED/FRD.
                let q = frames::q_ned_frd_to_enu_flu(o.orientation);
                put_u64(&mut b, t);
                put_u64(&mut b, t);
                put_v3(&mut b, frames::ned_to_enu(o.position));
                put_q(&mut b, q);
                let nan = Vector3::repeat(f64::NAN);
                put_v3(&mut b, o.velocity.map_or(nan, frames::frd_to_flu));
                put_v3(&mut b, o.angular_velocity.map_or(nan, frames::frd_to_flu));
                let var = |c: Option<nalgebra::Matrix6<f64>>, at: usize| {
                    c.map_or(nan, |c| {
                        Vector3::new(c[(at, at)], c[(at + 1, at + 1)], c[(at + 2, at + 2)])
                    })
                };
                // NED and ENU variances are the same permutation of each other.
                let pv = var(o.pose_cov, 0);
                put_v3(&mut b, Vector3::new(pv.y, pv.x, pv.z));
                put_v3(&mut b, var(o.pose_cov, 3));
                put_v3(&mut b, var(o.twist_cov, 0));
                b.extend_from_slice(&[
                    POSE_FRAME_NED,
                    VELOCITY_FRAME_BODY_FRD,
                    o.reset_counter.unwrap_or(0),
                ]);
                b.push(o.quality.unwrap_or(100) as u8);
                &VEHICLE_ODOMETRY
            }
            SensorData::Flow(f) => {
                let (Some(rate), Some(dt)) = (f.rate, f.integration_s) else {
                    return self.skip(b);
                };
                put_u64(&mut b, t);
                put_u64(&mut b, t);
                put_u32(&mut b, 0);
                // The reader's inverse: rate = (x/dt, −y/dt), gyro = FRD→FLU of the integral/dt.
                put_f32s(&mut b, &[rate.x * dt, -rate.y * dt]);
                let nan = Vector3::repeat(f64::NAN);
                put_v3(&mut b, f.gyro.map_or(nan, |g| frames::frd_to_flu(g) * dt));
                put_f32s(&mut b, &[f.tof.as_ref().map_or(f64::NAN, |t| t.distance_m)]);
                put_u32(&mut b, (dt * 1e6).round() as u32);
                b.push(f.quality);
                put_f32s(&mut b, &[8.0, 0.08, 4.0]);
                &VEHICLE_OPTICAL_FLOW
            }
            SensorData::Range(r) => {
                put_u64(&mut b, t);
                put_u32(&mut b, 0);
                put_f32s(
                    &mut b,
                    &[
                        r.min_m.unwrap_or(0.0),
                        r.max_m.unwrap_or(0.0),
                        r.distance_m,
                        r.variance.unwrap_or(0.0),
                        0.05,
                        0.05,
                        1.0,
                        0.0,
                        0.0,
                        0.0,
                    ],
                );
                let quality = match r.signal_quality {
                    None => -1i8,
                    Some(1) => 0,
                    Some(q) => q.min(100) as i8,
                };
                b.push(quality as u8);
                b.push(0); // MAV_DISTANCE_SENSOR_LASER
                b.push(r.orientation.unwrap_or(25));
                &DISTANCE_SENSOR
            }
            SensorData::Gnss(g) => {
                put_u64(&mut b, t);
                put_u64(&mut b, t);
                for v in [g.lat_deg, g.lon_deg, g.alt_m] {
                    b.extend_from_slice(&v.to_le_bytes());
                }
                b.push(match g.fix {
                    GnssFixType::NoFix => 1,
                    GnssFixType::Fix2d => 2,
                    GnssFixType::Fix3d => 3,
                    GnssFixType::Dgps => 4,
                    GnssFixType::RtkFloat => 5,
                    GnssFixType::RtkFixed => 6,
                });
                let (eph, epv) = g.position_cov.as_deref().map_or((f64::NAN, f64::NAN), |c| {
                    (c[(0, 0)].max(c[(1, 1)]).sqrt(), c[(2, 2)].sqrt())
                });
                put_f32s(&mut b, &[eph, epv]);
                let v = g.velocity.map(frames::ned_to_enu);
                put_v3(&mut b, v.unwrap_or(Vector3::repeat(f64::NAN)));
                b.push(v.is_some() as u8);
                b.push(g.satellites.unwrap_or(0));
                put_f32s(
                    &mut b,
                    &[g.hdop.unwrap_or(f64::NAN), g.vdop.unwrap_or(f64::NAN)],
                );
                &SENSOR_GPS
            }
            _ => return self.skip(b),
        };
        let id = TOPICS
            .iter()
            .position(|t| t.name == topic.name)
            .expect("every topic written is in TOPICS") as u16;
        b[..2].copy_from_slice(&id.to_le_bytes());
        let r = self.message(b'D', &b);
        self.buf = b;
        self.summary.messages += 1;
        r
    }

    /// A sample with no topic here: counted, nothing written.
    fn skip(&mut self, buf: Vec<u8>) -> io::Result<()> {
        self.summary.skipped += 1;
        self.buf = buf;
        Ok(())
    }

    /// Flushes and returns what was written.
    pub fn finish(mut self) -> io::Result<UlogSummary> {
        self.out.flush()?;
        Ok(self.summary)
    }
}

/// Writes the simulated flight `events` (in publication order, as the simulator emits
/// them) to `out`, each at its measurement time.
pub fn write_flight(
    events: impl Iterator<Item = SimEvent>,
    out: impl Write,
) -> io::Result<UlogSummary> {
    let mut w = UlogWriter::new(out)?;
    for e in events {
        w.sample((e.measured_t.max(0.0) * 1e6).round() as u64, &e.data)?;
    }
    w.finish()
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}

/// Little-endian f32s (both simulated logs' floats).
pub(super) fn put_f32s(b: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        b.extend_from_slice(&(*x as f32).to_le_bytes());
    }
}

fn put_v3(b: &mut Vec<u8>, v: Vector3<f64>) {
    put_f32s(b, &[v.x, v.y, v.z]);
}

/// PX4's quaternion order: w, x, y, z.
fn put_q(b: &mut Vec<u8>, q: UnitQuaternion<f64>) {
    put_f32s(b, &[q.w, q.i, q.j, q.k]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::px4log;
    use crate::sample::SensorKind;
    use crate::sim::sensors::{with_imu_rate, DEMO_STREAMS};
    use crate::sim::Simulator;

    /// A topic whose times go back (a log of out-of-order publications) is read whole
    /// and sorted, stably, like every other.
    #[test]
    fn a_topic_out_of_time_order_is_read_and_sorted() {
        let imu = |g: f64| {
            SensorData::Imu(crate::sample::Imu::from_rates(
                Some(Vector3::new(g, 0.0, 0.0)),
                Some(Vector3::new(0.0, 0.0, 9.8)),
            ))
        };
        let range = |d: f64| {
            SensorData::Range(crate::sample::Range {
                distance_m: d,
                min_m: Some(0.1),
                max_m: Some(10.0),
                signal_quality: None,
                variance: None,
                orientation: Some(25),
            })
        };
        let path = std::env::temp_dir().join(format!("ooo-ulog-{}.ulg", std::process::id()));
        let mut w = UlogWriter::new(std::fs::File::create(&path).expect("temp")).expect("header");
        for (t, d) in [
            (0, imu(0.0)),
            (3_000, imu(3.0)),
            (1_000, imu(1.0)),
            (2_000, imu(2.0)),
        ] {
            w.sample(t, &d).expect("written");
        }
        for (t, d) in [(1_000, range(1.0)), (500, range(0.5))] {
            w.sample(t, &d).expect("written");
        }
        w.finish().expect("flushed");
        let log = px4log::read_ulog_with_progress(&path, &mut |_, _| {}).expect("read back");
        let _ = std::fs::remove_file(&path);
        let order: Vec<(i64, &str)> = log
            .samples
            .iter()
            .map(|s| {
                (
                    s.stamp_us.unwrap_or(0) - BOOT_OFFSET_US as i64,
                    s.source.as_ref(),
                )
            })
            .collect();
        // At 1000 µs the IMU first: sensor_combined comes before distance_sensor.
        assert_eq!(
            order,
            [
                (0, "imu"),
                (500, "range"),
                (1_000, "imu"),
                (1_000, "range"),
                (2_000, "imu"),
                (3_000, "imu")
            ]
        );
    }

    /// The simulator's samples written as a ULog and read back by the replay reader (the
    /// px4-ulog crate's parser, then the topic mapping): every sample, each as it was, to
    /// the precision of the log's floats.
    #[test]
    fn a_simulated_flight_reads_back_as_it_was_written() {
        let streams = with_imu_rate(DEMO_STREAMS, 1000.0);
        let events: Vec<SimEvent> = Simulator::new(&streams, 7, 3.0).collect();
        let path = std::env::temp_dir().join(format!("sim-ulog-{}.ulg", std::process::id()));
        let file = std::fs::File::create(&path).expect("temp file");
        let summary = write_flight(events.clone().into_iter(), file).expect("written");
        assert_eq!(summary.messages as usize, events.len());
        assert_eq!(summary.skipped, 0);
        assert_eq!(
            summary.bytes,
            std::fs::metadata(&path).expect("written").len()
        );
        let log = px4log::read_ulog_with_progress(&path, &mut |_, _| {}).expect("read back");
        let _ = std::fs::remove_file(&path);
        assert!(
            log.topics.iter().all(|t| t.skipped == 0),
            "{:?}",
            log.topics
        );
        assert_eq!(log.samples.len(), events.len());
        // Per kind, in time order, each read sample against the one written.
        let kinds = [
            SensorKind::Imu,
            SensorKind::Attitude,
            SensorKind::Odometry,
            SensorKind::Flow,
            SensorKind::Range,
            SensorKind::Gnss,
        ];
        for kind in kinds {
            let mut written: Vec<&SimEvent> =
                events.iter().filter(|e| e.data.kind() == kind).collect();
            written.sort_by(|a, b| a.measured_t.total_cmp(&b.measured_t));
            let read: Vec<_> = log
                .samples
                .iter()
                .filter(|s| s.data.kind() == kind)
                .collect();
            assert_eq!(read.len(), written.len(), "{kind:?}");
            assert!(!read.is_empty(), "{kind:?}");
            for (r, w) in read.iter().zip(&written) {
                let t = (w.measured_t * 1e6).round() as i64 + BOOT_OFFSET_US as i64;
                assert_eq!(r.stamp_us, Some(t), "{kind:?}");
                let close =
                    |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() < 1e-5 * (1.0 + b.norm());
                match (&r.data, &w.data) {
                    (SensorData::Imu(a), SensorData::Imu(b)) => {
                        assert!(close(a.gyro.unwrap(), b.gyro.unwrap()), "{a:?} {b:?}");
                        assert!(close(a.accel.unwrap(), b.accel.unwrap()), "{a:?} {b:?}");
                    }
                    (SensorData::Attitude(a), SensorData::Attitude(b)) => {
                        assert!(a.orientation.angle_to(&b.orientation) < 1e-6);
                    }
                    (SensorData::Odometry(a), SensorData::Odometry(b)) => {
                        assert!(close(a.position, b.position), "{a:?} {b:?}");
                        assert!(a.orientation.angle_to(&b.orientation) < 1e-6);
                        assert!(close(a.velocity.unwrap(), b.velocity.unwrap()));
                    }
                    (SensorData::Flow(a), SensorData::Flow(b)) => {
                        let (ra, rb) = (a.rate.unwrap(), b.rate.unwrap());
                        assert!((ra - rb).norm() < 1e-4 * (1.0 + rb.norm()), "{a:?} {b:?}");
                        match (a.gyro, b.gyro) {
                            (Some(ga), Some(gb)) => assert!(close(ga, gb), "{a:?} {b:?}"),
                            (ga, gb) => assert_eq!(ga.is_some(), gb.is_some()),
                        }
                        assert_eq!(a.quality, b.quality);
                    }
                    (SensorData::Range(a), SensorData::Range(b)) => {
                        assert!((a.distance_m - b.distance_m).abs() < 1e-5);
                    }
                    (SensorData::Gnss(a), SensorData::Gnss(b)) => {
                        assert!((a.lat_deg - b.lat_deg).abs() < 1e-12);
                        assert!((a.lon_deg - b.lon_deg).abs() < 1e-12);
                        assert!((a.alt_m - b.alt_m).abs() < 1e-9);
                        assert_eq!(a.fix, b.fix);
                    }
                    (a, b) => panic!("{a:?} read for {b:?}"),
                }
            }
        }
    }
}
