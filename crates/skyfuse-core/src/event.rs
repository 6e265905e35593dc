//! Events: what happened, typed. Every producer (estimator, health, the simulator's
//! faults, the service) builds an [`Event`]; it is turned into JSON only at the edge
//! (`events.jsonl`, the websocket's `event` frames, the Zenoh events key), always as
//! `{"kind": "<snake_case variant>", "data": {...}}` beside `source` and `message`
//! (web/PROTOCOL.md, checked against [`Event::KINDS`] by a test).

use crate::verdict::{HealthState, Reason};
use serde::Serialize;

/// One event: when, about which source, a sentence for people, and what it was.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorEvent {
    /// Host clock, µs.
    pub time_us: i64,
    pub source: Option<String>,
    pub message: String,
    pub what: Event,
}

impl EstimatorEvent {
    pub fn new(time_us: i64, source: Option<&str>, message: String, what: Event) -> Self {
        Self {
            time_us,
            source: source.map(str::to_string),
            message,
            what,
        }
    }

    pub fn kind(&self) -> &'static str {
        self.what.kind()
    }

    /// The JSON object of this event with `t` (seconds on the caller's time base) and,
    /// if given, `time_us`: keys sorted, so equal events give equal text.
    pub fn to_json(&self, t_s: f64, with_time_us: bool) -> serde_json::Value {
        let view = EventView {
            time_us: with_time_us.then_some(self.time_us),
            t: t_s,
            source: self.source.as_deref(),
            message: &self.message,
            what: &self.what,
        };
        serde_json::to_value(view).unwrap_or(serde_json::Value::Null)
    }
}

#[derive(Serialize)]
struct EventView<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    time_us: Option<i64>,
    t: f64,
    source: Option<&'a str>,
    message: &'a str,
    #[serde(flatten)]
    what: &'a Event,
}

/// What happened. `kind` is the variant in snake_case; `data` its fields.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", content = "data", rename_all = "snake_case")]
pub enum Event {
    /// The filter started, at this position (ENU, m).
    Initialised {
        position: [f64; 3],
    },
    /// The ENU origin was set from a GNSS fix.
    OriginSet {
        lat: f64,
        lon: f64,
        alt: f64,
    },
    /// A discontinuity of the published pose (the reset counter moved).
    Reset(Reset),
    /// A monitor found the filter diverged and reset it to its own estimate.
    MonitorReset(MonitorReset),
    /// An odometry source started a new segment (its own reset, a jump, a realignment).
    Segment {
        segment: u32,
        reason: String,
        yaw_align: f64,
    },
    /// The set of fused sources, or the attitude source, changed.
    SourceSwitch(SourceSwitch),
    /// A sample was not used (checks failed); throttled per source.
    SampleRejected {
        reason: String,
    },
    /// A measurement failed the innovation gate; throttled per source.
    GateReject {
        test_ratio: f64,
        innovation: Vec<f64>,
    },
    /// A sample older than the history was dropped.
    LateDrop {
        dropped: u64,
    },
    /// Health enabled or disabled a source for the estimator.
    SourceUsable {
        usable: bool,
        reason: String,
    },
    /// A sensor's health changed.
    Health {
        from: HealthState,
        to: HealthState,
        reasons: Vec<Reason>,
    },
    CalibrationStarted {
        samples_per_axis: usize,
    },
    CalibrationResult(CalibrationResult),
    /// Disarmed but moving: carried by hand; the estimate is invalid until set down.
    Handled {
        lifted: bool,
        moving: bool,
        imu_moving: bool,
    },
    /// A constraint (on the ground, fake position) started, or aiding released it.
    Constraint(ConstraintChange),
    /// The range finder's terrain moved under the vehicle.
    TerrainReset {
        from_m: f64,
        to_m: f64,
        test_ratio: f64,
    },
    /// A source's clock restarted (a consistent new series of stamps).
    ClockRestart {
        clock_restarts: u64,
    },
    /// The estimator moved to another clock: the vehicle's, running `rate` times the
    /// host's (a simulator faster than real time), or back to the host's (rate 1).
    TimeBase {
        rate: f64,
        reference: String,
    },
    /// The Zenoh link to the routers was lost or is back.
    ZenohLink,
    /// A simulated fault started or ended (demo and `sim` only).
    FaultInjected,
    FaultCleared,
    /// The integrity monitor excluded a source: the estimate with it departed from the
    /// one without it by `separation` (ENU, m) against `sigma`, `test_ratio` times the
    /// threshold; the solution without it is the estimate from here on.
    IntegrityExclusion {
        separation: [f64; 3],
        sigma: [f64; 3],
        test_ratio: f64,
        reset_counter: u8,
    },
    /// An excluded source agreed again and is fused again.
    IntegrityReadmit {
        excluded_s: f64,
    },
    /// A velocity back after `gap_s` of dead reckoning disagreed beyond the IMU's noise:
    /// the filters allowed for an accelerometer fault over the gap (the position
    /// `reach_m` off at 1σ) and took it (`test_ratio` against the widened filter).
    DeadReckoningDoubted {
        gap_s: f64,
        reach_m: f64,
        test_ratio: f64,
    },
    /// A flow's learnt `state` (its scale or heading error) moved by `moved` over
    /// `window_s`, `test_ratio` times what the data could teach it: the filters allowed
    /// for an accelerometer fault over the window (the IMU it is learnt against).
    CalibrationRanAway {
        state: &'static str,
        moved: f64,
        window_s: f64,
        test_ratio: f64,
    },
}

