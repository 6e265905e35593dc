//! End to end: the dashboard in Debian's headless Chromium (driven by Python
//! playwright) against `skyfuse demo`; the control API's token; a websocket client that
//! never reads next to one that does; /metrics read by the Prometheus client's parser.

mod common;
use common::*;
use std::time::Duration;

/// The tests that drive Chromium or load the service take turns: two browsers and two
/// demos at once on a 2-core machine starve the pages' websockets, and a page that
/// falls behind shows the gaps of the frames it lost.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

#[test]
fn the_page_draws_live_data_and_an_injected_fault_reaches_the_log_and_its_tile() {
    let _turn = one_at_a_time();
    if skip_requested("browser", "the dashboard in Chromium") {
        return;
    }
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    // The README shows docs/dashboard.png: written only when asked
    // (SKYFUSE_SCREENSHOT=1), so a test run never rewrites a tracked file.
    let scratch = TempDir::new("dashboard");
    let shot = if std::env::var_os("SKYFUSE_SCREENSHOT").is_some() {
        repo_root().join("docs/dashboard.png")
    } else {
        scratch.join("dashboard.png")
    };
    if let Some(dir) = shot.parent() {
        std::fs::create_dir_all(dir).expect("screenshot dir");
    }
    let out = json(&run_py(
        "dashboard_check.py",
        &[
            "--url",
            &format!("http://127.0.0.1:{}/", svc.http_port),
            "--token",
            &svc.token,
            "--screenshot",
            shot.to_str().expect("path"),
            "--inject-sensor",
            "gps",
            "--inject-fault",
            "stop",
            "--inject-duration",
            "20",
        ],
    ));
    assert_eq!(out["ok"], true, "{out}");
    // The demo serves Foxglove: the page says where.
    assert!(
        out["recorder_row"]
            .as_str()
            .is_some_and(|r| r.contains("Foxglove ws://127.0.0.1:")),
        "{out}"
    );
    // Every configured sensor has a tile.
    let status = svc.get_json("/api/v1/status");
    let tiles = out["tiles"].as_array().expect("tiles");
    for s in status["sensors"].as_array().expect("sensors") {
        assert!(tiles.contains(&s["id"]), "no tile for {}: {out}", s["id"]);
    }
    // Every plot and the map drew points from the running simulator.
    for (name, n) in out["point_counts"].as_object().expect("point counts") {
        assert!(n.as_u64().unwrap_or(0) > 0, "{name} drew nothing: {out}");
    }
    // The fault reached the service: gps is stale in the API as on the tile.
    let s = svc.wait_status(Duration::from_secs(10), |s| {
        sensor(s, "gps")["health"] == "stale"
    });
    assert_eq!(sensor(&s, "gps")["health"], "stale");
    assert!(shot.exists());
}

#[test]
fn controls_need_the_token_and_change_nothing_without_it() {
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let reset = |s: &serde_json::Value| s["estimator"]["reset_counter"].as_u64().unwrap_or(999);
    let before = reset(&svc.get_json("/api/v1/status"));
    for token in [None, Some("wrong-token")] {
        let (code, body) =
            http_post(svc.http_port, "/api/v1/control/reset-origin", "", token).expect("POST");
        assert_eq!(code, 401, "{body}");
        let (code, _) = http_post(
            svc.http_port,
            "/api/v1/control/fault",
            r#"{"sensor":"gps","fault":"stop"}"#,
            token,
        )
        .expect("POST");
        assert_eq!(code, 401);
    }
    std::thread::sleep(Duration::from_millis(700));
    let s = svc.get_json("/api/v1/status");
    assert_eq!(reset(&s), before, "a refused control changed the estimate");
    assert_eq!(s["controls"]["refused"], 4);
    assert_ne!(sensor(&s, "gps")["health"], "stale");
    // The token never shows.
    let cfg = svc.get_json("/api/v1/config");
    assert!(!cfg.to_string().contains(&svc.token));
    // With the token it works: the origin reset is a discontinuity.
    let (code, body) = http_post(
        svc.http_port,
        "/api/v1/control/reset-origin",
        "",
        Some(&svc.token),
    )
    .expect("POST");
    assert_eq!(code, 200, "{body}");
    let s = svc.get_json("/api/v1/status");
    assert_eq!(reset(&s), (before + 1) % 256);
}

