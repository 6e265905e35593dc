//! End to end in containers, with podman as the engine: the image built from
//! `docker/Dockerfile` and the deployment in `docker/compose.yaml` (a zenohd router,
//! skyfuse as its client, `skyfuse sim` as the vehicle), exactly the files users get.
//! From the host: the dashboard port shows the simulated vehicle's sensors arriving
//! through the router and the estimate valid; VISION_POSITION_ESTIMATE reaches a UDP
//! port on the host (decoded by pymavlink); the pose crosses the router to a Zenoh
//! client on the host; the router restarts and data resumes without restarting
//! skyfuse; `podman stop` ends skyfuse with exit code 0 within 2 s.
//!
//! What this machine lacks is made by `tests/containers/prepare` (base images from
//! debootstrap, zenohd from crates.io); the build mounts the host's CA bundle, which
//! the machine's TLS interception needs, as a flag of the test, not of the Dockerfile.

mod common;
use common::*;
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const IMAGE: &str = "localhost/skyfuse:e2e";
const BUILD_STAGE_IMAGE: &str = "localhost/skyfuse-build-stage:e2e";
const BASE_IMAGE: &str = "docker.io/library/debian:bookworm-slim";
const CA_BUNDLE: &str = "/etc/ssl/certs/ca-certificates.crt";

/// podman's settings and image store, as `tests/containers/env` sets them.
struct Podman {
    env: Vec<(String, String)>,
    cache: PathBuf,
}

impl Podman {
    fn new() -> Podman {
        let out = Command::new("bash")
            .arg("-c")
            .arg(". tests/containers/env && printf '%s\\n%s\\n%s\\n' \"$CONTAINERS_CONF\" \"$CONTAINERS_STORAGE_CONF\" \"$SKYFUSE_CONTAINER_CACHE\"")
            .current_dir(repo_root())
            .output()
            .expect("bash");
        assert!(out.status.success(), "tests/containers/env failed");
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        let v: Vec<&str> = text.lines().collect();
        assert_eq!(v.len(), 3, "tests/containers/env printed {text:?}");
        Podman {
            env: vec![
                ("CONTAINERS_CONF".into(), v[0].into()),
                ("CONTAINERS_STORAGE_CONF".into(), v[1].into()),
            ],
            cache: PathBuf::from(v[2]),
        }
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.current_dir(repo_root()).envs(self.env.iter().cloned());
        c
    }

    /// Run podman; panics with its output unless it succeeds.
    fn run(&self, args: &[&str]) -> String {
        let out = self.output(args);
        assert!(
            out.status.success(),
            "podman {args:?}: {}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    }

    fn output(&self, args: &[&str]) -> Output {
        self.command("podman")
            .args(args)
            .stdin(Stdio::null())
            .output()
            .expect("podman")
    }

    fn inspect(&self, what: &str, format: &str) -> String {
        self.run(&["inspect", "--format", format, what])
    }
}

/// A compose project, taken down when dropped (also when a check fails).
struct Stack<'a> {
    podman: &'a Podman,
    project: String,
    /// The compose file, from the repository root.
    file: &'static str,
    services: &'static [&'static str],
    env: Vec<(String, String)>,
}

impl Stack<'_> {
    fn compose(&self, args: &[&str]) -> Output {
        self.podman
            .command("podman-compose")
            .args(["-p", &self.project, "-f", self.file])
            .args(args)
            .envs(self.env.iter().cloned())
            .stdin(Stdio::null())
            .output()
            .expect("podman-compose")
    }

    /// `up -d`; panics with podman-compose's output unless it succeeds.
    fn up(&self) {
        let up = self.compose(&["up", "-d"]);
        assert!(
            up.status.success(),
            "podman-compose up: {}\n{}",
            String::from_utf8_lossy(&up.stdout),
            String::from_utf8_lossy(&up.stderr)
        );
    }

    /// podman-compose names containers <project>_<service>_1.
    fn container(&self, service: &str) -> String {
        format!("{}_{service}_1", self.project)
    }

    fn logs(&self, service: &str) -> String {
        let out = self.podman.output(&["logs", &self.container(service)]);
        let mut text = String::from_utf8_lossy(&out.stdout).into_owned();
        text.push_str(&String::from_utf8_lossy(&out.stderr));
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(40)..].join("\n")
    }

    fn all_logs(&self) -> String {
        self.services
            .iter()
            .map(|s| format!("--- {s} ---\n{}", self.logs(s)))
            .collect::<Vec<_>>()
            .join("\n")
    }
}

