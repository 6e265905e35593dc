//! Closed loop with a real autopilot: ArduCopter SITL 4.6.3 (the real flight code with
//! simulated physics) flies on skyfuse's VISION_POSITION_ESTIMATE as EKF3's only
//! horizontal position source. BlueOS's chain: SITL SERIAL0 ⇄ the real mavlink-server
//! (`tcpclient://`, `zenoh://`, `zenohraw://`) ⇄ Zenoh ⇄ `skyfuse run`, which takes every
//! sensor from the autopilot's own MAVLink (HIGHRES_IMU, ATTITUDE_QUATERNION,
//! OPTICAL_FLOW, DISTANCE_SENSOR, GPS_RAW_INT, HEARTBEAT, EXTENDED_SYS_STATE, each
//! mavlink-server JSON with its per-field keys beside it) and sends VPE back through
//! `mavlink_raw/in`, or straight to SITL over `tcpout:` (SERIAL2) and UDP. The flight:
//! GUIDED, arm, take-off to 3 m, a 10 m square, LAND, disarm; EKF3's
//! LOCAL_POSITION_NED and skyfuse's pose are scored against SITL's truth (SIM_STATE).
//! The work is in `tests/py/sitl/sitl_flight.py` (see its README); each scenario must fly
//! and land within its limits there, and the figures are printed here.
//!
//! Skips (and passes) when the peers are absent ($SKYFUSE_PEERS, default
//! ../shared/peers): a clone of the project alone must pass.

mod common;
use common::*;
use serde_json::Value;
use std::process::Command;

/// Why the flights cannot run here, if they cannot.
fn missing() -> Option<String> {
    let peers = peers_dir();
    for f in [
        "bin/arducopter",
        "bin/mavlink-server",
        "ardupilot/copter.parm",
    ] {
        if !peers.join(f).is_file() {
            return Some(format!(
                "no {} (set SKYFUSE_PEERS)",
                peers.join(f).display()
            ));
        }
    }
    let ok = Command::new(python())
        .args(["-c", "import pymavlink, zenoh"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    (!ok).then(|| {
        format!(
            "pymavlink or eclipse-zenoh missing in {}",
            python().display()
        )
    })
}

/// Fly one scenario over one link at real-time speed as SITL instance `instance` (its
/// own ports: tests run two at a time, and two SITLs picking "a free instance" at the
/// same moment can pick the same one); returns the result JSON.
fn fly(scenario: &str, link: &str, instance: u32) -> Option<Value> {
    fly_with(scenario, link, instance, None)
}

/// [`fly`] with another skyfuse config from `tests/data/sitl/`.
fn fly_with(scenario: &str, link: &str, instance: u32, config: Option<&str>) -> Option<Value> {
    fly_at(scenario, link, instance, config, 1)
}

/// [`fly_with`] with SITL running `speedup` times real time.
fn fly_at(
    scenario: &str,
    link: &str,
    instance: u32,
    config: Option<&str>,
    speedup: u32,
) -> Option<Value> {
    if skip_requested("peers", &format!("SITL {scenario}/{link}")) {
        return None;
    }
    if let Some(why) = missing() {
        skipped(&format!("SITL {scenario}/{link}"), &why);
        return None;
    }
    let out = std::env::temp_dir().join(format!(
        "skyfuse-sitl-{}-{scenario}-{link}.json",
        std::process::id()
    ));
    let run = Command::new(python())
        .arg(repo_root().join("tests/py/sitl/sitl_flight.py"))
        .args(["--skyfuse", env!("CARGO_BIN_EXE_skyfuse")])
        .args(["--scenario", scenario, "--link", link])
        .args(["--speedup", &speedup.to_string()])
        .arg("--fast-arm")
        .args(["--instance", &instance.to_string()])
        .args(
            config
                .map(|c| {
                    vec![
                        "--config".to_string(),
                        repo_root()
                            .join("tests/data/sitl")
                            .join(c)
                            .display()
                            .to_string(),
                    ]
                })
                .unwrap_or_default(),
        )
        .arg("--out")
        .arg(&out)
        .env("SKYFUSE_PEERS", peers_dir())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python().display()));
    let text = std::fs::read_to_string(&out).unwrap_or_default();
    let r: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
    let stderr = String::from_utf8_lossy(&run.stderr);
    let fig = |who: &str, k: &str| r[who]["flight"]["raw"][k].as_f64().unwrap_or(f64::NAN);
    eprintln!(
        "SITL {scenario}/{link}: EKF3 vs truth {:.2} / {:.2} m (RMSE / max), skyfuse vs truth {:.2} / {:.2} m; \
         worst corner miss {:.2} m; skyfuse valid {:.1} %; VPE sent {}; wall {} s",
        fig("ekf3_vs_truth", "rmse_h"),
        fig("ekf3_vs_truth", "max_h"),
        fig("skyfuse_vs_truth", "rmse_h"),
        fig("skyfuse_vs_truth", "max_h"),
        r["square"]["max_truth_distance_from_corner_m"]
            .as_f64()
            .unwrap_or(f64::NAN),
        100.0 * r["skyfuse_pose_valid_fraction"].as_f64().unwrap_or(f64::NAN),
        r["vpe_sent_by_skyfuse"],
        r["wall_s"],
    );
    assert!(
        run.status.success() && r["pass"] == true,
        "SITL {scenario}/{link} failed ({}): fails {}, problems {}\n{}",
        run.status,
        r["fails"],
        r["problems"],
        stderr.lines().rev().take(30).collect::<Vec<_>>().join("\n")
    );
    let _ = std::fs::remove_file(&out);
    Some(r)
}

