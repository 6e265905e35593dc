//! End to end: `skyfuse demo` (the service fed by its simulator over Zenoh) with a
//! MAVLink UDP endpoint. What arrives is decoded by pymavlink; the Zenoh pose is read by
//! Python eclipse-zenoh and its CDR by rosbags; both are checked against the flight the
//! simulator flies and against the status API.

mod common;
use common::*;
use std::time::Duration;

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// `skyfuse demo` sending MAVLink to a free UDP port; returns the service and the port.
fn demo_with_mavlink_udp() -> (Service, u16) {
    let udp = free_port();
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("udpout:127.0.0.1:{udp}"),
        ],
        &[],
    );
    (svc, udp)
}

#[test]
fn demo_sends_vision_position_estimate_at_rate_with_ned_signs_and_zenoh_pose() {
    let (svc, udp) = demo_with_mavlink_udp();
    // The listener starts right away: it sees take-off (4–10 s, to 2 m) and the first
    // leg of the figure-eight (from 10 s: east and north both grow).
    let out = json(&run_py(
        "mavlink_listen.py",
        &["--port", &udp.to_string(), "--seconds", "17"],
    ));
    let vpe = out["vpe"].as_array().expect("vpe list");
    let hb = out["heartbeat"].as_array().expect("heartbeats");
    assert_eq!(out["bad_data"], 0, "undecodable frames: {out}");
    assert!(
        vpe.len() > 100,
        "only {} VPE: {}",
        vpe.len(),
        svc.log_text()
    );

    // Rate: 30 Hz ± 10 % over the steady part (after the first seconds).
    let steady: Vec<&serde_json::Value> = vpe.iter().filter(|v| f(&v["rx"]) > 6.0).collect();
    let span = f(&steady[steady.len() - 1]["rx"]) - f(&steady[0]["rx"]);
    let rate = (steady.len() - 1) as f64 / span;
    assert!((27.0..=33.0).contains(&rate), "VPE rate {rate:.1} Hz");

    for v in vpe {
        assert_eq!(v["finite"], true, "non-finite VPE {v}");
        assert_eq!(v["mavlink2"], true, "not MAVLink 2: {v}");
        assert_eq!(
            (v["sys"].as_u64(), v["comp"].as_u64()),
            (Some(1), Some(197))
        );
        // Covariance: the upper triangle's diagonal entries (0, 6, 11) are variances.
        for i in [0, 6, 11, 15, 18, 20] {
            assert!(f(&v["covariance"][i]) > 0.0, "variance {i} of {v}");
        }
    }
    // Timestamps move forward with the samples.
    for w in vpe.windows(2) {
        assert!(
            w[1]["usec"].as_u64() > w[0]["usec"].as_u64(),
            "{} then {}",
            w[0],
            w[1]
        );
    }

    // Signs: at cruise height NED z ≈ −2 m; on the first leg north (x) and east (y) grow.
    let at = |t: f64| {
        vpe.iter()
            .min_by(|a, b| (f(&a["rx"]) - t).abs().total_cmp(&(f(&b["rx"]) - t).abs()))
            .expect("a VPE")
    };
    let (a, b) = (at(11.0), at(16.5));
    assert!((f(&b["z"]) + 2.0).abs() < 0.4, "z at cruise {}", b["z"]);
    assert!(
        f(&b["y"]) - f(&a["y"]) > 1.0,
        "east did not grow: {a} -> {b}"
    );
    // North (3 sin 2ωτ) peaks a few seconds into the leg and comes back: its maximum
    // over the leg, not its end, shows the sign (the simulator's clock starts a little
    // before the listener's).
    let north_max = vpe
        .iter()
        .filter(|v| (11.0..=16.5).contains(&f(&v["rx"])))
        .map(|v| f(&v["x"]))
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(
        north_max - f(&a["x"]) > 0.8,
        "north did not grow: {a}, max {north_max}"
    );

    // HEARTBEAT at 1 Hz from component 197, an onboard controller.
    assert!(
        (14..=19).contains(&hb.len()),
        "{} heartbeats in 17 s",
        hb.len()
    );
    for h in hb {
        assert_eq!(h["comp"], 197);
        assert_eq!(h["type"], 18, "MAV_TYPE_ONBOARD_CONTROLLER");
    }

    // The reset counter is the estimator's; the status shows the output's counters.
    let status = svc.get_json("/api/v1/status");
    let last = vpe.last().expect("vpe");
    assert_eq!(last["reset_counter"], status["estimator"]["reset_counter"]);
    let mav = &status["outputs"][0];
    assert_eq!(mav["kind"], "mavlink");
    assert!(mav["sent"].as_u64().unwrap_or(0) >= vpe.len() as u64);
    assert_eq!(mav["sending"], true, "{mav}");

    // Zenoh: the JSON pose and the CDR PoseStamped (decoded by rosbags) agree.
    let z = json(&run_py(
        "zenoh_pose_listen.py",
        &[
            "--connect",
            &svc.zenoh_endpoint(),
            "--seconds",
            "3",
            "--prefix",
            "skyfuse/demo",
        ],
    ));
    assert!(z["json"].as_u64().unwrap_or(0) > 50, "{z}");
    assert!(z["cdr"].as_u64().unwrap_or(0) > 50, "{z}");
    // The full health goes every [output] health_interval_s (5 s).
    assert!(z["health"].as_u64().unwrap_or(9) <= 1, "{z}");
    assert!(z["matched"].as_u64().unwrap_or(0) > 20, "{z}");
    // The JSON's position is to the millimetre, the CDR's the f64 itself.
    assert!(f(&z["max_position_diff"]) <= 0.000_5 + 1e-9, "{z}");
    assert_eq!(z["last_cdr"]["frame_id"], "map");
    assert_eq!(z["errors"].as_array().map(Vec::len), Some(0), "{z}");
    // ENU JSON and NED VPE describe the same vehicle: up is positive here.
    assert!(f(&z["last_json"]["position"][2]) > 1.5, "{z}");
    // The pose comes at [output] pose_rate_hz (50) on its own clock, from 200 Hz of IMU
    // (a limit of "a period since the last one" would give ~40 Hz with jittered
    // samples); the debug series at most at debug_rate_hz (10): the T265's from 200 Hz,
    // the flow's from its own 50 Hz.
    let pose_rate = f(&z["json_rate_hz"]);
    assert!(
        (46.0..=50.5).contains(&pose_rate),
        "pose at {pose_rate:.1} Hz: {z}"
    );
    let debug = z["debug_rate_hz"].as_object().expect("debug rates");
    for series in ["oriUAV_t265", "OF_sum"] {
        assert!(debug.contains_key(series), "no {series}: {z}");
    }
    for (series, r) in debug {
        // null: one message in the window, no rate to speak of.
        assert!(
            r.as_f64().is_none_or(|r| r <= 10.5),
            "{series} at {r} Hz: {z}"
        );
    }
    // At least the series flows near its rate (the upper bound above is the one the
    // limiter promises).
    assert!(f(&debug["oriUAV_t265"]) > 8.0, "{z}");
    assert!(f(&debug["OF_sum"]) > 8.0, "{z}");
}

