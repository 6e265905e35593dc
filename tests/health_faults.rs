//! Health checks on simulated faults: each scenario flies through the same fusion core
//! the service runs (health + estimator), and the test asserts that the right sensor is
//! flagged with the right reason within a stated latency, that the fused position stays
//! within a stated bound of the truth through the fault, and that the sensor is taken
//! back after it recovers. Nominal flights of 30 simulated minutes raise no fault.

use skyfuse::estimator::EstimatorConfig;
use skyfuse::event::Event;
use skyfuse::fusion::{Fusion, InputList, InputSpec};
use skyfuse::health::HealthConfig;
use skyfuse::sample::Sample;
use skyfuse::sim::faults::FaultSchedule;
use skyfuse::sim::scenario::{scenario, Scenario};
use skyfuse::sim::truth::truth_of;
use skyfuse::sim::Simulator;
use std::sync::Arc;

struct Run {
    /// (t s, sensor, to, reason codes)
    transitions: Vec<(f64, String, String, Vec<String>)>,
    /// (t s, |fused − truth − offset| m) at 10 Hz, valid estimates only
    errors: Vec<(f64, f64)>,
    /// (t s, estimate valid) at every health tick (100 ms), samples or not
    validity: Vec<(f64, bool)>,
}

fn health_transitions(
    events: &[skyfuse::estimator::EstimatorEvent],
) -> Vec<(f64, String, String, Vec<String>)> {
    events
        .iter()
        .filter_map(|e| match &e.what {
            Event::Health { to, reasons, .. } => Some((
                e.time_us as f64 * 1e-6,
                e.source.clone().unwrap_or_default(),
                to.as_str().to_string(),
                reasons.iter().map(|r| r.code.to_string()).collect(),
            )),
            _ => None,
        })
        .collect()
}

fn fly(scn: &Scenario, duration_s: f64) -> Run {
    let inputs: InputList = scn
        .streams
        .iter()
        .map(|s| InputSpec::new(s.input_id, s.kind, s.rate_hz))
        .collect();
    let sensors = scn.streams.iter().map(|s| s.input_id.to_string()).collect();
    let faults = Arc::new(FaultSchedule::new(sensors, scn.faults.clone()));
    // The faults' effects are judged in decimetres: a GNSS good to 0.2 m (which it
    // reports as such), so its own slow wander does not hide them.
    let hardware = skyfuse::sim::sensors::Hardware {
        gnss_std_m: (0.2, 0.3),
        ..scn.hardware
    };
    let sim = Simulator::with_profile(&scn.streams, 1, duration_s, scn.profile, faults)
        .with_hardware(hardware);
    let mut f = Fusion::new(EstimatorConfig::default(), HealthConfig::default(), &inputs);
    let mut run = Run {
        transitions: vec![],
        errors: vec![],
        validity: vec![],
    };
    let mut raw_err: Vec<(f64, nalgebra::Vector3<f64>)> = vec![];
    let mut next_err_t = 0.0;
    let mut next_tick_t = 0.0;
    for ev in sim {
        // The service's health timer (100 ms): time passes even when nothing arrives.
        while next_tick_t < ev.publish_t {
            let events = f.tick((next_tick_t * 1e6).round() as i64);
            run.transitions.extend(health_transitions(&events));
            let valid = f.est.pose().is_some_and(|p| p.valid);
            run.validity.push((next_tick_t, valid));
            next_tick_t += 0.1;
        }
        let s = Sample {
            source: scn.streams[ev.stream].input_id.into(),
            stamp_us: Some((ev.measured_t * 1e6).round() as i64),
            arrival_us: (ev.publish_t * 1e6).round() as i64,
            data: ev.data,
        };
        let events = f.process(&s, s.arrival_us);
        run.transitions.extend(health_transitions(&events));
        if ev.publish_t >= next_err_t {
            next_err_t += 0.1;
            if let Some(p) = f.est.pose().filter(|p| p.valid) {
                let t = p.time_us as f64 * 1e-6;
                raw_err.push((t, p.position - truth_of(scn.profile, t).position));
            }
        }
    }
    // The fused frame's origin is the first GNSS fix (or where it started): take the
    // mean offset over 10-35 s, before any fault, out of the error.
    let pre: Vec<_> = raw_err
        .iter()
        .filter(|(t, _)| (10.0..35.0).contains(t))
        .map(|(_, e)| *e)
        .collect();
    let offset = pre.iter().sum::<nalgebra::Vector3<f64>>() / pre.len().max(1) as f64;
    run.errors = raw_err
        .into_iter()
        .map(|(t, e)| (t, (e - offset).norm()))
        .collect();
    run
}

