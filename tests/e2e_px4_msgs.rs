//! PX4 natively on Zenoh (issue 37): a Python eclipse-zenoh session behaves as PX4
//! (tests/py/px4_zenoh_node.py: px4_msgs serialised by CycloneDDS with PX4 1.16's field
//! lists) and flies a circle, publishing SensorCombined, VehicleAttitude, SensorGps,
//! VehicleAirData, DistanceSensor, VehicleStatus and TimesyncStatus the three ways they
//! reach Zenoh: through zenoh-bridge-ros2dds from uXRCE-DDS (`fmu/out/...`, XCDR1, the
//! agent's clock), as PX4 ≥ 1.17's zenoh module (rmw_zenoh keys with the type hash,
//! attachment, 24 bytes of buffer behind each message, PX4's clock) and as PX4 1.16's
//! (user keys, XCDR2, 12 bytes behind, PX4's clock). skyfuse fuses them and sends
//! px4_msgs/VehicleOdometry on `fmu/in/vehicle_visual_odometry`; the node checks each
//! message as px4-ros2-interface-lib would, its position against the circle, and its
//! `timestamp_sample` against the clock PX4 expects on that path.

mod common;
use common::*;

/// The inputs, with `{transport}` and `{prefix}` filled per style.
fn config(style: &str) -> String {
    let (prefix, extra, output) = match style {
        "bridge" => ("", "", "px4_clock = \"agent\"\n"),
        "rmw_zenoh" => (
            "/",
            "transport = \"rmw_zenoh\"\n",
            "rmw_zenoh = true\npx4_clock = \"px4\"\npx4_timesync_key = \"/fmu/out/timesync_status\"\npx4_timesync_transport = \"rmw_zenoh\"\n",
        ),
        "px4_zenoh" => (
            "",
            "transport = \"px4_zenoh\"\n",
            "px4_clock = \"px4\"\npx4_timesync_transport = \"px4_zenoh\"\n",
        ),
        _ => unreachable!(),
    };
    let mut cfg = format!("[output]\npx4_odometry = true\n{output}\n");
    for (id, kind, topic, ty, hz) in [
        ("imu", "imu", "sensor_combined", "SensorCombined", 200),
        (
            "attitude",
            "attitude",
            "vehicle_attitude",
            "VehicleAttitude",
            50,
        ),
        ("gps", "gnss", "vehicle_gps_position", "SensorGps", 5),
        ("baro", "baro", "vehicle_air_data", "VehicleAirData", 20),
        ("range", "range", "distance_sensor", "DistanceSensor", 20),
        (
            "status",
            "vehicle_state",
            "vehicle_status",
            "VehicleStatus",
            2,
        ),
    ] {
        // rmw_zenoh keys name their type: some inputs read it from there.
        let ty = if style == "rmw_zenoh" && (id == "imu" || id == "gps") {
            "auto".to_string()
        } else {
            format!("px4_msgs/msg/{ty}")
        };
        cfg += &format!(
            "[[inputs]]\nid = \"{id}\"\nkind = \"{kind}\"\nkey = \"{prefix}fmu/out/{topic}\"\nformat = \"ros2\"\ntype = \"{ty}\"\n{extra}rate_hz = {hz}.0\n\n"
        );
    }
    cfg
}

fn fly(style: &str) -> (serde_json::Value, serde_json::Value) {
    let dir = TempDir::new(&format!("px4-{style}"));
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("px4.toml");
    std::fs::write(&cfg, config(style)).expect("config");
    let svc = Service::start(&["run", "-c", cfg.to_str().expect("path")], &[]);
    let out: serde_json::Value = serde_json::from_str(
        run_py(
            "px4_zenoh_node.py",
            &[
                "--connect",
                &svc.zenoh_endpoint(),
                "--style",
                style,
                "--seconds",
                "12",
            ],
        )
        .trim(),
    )
    .expect("node JSON");
    let status = svc.get_json("/api/v1/status");
    eprintln!("{style}: node {out}");
    (out, status)
}

fn check_flight(style: &str, out: &serde_json::Value, s: &serde_json::Value) {
    for (id, topic) in [
        ("imu", "imu"),
        ("attitude", "attitude"),
        ("gps", "gps"),
        ("baro", "baro"),
        ("range", "range"),
        ("status", "status"),
    ] {
        let sensor = sensor(s, id);
        let sent = out["sent"][topic].as_u64().unwrap_or(0);
        let accepted = sensor["accepted"].as_u64().unwrap_or(0);
        eprintln!(
            "{style} {id}: sent {sent}, accepted {accepted}, rejected {}, last error {}",
            sensor["rejected"], sensor["last_error"]
        );
        assert!(sent > 10, "{out}");
        assert_eq!(sensor["rejected"], 0, "{style} {id}: {sensor}");
        // Every message decoded (the last may be in flight at the status read).
        assert!(
            accepted + 3 >= sent && accepted <= sent,
            "{style} {id}: {sensor}"
        );
    }
    let est = &s["estimator"];
    assert_eq!(est["valid"], true, "{style}: {est}");
    let used: Vec<&str> = est["sources_used"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_str()).collect())
        .unwrap_or_default();
    for id in ["imu", "gps"] {
        assert!(used.contains(&id), "{style}: {id} not fused: {used:?}");
    }
    let o = &out["odometry"];
    let received = o["received"].as_u64().unwrap_or(0);
    assert!(received > 100, "{style}: {o}");
    // Every message passes px4-ros2-interface-lib's checks, NED/NED.
    assert_eq!(o["passed"], received, "{style}: {o}");
    assert_eq!(o["frames"], serde_json::json!([[1, 1]]), "{style}: {o}");
    // It follows the circle (4 m radius, 1 m/s) once its origin is taken out.
    let rmse = o["rmse_m"].as_f64().unwrap_or(f64::INFINITY);
    assert!(rmse < 0.6, "{style}: position RMSE {rmse} m: {o}");
    // timestamp_sample is in the clock PX4 expects on this path: the newest pose is a
    // few ms to tens of ms old when it arrives, never in the future, never seconds off.
    let median = o["clock_err_ms_median"].as_f64().unwrap_or(f64::NAN);
    let max = o["clock_err_ms_max"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (-150.0..=5.0).contains(&median) && max < 300.0,
        "{style}: timestamp_sample off by {median} ms (max {max}): {o}"
    );
    let zenoh = s["outputs"]
        .as_array()
        .and_then(|a| a.iter().find(|o| o["kind"] == "zenoh"))
        .cloned()
        .unwrap_or_default();
    let sent = zenoh["px4_odometry_sent"].as_u64().unwrap_or(0);
    assert!(sent >= received, "{style}: {zenoh}");
}

