//! Health checks and fault diagnosis: a verdict per sensor (ok, degraded, failed,
//! stale, disabled) with machine-readable reason codes, hysteresis so a borderline
//! sensor does not flap, and the usable/unusable decision the estimator obeys.
//!
//! Pure and deterministic like the estimator: time is passed in (the sample's host
//! time), nothing is read from a clock. Checks follow the seeds and PX4/ArduPilot
//! practice; thresholds are config keys (`[health]`), defaults are named constants.
//!
//! How a verdict forms: each check that fails raises a *condition* (code, severity,
//! text) with the times it was first and last seen in its current run. A condition is
//! active while it was seen within its hold time (`hold_ms`, at least 2.5 expected
//! sample periods, so a slow sensor's run does not break between samples). It counts
//! once it has been seen over `confirm_ms` (a lone bad sample, a momentary dip of flow
//! quality, is the estimator's to drop sample by sample, not a reason to take the
//! sensor out for `recover_ms`), or while the sensor is already that bad, or at once
//! if one sample shows it in full ([`STEP_CODES`]: a jump, a reset). The sensor's
//! raw state is the worst counting condition (or `stale` without data), adopted at
//! once when worse; a better one only after `recover_ms` — a recovered sensor is taken
//! back only after it has been good for that long — except out of `stale`/`no_data`:
//! data that is back is judged by the checks from its first sample.

mod checks;

use crate::estimator::EstimatorStatus;
use crate::sample::{Sample, SensorData, SensorKind};
use crate::source_map::SourceMap;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

pub use checks::Observation;

pub use crate::verdict::{HealthState, Reason};

/// Thresholds (`[health]` in the config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HealthConfig {
    /// A condition counts (makes the state worse) once seen over this long, ms.
    pub confirm_ms: f64,
    /// A better state is adopted (a sensor taken back) after this long, ms; leaving
    /// `stale` or `no_data` needs no wait.
    pub recover_ms: f64,
    /// A condition stays active this long after it was last seen, ms.
    pub hold_ms: f64,
    /// Stale after this many expected periods without data (never under `stale_min_ms`).
    pub stale_periods: f64,
    pub stale_min_ms: f64,
    /// Degraded when the rate is below this fraction of the expected rate.
    pub rate_low_fraction: f64,
    /// Flow: quality (0–255) below this is failed (seed: flow_qual).
    pub flow_min_quality: u8,
    /// Flow: ToF strength below this is failed.
    pub tof_min_strength: u8,
    /// Flow: ToF limits, m.
    pub tof_min_m: f64,
    pub tof_max_m: f64,
    /// Flow: raw rate above this is degraded, rad/s.
    pub flow_max_rate: f64,
    /// Below this height flow and its quality are not judged (on the ground), m.
    pub flow_ground_m: f64,
    /// GNSS: horizontal variance above this is degraded, m² (seed: < 1.5 outdoors).
    pub gnss_degraded_var: f64,
    /// GNSS: horizontal variance above this is failed, m².
    pub gnss_failed_var: f64,
    pub gnss_min_satellites: u8,
    pub gnss_max_hdop: f64,
    /// GNSS: a step between fixes faster than this is a jump, m/s.
    pub gnss_max_speed: f64,
    /// Visual odometry covariance (position variance) at which it may be drifting.
    pub vo_degraded_var: f64,
    /// ... and at which it is unusable (T265: 0.01).
    pub vo_failed_var: f64,
    /// Odometry: a step larger than this not explained by its velocity is a jump, m.
    pub vo_jump_m: f64,
    /// IMU still vs odometry moving (or the reverse) beyond this speed, m/s.
    pub vo_imu_speed_mps: f64,
    /// ... for this long, ms.
    pub vo_imu_window_ms: f64,
    /// Innovation test ratio that warns (degraded) and that rejects (failed).
    pub test_ratio_warn: f64,
    pub test_ratio_fail: f64,
    /// An odometry's frame drifting faster than this against the fused estimate
    /// degrades it, m/s.
    pub vo_drift_warn_mps: f64,
    /// Estimator: position 1σ above this degrades the estimator, m.
    pub estimator_max_std_m: f64,
}

