//! End to end: the service binary on free ports, real producers (Python eclipse-zenoh
//! sessions publishing rosbags-serialised ROS 2 / ROS 1 bytes, mavlink-server JSON from
//! the reference Codec, pymavlink frames, skyfuse JSON), and `/api/v1/status` checked
//! to count every sample for the right sensor.

mod common;
use common::*;
use std::time::Duration;

fn count(s: &serde_json::Value, field: &str) -> u64 {
    s[field].as_u64().unwrap_or(u64::MAX)
}

#[test]
fn every_format_is_counted_for_the_right_sensor_and_bad_input_is_rejected() {
    let dir = std::env::temp_dir().join(format!("skyfuse-e2e-{}", free_port()));
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("e2e.toml");
    let inputs = run_py("publish_inputs.py", &["--print-config"]);
    std::fs::write(&cfg, format!("[service]\nvehicle = \"e2e\"\n\n{inputs}")).expect("config");
    let svc = Service::start(&["run", "-c", cfg.to_str().expect("path")], &[]);

    let expected_text = run_py("publish_inputs.py", &["--connect", &svc.zenoh_endpoint()]);
    let expected: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(expected_text.trim()).expect("publisher summary");
    assert!(
        expected.len() >= 27,
        "publisher covered {} inputs",
        expected.len()
    );

    let all_counted = |s: &serde_json::Value| {
        expected.iter().all(|(id, e)| {
            let x = sensor(s, id);
            count(x, "accepted") == e["good"].as_u64().unwrap_or(0)
                && count(x, "rejected") == e["bad"].as_u64().unwrap_or(0)
                && count(x, "ignored") == e["ignored"].as_u64().unwrap_or(0)
        })
    };
    let status = svc.wait_status(Duration::from_secs(15), all_counted);
    let mut failures = Vec::new();
    for (id, e) in &expected {
        let x = sensor(&status, id);
        let got = (
            count(x, "accepted"),
            count(x, "rejected"),
            count(x, "ignored"),
        );
        let want = (
            e["good"].as_u64().unwrap_or(0),
            e["bad"].as_u64().unwrap_or(0),
            e["ignored"].as_u64().unwrap_or(0),
        );
        if got != want {
            failures.push(format!(
                "{id}: (accepted, rejected, ignored) = {got:?}, want {want:?}; last_error {}",
                x["last_error"]
            ));
        }
        // One message per payload here, so every payload is exactly one of the three.
        assert_eq!(count(x, "received"), got.0 + got.1 + got.2, "{id}: {x}");
        if want.1 > 0 {
            let err = x["last_error"].as_str().unwrap_or("");
            assert!(!err.is_empty(), "{id}: rejected input without last_error");
        }
    }
    assert!(
        failures.is_empty(),
        "{}\nlog:\n{}",
        failures.join("\n"),
        svc.log_text()
    );

    // The errors are readable and name the thing at fault.
    let gps = sensor(&status, "r2_gps");
    let err = gps["last_error"].as_str().unwrap_or("");
    assert!(
        err.contains("NavSatFix.latitude"),
        "r2_gps last_error: {err}"
    );
    let r1 = sensor(&status, "r1_imu")["last_error"]
        .as_str()
        .unwrap_or("")
        .to_string();
    assert!(
        r1.contains("sensor_msgs/Range") && r1.contains("sensor_msgs/Imu"),
        "{r1}"
    );
    let raw = sensor(&status, "raw_imu")["last_error"]
        .as_str()
        .unwrap_or("")
        .to_string();
    assert!(
        raw.to_lowercase().contains("crc"),
        "raw_imu last_error: {raw}"
    );
    // The publisher has stopped by now: the stream is stale, and it says so.
    assert_eq!(sensor(&status, "r2_gps")["health"], "stale");
    assert!(sensor(&status, "r2_imu")["last_error"].is_null());
}

#[test]
fn check_config_names_unknown_keys_and_missing_files() {
    let dir = std::env::temp_dir().join(format!("skyfuse-cc-{}", free_port()));
    std::fs::create_dir_all(&dir).expect("dir");
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[zenoh]\nmode = \"peer\"\nlisten_on = []\n").expect("write");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args(["check-config", bad.to_str().expect("path")])
        .output()
        .expect("run");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("listen_on") && err.contains("bad.toml"),
        "{err}"
    );

    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args(["check-config", "/nonexistent/skyfuse.toml"])
        .output()
        .expect("run");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/skyfuse.toml"));

    let out = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args([
            "check-config",
            repo_root()
                .join("config/default.toml")
                .to_str()
                .expect("path"),
        ])
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("gps/fix"));
}