#[test]
fn px4_through_the_ros2_bridge_in_the_agents_clock() {
    let (out, s) = fly("bridge");
    check_flight("bridge", &out, &s);
}

#[test]
fn px4_1_17_zenoh_module_on_rmw_zenoh_keys_in_px4s_clock() {
    let (out, s) = fly("rmw_zenoh");
    check_flight("rmw_zenoh", &out, &s);
    // The type named by each key, the layout by its hash; the node's hashes (rosbags,
    // from the field lists) are the decoder's.
    for id in ["imu", "gps"] {
        assert_eq!(
            sensor(&s, id)["resolved_type"]
                .as_str()
                .map(|t| t.starts_with("px4_msgs/msg/")),
            Some(true),
            "{id}: {}",
            sensor(&s, id)
        );
    }
    // Also on its rmw_zenoh key, each with the attachment.
    let o = &out["odometry"];
    let rmw = o["rmw_received"].as_u64().unwrap_or(0);
    assert!(rmw + 5 >= o["received"].as_u64().unwrap_or(0), "{o}");
    assert_eq!(o["attachment_ok"], rmw, "{o}");
    // No PX4 clock for the first 3 s (TimesyncStatus starts late): those poses were
    // withheld, saying why, not sent in the wrong clock.
    let zenoh = s["outputs"]
        .as_array()
        .and_then(|a| a.iter().find(|o| o["kind"] == "zenoh"))
        .cloned()
        .unwrap_or_default();
    assert!(
        zenoh["px4_odometry_withheld"].as_u64() > Some(10),
        "{zenoh}"
    );
}

#[test]
fn px4_1_16_zenoh_module_xcdr2_on_user_keys_in_px4s_clock() {
    let (out, s) = fly("px4_zenoh");
    check_flight("px4_zenoh", &out, &s);
}

/// A ROS 2 user's `ros2 bag record` of PX4's `/fmu/out/...` topics (a rosbag2 bag in
/// MCAP written by rosbags, px4_msgs registered from PX4 1.16's fields) replays with no
/// config: each topic becomes an input by the type the bag names, TimesyncStatus is
/// said to be no sensor, and the 40 s circle comes out valid throughout and consistent
/// with the bag's GPS.
#[test]
fn a_ros2_bag_of_px4_topics_replays_by_the_types_it_names() {
    let dir = TempDir::new("px4-bag");
    std::fs::create_dir_all(&dir).expect("dir");
    let bag = dir.join("bag");
    let made: serde_json::Value = serde_json::from_str(
        run_py(
            "px4_zenoh_node.py",
            &["--bag", bag.to_str().expect("path"), "--seconds", "40"],
        )
        .trim(),
    )
    .expect("bag JSON");
    assert_eq!(made["counts"]["/fmu/out/sensor_combined"], 8000, "{made}");
    let out = dir.join("replay");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .arg("replay")
        .arg(&bag)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("run skyfuse replay");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    for topic in [
        "sensor_combined",
        "vehicle_attitude",
        "vehicle_gps_position",
        "vehicle_air_data",
        "distance_sensor",
        "vehicle_status",
    ] {
        assert!(
            text.contains(&format!("inputs=[\"fmu_out_{topic}\"]")),
            "{topic} not an input:\n{text}"
        );
    }
    assert!(
        text.contains("px4_msgs/msg/TimesyncStatus is not one skyfuse decodes"),
        "{text}"
    );
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("summary");
    eprintln!("{}", summary["consistency"]);
    assert_eq!(summary["availability"]["valid_fraction"], 1.0, "{summary}");
    let fused = &summary["scores"][0];
    assert_eq!(fused["name"], "fused");
    let rmse = fused["ape"]["rmse"].as_f64().unwrap_or(f64::INFINITY);
    assert!(rmse < 0.2, "SE(3)-aligned RMSE {rmse} m: {fused}");
    let c = &summary["consistency"];
    for axis in 0..3 {
        let within = c["within_3_sigma"][axis].as_f64().unwrap_or(0.0);
        assert!(within > 0.99, "axis {axis}: {c}");
    }
}