/// The rate is measured over this much of the newest arrivals, µs ...
const RATE_WINDOW_US: i64 = 2_000_000;
/// ... and over at least this many expected periods.
const RATE_PERIODS: f64 = 2.5;

pub const DEFAULT_CONFIRM_MS: f64 = 300.0;
pub const DEFAULT_RECOVER_MS: f64 = 3000.0;
pub const DEFAULT_HOLD_MS: f64 = 500.0;
/// The reasons a set of conditions gives.
fn reasons_of<'a>(
    conditions: impl IntoIterator<Item = (&'static str, &'a Condition)>,
) -> Vec<Reason> {
    conditions
        .into_iter()
        .map(|(code, c)| Reason {
            code,
            text: c.text.clone(),
        })
        .collect()
}

/// Conditions a single sample shows in full (a jump, a reset, a divergence): they count
/// at once, held for `hold_ms`, instead of waiting to be seen over `confirm_ms`.
const STEP_CODES: [&str; 4] = ["gnss_jump", "vo_jump", "vo_reset", "diverged"];
pub const DEFAULT_STALE_PERIODS: f64 = 5.0;
pub const DEFAULT_STALE_MIN_MS: f64 = 250.0;
pub const DEFAULT_RATE_LOW_FRACTION: f64 = 0.5;
pub const DEFAULT_FLOW_MIN_QUALITY: u8 = 50;
pub const DEFAULT_TOF_MIN_STRENGTH: u8 = 20;
pub const DEFAULT_TOF_MIN_M: f64 = 0.05;
pub const DEFAULT_TOF_MAX_M: f64 = 8.0;
pub const DEFAULT_FLOW_MAX_RATE: f64 = 4.0;
pub const DEFAULT_FLOW_GROUND_M: f64 = 0.15;
pub const DEFAULT_GNSS_DEGRADED_VAR: f64 = 1.5;
pub const DEFAULT_GNSS_FAILED_VAR: f64 = 25.0;
pub const DEFAULT_GNSS_MIN_SATELLITES: u8 = 6;
pub const DEFAULT_GNSS_MAX_HDOP: f64 = 2.5;
pub const DEFAULT_GNSS_MAX_SPEED: f64 = 25.0;
pub const DEFAULT_VO_DEGRADED_VAR: f64 = 0.001;
pub const DEFAULT_VO_FAILED_VAR: f64 = 0.01;
pub const DEFAULT_VO_JUMP_M: f64 = 0.3;
pub const DEFAULT_VO_IMU_SPEED_MPS: f64 = 0.3;
pub const DEFAULT_VO_IMU_WINDOW_MS: f64 = 3000.0;
pub const DEFAULT_TEST_RATIO_WARN: f64 = 0.5;
pub const DEFAULT_TEST_RATIO_FAIL: f64 = 1.0;
/// A T265 holding track drifts by centimetres a second; one that lost it slides by
/// decimetres.
pub const DEFAULT_VO_DRIFT_WARN_MPS: f64 = 0.1;
pub const DEFAULT_ESTIMATOR_MAX_STD_M: f64 = 2.0;

