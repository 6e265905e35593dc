//! End to end, ROS 2 for real: Zenoh's ROS 2 bridge (`zenoh-plugin-ros2dds` 1.10.2 from
//! crates.io, started statically by `tests/ros2dds-bridge`, as upstream's
//! zenoh-bridge-ros2dds does; humble) between skyfuse and a ROS 2 node emulated on DDS
//! (Python cyclonedds, the peers' `ros2/ros2_dds.py`). The node publishes NavSatFix, T265
//! Odometry, Imu and FlowTof of a vehicle flying a circle; skyfuse takes every input's
//! type from the bridge's announcement (`type = "auto"`), fuses, and its pose and debug
//! series come back through the bridge to ROS readers on DDS, one subscribed before
//! skyfuse starts and one after (once the topics are in DDS discovery with their types).
//! The work is in `tests/py/ros2_bridge_check.py`, which prints the figures as JSON.
//!
//! The bridge: $SKYFUSE_ROS2DDS_BRIDGE (`tests/run` builds tests/ros2dds-bridge once per
//! machine and sets it), else an upstream binary at $SKYFUSE_PEERS/bin/zenoh-bridge-ros2dds.
//! Skips (and passes), saying why, when there is no bridge, when the peers dir
//! ($SKYFUSE_PEERS, default ../shared/peers) lacks the emulated node or the Python
//! `cyclonedds` module is absent: a clone of the project alone must pass.

mod common;
use common::*;
use std::path::PathBuf;
use std::process::Command;

/// The bridge binary, or why there is none.
fn bridge() -> Result<PathBuf, String> {
    if let Some(b) = std::env::var_os("SKYFUSE_ROS2DDS_BRIDGE") {
        let b = PathBuf::from(b);
        return if b.is_file() {
            Ok(b)
        } else {
            Err(format!(
                "SKYFUSE_ROS2DDS_BRIDGE={} is not a file (tests/run builds it from tests/ros2dds-bridge)",
                b.display()
            ))
        };
    }
    let upstream = peers_dir().join("bin/zenoh-bridge-ros2dds");
    if upstream.is_file() {
        return Ok(upstream);
    }
    Err(format!(
        "no bridge: SKYFUSE_ROS2DDS_BRIDGE unset (tests/run builds tests/ros2dds-bridge and sets it) and no {}",
        upstream.display()
    ))
}

