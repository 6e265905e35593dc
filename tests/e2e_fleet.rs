//! End to end: the fleet view. Real skyfuse vehicles (`skyfuse demo`, each in its own
//! Zenoh namespace so their sensors stay apart) joined to `skyfuse monitor`, the page in
//! Debian's headless Chromium (tests/py/fleet_check.py); light stand-in vehicles and
//! malformed payloads from Python eclipse-zenoh (tests/py/fleet_load.py).

mod common;
use common::*;
use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn vehicle(monitor: &Service, n: u32) -> Service {
    let (ns, name) = (format!("v{n}"), format!("drone{n}"));
    let connect = monitor.zenoh_endpoint();
    // Side by side, ~40 m apart (PX4 SITL's home moved north).
    let home = format!("{:.6},8.545594", 47.397742 + 0.00036 * f64::from(n));
    Service::start(
        &[
            "demo",
            "--no-browser",
            "--namespace",
            &ns,
            "--vehicle",
            &name,
            "--connect",
            &connect,
            "--seed",
            &n.to_string(),
            "--home",
            &home,
        ],
        &[],
    )
}

fn row<'a>(fleet: &'a serde_json::Value, name: &str) -> Option<&'a serde_json::Value> {
    fleet["vehicles"]
        .as_array()?
        .iter()
        .find(|v| v["name"] == name)
}

/// The page driver: one JSON line per step, the next step after a line on its stdin.
struct Page {
    child: std::process::Child,
    out: BufReader<std::process::ChildStdout>,
}

impl Page {
    fn open(url: &str, steps: &[&str], screenshot: &str, click: &str) -> Page {
        let mut cmd = Command::new(python());
        cmd.arg(repo_root().join("tests/py/fleet_check.py")).args([
            "--url",
            url,
            "--screenshot",
            screenshot,
            "--timeout",
            "60",
            "--click",
            click,
        ]);
        for s in steps {
            cmd.args(["--step", s]);
        }
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("fleet_check.py");
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        Page { child, out }
    }

    fn step(&mut self) -> serde_json::Value {
        let mut line = String::new();
        self.out.read_line(&mut line).expect("read fleet_check.py");
        let v: serde_json::Value =
            serde_json::from_str(line.trim()).unwrap_or_else(|e| panic!("{e}: {line:?}"));
        assert_eq!(v["ok"], true, "{v}");
        assert_eq!(v["errors"], serde_json::json!([]), "page errors: {v}");
        v
    }

    /// Waits for the driver to write the screenshot and exit.
    fn finish(&mut self) {
        let status = self.child.wait().expect("fleet_check.py");
        assert!(status.success(), "fleet_check.py: {status}");
    }