impl Default for HealthConfig {
    fn default() -> Self {
        Self {
            confirm_ms: DEFAULT_CONFIRM_MS,
            recover_ms: DEFAULT_RECOVER_MS,
            hold_ms: DEFAULT_HOLD_MS,
            stale_periods: DEFAULT_STALE_PERIODS,
            stale_min_ms: DEFAULT_STALE_MIN_MS,
            rate_low_fraction: DEFAULT_RATE_LOW_FRACTION,
            flow_min_quality: DEFAULT_FLOW_MIN_QUALITY,
            tof_min_strength: DEFAULT_TOF_MIN_STRENGTH,
            tof_min_m: DEFAULT_TOF_MIN_M,
            tof_max_m: DEFAULT_TOF_MAX_M,
            flow_max_rate: DEFAULT_FLOW_MAX_RATE,
            flow_ground_m: DEFAULT_FLOW_GROUND_M,
            gnss_degraded_var: DEFAULT_GNSS_DEGRADED_VAR,
            gnss_failed_var: DEFAULT_GNSS_FAILED_VAR,
            gnss_min_satellites: DEFAULT_GNSS_MIN_SATELLITES,
            gnss_max_hdop: DEFAULT_GNSS_MAX_HDOP,
            gnss_max_speed: DEFAULT_GNSS_MAX_SPEED,
            vo_degraded_var: DEFAULT_VO_DEGRADED_VAR,
            vo_failed_var: DEFAULT_VO_FAILED_VAR,
            vo_jump_m: DEFAULT_VO_JUMP_M,
            vo_imu_speed_mps: DEFAULT_VO_IMU_SPEED_MPS,
            vo_imu_window_ms: DEFAULT_VO_IMU_WINDOW_MS,
            test_ratio_warn: DEFAULT_TEST_RATIO_WARN,
            test_ratio_fail: DEFAULT_TEST_RATIO_FAIL,
            vo_drift_warn_mps: DEFAULT_VO_DRIFT_WARN_MPS,
            estimator_max_std_m: DEFAULT_ESTIMATOR_MAX_STD_M,
        }
    }
}

impl HealthConfig {
    pub fn validate(&self) -> Result<(), String> {
        for (k, v) in [
            ("confirm_ms", self.confirm_ms),
            ("recover_ms", self.recover_ms),
            ("hold_ms", self.hold_ms),
            ("stale_periods", self.stale_periods),
            ("stale_min_ms", self.stale_min_ms),
            ("gnss_max_speed", self.gnss_max_speed),
            ("test_ratio_fail", self.test_ratio_fail),
            ("vo_drift_warn_mps", self.vo_drift_warn_mps),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("health.{k} = {v} must be positive"));
            }
        }
        if self.test_ratio_warn > self.test_ratio_fail {
            return Err("health.test_ratio_warn must not exceed test_ratio_fail".into());
        }
        Ok(())
    }
}

/// An active condition on a sensor.
#[derive(Debug, Clone)]
struct Condition {
    state: HealthState,
    text: String,
    /// First and last time seen in this run (a run ends when the hold lapses).
    first_us: i64,
    last_us: i64,
}

/// One sensor's health.
#[derive(Debug, Clone)]
pub struct SensorHealth {
    pub id: String,
    pub kind: Option<SensorKind>,
    pub expected_rate_hz: f64,
    pub state: HealthState,
    pub reasons: Vec<Reason>,
    pub since_us: Option<i64>,
    conditions: BTreeMap<&'static str, Condition>,
    /// Raw state and since when (for hysteresis).
    pending: Option<(HealthState, i64)>,
    pub last_sample_us: Option<i64>,
    arrivals: std::collections::VecDeque<i64>,
    pub checks: checks::SensorMemory,
    pub disabled: bool,
    /// Innovation test ratio low-passed (warnings on single spikes would flap).
    pub test_ratio_lp: Option<(i64, f64)>,
    /// The estimator's counts of tested samples and of those over the gate at the
    /// last look.
    tests_seen: Option<(u64, u64)>,
}

/// Time constant of the low-passed test ratio that raises warnings, s.
const TEST_RATIO_TAU_S: f64 = 1.0;

/// Health reasons that only say a source disagrees with the estimate.
pub const INNOVATION_CODES: [&str; 2] = ["innovation_rejected", "innovation_high"];

/// A state change, for the event log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Transition {
    pub time_us: i64,
    pub sensor: String,
    pub from: HealthState,
    pub to: HealthState,
    pub reasons: Vec<Reason>,
}

impl Transition {
    pub fn message(&self) -> String {
        let why: Vec<String> = self
            .reasons
            .iter()
            .map(|r| format!("{}: {}", r.code, r.text))
            .collect();
        format!(
            "{}: {} -> {}{}",
            self.sensor,
            self.from.as_str(),
            self.to.as_str(),
            if why.is_empty() {
                String::new()
            } else {
                format!(" ({})", why.join("; "))
            }
        )
    }
}

