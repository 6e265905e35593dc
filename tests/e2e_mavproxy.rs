//! End to end with a real ground station and MAVLink router: MAVProxy (PyPI) between
//! `skyfuse demo`'s VISION_POSITION_ESTIMATE and a pymavlink autopilot stand-in. skyfuse
//! sends to three MAVProxy processes at once: as their master over UDP (`udpout:`) and
//! over TCP (`tcpout:`), routed to a stand-in and to a pymavlink reader on MAVProxy's own
//! `--out`; and, as a GCS layout, on an `--out` of a MAVProxy whose master is the
//! stand-in. The two router instances are killed and started again mid-run. The work is in
//! `tests/py/mavproxy_check.py`, which prints the figures as JSON.
//!
//! Skips (and passes) only when MAVProxy is not in the test venv (`tests/run` installs it
//! from tests/requirements.txt), or when SKYFUSE_SKIP names `peers`.

mod common;
use common::*;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// The `mavproxy.py` beside the test Python, if MAVProxy is installed there.
fn mavproxy() -> Result<PathBuf, String> {
    let py = python();
    let import = Command::new(&py)
        .args(["-c", "import MAVProxy, pymavlink"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    let script = py.parent().map(|d| d.join("mavproxy.py"));
    match script {
        Some(s) if import && s.is_file() => Ok(s),
        _ => Err(format!(
            "MAVProxy is not installed for {} (tests/run installs it from tests/requirements.txt)",
            py.display()
        )),
    }
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// One MAVLink link of skyfuse's status, in short.
fn link_summary(l: &serde_json::Value) -> serde_json::Value {
    serde_json::json!({
        "endpoint": l["endpoint"],
        "sent": l["sent"],
        "errors": l["errors"],
        "connected": l["connected"],
    })
}

#[test]
fn vpe_through_mavproxy_over_udp_and_tcp_survives_its_restart() {
    let name = "vpe_through_mavproxy_over_udp_and_tcp_survives_its_restart";
    if skip_requested("peers", name) {
        return;
    }
    let mavproxy = match mavproxy() {
        Ok(p) => p,
        Err(why) => {
            skipped(name, &why);
            return;
        }
    };
    let (router_udp, router_tcp, gcs_udp) = (free_port(), free_port(), free_port());
    let svc = Service::start(
        &[
            "demo",
            "--no-browser",
            "--mavlink",
            &format!("udpout:127.0.0.1:{router_udp}"),
            "--mavlink",
            &format!("tcpout:127.0.0.1:{router_tcp}"),
            "--mavlink",
            &format!("udpout:127.0.0.1:{gcs_udp}"),
        ],
        &[],
    );
    let status = svc.wait_status(Duration::from_secs(30), |s| {
        s["outputs"][0]["sending"] == true
    });
    let mav = &status["outputs"][0];
    assert_eq!(mav["kind"], "mavlink", "{status}");
    assert_eq!(mav["sending"], true, "VPE not flowing: {mav}");
    let rate = f(&mav["configured_rate_hz"]);
    assert!(rate > 0.0, "no configured rate in {mav}");

    let text = run_py(
        "mavproxy_check.py",
        &[
            "--router-udp",
            &router_udp.to_string(),
            "--router-tcp",
            &router_tcp.to_string(),
            "--gcs-udp",
            &gcs_udp.to_string(),
            "--rate-hz",
            &rate.to_string(),
            "--mavproxy",
            mavproxy.to_str().expect("path"),
        ],
    );
    let v: serde_json::Value =
        serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"));
    // The script exits non-zero on any failed check (run_py panics with its stderr);
    // these hold whenever it passed, and name what was measured.
    assert_eq!(v["ok"], true, "{v}");
    for link in ["router_udp", "router_tcp", "gcs_udp"] {
        let l = &v["links"][link];
        let r = f(&l["rate_hz_steady"]);
        assert!(
            (0.8 * rate..=1.2 * rate).contains(&r),
            "{link}: {r} Hz at the stand-in: {l}"
        );
        assert_eq!(l["ids"], serde_json::json!([[1, 197]]), "{link}: {l}");
        assert_eq!(l["non_finite"], 0, "{link}: {l}");
        assert_eq!(l["usec_not_increasing"], 0, "{link}: {l}");
        assert_eq!(l["bad_data"], 0, "{link}: {l}");
    }
    for link in ["router_udp", "router_tcp"] {
        let rd = &v["readers"][link];
        let want = rd["steady_frames_at_stand_in"].as_u64().unwrap_or(0);
        assert!(want > 0, "{link}: {rd}");
        assert!(
            rd["same_frame"].as_u64().unwrap_or(0) as f64 >= 0.98 * want as f64,
            "{link}: MAVProxy's --out reader: {rd}"
        );
        let back = &v["restart"][link];
        assert!(
            back["gap_s"].as_f64().is_some(),
            "{link}: VPE did not come back after MAVProxy's restart: {back}"
        );
    }
    // skyfuse kept sending through it all, to all three endpoints.
    let after = svc.get_json("/api/v1/status");
    let links = after["outputs"][0]["links"].as_array().expect("links");
    assert_eq!(links.len(), 3, "{after}");
    for l in links {
        assert!(l["sent"].as_u64().unwrap_or(0) > 0, "{l}");
    }
    eprintln!(
        "MAVProxy {}: first VPE at the stand-ins after {} s; steady rate at the stand-ins {} / {} / {} Hz \
         (router udp / router tcp / gcs udp, configured {rate}); MAVProxy's --out readers matched {} / {} of {} / {} frames byte for byte; \
         killed {} s: VPE back {} s (udp) and {} s (tcp) after the restart, gaps {} s and {} s; \
         rate after {} / {} Hz; GCS layout: {} MAVProxy HEARTBEATs and its requests {} at the stand-in; skyfuse's links: {}; wall {} s",
        v["mavproxy_version"],
        v["first_vpe_s"],
        v["links"]["router_udp"]["rate_hz_steady"],
        v["links"]["router_tcp"]["rate_hz_steady"],
        v["links"]["gcs_udp"]["rate_hz_steady"],
        v["readers"]["router_udp"]["same_frame"],
        v["readers"]["router_tcp"]["same_frame"],
        v["readers"]["router_udp"]["steady_frames_at_stand_in"],
        v["readers"]["router_tcp"]["steady_frames_at_stand_in"],
        v["restart"]["down_s"],
        v["restart"]["router_udp"]["vpe_back_after_restart_s"],
        v["restart"]["router_tcp"]["vpe_back_after_restart_s"],
        v["restart"]["router_udp"]["gap_s"],
        v["restart"]["router_tcp"]["gap_s"],
        v["links"]["router_udp"]["rate_hz_after_restart"],
        v["links"]["router_tcp"]["rate_hz_after_restart"],
        v["links"]["gcs_udp"]["mavproxy_gcs_heartbeats"],
        v["links"]["gcs_udp"]["other"],
        serde_json::Value::Array(links.iter().map(link_summary).collect()),
        v["wall_s"],
    );
}
