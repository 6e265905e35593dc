//! Facade tests over the simulator (crate::sim) and constructed sequences.

use super::ekf::GRAVITY;
use super::*;
use crate::geo::LocalEnu;
use crate::sample::{
    Attitude, GnssFix, Imu, LandedState, Odometry, OpticalFlow, Range, Tof, VehicleState,
};
use crate::sim::sensors::DEMO_STREAMS;
use crate::sim::truth::{truth, TruthState};
use crate::sim::Simulator;
use nalgebra::{UnitQuaternion, Vector2};

fn sim_samples(seed: u64, duration_s: f64) -> (Vec<(Sample, TruthState)>, LocalEnu) {
    sim_samples_of(DEMO_STREAMS, seed, duration_s)
}

fn sim_samples_of(
    streams: &[crate::sim::sensors::StreamSpec],
    seed: u64,
    duration_s: f64,
) -> (Vec<(Sample, TruthState)>, LocalEnu) {
    // The mechanics under test (re-runs, down-sampling, segments, resets) show in
    // centimetres: a GNSS good to 0.2 m (an RTK float, say), which it reports as such.
    let hardware = crate::sim::sensors::Hardware {
        gnss_std_m: (0.2, 0.3),
        ..crate::sim::sensors::Hardware::default()
    };
    let sim = Simulator::new(streams, seed, duration_s).with_hardware(hardware);
    let origin = sim.origin();
    let v = sim
        .map(|e| {
            (
                Sample {
                    source: Arc::from(streams[e.stream].input_id),
                    stamp_us: Some((e.measured_t * 1e6).round() as i64),
                    arrival_us: (e.publish_t * 1e6).round() as i64,
                    data: e.data,
                },
                e.truth,
            )
        })
        .collect();
    (v, origin)
}

fn cfg(mode: Mode) -> EstimatorConfig {
    EstimatorConfig {
        mode,
        ..EstimatorConfig::default()
    }
}

/// The simulated vehicle's configuration: the default one. Its GPS reports what its
/// error is (here 0.2 m 1σ horizontal, 85 % of it a slow wander over 120 s, see
/// sim/sensors.rs), which the default GNSS model takes as it is.
fn sim_cfg(mode: Mode) -> EstimatorConfig {
    cfg(mode)
}

/// Truth position in the estimator's frame (its origin may be the first GNSS fix).
struct Frame {
    sim: LocalEnu,
    ours: Option<((f64, f64, f64), LocalEnu)>,
}

impl Frame {
    fn in_our_frame(&mut self, origin: Option<(f64, f64, f64)>, p: Vector3<f64>) -> Vector3<f64> {
        let Some(o) = origin else { return p };
        let enu = match &self.ours {
            Some((k, e)) if *k == o => *e,
            _ => {
                let e = LocalEnu::new(o.0, o.1, o.2);
                self.ours = Some((o, e));
                e
            }
        };
        let (lat, lon, alt) = self.sim.to_geodetic(p);
        enu.to_enu(lat, lon, alt)
    }
}

#[derive(Debug, Default)]
struct Score {
    sq: f64,
    n: f64,
    nees: f64,
    nees_n: f64,
    /// Per axis, Σ e²/σ².
    nees_axis: [f64; 3],
    invalid: usize,
}

impl Score {
    fn rmse(&self) -> f64 {
        (self.sq / self.n.max(1.0)).sqrt()
    }
    fn nees(&self) -> f64 {
        self.nees / self.nees_n.max(1.0)
    }
    fn nees_axis(&self) -> [f64; 3] {
        self.nees_axis.map(|v| v / self.n.max(1.0))
    }
}

/// Run the estimator over a simulated flight and score the fused position against the
/// truth at the pose's time, once per IMU sample after `warmup_s`.
fn run(mode: Mode, seed: u64, duration_s: f64, warmup_s: f64) -> (Score, Vec<EstimatorEvent>) {
    let (s, ev, _) = run_with(sim_cfg(mode), seed, duration_s, warmup_s);
    (s, ev)
}

/// Also returns the RMSE of the T265 alone, anchored as the estimator anchors it (at the
/// start pose, in the published frame).
fn run_with(
    config: EstimatorConfig,
    seed: u64,
    duration_s: f64,
    warmup_s: f64,
) -> (Score, Vec<EstimatorEvent>, f64) {
    let (samples, sim_origin) = sim_samples(seed, duration_s);
    let mut est = Estimator::new(config);
    let q0 = truth(0.0).attitude;
    let mut t265: (f64, f64) = (0.0, 0.0);
    let mut frame = Frame {
        sim: sim_origin,
        ours: None,
    };
    let mut score = Score::default();
    let mut events = vec![];
    let mut last_t = i64::MIN;
    for (s, tr) in &samples {
        events.extend(est.process(s));
        if let (SensorData::Odometry(o), Some(p)) = (&s.data, est.pose()) {
            if tr.t >= warmup_s {
                let e = q0 * o.position - frame.in_our_frame(p.origin, tr.position);
                t265.0 += e.norm_squared();
                t265.1 += 1.0;
            }
        }
        if s.source.as_ref() != "imu" {
            continue;
        }
        let Some(p) = est.pose() else { continue };
        if p.time_us == last_t || (p.time_us as f64) * 1e-6 < warmup_s {
            continue;
        }
        last_t = p.time_us;
        if !p.valid {
            score.invalid += 1;
            continue;
        }
        let tr = frame.in_our_frame(p.origin, truth(p.time_us as f64 * 1e-6).position);
        let e = p.position - tr;
        score.sq += e.norm_squared();
        score.n += 1.0;
        if let Some(inv) = p.position_cov.try_inverse() {
            score.nees += e.dot(&(inv * e));
            score.nees_n += 1.0;
        }
        for a in 0..3 {
            score.nees_axis[a] += e[a] * e[a] / p.position_cov[(a, a)].max(1e-12);
        }
    }
    (score, events, (t265.0 / t265.1.max(1.0)).sqrt())
}

/// RMSE of the raw single sources against truth (sim frame): GNSS fixes (3D fixes only)
/// and T265 aligned with the true start pose (an oracle alignment, its best case).
fn single_source_rmse(seed: u64, duration_s: f64, warmup_s: f64) -> BTreeMap<&'static str, f64> {
    let (samples, origin) = sim_samples(seed, duration_s);
    let start = truth(0.0);
    let mut acc: BTreeMap<&'static str, (f64, f64)> = BTreeMap::new();
    for (s, tr) in &samples {
        if tr.t < warmup_s {
            continue;
        }
        let (name, p) = match &s.data {
            SensorData::Gnss(g) if g.fix != crate::sample::GnssFixType::NoFix => {
                ("gps", origin.to_enu(g.lat_deg, g.lon_deg, g.alt_m))
            }
            SensorData::Odometry(o) => ("t265", start.attitude * o.position + start.position),
            _ => continue,
        };
        let a = acc.entry(name).or_default();
        a.0 += (p - tr.position).norm_squared();
        a.1 += 1.0;
    }
    acc.into_iter()
        .map(|(k, (sq, n))| (k, (sq / n).sqrt()))
        .collect()
}

/// Outdoors + indoors with every stream. The published frame is anchored at the first
/// GNSS fix, so the single sources are scored in that frame too: GNSS as measured, the
/// T265 anchored at the start pose as the estimator does (its frame offset is the first
/// fix's error). The T265 with an oracle alignment (true start pose, sim frame) is
/// reported for reference.
#[test]
fn sim_every_mode_beats_the_best_single_source() {
    let (dur, warm) = (300.0, 5.0);
    let single = single_source_rmse(11, dur, warm);
    let mut report = format!("single sources (sim frame): {single:?}\n");
    for mode in [Mode::Ekf, Mode::Wrls, Mode::WrlsEkf] {
        let (s, ev, t265) = run_with(sim_cfg(mode), 11, dur, warm);
        let resets = ev.iter().filter(|e| e.kind() == "monitor_reset").count();
        let best = single["gps"].min(t265);
        report += &format!(
            "{}: rmse {:.4} m, nees {:.2}, invalid {}, monitor resets {}; t265 in this frame {:.4}\n",
            mode.as_str(),
            s.rmse(),
            s.nees(),
            s.invalid,
            resets,
            t265
        );
        assert!(s.n > 1000.0, "{report}");
        // In the GNSS frame every track carries the GNSS's slow error (its wander over
        // minutes, which no averaging removes): fused, no worse than the best source.
        assert!(
            s.rmse() < best + 0.1,
            "{} worse than best single source\n{report}",
            mode.as_str()
        );
    }
    println!("{report}");
}

