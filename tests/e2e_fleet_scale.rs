//! End to end: the fleet view at scale through real zenohd routers. A hundred stand-in
//! vehicles (`skyfuse sim --fleet`, 50 Hz poses as a real skyfuse's default) split over
//! two routers, `skyfuse monitor` on the second, which runs config/zenohd-fleet.json5
//! (the monitor side's router). Asserts every vehicle present once, a stopped one grey
//! in time, the bytes into the monitor under a budget that full-rate poses would break,
//! and a router restart the vehicles come back from without a restart of anything else.

mod common;
use common::*;
use std::collections::BTreeSet;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Poses per second of each stand-in: skyfuse's default `[output] pose_rate_hz`.
const POSE_HZ: &str = "50";
/// Bytes a second into the monitor per vehicle at most. A summary is ~1 KB once a
/// second; the 50 Hz poses it replaces are ~35 KB/s per vehicle, so a monitor that
/// received them (or a router config that let them through) is 10× over.
const INGRESS_PER_VEHICLE_B_S: f64 = 3_000.0;
/// A vehicle that stops shows grey within this (its liveliness token goes with its
/// session; the router tells the monitor at once).
const GONE_WITHIN: Duration = Duration::from_secs(5);

/// `skyfuse sim --fleet` as a child process, killed on drop.
struct Stand {
    child: Child,
}

impl Stand {
    fn start(router: &Router, n: usize, first: usize) -> Stand {
        let child = Command::new(env!("CARGO_BIN_EXE_skyfuse"))
            .args([
                "sim",
                "--fleet",
                &n.to_string(),
                "--fleet-first",
                &first.to_string(),
            ])
            .args(["--pose-hz", POSE_HZ, "--mode", "client", "--no-multicast"])
            .args(["--connect", &router.endpoint()])
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("skyfuse sim --fleet");
        Stand { child }
    }

