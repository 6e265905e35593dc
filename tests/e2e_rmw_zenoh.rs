//! ROS 2 nodes on rmw_zenoh, with no bridge (issue 37): a Python eclipse-zenoh session
//! behaves as an rmw_zenoh node (its keys `<domain>/<topic>/<type>/<RIHS01 hash>`, the
//! attachment on every sample, liveliness tokens; the CDR from rosbags' Kilted type
//! store) and publishes sensor_msgs/Imu, NavSatFix and nav_msgs/Odometry. skyfuse, with
//! `transport = "rmw_zenoh"` and `type = "auto"`, reads each type from the keys, fuses
//! all three, and refuses (counting, saying why) the samples rmw_zenoh itself would
//! drop: no attachment, or a cut one. The other way, with `[output] rmw_zenoh`, the node
//! receives skyfuse's pose on rmw_zenoh's key with a well-formed attachment, and its
//! graph query finds the node /skyfuse and its publishers with their types.

mod common;
use common::*;

const CONFIG: &str = r#"
[output]
rmw_zenoh = true

[[inputs]]
id = "imu"
kind = "imu"
key = "/imu/data"
format = "ros2"
type = "auto"
transport = "rmw_zenoh"
rate_hz = 100.0

[[inputs]]
id = "gps"
kind = "gnss"
key = "/gps/fix"
format = "ros2"
type = "auto"
transport = "rmw_zenoh"
rate_hz = 5.0

[[inputs]]
id = "t265"
kind = "odometry"
key = "/camera/odom/sample"
format = "ros2"
type = "auto"
transport = "rmw_zenoh"
rate_hz = 30.0
"#;

#[test]
fn an_rmw_zenoh_node_is_fused_with_its_types_from_the_keys() {
    let dir = TempDir::new("rmw-zenoh");
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("rmw.toml");
    std::fs::write(&cfg, CONFIG).expect("config");
    let svc = Service::start(&["run", "-c", cfg.to_str().expect("path")], &[]);
    let out: serde_json::Value = serde_json::from_str(
        run_py(
            "rmw_zenoh_node.py",
            &["--connect", &svc.zenoh_endpoint(), "--seconds", "8"],
        )
        .trim(),
    )
    .expect("node JSON");
    let s = svc.get_json("/api/v1/status");
    eprintln!("node: {out}");
    for (id, topic) in [("imu", "imu"), ("gps", "gps"), ("t265", "odom")] {
        let sensor = sensor(&s, id);
        let good = out[topic]["good"].as_u64().unwrap_or(0);
        let accepted = sensor["accepted"].as_u64().unwrap_or(0);
        eprintln!(
            "{id}: sent {good} good, accepted {accepted}, rejected {}, health {}",
            sensor["rejected"], sensor["health"]
        );
        assert!(good > 20, "{out}");
        // Every good sample decoded (the last may be in flight at the status read).
        assert!(accepted + 2 >= good && accepted <= good, "{id}: {sensor}");
    }
    // What rmw_zenoh drops, refused and said: 5 without an attachment, 5 cut.
    let imu = sensor(&s, "imu");
    assert_eq!(imu["rejected"], out["imu"]["bad"], "{imu}");
    assert!(
        imu["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("attachment")),
        "{imu}"
    );
    let est = &s["estimator"];
    assert_eq!(est["valid"], true, "{est}");
    let used: Vec<&str> = est["sources_used"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_str()).collect())
        .unwrap_or_default();
    for id in ["imu", "gps", "t265"] {
        assert!(used.contains(&id), "{id} not fused: {used:?}");
    }
    // skyfuse's pose, as an rmw_zenoh subscriber gets it.
    let pose = &out["skyfuse_pose"];
    let n = pose["samples"].as_u64().unwrap_or(0);
    assert!(n > 20, "{pose}");
    assert_eq!(pose["attachment_ok"], n, "{pose}");
    assert_eq!(pose["decoded"], n, "{pose}");
    assert!(pose["consecutive"].as_u64() >= Some(n - 1), "{pose}");
    // The graph: our node, its pose publisher typed, the debug series typed.
    let graph = out["graph"].as_array().cloned().unwrap_or_default();
    let has = |f: &dyn Fn(&serde_json::Value) -> bool| graph.iter().any(f);
    assert!(
        has(&|t| t["kind"] == "NN" && t["node"] == "skyfuse"),
        "{graph:?}"
    );
    assert!(
        has(&|t| t["kind"] == "MP"
            && t["topic"] == "/data_fusion/pose_msg"
            && t["type"] == "geometry_msgs::msg::dds_::PoseStamped_"
            && t["hash"]
                .as_str()
                .is_some_and(|h| h.starts_with("RIHS01_10f3786d"))),
        "{graph:?}"
    );
    let debug = graph
        .iter()
        .filter(|t| t["kind"] == "MP" && t["type"] == "geometry_msgs::msg::dds_::PointStamped_")
        .count();
    assert!(debug >= 5, "{debug} debug publishers: {graph:?}");
}