#[test]
fn guessing_the_token_is_limited_per_address_and_big_bodies_are_refused() {
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"].is_object());
    let post = |token: Option<&str>| {
        http_post(svc.http_port, "/api/v1/control/reset-origin", "", token).expect("POST")
    };
    // Ten wrong guesses are answered 401; the eleventh and anything after, the right
    // token included, 429 with Retry-After, for the rest of the minute.
    for i in 0..10 {
        assert_eq!(post(Some(&format!("guess-{i}"))).0, 401, "guess {i}");
    }
    let (code, body) = post(Some("guess-10"));
    assert_eq!(code, 401, "{body}");
    let (code, body) = post(Some(&svc.token));
    assert_eq!(code, 429, "{body}");
    assert!(body.contains("try again later"), "{body}");
    let s = svc.get_json("/api/v1/status");
    assert_eq!(s["controls"]["refused"], 12);
    assert!(svc.log_text().contains("too many refused requests"));
    // A body beyond 16 KiB is refused before any handler reads it.
    let big = format!(
        r#"{{"sensor":"gps","fault":"stop","pad":"{}"}}"#,
        "x".repeat(20_000)
    );
    let (code, _) = http_post(svc.http_port, "/api/v1/control/fault", &big, None).expect("POST");
    assert_eq!(code, 413);
}

#[test]
fn prometheus_reads_the_metrics_and_they_agree_with_the_status() {
    // Parsed by the Prometheus project's own OpenMetrics parser (tests/py/metrics_check.py)
    // and checked against /api/v1/status: every input, each sensor's health state,
    // validity, position σ, the refused controls; counters never go back; VPE flows.
    // VPE to a real UDP socket: with no endpoint nothing counts as sent.
    let autopilot = std::net::UdpSocket::bind("127.0.0.1:0").expect("udp");
    let to = format!("udpout:{}", autopilot.local_addr().expect("addr"));
    let svc = Service::start(&["demo", "--no-browser", "--mavlink", &to], &[]);
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    for _ in 0..2 {
        let (code, _) = http_post(
            svc.http_port,
            "/api/v1/control/reset-origin",
            "",
            Some("nope"),
        )
        .expect("POST");
        assert_eq!(code, 401);
    }
    let out = json(&run_py(
        "metrics_check.py",
        &["--port", &svc.http_port.to_string()],
    ));
    assert_eq!(out["problems"], serde_json::json!([]), "{out}");
    assert!(out["inputs"].as_u64().unwrap_or(0) >= 6, "{out}");
    assert!(out["vpe_per_s"].as_f64().unwrap_or(0.0) >= 20.0, "{out}");
    assert!(out["rss_mb"].as_f64().unwrap_or(0.0) > 1.0, "{out}");
    let (code, text) = http_get(svc.http_port, "/metrics").expect("GET");
    assert_eq!(code, 200);
    assert!(
        text.contains("skyfuse_controls_refused_total 2\n"),
        "{text}"
    );
    assert!(text.ends_with("# EOF\n"));
}

#[test]
fn a_client_that_never_reads_does_not_slow_the_others() {
    let _turn = one_at_a_time();
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let out = json(&run_py(
        "ws_clients.py",
        &["--port", &svc.http_port.to_string(), "--seconds", "25"],
    ));
    let rates: Vec<f64> = out["tick_rate_per_second"]
        .as_array()
        .expect("rates")
        .iter()
        .filter_map(|v| v.as_f64())
        .collect();
    assert!(rates.len() >= 20, "{out}");
    // The reading client keeps its 20 Hz ticks every second, start to end.
    let worst = rates.iter().skip(1).copied().fold(f64::INFINITY, f64::min);
    assert!(worst >= 15.0, "reader slowed to {worst:.1} Hz: {rates:?}");
    assert!(
        out["snapshot"]["sensors"].as_u64().unwrap_or(0) >= 6,
        "{out}"
    );
    // The slow one lost frames, and they were counted.
    let s = svc.get_json("/api/v1/status");
    let dropped = s["websocket"]["dropped_total"].as_u64().unwrap_or(0);
    assert!(dropped > 0, "no drops counted: {}", s["websocket"]);
    // And the estimator kept up with its input all along.
    assert!(
        s["ingest"]["queue_len"].as_u64().unwrap_or(u64::MAX) < 100,
        "{}",
        s["ingest"]
    );
}

/// A self-signed certificate for 127.0.0.1 (openssl): (cert, key).
fn self_signed(dir: &std::path::Path, name: &str) -> (String, String) {
    std::fs::create_dir_all(dir).expect("dir");
    let (cert, key) = (
        dir.join(format!("{name}.pem")),
        dir.join(format!("{name}.key")),
    );
    let ok = std::process::Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
        ])
        .args([
            "-subj",
            "/CN=skyfuse",
            "-addext",
            "subjectAltName=IP:127.0.0.1",
        ])
        .arg("-keyout")
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .output()
        .expect("openssl");
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    (cert.display().to_string(), key.display().to_string())
}