/// Without GNSS the frame is the take-off pose for every track: each mode against the
/// T265 (the best single position source) aligned with the true start pose.
#[test]
fn sim_without_gnss_every_mode_beats_the_t265() {
    let (dur, warm) = (300.0, 5.0);
    let single = single_source_rmse(12, dur, warm);
    let mut report = format!("single sources: {single:?}\n");
    let mut results = Vec::new();
    for mode in [Mode::Ekf, Mode::Wrls, Mode::WrlsEkf] {
        let mut c = sim_cfg(mode);
        c.sources.insert(
            "gps".into(),
            SourceConfig {
                fuse: false,
                ..SourceConfig::default()
            },
        );
        let (s, _, _) = run_with(c, 12, dur, warm);
        report += &format!(
            "{} (no gnss): rmse {:.4} m, nees {:.2}, invalid {}\n",
            mode.as_str(),
            s.rmse(),
            s.nees(),
            s.invalid
        );
        results.push(s.rmse());
    }
    println!("{report}");
    // The EKF beats the T265 it fuses; seed 002's WRLS layouts come within 15 % of it.
    assert!(results[0] < single["t265"], "{report}");
    assert!(
        results.iter().all(|r| *r < 1.15 * single["t265"]),
        "{report}"
    );
}

#[test]
fn sim_ekf_nees_is_consistent() {
    // Neither over- nor under-confident on any axis (1 expected), over four flights:
    // the GNSS's slowly wandering error is a few independent draws per axis in a 300 s
    // run, so one run's mean e²/σ² is as those draws fell, and the σ sent overbounds that
    // error 1.3× where one receiver holds the position (`GNSS_SLOW_OVERBOUND`: 1/1.69 of
    // a calibrated error's NEES). The height above the GNSS origin is nearly one draw
    // per run (below 9 in 99.7 % of runs).
    let mut sum = [0.0; 3];
    let seeds = [3, 4, 5, 6];
    for seed in seeds {
        let (s, ev) = run(Mode::Ekf, seed, 300.0, 5.0);
        println!(
            "seed {seed}, ekf 300 s: position NEES mean {:.3} (expected 3), per axis {:?}, rmse {:.4} m, invalid {}",
            s.nees(),
            s.nees_axis(),
            s.rmse(),
            s.invalid
        );
        assert!(
            ev.iter().all(|e| e.kind() != "monitor_reset"),
            "unexpected reset: {:?}",
            ev.iter().find(|e| e.kind() == "monitor_reset")
        );
        assert_eq!(s.invalid, 0);
        let n = s.nees_axis();
        assert!((0.05..9.0).contains(&n[2]), "seed {seed}: {n:?}");
        for (a, v) in n.iter().enumerate() {
            sum[a] += v / seeds.len() as f64;
        }
    }
    assert!(
        (0.3..3.0).contains(&sum[0]) && (0.3..3.0).contains(&sum[1]),
        "mean over the seeds {sum:?}"
    );
}

/// EKF2's IMU down-sampling at 1 kHz: the filter predicts with 5 ms means, the output
/// predictor still with every sample, so the pose is as fresh as without it and as
/// close to the truth.
#[test]
fn a_1_khz_imu_is_down_sampled_without_losing_the_present() {
    let streams = crate::sim::sensors::with_imu_rate(DEMO_STREAMS, 1000.0);
    let (samples, sim_origin) = sim_samples_of(&streams, 3, 40.0);
    let every = EstimatorConfig {
        predict_period_ms: 0.0,
        ..sim_cfg(Mode::Ekf)
    };
    let mut down = Estimator::new(sim_cfg(Mode::Ekf));
    let mut all = Estimator::new(every);
    let mut frame = Frame {
        sim: sim_origin,
        ours: None,
    };
    let (mut sq_down, mut sq_all, mut n, mut newest) = (0.0, 0.0, 0.0, 0);
    for (s, _) in &samples {
        down.process(s);
        all.process(s);
        newest = newest.max(s.stamp_us.unwrap_or(0));
        if s.source.as_ref() != "imu" {
            continue;
        }
        let (Some(a), Some(b)) = (down.pose(), all.pose()) else {
            continue;
        };
        assert_eq!(
            a.time_us, b.time_us,
            "the pose is brought to the same present"
        );
        if a.time_us < 5_000_000 || !a.valid || !b.valid {
            continue;
        }
        let tr = frame.in_our_frame(a.origin, truth(a.time_us as f64 * 1e-6).position);
        sq_down += (a.position - tr).norm_squared();
        sq_all += (b.position - tr).norm_squared();
        n += 1.0;
    }
    assert!(n > 30_000.0, "{n} poses scored");
    let (rmse_down, rmse_all) = ((sq_down / n).sqrt(), (sq_all / n).sqrt());
    assert!(
        rmse_down < 1.15 * rmse_all + 0.002,
        "down-sampled {rmse_down:.4} m vs every sample {rmse_all:.4} m"
    );
    // Against the truth: the GNSS frame's own error (0.2 m horizontal, 0.3 m vertical
    // 1σ, a slow wander) is in every pose.
    assert!(rmse_down < 0.6, "{rmse_down} {rmse_all}");
}

fn pose_bits(p: &FusedPose) -> String {
    serde_json::to_string(p).expect("serialise pose")
}

#[test]
fn late_measurements_rerun_equals_in_order_processing() {
    let (samples, _) = sim_samples(5, 20.0);
    // As published (GNSS arrives 100 ms late, T265 6 ms, ...) vs sorted by measurement
    // time (every sample in order: no re-run ever needed). Without the delay states:
    // a delay the filter finds moves into the times of the samples that come after it
    // is found, which differ between the two orders (each order replays to itself
    // bit for bit, as a recording does).
    let cfg = |m| EstimatorConfig {
        delay_std_s: 0.0,
        ..cfg(m)
    };
    let mut late = Estimator::new(cfg(Mode::Ekf));
    for (s, _) in &samples {
        late.process(s);
    }
    let mut sorted: Vec<&Sample> = samples.iter().map(|(s, _)| s).collect();
    sorted.sort_by_key(|s| (s.stamp_us, rank(s.data.kind())));
    let mut inorder = Estimator::new(cfg(Mode::Ekf));
    for s in sorted {
        inorder.process(s);
    }
    // The late samples held the horizon back; fused to the end, both are one state.
    assert!(late.horizon_us() > 90_000, "{}", late.horizon_us());
    late.flush();
    inorder.flush();
    let (a, b) = (late.pose().expect("pose"), inorder.pose().expect("pose"));
    assert_eq!(pose_bits(&a), pose_bits(&b));
    assert!(a.valid && a.sources.iter().any(|s| s == "gps"), "{a:?}");
}

#[test]
fn deterministic_for_the_same_input() {
    let (samples, _) = sim_samples(9, 15.0);
    let run = |mode| {
        let mut est = Estimator::new(cfg(mode));
        let mut out = String::new();
        for (s, _) in &samples {
            for e in est.process(s) {
                out += &e.to_json(0.0, true).to_string();
            }
            if let Some(p) = est.pose() {
                out += &pose_bits(&p);
            }
        }
        out
    };
    for mode in [Mode::Ekf, Mode::Wrls, Mode::WrlsEkf] {
        assert_eq!(run(mode), run(mode));
    }
}

#[test]
fn odometry_jump_starts_a_segment_without_moving_the_pose() {
    let (samples, sim_origin) = sim_samples(4, 40.0);
    let mut est = Estimator::new(sim_cfg(Mode::Ekf));
    let mut frame = Frame {
        sim: sim_origin,
        ours: None,
    };
    let jump_t = 30.0;
    let mut err_before: Option<Vector3<f64>> = None;
    let mut segment_event = None;
    let mut max_err_after: f64 = 0.0;
    for (s, tr) in &samples {
        let mut s = s.clone();
        if let SensorData::Odometry(o) = &mut s.data {
            if tr.t >= jump_t {
                // The T265 relocalised: its frame moved by 5 m and turned.
                let q = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5);
                o.position = q * o.position + Vector3::new(4.0, -3.0, 0.2);
                o.orientation = q * o.orientation;
            }
        }
        let ev = est.process(&s);
        if let Some(e) = ev
            .iter()
            .find(|e| e.kind() == "segment" && e.time_us > 1_000_000)
        {
            segment_event = Some(e.clone());
        }
        let Some(p) = est.pose() else { continue };
        let t = p.time_us as f64 * 1e-6;
        let err = p.position - frame.in_our_frame(p.origin, truth(t).position);
        if t < jump_t - 0.005 {
            err_before = Some(err);
        } else if t < jump_t + 0.1 {
            // Continuous: the error hardly changes across the 5 m jump (the filter
            // goes on correcting itself as it does every 100 ms).
            let b = err_before.expect("pose before the jump");
            assert!((err - b).norm() < 0.06, "pose jumped by {}", err - b);
        } else {
            max_err_after = max_err_after.max(err.norm());
        }
    }
    let e = segment_event.expect("a segment event");
    assert!(e.message.contains("jump"), "{}", e.message);
    assert!(max_err_after < 0.6, "error after the jump {max_err_after}");
}