/// The health of every sensor.
#[derive(Debug, Clone)]
pub struct HealthMonitor {
    cfg: HealthConfig,
    sensors: SourceMap<SensorHealth>,
    /// Last IMU sample time and the last time the IMU showed motion.
    imu_last_us: Option<i64>,
    imu_moving_us: Option<i64>,
    /// Last height above ground from a range finder or flow ToF: (time, m).
    height: Option<(i64, f64)>,
}

/// The IMU counts as still after this long without motion, µs.
const IMU_STILL_AFTER_US: i64 = 1_000_000;
/// Stillness thresholds: gyro rad/s, |specific force| − g in m/s².
const IMU_STILL_GYRO: f64 = 0.05;
const IMU_STILL_ACCEL: f64 = 0.25;

/// One configured input as the health layer sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct InputSpec {
    pub id: String,
    pub kind: SensorKind,
    /// Expected rate, Hz (staleness and low-rate checks).
    pub rate_hz: f64,
    pub enabled: bool,
}

impl InputSpec {
    /// An enabled input.
    pub fn new(id: impl Into<String>, kind: SensorKind, rate_hz: f64) -> Self {
        Self {
            id: id.into(),
            kind,
            rate_hz,
            enabled: true,
        }
    }
}

/// The name of the estimator's own health entry.
pub const ESTIMATOR_ID: &str = "estimator";

impl HealthMonitor {
    pub fn new(cfg: HealthConfig, sensors: &[InputSpec]) -> Self {
        let mut map = SourceMap::new();
        for s in sensors {
            map.put(
                &s.id,
                SensorHealth::new(&s.id, Some(s.kind), s.rate_hz, !s.enabled),
            );
        }
        map.put(
            ESTIMATOR_ID,
            SensorHealth::new(ESTIMATOR_ID, None, 0.0, false),
        );
        Self {
            cfg,
            sensors: map,
            imu_last_us: None,
            imu_moving_us: None,
            height: None,
        }
    }

    pub fn config(&self) -> &HealthConfig {
        &self.cfg
    }

    pub fn sensor(&self, id: &str) -> Option<&SensorHealth> {
        self.sensors.get(id)
    }

    pub fn sensors(&self) -> impl Iterator<Item = &SensorHealth> {
        self.sensors.values()
    }

    /// Whether the estimator may fuse `id` (unknown sensors are not judged).
    pub fn usable(&self, id: &str) -> bool {
        self.sensors.get(id).is_none_or(|s| s.state.usable())
    }

    /// Whether the estimator may fuse `id`, whatever its disagreement with the
    /// estimate: a source failed only for its innovations stays the estimator's to
    /// judge (its gate, the integrity monitor's exclusion, the rule against locking out
    /// the only source). Taken away by health, it could never show that the estimate,
    /// not the source, had gone wrong.
    pub fn fusable(&self, id: &str) -> bool {
        let Some(s) = self.sensors.get(id) else {
            return true;
        };
        if !s.state.usable() && s.conditions.is_empty() {
            // No data, stale, disabled: nothing to fuse anyway.
            return false;
        }
        if matches!(
            s.state,
            HealthState::NoData | HealthState::Stale | HealthState::Disabled
        ) {
            return false;
        }
        s.conditions
            .iter()
            .filter(|(code, _)| !INNOVATION_CODES.contains(*code))
            .map(|(_, c)| c.state)
            .max_by_key(|st| st.rank())
            .unwrap_or(HealthState::Ok)
            .usable()
    }