#[test]
fn https_serves_page_and_api_over_tls_only_and_the_healthcheck_asks_over_tls() {
    let _turn = one_at_a_time();
    let dir = TempDir::new("https");
    let (cert, key) = self_signed(&dir, "https");
    let env = [
        ("SKYFUSE__HTTP__TLS_CERT", cert.as_str()),
        ("SKYFUSE__HTTP__TLS_KEY", key.as_str()),
    ];
    let svc = Service::spawn(&["demo", "--no-browser"], &env);
    let out = json(&run_py(
        "https_check.py",
        &["--port", &svc.http_port.to_string(), "--ca", &cert],
    ));
    assert_eq!(out["page"], serde_json::json!([200, true, true]), "{out}");
    assert_eq!(out["access"], serde_json::json!([200, true]), "{out}");
    assert_eq!(out["status"], serde_json::json!([200, "skyfuse"]), "{out}");
    assert!(
        out["plain_http"]
            .as_str()
            .is_some_and(|s| s.starts_with("refused")),
        "plain HTTP gets no answer: {out}"
    );
    assert!(
        out["untrusted"]
            .as_str()
            .is_some_and(|s| s.starts_with("refused")),
        "{out}"
    );
    // The container's HEALTHCHECK: over TLS, trusting exactly the configured cert.
    let healthcheck = |cert: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_skyfuse"))
            .args([
                "healthcheck",
                "--http",
                &format!("127.0.0.1:{}", svc.http_port),
            ])
            .env("SKYFUSE__HTTP__TLS_CERT", cert)
            .env("SKYFUSE__HTTP__TLS_KEY", &key)
            .output()
            .expect("healthcheck")
    };
    let good = healthcheck(&cert);
    assert!(
        good.status.success(),
        "{}",
        String::from_utf8_lossy(&good.stderr)
    );
    let (other, _) = self_signed(&dir, "other");
    let bad = healthcheck(&other);
    assert_eq!(bad.status.code(), Some(1), "another certificate: unhealthy");
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("not the configured tls_cert"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
}

/// The page says what the API says (issue 35, "status as facts"): in Chromium, every
/// card, output row, the recorder row and the connection badge against
/// `/api/v1/status`, for a flying demo (no MAVLink endpoint, GPS at 10 Hz drawn as one
/// line, the Network panel listing the simulator's keys) and for a service nothing
/// publishes to (every card names the key it waits for, nothing sending, not "live").
#[test]
fn the_page_says_what_the_api_says() {
    let _turn = one_at_a_time();
    if skip_requested("browser", "the page against the API in Chromium") {
        return;
    }
    let demo = Service::start(&["demo", "--no-browser"], &[]);
    let url = format!("http://127.0.0.1:{}/", demo.http_port);
    let out = json(&run_py(
        "page_vs_api.py",
        &["--url", &url, "--expect", "flying"],
    ));
    assert_eq!(out["ok"], true, "{out}");
    // No endpoint configured: the MAVLink row says so, as the API does.
    let mavlink = out["page"]["outputs"]
        .as_array()
        .and_then(|o| o.iter().find(|r| r["name"] == "mavlink"))
        .cloned()
        .unwrap_or_default();
    assert_eq!(mavlink["badge"], "not sending", "{out}");
    assert!(
        mavlink["why"]
            .as_str()
            .unwrap_or("")
            .contains("no MAVLink endpoint"),
        "{out}"
    );
    drop(demo);

    let silent = Service::start(&["run"], &[]);
    let url = format!("http://127.0.0.1:{}/", silent.http_port);
    let out = json(&run_py(
        "page_vs_api.py",
        &["--url", &url, "--expect", "silent"],
    ));
    assert_eq!(out["ok"], true, "{out}");
    let status = silent.get_json("/api/v1/status");
    let tiles = out["page"]["tiles"].as_array().expect("tiles");
    let waiting: Vec<_> = tiles.iter().filter(|t| t["state"] == "no_data").collect();
    assert!(!waiting.is_empty(), "{out}");
    for t in waiting {
        let key = sensor(&status, t["id"].as_str().unwrap_or(""))["key"].clone();
        assert!(
            t["waiting"]
                .as_str()
                .unwrap_or("")
                .contains(key.as_str().unwrap_or("?")),
            "{t} {key}"
        );
    }
}
