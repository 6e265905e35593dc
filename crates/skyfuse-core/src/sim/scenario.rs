//! Named simulated flights for offline runs and tests: a flight profile, the streams
//! that exist, and the faults injected on a schedule.

use super::faults::{Fault, FaultKind, FaultSchedule};
use super::sensors::{Hardware, StreamSpec, DEMO_STREAMS};
use super::truth::{loop_s, Profile, LOOP_S};
use super::Simulator;
use crate::sample::SensorKind;
use std::sync::Arc;

/// One named scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub name: &'static str,
    pub description: &'static str,
    pub profile: Profile,
    pub streams: Vec<StreamSpec>,
    pub faults: Vec<Fault>,
    pub hardware: Hardware,
}

impl Scenario {
    /// Its flight for `duration_s`, with its faults on their schedule.
    pub fn simulator(&self, seed: u64, duration_s: f64) -> Simulator {
        let sensors = self
            .streams
            .iter()
            .map(|s| s.input_id.to_string())
            .collect();
        let faults = Arc::new(FaultSchedule::new(sensors, self.faults.clone()));
        Simulator::with_profile(&self.streams, seed, duration_s, self.profile, faults)
            .with_hardware(self.hardware)
    }

    /// Its length unless asked otherwise: one loop of its flight, s.
    pub fn default_duration_s(&self) -> f64 {
        loop_s(self.profile)
    }
}

/// Default length of the demo's scenarios: one loop of the flight, s.
pub const DEFAULT_DURATION_S: f64 = LOOP_S;

/// A PX4Flow-class vehicle: flow without a ToF of its own (integrating at `flow_hz`),
/// a downward range finder with its own limits, the autopilot's attitude; an IMU when
/// `imu`. No GNSS, no camera.
fn flow_vehicle(flow_hz: f64, range_hz: f64, attitude_hz: f64, imu: bool) -> Vec<StreamSpec> {
    let mut streams = vec![
        StreamSpec {
            input_id: "attitude",
            kind: SensorKind::Attitude,
            rate_hz: attitude_hz,
            delay_s: 0.005,
        },
        StreamSpec {
            input_id: "flow",
            kind: SensorKind::Flow,
            rate_hz: flow_hz,
            delay_s: 0.01,
        },
        StreamSpec {
            input_id: "rangefinder",
            kind: SensorKind::Range,
            rate_hz: range_hz,
            delay_s: 0.01,
        },
    ];
    if imu {
        streams.insert(0, DEMO_STREAMS[0]);
    }
    streams
}

/// An autopilot's barometer as SCALED_PRESSURE streams it.
const BARO_STREAM: StreamSpec = StreamSpec {
    input_id: "baro",
    kind: SensorKind::Baro,
    rate_hz: 20.0,
    delay_s: 0.01,
};

/// A PX4Flow's own sonar: 0.3-3.7 m, echoes now and then beyond it.
fn px4flow_sonar(flow_hz: f64) -> Hardware {
    Hardware {
        range_min_m: 0.3,
        range_max_m: 3.7,
        range_spurious: 0.03,
        flow_tof: false,
        flow_integration_s: 1.0 / flow_hz,
        ..Hardware::default()
    }
}

/// A PX4Flow at 9.5 Hz with a separate range finder to 4.3 m, its flow reading
/// `scale` times the truth.
fn slow_flow_outdoors(scale: f64) -> Hardware {
    Hardware {
        range_min_m: 0.1,
        range_max_m: 4.3,
        flow_tof: false,
        flow_scale: scale,
        flow_integration_s: 1.0 / 9.5,
        ..Hardware::default()
    }
}

/// PX4's offboard square on GNSS + IMU + attitude only (what `px4_flight.py` flies in
/// SITL): the IMU at 120 Hz as PX4 streams HIGHRES_IMU, and the GNSS 0.25 s later than
/// the configuration assumes, so that its fixes are refused in the hard steps while
/// nothing else holds the position.
fn gnss_square(late_s: f64) -> (Profile, Vec<StreamSpec>) {
    let plan = square_plan();
    let streams = DEMO_STREAMS
        .iter()
        .filter(|s| matches!(s.input_id, "imu" | "attitude" | "gps"))
        .map(|&s| match s.input_id {
            "imu" => StreamSpec {
                rate_hz: 120.0,
                ..s
            },
            "gps" => StreamSpec {
                delay_s: s.delay_s + late_s,
                ..s
            },
            _ => s,
        })
        .collect();
    (Profile::Plan(plan), streams)
}

/// How much later than assumed the `gps-square` GNSS fixes come, s.
pub const GNSS_SQUARE_LATE_S: f64 = 0.25;

/// The square the `gps-square` scenarios fly: 10 m, 5 m/s moves, at 5 m.
fn square_plan() -> super::plan::FlightPlan {
    super::plan::FlightPlan {
        kind: super::plan::PlanKind::Square,
        duration_s: 150.0,
        height_m: 5.0,
        speed_mps: 5.0,
        size_m: 10.0,
        climb_to_m: 5.0,
        yaw_swing_rad: 0.0,
        yaw0_rad: 0.0,
    }
}