/// The ways the pose is reset.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Reset {
    /// GNSS back after a spell without position sources.
    Gnss {
        reset_counter: u8,
        jump_m: f64,
        gap_s: Option<f64>,
    },
    /// The origin moved to the current position (control).
    Origin { shift: [f64; 3], reset_counter: u8 },
    /// The filter re-initialised after going non-finite.
    Restart { reset_counter: u8 },
    /// Every measurement of the only sources of a channel was refused for
    /// `rejected_s`: the filter was reset to the newest one (EKF2 and EKF3 do the same),
    /// rather than locking them out for good with its own drift.
    Rejected {
        reset_counter: u8,
        rejected_s: f64,
        jump_m: f64,
    },
    /// A frame of its own re-anchored where the estimate is (it does not move): the
    /// position is relative navigation from here, and the horizontal bound of
    /// `hpl_m` it had reached since the last anchor starts again (see
    /// `integrity::DEFAULT_REANCHOR_FRACTION`).
    Anchor { reset_counter: u8, hpl_m: f64 },
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MonitorReset {
    pub monitor: &'static str,
    pub reason: String,
    pub from: [f64; 3],
    pub to: [f64; 3],
    pub position_departure_m: f64,
    pub velocity_departure_mps: f64,
    pub reset_counter: u8,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum SourceSwitch {
    Fused {
        sources: Vec<String>,
        added: Vec<String>,
        removed: Vec<String>,
    },
    Attitude {
        attitude: &'static str,
    },
    /// The IMU that drives the prediction (one at a time: each has its own biases).
    Imu {
        imu: String,
        from: Option<String>,
        why: &'static str,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum CalibrationResult {
    Done {
        success: bool,
        scale_x: f64,
        scale_y: f64,
        rms_before: [f64; 2],
        rms_after: [f64; 2],
    },
    TimedOut {
        success: bool,
        reason: &'static str,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ConstraintChange {
    Started {
        constraint: &'static str,
        hold: [f64; 3],
    },
    Released {
        constraint: Option<&'static str>,
        held_s: f64,
    },
}

impl Event {
    /// Every kind, as `kind` names it (web/PROTOCOL.md lists these).
    pub const KINDS: [&'static str; 25] = [
        "initialised",
        "origin_set",
        "reset",
        "monitor_reset",
        "segment",
        "source_switch",
        "sample_rejected",
        "gate_reject",
        "late_drop",
        "source_usable",
        "health",
        "calibration_started",
        "calibration_result",
        "handled",
        "constraint",
        "terrain_reset",
        "clock_restart",
        "time_base",
        "zenoh_link",
        "fault_injected",
        "fault_cleared",
        "integrity_exclusion",
        "integrity_readmit",
        "dead_reckoning_doubted",
        "calibration_ran_away",
    ];

    pub fn kind(&self) -> &'static str {
        match self {
            Event::Initialised { .. } => "initialised",
            Event::OriginSet { .. } => "origin_set",
            Event::Reset(_) => "reset",
            Event::MonitorReset(_) => "monitor_reset",
            Event::Segment { .. } => "segment",
            Event::SourceSwitch(_) => "source_switch",
            Event::SampleRejected { .. } => "sample_rejected",
            Event::GateReject { .. } => "gate_reject",
            Event::LateDrop { .. } => "late_drop",
            Event::SourceUsable { .. } => "source_usable",
            Event::Health { .. } => "health",
            Event::CalibrationStarted { .. } => "calibration_started",
            Event::CalibrationResult(_) => "calibration_result",
            Event::Handled { .. } => "handled",
            Event::Constraint(_) => "constraint",
            Event::TerrainReset { .. } => "terrain_reset",
            Event::ClockRestart { .. } => "clock_restart",
            Event::TimeBase { .. } => "time_base",
            Event::ZenohLink => "zenoh_link",
            Event::IntegrityExclusion { .. } => "integrity_exclusion",
            Event::IntegrityReadmit { .. } => "integrity_readmit",
            Event::DeadReckoningDoubted { .. } => "dead_reckoning_doubted",
            Event::CalibrationRanAway { .. } => "calibration_ran_away",
            Event::FaultInjected => "fault_injected",
            Event::FaultCleared => "fault_cleared",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One of each kind (every variant, every shape of the untagged payloads).
    fn one_of_each() -> Vec<Event> {
        vec![
            Event::Initialised {
                position: [1.0, 2.0, 3.0],
            },
            Event::OriginSet {
                lat: 1.0,
                lon: 2.0,
                alt: 3.0,
            },
            Event::Reset(Reset::Gnss {
                reset_counter: 1,
                jump_m: 2.0,
                gap_s: None,
            }),
            Event::Reset(Reset::Origin {
                shift: [1.0, 0.0, 0.0],
                reset_counter: 2,
            }),
            Event::Reset(Reset::Restart { reset_counter: 3 }),
            Event::Reset(Reset::Anchor {
                reset_counter: 4,
                hpl_m: 25.3,
            }),
            Event::MonitorReset(MonitorReset {
                monitor: "gps_imu",
                reason: "far".into(),
                from: [0.0; 3],
                to: [1.0; 3],
                position_departure_m: 5.0,
                velocity_departure_mps: 1.0,
                reset_counter: 4,
            }),
            Event::Segment {
                segment: 2,
                reason: "reset".into(),
                yaw_align: 0.1,
            },
            Event::SourceSwitch(SourceSwitch::Fused {
                sources: vec!["gps".into()],
                added: vec!["gps".into()],
                removed: vec![],
            }),
            Event::SourceSwitch(SourceSwitch::Attitude { attitude: "own" }),
            Event::SampleRejected {
                reason: "nan".into(),
            },
            Event::GateReject {
                test_ratio: 2.0,
                innovation: vec![1.0],
            },
            Event::LateDrop { dropped: 3 },
            Event::SourceUsable {
                usable: false,
                reason: "stale".into(),
            },
            Event::Health {
                from: HealthState::Ok,
                to: HealthState::Failed,
                reasons: vec![],
            },
            Event::CalibrationStarted {
                samples_per_axis: 50,
            },
            Event::CalibrationResult(CalibrationResult::Done {
                success: true,
                scale_x: 1.0,
                scale_y: 1.0,
                rms_before: [0.1, 0.1],
                rms_after: [0.05, 0.05],
            }),
            Event::CalibrationResult(CalibrationResult::TimedOut {
                success: false,
                reason: "timeout",
            }),
            Event::Handled {
                lifted: true,
                moving: false,
                imu_moving: false,
            },
            Event::Constraint(ConstraintChange::Started {
                constraint: "on_ground",
                hold: [0.0; 3],
            }),
            Event::Constraint(ConstraintChange::Released {
                constraint: None,
                held_s: 1.0,
            }),
            Event::TerrainReset {
                from_m: 0.4,
                to_m: 1.1,
                test_ratio: 20.0,
            },
            Event::ClockRestart { clock_restarts: 1 },
            Event::TimeBase {
                rate: 5.0,
                reference: "imu".into(),
            },
            Event::ZenohLink,
            Event::FaultInjected,
            Event::FaultCleared,
            Event::IntegrityExclusion {
                separation: [0.1, 4.0, 0.0],
                sigma: [0.5, 0.5, 0.2],
                test_ratio: 1.6,
                reset_counter: 2,
            },
            Event::IntegrityReadmit { excluded_s: 12.0 },
            Event::DeadReckoningDoubted {
                gap_s: 4.0,
                reach_m: 8.0,
                test_ratio: 0.4,
            },
            Event::CalibrationRanAway {
                state: "scale",
                moved: -0.2,
                window_s: 1.0,
                test_ratio: 3.1,
            },
            Event::Reset(Reset::Rejected {
                reset_counter: 3,
                rejected_s: 3.1,
                jump_m: 4.2,
            }),
        ]
    }

    #[test]
    fn kind_is_the_serialised_tag_and_every_kind_is_listed() {
        let mut seen = std::collections::BTreeSet::new();
        for what in one_of_each() {
            let e = EstimatorEvent::new(1_500_000, Some("gps"), "m".into(), what);
            let v = e.to_json(1.5, true);
            assert_eq!(v["kind"], e.kind(), "{v}");
            assert!(
                Event::KINDS.contains(&e.kind()),
                "{} not in KINDS",
                e.kind()
            );
            assert_eq!(
                (v["t"].as_f64(), v["time_us"].as_i64()),
                (Some(1.5), Some(1_500_000))
            );
            assert_eq!(
                (v["source"].as_str(), v["message"].as_str()),
                (Some("gps"), Some("m"))
            );
            seen.insert(e.kind());
        }
        assert_eq!(seen.len(), Event::KINDS.len(), "an example of every kind");
    }

    #[test]
    fn payloads_keep_their_field_names() {
        let v = EstimatorEvent::new(
            0,
            None,
            String::new(),
            Event::Reset(Reset::Gnss {
                reset_counter: 1,
                jump_m: 2.0,
                gap_s: None,
            }),
        )
        .to_json(0.0, false);
        assert_eq!(
            v["data"],
            serde_json::json!({ "reset_counter": 1, "jump_m": 2.0, "gap_s": null })
        );
        assert!(v.get("time_us").is_none());
        let v = EstimatorEvent::new(0, None, String::new(), Event::ZenohLink).to_json(0.0, false);
        assert_eq!(v["kind"], "zenoh_link");
        assert!(v["data"].is_null());
    }

    #[test]
    fn the_protocol_document_lists_every_kind() {
        let doc = include_str!("../../../web/PROTOCOL.md");
        let listed = doc
            .split("`kind` is one of")
            .nth(1)
            .and_then(|rest| rest.split("\n\n").next())
            .unwrap_or_else(|| panic!("PROTOCOL.md: no \"`kind` is one of\" list"));
        let names: Vec<&str> = listed.split('`').skip(1).step_by(2).collect();
        assert_eq!(names, Event::KINDS, "web/PROTOCOL.md's event kinds");
    }
}