    /// Killed, as a crash or a power cut: no clean goodbye on Zenoh.
    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Stand {
    fn drop(&mut self) {
        self.kill();
    }
}

fn names(f: &serde_json::Value, presence: &str) -> Vec<String> {
    f["vehicles"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter(|v| presence.is_empty() || v["presence"] == presence)
                .filter_map(|v| v["name"].as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

fn presence_of(f: &serde_json::Value, name: &str) -> Option<String> {
    f["vehicles"]
        .as_array()?
        .iter()
        .find(|v| v["name"] == name)
        .and_then(|v| v["presence"].as_str().map(String::from))
}

#[test]
fn a_hundred_vehicles_through_two_routers_all_present_one_stops_a_router_restarts() {
    if skip_requested("routers", "the fleet at scale through zenohd routers") {
        return;
    }
    let config = repo_root().join("config/zenohd-fleet.json5");
    let mut router_a = Router::start(&[]);
    let router_b = Router::start(&[
        "-c",
        config.to_str().expect("path"),
        "-e",
        &router_a.endpoint(),
    ]);
    // 50 on router A (the one that restarts later), 49 on B, one alone on A to stop.
    let _on_a = Stand::start(&router_a, 50, 0);
    let _on_b = Stand::start(&router_b, 49, 50);
    let mut lone = Stand::start(&router_a, 1, 99);
    let monitor = Service::start(
        &[
            "monitor",
            "--mode",
            "client",
            "--connect",
            &router_b.endpoint(),
        ],
        &[],
    );
    let expected: BTreeSet<String> = (0..100).map(|i| format!("v{i:04}")).collect();

    // 1. All present, each once, live, placed on the map (a token alone is not enough:
    // its summary must have come too).
    let placed_of = |f: &serde_json::Value| {
        f["vehicles"]
            .as_array()
            .map_or(0, |a| a.iter().filter(|v| v["frame"] == "geo").count())
    };
    let f = monitor.wait_json("/api/v1/fleet?tracks=false", Duration::from_secs(40), |f| {
        names(f, "live").len() == 100 && placed_of(f) == 100
    });
    let all = names(&f, "");
    let unique: BTreeSet<String> = all.iter().cloned().collect();
    assert_eq!(all.len(), unique.len(), "a vehicle listed twice: {all:?}");
    assert_eq!(unique, expected, "missing or extra vehicles");
    assert_eq!(names(&f, "live").len(), 100, "not all live: {f}");
    assert!(
        f["vehicles"][0].get("track").is_none(),
        "asked without tracks: {}",
        f["vehicles"][0]
    );
    assert_eq!(
        placed_of(&f),
        100,
        "every vehicle placed by its GNSS origin"
    );

    // 2. What reaches the monitor: bytes on its TCP link to router B over 10 s.
    let pid = monitor.child.id();
    let (b0, c0, t0) = (
        tcp_bytes_received(pid, router_b.port),
        cpu_seconds(pid),
        Instant::now(),
    );
    assert!(
        b0 > 0,
        "no bytes seen on the monitor's link to router B (ss)"
    );
    std::thread::sleep(Duration::from_secs(10));
    let secs = t0.elapsed().as_secs_f64();
    let ingress = (tcp_bytes_received(pid, router_b.port) - b0) as f64 / secs;
    let cpu = (cpu_seconds(pid) - c0) / secs;
    let limit = 100.0 * INGRESS_PER_VEHICLE_B_S;
    eprintln!(
        "monitor at 100 vehicles: {:.0} B/s in ({:.0} per vehicle), {:.1} % of a core, {:.1} MiB",
        ingress,
        ingress / 100.0,
        cpu * 100.0,
        rss_mib(pid)
    );
    assert!(
        ingress < limit,
        "{ingress:.0} B/s into the monitor, over {limit:.0}"
    );
    // Not silent either: the summaries do arrive (≥ 300 B per vehicle a second).
    assert!(
        ingress > 100.0 * 300.0,
        "{ingress:.0} B/s: summaries missing?"
    );

    // 3. One stops hard: grey within GONE_WITHIN, the 99 others stay live.
    let stopped = Instant::now();
    lone.kill();
    let f = monitor.wait_json("/api/v1/fleet?tracks=false", GONE_WITHIN * 2, |f| {
        presence_of(f, "v0099").as_deref() == Some("gone")
    });
    let to_gone = stopped.elapsed();
    assert_eq!(presence_of(&f, "v0099").as_deref(), Some("gone"), "{f}");
    assert!(to_gone < GONE_WITHIN, "gone after {to_gone:?}");
    assert_eq!(names(&f, "live").len(), 99, "{f}");
    eprintln!(
        "v0099 gone {:.2} s after it was killed",
        to_gone.as_secs_f64()
    );

    // 3a. Prometheus: the fleet in aggregate, no series per vehicle (a hundred vehicles
    // give the same handful of lines as one).
    let (code, metrics) = http_get(monitor.http_port, "/metrics").expect("GET /metrics");
    assert_eq!(code, 200, "{metrics}");
    for line in [
        "skyfuse_fleet_vehicles{presence=\"live\"} 99",
        "skyfuse_fleet_vehicles{presence=\"gone\"} 1",
        "skyfuse_fleet_refused_total 0",
    ] {
        assert!(metrics.contains(line), "{line} in:\n{metrics}");
    }
    let samples: Vec<&str> = metrics
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .collect();
    assert!(samples.len() < 20, "{} series:\n{metrics}", samples.len());
    assert!(
        !metrics.contains("v00"),
        "a vehicle named in /metrics:\n{metrics}"
    );

    // 3b. The page at this size (Chromium): only the rows in view in the DOM, the last
    // ones reachable by scrolling, search finds one, sort by state puts the gone one
    // first, the map clusters.
    if !skip_requested("browser", "the fleet page at 100 vehicles") {
        let url = format!("http://127.0.0.1:{}/fleet", monitor.http_port);
        let out = run_py(
            "fleet_page_scale.py",
            &["--url", &url, "--vehicles", "100", "--search", "v0042"],
        );
        let p: serde_json::Value = serde_json::from_str(out.trim()).expect("page JSON");
        assert_eq!(p["ok"], true, "{p}");
        assert_eq!(p["errors"], serde_json::json!([]), "{p}");
        let in_dom = p["rows_in_dom"].as_u64().unwrap_or(0);
        assert!(
            (5..50).contains(&in_dom),
            "only the rows in view: {in_dom} <tr> for 100 vehicles: {p}"
        );
        let scrolled: Vec<&str> = p["scroll_rows"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_str()).collect())
            .unwrap_or_default();
        assert!(
            scrolled.contains(&"v0099"),
            "the list's last row after scrolling to the end: {p}"
        );
        assert_eq!(p["search_rows"], serde_json::json!(["v0042"]), "{p}");
        assert_eq!(p["state_first"]["name"], "v0099", "gone first: {p}");
        assert_eq!(p["state_first"]["presence"], "gone", "{p}");
        assert!(p["clusters"].as_u64().unwrap_or(0) >= 1, "{p}");
        // A click on the largest cluster lists exactly its vehicles (at least two).
        let picked = p["cluster_ids"].as_array().map_or(0, Vec::len);
        assert!(picked >= 2, "{p}");
        // The one aimed at, give or take a vehicle that moved in or out meanwhile.
        let aimed = p["aimed_ids"].as_array().cloned().unwrap_or_default();
        let shared = p["cluster_ids"]
            .as_array()
            .map_or(0, |a| a.iter().filter(|id| aimed.contains(id)).count());
        assert!(shared >= 2 && shared + 2 >= aimed.len(), "{p}");
        // Listed: that many of 100, and every row in view one of them (a large cluster
        // may have more rows than the view).
        assert_eq!(p["cluster_shown"], format!("{picked} of 100 shown"), "{p}");
        let ids: Vec<&serde_json::Value> = p["cluster_ids"]
            .as_array()
            .map_or(vec![], |a| a.iter().collect());
        let rows = p["cluster_rows"]
            .as_array()
            .map_or(vec![], |a| a.iter().collect::<Vec<_>>());
        assert!(
            !rows.is_empty() && rows.iter().all(|r| ids.contains(r)),
            "{p}"
        );
        assert!(
            p["cluster_note"]
                .as_str()
                .is_some_and(|t| t.contains(&format!("{picked} picked"))),
            "{p}"
        );
        assert_eq!(
            p["after_clear_shown"], "",
            "every vehicle listed again: {p}"
        );
        eprintln!(
            "fleet page at 100 vehicles: {in_dom} rows in the DOM, {} clusters, {} fps",
            p["clusters"], p["fps"]
        );
    }

    // 4. Router A restarts: its 50 go grey, then come back live by themselves (the
    // stand-ins reconnect as clients, router B re-links); B's 49 never leave.
    router_a.stop();
    let restarted = Instant::now();
    let f = monitor.wait_json("/api/v1/fleet?tracks=false", Duration::from_secs(10), |f| {
        presence_of(f, "v0000").as_deref() == Some("gone")
    });
    assert_eq!(
        presence_of(&f, "v0000").as_deref(),
        Some("gone"),
        "router A's vehicles not seen leaving: {f}"
    );
    assert_eq!(
        presence_of(&f, "v0050").as_deref(),
        Some("live"),
        "router B's stay: {f}"
    );
    router_a.restart();
    let f = monitor.wait_json("/api/v1/fleet?tracks=false", Duration::from_secs(60), |f| {
        names(f, "live").len() == 99
            && (0..50).all(|i| presence_of(f, &format!("v{i:04}")).as_deref() == Some("live"))
    });
    let back = restarted.elapsed();
    let live: BTreeSet<String> = names(&f, "live").into_iter().collect();
    let want: BTreeSet<String> = (0..99).map(|i| format!("v{i:04}")).collect();
    assert_eq!(live, want, "after router A's restart: {f}");
    assert_eq!(
        names(&f, "").len(),
        100,
        "nobody listed twice after the restart"
    );
    // The link came back; nothing restarted (the same start time in their summaries).
    let restarts: u64 = f["vehicles"]
        .as_array()
        .map_or(0, |a| a.iter().filter_map(|v| v["restarts"].as_u64()).sum());
    assert_eq!(restarts, 0, "{f}");
    eprintln!(
        "router A restarted: its vehicles live again after {:.1} s",
        back.as_secs_f64()
    );
}