/// One fault's expectations.
struct Expect {
    scenario: &'static str,
    sensor: &'static str,
    states: &'static [&'static str],
    codes: &'static [&'static str],
    /// Detection latency bound after the fault starts, s.
    latency_s: f64,
    /// Fused error bound from the fault's start to 10 s after its end, m.
    bound_m: f64,
    /// Taken back (`ok`) within this long after the fault ends, s (None: lasting fault).
    recover_s: Option<f64>,
}

const FAULTS: &[Expect] = &[
    Expect {
        scenario: "gps-loss",
        sensor: "gps",
        states: &["failed"],
        codes: &["gnss_no_fix"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        scenario: "gps-jump",
        sensor: "gps",
        states: &["failed"],
        codes: &["gnss_jump", "innovation_rejected"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(10.0),
    },
    Expect {
        scenario: "t265-drift",
        sensor: "t265",
        states: &["degraded", "failed"],
        codes: &["innovation_high", "innovation_rejected", "vo_drift"],
        latency_s: 10.0,
        bound_m: 0.5,
        recover_s: Some(10.0),
    },
    Expect {
        scenario: "t265-covariance",
        sensor: "t265",
        states: &["failed"],
        codes: &["vo_covariance"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        scenario: "t265-reset",
        sensor: "t265",
        states: &["degraded", "failed"],
        codes: &["vo_jump", "vo_reset"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        scenario: "flow-dark-floor",
        sensor: "flow",
        states: &["failed"],
        codes: &["flow_quality_low", "flow_status"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        scenario: "tof-range",
        sensor: "flow",
        states: &["failed"],
        codes: &["tof_out_of_range", "tof_status", "tof_weak"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        scenario: "sensor-stop",
        sensor: "t265",
        states: &["stale"],
        codes: &["stale"],
        latency_s: 0.5,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
    Expect {
        // Every stream at once, as when the Zenoh router restarts.
        scenario: "link-loss",
        sensor: "gps",
        states: &["stale"],
        codes: &["stale"],
        latency_s: 1.0,
        bound_m: 1.5,
        recover_s: Some(1.0),
    },
    Expect {
        scenario: "sensor-nan",
        sensor: "gps",
        states: &["failed", "stale"],
        codes: &["invalid_value", "stale"],
        latency_s: 1.0,
        bound_m: 0.5,
        recover_s: Some(5.0),
    },
];

#[test]
fn every_fault_is_flagged_bounded_and_recovered() {
    let mut report = vec![];
    let mut failures = vec![];
    for x in FAULTS {
        let scn = scenario(x.scenario).expect("scenario");
        let fault = &scn.faults[0];
        let run = fly(&scn, 100.0);
        let flagged = run
            .transitions
            .iter()
            .find(|(t, s, _, _)| *t >= fault.start_s && s == x.sensor);
        // Nothing said of the sensor before its fault: a false alarm is a wrong report.
        let early: Vec<_> = run
            .transitions
            .iter()
            .filter(|(t, s, to, _)| *t < fault.start_s && s == x.sensor && to != "ok")
            .collect();
        if !early.is_empty() {
            failures.push(format!(
                "{}: {} flagged before its fault at {} s: {early:?}",
                x.scenario, x.sensor, fault.start_s
            ));
        }
        let Some((t_flag, _, to, codes)) = flagged else {
            failures.push(format!("{}: {} never flagged", x.scenario, x.sensor));
            continue;
        };
        let latency = t_flag - fault.start_s;
        if !x.states.contains(&to.as_str()) || !codes.iter().any(|c| x.codes.contains(&c.as_str()))
        {
            failures.push(format!(
                "{}: flagged {to} {codes:?}, want {:?} {:?}",
                x.scenario, x.states, x.codes
            ));
        }
        if latency > x.latency_s {
            failures.push(format!(
                "{}: detected after {latency:.2} s > {} s",
                x.scenario, x.latency_s
            ));
        }
        let end = if fault.end_s.is_finite() {
            fault.end_s
        } else {
            fault.start_s
        };
        let worst = run
            .errors
            .iter()
            .filter(|(t, _)| *t >= fault.start_s && *t <= end + 10.0)
            .map(|(_, e)| *e)
            .fold(0.0, f64::max);
        if worst > x.bound_m {
            failures.push(format!(
                "{}: fused error {worst:.2} m > {} m",
                x.scenario, x.bound_m
            ));
        }
        let back = run
            .transitions
            .iter()
            .find(|(t, s, to, _)| *t > *t_flag && s == x.sensor && to == "ok")
            .map(|(t, ..)| t - end);
        match (x.recover_s, back) {
            (Some(r), Some(b)) if b <= r => {}
            (Some(r), b) => failures.push(format!(
                "{}: taken back after {b:?} s, want ≤ {r} s",
                x.scenario
            )),
            (None, _) => {}
        }
        report.push(format!(
            "{:<16} {:<5} -> {:<8} {:<22} latency {:>5.2} s  worst fused error {:.3} m  back after {}",
            x.scenario,
            x.sensor,
            to,
            codes.join(","),
            latency,
            worst,
            back.map(|b| format!("{b:.1} s")).unwrap_or_else(|| "-".into())
        ));
    }
    println!("{}", report.join("\n"));
    assert!(
        failures.is_empty(),
        "{}\n\n{}",
        failures.join("\n"),
        report.join("\n")
    );
}

#[test]
fn thirty_nominal_minutes_raise_no_fault() {
    for name in ["figure8", "indoor", "outdoor", "hover"] {
        let scn = scenario(name).expect("scenario");
        let run = fly(&scn, 1800.0);
        let faults: Vec<_> = run
            .transitions
            .iter()
            .filter(|(_, _, to, _)| to != "ok")
            .collect();
        assert!(faults.is_empty(), "{name}: false fault events {faults:?}");
        let worst = run.errors.iter().map(|(_, e)| *e).fold(0.0, f64::max);
        println!("{name}: 1800 s, no fault events, worst fused error {worst:.3} m");
    }
}

#[test]
fn a_lost_link_makes_the_estimate_invalid_until_data_is_back() {
    let scn = scenario("link-loss").expect("link-loss scenario");
    let run = fly(&scn, 70.0);
    let ticks = |a: f64, b: f64| {
        run.validity
            .iter()
            .filter(move |(t, _)| *t >= a && *t < b)
            .collect::<Vec<_>>()
    };
    assert!(
        ticks(20.0, 40.0).iter().all(|(_, v)| *v),
        "invalid before the gap"
    );
    // Nothing arrives from 40 s: invalid once aiding_timeout (1 s) has passed, although
    // no sample came to say so; nothing valid is sent on a silent link.
    let silent = ticks(41.1, 46.0);
    assert!(!silent.is_empty());
    assert!(
        silent.iter().all(|(_, v)| !*v),
        "valid during the silence: {silent:?}"
    );
    // Data back at 46 s. The first 0.1 s are dead reckoning on flow from a state 6 s
    // old (1.3 m off, inside its reported σ) until the first GNSS fix resets the
    // position (reset counter +1); then ≈ 0.5 m, the GNSS's own slow error in the
    // frame the T265 had held before. That fix comes in unchecked (nothing else
    // measures the absolute position) and carries the receiver's unreported error as
    // doubt (σ 2.6 m): the protection level stays at 51 m against the 50 m alert limit
    // until 60.2 s, and the pose is valid again from there (within a second before
    // the doubt; BENCHMARKS.md, stop 58).
    let back = ticks(61.0, 70.0);
    assert!(
        back.iter().all(|(_, v)| *v),
        "not valid after the link came back"
    );
    let worst = run
        .errors
        .iter()
        .filter(|(t, _)| (46.0..56.0).contains(t))
        .map(|(_, e)| *e)
        .fold(0.0, f64::max);
    println!("link-loss: worst error of a valid estimate after the gap {worst:.3} m");

    assert!(worst < 1.5, "{worst} m");
}