/// What one vehicle's default outputs may cost on the link, payload bytes a second
/// (issue 46: 50 vehicles on one ground link; BENCHMARKS.md, "Fleet at scale").
const ONE_VEHICLE_BUDGET_BYTES_PER_S: f64 = 50_000.0;

#[test]
fn one_demo_vehicles_default_outputs_stay_under_50_kb_a_second() {
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    // In the air (take-off from 4 s), where the pose lists the most sources.
    std::thread::sleep(Duration::from_secs(6));
    let bw = json(&run_py(
        "vehicle_bandwidth.py",
        &[
            "--connect",
            &svc.zenoh_endpoint(),
            "--seconds",
            "20",
            "--vehicle",
            "demo",
        ],
    ));
    let keys = &bw["keys"];
    let rate = |key: &str| f(&keys[key]["msgs_per_s"]);
    // Every output there, at its rate: the budget is not met by sending nothing.
    let pose_hz = rate("skyfuse/demo/pose");
    assert!(pose_hz > 40.0, "pose at {pose_hz} msg/s: {bw}");
    assert!(rate("data_fusion/pose_msg") > 40.0, "{bw}");
    assert!((0.8..=1.3).contains(&rate("skyfuse/demo/summary")), "{bw}");
    // The full health every [output] health_interval_s (5): four or five in 20 s.
    assert!((0.1..=0.35).contains(&rate("skyfuse/demo/health")), "{bw}");
    // The debug series at [output] debug_rate_hz (10), the camera's from 200 Hz.
    for series in ["oriUAV_t265", "OF_sum"] {
        let hz = rate(&format!("data_fusion/{series}"));
        assert!((7.0..=10.6).contains(&hz), "{series} at {hz} msg/s: {bw}");
    }
    // Scaled up to the full pose rate, so a slow machine cannot pass by publishing less.
    let total = f(&bw["total_bytes_per_s"]);
    let at_full_rate = total * (50.0 / pose_hz).max(1.0);
    assert!(
        at_full_rate < ONE_VEHICLE_BUDGET_BYTES_PER_S,
        "{total} B/s ({at_full_rate:.0} at 50 poses/s): {bw}"
    );
}

