//! Sensor faults the simulator can inject: scheduled by a scenario, or live from the
//! demo's control API. A fault changes what a sensor model reports, never the truth.

use crate::sample::{GnssFixType, SensorData};
use crate::sync::lock;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::Mutex;

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// The sensor stops sending.
    Stop,
    /// Values become NaN.
    Nan,
    /// GNSS: no fix (indoors, jammed). Other sensors: same as `stop`.
    NoFix,
    /// A sudden position offset (GNSS multipath, odometry relocalisation error).
    Jump,
    /// Reported covariance goes up: T265 pose variance 0.01 (unusable), GNSS 25 m².
    Covariance,
    /// Odometry drifts away at 0.3 m/s.
    Drift,
    /// Odometry frame resets to the current pose (tracking lost and restarted).
    Reset,
    /// Flow over a dark, featureless floor: quality collapses, rates are noise.
    DarkFloor,
    /// The flow module's ToF reads out of range.
    TofRange,
    /// The accelerometer reads [`ACCEL_OFFSET_MPS2`] more along the body's forward
    /// axis: a knock that shifted its mount, vibration rectified by a loose one.
    AccelOffset,
    /// Remove every fault of this sensor.
    Clear,
}

impl FaultKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::Stop => "stop",
            FaultKind::Nan => "nan",
            FaultKind::NoFix => "no-fix",
            FaultKind::Jump => "jump",
            FaultKind::Covariance => "covariance",
            FaultKind::Drift => "drift",
            FaultKind::Reset => "reset",
            FaultKind::DarkFloor => "dark-floor",
            FaultKind::TofRange => "tof-range",
            FaultKind::AccelOffset => "accel-offset",
            FaultKind::Clear => "clear",
        }
    }
}

/// Multipath jump size, m (east).
pub const JUMP_M: f64 = 12.0;
/// The `accel-offset` fault's error, m/s² (the largest bias the randomised flights
/// draw).
pub const ACCEL_OFFSET_MPS2: f64 = 1.0;
/// Odometry drift rate of the `drift` fault, m/s.
pub const DRIFT_MPS: f64 = 0.3;

/// One fault on one sensor input over `[start_s, end_s)` of simulated time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fault {
    pub sensor: String,
    pub kind: FaultKind,
    pub start_s: f64,
    pub end_s: f64,
}

/// The control API's request body.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultRequest {
    pub sensor: String,
    pub fault: FaultKind,
    /// Default: until cleared.
    #[serde(default)]
    pub duration_s: Option<f64>,
}

/// The faults of one simulated vehicle; shared between the simulator and the controls.
#[derive(Debug, Default)]
pub struct FaultSchedule {
    faults: Mutex<Vec<Fault>>,
    /// The simulator's current time, s (so live faults start "now").
    now_s: Mutex<f64>,
    /// Input ids the simulator publishes (to refuse unknown sensors).
    sensors: Vec<String>,
}

impl FaultSchedule {
    pub fn new(sensors: Vec<String>, faults: Vec<Fault>) -> Self {
        Self {
            faults: Mutex::new(faults),
            now_s: Mutex::new(0.0),
            sensors,
        }
    }

    pub fn set_now(&self, t: f64) {
        *lock(&self.now_s) = t;
    }

    pub fn faults(&self) -> Vec<Fault> {
        lock(&self.faults).clone()
    }

    /// Faults of `sensor` active at `t`.
    pub fn active(&self, sensor: &str, t: f64) -> Vec<Fault> {
        lock(&self.faults)
            .iter()
            .filter(|f| f.sensor == sensor && f.start_s <= t && t < f.end_s)
            .cloned()
            .collect()
    }

    /// Faults of `sensor` that started before `t` (for lasting effects: drift, reset).
    pub fn started(&self, sensor: &str, t: f64) -> Vec<Fault> {
        lock(&self.faults)
            .iter()
            .filter(|f| f.sensor == sensor && f.start_s <= t)
            .cloned()
            .collect()
    }

    /// Apply a live request; returns a description for the event log.
    pub fn inject(&self, req: &FaultRequest) -> Result<String, String> {
        if !self.sensors.iter().any(|s| s == &req.sensor) {
            return Err(format!(
                "unknown sensor {:?}; the simulator has {}",
                req.sensor,
                self.sensors.join(", ")
            ));
        }
        let now = *lock(&self.now_s);
        let mut faults = lock(&self.faults);
        if req.fault == FaultKind::Clear {
            for f in faults.iter_mut().filter(|f| f.sensor == req.sensor) {
                f.end_s = f.end_s.min(now);
            }
            return Ok(format!("sim: faults of {} cleared", req.sensor));
        }
        let duration = match req.duration_s {
            Some(d) if d.is_finite() && d > 0.0 => d,
            Some(d) => return Err(format!("duration_s = {d} must be positive")),
            None => f64::INFINITY,
        };
        faults.push(Fault {
            sensor: req.sensor.clone(),
            kind: req.fault,
            start_s: now,
            end_s: now + duration,
        });
        Ok(format!(
            "sim: fault {} injected on {} at t={now:.1} s{}",
            req.fault.as_str(),
            req.sensor,
            if duration.is_finite() {
                format!(" for {duration} s")
            } else {
                String::new()
            }
        ))
    }
}

