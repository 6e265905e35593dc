//! Randomised flights: each draw is its own vehicle, sensors and flight, flown through
//! the same default configuration (`skyfuse sim --monte-carlo N --seed S`). What is
//! drawn, per the integrity issue:
//!
//! - the sensors on board, always an IMU and the autopilot's attitude, and at least one
//!   horizontal source among optical flow (with its own ToF or a range finder), GNSS
//!   and a visual odometry; a barometer most of the time;
//! - their rates (flow 5-100 Hz, IMU 40-1000 Hz, attitude 9-250 Hz, range 10-100 Hz,
//!   barometer 5-50 Hz, GNSS 1-10 Hz, odometry 15-200 Hz, log-uniform);
//! - time offsets the configuration does not know: every aiding stream arrives
//!   0-300 ms later than its kind's default latency says (the attitude 0-50 ms);
//! - the flow's scale error (±15 %), mounting yaw (±5°), noise and dark-ground
//!   stretches (quality drops, reads slow and noisy); accelerometer bias up to 1 m/s²
//!   and gyro bias up to 0.02 rad/s; the autopilot's heading error (up to 15°, wandering
//!   over 1-10 min: magnetic disturbance); the barometer's drift, prop-wash step and
//!   speed error; a range finder (sonar to 3-5 m or lidar to 8-40 m) that reports
//!   spurious short readings flagged good when out of range; GNSS multipath offsets
//!   (3-15 m, not in the accuracy the receiver reports) and outages, its reported
//!   accuracy (0.5-2.5 m) and the wander of its slow error (30-300 s); dropouts of any
//!   stream;
//! - the flight: a hover, laps, a figure-eight or a climb beyond the range finder,
//!   2-15 min, at up to 5 m/s.
//!
//! Everything comes from the draw's seed, so a failing draw is reproduced by its
//! number alone.

use super::faults::{Fault, FaultKind, ACCEL_OFFSET_MPS2};
use super::plan::{FlightPlan, PlanKind};
use super::scenario::Scenario;
use super::sensors::{DarkGround, Hardware, Multipath, StreamSpec, YawError};
use super::truth::Profile;
use crate::estimator::config as defaults;
use crate::sample::SensorKind;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

/// The largest unknown delay of an aiding stream, s.
pub const MAX_UNKNOWN_DELAY_S: f64 = 0.3;
/// The largest unknown delay of the attitude, s.
pub const MAX_ATTITUDE_DELAY_S: f64 = 0.05;

