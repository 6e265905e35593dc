//! MAVLink TIMESYNC against an autopilot stand-in written with pymavlink (issue 36): the
//! stand-in keeps its own clock (time since its boot, at real time or 5× as SITL's
//! `--speedup 5`), answers skyfuse's requests and sends its own as PX4 and ArduPilot do.
//! skyfuse must answer it, converge on its clock from the answers to its own requests,
//! say so in the status, and stamp each VISION_POSITION_ESTIMATE in the autopilot's
//! time (PX4 ignores `usec` otherwise and stamps the pose at arrival).

mod common;
use common::*;

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// The demo sending MAVLink to the stand-in (on a free UDP port) for its run, with
/// `env`; the stand-in's report, the service's status and the service.
fn fly_against_standin(
    standin_args: &[&str],
    env: &[(&str, &str)],
) -> (serde_json::Value, serde_json::Value, Service) {
    fly_against_standin_on("udpout", standin_args, env)
}

/// [`fly_against_standin`] over `scheme` (`udpout`, or `tcpout` to the stand-in
/// listening on TCP as SITL's serial ports do).
fn fly_against_standin_on(
    scheme: &str,
    standin_args: &[&str],
    env: &[(&str, &str)],
) -> (serde_json::Value, serde_json::Value, Service) {
    let port = if scheme == "tcpout" {
        free_port().to_string()
    } else {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .expect("udp port")
            .to_string()
    };
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("{scheme}:127.0.0.1:{port}"),
        ],
        env,
    );
    let args: Vec<&str> = ["--port", port.as_str()]
        .into_iter()
        .chain((scheme == "tcpout").then_some("--tcp"))
        .chain(standin_args.iter().copied())
        .collect();
    let out = json(&run_py("timesync_standin.py", &args));
    let status = svc.get_json("/api/v1/status");
    (out, status, svc)
}

/// The MAVLink output's part of a status.
fn mavlink_of(status: &serde_json::Value) -> serde_json::Value {
    status["outputs"]
        .as_array()
        .and_then(|o| o.iter().find(|x| x["name"] == "mavlink"))
        .cloned()
        .unwrap_or_default()
}

#[test]
fn timesync_converges_and_poses_carry_the_autopilots_time() {
    let (out, status, _svc) = fly_against_standin(&["--seconds", "12"], &[]);
    let mav = mavlink_of(&status);
    let ts = &mav["timesync"];
    // Both ways: its requests answered, ours answered and used.
    assert!(out["requests_from_skyfuse"].as_u64() > Some(10), "{out}");
    assert!(out["answers_from_skyfuse"].as_u64() > Some(10), "{out}");
    assert!(ts["answered"].as_u64() > Some(10), "{mav}");
    assert_eq!(ts["converged"], true, "{mav}");
    assert!(ts["rtt_ms"].as_f64() < Some(50.0), "{mav}");
    assert_eq!(ts["rate"], 1.0, "{mav}");
    // VPE usec by the autopilot's clock: arrival minus usec is the pose's age plus the
    // hop, tens of ms (our clock would put it 56 years off).
    let age = out["late_age_ms"]["median"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (-5.0..250.0).contains(&age),
        "VPE usec not in the autopilot's time: {out}"
    );
    eprintln!(
        "timesync: rtt {} ms, {} used / {} rejected; VPE age by the autopilot's clock: median {age:.1} ms (min {}, max {})",
        ts["rtt_ms"], ts["used"], ts["rejected"], out["late_age_ms"]["min"], out["late_age_ms"]["max"]
    );
}

/// TIMESYNC on a byte stream (TCP here; serial takes the same path): frames cut across
/// reads are put together again, the autopilot's requests answered on the link.
#[test]
fn timesync_converges_over_tcp() {
    let (out, status, _svc) = fly_against_standin_on("tcpout", &["--seconds", "10"], &[]);
    let mav = mavlink_of(&status);
    let ts = &mav["timesync"];
    eprintln!("timesync over tcp: {out}\n{ts}");
    assert!(out["answers_from_skyfuse"].as_u64() > Some(10), "{out}");
    assert!(ts["answered"].as_u64() > Some(10), "{mav}");
    assert_eq!(ts["converged"], true, "{mav}");
    let age = out["late_age_ms"]["median"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (-5.0..250.0).contains(&age),
        "VPE usec not in the autopilot's time: {out}"
    );
}

#[test]
fn an_autopilot_clock_at_five_times_real_time_is_found_and_followed() {
    let (out, status, _svc) = fly_against_standin(&["--seconds", "12", "--rate", "5"], &[]);
    let mav = mavlink_of(&status);
    let ts = &mav["timesync"];
    assert_eq!(ts["converged"], true, "{mav}");
    let rate = ts["rate"].as_f64().unwrap_or(f64::NAN);
    assert!((rate - 5.0).abs() < 0.1, "clock rate {rate}: {mav}");
    // The age by a clock at 5×: five times the real one.
    let age = out["late_age_ms"]["median"].as_f64().unwrap_or(f64::NAN);
    assert!((-25.0..1250.0).contains(&age), "{out}");
    eprintln!(
        "timesync at 5x: rate {rate:.3}, VPE age by the autopilot's clock median {age:.1} ms"
    );
}

