//! End to end: skyfuse's ROS 2 outputs are announced with zenoh-bridge-ros2dds's
//! liveliness tokens (checked with Python eclipse-zenoh, key strings parsed back), gone
//! when the service stops; tokens declared as the bridge does are listed at
//! /api/v1/ros/topics with their types, and marked gone when undeclared.

mod common;
use common::*;
use std::time::Duration;

/// Tokens declared as zenoh-bridge-ros2dds does, for 6 s; the gps one goes after
/// `drop_after_s`.
fn bridge_tokens(svc: &Service, drop_after_s: u32) -> std::thread::JoinHandle<String> {
    let ep = svc.zenoh_endpoint();
    std::thread::spawn(move || {
        let drop = drop_after_s.to_string();
        run_py(
            "ros_tokens.py",
            &[
                "bridge",
                "--connect",
                &ep,
                "--hold",
                "6",
                "--drop-after",
                &drop,
            ],
        )
    })
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

#[test]
fn outputs_are_announced_and_bridge_topics_are_listed() {
    // A second node on the network, to watch from after the first one stops.
    let watcher = Service::start(&["run", "--connect", "tcp/127.0.0.1:1"], &[]);
    let mut svc = Service::start(&["run", "--connect", &watcher.zenoh_endpoint()], &[]);
    let zid = svc.get_json("/api/v1/status")["service"]["zenoh"]["zid"]
        .as_str()
        .expect("zid")
        .to_string();
    let list = |ep: &str| -> Vec<String> {
        json(&run_py("ros_tokens.py", &["list", "--connect", ep]))
            .as_array()
            .expect("list")
            .iter()
            .filter_map(|v| v.as_str().map(String::from))
            .filter(|k| k.starts_with(&format!("@/{zid}/")))
            .collect()
    };
    let keys = list(&svc.zenoh_endpoint());
    let ours: Vec<(&str, &str, &str)> = keys
        .iter()
        .filter_map(|k| {
            let rest = k.strip_prefix("@/")?;
            let (_zid, rest) = rest.split_once("/@ros2_lv/MP/")?;
            let mut p = rest.splitn(3, '/');
            Some((p.next()?, p.next()?, p.next()?))
        })
        .collect();
    let want = [
        ("data_fusion§pose_msg", "geometry_msgs§msg§PoseStamped"),
        (
            "data_fusion§compensated_OF",
            "geometry_msgs§msg§PointStamped",
        ),
        ("data_fusion§OF_sum", "geometry_msgs§msg§PointStamped"),
        ("data_fusion§oriUAV_t265", "geometry_msgs§msg§PointStamped"),
        ("data_fusion§oriUAV_gps", "geometry_msgs§msg§PointStamped"),
        ("data_fusion§origin_dOF", "geometry_msgs§msg§PointStamped"),
        ("data_fusion§origin_dt265", "geometry_msgs§msg§PointStamped"),
        ("data_fusion§origin_dgps", "geometry_msgs§msg§PointStamped"),
        (
            "data_fusion§fusion_displace",
            "geometry_msgs§msg§PointStamped",
        ),
    ];
    assert_eq!(ours.len(), want.len(), "{keys:?}");
    for (k, t) in want {
        assert!(
            ours.iter()
                .any(|(a, b, q)| *a == k && *b == t && *q == ":1::0,10"),
            "no token for {k} {t}: {keys:?}"
        );
    }

    // A bridge's tokens: listed with their types; the gps one goes away after 3 s.
    let bridge = bridge_tokens(&svc, 3);
    let listed = |s: &serde_json::Value, key: &str| {
        s["topics"]
            .as_array()
            .and_then(|a| a.iter().find(|t| t["key"] == key).cloned())
    };
    let start = std::time::Instant::now();
    let mut seen = serde_json::Value::Null;
    while start.elapsed() < Duration::from_secs(3) {
        seen = svc.get_json("/api/v1/ros/topics");
        if listed(&seen, "weird/thing").is_some() && listed(&seen, "gps/fix").is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let gps = listed(&seen, "gps/fix").unwrap_or_else(|| panic!("{seen}"));
    assert_eq!(gps["type"], "sensor_msgs/msg/NavSatFix");
    assert_eq!(gps["topic"], "/gps/fix");
    assert_eq!(gps["alive"], true);
    assert_eq!(gps["used_by"][0], "gps", "{gps}");
    assert_eq!(
        listed(&seen, "camera/odom/sample").map(|t| t["type"].clone()),
        Some("nav_msgs/msg/Odometry".into())
    );
    let weird = listed(&seen, "weird/thing").expect("unknown type listed");
    assert_eq!(weird["decodable"], false);
    // Our own tokens are not listed as others' topics (the other skyfuse's are).
    let topics = seen["topics"].as_array().expect("topics");
    assert!(topics.iter().all(|t| t["zid"] != zid.as_str()), "{seen}");
    assert!(
        topics.iter().any(|t| t["key"] == "data_fusion/pose_msg"),
        "{seen}"
    );
    let out = json(&bridge.join().expect("bridge"));
    assert_eq!(out["declared"].as_array().map(Vec::len), Some(4));
    let after = svc.get_json("/api/v1/ros/topics");
    assert_eq!(
        listed(&after, "gps/fix").map(|t| t["alive"].clone()),
        Some(false.into())
    );

    // Seen from the other node: there while the service runs, gone when it stops.
    assert_eq!(list(&watcher.zenoh_endpoint()).len(), want.len());
    let (status, _) = svc.terminate();
    assert!(status.success());
    let left = list(&watcher.zenoh_endpoint());
    assert!(left.is_empty(), "tokens outlived the service: {left:?}");
}

#[test]
fn jazzy_tokens_carry_the_rep_2011_type_hash_rosbags_computes() {
    let svc = Service::start(&["run"], &[("SKYFUSE__OUTPUT__ROS_DISTRO", "jazzy")]);
    let keys = json(&run_py(
        "ros_tokens.py",
        &["list", "--connect", &svc.zenoh_endpoint()],
    ));
    let want = json(&run_py(
        "rihs01.py",
        &[
            "geometry_msgs/msg/PoseStamped",
            "geometry_msgs/msg/PointStamped",
        ],
    ));
    let keys: Vec<&str> = keys
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|v| v.as_str())
        .collect();
    let pose = keys
        .iter()
        .find(|k| k.contains("/data_fusion§pose_msg/"))
        .unwrap_or_else(|| panic!("{keys:?}"));
    let hash = want["geometry_msgs/msg/PoseStamped"]
        .as_str()
        .expect("hash");
    assert!(
        pose.ends_with(&format!("/:1::0,10:typehash={hash};")),
        "{pose} vs {hash}"
    );
    let point_hash = want["geometry_msgs/msg/PointStamped"]
        .as_str()
        .expect("hash");
    let points = keys
        .iter()
        .filter(|k| k.ends_with(&format!(":typehash={point_hash};")))
        .count();
    assert_eq!(points, 8, "{keys:?}");
}

#[test]
fn auto_typed_inputs_decode_and_a_mismatched_type_is_reported_not_decoded() {
    let dir = TempDir::new("rosgraph");
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("auto.toml");
    std::fs::write(
        &cfg,
        r#"
[[inputs]]
id = "gps"
kind = "gnss"
key = "gps/fix"
format = "ros2"
type = "auto"
rate_hz = 10.0

[[inputs]]
id = "t265"
kind = "odometry"
key = "camera/odom/sample"
format = "ros2"
type = "geometry_msgs/msg/PoseStamped"
rate_hz = 200.0

[[inputs]]
id = "imu"
kind = "imu"
key = "mavros/imu/data"
format = "ros2"
type = "auto"
rate_hz = 100.0
"#,
    )
    .expect("config");
    let svc = Service::start(&["run", "-c", cfg.to_str().expect("path")], &[]);
    let bridge = bridge_tokens(&svc, 5);
    // All three are put one after the other: wait for the last to be counted.
    let s = svc.wait_status(Duration::from_secs(5), |s| {
        sensor(s, "t265")["rejected"].as_u64() == Some(1)
            && sensor(s, "gps")["received"].as_u64() == Some(1)
            && sensor(s, "imu")["received"].as_u64() == Some(1)
    });
    let (gps, t265, imu) = (sensor(&s, "gps"), sensor(&s, "t265"), sensor(&s, "imu"));
    assert_eq!(gps["accepted"], 1, "{gps}");
    assert_eq!(gps["type"], "auto");
    assert_eq!(imu["accepted"], 1, "{imu}");
    assert_eq!(t265["accepted"], 0, "{t265}");
    assert_eq!(t265["rejected"], 1, "{t265}");
    let why = "camera/odom/sample is announced as nav_msgs/msg/Odometry, configured as geometry_msgs/msg/PoseStamped";
    assert_eq!(t265["last_error"], why);
    // And it is a health reason of the sensor.
    let s = svc.wait_status(Duration::from_secs(3), |s| {
        sensor(s, "t265")["reasons"].to_string().contains(why)
    });
    assert!(
        sensor(&s, "t265")["reasons"].to_string().contains(why),
        "{}\n{}",
        sensor(&s, "t265"),
        svc.get_json("/api/v1/ros/topics")
    );
    assert_eq!(sensor(&s, "t265")["health"], "failed");
    bridge.join().expect("bridge");
}
