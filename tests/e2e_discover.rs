//! Discovery (issue 35): `skyfuse discover` lists what a publisher puts on a real Zenoh
//! network and writes a config that `skyfuse run` fuses from with no edit; the running
//! service shows the same keys on `/api/v1/discovered`, with the input that reads each
//! and, for a key none reads, the input it looks meant for.

mod common;

use common::{sensor, Service, TempDir};
use std::process::Command;
use std::time::Duration;

/// What the simulator publishes with the default config: ROS 2 CDR on the topic keys a
/// zenoh-bridge-ros2dds would use, mavlink-server JSON on its per-message keys.
const SIM_KEYS: [(&str, &str); 6] = [
    ("gps/fix", "gnss"),
    ("camera/odom/sample", "odometry"),
    ("mavros/imu/data", "imu"),
    ("data_fusion/OF_data", "flow"),
    ("mavlink/1/1/ATTITUDE_QUATERNION", "attitude"),
    ("mavlink/1/1/DISTANCE_SENSOR", "range"),
];

#[test]
fn discover_writes_a_config_that_run_fuses_from_as_it_is() {
    let dir = TempDir::new("discover");
    std::fs::create_dir_all(&dir).expect("dir");
    let sim = Service::spawn(&["sim", "--duration", "300"], &[]);
    let found = dir.join("found.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args([
            "discover",
            "--connect",
            &sim.zenoh_endpoint(),
            "--no-multicast",
            "--seconds",
            "4",
            "--write",
            found.to_str().expect("path"),
        ])
        .env("RUST_LOG", "warn")
        .output()
        .expect("skyfuse discover");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{stdout}\n{stderr}\nsim:\n{}",
        sim.log_text()
    );
    // The table: every key, what it is, and that the default config reads it.
    for (key, kind) in SIM_KEYS {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(key))
            .unwrap_or_else(|| panic!("{key} not listed:\n{stdout}"));
        assert!(line.contains(&format!("({kind}")), "{line}");
        assert!(
            !line.contains("unused"),
            "the default config reads {key}: {line}"
        );
    }
    let text = std::fs::read_to_string(&found).expect("written config");
    for (key, _) in SIM_KEYS {
        assert!(text.contains(&format!("key = {key:?}")), "{key}:\n{text}");
    }
    assert!(
        text.contains("type = \"sensor_msgs/msg/NavSatFix\""),
        "{text}"
    );
    // Stamped as what the sim is, and kept on this network.
    assert!(
        text.contains(&format!("connect = [{:?}]", sim.zenoh_endpoint())),
        "{text}"
    );

    // `skyfuse run` takes the file as written (its [zenoh] connect reaches the sim).
    let run = Service::start(&["run", "-c", found.to_str().expect("path")], &[]);
    // Valid and every input accepted, and the three the filter takes fused: the first
    // valid pose can come from the camera a sample before the first fix is fused.
    let status = run.wait_status(Duration::from_secs(30), |s| {
        s["estimator"]["valid"] == true
            && s["sensors"]
                .as_array()
                .is_some_and(|a| a.iter().all(|x| x["accepted"].as_u64() > Some(0)))
            && s["estimator"]["sources_used"].as_array().is_some_and(|u| {
                ["gps", "odometry", "imu"]
                    .iter()
                    .all(|id| u.iter().any(|x| x == id))
            })
    });
    assert_eq!(
        status["estimator"]["valid"],
        true,
        "{status}\n{}",
        run.log_text()
    );
    let sensors = status["sensors"].as_array().expect("sensors");
    assert_eq!(sensors.len(), SIM_KEYS.len(), "{status}");
    for s in sensors {
        assert!(s["accepted"].as_u64() > Some(0), "{s}");
    }
    let used = status["estimator"]["sources_used"]
        .as_array()
        .expect("used");
    for id in ["gps", "odometry", "imu"] {
        assert!(used.iter().any(|u| u == id), "{id} not fused: {used:?}");
    }

    // The running service sees the same network: its own inputs read the sim's keys,
    // and its own outputs are marked as such.
    let d = run.wait_json("/api/v1/discovered", Duration::from_secs(10), |d| {
        d["keys"].as_array().is_some_and(|k| {
            k.iter().any(|x| x["own_output"] == true)
                && SIM_KEYS.iter().all(|(key, _)| {
                    k.iter()
                        .any(|x| x["key"] == *key && x["rate_hz"].as_f64() > Some(0.0))
                })
        })
    });
    let keys = d["keys"].as_array().expect("keys");
    for (key, kind) in SIM_KEYS {
        let k = keys
            .iter()
            .find(|x| x["key"] == key)
            .unwrap_or_else(|| panic!("{key}: {d}"));
        assert!(k["rate_hz"].as_f64() > Some(0.0), "{k}");
        assert_eq!(k["kinds"][0], kind, "{k}");
        assert_eq!(k["read_by"].as_array().map(Vec::len), Some(1), "{k}");
    }
}

/// A key no input reads but that looks meant for one (the IMU topic without the
/// configured namespace) is named on `/api/v1/discovered` with that input, and the
/// input's card can say so.
#[test]
fn a_key_close_to_a_configured_one_is_pointed_out() {
    let dir = TempDir::new("discover-near");
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("near.toml");
    // The sim publishes its IMU on "imu/data"; the service waits on "mavros/imu/data".
    std::fs::write(
        &cfg,
        "[[inputs]]\nid = \"imu\"\nkind = \"imu\"\nkey = \"imu/data\"\nformat = \"ros2\"\n\
         type = \"sensor_msgs/msg/Imu\"\nrate_hz = 200.0\n",
    )
    .expect("config");
    let sim = Service::spawn(
        &[
            "sim",
            "-c",
            cfg.to_str().expect("path"),
            "--duration",
            "300",
        ],
        &[],
    );
    let run = Service::start(&["run", "--connect", &sim.zenoh_endpoint()], &[]);
    let d = run.wait_json("/api/v1/discovered", Duration::from_secs(20), |d| {
        d["keys"].as_array().is_some_and(|k| {
            k.iter()
                .any(|x| x["key"] == "imu/data" && !x["near"].is_null())
        })
    });
    let k = d["keys"]
        .as_array()
        .and_then(|k| k.iter().find(|x| x["key"] == "imu/data"))
        .unwrap_or_else(|| panic!("imu/data not discovered: {d}\n{}", sim.log_text()));
    assert_eq!(k["read_by"], serde_json::json!([]), "{k}");
    assert_eq!(k["near"]["input"], "imu", "{k}");
    assert!(
        k["near"]["why"]
            .as_str()
            .unwrap_or("")
            .contains("mavros/imu/data"),
        "{k}"
    );
    assert_eq!(k["ros_type"], "sensor_msgs/msg/Imu", "{k}");
    // The input it is meant for has no data, and the log says where it waits and
    // what is published instead.
    let status = run.get_json("/api/v1/status");
    assert_eq!(sensor(&status, "imu")["accepted"], 0, "{status}");
    let end = std::time::Instant::now() + Duration::from_secs(20);
    let said = |log: &str| {
        log.lines().any(|l| {
            l.contains("nothing received on mavros/imu/data yet")
                && l.contains("published and looking meant for it: imu/data")
        })
    };
    while !said(&run.log_text()) && std::time::Instant::now() < end {
        std::thread::sleep(Duration::from_millis(250));
    }
    assert!(said(&run.log_text()), "{}", run.log_text());
    // Written to a file, the log carries no colour codes (issue 35).
    assert!(
        !run.log_text().contains('\u{1b}'),
        "ANSI escapes in a log file"
    );
}
