//! Plain optical-flow dead reckoning: the baseline any flow estimate has to beat, as a
//! user would compute it from a log by hand. Flow rate minus the sensor's own gyro
//! (else the autopilot's body rates), times the range finder's reading, rotated by the
//! attitude's yaw, integrated over the flow's interval. No filter, no gating, no
//! calibration: if the fused track is worse than this, the fusion is doing harm.

use crate::eval::Trajectory;
use crate::sample::{Sample, SensorData};
use crate::source_map::SourceMap;
use nalgebra::{UnitQuaternion, Vector2, Vector3};

/// A range reading older than this is no height for the flow, µs.
const RANGE_FRESH_US: i64 = 500_000;
/// A flow interval longer than this is a gap, not motion, s.
const MAX_INTERVAL_S: f64 = 0.5;

/// Dead reckoning of every flow source in a log, fed its samples in time order.
#[derive(Debug, Default)]
pub struct FlowDeadReckoning {
    attitude: Option<(UnitQuaternion<f64>, Option<Vector3<f64>>)>,
    /// An attitude source was seen: an IMU's orientation no longer stands in.
    attitude_source: bool,
    /// Latest usable range reading: (stamp, slant distance).
    range: Option<(i64, f64)>,
    /// Per flow source: position so far and the last flow stamp.
    tracks: SourceMap<(Vector3<f64>, Option<i64>)>,
    /// The tracks, named `<flow source>_dr`, in seconds from `t0_us`.
    pub out: SourceMap<Trajectory>,
}

impl FlowDeadReckoning {
    /// Take one sample (its stamp, µs); `t` is its time in seconds for the output.
    pub fn sample(&mut self, s: &Sample, t: f64) {
        let Some(stamp) = s.stamp_us else { return };
        match &s.data {
            SensorData::Attitude(a) => {
                self.attitude = Some((a.orientation, a.rates));
                self.attitude_source = true;
            }
            // An IMU with an orientation stands in for a missing attitude source.
            SensorData::Imu(i) if !self.attitude_source => {
                if let Some(q) = i.orientation {
                    self.attitude = Some((q, i.gyro));
                }
            }
            SensorData::Range(r) => {
                let inside = r.min_m.is_none_or(|m| r.distance_m > m)
                    && r.max_m.is_none_or(|m| r.distance_m < m);
                if r.distance_m.is_finite() && inside && r.signal_quality != Some(1) {
                    self.range = Some((stamp, r.distance_m));
                }
            }
            SensorData::Flow(f) => self.flow(&s.source, stamp, t, f),
            _ => {}
        }
    }

    fn flow(&mut self, source: &str, stamp: i64, t: f64, f: &crate::sample::OpticalFlow) {
        let Some((q, rates)) = self.attitude else {
            return;
        };
        let track = self
            .tracks
            .get_or_insert_with(source, || (Vector3::zeros(), None));
        let last = track.1.replace(stamp);
        let dt = match (f.integration_s, last) {
            (Some(i), _) if i.is_finite() && i > 0.0 && i < MAX_INTERVAL_S => i,
            (_, Some(l)) if stamp > l && ((stamp - l) as f64) * 1e-6 < MAX_INTERVAL_S => {
                (stamp - l) as f64 * 1e-6
            }
            _ => return,
        };
        let range = self
            .range
            .filter(|(tr, _)| (stamp - tr).abs() <= RANGE_FRESH_US)
            .map(|(_, d)| d)
            .or_else(|| {
                f.tof
                    .as_ref()
                    .map(|t| t.distance_m)
                    .filter(|d| d.is_finite() && *d > 0.0)
            });
        let (Some(rate), Some(d)) = (f.rate, range) else {
            return;
        };
        let gyro = f.gyro.or(rates).map_or(Vector2::zeros(), |g| g.xy());
        if f.quality == 0 || !rate.iter().chain(gyro.iter()).all(|v| v.is_finite()) {
            return;
        }
        let c = rate - gyro;
        let (_, _, yaw) = q.euler_angles();
        let v_body = Vector3::new(-c.y * d, c.x * d, 0.0);
        let v_nav = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw) * v_body;
        track.0 += v_nav * dt;
        track.0.z = d * (q * Vector3::z()).z.max(0.0);
        let p = track.0;
        let name = format!("{source}_dr");
        self.out
            .get_or_insert_with(&name, Trajectory::default)
            .push(t, p, UnitQuaternion::from_euler_angles(0.0, 0.0, yaw));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::{Attitude, OpticalFlow, Range};

    fn sample(source: &str, stamp: i64, data: SensorData) -> Sample {
        Sample {
            source: source.into(),
            stamp_us: Some(stamp),
            arrival_us: stamp,
            data,
        }
    }

    /// Flying north (ENU y) at 2 m/s, 4 m up, yawed 90° (nose north): the body's x is
    /// north, so the flow sees rate = (v_y, −v_x)/d = (0, −0.5) rad/s plus the rotation.
    #[test]
    fn integrates_compensated_flow_times_range_rotated_by_yaw() {
        let mut dr = FlowDeadReckoning::default();
        let q = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let w = Vector3::new(0.1, -0.05, 0.0);
        for k in 0..100 {
            let t = k * 20_000;
            let att = SensorData::Attitude(Attitude {
                orientation: q,
                rates: Some(w),
            });
            dr.sample(&sample("attitude", t, att), t as f64 * 1e-6);
            let r = SensorData::Range(Range {
                distance_m: 4.0,
                min_m: Some(0.3),
                max_m: Some(10.0),
                signal_quality: None,
                variance: None,
                orientation: Some(25),
            });
            dr.sample(&sample("range", t, r), t as f64 * 1e-6);
            let flow = SensorData::Flow(OpticalFlow {
                rate: Some(Vector2::new(w.x, w.y - 0.5)),
                gyro: None,
                velocity: None,
                integration_s: Some(0.02),
                quality: 200,
                status: None,
                tof: None,
            });
            dr.sample(&sample("flow", t, flow), t as f64 * 1e-6);
        }
        let tr = dr.out.get("flow_dr").expect("a track");
        let p = tr.p[tr.p.len() - 1];
        // 100 intervals of 20 ms at 2 m/s northwards.
        assert!((p - Vector3::new(0.0, 4.0, 4.0)).norm() < 1e-9, "{p}");
    }
}