    /// A sample arrived and passed decoding (time `t`: host µs).
    pub fn on_sample(&mut self, s: &Sample, t: i64) {
        let cfg = &self.cfg;
        let Some(h) = self.sensors.get_mut(s.source.as_ref()) else {
            return;
        };
        h.last_sample_us = Some(t);
        h.arrivals.push_back(t);
        // ~2 s, and at least 2.5 expected periods: a 1 Hz input keeps two arrivals.
        let window = if h.expected_rate_hz > 0.0 {
            (RATE_PERIODS * 1e6 / h.expected_rate_hz).max(RATE_WINDOW_US as f64) as i64
        } else {
            RATE_WINDOW_US
        };
        while h.arrivals.front().is_some_and(|&a| t - a > window) {
            h.arrivals.pop_front();
        }
        let mut found = checks::check_sample(cfg, &mut h.checks, &s.data, t);
        match &s.data {
            SensorData::Imu(imu) => {
                // Still: no rotation and specific force of gravity alone, tightly (cruise at
                // constant velocity also looks like this, hence the long window).
                let moving = imu.gyro.is_some_and(|g| g.norm() > IMU_STILL_GYRO)
                    || imu.accel.is_some_and(|a| {
                        (a.norm() - crate::estimator::ekf::GRAVITY).abs() > IMU_STILL_ACCEL
                    });
                self.imu_last_us = Some(t);
                if moving || self.imu_moving_us.is_none() {
                    self.imu_moving_us = Some(t);
                }
            }
            SensorData::Range(r) => self.height = Some((t, r.distance_m)),
            SensorData::Flow(f) => {
                if let Some(tof) = &f.tof {
                    self.height = Some((t, tof.distance_m));
                }
            }
            SensorData::Odometry(o) => {
                // Judged on the ground only: in flight a vehicle at constant velocity
                // looks still to an IMU, and the EKF's innovation test already
                // compares odometry with the IMU-driven prediction.
                let on_ground = self
                    .height
                    .is_some_and(|(ht, h)| t - ht < 500_000 && h < cfg.flow_ground_m);
                let imu_fresh = self.imu_last_us.is_some_and(|l| t - l < 200_000);
                let still = on_ground
                    && imu_fresh
                    && self
                        .imu_moving_us
                        .is_some_and(|m| t - m > IMU_STILL_AFTER_US);
                let speed = o.velocity.map(|v| v.norm()).unwrap_or(0.0);
                found.extend(checks::vo_imu_consistency(
                    cfg,
                    &mut h.checks,
                    speed,
                    still,
                    t,
                ));
            }
            _ => {}
        }
        for o in found {
            h.raise(o, t);
        }
    }

    /// A sample of `id` was rejected before fusion (malformed, NaN, time backwards).
    pub fn on_rejected(&mut self, id: &str, code: &'static str, text: &str, t: i64) {
        if let Some(h) = self.sensors.get_mut(id) {
            h.raise(
                Observation {
                    code,
                    state: HealthState::Failed,
                    text: text.to_string(),
                },
                t,
            );
        }
    }

    /// What the estimator says about its sources and itself.
    pub fn on_estimator(&mut self, st: &EstimatorStatus, t: i64) {
        let cfg = self.cfg.clone();
        for (id, src) in &st.sources {
            let Some(h) = self.sensors.get_mut(id) else {
                continue;
            };
            // Only judge a test ratio that is fresh.
            if src.last_time_us.is_none_or(|lt| t - lt > 500_000) || src.innovation.is_empty() {
                continue;
            }
            if let Some(d) = src.drift_mps.filter(|d| *d > cfg.vo_drift_warn_mps) {
                h.raise(
                    Observation {
                        code: "vo_drift",
                        state: HealthState::Degraded,
                        text: format!(
                            "odometry frame drifting at {d:.2} m/s against the fused estimate (> {} m/s)",
                            cfg.vo_drift_warn_mps
                        ),
                    },
                    t,
                );
            }
            let lp = match h.test_ratio_lp {
                Some((t0, v)) if t > t0 => {
                    let dt = (t - t0) as f64 * 1e-6;
                    v + (src.test_ratio - v) * dt / (TEST_RATIO_TAU_S + dt)
                }
                Some((_, v)) => v,
                None => src.test_ratio,
            };
            h.test_ratio_lp = Some((t, lp));
            // Rejected means most of the samples tested since the last look were over
            // the gate, not the latest one alone: a look sees a single sample, and a
            // source that mostly agrees (two flow sensors at take-off, while the
            // estimate settles) is the filter's to gate sample by sample. Taken out,
            // it could leave nothing to aid the estimate.
            let (tested, over) = match h.tests_seen.replace((src.tested, src.tested_over_gate)) {
                Some((n, o)) => (
                    src.tested.saturating_sub(n),
                    src.tested_over_gate.saturating_sub(o),
                ),
                None => (src.tested, src.tested_over_gate),
            };
            if src.test_ratio > cfg.test_ratio_fail && 2 * over > tested {
                h.raise(
                    Observation {
                        code: "innovation_rejected",
                        state: HealthState::Failed,
                        text: format!(
                            "innovation test ratio {:.2} > {:.1} ({over} of {tested} samples over the gate): disagrees with the other sources",
                            src.test_ratio, cfg.test_ratio_fail
                        ),
                    },
                    t,
                );
            } else if lp > cfg.test_ratio_warn {
                h.raise(
                    Observation {
                        code: "innovation_high",
                        state: HealthState::Degraded,
                        text: format!(
                            "innovation test ratio {lp:.2} (1 s mean) > {:.1}",
                            cfg.test_ratio_warn
                        ),
                    },
                    t,
                );
            }
        }
        if let Some(h) = self.sensors.get_mut(ESTIMATOR_ID) {
            h.last_sample_us = Some(t);
            if st.initialised && !st.valid {
                h.raise(
                    Observation {
                        code: "estimate_invalid",
                        state: HealthState::Failed,
                        text: st
                            .invalid_reason
                            .clone()
                            .unwrap_or_else(|| "invalid".into()),
                    },
                    t,
                );
            }
            if let Some(std) = st.position_std {
                let m = std[0].max(std[1]);
                if m > cfg.estimator_max_std_m {
                    h.raise(
                        Observation {
                            code: "covariance_growth",
                            state: HealthState::Degraded,
                            text: format!(
                                "horizontal position 1σ {m:.2} m > {:.1} m",
                                cfg.estimator_max_std_m
                            ),
                        },
                        t,
                    );
                }
            }
        }
    }