/// Whether the sample is not sent at all.
pub fn suppressed(active: &[Fault]) -> bool {
    active.iter().any(|f| f.kind == FaultKind::Stop)
}

/// Change a measurement as the active faults say. Lasting effects (drift, reset) are
/// handled by the sensor models.
pub fn apply(data: &mut SensorData, active: &[Fault], t: f64) {
    for f in active {
        match (f.kind, &mut *data) {
            (FaultKind::Nan, SensorData::Imu(m)) => m.accel = Some(Vector3::repeat(f64::NAN)),
            (FaultKind::Nan, SensorData::Gnss(m)) => m.lat_deg = f64::NAN,
            (FaultKind::Nan, SensorData::Odometry(m)) => m.position.x = f64::NAN,
            (FaultKind::Nan, SensorData::Flow(m)) => {
                m.rate = m.rate.map(|r| r.map(|_| f64::NAN));
            }
            (FaultKind::Nan, SensorData::Range(m)) => m.distance_m = f64::NAN,
            (FaultKind::Nan, SensorData::Attitude(m)) => m.rates = Some(Vector3::repeat(f64::NAN)),
            (FaultKind::NoFix, SensorData::Gnss(m)) => {
                m.fix = GnssFixType::NoFix;
                m.satellites = Some(3);
                m.hdop = Some(25.0);
                m.position_cov = m.position_cov.take().map(|c| Box::new(*c * 1e4));
                m.velocity = None;
            }
            (FaultKind::Jump, SensorData::Gnss(m)) => {
                // 12 m east at this latitude.
                m.lon_deg += JUMP_M / (111_320.0 * m.lat_deg.to_radians().cos());
            }
            (FaultKind::Jump, SensorData::Odometry(m)) => m.position.x += JUMP_M / 10.0,
            (FaultKind::Covariance, SensorData::Odometry(m)) => {
                if let Some(c) = m.pose_cov.as_mut() {
                    for i in 0..6 {
                        c[(i, i)] = 0.01;
                    }
                }
            }
            (FaultKind::Covariance, SensorData::Gnss(m)) => {
                m.position_cov = Some(Box::new(Matrix3::identity() * 25.0));
                m.hdop = Some(6.0);
            }
            (FaultKind::DarkFloor, SensorData::Flow(m)) => {
                m.quality = 8;
                m.status = Some(0);
                // A featureless floor: the correlator locks onto noise.
                let k = (t * 37.0).sin();
                m.rate = m
                    .rate
                    .map(|r| r * 0.1 + nalgebra::Vector2::new(k, -k) * 0.8);
            }
            (FaultKind::AccelOffset, SensorData::Imu(m)) => {
                if let Some(a) = m.accel.as_mut() {
                    a.x += ACCEL_OFFSET_MPS2;
                }
            }
            (FaultKind::TofRange, SensorData::Flow(m)) => {
                if let Some(tof) = m.tof.as_mut() {
                    tof.distance_m = 0.0;
                    tof.status = Some(1);
                    tof.strength = Some(0);
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn live_injection_starts_now_and_clear_ends_it() {
        let s = FaultSchedule::new(vec!["gps".into()], vec![]);
        s.set_now(10.0);
        let msg = s
            .inject(&FaultRequest {
                sensor: "gps".into(),
                fault: FaultKind::NoFix,
                duration_s: None,
            })
            .expect("inject");
        assert!(msg.contains("no-fix"), "{msg}");
        assert!(s.active("gps", 9.9).is_empty());
        assert_eq!(s.active("gps", 50.0).len(), 1);
        s.set_now(60.0);
        s.inject(&FaultRequest {
            sensor: "gps".into(),
            fault: FaultKind::Clear,
            duration_s: None,
        })
        .expect("clear");
        assert!(s.active("gps", 61.0).is_empty());
        assert!(s
            .inject(&FaultRequest {
                sensor: "lidar".into(),
                fault: FaultKind::Stop,
                duration_s: None
            })
            .is_err());
    }
}