#[test]
fn monitor_resets_a_diverged_filter() {
    let (samples, sim_origin) = sim_samples(6, 50.0);
    let mut est = Estimator::new(EstimatorConfig {
        monitor_reset: true,
        ..sim_cfg(Mode::Ekf)
    });
    let mut frame = Frame {
        sim: sim_origin,
        ours: None,
    };
    let mut forced = false;
    let mut reset = None;
    let mut counter_before = 0;
    for (s, tr) in &samples {
        if !forced && tr.t > 30.0 {
            // Force a divergence: the filter believes it is 10 m east.
            counter_before = est.pose().expect("pose").reset_counter;
            if let Some(bank) = est.core.ekf.as_mut() {
                bank.each(|ekf| ekf.shift_position(Vector3::new(10.0, 0.0, 0.0)));
            }
            est.clear_history();
            forced = true;
        }
        for e in est.process(s) {
            if e.kind() == "monitor_reset" {
                reset = Some(e);
            }
        }
    }
    let e = reset.expect("monitor reset");
    let Event::MonitorReset(m) = &e.what else {
        panic!("{e:?}")
    };
    assert_eq!(m.monitor, "gps_imu");
    let p = est.pose().expect("pose");
    assert_eq!(p.reset_counter, counter_before.wrapping_add(1));
    let tr = frame.in_our_frame(p.origin, truth(p.time_us as f64 * 1e-6).position);
    assert!(
        (p.position - tr).norm() < 1.0,
        "{}",
        (p.position - tr).norm()
    );
    assert!(p.valid);
}

#[test]
fn gnss_outlier_is_gated_and_reported() {
    let (samples, _) = sim_samples(7, 20.0);
    let mut est = Estimator::new(sim_cfg(Mode::Ekf));
    let mut rejected = false;
    let mut pos_before = None;
    for (s, tr) in &samples {
        let mut s = s.clone();
        let outlier = (15.0..15.1).contains(&tr.t);
        if let (true, SensorData::Gnss(g)) = (outlier, &mut s.data) {
            g.lat_deg += 50.0 / 111_000.0;
            pos_before = est.pose().map(|p| p.position);
        }
        let ev = est.process(&s);
        if ev
            .iter()
            .any(|e| e.kind() == "gate_reject" && e.source.as_deref() == Some("gps"))
        {
            rejected = true;
        }
        if let (true, Some(b), SensorData::Gnss(_)) = (outlier, pos_before, &s.data) {
            let p = est.pose().expect("pose").position;
            assert!(
                (p - b).norm() < 0.2,
                "outlier moved the pose by {}",
                (p - b).norm()
            );
        }
    }
    assert!(rejected);
    assert!(est.test_ratios().any(|(s, r)| s == "gps" && r.is_finite()));
}

#[test]
fn invalid_before_initialisation_and_without_aiding() {
    let mut est = Estimator::new(EstimatorConfig::default());
    assert!(est.pose().is_none());
    let st = est.state_summary();
    assert!(!st.valid && st.invalid_reason.as_deref() == Some("not initialised"));
    // Initialise from odometry, then feed only IMU for 2 s: invalid (no aiding).
    let imu = |t: i64| Sample {
        source: Arc::from("imu"),
        stamp_us: Some(t),
        arrival_us: t + 2_000,
        data: SensorData::Imu(Imu {
            gyro: Some(Vector3::zeros()),
            accel: Some(Vector3::new(0.0, 0.0, GRAVITY)),
            orientation: Some(UnitQuaternion::identity()),
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        }),
    };
    est.process(&imu(0));
    est.process(&Sample {
        source: Arc::from("t265"),
        stamp_us: Some(1_000),
        arrival_us: 7_000,
        data: SensorData::Odometry(Box::new(Odometry {
            position: Vector3::zeros(),
            orientation: UnitQuaternion::identity(),
            velocity: Some(Vector3::zeros()),
            angular_velocity: None,
            pose_cov: None,
            twist_cov: None,
            frame_id: "odom".into(),
            child_frame_id: "camera".into(),
            reset_counter: None,
            quality: None,
        })),
    });
    let p = est.pose().expect("initialised");
    assert!(p.valid, "{p:?}");
    for i in 1..400 {
        est.process(&imu(i * 5_000));
    }
    let p = est.pose().expect("pose");
    assert!(!p.valid);
    assert!(p.invalid_reason.expect("reason").contains("no position"));
    // NaN never comes out as valid.
    est.core
        .ekf
        .as_mut()
        .expect("ekf")
        .each(|e| e.x[0] = f64::NAN);
    let p = est.pose().expect("pose");
    assert!(!p.valid);
}

#[test]
fn origin_reset_and_calibration_events() {
    let (samples, _) = sim_samples(8, 60.0);
    let mut est = Estimator::new(sim_cfg(Mode::Ekf));
    let mut cal_result = None;
    let mut started = false;
    for (s, tr) in &samples {
        if !started && tr.t > 12.0 {
            let ev = est.start_flow_calibration(s.arrival_us);
            assert_eq!(ev[0].kind(), "calibration_started");
            started = true;
        }
        for e in est.process(s) {
            if e.kind() == "calibration_result" {
                cal_result = Some(e);
            }
        }
    }
    let e = cal_result.expect("calibration result");
    let Event::CalibrationResult(crate::event::CalibrationResult::Done {
        success: true,
        scale_x: sx,
        scale_y: sy,
        ..
    }) = e.what
    else {
        panic!("{e:?}")
    };
    // The sim's ToF reads 2 cm long at 2 m: the true scale is close to 1.
    assert!(
        (sx - 1.0).abs() < 0.1 && (sy - 1.0).abs() < 0.1,
        "{sx} {sy}"
    );
    let before = est.pose().expect("pose");
    let ev = est.reset_origin(before.time_us);
    assert_eq!(ev[0].kind(), "reset");
    let after = est.pose().expect("pose");
    assert_eq!(after.reset_counter, before.reset_counter.wrapping_add(1));
    assert!(after.position.xy().norm() < 1e-9);
    assert!((after.position.z - before.position.z).abs() < 1e-12);
    let st = est.state_summary();
    assert!(serde_json::to_string(&st).is_ok());
}

#[test]
fn gnss_sets_the_origin_and_no_fix_is_skipped() {
    let mut est = Estimator::new(EstimatorConfig::default());
    let imu = Sample {
        source: Arc::from("imu"),
        stamp_us: None,
        arrival_us: 1_000,
        data: SensorData::Imu(Imu {
            gyro: Some(Vector3::zeros()),
            accel: Some(Vector3::new(0.0, 0.0, GRAVITY)),
            orientation: Some(UnitQuaternion::identity()),
            gyro_cov: None,
            accel_cov: None,
            orientation_cov: None,
        }),
    };
    est.process(&imu);
    let mut fix = GnssFix {
        lat_deg: 47.0,
        lon_deg: 8.0,
        alt_m: 500.0,
        fix: crate::sample::GnssFixType::NoFix,
        position_cov: None,
        satellites: Some(3),
        hdop: Some(9.0),
        vdop: None,
        velocity: None,
        velocity_up_known: false,
    };
    let gps = |f: &GnssFix, t: i64| Sample {
        source: Arc::from("gps"),
        stamp_us: None,
        arrival_us: t,
        data: SensorData::Gnss(f.clone()),
    };
    est.process(&gps(&fix, 200_000));
    assert!(est.pose().is_none());
    fix.fix = crate::sample::GnssFixType::Fix3d;
    fix.hdop = Some(0.8);
    let ev = est.process(&gps(&fix, 300_000));
    assert!(ev.iter().any(|e| e.kind() == "origin_set"), "{ev:?}");
    let p = est.pose().expect("initialised");
    assert_eq!(p.origin, Some((47.0, 8.0, 500.0)));
    assert!(p.position.norm() < 1e-9);
}

