use super::*;
use crate::sample::*;
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector2, Vector3};
use std::sync::Arc;

fn monitor() -> HealthMonitor {
    HealthMonitor::new(
        HealthConfig::default(),
        &[
            InputSpec::new("gps", SensorKind::Gnss, 10.0),
            InputSpec::new("flow", SensorKind::Flow, 50.0),
            InputSpec::new("t265", SensorKind::Odometry, 200.0),
            InputSpec::new("imu", SensorKind::Imu, 200.0),
            InputSpec {
                enabled: false,
                ..InputSpec::new("lidar", SensorKind::Range, 20.0)
            },
        ],
    )
}

fn fix(east_m: f64, fix: GnssFixType) -> Sample {
    let o = crate::geo::LocalEnu::new(47.0, 8.0, 400.0);
    let (lat, lon, alt) = o.to_geodetic(Vector3::new(east_m, 0.0, 0.0));
    Sample {
        source: Arc::from("gps"),
        stamp_us: None,
        arrival_us: 0,
        data: SensorData::Gnss(GnssFix {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            fix,
            position_cov: Some(Box::new(Matrix3::identity() * 0.5)),
            satellites: Some(14),
            hdop: Some(0.8),
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        }),
    }
}

fn flow(quality: u8, tof: f64) -> Sample {
    Sample {
        source: Arc::from("flow"),
        stamp_us: None,
        arrival_us: 0,
        data: SensorData::Flow(OpticalFlow {
            rate: Some(Vector2::new(0.1, 0.0)),
            gyro: None,
            velocity: None,
            integration_s: Some(0.02),
            quality,
            status: Some(1),
            tof: Some(Tof {
                distance_m: tof,
                strength: Some(200),
                precision: None,
                status: Some(0),
            }),
        }),
    }
}

fn odom(var: f64, x: f64) -> Sample {
    Sample {
        source: Arc::from("t265"),
        stamp_us: None,
        arrival_us: 0,
        data: SensorData::Odometry(Box::new(Odometry {
            position: Vector3::new(x, 0.0, 1.0),
            orientation: UnitQuaternion::identity(),
            velocity: Some(Vector3::zeros()),
            angular_velocity: None,
            pose_cov: Some(Matrix6::identity() * var),
            twist_cov: None,
            frame_id: String::new(),
            child_frame_id: String::new(),
            reset_counter: None,
            quality: None,
        })),
    }
}

/// Feed `make(t)` every `period_ms` from `from_ms` to `to_ms`, evaluating each time;
/// returns the transitions of `sensor`.
fn run(
    m: &mut HealthMonitor,
    sensor: &str,
    from_ms: i64,
    to_ms: i64,
    period_ms: i64,
    make: impl Fn(i64) -> Sample,
) -> Vec<Transition> {
    let mut out = vec![];
    let mut t = from_ms;
    while t < to_ms {
        m.on_sample(&make(t), t * 1000);
        out.extend(
            m.evaluate(t * 1000)
                .into_iter()
                .filter(|tr| tr.sensor == sensor),
        );
        t += period_ms;
    }
    out
}

#[test]
fn gnss_loss_is_failed_after_the_confirm_time_and_taken_back_after_recover() {
    let mut m = monitor();
    let tr = run(&mut m, "gps", 0, 5000, 100, |_| {
        fix(0.0, GnssFixType::Fix3d)
    });
    assert_eq!(tr.len(), 1, "{tr:?}");
    assert_eq!(
        (tr[0].from, tr[0].to),
        (HealthState::NoData, HealthState::Ok)
    );
    let tr = run(&mut m, "gps", 5000, 10_000, 100, |_| {
        fix(0.0, GnssFixType::NoFix)
    });
    assert_eq!(tr.len(), 1, "{tr:?}");
    assert_eq!(tr[0].to, HealthState::Failed);
    assert_eq!(tr[0].reasons[0].code, "gnss_no_fix");
    // Confirmed 300 ms after the first bad fix.
    assert_eq!(tr[0].time_us, 5_300_000);
    assert!(!m.usable("gps"));
    let tr = run(&mut m, "gps", 10_000, 20_000, 100, |_| {
        fix(0.0, GnssFixType::Fix3d)
    });
    assert_eq!(tr.len(), 1, "{tr:?}");
    assert_eq!(tr[0].to, HealthState::Ok);
    // Hold 500 ms + recover 3000 ms after the last bad fix (9.9 s).
    assert!(
        (13_300_000..=13_600_000).contains(&tr[0].time_us),
        "{}",
        tr[0].time_us
    );
}

