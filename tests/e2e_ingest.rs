//! End to end: the service binary on free ports, real producers (Python eclipse-zenoh
//! sessions publishing rosbags-serialised ROS 2 / ROS 1 bytes, mavlink-server JSON from
//! the reference Codec, pymavlink frames, skyfuse JSON), and `/api/v1/status` checked
//! to count every sample for the right sensor; as a Zenoh client, waiting for its
//! router and reconnecting after the router restarts.

mod common;
use common::*;
use std::time::{Duration, Instant};

fn count(s: &serde_json::Value, field: &str) -> u64 {
    s[field].as_u64().unwrap_or(u64::MAX)
}

#[test]
fn every_format_is_counted_for_the_right_sensor_and_bad_input_is_rejected() {
    let dir = TempDir::new("e2e");
    std::fs::create_dir_all(&dir).expect("dir");
    let cfg = dir.join("e2e.toml");
    let inputs = run_py("publish_inputs.py", &["--print-config"]);
    std::fs::write(&cfg, format!("[service]\nvehicle = \"e2e\"\n\n{inputs}")).expect("config");
    let svc = Service::start(&["run", "-c", cfg.to_str().expect("path")], &[]);

    let expected_text = run_py("publish_inputs.py", &["--connect", &svc.zenoh_endpoint()]);
    let expected: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(expected_text.trim()).expect("publisher summary");
    // The mavlink-server JSON inputs need the shared reference Codec (left out, saying
    // so, without it): 13 of them.
    let codec = skyfuse_core::shared_data::shared_dir().join("tools/mavlink_server_json.py");
    let covered = if codec.is_file() { 30 } else { 18 };
    assert!(
        expected.len() >= covered,
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

/// Issue 35: a listing whose reader goes away (`skyfuse sim --list | head -1`) ends
/// quietly, killed by SIGPIPE as Unix tools are, not with a panic on its next line.
#[test]
fn a_listing_whose_reader_goes_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args(["sim", "--list"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    // The reader is gone before the first line is written.
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("wait");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("panicked") && !err.contains("Broken pipe"),
        "{err}"
    );
    assert!(
        out.status.signal() == Some(13) || out.status.success(),
        "{:?}: {err}",
        out.status
    );
}

#[test]
fn check_config_names_unknown_keys_and_missing_files() {
    let dir = TempDir::new("cc");
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

/// A router on `port` (Python eclipse-zenoh in router mode) publishing an IMU for
/// `seconds`, in a thread; joins to the number of samples it published.
fn router(port: u16, seconds: f64) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let out = run_py(
            "zenoh_router.py",
            &[
                "--listen",
                &format!("tcp/127.0.0.1:{port}"),
                "--seconds",
                &seconds.to_string(),
            ],
        );
        let v: serde_json::Value = serde_json::from_str(out.trim()).expect("router JSON");
        v["published"].as_u64().unwrap_or(0)
    })
}

fn client_of(router_port: u16) -> Service {
    Service::spawn(
        &[
            "run",
            "--mode",
            "client",
            "--connect",
            &format!("tcp/127.0.0.1:{router_port}"),
        ],
        &[],
    )
}

fn imu_count(status: &serde_json::Value) -> u64 {
    sensor(status, "imu")["received"].as_u64().unwrap_or(0)
}

fn imu_received(svc: &Service) -> u64 {
    imu_count(&svc.get_json("/api/v1/status"))
}