/// Diagnostics: per-axis errors over time (run with `--ignored --nocapture`).
#[test]
#[ignore]
fn diag_per_axis() {
    let mode = match std::env::var("MODE").as_deref() {
        Ok("wrls") => Mode::Wrls,
        Ok("wrls+ekf") => Mode::WrlsEkf,
        _ => Mode::Ekf,
    };
    let (samples, sim_origin) = sim_samples(11, 300.0);
    let mut c = if std::env::var("DEFAULTCFG").is_ok() {
        cfg(mode)
    } else {
        sim_cfg(mode)
    };
    for off in std::env::var("OFF")
        .unwrap_or_default()
        .split(',')
        .filter(|s| !s.is_empty())
    {
        c.sources.insert(
            off.to_string(),
            SourceConfig {
                fuse: false,
                ..SourceConfig::default()
            },
        );
    }
    let mut est = Estimator::new(c);
    let mut frame = Frame {
        sim: sim_origin,
        ours: None,
    };
    let mut win = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros(), 0.0);
    let mut next = 10.0;
    for (s, _) in &samples {
        for e in est.process(s) {
            if e.kind() != "gate_reject" && e.kind() != "sample_rejected" {
                println!(
                    "event {} {} {:?} {}",
                    e.time_us,
                    e.kind(),
                    e.source,
                    e.message
                );
            }
        }
        if s.source.as_ref() != "imu" {
            continue;
        }
        let Some(p) = est.pose() else { continue };
        let t = p.time_us as f64 * 1e-6;
        let tr = frame.in_our_frame(p.origin, truth(t).position);
        let e = p.position - tr;
        win.0 += e.component_mul(&e);
        for i in 0..3 {
            win.1[i] += e[i] * e[i] / p.position_cov[(i, i)];
        }
        win.2 += 1.0;
        if t > next {
            let st = est.state_summary();
            println!(
                "t {t:6.1} rmse {:.3} {:.3} {:.3}  nees/axis {:.2} {:.2} {:.2}  std {:?} bias {:?} err {:.3} {:.3} {:.3}",
                (win.0.x / win.2).sqrt(),
                (win.0.y / win.2).sqrt(),
                (win.0.z / win.2).sqrt(),
                win.1.x / win.2,
                win.1.y / win.2,
                win.1.z / win.2,
                st.position_std,
                st.accel_bias,
                e.x,
                e.y,
                e.z
            );
            win = (Vector3::zeros(), Vector3::zeros(), 0.0);
            next += 10.0;
        }
    }
    let st = est.state_summary();
    println!(
        "{}",
        serde_json::to_string_pretty(&st.sources).expect("json")
    );
}

/// What a flow + range + attitude vehicle senses at one instant.
struct Seen {
    /// Tilt about body x, rad.
    roll: f64,
    /// Range reading, m.
    range: f64,
    /// Body velocity the flow sees (at the range's height), m/s.
    vel: Vector2<f64>,
    flow_quality: u8,
}

fn seen(roll: f64, range: f64, vel: Vector2<f64>) -> Seen {
    Seen {
        roll,
        range,
        vel,
        flow_quality: 200,
    }
}

/// `data` from `source`, stamped and arriving at `t`.
fn sample_at(source: &str, t: i64, data: SensorData) -> Sample {
    Sample {
        source: Arc::from(source),
        stamp_us: Some(t),
        arrival_us: t,
        data,
    }
}

/// The autopilot says: disarmed, landed.
const DISARMED_ON_GROUND: VehicleState = VehicleState {
    armed: Some(false),
    landed: Some(LandedState::OnGround),
};

/// A flow + range + attitude vehicle (no IMU) at 50 Hz, sensing `at(t)`; `state` the
/// autopilot's word (5 Hz).
fn flow_range_vehicle(
    est: &mut Estimator,
    from_us: i64,
    to_us: i64,
    at: impl Fn(i64) -> Seen,
    state: Option<VehicleState>,
) -> Vec<EstimatorEvent> {
    let mut events = Vec::new();
    let mut t = from_us;
    while t <= to_us {
        let Seen {
            roll,
            range: d,
            vel: v,
            flow_quality,
        } = at(t);
        let sample = |source: &str, data: SensorData| sample_at(source, t, data);
        let q = UnitQuaternion::from_euler_angles(roll, 0.0, 0.0);
        let mut batch = vec![
            sample(
                "attitude",
                SensorData::Attitude(Attitude {
                    orientation: q,
                    rates: None,
                }),
            ),
            sample(
                "range",
                SensorData::Range(Range {
                    distance_m: d,
                    min_m: Some(0.3),
                    max_m: Some(40.0),
                    signal_quality: None,
                    variance: None,
                    orientation: Some(25),
                }),
            ),
            sample(
                "flow",
                SensorData::Flow(OpticalFlow {
                    rate: Some(Vector2::new(v.y / d, -v.x / d)),
                    gyro: Some(Vector3::zeros()),
                    velocity: None,
                    integration_s: Some(0.02),
                    quality: flow_quality,
                    status: None,
                    tof: None,
                }),
            ),
        ];
        if let Some(s) = &state {
            if t % 200_000 == 0 {
                batch.push(sample("state", SensorData::VehicleState(*s)));
            }
        }
        for s in &batch {
            events.extend(est.process(s));
        }
        t += 20_000;
    }
    events
}

/// An IMU at rest, level: no rotation, gravity's specific force.
fn still_imu() -> SensorData {
    SensorData::Imu(Imu::from_rates(
        Some(Vector3::zeros()),
        Some(Vector3::new(0.0, 0.0, GRAVITY)),
    ))
}

fn flow_range_cfg() -> EstimatorConfig {
    EstimatorConfig {
        mode: Mode::Ekf,
        ..EstimatorConfig::default()
    }
}

/// 4 m/s laps of 40 s (the speed reached in 5 s), m/s, at `t` µs.
fn laps_velocity(t: i64) -> Vector2<f64> {
    let turn_rate = 2.0 * std::f64::consts::PI / 40.0;
    let s = t as f64 * 1e-6;
    let speed = 4.0 * (s / 5.0).min(1.0);
    Vector2::new((turn_rate * s).cos(), (turn_rate * s).sin()) * speed
}

/// Issue 44's first flight in kind: laps on flow + range + attitude, no IMU. Nothing
/// there sees a heading, neither the flow's own (its mounting) nor the attitude's
/// error: without accelerations to turn it, the predicted velocity lags every turn,
/// always the same way round, and a filter free to correct the headings took that lag
/// for one (the flow's wandered 8° in 300 s of the `flow-laps` scenario, the fused
/// track farther off than the flow integrated). Considered instead, as the scale error
/// already was: held, their σ carried into the velocity and the position.
#[test]
fn laps_on_a_flow_without_an_imu_learn_no_heading() {
    let mut est = Estimator::new(flow_range_cfg());
    flow_range_vehicle(
        &mut est,
        0,
        120_000_000,
        |t| seen(0.0, 2.0, laps_velocity(t)),
        None,
    );
    let (x, var, names) = est.filter_state().expect("a filter");
    for name in ["flow.heading", "yaw"] {
        let i = names.iter().position(|n| n == name).expect(name);
        let sigma = var[i].sqrt();
        println!("{name}: {:.4} ± {sigma:.4} rad", x[i]);
        assert!(
            x[i].abs() < 1e-6,
            "{name} learnt without a reference: {}",
            x[i]
        );
        assert!(
            sigma > 0.04,
            "{name} σ {sigma}: claimed without a reference"
        );
    }
}

