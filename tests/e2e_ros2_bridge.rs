//! End to end, ROS 2 for real: the real zenoh-bridge-ros2dds (1.9.0, humble) between
//! skyfuse and a ROS 2 node emulated on DDS (Python cyclonedds, the peers'
//! `ros2/ros2_dds.py`). The node publishes NavSatFix, T265 Odometry, Imu and FlowTof of
//! a vehicle flying a circle; skyfuse takes every input's type from the bridge's
//! announcement (`type = "auto"`), fuses, and its pose and debug series come back
//! through the bridge to ROS readers on DDS, one subscribed before skyfuse starts and
//! one after (once the topics are in DDS discovery with their types). The work is in
//! `tests/py/ros2_bridge_check.py`, which prints the figures as JSON.
//!
//! Skips (and passes) when the peers dir ($SKYFUSE_PEERS, default ../shared/peers), the
//! bridge binary or the Python `cyclonedds` module is absent: a clone of the project
//! alone must pass.

mod common;
use common::*;
use std::process::Command;

/// Why the test cannot run here, if it cannot.
fn missing() -> Option<String> {
    let peers = peers_dir();
    if !peers.is_dir() {
        return Some(format!(
            "no peers dir {} (set SKYFUSE_PEERS)",
            peers.display()
        ));
    }
    for f in [
        "bin/zenoh-bridge-ros2dds",
        "ros2/ros2_dds.py",
        "ros2/cyclonedds-localhost.xml",
    ] {
        if !peers.join(f).is_file() {
            return Some(format!("no {}", peers.join(f).display()));
        }
    }
    let cyclonedds = Command::new(python())
        .args(["-c", "import cyclonedds"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !cyclonedds {
        return Some(format!(
            "Python module cyclonedds missing in {} (tests/run installs it from tests/requirements.txt)",
            python().display()
        ));
    }
    None
}

#[test]
fn ros2_node_through_the_real_bridge_both_ways() {
    if skip_requested("peers", "ros2_node_through_the_real_bridge_both_ways") {
        return;
    }
    if let Some(why) = missing() {
        eprintln!("SKIPPED ros2_node_through_the_real_bridge_both_ways: {why}");
        return;
    }
    let peers = peers_dir();
    let out = run_py(
        "ros2_bridge_check.py",
        &[
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--peers",
            peers.to_str().expect("peers path"),
            "--strict",
        ],
    );
    let v: serde_json::Value =
        serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));
    // The script exits non-zero on any failure (run_py panics with its stderr); these
    // hold whenever it passed, and say what the run measured.
    assert_eq!(v["ok"], true, "{v}");
    for id in ["gps", "t265", "imu", "flow"] {
        let s = &v["status"][id];
        assert!(s["accepted"].as_u64().unwrap_or(0) > 0, "{id}: {s}");
    }
    assert_eq!(v["estimator_in_flight"]["valid"], true, "{v}");
    for reader in ["early_listener", "late_listener"] {
        assert!(
            v["readers"][reader]["pose_msg"].as_u64().unwrap_or(0) > 0,
            "{reader}: {v}"
        );
    }
    eprintln!(
        "ros2 bridge: wall {} s; pose vs odometry {} m RMS (yaw {}°, T265 frame at {}°); pose vs truth {} m RMS; \
         latency median {} ms, p95 {} ms; readers {}; DDS writers {} s after skyfuse started, gone {} s after it stopped",
        v["wall_s"],
        v["pose_vs_odometry"]["horizontal_rms_m"],
        v["pose_vs_odometry"]["fitted_yaw_deg"],
        v["pose_vs_odometry"]["odom_frame_yaw_deg"],
        v["pose_vs_truth"]["horizontal_rms_m"],
        v["latency_ms"]["median"],
        v["latency_ms"]["p95"],
        v["readers"],
        v["dds_writer_appeared_after_skyfuse_start_s"],
        v["dds_writers_gone_after_stop_s"]["seconds"],
    );
    if let Some(w) = v["warnings"].as_array().filter(|w| !w.is_empty()) {
        eprintln!("ros2 bridge warnings: {w:?}");
    }
}