#[test]
fn a_borderline_sensor_does_not_flap() {
    let mut m = monitor();
    run(&mut m, "flow", 0, 2000, 20, |_| flow(200, 1.5));
    // Quality dips below the limit on every 10th sample only (a single 20 ms blip).
    let tr = run(&mut m, "flow", 2000, 30_000, 20, |t| {
        flow(if t % 200 == 0 { 40 } else { 200 }, 1.5)
    });
    // A condition lives 500 ms after each blip: the raw state is bad for good, so it
    // fails once and stays failed, never flapping.
    assert!(tr.len() <= 1, "{tr:?}");
}

#[test]
fn flow_on_the_ground_is_not_a_fault_but_a_dark_floor_is() {
    let mut m = monitor();
    let tr = run(&mut m, "flow", 0, 3000, 20, |_| flow(20, 0.09));
    assert!(tr.iter().all(|t| t.to == HealthState::Ok), "{tr:?}");
    let tr = run(&mut m, "flow", 3000, 6000, 20, |_| flow(8, 1.5));
    assert_eq!(tr.last().map(|t| t.to), Some(HealthState::Failed));
    assert_eq!(
        tr.last().map(|t| t.reasons[0].code),
        Some("flow_quality_low")
    );
    let tr = run(&mut m, "flow", 6000, 9000, 20, |_| flow(200, 9.5));
    assert!(
        m.sensor("flow")
            .is_some_and(|s| s.reasons.iter().any(|r| r.code == "tof_out_of_range")),
        "{tr:?}"
    );
}

#[test]
fn t265_covariance_levels() {
    let mut m = monitor();
    run(&mut m, "t265", 0, 2000, 5, |_| odom(1e-4, 0.0));
    assert_eq!(m.sensor("t265").map(|s| s.state), Some(HealthState::Ok));
    run(&mut m, "t265", 2000, 4000, 5, |_| odom(0.002, 0.0));
    assert_eq!(
        m.sensor("t265").map(|s| s.state),
        Some(HealthState::Degraded)
    );
    assert!(m.usable("t265"));
    run(&mut m, "t265", 4000, 6000, 5, |_| odom(0.01, 0.0));
    assert_eq!(m.sensor("t265").map(|s| s.state), Some(HealthState::Failed));
    assert!(!m.usable("t265"));
}

#[test]
fn a_sensor_that_stops_goes_stale_and_a_disabled_one_stays_disabled() {
    let mut m = monitor();
    run(&mut m, "gps", 0, 2000, 100, |_| {
        fix(0.0, GnssFixType::Fix3d)
    });
    // Last fix at 1.9 s; stale after 500 ms = 5 periods at 10 Hz.
    let tr = m.evaluate(2_350_000);
    assert!(tr.is_empty(), "{tr:?}");
    let tr = m.evaluate(2_450_000);
    assert_eq!(
        tr.iter().find(|t| t.sensor == "gps").map(|t| t.to),
        Some(HealthState::Stale)
    );
    assert_eq!(
        m.sensor("lidar").map(|s| s.state),
        Some(HealthState::Disabled)
    );
}

#[test]
fn gnss_jump_is_caught() {
    let mut m = monitor();
    run(&mut m, "gps", 0, 3000, 100, |_| {
        fix(0.0, GnssFixType::Fix3d)
    });
    let tr = run(&mut m, "gps", 3000, 4000, 100, |t| {
        fix(if t >= 3000 { 12.0 } else { 0.0 }, GnssFixType::Fix3d)
    });
    // One jump sample is the whole story: it counts at once, held for the hold time.
    assert_eq!(
        tr.first().map(|t| t.reasons[0].code),
        Some("gnss_jump"),
        "{tr:?}"
    );
}

#[test]
fn rejected_samples_fail_the_sensor() {
    let mut m = monitor();
    run(&mut m, "gps", 0, 2000, 100, |_| {
        fix(0.0, GnssFixType::Fix3d)
    });
    for t in (2000..3000).step_by(100) {
        m.on_rejected("gps", "invalid_value", "latitude is NaN", t * 1000);
        m.on_sample(&fix(0.0, GnssFixType::Fix3d), t * 1000);
        m.evaluate(t * 1000);
    }
    let s = m.sensor("gps").expect("gps");
    assert_eq!(s.state, HealthState::Failed);
    assert_eq!(s.reasons[0].code, "invalid_value");
}