#[test]
fn laps_on_a_flow_without_an_imu_follow_the_flow_integrated() {
    // The same laps, the flow exact: with nothing but the flow telling the velocity,
    // the track is the flow integrated. The constant-velocity stand-in, corrected by
    // each sample, trailed it: its decay read a 4 m/s cruise ~5 % slow and every turn
    // lagged, and those lasting innovations moved the position through its
    // covariance with the velocity and the flow's consider states.
    let mut est = Estimator::new(flow_range_cfg());
    let (mut truth, mut worst) = (Vector2::zeros(), 0.0f64);
    let step = 20_000;
    for second in 0..120i64 {
        let from = second * 1_000_000;
        let to = from + 1_000_000 - step;
        flow_range_vehicle(
            &mut est,
            from,
            to,
            |t| seen(0.0, 2.0, laps_velocity(t)),
            None,
        );
        let mut t = from;
        while t <= to {
            // The position at the sample after this one: the filter moves between
            // samples with the velocity it last took.
            truth += laps_velocity(t) * (step as f64 * 1e-6);
            t += step;
        }
        match est.pose() {
            Some(p) => worst = worst.max((p.position.xy() - truth).norm()),
            // Not started yet: the track starts where the filter does.
            None => truth = Vector2::zeros(),
        }
    }
    let p = est.pose().expect("pose");
    println!(
        "after 120 s: fused {:.2?}, flow integrated {truth:.2?}, worst {worst:.3} m",
        p.position.xy()
    );
    assert!(
        worst < 0.2,
        "fused trails the flow integrated by {worst:.2} m"
    );
}

#[test]
fn a_table_edge_below_moves_the_terrain_not_the_vehicle() {
    // Hovering at 1.5 m; from 10 to 14 s a 1.2 m high table passes below (the range
    // reads 0.3 m, a step no vehicle climbs), then the floor again.
    let mut est = Estimator::new(flow_range_cfg());
    let range = |t: i64| {
        if (10_000_000..14_000_000).contains(&t) {
            0.3 + 1e-3
        } else {
            1.5
        }
    };
    let events = flow_range_vehicle(
        &mut est,
        0,
        20_000_000,
        |t| seen(0.0, range(t), Vector2::zeros()),
        None,
    );
    let resets: Vec<_> = events
        .iter()
        .filter(|e| e.kind() == "terrain_reset")
        .collect();
    assert_eq!(resets.len(), 2, "onto the table and off it: {resets:?}");
    let p = est.pose().expect("pose");
    assert!(p.valid, "{p:?}");
    assert!(
        (p.position.z - 1.5).abs() < 0.1,
        "the vehicle stayed at 1.5 m: {}",
        p.position
    );
    assert!(
        !events.iter().any(|e| e.kind() == "gate_reject"),
        "no reading refused as disagreeing"
    );
}

#[test]
fn flow_and_range_held_on_the_side_are_not_used() {
    // Standing at 0.5 m, then turned onto its side by hand in 0.5 s and held there for
    // 4.5 s (75° of roll): the range reads the far wall and the flow sees it slide by;
    // neither is a ground measurement. While it turns, the flow (compensated for the
    // rotation) sees the floor still and the range the floor, slanted.
    let mut est = Estimator::new(flow_range_cfg());
    let side = 75f64.to_radians();
    let roll = |t: i64| {
        let s = t as f64 * 1e-6;
        side * ((s - 5.0) / 0.5).clamp(0.0, 1.0) * ((10.5 - s) / 0.5).clamp(0.0, 1.0)
    };
    let events = flow_range_vehicle(
        &mut est,
        0,
        12_000_000,
        |t| {
            let r = roll(t);
            if r >= side {
                seen(r, 4.0, Vector2::new(2.0, 0.0))
            } else {
                seen(r, 0.5 / r.cos(), Vector2::zeros())
            }
        },
        None,
    );
    let refused = |what: &str| {
        events
            .iter()
            .any(|e| e.kind() == "sample_rejected" && e.message.contains(what))
    };
    assert!(refused("tilt too large for the flow"));
    assert!(refused("tilt too large for the range finder"));
    let p = est.pose().expect("pose");
    assert!(p.position.xy().norm() < 0.2, "no slide: {}", p.position);
}

#[test]
fn a_vehicle_carried_while_disarmed_is_not_held_on_the_ground() {
    // Disarmed and "landed" all along (a land detector does not see a carry). Lifted to
    // 1 m and walked at 0.8 m/s along x for 5 s; for 3 s of it the flow's quality is
    // too low to use. The ground constraint must not pin the vehicle then (zero
    // velocity, held position): the track keeps its velocity through the gap. The
    // estimate is invalid while carried, valid once set down.
    let mut est = Estimator::new(flow_range_cfg());
    let carried = |t: i64| (5_000_000..10_000_000).contains(&t);
    let poor_flow = |t: i64| (6_500_000..9_500_000).contains(&t);
    let mut valid_while_carried = Vec::new();
    let mut t0 = 0;
    for end in (1..=30).map(|i| i * 500_000) {
        flow_range_vehicle(
            &mut est,
            t0,
            end - 20_000,
            |t| {
                let mut s = if carried(t) {
                    seen(0.0, 1.0, Vector2::new(0.8, 0.0))
                } else {
                    seen(0.0, 0.1, Vector2::zeros())
                };
                if poor_flow(t) {
                    s.flow_quality = 10;
                }
                s
            },
            Some(DISARMED_ON_GROUND),
        );
        if carried(end) && end > 6_000_000 {
            valid_while_carried.push(est.pose().is_some_and(|p| p.valid));
        }
        t0 = end;
    }
    assert!(!valid_while_carried.is_empty());
    assert!(
        valid_while_carried.iter().all(|v| !v),
        "{valid_while_carried:?}"
    );
    let p = est.pose().expect("pose");
    assert!(p.valid, "set down again: {p:?}");
    assert!(
        (p.position.x - 4.0).abs() < 0.5,
        "carried 4 m, the track says {}",
        p.position
    );
}

/// Over dark ground the flow's own quality is drawn around the threshold and what it
/// still calls good reads slow or wrong. Hovering at 1 m, from 5 to 8 s every other
/// sample is poor and the others read 0.5 m/s that is not there: none of them is fused
/// (each comes within `flow_quality_hold_ms` of a poor one), and the flow is fused
/// again once it has read good for the hold (a 2 s walk at 0.5 m/s from 10 s moves the
/// track 1 m). Without the hold the lie moved the track by 1.45 m.
#[test]
fn a_flow_is_held_out_after_a_poor_reading_in_the_air() {
    let mut est = Estimator::new(flow_range_cfg());
    let dark = |t: i64| (5_000_000..8_000_000).contains(&t);
    let events = flow_range_vehicle(
        &mut est,
        0,
        10_000_000,
        |t| {
            if dark(t) && (t / 20_000) % 2 == 0 {
                Seen {
                    flow_quality: 10,
                    ..seen(0.0, 1.0, Vector2::zeros())
                }
            } else if dark(t) {
                seen(0.0, 1.0, Vector2::new(0.5, 0.0))
            } else {
                seen(0.0, 1.0, Vector2::zeros())
            }
        },
        None,
    );
    let held = events
        .iter()
        .filter(|e| e.kind() == "sample_rejected" && e.message.contains("flow_quality_hold_ms"))
        .count();
    assert!(held > 0, "the good-looking samples are held out");
    let p = est.pose().expect("pose");
    assert!(p.valid, "{p:?}");
    assert!(
        p.position.x.abs() < 0.1,
        "the lie is not fused: {}",
        p.position
    );
    flow_range_vehicle(
        &mut est,
        10_020_000,
        12_000_000,
        |_| seen(0.0, 1.0, Vector2::new(0.5, 0.0)),
        None,
    );
    let p = est.pose().expect("pose");
    assert!(
        (p.position.x - 1.0).abs() < 0.15,
        "fused again after the hold: {}",
        p.position
    );
}

/// Tick `k` of a vehicle standing level on its gear from 1 s: a still IMU at 200 Hz and,
/// every fourth tick, the attitude and `sensor`'s sample.
fn still_on_gear(k: i64, sensor: (&str, &SensorData)) -> Vec<Sample> {
    let t = 1_000_000 + k * 5_000;
    let mut batch = vec![sample_at("imu", t, still_imu())];
    if k % 4 == 0 {
        batch.push(sample_at(sensor.0, t, sensor.1.clone()));
        batch.push(sample_at(
            "attitude",
            t,
            SensorData::Attitude(Attitude {
                orientation: UnitQuaternion::identity(),
                rates: None,
            }),
        ));
    }
    batch
}