/// When the `gps-square` scenarios' first move (their first hard step) starts, s.
pub fn gnss_square_first_move_s() -> f64 {
    square_plan().square_first_move_s()
}

/// `gps-square-lockout`'s receiver: as precise as SITL's (PX4 SIH's fixes are
/// centimetres apart), so the gate is as tight as it was in the flights that locked
/// the GNSS out.
fn precise_gnss() -> Hardware {
    Hardware {
        gnss_std_m: (0.05, 0.1),
        ..Hardware::default()
    }
}

fn streams_without(ids: &[&str]) -> Vec<StreamSpec> {
    DEMO_STREAMS
        .iter()
        .filter(|s| !ids.contains(&s.input_id))
        .copied()
        .collect()
}

fn fault(sensor: &str, kind: FaultKind, start_s: f64, end_s: f64) -> Fault {
    Fault {
        sensor: sensor.to_string(),
        kind,
        start_s,
        end_s,
    }
}

/// Every scenario: `(name, description)`.
pub const NAMES: &[(&str, &str)] = &[
    (
        "demo",
        "the demo flight: figure-eight with an indoor stretch (70-100 s) without GPS",
    ),
    (
        "hover",
        "take-off, hover at 2 m with yaw changes, landing; every sensor",
    ),
    ("figure8", "figure-eight outdoors; every sensor"),
    (
        "indoor",
        "figure-eight indoors: no GPS; flow + ToF, T265, range, IMU",
    ),
    (
        "outdoor",
        "figure-eight outdoors: GPS + IMU + flow + range, no T265",
    ),
    (
        "flow-range",
        "figure-eight indoors on flow + range + attitude + IMU only: valid on the ground before take-off and after landing",
    ),
    (
        "flow-loss",
        "flow-range, and the flow stops in flight from 40 to 50 s: nothing aids the horizontal position",
    ),
    ("gps-loss", "figure-eight; GPS has no fix from 40 to 70 s"),
    (
        "gps-jump",
        "figure-eight; GPS multipath jump of 12 m from 50 to 60 s",
    ),
    (
        "t265-drift",
        "figure-eight; the T265 drifts away at 0.3 m/s from 40 to 60 s",
    ),
    (
        "t265-covariance",
        "figure-eight; T265 pose covariance at 0.01 (unusable) from 40 to 60 s",
    ),
    (
        "t265-reset",
        "figure-eight; the T265 loses tracking and restarts its frame at 50 s",
    ),
    (
        "flow-dark-floor",
        "indoor; flow over a dark floor (quality collapses) from 40 to 60 s",
    ),
    (
        "tof-range",
        "indoor; the flow module's ToF reads out of range from 40 to 50 s",
    ),
    (
        "sensor-stop",
        "figure-eight; the T265 stops sending from 40 to 55 s",
    ),
    ("sensor-nan", "figure-eight; GPS sends NaN from 40 to 50 s"),
    (
        "link-loss",
        "figure-eight; nothing arrives from 40 to 46 s (the Zenoh router restarts)",
    ),
    (
        "sonar-climb",
        "climb to 12 m and hover outdoors for 280 s on a PX4Flow with its 0.3-3.7 m sonar (spurious echoes above it) + attitude; no IMU, no GNSS: nothing measures the height up there",
    ),
    (
        "sonar-climb-imu",
        "sonar-climb with the IMU as well",
    ),
    (
        "sonar-climb-baro",
        "sonar-climb with the autopilot's barometer: the height held where the sonar ends",
    ),
    (
        "flow-laps",
        "290 s of 4 m/s laps outdoors at 3 m: a 9.5 Hz PX4Flow reading 5 % fast, a range finder to 4.3 m, attitude at 57 Hz; no IMU, no GNSS",
    ),
    (
        "flow-laps-imu",
        "flow-laps with the IMU, the flow reading 5 % slow",
    ),
    (
        "gps-square",
        "PX4's offboard square (10 m, 5 m/s moves, 4 m/s² at their ends) on GNSS + IMU + attitude only, the fixes 0.25 s later than configured: the only position source refused in the hard steps",
    ),
    (
        "flow-laps-slow",
        "flow-laps with the flow reading 5 % slow and no IMU: nothing sees the scale",
    ),
    (
        "gps-square-lockout",
        "PX4's offboard square on a GNSS as precise as SITL's (5 cm) + IMU + attitude; from the first hard step the accelerometer reads 1 m/s² off: the only position source refused while the vehicle accelerates, reset to rather than locked out",
    ),
];