#[test]
fn a_lone_bad_sample_does_not_take_a_sensor_out() {
    // One flow sample of low quality in a run of good ones: the estimator drops it;
    // the sensor stays usable (it used to be failed, then out for recover_ms). The same
    // quality low for 0.5 s does take it out.
    let mut m = monitor();
    let q = |t: i64, bad: &dyn Fn(i64) -> bool| if bad(t) { 10 } else { 200 };
    let lone = |t: i64| t == 3000;
    let tr = run(&mut m, "flow", 0, 5000, 20, |t| flow(q(t, &lone), 1.0));
    assert!(
        !tr.iter()
            .any(|t| t.sensor == "flow" && t.to == HealthState::Failed),
        "{tr:?}"
    );
    assert!(m.usable("flow"));
    let long = |t: i64| (6000..6500).contains(&t);
    let tr = run(&mut m, "flow", 5000, 7000, 20, |t| flow(q(t, &long), 1.0));
    assert!(
        tr.iter()
            .any(|t| t.sensor == "flow" && t.to == HealthState::Failed),
        "{tr:?}"
    );
}

#[test]
fn a_source_is_failed_by_its_innovations_only_when_most_samples_are_over_the_gate() {
    // Each look (10 Hz) sees the latest test ratio over the gate. With one sample in
    // five over it (two flow sensors at take-off, while the estimate settles) the
    // source stays usable; with four in five it is failed, the estimator disagreeing
    // with it throughout.
    let mut m = monitor();
    let mut status = crate::estimator::Estimator::new(Default::default()).state_summary();
    let mut src = crate::estimator::SourceStatus::default();
    src.innovation = vec![0.3, 0.3];
    src.test_ratio = 2.0;
    let mut look = |m: &mut HealthMonitor, t_ms: i64, over: u64| {
        m.on_sample(&flow(200, 1.0), t_ms * 1000);
        src.tested += 5;
        src.tested_over_gate += over;
        src.last_time_us = Some(t_ms * 1000);
        status.sources.insert("flow".into(), src.clone());
        m.on_estimator(&status, t_ms * 1000);
        m.evaluate(t_ms * 1000)
            .into_iter()
            .filter(|tr| tr.sensor == "flow" && tr.to == HealthState::Failed)
            .count()
    };
    let failed: usize = (0..30).map(|i| look(&mut m, i * 100, 1)).sum();
    assert_eq!(failed, 0);
    assert!(m.usable("flow"));
    let failed: usize = (30..40).map(|i| look(&mut m, i * 100, 4)).sum();
    assert_eq!(failed, 1);
    assert!(!m.usable("flow"));
    let s = m.sensor("flow").expect("flow");
    assert!(
        s.reasons
            .iter()
            .any(|r| r.code == "innovation_rejected" && r.text.contains("4 of 5 samples")),
        "{:?}",
        s.reasons
    );
}

/// A 1 Hz input at 1 Hz is never "rate low", whenever it is looked at between samples
/// (PX4's land detector: it read 0.5 Hz 0.9 s after a sample); at a third of its rate
/// it is.
#[test]
fn a_slow_input_at_its_rate_is_not_rate_low_between_samples() {
    let mut m = HealthMonitor::new(
        HealthConfig::default(),
        &[InputSpec::new("gps", SensorKind::Gnss, 1.0)],
    );
    let mut worst = HealthState::Ok;
    for k in 0..20 {
        let t = k * 1_000_000;
        m.on_sample(&fix(0.0, GnssFixType::Fix3d), t);
        for dt in [0, 300_000, 600_000, 900_000, 990_000] {
            m.evaluate(t + dt);
            let s = m
                .sensor("gps")
                .map(|s| s.state)
                .unwrap_or(HealthState::NoData);
            worst = worst.max(s);
        }
        let h = m.sensors.get("gps").expect("gps");
        if k > 0 {
            assert!(
                h.rate_hz(t + 900_000) > 0.95,
                "{} Hz",
                h.rate_hz(t + 900_000)
            );
        }
    }
    assert_eq!(worst, HealthState::Ok);
    let mut m = HealthMonitor::new(
        HealthConfig::default(),
        &[InputSpec::new("gps", SensorKind::Gnss, 3.0)],
    );
    for k in 0..20 {
        let t = k * 1_000_000;
        m.on_sample(&fix(0.0, GnssFixType::Fix3d), t);
        for dt in (0..10).map(|i| i * 100_000) {
            m.evaluate(t + dt);
        }
    }
    let s = m.sensor("gps").expect("gps");
    assert_eq!(s.state, HealthState::Degraded, "{s:?}");
}