#[test]
fn no_position_source_means_no_vision_position_estimate() {
    let (svc, udp) = demo_with_mavlink_udp();
    // Wait for a valid estimate, then take every position and velocity source away.
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let token_env = svc.token.clone();
    let post = |sensor: &str, fault: &str| {
        let body = format!(r#"{{"sensor":"{sensor}","fault":"{fault}","duration_s":4}}"#);
        let (code, text) = http_post(
            svc.http_port,
            "/api/v1/control/fault",
            &body,
            Some(&token_env),
        )
        .expect("POST");
        assert_eq!(code, 200, "{text}");
    };
    let before = svc.get_json("/api/v1/status")["estimator"]["reset_counter"].clone();
    let listener = std::thread::spawn(move || {
        run_py(
            "mavlink_listen.py",
            &["--port", &udp.to_string(), "--seconds", "16"],
        )
    });
    std::thread::sleep(Duration::from_secs(2));
    for s in ["gps", "t265", "flow", "rangefinder"] {
        post(s, "stop");
    }
    let out = json(&listener.join().expect("listener"));
    let vpe = out["vpe"].as_array().expect("vpe");
    // Arrival gaps: one long gap while nothing could be trusted, VPE before and after.
    let gaps: Vec<(f64, f64)> = vpe
        .windows(2)
        .map(|w| (f(&w[0]["rx"]), f(&w[1]["rx"]) - f(&w[0]["rx"])))
        .filter(|(_, g)| *g > 0.5)
        .collect();
    assert_eq!(gaps.len(), 1, "gaps {gaps:?}");
    let (at, gap) = gaps[0];
    assert!((2.0..4.5).contains(&at), "gap started at {at}");
    assert!(gap > 2.0, "gap {gap}");
    assert!(
        vpe.iter().any(|v| f(&v["rx"]) > at + gap + 1.0),
        "VPE did not resume"
    );
    let status = svc.get_json("/api/v1/status");
    let mav = &status["outputs"][0];
    assert!(mav["withheld"].as_u64().unwrap_or(0) > 30, "{mav}");
    // Coming back after the gap is a discontinuity the autopilot must be told of.
    let after = vpe
        .last()
        .map(|v| v["reset_counter"].clone())
        .unwrap_or_default();
    assert_ne!(after, before, "reset counter did not move");
    assert!(
        svc.log_text().contains("not sending: estimate invalid"),
        "no reason logged"
    );
}

#[test]
fn a_serial_link_absent_at_start_unplugged_and_plugged_back_carries_vpe() {
    // A pseudo-terminal pair stands in for a USB serial adapter (tests/py/pty_serial.py):
    // the path does not exist when skyfuse starts, appears, vanishes, comes back.
    let dir = TempDir::new("pty");
    std::fs::create_dir_all(&dir).expect("temp dir");
    let link = dir.join("ttyFC");
    let endpoint = format!("serial:{}:57600", link.display());
    let svc = Service::start(&["demo", "--no-browser", "--mavlink", &endpoint], &[]);
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    // Absent so far: refused and counted, not fatal.
    let s = svc.get_json("/api/v1/status");
    let link_status = &s["outputs"][0]["links"][0];
    assert_eq!(link_status["connected"], false, "{link_status}");
    assert!(
        link_status["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("cannot open")),
        "{link_status}"
    );
    let out = json(&run_py(
        "pty_serial.py",
        &[
            "--link",
            &link.display().to_string(),
            "--seconds",
            "5",
            "--gap",
            "3",
        ],
    ));
    let _ = std::fs::remove_dir_all(&dir);
    println!("serial link, plugged / unplugged 3 s / plugged: {out}");
    for phase in ["before", "after"] {
        let p = &out[phase];
        // 30 Hz VPE; the first second of each phase goes to the back-off (≤ 2 s).
        assert!(p["vpe"].as_u64().unwrap_or(0) >= 60, "{phase}: {out}");
        assert!(p["heartbeat"].as_u64().unwrap_or(0) >= 2, "{phase}: {out}");
        assert_eq!(p["bad"], 0, "{phase}: {out}");
    }
    let s = svc.get_json("/api/v1/status");
    let l = &s["outputs"][0]["links"][0];
    assert!(
        l["errors"].as_u64().unwrap_or(0) >= 2,
        "the outage is counted: {l}"
    );
    assert!(l["sent"].as_u64().unwrap_or(0) >= 120, "{l}");
}

/// tests/py/flood.py on gps/fix for 5 s, with `extra` arguments; its report.
fn flood_gps(svc: &Service, extra: &[&str]) -> serde_json::Value {
    let endpoint = svc.zenoh_endpoint();
    let mut args = vec!["--connect", &endpoint, "--key", "gps/fix", "--seconds", "5"];
    args.extend_from_slice(extra);
    json(&run_py("flood.py", &args))
}

#[test]
fn one_input_flooded_is_shed_and_the_others_lose_nothing() {
    // A publisher floods gps/fix (10 Hz configured) as fast as Python can put (tens of
    // kHz): its excess is shed at ingest (4 × 10 + 20 Hz pass), the queue the other
    // sensors share never fills, no other sample is dropped, the pose stays valid and
    // the autopilot keeps getting VPE at its rate.
    let (svc, udp) = demo_with_mavlink_udp();
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let listener = std::thread::spawn(move || {
        run_py(
            "mavlink_listen.py",
            &["--port", &udp.to_string(), "--seconds", "8"],
        )
    });
    let flood = flood_gps(&svc, &[]);
    let out = json(&listener.join().expect("listener"));
    let s = svc.get_json("/api/v1/status");
    println!("flood: {flood}; gps: {}", sensor(&s, "gps"));
    let put = flood["put"].as_u64().unwrap_or(0);
    assert!(
        put > 5_000,
        "the flood was too weak to mean anything: {flood}"
    );
    let gps = sensor(&s, "gps");
    let (shed, received) = (
        gps["shed"].as_u64().unwrap_or(0),
        gps["received"].as_u64().unwrap_or(0),
    );
    // Zenoh itself drops part of a flood this size (put is not received); of what
    // arrives, all but ≤ 60 a second is shed.
    assert!(received > 5_000, "{gps}");
    assert!(shed + 60 * 8 + 200 >= received, "shed {shed} of {received}");
    for other in s["sensors"].as_array().expect("sensors") {
        assert_eq!(other["dropped"], 0, "{}", other["id"]);
    }
    assert_eq!(s["estimator"]["valid"], true);
    // VPE at ~30 Hz all through: no gap of half a second.
    let rx: Vec<f64> = out["vpe"]
        .as_array()
        .expect("vpe")
        .iter()
        .map(|v| f(&v["rx"]))
        .collect();
    assert!(rx.len() > 180, "{} VPE in 8 s", rx.len());
    let worst = rx.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    assert!(worst < 0.5, "VPE gap {worst:.2} s during the flood");
}

#[test]
fn a_flood_on_a_clock_a_day_behind_is_shed_and_the_real_gps_recovers_at_once() {
    // Beside the real GPS, a publisher floods gps/fix with messages stamped a day in the
    // past and advancing: a consistent second series, the worst case for the clock
    // restart detector. The flood is shed, nothing else is dropped, the estimate stays
    // valid, and within seconds of the flood ending the real GPS is accepted and ok.
    let (svc, _udp) = demo_with_mavlink_udp();
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let flood = flood_gps(&svc, &["--clock-jump", "-86400"]);
    let during = svc.get_json("/api/v1/status");
    assert!(flood["put"].as_u64().unwrap_or(0) > 2_000, "{flood}");
    assert_eq!(
        during["estimator"]["valid"], true,
        "{}",
        during["estimator"]
    );
    for other in during["sensors"].as_array().expect("sensors") {
        assert_eq!(other["dropped"], 0, "{}", other["id"]);
    }
    let accepted = |s: &serde_json::Value| sensor(s, "gps")["accepted"].as_u64().unwrap_or(0);
    let ended = std::time::Instant::now();
    let base = accepted(&during);
    // The real GPS at 10 Hz: 20 more accepted, and healthy, within 5 s.
    let after = svc.wait_status(Duration::from_secs(5), |s| {
        accepted(s) >= base + 20 && sensor(s, "gps")["health"] == "ok"
    });
    let gps = sensor(&after, "gps");
    println!(
        "flood: {flood}; recovered in {:.1} s; gps: {gps}",
        ended.elapsed().as_secs_f64()
    );
    assert!(
        accepted(&after) >= base + 20 && gps["health"] == "ok",
        "the real GPS is still refused after the flood: {gps}"
    );
    assert_eq!(after["estimator"]["valid"], true);
}

#[test]
fn mavlink_server_killed_and_restarted_is_seen_and_nothing_else_notices() {
    // The real mavlink-server between an autopilot stand-in (pymavlink frames over TCP)
    // and skyfuse: killed, down 3 s, started again. The autopilot input goes stale and
    // comes back on its own; the other sensors, the estimate and the VPE carry on.
    let msrv = common::peers_dir().join("bin/mavlink-server");
    if !msrv.exists() {
        common::skipped(
            "mavlink_server_killed_and_restarted",
            &format!("no {} ($SKYFUSE_PEERS)", msrv.display()),
        );
        return;
    }
    // The `autopilot` input (LOCAL_POSITION_NED, compared, never fused) is input 6.
    let svc = Service::start(
        &["demo", "--no-browser"],
        &[("SKYFUSE__INPUTS__6__ENABLED", "true")],
    );
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let r = json(&run_py(
        "msrv_restart.py",
        &[
            "--mavlink-server",
            msrv.to_str().expect("path"),
            "--zenoh",
            &svc.zenoh_endpoint(),
            "--http",
            &svc.http_port.to_string(),
        ],
    ));
    println!("{r}");
    assert!(r["error"].is_null(), "{r}");
    let stale = r["stale_after_s"].as_f64().unwrap_or(f64::NAN);
    let back = r["ok_again_after_restart_s"].as_f64().unwrap_or(f64::NAN);
    // Stale after 5 periods (167 ms) plus the health tick; back once mavlink-server has
    // reconnected to both sides (it takes about a second to start).
    assert!(stale < 2.0, "stale after {stale} s: {r}");
    assert!(back < 10.0, "ok again after {back} s: {r}");
    for (phase, key) in [("while_down", "others"), ("after", "others")] {
        for (id, v) in r[phase][key].as_object().expect("others") {
            assert_eq!(v[0], "ok", "{id} {phase}: {r}");
            assert_eq!(v[1], 0, "{id} dropped {phase}: {r}");
        }
    }
    assert_eq!(r["while_down"]["valid"], true, "{r}");
    assert_eq!(r["after"]["valid"], true, "{r}");
    assert!(
        r["after"]["received"].as_u64() > r["before"]["received"].as_u64(),
        "{r}"
    );
    assert_eq!(r["after"]["rejected"], 0, "{r}");
    let vpe = r["after"]["vpe_sent"].as_u64().unwrap_or(0)
        - r["before"]["vpe_sent"].as_u64().unwrap_or(0);
    assert!(
        vpe > 100,
        "VPE kept going: {vpe} in the outage and after: {r}"
    );
    // The outage and the recovery are events on Zenoh as well as in the status.
    let events = r["events"].to_string();
    assert!(
        events.contains("stale") && events.contains("ok"),
        "autopilot events: {events}"
    );
}

#[test]
fn a_tcp_peer_that_restarts_gets_vpe_again() {
    // skyfuse connects out (`tcpout:`) to a server that is not there yet, then is, then
    // closes and refuses for 2 s, then listens again on the same port.
    let port = free_port();
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("tcpout:127.0.0.1:{port}"),
        ],
        &[],
    );
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    let out = json(&run_py(
        "tcp_restart.py",
        &["--port", &port.to_string(), "--seconds", "4", "--gap", "2"],
    ));
    println!("tcp peer restart: {out}");
    for phase in ["before", "after"] {
        let p = &out[phase];
        assert!(p["vpe"].as_u64().unwrap_or(0) >= 60, "{phase}: {out}");
        assert_eq!(p["bad"].as_u64().unwrap_or(0), 0, "{phase}: {out}");
    }
    // Back within the back-off (250 ms doubling, the outage was 2 s).
    assert!(f(&out["after"]["accepted_after_s"]) < 5.0, "{out}");
    let s = svc.get_json("/api/v1/status");
    let l = &s["outputs"][0]["links"][0];
    assert!(
        l["errors"].as_u64().unwrap_or(0) >= 1,
        "the outage is counted: {l}"
    );
}