impl Drop for Stack<'_> {
    fn drop(&mut self) {
        let _ = self.compose(&["down", "-t", "2"]);
        let _ = self
            .podman
            .output(&["network", "rm", "-f", &format!("{}_default", self.project)]);
    }
}

fn sh(podman: &Podman, script: &str) {
    let status = podman
        .command("bash")
        .arg(script)
        .status()
        .unwrap_or_else(|e| panic!("{script}: {e}"));
    assert!(status.success(), "{script} failed: {status}");
}

fn get_json(port: u16, path: &str) -> Option<Value> {
    match http_get(port, path) {
        Ok((200, body)) => serde_json::from_str(&body).ok(),
        _ => None,
    }
}

fn get_status(port: u16) -> Option<Value> {
    get_json(port, "/api/v1/status")
}

/// Poll the status through the published port until `done` holds.
fn wait_for(
    port: u16,
    timeout: Duration,
    what: &str,
    stack: &Stack,
    done: impl Fn(&Value) -> bool,
) -> Value {
    wait_json(port, "/api/v1/status", timeout, what, stack, done)
}

/// Poll a JSON endpoint through the published port until `done` holds; panics with the
/// last answer and the stack's logs when it does not.
fn wait_json(
    port: u16,
    path: &str,
    timeout: Duration,
    what: &str,
    stack: &Stack,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let start = Instant::now();
    let mut last = None;
    while start.elapsed() < timeout {
        if let Some(s) = get_json(port, path) {
            if done(&s) {
                return s;
            }
            last = Some(s);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!(
        "{what}: not within {timeout:?}; last {path}: {}\n{}",
        last.map(|s| s.to_string()).unwrap_or_default(),
        stack.all_logs()
    );
}

fn sensors(s: &Value) -> &Vec<Value> {
    s["sensors"].as_array().expect("sensors in status")
}

fn received_total(s: &Value) -> u64 {
    sensors(s)
        .iter()
        .map(|x| x["received"].as_u64().unwrap_or(0))
        .sum()
}

/// Every enabled sensor receiving and healthy, and the estimate valid.
fn all_healthy(s: &Value) -> bool {
    s["estimator"]["valid"] == true
        && sensors(s)
            .iter()
            .filter(|x| x["enabled"] == true)
            .all(|x| x["health"] == "ok" && x["received"].as_u64().unwrap_or(0) > 0)
}

/// One container test at a time: each stack starts several skyfuse processes, and the
/// image is built once (the first test builds it, the next finds it done).
static CONTAINER_TESTS: std::sync::Mutex<bool> = std::sync::Mutex::new(false);

fn lock(m: &'static std::sync::Mutex<bool>) -> std::sync::MutexGuard<'static, bool> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn podman_installed() {
    for tool in ["podman", "podman-compose"] {
        assert!(
            Command::new(tool).arg("--version").output().is_ok(),
            "{tool} is not installed: ./tests/run installs it (Debian packages podman runc podman-compose debootstrap)"
        );
    }
}

/// The base images (tests/containers/prepare) and the image from docker/Dockerfile,
/// checked (size, user, health check). Called with CONTAINER_TESTS held.
fn build_image(podman: &Podman) {
    static BUILT: std::sync::Mutex<bool> = std::sync::Mutex::new(false);
    let mut built = lock(&BUILT);
    if *built {
        return;
    }
    sh(podman, "tests/containers/prepare");

    // The image, from the Dockerfile users get. The registry cache and the CA bundle are
    // mounts of this test, not part of the Dockerfile.
    let registry = podman.cache.join("cargo-registry");
    std::fs::create_dir_all(&registry).expect("cargo registry cache dir");
    let started = Instant::now();
    // The build stage gets a tag of its own, so that pruning the images the previous run
    // left behind keeps its cached layers (Zenoh compiled) for the next run.
    for (target, tag) in [(Some("build"), BUILD_STAGE_IMAGE), (None, IMAGE)] {
        let mut cmd = podman.command("podman");
        cmd.args([
            "build",
            "--pull=never",
            "--format",
            "docker",
            "--volume",
            &format!("{CA_BUNDLE}:{CA_BUNDLE}:ro"),
            "--volume",
            &format!("{}:/usr/local/cargo/registry", registry.display()),
            // Compiled at opt-level 1: the same Dockerfile in half the build time.
            "--build-arg",
            "RELEASE_OPT_LEVEL=1",
            "-f",
            "docker/Dockerfile",
            "-t",
            tag,
        ]);
        if let Some(t) = target {
            cmd.args(["--target", t]);
        }
        let build = cmd
            .arg(".")
            .stdin(Stdio::null())
            .status()
            .expect("podman build");
        assert!(
            build.success(),
            "podman build -f docker/Dockerfile ({tag}) failed"
        );
    }
    let build_time = started.elapsed();
    let _ = podman.output(&["image", "prune", "-f"]);
    let size = |image: &str| -> f64 {
        podman
            .inspect(image, "{{.Size}}")
            .parse::<f64>()
            .unwrap_or(0.0)
            / 1e6
    };
    let (image_mb, base_mb) = (size(IMAGE), size(BASE_IMAGE));
    eprintln!(
        "image {IMAGE}: {image_mb:.1} MB, {:.1} MB over {BASE_IMAGE} ({base_mb:.1} MB); build {:.0} s",
        image_mb - base_mb,
        build_time.as_secs_f64()
    );
    assert!(
        image_mb - base_mb < 40.0,
        "the image adds {:.1} MB",
        image_mb - base_mb
    );
    assert_eq!(podman.inspect(IMAGE, "{{.Config.User}}"), "skyfuse");
    assert!(podman
        .run(&[
            "image",
            "inspect",
            "--format",
            "{{json .HealthCheck}}",
            IMAGE
        ])
        .contains(r#"["CMD","/usr/local/bin/skyfuse","healthcheck"]"#));

    *built = true;
}

/// The start of every container test: None when skipped, else podman checked, the
/// other container tests waited for (held until the guard drops), the image built.
fn container_test(what: &str) -> Option<(std::sync::MutexGuard<'static, bool>, Podman)> {
    if skip_requested("containers", what) {
        return None;
    }
    podman_installed();
    let one_stack_at_a_time = lock(&CONTAINER_TESTS);
    let podman = Podman::new();
    build_image(&podman);
    Some((one_stack_at_a_time, podman))
}

#[test]
fn the_compose_deployment_fuses_across_containers_survives_a_router_restart_and_stops_cleanly() {
    let Some((_one_stack_at_a_time, podman)) = container_test("the compose deployment") else {
        return;
    };

    // The deployment: ports on the host chosen free; MAVLink to a UDP port on the host.
    let http_port = free_port();
    let zenoh_port = free_port();
    let udp_port = free_port();
    let stack = Stack {
        podman: &podman,
        project: format!("skyfuse-e2e-{}", std::process::id()),
        file: "docker/compose.yaml",
        services: &["zenohd", "skyfuse", "vehicle-sim"],
        env: vec![
            ("SKYFUSE_IMAGE".into(), IMAGE.into()),
            ("SKYFUSE_HTTP_PORT".into(), http_port.to_string()),
            ("ZENOH_PORT".into(), zenoh_port.to_string()),
            (
                "SKYFUSE_MAVLINK".into(),
                format!(r#"["udpout:host.containers.internal:{udp_port}"]"#),
            ),
            ("SKYFUSE_VEHICLE".into(), "e2e".into()),
        ],
    };
    stack.up();

    // Samples crossed from the sim's container through the router's into skyfuse's.
    let s = wait_for(
        http_port,
        Duration::from_secs(120),
        "every sensor ok and the estimate valid",
        &stack,
        all_healthy,
    );
    let (code, body) = http_get(http_port, "/healthz").expect("GET /healthz");
    assert_eq!((code, body.trim()), (200, "ok"));
    assert_eq!(s["service"]["vehicle"], "e2e", "environment override");
    eprintln!(
        "sensors: {:?}",
        sensors(&s)
            .iter()
            .map(|x| format!("{} {} {}", x["id"], x["health"], x["received"]))
            .collect::<Vec<_>>()
    );
    let health = podman.output(&["healthcheck", "run", &stack.container("skyfuse")]);
    assert!(
        health.status.success(),
        "the image's HEALTHCHECK failed: {}",
        String::from_utf8_lossy(&health.stderr)
    );

    // VISION_POSITION_ESTIMATE on the host, decoded by pymavlink.
    let mav: Value = serde_json::from_str(&run_py(
        "mavlink_listen.py",
        &[
            "--host",
            "0.0.0.0",
            "--port",
            &udp_port.to_string(),
            "--seconds",
            "6",
        ],
    ))
    .expect("mavlink_listen JSON");
    let vpe = mav["vpe"].as_array().expect("vpe");
    assert!(
        vpe.len() >= 120,
        "{} VPE in 6 s (30 Hz expected)",
        vpe.len()
    );
    assert!(vpe
        .iter()
        .all(|m| m["finite"] == true && m["mavlink2"] == true && m["comp"] == 197));
    assert!(mav["heartbeat"].as_array().map_or(0, |h| h.len()) >= 4);
    assert_eq!(mav["bad_data"], 0);

    // The fused pose through the router to a Zenoh client on the host (as the LAN sees it).
    let zp: Value = serde_json::from_str(&run_py(
        "zenoh_pose_listen.py",
        &[
            "--connect",
            &format!("tcp/127.0.0.1:{zenoh_port}"),
            "--seconds",
            "3",
            "--prefix",
            "skyfuse/e2e",
        ],
    ))
    .expect("zenoh_pose_listen JSON");
    assert!(zp["json"].as_u64().unwrap_or(0) > 50, "{zp}");
    assert!(zp["cdr"].as_u64().unwrap_or(0) > 50, "{zp}");

    // Router restart: data stops, then resumes in the same skyfuse process.
    let skyfuse_started = podman.inspect(&stack.container("skyfuse"), "{{.State.StartedAt}}");
    podman.run(&["stop", "-t", "2", &stack.container("zenohd")]);
    std::thread::sleep(Duration::from_secs(2));
    let a = received_total(&get_status(http_port).expect("status while the router is down"));
    std::thread::sleep(Duration::from_secs(2));
    let during = get_status(http_port).expect("status while the router is down");
    assert_eq!(
        received_total(&during),
        a,
        "samples arrived with the router stopped"
    );
    assert_eq!(
        http_get(http_port, "/healthz").map(|r| r.0).ok(),
        Some(200),
        "skyfuse stays up without its router"
    );
    podman.run(&["start", &stack.container("zenohd")]);
    let restarted = Instant::now();
    wait_for(
        http_port,
        Duration::from_secs(60),
        "samples again after the router restart",
        &stack,
        |s| received_total(s) > a,
    );
    let flowing = restarted.elapsed();
    wait_for(
        http_port,
        // The demo flight's 30 s indoor stretch (70-100 s of each 140 s loop) has no GPS
        // fix; the wait covers it.
        Duration::from_secs(90),
        "healthy again after the router restart",
        &stack,
        all_healthy,
    );
    let healthy = restarted.elapsed();
    eprintln!(
        "router restart: data flowing again {:.2} s after `podman start`, all sensors ok and the estimate valid after {:.2} s",
        flowing.as_secs_f64(),
        healthy.as_secs_f64()
    );
    assert_eq!(
        podman.inspect(&stack.container("skyfuse"), "{{.State.StartedAt}}"),
        skyfuse_started,
        "skyfuse was restarted"
    );
    assert_eq!(
        podman.inspect(&stack.container("skyfuse"), "{{.RestartCount}}"),
        "0"
    );

    // docker stop: SIGTERM, exit code 0, within 2 s.
    let t = Instant::now();
    podman.run(&["stop", "-t", "10", &stack.container("skyfuse")]);
    let stop_time = t.elapsed();
    let code = podman.inspect(&stack.container("skyfuse"), "{{.State.ExitCode}}");
    eprintln!(
        "podman stop skyfuse: {:.2} s, exit code {code}",
        stop_time.as_secs_f64()
    );
    assert_eq!(code, "0", "{}", stack.logs("skyfuse"));
    assert!(
        stop_time < Duration::from_secs(2),
        "stop took {stop_time:?}"
    );
}

fn fleet_row<'a>(f: &'a Value, name: &str) -> Option<&'a Value> {
    f["vehicles"].as_array()?.iter().find(|v| v["name"] == name)
}

#[test]
fn the_fleet_compose_shows_three_vehicles_across_two_routers_on_one_monitor() {
    let Some((_one_stack_at_a_time, podman)) = container_test("the fleet compose deployment")
    else {
        return;
    };

    let monitor_port = free_port();
    let drone_ports = [free_port(), free_port(), free_port()];
    let mut env = vec![
        ("SKYFUSE_IMAGE".to_string(), IMAGE.to_string()),
        ("FLEET_HTTP_PORT".into(), monitor_port.to_string()),
        ("ZENOH_PORT".into(), free_port().to_string()),
    ];
    for (i, p) in drone_ports.iter().enumerate() {
        env.push((format!("DRONE{}_HTTP_PORT", i + 1), p.to_string()));
    }
    let stack = Stack {
        podman: &podman,
        project: format!("skyfuse-fleet-{}", std::process::id()),
        file: "docker/compose.fleet.yaml",
        services: &[
            "router-a",
            "router-b",
            "router-gs",
            "standins",
            "drone1",
            "drone1-sim",
            "drone2",
            "drone2-sim",
            "drone3",
            "drone3-sim",
            "monitor",
        ],
        env,
    };
    let started = Instant::now();
    stack.up();
    let up_took = started.elapsed();
    // drone1 and drone2 reach the monitor across the link between the routers.
    let names = ["drone1", "drone2", "drone3"];
    let f = wait_json(
        monitor_port,
        "/api/v1/fleet",
        Duration::from_secs(120),
        "three vehicles live with a valid estimate on the monitor",
        &stack,
        |f| {
            names.iter().all(|n| {
                fleet_row(f, n).is_some_and(|r| r["presence"] == "live" && r["valid"] == true)
            })
        },
    );
    eprintln!(
        "fleet: `up` took {:.1} s; 3 vehicles live and valid on the monitor {:.1} s after it began",
        up_took.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    assert_eq!(f["monitor"], true);
    // The stand-ins (`skyfuse sim --fleet 20` on router-b) reach the monitor on router-gs
    // too, each once, placed by its summary.
    let standins = |f: &Value| -> Vec<String> {
        f["vehicles"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter(|v| v["id"].as_str().is_some_and(|i| i.starts_with("standins/")))
                    .filter(|v| v["presence"] == "live" && v["frame"] == "geo")
                    .filter_map(|v| v["name"].as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default()
    };
    let f = wait_json(
        monitor_port,
        "/api/v1/fleet?tracks=false",
        Duration::from_secs(30),
        "the 20 stand-ins live and placed on the monitor",
        &stack,
        |f| standins(f).len() == 20,
    );
    let mut got = standins(&f);
    got.sort();
    let want: Vec<String> = (0..20).map(|i| format!("v{i:04}")).collect();
    assert_eq!(got, want, "{f}");
    for (n, port) in names.iter().zip(drone_ports) {
        let r = fleet_row(&f, n).expect("row");
        assert_eq!(r["id"], format!("{n}/skyfuse/{n}"), "its namespace: {f}");
        assert_eq!(r["dashboard"], format!("http://localhost:{port}/"), "{f}");
        assert_eq!(r["frame"], "geo", "{f}");
        assert_eq!(r["zenoh"]["routers"], 1, "a client of one router: {f}");
        // Each vehicle fuses its own sensors only (namespaces keep them apart).
        let s = get_status(port).expect("the vehicle's own status");
        assert_eq!(s["service"]["vehicle"], *n);
        let imu = s["sensors"]
            .as_array()
            .and_then(|v| v.iter().find(|x| x["id"] == "imu"))
            .expect("imu");
        let rate = imu["rate_hz"].as_f64().unwrap_or(0.0);
        assert!((150.0..260.0).contains(&rate), "{n}: imu at {rate} Hz: {s}");
    }
    // The vehicles fly side by side (each sim's home 40 m north of the last).
    let y = |n: &str| {
        fleet_row(&f, n)
            .and_then(|r| r["xy"][1].as_f64())
            .unwrap_or(f64::NAN)
    };
    assert!(y("drone3") - y("drone1") > 50.0, "{f}");

    // drone2 stops: grey on the monitor; the others stay live.
    let stopped = Instant::now();
    podman.run(&["stop", "-t", "5", &stack.container("drone2")]);
    let f = wait_json(
        monitor_port,
        "/api/v1/fleet",
        Duration::from_secs(20),
        "drone2 gone",
        &stack,
        |f| fleet_row(f, "drone2").is_some_and(|r| r["presence"] == "gone"),
    );
    eprintln!(
        "fleet: drone2 grey {:.2} s after `podman stop` began",
        stopped.elapsed().as_secs_f64()
    );
    for n in ["drone1", "drone3"] {
        assert_eq!(
            fleet_row(&f, n).map(|r| r["presence"].clone()),
            Some("live".into()),
            "{f}"
        );
    }
    // The page itself comes from the monitor.
    let (code, page) = http_get(monitor_port, "/fleet").expect("GET /fleet");
    assert_eq!(code, 200);
    assert!(page.contains("js/fleet-main.js"));
    let (code, module) = http_get(monitor_port, "/js/fleet-main.js").expect("GET module");
    assert_eq!(code, 200);
    assert!(module.contains("import "), "an ES module: {module}");
    let health = podman.output(&["healthcheck", "run", &stack.container("monitor")]);
    assert!(health.status.success(), "the monitor's HEALTHCHECK failed");
}
