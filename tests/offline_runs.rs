//! Offline runs: deterministic output files, and the real PX4 flight replayed with only
//! optical flow, range finder and attitude, scored against the flight's visual odometry
//! (which PX4 did not fuse) beside PX4 EKF2's own estimate, same metric and alignment.

use skyfuse::estimator::EstimatorConfig;
use skyfuse::health::HealthConfig;
use skyfuse::offline::{run_replay, run_scenario, ReplayOptions};
use skyfuse::sim::scenario::scenario;
use std::path::{Path, PathBuf};

const PX4_FLOW_VIO: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/data/px4-flow-vio-7c824ee5"
);

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("skyfuse-offline-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn same_files(a: &Path, b: &Path) {
    let mut names: Vec<_> = std::fs::read_dir(a)
        .expect("dir")
        .filter_map(|e| e.ok().map(|e| e.file_name()))
        .collect();
    names.sort();
    assert!(names.len() >= 5, "{names:?}");
    for n in names {
        let x = std::fs::read(a.join(&n)).expect("read");
        let y = std::fs::read(b.join(&n)).unwrap_or_else(|_| panic!("{n:?} missing in {b:?}"));
        assert!(x == y, "{n:?} differs between runs");
    }
}

#[test]
fn a_scenario_run_twice_gives_byte_identical_files() {
    let scn = scenario("gps-loss").expect("scenario");
    let (a, b) = (tmp("sim-a"), tmp("sim-b"));
    for d in [&a, &b] {
        run_scenario(
            &scn,
            7,
            60.0,
            EstimatorConfig::default(),
            HealthConfig::default(),
            d,
            &mut |_| {},
        )
        .expect("run");
    }
    same_files(&a, &b);
    // And the files are what they say: TUM lines of 8 numbers.
    let fused = std::fs::read_to_string(a.join("fused.tum")).expect("fused");
    assert!(fused.lines().count() > 2000);
    assert!(fused
        .lines()
        .all(|l| l.split(' ').filter_map(|v| v.parse::<f64>().ok()).count() == 8));
}

#[test]
fn real_px4_flight_flow_range_attitude_beats_ekf2_against_vio() {
    let log = skyfuse::replay::px4csv::read_dir(Path::new(PX4_FLOW_VIO)).expect("PX4 CSV");
    let opts = ReplayOptions {
        fuse: Some(["flow", "range", "attitude"].map(String::from).to_vec()),
        reference: "vio".into(),
        // Airborne: take-off at 209.8 s, landing at 308.3 s (log time).
        window: Some((212.0, 306.0)),
    };
    let (a, b) = (tmp("px4-a"), tmp("px4-b"));
    let mut summaries = vec![];
    for d in [&a, &b] {
        summaries.push(
            run_replay(
                "px4-flow-vio-7c824ee5",
                &log.samples,
                EstimatorConfig::default(),
                HealthConfig::default(),
                &opts,
                d,
                &mut |_| {},
            )
            .expect("replay"),
        );
    }
    same_files(&a, &b);
    let s = &summaries[0];
    let rmse = |name: &str| {
        s.scores
            .iter()
            .find(|x| x.name == name)
            .and_then(|x| x.ape.as_ref())
            .map(|a| a.rmse)
            .unwrap_or_else(|| panic!("no score for {name}: {s:?}"))
    };
    let (fused, ekf2) = (rmse("fused"), rmse("ekf2"));
    println!(
        "APE RMSE vs VIO (SE(3)-aligned, 212-306 s): skyfuse {fused:.3} m, PX4 EKF2 {ekf2:.3} m"
    );
    assert!(
        fused < ekf2,
        "skyfuse {fused:.3} m not closer to the VIO than EKF2 {ekf2:.3} m"
    );
    // Not fused, still written for comparison.
    assert!(a.join("vio.tum").exists() && a.join("ekf2.tum").exists());
}

#[test]
fn on_every_scenario_the_fused_track_beats_the_best_single_source() {
    let mut table = vec![];
    let mut losers = vec![];
    for (name, _) in skyfuse::sim::scenario::NAMES {
        let scn = scenario(name).expect("scenario");
        let out = tmp(&format!("all-{name}"));
        let s = run_scenario(
            &scn,
            1,
            skyfuse::sim::scenario::DEFAULT_DURATION_S,
            EstimatorConfig::default(),
            HealthConfig::default(),
            &out,
            &mut |_| {},
        )
        .expect("run");
        let (fused, best) = s.fused_and_best_source();
        let fused = fused.unwrap_or_else(|| panic!("{name}: no fused score"));
        let (src, b) = best.unwrap_or_else(|| panic!("{name}: no source score"));
        table.push(format!(
            "{name:<16} fused {fused:.3} m, best source {src} {b:.3} m"
        ));
        if fused >= b {
            losers.push(name);
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    println!("{}", table.join("\n"));
    assert!(
        losers.is_empty(),
        "fused not better on {losers:?}:\n{}",
        table.join("\n")
    );
}