#[test]
fn a_zenoh_client_waits_for_its_router_and_reconnects_after_a_router_restart() {
    let router_port = free_port();
    let mut svc = client_of(router_port);
    // No router yet: skyfuse waits (a container started beside its router), it does not exit.
    std::thread::sleep(Duration::from_millis(2500));
    assert!(
        svc.running(),
        "exited without a router:\n{}",
        svc.log_text()
    );
    assert!(
        svc.log_text().contains("connecting to the Zenoh router"),
        "{}",
        svc.log_text()
    );

    let first = router(router_port, 8.0);
    svc.wait_healthy(Duration::from_secs(15));
    let s = svc.wait_status(Duration::from_secs(10), |s| imu_count(s) > 50);
    assert!(imu_count(&s) > 50, "{s}");
    let s = svc.wait_status(Duration::from_secs(3), |s| {
        s["service"]["zenoh"]["routers"] == 1
    });
    assert_eq!(s["service"]["zenoh"]["routers"], 1, "{}", s["service"]);
    let published = first.join().expect("router thread");
    assert!(published > 300, "router published {published}");

    // The router is gone: skyfuse stays up, nothing arrives.
    std::thread::sleep(Duration::from_millis(1500));
    assert!(svc.running(), "exited when the router went away");
    let before = imu_received(&svc);
    std::thread::sleep(Duration::from_millis(1000));
    assert_eq!(imu_received(&svc), before, "samples without a router");
    // ... and says why: the link, not the sensors.
    let s = svc.get_json("/api/v1/status");
    assert_eq!(s["service"]["zenoh"]["routers"], 0, "{}", s["service"]);
    assert!(
        svc.log_text().contains("Zenoh: lost every router"),
        "{}",
        svc.log_text()
    );

    // The router comes back on the same endpoint: the same process resumes ingest.
    let second = router(router_port, 12.0);
    let restarted = Instant::now();
    let s = svc.wait_status(Duration::from_secs(12), |s| imu_count(s) > before + 20);
    let resumed = restarted.elapsed();
    assert!(
        imu_count(&s) > before + 20,
        "no samples after the router came back: {s}\n{}",
        svc.log_text()
    );
    eprintln!("router back: samples again after {resumed:.2?}");
    let (status, took) = svc.terminate();
    assert!(status.success(), "{status}");
    assert!(took < Duration::from_secs(2), "stop took {took:?}");
    second.join().expect("router thread");
}

#[test]
fn sigterm_while_waiting_for_the_router_exits_cleanly() {
    let mut svc = client_of(free_port());
    std::thread::sleep(Duration::from_millis(1500));
    assert!(svc.running(), "{}", svc.log_text());
    // Issue 35, item 9: the HTTP port answers while the router is away (it held
    // connections unanswered, and the container's healthcheck said "Resource
    // temporarily unavailable"): 503 and why, to a browser and to `skyfuse healthcheck`.
    let (code, body) = common::http_get(svc.http_port, "/healthz").expect("an answer");
    assert_eq!(code, 503, "{body}");
    assert!(body.contains("waiting for the Zenoh session"), "{body}");
    let hc = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args([
            "healthcheck",
            "--http",
            &format!("127.0.0.1:{}", svc.http_port),
        ])
        .output()
        .expect("healthcheck");
    assert_eq!(hc.status.code(), Some(1));
    let said = String::from_utf8_lossy(&hc.stderr);
    assert!(
        said.contains("answered 503: starting: waiting for the Zenoh session"),
        "{said}"
    );
    let (status, took) = svc.terminate();
    assert!(status.success(), "{status}: {}", svc.log_text());
    assert!(took < Duration::from_secs(2), "stop took {took:?}");
    assert!(svc
        .log_text()
        .contains("stopped before the Zenoh session opened"));
}