/// What every flight must show, beyond the script's limits.
fn flew(r: &Value) {
    for k in ["armed", "took_off", "landed", "disarmed"] {
        assert_eq!(r[k], true, "{k}: {}", r["problems"]);
    }
    assert_eq!(r["extnav_used"], true, "EKF3 never used external nav");
    // Every corner of the square was reached on skyfuse's pose.
    let legs = r["square"]["legs"].as_array().expect("legs");
    assert_eq!(legs.len(), 4);
    assert!(legs.iter().all(|l| l["reached_by_ekf"] == true), "{legs:?}");
}

#[test]
fn gps_and_flow_through_mavlink_server() {
    if let Some(r) = fly("gps_flow", "zenoh_raw", 11) {
        flew(&r);
        // EKF3 followed skyfuse's pose all the time: no VPE gap an autopilot notices.
        let gap = r["vpe_clock"]["max_gap_wall_s"]
            .as_f64()
            .unwrap_or(f64::NAN);
        assert!(gap < 0.4, "largest VPE gap {gap} s");
    }
}

#[test]
fn no_gps_from_boot_arms_on_skyfuse_and_flies() {
    // Flow + range only: the estimate must be valid on the ground (the no-aiding hold)
    // and the EKF origin comes from skyfuse (`[mavlink] ekf_origin`).
    if let Some(r) = fly("no_gps", "zenoh_raw", 12) {
        flew(&r);
        assert_eq!(r["ekf_origin_by"], "skyfuse");
        let prearm = r["statustext"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter(|s| s["text"].as_str().is_some_and(|t| t.contains("VisOdom")))
                    .count()
            })
            .unwrap_or(0);
        assert_eq!(prearm, 0, "ArduPilot complained about VisOdom");
    }
}

#[test]
fn gps_lost_in_flight() {
    if let Some(r) = fly("gps_loss", "zenoh_raw", 13) {
        flew(&r);
    }
}

#[test]
fn flow_fails_in_flight() {
    if let Some(r) = fly("flow_fail", "zenoh_raw", 14) {
        flew(&r);
    }
}

#[test]
fn vpe_over_tcp_to_serial2() {
    if let Some(r) = fly("gps_flow", "tcpout", 15) {
        flew(&r);
    }
}

#[test]
fn vpe_over_udp() {
    if let Some(r) = fly("gps_flow", "udpin", 16) {
        flew(&r);
    }
}

#[test]
fn gps_and_flow_from_mavlink_servers_raw_frames() {
    // The same flight with every input from mavlink-server's zenohraw:// endpoint
    // (mavlink_raw/out, raw frames) instead of its JSON.
    if let Some(r) = fly_with("gps_flow", "zenoh_raw", 17, Some("skyfuse-gps-raw.toml")) {
        flew(&r);
    }
}