    fn next(&mut self) {
        let stdin = self.child.stdin.as_mut().expect("stdin");
        stdin.write_all(b"go\n").expect("write");
        stdin.flush().expect("flush");
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn page_row<'a>(step: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    step["rows"]
        .as_array()
        .and_then(|r| r.iter().find(|r| r["name"] == name))
        .unwrap_or_else(|| panic!("no row {name}: {step}"))
}

#[test]
fn three_vehicles_on_one_monitor_page_one_goes_grey_a_fourth_joins_and_a_restart_keeps_its_place() {
    if skip_requested("browser", "the fleet page in Chromium") {
        return;
    }
    let monitor = Service::start(&["monitor"], &[]);
    let mut d1 = vehicle(&monitor, 1);
    let _d2 = vehicle(&monitor, 2);
    let mut d3 = vehicle(&monitor, 3);
    // README shows docs/fleet.png: written only when asked (SKYFUSE_SCREENSHOT=1).
    let scratch = TempDir::new("fleet");
    let shot = if std::env::var_os("SKYFUSE_SCREENSHOT").is_some() {
        repo_root().join("docs/fleet.png")
    } else {
        scratch.join("fleet.png")
    };
    if let Some(dir) = shot.parent() {
        std::fs::create_dir_all(dir).expect("screenshot dir");
    }
    let url = format!("http://127.0.0.1:{}/fleet", monitor.http_port);
    let mut page = Page::open(
        &url,
        &[
            "live:drone1,drone2,drone3",
            "gone:drone3",
            "live:drone4",
            "live:drone3",
        ],
        shot.to_str().expect("path"),
        "drone1",
    );

    // 1. Three vehicles, each on the page with its own colour and drawn on the map.
    let s1 = page.step();
    let rows = s1["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 3, "{s1}");
    let colours: std::collections::BTreeSet<&str> =
        rows.iter().filter_map(|r| r["colour"].as_str()).collect();
    assert_eq!(colours.len(), 3, "one colour each: {s1}");
    // Drawn: a marker's worth of pixels in the vehicle's own colour (30 seen for one of
    // three vehicles whose tracks had just begun and overlapped: the count measures the
    // overlap as much as the drawing; not drawn is 0).
    for name in ["drone1", "drone2", "drone3"] {
        assert!(
            s1["pixels"][name].as_u64().unwrap_or(0) > 12,
            "{name} not drawn on the map: {s1}"
        );
    }
    assert!(s1["stats"]["frames"].as_u64().unwrap_or(0) >= 1, "{s1}");
    // The monitor's API agrees, and each vehicle says where its dashboard is.
    let f = monitor.wait_json("/api/v1/fleet", Duration::from_secs(30), |f| {
        ["drone1", "drone2", "drone3"]
            .iter()
            .all(|n| row(f, n).is_some_and(|r| r["valid"] == true && r["worst_health"] == "ok"))
    });
    for (n, svc) in [("drone1", &d1), ("drone3", &d3)] {
        let r = row(&f, n).expect("row");
        assert_eq!(r["valid"], true, "{f}");
        assert_eq!(r["vpe"], "off", "no MAVLink endpoint: {f}");
        assert_eq!(
            r["dashboard"],
            format!("http://127.0.0.1:{}/", svc.http_port),
            "{f}"
        );
        assert_eq!(r["frame"], "geo", "placed by its GNSS origin: {f}");
        assert!(r["track"].as_array().is_some_and(|t| !t.is_empty()), "{f}");
    }
    let slot3 = row(&f, "drone3").expect("drone3")["slot"].clone();
    let colour3 = page_row(&s1, "drone3")["colour"].clone();

    // 2. drone3 stops: grey on the page, the others live.
    let stopped = Instant::now();
    let (status, _) = d3.terminate();
    assert!(status.success());
    page.next();
    let s2 = page.step();
    let to_grey = stopped.elapsed();
    assert!(to_grey < Duration::from_secs(10), "grey after {to_grey:?}");
    assert_eq!(page_row(&s2, "drone1")["presence"], "live", "{s2}");
    assert_eq!(page_row(&s2, "drone2")["presence"], "live", "{s2}");

    // 3. A fourth joins: a new row and colour; drone3 stays listed, grey.
    let _d4 = vehicle(&monitor, 4);
    page.next();
    let s3 = page.step();
    assert_eq!(s3["rows"].as_array().map(Vec::len), Some(4), "{s3}");
    assert_eq!(page_row(&s3, "drone3")["presence"], "gone", "{s3}");
    assert!(s3["pixels"]["drone4"].as_u64().unwrap_or(0) > 12, "{s3}");
    assert_ne!(page_row(&s3, "drone4")["colour"], colour3, "{s3}");

    // 4. drone3 comes back: its old place and colour, one restart counted.
    let _d3 = vehicle(&monitor, 3);
    page.next();
    let s4 = page.step();
    assert_eq!(page_row(&s4, "drone3")["colour"], colour3, "{s4}");
    // Its health (once a second) carries the new start time: one restart.
    let f = monitor.wait_json("/api/v1/fleet", Duration::from_secs(10), |f| {
        row(f, "drone3").is_some_and(|r| r["restarts"] == 1)
    });
    let r3 = row(&f, "drone3").expect("drone3");
    assert_eq!(r3["slot"], slot3, "{f}");
    assert_eq!(r3["restarts"], 1, "{f}");
    // A click on drone1's row opens drone1's own dashboard.
    let click = page.step();
    assert_eq!(
        click["opened"],
        format!("http://127.0.0.1:{}/", d1.http_port),
        "{click}"
    );
    assert_eq!(click["opened_title"], "skyfuse", "{click}");
    page.finish();
    assert!(shot.exists());
    eprintln!(
        "fleet page: grey {:.2} s after drone3 stopped; {} frames, {:.0} fps",
        to_grey.as_secs_f64(),
        s4["stats"]["frames"],
        s4["stats"]["fps"].as_f64().unwrap_or(0.0)
    );
    let (status, _) = d1.terminate();
    assert!(status.success());
}

#[test]
fn a_vehicles_own_page_shows_the_fleet_and_bad_payloads_are_counted_not_shown() {
    let monitor = Service::start(&["monitor"], &[]);
    let d1 = vehicle(&monitor, 1);
    // A vehicle's own /api/v1/fleet (its namespace's vehicles: itself here). It starts
    // watching at the first request.
    let f = d1.wait_json("/api/v1/fleet", Duration::from_secs(30), |f| {
        row(f, "drone1").is_some_and(|r| r["version"].is_string() && r["valid"] == true)
    });
    let r = row(&f, "drone1").unwrap_or_else(|| panic!("{f}"));
    assert_eq!(r["id"], "skyfuse/drone1", "inside its namespace: {f}");
    assert_eq!(r["presence"], "live");
    assert_eq!(r["version"], env!("CARGO_PKG_VERSION"));

    // Stand-ins and garbage on the fleet keys reach the monitor.
    let out = run_py(
        "fleet_load.py",
        &[
            "--connect",
            &monitor.zenoh_endpoint(),
            "--vehicles",
            "3",
            "--seconds",
            "3",
            "--bad",
            "18",
        ],
    );
    let load: serde_json::Value = serde_json::from_str(out.trim()).expect("json");
    assert_eq!(load["messages"]["bad"], 18, "{load}");
    let f = monitor.wait_json("/api/v1/fleet", Duration::from_secs(10), |f| {
        f["counters"]["rejected"].as_u64().unwrap_or(0) >= 12
    });
    // Health and events are read on arrival; poses at the next refresh, the newest only.
    let rejected = f["counters"]["rejected"].as_u64().unwrap_or(0);
    assert!((12..=18).contains(&rejected), "{f}");
    let bad = row(&f, "bad");
    assert!(
        bad.is_none_or(|b| b["xy"].is_null() && b["valid"].is_null()),
        "nothing of the garbage is shown: {f}"
    );
    for n in ["v00", "v01", "v02"] {
        let r = row(&f, n).unwrap_or_else(|| panic!("{n}: {f}"));
        assert_eq!(r["frame"], "geo", "{f}");
    }
    assert_eq!(
        row(&f, "drone1").map(|r| r["presence"].clone()),
        Some("live".into()),
        "{f}"
    );
    // The stand-ins dropped their tokens when they ended: grey.
    let f = monitor.wait_json("/api/v1/fleet", Duration::from_secs(10), |f| {
        row(f, "v00").is_some_and(|r| r["presence"] == "gone")
    });
    assert_eq!(
        row(&f, "v00").map(|r| r["presence"].clone()),
        Some("gone".into()),
        "{f}"
    );
}