/// MAVLink 2 signing (issue 36): an autopilot stand-in that requires signing with the
/// passphrase's key takes skyfuse's frames (good signatures, none rejected) and answers
/// its TIMESYNC; a sender without the key (unsigned TIMESYNC from the same address) is
/// refused and counted by skyfuse, and never answered.
#[test]
fn a_signed_link_is_accepted_and_an_unsigned_sender_refused() {
    let dir = TempDir::new("signing");
    std::fs::create_dir_all(&dir).expect("dir");
    let key = dir.join("mavlink.key");
    std::fs::write(&key, "correct horse battery staple\n").expect("key");
    let (out, status, svc) = fly_against_standin(
        &[
            "--seconds",
            "8",
            "--passphrase",
            "correct horse battery staple",
            "--intruder",
        ],
        &[
            (
                "SKYFUSE__MAVLINK__SIGNING_KEY_FILE",
                key.to_str().expect("path"),
            ),
            ("SKYFUSE__MAVLINK__SIGNING_REQUIRED", "true"),
        ],
    );
    // The autopilot verified every frame: signed, none unsigned.
    assert!(out["signing"]["good"].as_u64() > Some(50), "{out}");
    assert_eq!(out["signing"]["bad"], 0, "{out}");
    assert_eq!(out["signing"]["unsigned_rejected"], 0, "{out}");
    assert!(out["vpe"].as_u64() > Some(50), "{out}");
    assert!(out["answers_from_skyfuse"].as_u64() > Some(5), "{out}");
    // The sender without the key: refused, counted, never answered.
    assert!(out["intruder_sent"].as_u64() > Some(5), "{out}");
    assert!(out["intruder_answered"].is_null(), "{out}");
    let mav = mavlink_of(&status);
    let link = &mav["links"][0];
    assert_eq!(link["signed"], true, "{mav}");
    assert!(
        link["refused"].as_u64() >= out["intruder_sent"].as_u64().map(|n| n - 1),
        "{mav} {out}"
    );
    assert_eq!(mav["timesync"]["converged"], true, "{mav}");
    // The key is in no status and no log line.
    let text = format!("{status}{}", svc.log_text());
    assert!(!text.contains("correct horse"), "key leaked");
}

/// SETUP_SIGNING on request (issue 36): with a key configured, `POST
/// /api/v1/control/setup-signing` (token needed) gives the key to an autopilot that had
/// signing off; it then requires it, and skyfuse's frames pass. Never sent unasked, and
/// refused (409, nothing sent) without a key.
#[test]
fn setup_signing_is_sent_on_request_and_the_autopilot_then_requires_the_key() {
    let dir = TempDir::new("setup-signing");
    std::fs::create_dir_all(&dir).expect("dir");
    let key = dir.join("mavlink.key");
    let phrase = "hover over the lake at dawn";
    std::fs::write(&key, phrase).expect("key");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .expect("udp port")
        .to_string();
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("udpout:127.0.0.1:{port}"),
        ],
        &[(
            "SKYFUSE__MAVLINK__SIGNING_KEY_FILE",
            key.to_str().expect("path"),
        )],
    );
    let standin = std::process::Command::new(python())
        .arg(repo_root().join("tests/py/timesync_standin.py"))
        .args(["--port", &port, "--seconds", "9", "--accept-setup-signing"])
        .args(["--passphrase-check", phrase])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("stand-in");
    std::thread::sleep(std::time::Duration::from_secs(3));
    let path = "/api/v1/control/setup-signing";
    // Without the token: refused, nothing sent.
    let (code, _) = http_post(svc.http_port, path, "", None).expect("POST");
    assert_eq!(code, 401);
    let (code, body) = http_post(svc.http_port, path, "", Some(&svc.token)).expect("POST");
    assert_eq!(code, 200, "{body}");
    let out = standin.wait_with_output().expect("stand-in output");
    let out = json(&String::from_utf8_lossy(&out.stdout));
    let setup = &out["setup_signing"];
    eprintln!("setup-signing: {body}\nstand-in: {out}");
    assert_eq!(setup["received"], 1, "{out}");
    assert_eq!(setup["target_system"], 1, "{out}");
    assert_eq!(setup["target_component"], 1, "{out}");
    assert_eq!(setup["key_matches"], true, "{out}");
    let skew = setup["initial_timestamp_vs_now_s"]
        .as_f64()
        .unwrap_or(f64::NAN);
    assert!(skew.abs() < 2.0, "initial timestamp {skew} s off: {out}");
    // Asked for ~3 s in, not at start.
    assert!(setup["at_s"].as_f64() > Some(2.0), "{out}");
    // From then on the autopilot requires the key: skyfuse's frames carry it.
    assert_eq!(out["signing"]["enabled"], true, "{out}");
    assert!(out["signing"]["good"].as_u64() > Some(50), "{out}");
    assert_eq!(out["signing"]["bad"], 0, "{out}");
    assert_eq!(out["signing"]["unsigned_rejected"], 0, "{out}");
    let mav = mavlink_of(&svc.get_json("/api/v1/status"));
    assert_eq!(mav["setup_signing_sent"], 1, "{mav}");
    assert!(!svc.log_text().contains(phrase), "key leaked");

    // No key configured: 409 and nothing sent.
    let plain = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("udpout:127.0.0.1:{port}"),
        ],
        &[],
    );
    let (code, body) = http_post(plain.http_port, path, "", Some(&plain.token)).expect("POST");
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("signing_key_file"), "{body}");
    assert_eq!(
        mavlink_of(&plain.get_json("/api/v1/status"))["setup_signing_sent"],
        0
    );
}