#[test]
fn a_flow_modules_own_tof_at_its_minimum_starts_the_filter_on_the_ground() {
    // A flow module with its own ToF and nothing else below: on its gear the lens is
    // too close to focus (quality 20) and the ToF reads 2 cm, under its 5 cm minimum.
    // That is the ground, as a range finder at its minimum is: the filter starts there,
    // at rest, before the take-off, not in the climb once the flow sees texture.
    let mut est = Estimator::new(flow_range_cfg());
    let mut started = None;
    let flow = SensorData::Flow(OpticalFlow {
        rate: Some(Vector2::zeros()),
        gyro: Some(Vector3::zeros()),
        velocity: None,
        integration_s: Some(0.02),
        quality: 20,
        status: Some(0),
        tof: Some(Tof {
            distance_m: 0.02,
            strength: None,
            precision: None,
            status: None,
        }),
    });
    for k in 0..600i64 {
        let batch = still_on_gear(k, ("flow", &flow));
        for e in batch.iter().flat_map(|s| est.process(s)) {
            if e.kind() == "initialised" {
                started = Some((e.time_us, e.source.clone()));
            }
        }
    }
    let Some((at, source)) = started else {
        panic!("never started: no ground evidence from the ToF");
    };
    assert_eq!(source.as_deref(), Some("ground"));
    assert!(at < 3_000_000, "started at {at} µs");
    let p = est.pose().expect("a pose");
    assert!(p.valid && p.velocity.norm() < 0.05, "{p:?}");
}

#[test]
fn an_imu_that_has_just_started_is_not_a_carry() {
    // Disarmed on the ground, range at its minimum, the IMU still from its first sample
    // (ArduCopter SITL at start-up). Still, but not yet for the rest time, is not
    // "moving": the estimate is valid from the first pose on, with no `handled` event.
    let mut est = Estimator::new(flow_range_cfg());
    let mut events = Vec::new();
    let mut valid = Vec::new();
    let range = SensorData::Range(Range {
        distance_m: 0.0,
        min_m: Some(0.2),
        max_m: Some(40.0),
        signal_quality: None,
        variance: None,
        orientation: Some(25),
    });
    for k in 0..600i64 {
        let t = 1_000_000 + k * 5_000;
        let mut batch = still_on_gear(k, ("range", &range));
        if k % 40 == 0 {
            batch.push(sample_at(
                "state",
                t,
                SensorData::VehicleState(DISARMED_ON_GROUND),
            ));
        }
        for s in &batch {
            events.extend(est.process(s));
        }
        if let Some(p) = est.pose() {
            valid.push(p.valid);
        }
    }
    // The range's first sample maps 8 ms before the IMU's first (its latency): fused
    // from the empty filter, not dropped as older than the history.
    assert!(
        !events
            .iter()
            .any(|e| e.kind() == "handled" || e.kind() == "late_drop"),
        "{:?}",
        events.iter().map(|e| &e.message).collect::<Vec<_>>()
    );
    // Initialised once the IMU has been still for the rest time; valid from then on.
    assert!(valid.len() > 250, "{}", valid.len());
    assert!(valid.iter().all(|v| *v), "invalid at some pose after start");
}

#[test]
fn a_re_run_fuses_at_least_as_far_as_before() {
    // IMU alone, on time: the horizon is 0 and every sample is fused as it comes. Then
    // a GNSS fix 100 ms late: it is fused by a re-run, and the horizon grows to its
    // lateness. The re-run must still fuse everything fused before it (the output
    // predictor has already let those IMU samples go): the filter's time never moves
    // back.
    let mut est = Estimator::new(EstimatorConfig::default());
    let imu = |t: i64| Sample {
        source: Arc::from("imu"),
        stamp_us: None,
        arrival_us: t,
        data: still_imu(),
    };
    let mut t = 1_000_000;
    while t <= 2_000_000 {
        est.process(&imu(t));
        t += 5_000;
    }
    assert_eq!(est.horizon_us(), 0);
    let before = est.state_time().expect("fused");
    est.process(&Sample {
        source: Arc::from("gps"),
        stamp_us: None,
        arrival_us: 2_000_000,
        data: SensorData::Gnss(GnssFix {
            lat_deg: 47.0,
            lon_deg: 8.0,
            alt_m: 500.0,
            fix: crate::sample::GnssFixType::Fix3d,
            position_cov: None,
            satellites: Some(12),
            hdop: Some(0.8),
            vdop: None,
            velocity: None,
            velocity_up_known: false,
        }),
    });
    assert!(est.horizon_us() >= 90_000, "{}", est.horizon_us());
    let after = est.state_time().expect("fused");
    assert!(
        after >= before,
        "fused to {after} after the re-run, {before} before"
    );
}

#[test]
fn a_samples_gate_tests_count_once_and_over_the_gate_once() {
    let mut s = SourceStatus::default();
    // A T265 sample: position accepted, body velocity over the gate.
    assert!(!s.count_test(1_000, 0.4));
    assert!(s.count_test(1_000, 3.0));
    // A second sample: both updates over the gate.
    assert!(!s.count_test(6_000, 2.0));
    assert!(s.count_test(6_000, 5.0));
    // A third, accepted; a fourth whose ratio is not a number.
    assert!(!s.count_test(11_000, 0.2));
    assert!(!s.count_test(16_000, f64::NAN));
    assert_eq!((s.tested, s.tested_over_gate), (4, 3));
    assert_eq!(s.last_time_us, Some(16_000));
}

/// An IMU at 2 Hz (a log's `vehicle_imu`) cannot drive the prediction: after its first
/// sample every one is refused, saying why; the same IMU at 200 Hz is used.
#[test]
fn an_imu_too_slow_to_integrate_is_refused() {
    let imu = |t: i64| Sample {
        source: Arc::from("imu"),
        stamp_us: Some(t),
        arrival_us: t,
        data: SensorData::Imu(Imu::from_rates(
            Some(Vector3::zeros()),
            Some(Vector3::new(0.0, 0.0, GRAVITY)),
        )),
    };
    for (period_us, refused) in [(500_000, true), (5_000, false)] {
        let mut est = Estimator::new(EstimatorConfig::default());
        let mut said = vec![];
        for i in 0..10 {
            for e in est.process(&imu(i * period_us)) {
                said.push(format!("{e:?}"));
            }
        }
        let refusals = said
            .iter()
            .filter(|e| e.contains("too far apart to integrate"))
            .count();
        assert_eq!(refusals > 0, refused, "{period_us} µs: {said:?}");
        assert_eq!(est.core.imu.last.is_some(), !refused, "{period_us} µs");
    }
}

/// A 1 Hz source (the autopilot's HEARTBEAT armed state) is used between its samples:
/// the list of sources does not drop and re-add it every second (the PX4 flights
/// logged a source switch a second for it).
#[test]
fn a_1_hz_source_stays_in_the_used_list_between_its_samples() {
    let mut est = Estimator::new(flow_range_cfg());
    let hover = |_t: i64| Seen {
        roll: 0.0,
        range: 1.5,
        vel: Vector2::zeros(),
        flow_quality: 200,
    };
    let mut switches = Vec::new();
    // Every 1.2 s: a HEARTBEAT a little late each time, past the 1 s aiding timeout.
    for k in 0..20i64 {
        let t = k * 1_200_000;
        let mut events = flow_range_vehicle(&mut est, t, t + 1_180_000, hover, None);
        events.extend(est.process(&sample_at(
            "armed",
            t + 1_190_000,
            SensorData::VehicleState(VehicleState {
                armed: Some(true),
                landed: None,
            }),
        )));
        for e in events {
            if let Event::SourceSwitch(crate::event::SourceSwitch::Fused {
                added, removed, ..
            }) = &e.what
            {
                if added.iter().chain(removed).any(|s| s == "armed") {
                    switches.push((t, added.clone(), removed.clone()));
                }
            }
        }
    }
    // Its interval is known from its second sample on; from then it is never removed
    // (without it: removed and added again every cycle).
    let later: Vec<_> = switches.iter().filter(|s| s.0 >= 2_400_000).collect();
    assert!(
        later.iter().all(|s| s.2.is_empty()) && later.len() <= 1,
        "{switches:?}"
    );
    assert!(switches.len() <= 3, "{switches:?}");
}