/// Why the test cannot run here, if it cannot.
fn missing() -> Option<String> {
    let peers = peers_dir();
    if !peers.is_dir() {
        return Some(format!(
            "no peers dir {} for the emulated ROS 2 node (set SKYFUSE_PEERS)",
            peers.display()
        ));
    }
    for f in ["ros2/ros2_dds.py", "ros2/cyclonedds-localhost.xml"] {
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

/// The bridge binary when `test` can run here; else it is skipped, saying why.
fn ready(test: &str) -> Option<PathBuf> {
    if skip_requested("peers", test) {
        return None;
    }
    let why = match (bridge(), missing()) {
        (Ok(b), None) => return Some(b),
        (Err(why), _) | (Ok(_), Some(why)) => why,
    };
    skipped(test, &why);
    None
}

#[test]
fn ros2_node_through_the_real_bridge_both_ways() {
    let Some(bridge) = ready("ros2_node_through_the_real_bridge_both_ways") else {
        return;
    };
    let peers = peers_dir();
    let out = run_py(
        "ros2_bridge_check.py",
        &[
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--bridge",
            bridge.to_str().expect("bridge path"),
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
        "ros2 bridge ({} {}): wall {} s; pose vs odometry {} m RMS (yaw {}°, T265 frame at {}°); pose vs truth {} m RMS; \
         camera track (oriUAV_t265) vs pose {} m RMS; latency median {} ms, p95 {} ms; readers {}; DDS writers {} s after skyfuse started, gone {} s after it stopped",
        v["bridge"],
        v["bridge_version"],
        v["wall_s"],
        v["pose_vs_odometry"]["horizontal_rms_m"],
        v["pose_vs_odometry"]["fitted_yaw_deg"],
        v["pose_vs_odometry"]["odom_frame_yaw_deg"],
        v["pose_vs_truth"]["horizontal_rms_m"],
        v["debug"]["oriUAV_t265"]["horizontal_vs_pose_rms_m"],
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

/// Discovery through the real bridge (issue 35): while the emulated ROS 2 node publishes,
/// `skyfuse discover` finds its four topics with the types the bridge announces and
/// writes a config; `skyfuse run -c` on that file, unedited, fuses every one of them.
#[test]
fn discover_through_the_real_bridge_writes_a_config_run_fuses_from() {
    let Some(bridge) = ready("discover_through_the_real_bridge_writes_a_config_run_fuses_from")
    else {
        return;
    };
    let peers = peers_dir();
    let out = run_py(
        "ros2_bridge_check.py",
        &[
            "--role",
            "discover",
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--bridge",
            bridge.to_str().expect("bridge path"),
            "--peers",
            peers.to_str().expect("peers path"),
            "--duration",
            "30",
        ],
    );
    let v: serde_json::Value =
        serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));
    assert_eq!(v["ok"], true, "{v}");
    let sensors = v["sensors"].as_object().expect("sensors");
    assert_eq!(sensors.len(), 4, "{v}");
    assert!(sensors.values().all(|n| n.as_u64() > Some(0)), "{v}");
    for id in ["gps", "odometry", "imu", "flow"] {
        assert!(sensors.contains_key(id), "{id}: {v}");
    }
    eprintln!(
        "discover through the bridge: fused {:?} from the written config",
        v["sources_used"]
    );
}

/// PX4 through the real bridge (issue 37): PX4's topics published on DDS as a
/// uXRCE-DDS agent names and types them (`rt/fmu/out/...`, `px4_msgs::msg::dds_::<T>_`,
/// by the emulated node) reach skyfuse with the px4_msgs types the bridge announces,
/// are fused, and skyfuse's px4_msgs/VehicleOdometry comes back through the bridge to a
/// DDS reader on `rt/fmu/in/vehicle_visual_odometry`, each message passing
/// px4-ros2-interface-lib's checks (tests/py/px4_bridge_check.py).
#[test]
fn px4_topics_through_the_real_bridge_both_ways() {
    let Some(bridge) = ready("px4_topics_through_the_real_bridge_both_ways") else {
        return;
    };
    let peers = peers_dir();
    let out = run_py(
        "px4_bridge_check.py",
        &[
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--bridge",
            bridge.to_str().expect("bridge path"),
            "--peers",
            peers.to_str().expect("peers path"),
        ],
    );
    let v: serde_json::Value =
        serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));
    assert_eq!(v["ok"], true, "{v}");
    for (id, ty) in [
        ("imu", "SensorCombined"),
        ("attitude", "VehicleAttitude"),
        ("gps", "SensorGps"),
        ("baro", "VehicleAirData"),
        ("range", "DistanceSensor"),
        ("status", "VehicleStatus"),
    ] {
        let s = &v["inputs"][id];
        assert_eq!(
            s["resolved_type"],
            format!("px4_msgs/msg/{ty}"),
            "{id}: {s}"
        );
        assert_eq!(s["rejected"], 0, "{id}: {s}");
    }
    let o = &v["odometry"];
    assert!(o["received"].as_u64() > Some(50), "{o}");
    assert_eq!(o["passed"], o["received"], "{o}");
    let rmse = o["rmse_m"].as_f64().unwrap_or(f64::INFINITY);
    assert!(rmse < 0.6, "{o}");
    eprintln!(
        "px4 through the bridge ({}): {} VehicleOdometry back on DDS, all passing the checks, {rmse:.3} m RMSE",
        v["bridge_version"], o["received"]
    );
}