#[test]
fn a_udp_peer_that_is_not_listening_yet_gets_vpe_once_it_is() {
    // Nobody on the port: the kernel answers ICMP port unreachable, a connected UDP
    // socket reports it on a later send. skyfuse counts it and keeps sending; the
    // autopilot (here pymavlink) that starts listening later gets VPE at once.
    let (svc, udp) = demo_with_mavlink_udp();
    svc.wait_status(Duration::from_secs(20), |s| s["estimator"]["valid"] == true);
    std::thread::sleep(Duration::from_secs(2));
    let s = svc.get_json("/api/v1/status");
    let before = s["outputs"][0].clone();
    let out = json(&run_py(
        "mavlink_listen.py",
        &["--port", &udp.to_string(), "--seconds", "4"],
    ));
    let n = out["vpe"].as_array().map_or(0, Vec::len);
    println!("udp peer late: {n} VPE in 4 s; before it listened: {before}");
    assert!(n >= 100, "{n} VPE in 4 s");
    assert_eq!(out["bad_data"], 0);
    assert_eq!(before["sending"], true, "{before}");
}

/// Issue 35: `skyfuse demo` with no MAVLink endpoint must not say "sending": the status
/// (and so the dashboard and /metrics, built from it) says why nothing is sent, and
/// nothing is counted as sent, while the estimate is valid.
#[test]
fn without_an_endpoint_mavlink_says_it_is_not_sending() {
    let svc = Service::start(&["demo", "--no-browser"], &[]);
    let s = svc.wait_status(Duration::from_secs(20), |s| {
        s["estimator"]["valid"] == true && s["outputs"][0]["heartbeats"].as_u64() > Some(1)
    });
    let mav = &s["outputs"][0];
    assert_eq!(mav["name"], "mavlink", "{mav}");
    assert_eq!(mav["sending"], false, "{mav}");
    assert_eq!(mav["sent"], 0, "{mav}");
    let why = mav["not_sending_reason"].as_str().unwrap_or_default();
    assert!(why.contains("no MAVLink endpoint"), "{mav}");
    let (code, text) = http_get(svc.http_port, "/metrics").expect("GET");
    assert_eq!(code, 200);
    assert!(
        text.contains("skyfuse_output_sent_total{output=\"mavlink\",kind=\"mavlink\"} 0\n")
            || text.contains("skyfuse_output_sent_total{kind=\"mavlink\",output=\"mavlink\"} 0\n"),
        "{}",
        text.lines()
            .filter(|l| l.contains("output_sent"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Issue 36: each endpoint chooses its pose messages (`?messages=`): ODOMETRY to one
/// (ArduPilot `VISO_TYPE` 1/3 and PX4 EKF2 read it), VISION_POSITION_ESTIMATE to the
/// other, each only what it asked for. ODOMETRY as the autopilots read it: LOCAL_NED
/// pose, BODY_FRD velocity that, rotated by its own quaternion, is the pose's motion;
/// positive variances; quality; nothing non-finite.
#[test]
fn each_endpoint_gets_the_pose_messages_it_asks_for() {
    let (odo_port, vpe_port) = (free_port(), free_port());
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("udpout:127.0.0.1:{odo_port}?messages=odometry"),
            "--mavlink",
            &format!("udpout:127.0.0.1:{vpe_port}"),
        ],
        &[],
    );
    // In the figure-eight (from 10 s), where the body velocity is not zero.
    svc.wait_status(Duration::from_secs(30), |s| {
        s["estimator"]["valid"] == true && s["service"]["uptime_s"].as_f64() > Some(12.0)
    });
    let odo_listener = std::process::Command::new(python())
        .arg(repo_root().join("tests/py/mavlink_listen.py"))
        .args(["--port", &odo_port.to_string(), "--seconds", "4"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("listener");
    let vpe_side = json(&run_py(
        "mavlink_listen.py",
        &["--port", &vpe_port.to_string(), "--seconds", "4"],
    ));
    let out = odo_listener.wait_with_output().expect("listener output");
    let odo_side = json(&String::from_utf8_lossy(&out.stdout));
    let odo = odo_side["odometry"].as_array().cloned().unwrap_or_default();
    let n_vpe = vpe_side["vpe"].as_array().map_or(0, Vec::len);
    eprintln!(
        "ODOMETRY endpoint: {} ODOMETRY, {} VPE; VPE endpoint: {n_vpe} VPE, {} ODOMETRY",
        odo.len(),
        odo_side["vpe"].as_array().map_or(0, Vec::len),
        vpe_side["odometry"].as_array().map_or(0, Vec::len),
    );
    assert!(odo.len() >= 90, "{} ODOMETRY in 4 s", odo.len());
    assert_eq!(odo_side["vpe"].as_array().map_or(0, Vec::len), 0);
    assert!(n_vpe >= 90, "{n_vpe} VPE in 4 s");
    assert_eq!(vpe_side["odometry"].as_array().map_or(0, Vec::len), 0);
    for m in &odo {
        assert_eq!(m["finite"], true, "{m}");
        assert_eq!(m["frame_id"], 1, "MAV_FRAME_LOCAL_NED: {m}");
        assert_eq!(m["child_frame_id"], 12, "MAV_FRAME_BODY_FRD: {m}");
        let q = m["quality"].as_i64().unwrap_or(-1);
        assert!((1..=100).contains(&q), "quality of a valid pose: {m}");
        // Variances on the upper triangle's diagonal: x, y, z, roll, pitch, yaw.
        let pc: Vec<f64> = m["pose_covariance"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
            .unwrap_or_default();
        for i in [0, 6, 11, 15, 18, 20] {
            assert!(pc.get(i).is_some_and(|&v| v > 0.0), "variance {i}: {m}");
        }
    }
    // The body velocity, turned into NED by the message's own attitude, is the motion
    // of its position: a frame or sign slip would not be.
    let f = |m: &serde_json::Value, k: &str, i: usize| m[k][i].as_f64().unwrap_or(f64::NAN);
    let (mut errs, mut speeds) = (Vec::new(), Vec::new());
    for w in odo.windows(10).step_by(5) {
        let (a, b) = (&w[0], &w[9]);
        let dt =
            (b["time_usec"].as_f64().unwrap_or(0.0) - a["time_usec"].as_f64().unwrap_or(0.0)) / 1e6;
        if dt <= 0.05 {
            continue;
        }
        let moved = [
            (b["x"].as_f64().unwrap_or(0.0) - a["x"].as_f64().unwrap_or(0.0)) / dt,
            (b["y"].as_f64().unwrap_or(0.0) - a["y"].as_f64().unwrap_or(0.0)) / dt,
            (b["z"].as_f64().unwrap_or(0.0) - a["z"].as_f64().unwrap_or(0.0)) / dt,
        ];
        let m = &w[5];
        let q = [f(m, "q", 0), f(m, "q", 1), f(m, "q", 2), f(m, "q", 3)];
        let v = rotate(q, [f(m, "v", 0), f(m, "v", 1), f(m, "v", 2)]);
        errs.push(((0..3).map(|i| (v[i] - moved[i]).powi(2)).sum::<f64>()).sqrt());
        speeds.push((moved.iter().map(|x| x * x).sum::<f64>()).sqrt());
    }
    errs.sort_by(f64::total_cmp);
    speeds.sort_by(f64::total_cmp);
    let (err, speed) = (errs[errs.len() / 2], speeds[speeds.len() / 2]);
    eprintln!("ODOMETRY body velocity vs its pose's motion: median error {err:.2} m/s at median speed {speed:.2} m/s");
    assert!(speed > 0.5, "not moving: {speed}");
    assert!(err < 0.3 * speed, "{err} m/s off at {speed} m/s");
}

/// `v` rotated by the unit quaternion `q` = [w, x, y, z].
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}