/// Issue 36: SITL at `--speedup 5` flies the same square. skyfuse finds the autopilot's
/// clock running 5× the host's on its IMU, fuses on it and sends 30 Hz of the
/// autopilot's time (150 a host second), stamped in it by TIMESYNC.
#[test]
fn at_five_times_real_time_over_udp() {
    if let Some(r) = fly_at("gps_flow", "udpin", 18, None, 5) {
        flew(&r);
        let st = &r["status_last"];
        assert_eq!(st["clock"]["base"], "vehicle", "{}", st["clock"]);
        let rate = st["clock"]["rate"].as_f64().unwrap_or(f64::NAN);
        assert!((rate - 5.0).abs() < 0.15, "clock rate {rate}");
        let ts = &st["mavlink"]["timesync"];
        assert_eq!(ts["converged"], true, "{ts}");
        let vpe_rate = st["mavlink"]["rate_hz"].as_f64().unwrap_or(0.0);
        assert!(vpe_rate > 100.0, "VPE {vpe_rate} a host second");
    }
}

/// Issue 36: MAVLink 2 signing with a real autopilot. skyfuse gives ArduCopter SITL its
/// key on request (SETUP_SIGNING); from then on SITL answers skyfuse's signed frames
/// and a pymavlink sender signing with the key, and ignores an unsigned one (which it
/// answered before). The work is in `tests/py/sitl/signing_check.py`.
#[test]
fn sitl_requires_the_key_skyfuse_gave_it() {
    if skip_requested("peers", "SITL signing") {
        return;
    }
    if let Some(why) = missing() {
        skipped("SITL signing", &why);
        return;
    }
    let out =
        std::env::temp_dir().join(format!("skyfuse-sitl-signing-{}.json", std::process::id()));
    let run = Command::new(python())
        .arg(repo_root().join("tests/py/sitl/signing_check.py"))
        .args([
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--instance",
            "19",
        ])
        .arg("--out")
        .arg(&out)
        .env("SKYFUSE_PEERS", peers_dir())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python().display()));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap_or_default())
        .unwrap_or(Value::Null);
    let _ = std::fs::remove_file(&out);
    eprintln!(
        "SITL signing: unsigned answered before {} / after {}; signed pymavlink after {}; skyfuse's requests answered {}",
        r["unsigned_before"]["answered"], r["unsigned_after"]["answered"], r["signed_after"]["answered"],
        r["timesync_after"]["used"]
    );
    assert!(
        run.status.success() && r["pass"] == true,
        "{}: {}\n{}",
        run.status,
        r["fails"],
        String::from_utf8_lossy(&run.stderr)
    );
}

/// PX4 v1.16.0's own zenoh module (issue 37), no bridge: PX4 SITL built with it
/// (`$SKYFUSE_PEERS/px4-zenoh`, the SIH quadcopter on the ground) connects to skyfuse's
/// Zenoh listener and publishes px4_msgs (XCDR2, its buffer's tail behind each);
/// skyfuse with `transport = "px4_zenoh"` decodes every message of seven topics and
/// its heading equals EKF2's (tests/py/sitl/px4_zenoh_sitl.py).
#[test]
fn px4_zenoh_module_feeds_skyfuse_without_a_bridge() {
    let test = "px4_zenoh_module_feeds_skyfuse_without_a_bridge";
    if skip_requested("peers", test) {
        return;
    }
    let run = peers_dir().join("px4-zenoh/run-sih-quad-zenoh.sh");
    if !run.is_file() {
        skipped(
            test,
            &format!(
                "no {} (PX4 v1.16 px4_sitl_zenoh, built by you; set SKYFUSE_PEERS)",
                run.display()
            ),
        );
        return;
    }
    let out = run_py(
        "sitl/px4_zenoh_sitl.py",
        &[
            "--skyfuse",
            env!("CARGO_BIN_EXE_skyfuse"),
            "--peers",
            peers_dir().to_str().expect("peers path"),
            "--seconds",
            "25",
        ],
    );
    let v: Value = serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"));
    assert_eq!(v["ok"], true, "{v}");
    for (id, input) in v["inputs"].as_object().expect("inputs") {
        assert!(input["accepted"].as_u64() > Some(10), "{id}: {input}");
        assert_eq!(input["rejected"], 0, "{id}: {input}");
        // Healthy inputs say so, the 1 Hz land detector included.
        assert_eq!(input["health"], "ok", "{id}: {input}");
    }
    let heading = v["heading_vs_ekf2_deg"].as_f64().unwrap_or(f64::NAN);
    assert!(heading.abs() < 1.0, "{v}");
    let spread = v["skyfuse_horizontal_spread_m"]
        .as_f64()
        .unwrap_or(f64::NAN);
    assert!(spread < 1.0, "standing still: {v}");
    eprintln!(
        "PX4 zenoh module → skyfuse: {} (heading vs EKF2 {heading}°, {spread} m spread standing)",
        v["inputs"]
    );
}