    /// The estimator reset or replaced its filter (a divergence monitor tripped).
    pub fn on_divergence(&mut self, text: &str, t: i64) {
        if let Some(h) = self.sensors.get_mut(ESTIMATOR_ID) {
            h.raise(
                Observation {
                    code: "diverged",
                    state: HealthState::Degraded,
                    text: text.to_string(),
                },
                t,
            );
        }
    }

    /// Re-evaluate every sensor at time `t`; returns the state changes.
    pub fn evaluate(&mut self, t: i64) -> Vec<Transition> {
        let cfg = self.cfg.clone();
        let mut out = Vec::new();
        for h in self.sensors.values_mut() {
            if let Some(tr) = h.evaluate(&cfg, t) {
                out.push(tr);
            }
        }
        out
    }
}

impl SensorHealth {
    fn new(id: &str, kind: Option<SensorKind>, rate: f64, disabled: bool) -> Self {
        Self {
            id: id.to_string(),
            kind,
            expected_rate_hz: rate,
            state: if disabled {
                HealthState::Disabled
            } else {
                HealthState::NoData
            },
            reasons: vec![],
            since_us: None,
            conditions: BTreeMap::new(),
            pending: None,
            last_sample_us: None,
            arrivals: Default::default(),
            checks: Default::default(),
            disabled,
            test_ratio_lp: None,
            tests_seen: None,
        }
    }

    fn raise(&mut self, o: Observation, t: i64) {
        let c = self.conditions.entry(o.code).or_insert(Condition {
            state: o.state,
            text: o.text.clone(),
            first_us: t,
            last_us: t,
        });
        c.last_us = t;
        c.text = o.text;
        c.state = c.state.max(o.state);
    }

    /// Measured rate over the last ~2 s (at least 2.5 expected periods), Hz: the
    /// arrivals' own spacing, lower once the time since the last one outgrows it. (The
    /// time since the first arrival alone counts a partial period: a 1 Hz input read
    /// 0.9 s after a sample measured 0.5 Hz.)
    pub fn rate_hz(&self, t: i64) -> f64 {
        match (
            self.arrivals.front(),
            self.arrivals.back(),
            self.arrivals.len(),
        ) {
            (Some(&first), Some(&last), n) if n >= 2 && last > first => {
                let spaced = (n - 1) as f64 * 1e6 / (last - first) as f64;
                let with_silence = n as f64 * 1e6 / (t.max(last) - first) as f64;
                spaced.min(with_silence)
            }
            _ => 0.0,
        }
    }