/// One randomised vehicle and flight.
#[derive(Debug, Clone)]
pub struct Draw {
    /// The draw's own seed (the run's seed and its index).
    pub seed: u64,
    pub plan: FlightPlan,
    pub streams: Vec<StreamSpec>,
    pub hardware: Hardware,
    pub faults: Vec<Fault>,
    /// The unknown delay of each stream beyond its kind's default latency, s.
    pub unknown_delay_s: Vec<(&'static str, f64)>,
}

/// The seed of draw `index` of a run seeded `seed`.
pub fn draw_seed(seed: u64, index: u64) -> u64 {
    // SplitMix64 of the pair: neighbouring indices give unrelated draws.
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(index.wrapping_add(1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn log_uniform(rng: &mut SmallRng, lo: f64, hi: f64) -> f64 {
    (lo.ln() + (hi.ln() - lo.ln()) * rng.gen::<f64>()).exp()
}

fn uniform(rng: &mut SmallRng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

/// A default latency of the kind, s (what the default configuration assumes).
fn default_latency_s(kind: SensorKind) -> f64 {
    let ms = match kind {
        SensorKind::Imu => defaults::DEFAULT_LATENCY_MS_IMU,
        SensorKind::Attitude => defaults::DEFAULT_LATENCY_MS_ATTITUDE,
        SensorKind::Odometry => defaults::DEFAULT_LATENCY_MS_ODOMETRY,
        SensorKind::Flow => defaults::DEFAULT_LATENCY_MS_FLOW,
        SensorKind::Range => defaults::DEFAULT_LATENCY_MS_RANGE,
        SensorKind::Gnss => defaults::DEFAULT_LATENCY_MS_GNSS,
        SensorKind::Baro => defaults::DEFAULT_LATENCY_MS_BARO,
        SensorKind::AutopilotEstimate | SensorKind::VehicleState => 0.0,
    };
    ms * 1e-3
}

/// The default configuration's input id of each kind.
fn input_id(kind: SensorKind) -> &'static str {
    match kind {
        SensorKind::Imu => "imu",
        SensorKind::Attitude => "attitude",
        SensorKind::Odometry => "t265",
        SensorKind::Flow => "flow",
        SensorKind::Range => "rangefinder",
        SensorKind::Gnss => "gps",
        SensorKind::Baro => "baro",
        SensorKind::AutopilotEstimate => "autopilot",
        SensorKind::VehicleState => "vehicle",
    }
}

/// Faults beyond what the integrity issue draws, each from its own random stream so
/// that a draw is the same flight with and without them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stress {
    /// One flight in [`1 / ACCEL_STEP_SHARE`](ACCEL_STEP_SHARE) gets an accelerometer
    /// that steps by [`ACCEL_OFFSET_MPS2`](super::faults::ACCEL_OFFSET_MPS2) along the
    /// body's forward axis at a random time and stays so (a knock that shifted its
    /// mount): `skyfuse sim --monte-carlo N --accel-steps`.
    pub accel_steps: bool,
}

/// The share of flights that get an accelerometer step under [`Stress::accel_steps`].
pub const ACCEL_STEP_SHARE: f64 = 0.2;
/// Mixed into the draw's seed for the accelerometer step's own stream.
const ACCEL_STEP_STREAM: u64 = 0x0acc_e15e_5dab_0001;

/// Draw vehicle, sensors and flight number `index` of a run seeded `seed`.
pub fn draw(seed: u64, index: u64) -> Draw {
    draw_stressed(seed, index, Stress::default())
}

/// [`draw`], with the faults of `stress` on top.
pub fn draw_stressed(seed: u64, index: u64, stress: Stress) -> Draw {
    let seed = draw_seed(seed, index);
    let mut rng = SmallRng::seed_from_u64(seed);
    let rng = &mut rng;

    // Which sensors: at least one horizontal source.
    let mut flow = rng.gen_bool(0.8);
    let gnss = rng.gen_bool(0.5);
    let vio = rng.gen_bool(0.3);
    if !(flow || gnss || vio) {
        flow = true;
    }
    let flow_tof = flow && rng.gen_bool(0.4);
    let range = (flow && !flow_tof) || rng.gen_bool(0.4);
    let baro = rng.gen_bool(0.8);

    let kind = PlanKind::ALL[rng.gen_range(0..PlanKind::ALL.len())];
    let sonar = rng.gen_bool(0.5);
    let (range_min, range_max) = if sonar {
        (uniform(rng, 0.2, 0.3), uniform(rng, 3.0, 5.0))
    } else {
        (uniform(rng, 0.05, 0.2), uniform(rng, 8.0, 40.0))
    };
    let height_m = uniform(rng, 1.0, 4.0);
    // The highest any height sensor on board reaches (the flow module's ToF: 8 m).
    let reach = match (range, flow_tof) {
        (true, true) => range_max.max(8.0),
        (true, false) => range_max,
        _ => 8.0,
    };
    let plan = FlightPlan {
        kind,
        duration_s: uniform(rng, 120.0, 900.0),
        height_m,
        speed_mps: uniform(rng, 0.5, 5.0),
        size_m: match kind {
            PlanKind::Hover => uniform(rng, 0.1, 2.0),
            PlanKind::Laps => uniform(rng, 5.0, 40.0),
            PlanKind::Figure8 | PlanKind::Climb | PlanKind::Square => uniform(rng, 6.0, 60.0),
        },
        climb_to_m: reach + uniform(rng, 2.0, 10.0),
        yaw_swing_rad: uniform(rng, 0.0, 1.5),
        yaw0_rad: uniform(rng, -PI, PI),
    };

    // Streams: rates, and delays beyond what the configuration assumes.
    let mut streams = Vec::new();
    let mut unknown_delay_s = Vec::new();
    let mut stream = |rng: &mut SmallRng, kind: SensorKind, lo: f64, hi: f64, max_delay: f64| {
        let rate_hz = log_uniform(rng, lo, hi);
        let extra = uniform(rng, 0.0, max_delay);
        let id = input_id(kind);
        unknown_delay_s.push((id, extra));
        streams.push(StreamSpec {
            input_id: id,
            kind,
            rate_hz,
            delay_s: default_latency_s(kind) + extra,
        });
        rate_hz
    };
    stream(rng, SensorKind::Imu, 40.0, 1000.0, 0.0);
    stream(rng, SensorKind::Attitude, 9.0, 250.0, MAX_ATTITUDE_DELAY_S);
    let flow_hz = flow.then(|| stream(rng, SensorKind::Flow, 5.0, 100.0, MAX_UNKNOWN_DELAY_S));
    if range {
        stream(rng, SensorKind::Range, 10.0, 100.0, MAX_UNKNOWN_DELAY_S);
    }
    if baro {
        stream(rng, SensorKind::Baro, 5.0, 50.0, MAX_UNKNOWN_DELAY_S);
    }
    if gnss {
        stream(rng, SensorKind::Gnss, 1.0, 10.0, MAX_UNKNOWN_DELAY_S);
    }
    if vio {
        stream(rng, SensorKind::Odometry, 15.0, 200.0, MAX_UNKNOWN_DELAY_S);
    }

    // How each sensor errs.
    let unit = |rng: &mut SmallRng| {
        let z: f64 = uniform(rng, -1.0, 1.0);
        let a = uniform(rng, 0.0, 2.0 * PI);
        let r = (1.0 - z * z).sqrt();
        nalgebra::Vector3::new(r * a.cos(), r * a.sin(), z)
    };
    let accel_bias = unit(rng) * uniform(rng, 0.0, 1.0);
    let gyro_bias = unit(rng) * uniform(rng, 0.0, 0.02);
    let yaw_bias = uniform(rng, -10.0, 10.0).to_radians();
    let yaw_error = YawError {
        bias_rad: yaw_bias,
        amplitude_rad: uniform(rng, 0.0, 15f64.to_radians() - yaw_bias.abs()),
        period_s: uniform(rng, 60.0, 600.0),
        phase_rad: uniform(rng, 0.0, 2.0 * PI),
    };
    let duration = plan.duration_s;
    let mut gnss_multipath = [Multipath::default(); 3];
    if gnss {
        for m in gnss_multipath.iter_mut().take(rng.gen_range(0..=3)) {
            let a = uniform(rng, 0.0, 2.0 * PI);
            let size = uniform(rng, 3.0, 15.0);
            *m = Multipath {
                start_s: uniform(rng, 20.0, duration),
                duration_s: uniform(rng, 5.0, 60.0),
                offset: [size * a.cos(), size * a.sin(), uniform(rng, -5.0, 5.0)],
            };
        }
    }
    let gnss_h = uniform(rng, 0.5, 2.5);
    let mut dark_ground = [DarkGround::default(); 3];
    if flow {
        for g in dark_ground.iter_mut().take(rng.gen_range(0..=3)) {
            *g = DarkGround {
                start_s: uniform(rng, 10.0, duration),
                duration_s: uniform(rng, 2.0, 20.0),
                quality: (10, uniform(rng, 40.0, 120.0) as u8),
                scale: uniform(rng, 0.3, 1.0),
                noise_factor: uniform(rng, 2.0, 8.0),
            };
        }
    }
    let hardware = Hardware {
        range_min_m: range_min,
        range_max_m: range_max,
        range_spurious: if sonar {
            uniform(rng, 0.0, 0.1)
        } else {
            uniform(rng, 0.0, 0.02)
        },
        flow_tof,
        flow_scale: uniform(rng, 0.85, 1.15),
        flow_integration_s: 1.0 / flow_hz.unwrap_or(50.0),
        flow_mount_yaw_rad: uniform(rng, -5.0, 5.0).to_radians(),
        flow_rate_noise: uniform(rng, 0.01, 0.05),
        accel_bias: Some(accel_bias),
        gyro_bias: Some(gyro_bias),
        yaw_error,
        baro_drift_rw: uniform(rng, 0.005, 0.05),
        baro_wash_m: uniform(rng, -1.0, 1.0),
        baro_speed_coef: uniform(rng, 0.0, 0.05),
        vio_drift_rw: uniform(rng, 0.002, 0.02),
        gnss_std_m: (gnss_h, gnss_h * uniform(rng, 1.3, 2.0)),
        gnss_bias_tau_s: uniform(rng, 30.0, 300.0),
        gnss_multipath,
        dark_ground,
    };

    // Dropouts of any stream, GNSS outages.
    let mut faults = Vec::new();
    for s in &streams {
        let (count, longest) = match s.kind {
            SensorKind::Imu => (usize::from(rng.gen_bool(0.1)), 0.5),
            _ => (rng.gen_range(0..=2), 10.0),
        };
        for _ in 0..count {
            let start = uniform(rng, 10.0, duration);
            faults.push(Fault {
                sensor: s.input_id.to_string(),
                kind: FaultKind::Stop,
                start_s: start,
                end_s: start + uniform(rng, 0.2, longest),
            });
        }
    }
    if gnss {
        for _ in 0..rng.gen_range(0..=2) {
            let start = uniform(rng, 20.0, duration);
            faults.push(Fault {
                sensor: "gps".into(),
                kind: FaultKind::NoFix,
                start_s: start,
                end_s: start + uniform(rng, 5.0, 60.0),
            });
        }
    }
    if stress.accel_steps {
        // Its own stream: every other figure of the draw stays what it was without.
        let mut step = SmallRng::seed_from_u64(seed ^ ACCEL_STEP_STREAM);
        if step.gen_bool(ACCEL_STEP_SHARE) {
            faults.push(Fault {
                sensor: input_id(SensorKind::Imu).to_string(),
                kind: FaultKind::AccelOffset,
                start_s: uniform(&mut step, 20.0, (duration - 20.0).max(21.0)),
                end_s: f64::INFINITY,
            });
        }
    }
    faults.sort_by(|a, b| a.start_s.total_cmp(&b.start_s));
    Draw {
        seed,
        plan,
        streams,
        hardware,
        faults,
        unknown_delay_s,
    }
}

impl Draw {
    /// As a scenario: the flight, its streams, hardware and faults.
    pub fn scenario(&self) -> Scenario {
        Scenario {
            name: "monte-carlo",
            description: "a randomised vehicle and flight",
            profile: Profile::Plan(self.plan),
            streams: self.streams.clone(),
            faults: self.faults.clone(),
            hardware: self.hardware,
        }
    }

    /// How long to fly: the flight and a few seconds on the ground after it.
    pub fn duration_s(&self) -> f64 {
        self.plan.loop_s()
    }

    fn has(&self, kind: SensorKind) -> bool {
        self.streams.iter().any(|s| s.kind == kind)
    }

    /// The sources that hold the horizontal position or velocity, `+`-joined.
    pub fn horizontal_sources(&self) -> String {
        let mut h = Vec::new();
        if self.has(SensorKind::Flow) {
            h.push("flow");
        }
        if self.has(SensorKind::Gnss) {
            h.push("gnss");
        }
        if self.has(SensorKind::Odometry) {
            h.push("vio");
        }
        h.join("+")
    }

    /// The scenario family: the flight's kind and the horizontal sources.
    pub fn family(&self) -> String {
        format!(
            "{} / {}",
            self.plan.kind.as_str(),
            self.horizontal_sources()
        )
    }

    /// Whether the frame is absolute (a GNSS on board), else the vehicle's own from
    /// its start (scored registered at the first valid pose).
    pub fn absolute(&self) -> bool {
        self.has(SensorKind::Gnss)
    }

    /// One line: what was drawn.
    pub fn describe(&self) -> String {
        let rates: Vec<String> = self
            .streams
            .iter()
            .map(|s| {
                let extra = self
                    .unknown_delay_s
                    .iter()
                    .find(|(id, _)| *id == s.input_id)
                    .map_or(0.0, |d| d.1);
                format!("{} {:.0} Hz +{:.0} ms", s.input_id, s.rate_hz, extra * 1e3)
            })
            .collect();
        let h = &self.hardware;
        let p = &self.plan;
        format!(
            "{} {:.0} s at {:.1} m, {:.1} m/s, size {:.1} m{}; {}; flow scale {:.3} mount {:.1}°{}; accel bias {:.2} m/s²{}; yaw error {:.1}° ± {:.1}°; range {:.2}-{:.1} m ({:.0} % spurious); {} faults",
            p.kind.as_str(),
            p.duration_s,
            p.height_m,
            p.speed_mps,
            p.size_m,
            if p.kind == PlanKind::Climb {
                format!(", up to {:.1} m", p.climb_to_m)
            } else {
                String::new()
            },
            rates.join(", "),
            h.flow_scale,
            h.flow_mount_yaw_rad.to_degrees(),
            if h.flow_tof { " (own ToF)" } else { "" },
            h.accel_bias.map_or(0.0, |b| b.norm()),
            self.faults
                .iter()
                .find(|f| f.kind == FaultKind::AccelOffset)
                .map_or_else(String::new, |f| format!(
                    ", stepping {ACCEL_OFFSET_MPS2} m/s² at {:.0} s",
                    f.start_s
                )),
            h.yaw_error.bias_rad.to_degrees(),
            h.yaw_error.amplitude_rad.to_degrees(),
            h.range_min_m,
            h.range_max_m,
            h.range_spurious * 100.0,
            self.faults.len(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_reproducible_varied_and_within_the_stated_ranges() {
        let a = draw(7, 3);
        let b = draw(7, 3);
        assert_eq!(a.describe(), b.describe());
        assert_ne!(draw(7, 4).describe(), a.describe());
        let mut kinds = std::collections::BTreeSet::new();
        for i in 0..200 {
            let d = draw(1, i);
            kinds.insert(d.plan.kind);
            assert!(!d.horizontal_sources().is_empty());
            assert!((120.0..=900.0).contains(&d.plan.duration_s));
            assert!(d.plan.speed_mps <= 5.0);
            for s in &d.streams {
                let (lo, hi) = match s.kind {
                    SensorKind::Imu => (40.0, 1000.0),
                    SensorKind::Attitude => (9.0, 250.0),
                    SensorKind::Flow => (5.0, 100.0),
                    SensorKind::Range => (10.0, 100.0),
                    SensorKind::Baro => (5.0, 50.0),
                    SensorKind::Gnss => (1.0, 10.0),
                    SensorKind::Odometry => (15.0, 200.0),
                    _ => unreachable!("no such stream"),
                };
                assert!((lo..=hi).contains(&s.rate_hz), "{:?} {}", s.kind, s.rate_hz);
                let extra = s.delay_s - default_latency_s(s.kind);
                assert!((0.0..=MAX_UNKNOWN_DELAY_S + 1e-12).contains(&extra));
            }
            let h = d.hardware;
            assert!((0.85..=1.15).contains(&h.flow_scale));
            assert!(h.flow_mount_yaw_rad.abs() <= 5f64.to_radians());
            assert!(h.accel_bias.map_or(0.0, |b| b.norm()) <= 1.0 + 1e-12);
            let y = h.yaw_error;
            assert!(y.bias_rad.abs() + y.amplitude_rad <= 15f64.to_radians() + 1e-12);
            if d.streams.iter().any(|s| s.kind == SensorKind::Flow) {
                let height = h.flow_tof || d.streams.iter().any(|s| s.kind == SensorKind::Range);
                assert!(height, "a flow without a height");
            }
        }
        assert_eq!(kinds.len(), PlanKind::ALL.len());
    }

    #[test]
    fn an_accelerometer_step_is_one_fault_more_on_the_same_flight() {
        let stress = Stress { accel_steps: true };
        let mut stepped = 0;
        for i in 0..200 {
            let (plain, more) = (draw(1, i), draw_stressed(1, i, stress));
            let (steps, rest): (Vec<&Fault>, Vec<&Fault>) = more
                .faults
                .iter()
                .partition(|f| f.kind == FaultKind::AccelOffset);
            assert_eq!(rest, plain.faults.iter().collect::<Vec<_>>(), "draw {i}");
            assert_eq!(more.plan, plain.plan, "draw {i}");
            assert_eq!(more.streams, plain.streams, "draw {i}");
            match steps.as_slice() {
                [] => assert!(!more.describe().contains("stepping")),
                [f] => {
                    stepped += 1;
                    assert_eq!(f.sensor, "imu");
                    assert!(f.start_s >= 20.0 && f.end_s.is_infinite());
                    assert!(more.describe().contains("stepping 1 m/s²"));
                }
                _ => panic!("draw {i}: {} steps", steps.len()),
            }
        }
        // One flight in five, give or take.
        assert!((20..=60).contains(&stepped), "{stepped} of 200 stepped");
    }
}