/// Issue 45's lock-out: the GNSS (without velocity) is the only horizontal source,
/// and from 30 s its fixes are 40 m from where the IMU has carried the filter (which
/// of the two is wrong the filter cannot know). Each fix is refused at the gate; once
/// nothing has aided the horizontal for the aiding timeout the filter resets to the
/// GNSS, says so, and fuses it again instead of refusing it for good.
#[test]
fn the_only_position_source_refused_is_reset_to_not_locked_out() {
    let gnss_imu: Vec<crate::sim::sensors::StreamSpec> = DEMO_STREAMS
        .iter()
        .filter(|s| {
            use crate::sample::SensorKind as K;
            matches!(s.kind, K::Imu | K::Attitude | K::Gnss)
        })
        .copied()
        .collect();
    let (samples, _) = sim_samples_of(&gnss_imu, 3, 50.0);
    let mut est = Estimator::new(sim_cfg(Mode::Ekf));
    let mut resets = vec![];
    let mut accepted_at_step = None;
    for (s, tr) in &samples {
        let mut s = s.clone();
        if let SensorData::Gnss(g) = &mut s.data {
            g.velocity = None;
            if tr.t >= 30.0 {
                g.lat_deg += 40.0 / 111_000.0;
                accepted_at_step.get_or_insert_with(|| {
                    est.state_summary()
                        .sources
                        .get("gps")
                        .map_or(0, |s| s.accepted)
                });
            }
        }
        for e in est.process(&s) {
            if let crate::event::Event::Reset(r) = &e.what {
                resets.push((tr.t, format!("{r:?}")));
            }
        }
    }
    let accepted = est
        .state_summary()
        .sources
        .get("gps")
        .map_or(0, |s| s.accepted);
    let before = accepted_at_step.expect("stepped");
    println!("resets {resets:?}; gps accepted {before} at the step, {accepted} at the end");
    // One reset, soon after the step, and the GNSS fused since (10 Hz for 20 s).
    assert_eq!(resets.len(), 1, "{resets:?}");
    assert!((30.0..35.0).contains(&resets[0].0), "{resets:?}");
    assert!(accepted > before + 100, "{accepted} vs {before}");
    // The receiver is the one that stepped: the truth is where the IMU had it, 40 m
    // south. A jump that large is the receiver's doubt: the pose is not sent valid on
    // it, and its σ holds the truth.
    let pose = est.pose().expect("a pose");
    let truth = samples.last().expect("samples").1.position;
    let (north, sigma) = (pose.position.y - truth.y, pose.position_cov[(1, 1)].sqrt());
    println!(
        "{north:.1} m north of the truth, σ {sigma:.1} m, valid {}",
        pose.valid
    );
    assert!(!pose.valid && north.abs() < 3.0 * sigma);
}

/// A receiver's multipath that came in slowly and went at once: the filter followed
/// it while it grew, then refuses every fix that is right again, while the same
/// receiver's velocity still passes. Which of the two is wrong it cannot know, so the
/// covariance sent covers the refused fixes until a position is accepted: before, the
/// accepted velocity cleared the refusal and σ stayed at its fix-fed size (randomised
/// draw 74: 2 595 poses beyond 5σ).
#[test]
fn a_refused_position_is_covered_while_only_its_velocity_passes() {
    let offset = |t: f64| {
        if (20.0..60.0).contains(&t) {
            6.0 * ((t - 20.0) / 30.0).min(1.0)
        } else {
            0.0
        }
    };
    assert_covered_with_offset_north(5, 90.0, 60.0, offset, 80);
}

/// A receiver's multipath that came in at once and went out slowly: its fixes are
/// refused while the offset is large (its velocity still passing), and the first that
/// passes the gate at its edge moves the estimate onto the offset that remains. The
/// long refusal is not settled by that fix: what it said fades over a minute, so the
/// covariance sent covers the estimate that followed the liar (randomised draw 55: 1.7
/// m moved, σ back to 0.67 m, 502 poses beyond 5σ).
#[test]
fn a_long_refusal_is_not_settled_by_the_fix_that_ends_it() {
    let offset = |t: f64| {
        if t >= 20.0 {
            8.0 * (1.0 - (t - 25.0).max(0.0) / 40.0).max(0.0)
        } else {
            0.0
        }
    };
    assert_covered_with_offset_north(7, 90.0, 20.0, offset, 200);
}

/// A GNSS + IMU flight whose fixes are `offset(t)` m north of the truth keeps at least
/// 99 % of its valid poses after `from_s` within 3σ, and has more than `min_poses`.
fn assert_covered_with_offset_north(
    seed: u64,
    duration_s: f64,
    from_s: f64,
    offset: impl Fn(f64) -> f64,
    min_poses: usize,
) {
    let score = gnss_edited_flight(seed, duration_s, from_s, |g, t| {
        g.lat_deg += offset(t) / 111_000.0;
    });
    println!("{score:?}");
    assert!(score.poses > min_poses, "{score:?}");
    assert!(score.within_3_sigma >= 0.99, "{score:?}");
}

/// A receiver refused up to an outage (an 8 m multipath offset that came in at once,
/// its velocity still passing) and reset to when its fixes return: which of the two
/// was wrong nobody knows, so the position taken through the fix is as uncertain as
/// the jump. Before, it was reset onto the offset with the fix's σ (randomised draw 86:
/// 10.7 m off with σ 1 m, 1 099 poses beyond 5σ).
#[test]
fn a_reset_to_a_receiver_refused_before_its_outage_is_as_uncertain_as_the_jump() {
    let score = reset_after_outage_onto_offset(160.0, 48.0, 20.0, 40.0..48.0);
    // Invalid while the doubt is beyond the alert limit, valid again as it fades.
    assert!(score.poses > 100, "{score:?}");
    assert!(score.within_3_sigma >= 0.99, "{score:?}");
}

/// A lone receiver back from a 3 s outage 8 m into multipath, which nothing refused
/// before: the estimate was held by the no-aiding constraints, and the fix resets the
/// position. What it teaches is unchecked, and the σ of the hold says nothing of it:
/// the position taken through the fix is as uncertain as the jump. Before, it was
/// reset onto the offset with the hold's σ (randomised seed 3, draw 19: 8.7σ off,
/// 2 182 poses beyond 5σ).
#[test]
fn a_reset_onto_multipath_after_an_outage_is_as_uncertain_as_the_jump() {
    let score = reset_after_outage_onto_offset(120.0, 40.0, 43.0, 40.0..43.0);
    assert!(score.poses > 100, "{score:?}");
    assert!(score.within_3_sigma >= 0.99, "{score:?}");
}

/// A GNSS + IMU flight (seed 6) whose fixes are 8 m north of the truth from
/// `offset_from_s` on and missing over `outage` (s), scored from `from_s`.
fn reset_after_outage_onto_offset(
    duration_s: f64,
    from_s: f64,
    offset_from_s: f64,
    outage: std::ops::Range<f64>,
) -> FlightScore {
    let score = gnss_edited_flight(6, duration_s, from_s, |g, t| {
        if t >= offset_from_s {
            g.lat_deg += 8.0 / 111_000.0;
        }
        if outage.contains(&t) {
            g.fix = crate::sample::GnssFixType::NoFix;
        }
    });
    println!("{score:?}");
    score
}

/// [`gnss_imu_flight_scored`] with the default configuration and every GNSS fix
/// edited by `edit` (the fix, its time in s).
fn gnss_edited_flight(
    seed: u64,
    duration_s: f64,
    from_s: f64,
    edit: impl Fn(&mut crate::sample::GnssFix, f64),
) -> FlightScore {
    let (score, _, _) =
        gnss_imu_flight_scored(sim_cfg(Mode::Ekf), seed, duration_s, from_s, |s, tr| {
            let mut s = s.clone();
            if let SensorData::Gnss(g) = &mut s.data {
                edit(g, tr.t);
            }
            vec![s]
        });
    score
}

/// The DEMO streams of some kinds only.
fn streams_of(kinds: &[crate::sample::SensorKind]) -> Vec<crate::sim::sensors::StreamSpec> {
    DEMO_STREAMS
        .iter()
        .filter(|s| kinds.contains(&s.kind))
        .copied()
        .collect()
}

/// Worst horizontal error of the valid poses after `from_s` (at each fix), the IMUs
/// that drove the prediction, and the estimator at the end, of a GNSS + IMU + attitude
/// flight whose every sample `batch` turns into what goes in (itself, more, nothing).
fn gnss_imu_flight(
    seed: u64,
    duration_s: f64,
    from_s: f64,
    batch: impl Fn(&Sample, &TruthState) -> Vec<Sample>,
) -> (f64, Vec<String>, Estimator) {
    let (score, driving, est) =
        gnss_imu_flight_scored(sim_cfg(Mode::Ekf), seed, duration_s, from_s, batch);
    (score.worst_m, driving, est)
}

/// What [`gnss_imu_flight`] measures of the valid poses.
#[derive(Debug, Default)]
struct FlightScore {
    worst_m: f64,
    /// Poses within 3σ on east and on north (the smaller), and how many.
    within_3_sigma: f64,
    poses: usize,
}