#[test]
fn zenoh_with_mutual_tls_and_access_control_lets_only_the_named_bridge_in() {
    // skyfuse listens on Zenoh over TLS only, with mutual TLS and the access control list
    // of the shipped config/zenoh-secure.json5 (default deny; the certificate named
    // sensor-bridge may put on the input keys; any authenticated peer may watch the
    // outputs). Four publishers of gps/fix, each for 3 s at 10 Hz, each also subscribed
    // to skyfuse's health: the bridge's samples arrive; a certificate of the same CA with
    // another name is let in by TLS, sees the health, but its puts are denied; a
    // certificate of another CA, and plain TCP to the TLS port, get no session at all.
    let dir = TempDir::new("tls");
    let zport = free_port();
    let setup = run_py(
        "zenoh_tls.py",
        &["setup", dir.to_str().expect("path"), &zport.to_string()],
    );
    let config: serde_json::Value = serde_json::from_str(setup.trim()).expect("setup");
    let http = free_port();
    let log = std::fs::File::create(dir.join("skyfuse.log")).expect("log");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
        .args(["run", "--http", &format!("127.0.0.1:{http}")])
        .env(
            "SKYFUSE__ZENOH__CONFIG_FILE",
            config["config"].as_str().expect("path"),
        )
        // The file's TLS endpoint only: the default config's tcp/0.0.0.0:7447 would
        // otherwise be applied on top of it.
        .env("SKYFUSE__ZENOH__LISTEN", "[]")
        .env("SKYFUSE__ZENOH__MULTICAST_SCOUTING", "false")
        .env("RUST_LOG", "info,zenoh=warn")
        .stdout(log.try_clone().expect("log"))
        .stderr(log)
        .spawn()
        .expect("skyfuse");
    let start = Instant::now();
    while http_get(http, "/healthz").ok().map(|r| r.0) != Some(200) {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "skyfuse did not start: {}",
            std::fs::read_to_string(dir.join("skyfuse.log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let gps = || -> u64 {
        let (_, body) = http_get(http, "/api/v1/status").expect("status");
        let s: serde_json::Value = serde_json::from_str(&body).expect("json");
        sensor(&s, "gps")["received"].as_u64().unwrap_or(0)
    };
    let mut seen = vec![];
    for who in ["bridge", "intruder", "stranger", "plain"] {
        let before = gps();
        let out = run_py(
            "zenoh_tls.py",
            &[
                "publish",
                dir.to_str().expect("path"),
                &zport.to_string(),
                who,
                "3",
            ],
        );
        std::thread::sleep(Duration::from_millis(300));
        let r: serde_json::Value = serde_json::from_str(out.trim()).expect("publish");
        seen.push((who, gps() - before, r));
    }
    let _ = child.kill();
    let _ = child.wait();
    println!("{seen:?}");
    let got = |w: &str| seen.iter().find(|s| s.0 == w).map(|s| s.1).unwrap_or(0);
    let linked = |w: &str| {
        seen.iter()
            .find(|s| s.0 == w)
            .and_then(|s| s.2["linked_peers"].as_u64())
            .unwrap_or(0)
    };
    assert!(got("bridge") >= 25, "the bridge's 30 samples: {seen:?}");
    assert_eq!(linked("intruder"), 1, "TLS lets the intruder in: {seen:?}");
    assert_eq!(
        got("intruder"),
        0,
        "the access control keeps its puts out: {seen:?}"
    );
    assert_eq!(linked("stranger"), 0, "another CA: no session: {seen:?}");
    assert_eq!(got("stranger"), 0, "{seen:?}");
    assert_eq!(linked("plain"), 0, "plain TCP to the TLS port: {seen:?}");
    assert_eq!(got("plain"), 0, "{seen:?}");
}

/// Zenoh's thread names in process `pid` (`rx-0`, `acc-0`, ...), without the index.
fn zenoh_threads(pid: u32) -> std::collections::BTreeSet<String> {
    std::fs::read_dir(format!("/proc/{pid}/task"))
        .expect("/proc")
        .filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("comm")).ok())
        .filter_map(|c| Some(c.trim().rsplit_once('-')?.0.to_string()))
        .collect()
}

#[test]
fn links_accepted_by_the_service_are_read_by_zenohs_receiving_threads() {
    // By default a link skyfuse accepts stays with Zenoh's acceptor runtime, whose
    // thread wakes for every message to wake a receiving one; skyfuse hands the
    // acceptor over to the receiving runtime unless ZENOH_RUNTIME says otherwise.
    for (user, acceptor_thread) in [(None, false), (Some("(rx: (worker_threads: 1))"), true)] {
        let env: Vec<(&str, &str)> = user.map(|v| ("ZENOH_RUNTIME", v)).into_iter().collect();
        let listener = Service::start(&["run", "--connect", "tcp/127.0.0.1:1"], &env);
        let _peer = Service::start(&["run", "--connect", &listener.zenoh_endpoint()], &env);
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        let mut names = zenoh_threads(listener.child.id());
        while !names.contains("rx") && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(200));
            names = zenoh_threads(listener.child.id());
        }
        assert!(names.contains("rx"), "ZENOH_RUNTIME {user:?}: {names:?}");
        assert_eq!(
            names.contains("acc"),
            acceptor_thread,
            "ZENOH_RUNTIME {user:?}: {names:?}"
        );
    }
}