    fn raw(&mut self, cfg: &HealthConfig, t: i64) -> (HealthState, Vec<Reason>) {
        if self.disabled {
            return (HealthState::Disabled, vec![]);
        }
        let mut hold = cfg.hold_ms * 1e3;
        if self.expected_rate_hz > 0.0 {
            hold = hold.max(2.5e6 / self.expected_rate_hz);
        }
        let hold = hold as i64;
        self.conditions.retain(|_, c| t - c.last_us <= hold);
        let Some(last) = self.last_sample_us else {
            // Nothing usable yet: if everything so far was rejected, say why.
            if !self.conditions.is_empty() {
                return (HealthState::Failed, self.condition_reasons());
            }
            return (
                HealthState::NoData,
                vec![Reason {
                    code: "no_data",
                    text: "nothing received yet".into(),
                }],
            );
        };
        if self.id != ESTIMATOR_ID && self.expected_rate_hz > 0.0 {
            let stale_us = ((cfg.stale_periods * 1e6 / self.expected_rate_hz)
                .max(cfg.stale_min_ms * 1e3)) as i64;
            if t - last > stale_us {
                return (
                    HealthState::Stale,
                    vec![Reason {
                        code: "stale",
                        text: format!("no data for {} ms", (t - last) / 1000),
                    }],
                );
            }
            // Rate needs a full window to be meaningful.
            let window_full = self.arrivals.front().is_some_and(|&f| t - f >= 1_500_000)
                || self.arrivals.len() as f64 >= self.expected_rate_hz * 1.5;
            let rate = self.rate_hz(t);
            if window_full && rate < cfg.rate_low_fraction * self.expected_rate_hz {
                let text = format!("{rate:.1} Hz, expected {:.0} Hz", self.expected_rate_hz);
                self.raise(
                    Observation {
                        code: "rate_low",
                        state: HealthState::Degraded,
                        text,
                    },
                    t,
                );
            }
        }
        let confirm = (cfg.confirm_ms * 1e3) as i64;
        let state = self.state;
        let counting: Vec<(&'static str, &Condition)> = self
            .conditions
            .iter()
            .filter(|(code, c)| {
                STEP_CODES.contains(code)
                    || c.last_us - c.first_us >= confirm
                    || c.state.rank() <= state.rank()
            })
            .map(|(code, c)| (*code, c))
            .collect();
        let worst = counting
            .iter()
            .map(|(_, c)| c.state)
            .max_by_key(|s| s.rank())
            .unwrap_or(HealthState::Ok);
        (worst, reasons_of(counting))
    }

    fn condition_reasons(&self) -> Vec<Reason> {
        reasons_of(self.conditions.iter().map(|(code, c)| (*code, c)))
    }

    fn evaluate(&mut self, cfg: &HealthConfig, t: i64) -> Option<Transition> {
        let (raw, reasons) = self.raw(cfg, t);
        if raw == self.state {
            self.pending = None;
            self.reasons = reasons;
            return None;
        }
        let since = match self.pending {
            Some((s, since)) if s == raw => since,
            _ => {
                self.pending = Some((raw, t));
                t
            }
        };
        // Leaving no_data/stale needs no wait: data is back, and what it shows is judged
        // by the checks from its first sample (a link that came back after a Zenoh
        // router restart must not hold every sensor out for `recover_ms`). Going worse
        // needs no wait either (a condition counts only once seen over `confirm_ms`);
        // getting better waits `recover_ms`.
        let wait_ms = if matches!(self.state, HealthState::NoData | HealthState::Stale)
            || raw.rank() > self.state.rank()
        {
            0.0
        } else {
            cfg.recover_ms
        };
        if ((t - since) as f64) < wait_ms * 1e3 {
            return None;
        }
        let from = self.state;
        self.state = raw;
        self.since_us = Some(t);
        self.pending = None;
        self.reasons = reasons.clone();
        Some(Transition {
            time_us: t,
            sensor: self.id.clone(),
            from,
            to: raw,
            reasons,
        })
    }
}

#[cfg(test)]
mod tests;