fn gnss_imu_flight_scored(
    cfg: EstimatorConfig,
    seed: u64,
    duration_s: f64,
    from_s: f64,
    batch: impl Fn(&Sample, &TruthState) -> Vec<Sample>,
) -> (FlightScore, Vec<String>, Estimator) {
    use crate::sample::SensorKind as K;
    let streams = streams_of(&[K::Imu, K::Attitude, K::Gnss]);
    let (samples, origin) = sim_samples_of(&streams, seed, duration_s);
    let mut est = Estimator::new(cfg);
    let mut frame = Frame {
        sim: origin,
        ours: None,
    };
    let (mut worst, mut driving) = (0.0f64, vec![]);
    let (mut within, mut poses) = ([0usize; 2], 0usize);
    for (s, tr) in &samples {
        for b in &batch(s, tr) {
            for e in est.process(b) {
                if let crate::event::Event::SourceSwitch(crate::event::SourceSwitch::Imu {
                    imu,
                    ..
                }) = &e.what
                {
                    driving.push(imu.clone());
                }
            }
        }
        if tr.t < from_s || s.source.as_ref() != "gps" {
            continue;
        }
        if let Some(p) = est.pose().filter(|p| p.valid) {
            let at = frame.in_our_frame(p.origin, truth(p.time_us as f64 * 1e-6).position);
            let e = p.position - at;
            worst = worst.max(e.xy().norm());
            poses += 1;
            for (a, w) in within.iter_mut().enumerate() {
                *w += usize::from(e[a].abs() <= 3.0 * p.position_cov[(a, a)].sqrt());
            }
        }
    }
    let score = FlightScore {
        worst_m: worst,
        within_3_sigma: within[0].min(within[1]) as f64 / poses.max(1) as f64,
        poses,
    };
    (score, driving, est)
}

/// `s` from another source.
fn renamed(s: &Sample, source: &str, data: SensorData) -> Sample {
    Sample {
        source: Arc::from(source),
        data,
        ..s.clone()
    }
}

/// Two IMUs, the second going wrong in flight (2 m/s² of vibration rectification, as
/// one of three IMUs did on a real log): one drives the prediction, the other waits
/// and never pulls it (each IMU has its own biases, the filter one set of them).
#[test]
fn one_imu_drives_the_prediction_and_a_second_one_waits() {
    let (alone, _, _) = gnss_imu_flight(7, 60.0, 25.0, |s, _| vec![s.clone()]);
    let (worst, driving, _) = gnss_imu_flight(7, 60.0, 25.0, |s, tr| match &s.data {
        SensorData::Imu(imu) => {
            // From 20 s on, 2 m/s² wandering with a 3 s period: no bias state follows it.
            let mut bad = imu.clone();
            if tr.t >= 20.0 {
                let w = (tr.t * 2.0).sin();
                bad.accel = bad.accel.map(|a| a + Vector3::new(2.0 * w, -1.5 * w, -2.0));
            }
            vec![s.clone(), renamed(s, "imu_2", SensorData::Imu(bad))]
        }
        _ => vec![s.clone()],
    });
    println!(
        "worst horizontal error: one IMU {alone:.2} m, beside a failing second {worst:.2} m; driving {driving:?}"
    );
    assert_eq!(driving, ["imu"], "{driving:?}");
    assert!(worst < alone + 0.2, "{worst} vs {alone}");
}

/// The IMU that drives falls silent: the next one takes over, said, and the pose
/// stays valid and as good.
#[test]
fn a_second_imu_takes_over_when_the_first_stops() {
    let (alone, _, _) = gnss_imu_flight(8, 50.0, 20.0, |s, _| vec![s.clone()]);
    let (worst, driving, est) = gnss_imu_flight(8, 50.0, 20.0, |s, tr| match &s.data {
        SensorData::Imu(_) if tr.t >= 30.0 => vec![renamed(s, "imu_2", s.data.clone())],
        SensorData::Imu(_) => vec![s.clone(), renamed(s, "imu_2", s.data.clone())],
        _ => vec![s.clone()],
    });
    println!("driving {driving:?}; worst {worst:.2} m against {alone:.2} m with one IMU");
    assert_eq!(driving, ["imu", "imu_2"], "{driving:?}");
    assert!(est.pose().is_some_and(|p| p.valid));
    assert!(worst < alone + 0.2, "{worst} vs {alone}");
}

/// An attitude that is off by what an autopilot's is in flight (a tilt error of up to
/// 2° wandering over 12–18 s: 0.3 m/s² of specific force the noise model does not
/// have): the filter learns from the GNSS velocities that its prediction is worse than
/// modelled, keeps fusing the fixes, and its σ holds the truth. Without the learning:
/// 81 % within 3σ, a fifth of the fixes refused.
///
/// The GNSS's delay state is off here (`delay_std_s` 0): with it, the velocities
/// "see" a 0.3 ± 0.04 s delay in the wandering tilt (an attitude error comes and goes
/// with the vehicle's accelerations, as a delay's signature does) and 40 % of the poses
/// are within 3σ, learning or not. That is a weakness of the delay states still open
/// (BENCHMARKS.md, stop 50).
#[test]
fn a_prediction_worse_than_its_model_is_learnt_from_the_velocities() {
    let tilted = |s: &Sample, tr: &TruthState| {
        let roll = 2f64.to_radians() * (tr.t * 0.5).sin();
        let pitch = 2f64.to_radians() * (tr.t * 0.35 + 1.0).sin();
        let tilt = UnitQuaternion::from_euler_angles(roll, pitch, 0.0);
        let data = match &s.data {
            SensorData::Attitude(a) => SensorData::Attitude(Attitude {
                orientation: a.orientation * tilt,
                ..a.clone()
            }),
            SensorData::Imu(i) => SensorData::Imu(Imu {
                orientation: i.orientation.map(|q| q * tilt),
                ..i.clone()
            }),
            other => other.clone(),
        };
        vec![renamed(s, &s.source, data)]
    };
    let cfg = EstimatorConfig {
        delay_std_s: 0.0,
        ..sim_cfg(Mode::Ekf)
    };
    let (score, _, est) = gnss_imu_flight_scored(cfg, 11, 120.0, 30.0, tilted);
    let gps = est
        .state_summary()
        .sources
        .get("gps")
        .cloned()
        .expect("gps");
    let refused = gps.rejected as f64 / (gps.accepted + gps.rejected).max(1) as f64;
    println!("{score:?}; GNSS refused {:.1} %", 100.0 * refused);
    assert!(score.poses > 500, "{score:?}");
    assert!(score.within_3_sigma >= 0.97, "{score:?}");
    assert!(score.worst_m < 1.0, "{score:?}");
    assert!(refused < 0.02, "{refused}");
}

/// A delay moved into a source's sample times never takes them past the history: a
/// GNSS whose delay the filter took for 440 ms (on laps a delay and a turn look alike)
/// had its fixes moved earlier than the oldest snapshot and dropped, 16 s at a time, so
/// that nothing could show the delay was wrong (randomised draw 488).
#[test]
fn a_delay_moved_into_the_times_keeps_the_samples_in_the_history() {
    let (samples, _) = sim_samples(7, 40.0);
    let mut est = Estimator::new(sim_cfg(Mode::Ekf));
    let (before, after): (Vec<_>, Vec<_>) =
        samples.iter().partition(|(s, _)| s.arrival_us < 20_000_000);
    for (s, _) in &before {
        est.process(s);
    }
    // The filter sure the GNSS is 0.55 s later than configured.
    let set = |b: &mut bank::Bank| {
        b.each(|e| {
            let i = e.delay_state("gps", 1e-6);
            e.x[i] = 0.55;
            e.p[(i, i)] = 1e-6;
        })
    };
    if let Some(b) = est.core.ekf.as_mut() {
        set(b);
    }
    for (_, snap) in est.snaps.iter_mut() {
        if let Some(b) = snap.ekf.as_mut() {
            set(b);
        }
    }
    est.adopt_delays();
    let shift = est.delay_shift.get("gps").map_or(0, |d| d.0);
    let history = (est.cfg.history_ms * 1000.0) as i64;
    assert!(shift > 100_000 && shift < history, "shift {shift} µs");
    let dropped = est.late_dropped;
    let mut drops = Vec::new();
    for (s, _) in &after {
        drops.extend(
            est.process(s)
                .into_iter()
                .filter(|e| matches!(e.what, Event::LateDrop { .. })),
        );
    }
    assert!(drops.is_empty(), "{:?}", drops.first().map(|e| &e.message));
    assert_eq!(est.late_dropped, dropped);
}