/// Look up a scenario by name.
pub fn scenario(name: &str) -> Option<Scenario> {
    let (name, description) = NAMES.iter().find(|(n, _)| *n == name).copied()?;
    let all = DEMO_STREAMS.to_vec();
    let hardware = match name {
        "sonar-climb" | "sonar-climb-imu" | "sonar-climb-baro" => px4flow_sonar(20.0),
        "flow-laps" => slow_flow_outdoors(1.05),
        "flow-laps-imu" | "flow-laps-slow" => slow_flow_outdoors(0.95),
        "gps-square-lockout" => precise_gnss(),
        _ => Hardware::default(),
    };
    let (profile, streams, faults) = match name {
        "sonar-climb" => (
            Profile::HighHover,
            flow_vehicle(20.0, 10.0, 50.0, false),
            vec![],
        ),
        "sonar-climb-imu" => (
            Profile::HighHover,
            flow_vehicle(20.0, 10.0, 50.0, true),
            vec![],
        ),
        "sonar-climb-baro" => {
            let mut streams = flow_vehicle(20.0, 10.0, 50.0, false);
            streams.push(BARO_STREAM);
            (Profile::HighHover, streams, vec![])
        }
        "flow-laps" => (Profile::Laps, flow_vehicle(9.5, 20.0, 57.0, false), vec![]),
        "flow-laps-imu" => (Profile::Laps, flow_vehicle(9.5, 20.0, 57.0, true), vec![]),
        "flow-laps-slow" => (Profile::Laps, flow_vehicle(9.5, 20.0, 57.0, false), vec![]),
        "gps-square" => {
            let (profile, streams) = gnss_square(GNSS_SQUARE_LATE_S);
            (profile, streams, vec![])
        }
        "gps-square-lockout" => {
            let (profile, streams) = gnss_square(0.0);
            let offset = fault(
                "imu",
                FaultKind::AccelOffset,
                gnss_square_first_move_s(),
                f64::INFINITY,
            );
            (profile, streams, vec![offset])
        }
        "demo" => (Profile::Demo, all, vec![]),
        "hover" => (Profile::Hover, all, vec![]),
        "figure8" => (Profile::Figure8, all, vec![]),
        "indoor" => (Profile::Indoor, streams_without(&["gps"]), vec![]),
        "outdoor" => (Profile::Figure8, streams_without(&["t265"]), vec![]),
        "flow-range" => (Profile::Indoor, streams_without(&["gps", "t265"]), vec![]),
        "flow-loss" => (
            Profile::Indoor,
            streams_without(&["gps", "t265"]),
            vec![fault("flow", FaultKind::Stop, 40.0, 50.0)],
        ),
        "gps-loss" => (
            Profile::Figure8,
            all,
            vec![fault("gps", FaultKind::NoFix, 40.0, 70.0)],
        ),
        "gps-jump" => (
            Profile::Figure8,
            all,
            vec![fault("gps", FaultKind::Jump, 50.0, 60.0)],
        ),
        "t265-drift" => (
            Profile::Figure8,
            all,
            vec![fault("t265", FaultKind::Drift, 40.0, 60.0)],
        ),
        "t265-covariance" => (
            Profile::Figure8,
            all,
            vec![fault("t265", FaultKind::Covariance, 40.0, 60.0)],
        ),
        "t265-reset" => (
            Profile::Figure8,
            all,
            vec![fault("t265", FaultKind::Reset, 50.0, f64::INFINITY)],
        ),
        "flow-dark-floor" => (
            Profile::Indoor,
            streams_without(&["gps"]),
            vec![fault("flow", FaultKind::DarkFloor, 40.0, 60.0)],
        ),
        "tof-range" => (
            Profile::Indoor,
            streams_without(&["gps"]),
            vec![fault("flow", FaultKind::TofRange, 40.0, 50.0)],
        ),
        "link-loss" => (
            Profile::Figure8,
            all,
            DEMO_STREAMS
                .iter()
                .map(|st| fault(st.input_id, FaultKind::Stop, 40.0, 46.0))
                .collect(),
        ),
        "sensor-stop" => (
            Profile::Figure8,
            all,
            vec![fault("t265", FaultKind::Stop, 40.0, 55.0)],
        ),
        "sensor-nan" => (
            Profile::Figure8,
            all,
            vec![fault("gps", FaultKind::Nan, 40.0, 50.0)],
        ),
        _ => return None,
    };
    Some(Scenario {
        name,
        description,
        profile,
        streams,
        faults,
        hardware,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_listed_scenario_exists_and_unknown_does_not() {
        for (n, _) in NAMES {
            let s = scenario(n).expect("listed scenario");
            assert_eq!(s.name, *n);
            assert!(!s.streams.is_empty());
        }
        assert!(scenario("moon-landing").is_none());
        // Take-off at 4 s, 5 s of climb to 5 m, the first corner's 4 s hold.
        assert_eq!(gnss_square_first_move_s(), 13.0);
        assert!(scenario("indoor")
            .expect("indoor")
            .streams
            .iter()
            .all(|s| s.input_id != "gps"));
    }
}
