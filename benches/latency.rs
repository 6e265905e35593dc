//! Latency benchmark (`cargo bench --bench latency`): how long a sample takes from
//! arriving on Zenoh to leaving as VISION_POSITION_ESTIMATE on a UDP socket, at the
//! nominal rates (IMU 1 kHz, flow 100 Hz, T265 200 Hz, GPS 10 Hz), with the CPU and
//! memory the service uses meanwhile; beside the floors measured in the same run:
//! a bare Zenoh hop over loopback, and Zenoh in → UDP out with no work.
//!
//! The service runs as its own process (the release binary), fed by a Zenoh publisher
//! in this process. Each VPE carries the time of the sample that produced it (`usec`,
//! the sample's stamp mapped to the host clock, no latency compensation configured), so
//! `arrival of the VPE − usec` is that sample's trip through the service. The sender
//! stamps samples with the wall clock when it puts them; the service maps stamps with the
//! smallest transport delay it saw, so the figure starts at the sample's arrival.

use skyfuse::codec::{self, Format, MavIdentity};
use skyfuse::sample::SensorKind;
use skyfuse::sim::sensors::StreamSpec;
use skyfuse::sim::Simulator;
use std::net::UdpSocket;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use zenoh::Wait;

const RUN_S: f64 = 20.0;

fn wall_us() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_micros() as i64)
        .unwrap_or(0)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

fn session(listen: Option<u16>, connect: Option<u16>) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, k: &str, v: String| {
        c.insert_json5(k, &v).unwrap_or_else(|e| panic!("{k}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"".into());
    set(&mut c, "scouting/multicast/enabled", "false".into());
    set(
        &mut c,
        "listen/endpoints",
        match listen {
            Some(p) => format!("[\"tcp/127.0.0.1:{p}\"]"),
            None => "[]".into(),
        },
    );
    if let Some(p) = connect {
        set(
            &mut c,
            "connect/endpoints",
            format!("[\"tcp/127.0.0.1:{p}\"]"),
        );
    }
    zenoh::open(c).wait().expect("zenoh session")
}

fn percentiles(mut v: Vec<f64>) -> String {
    if v.is_empty() {
        return "no samples".into();
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| quantile(&v, p);
    format!(
        "p50 {:.0} µs, p90 {:.0} µs, p99 {:.0} µs, max {:.0} µs (n = {})",
        q(0.5),
        q(0.9),
        q(0.99),
        v[v.len() - 1],
        v.len()
    )
}

/// Floors: a bare Zenoh hop, and Zenoh in → UDP out with no work.
fn floors() -> (Vec<f64>, Vec<f64>) {
    let port = free_port();
    let a = session(Some(port), None);
    let b = session(None, Some(port));
    let udp_rx = UdpSocket::bind("127.0.0.1:0").expect("udp");
    let udp_addr = udp_rx.local_addr().expect("addr");
    let udp_tx = UdpSocket::bind("127.0.0.1:0").expect("udp");
    let hop: Arc<Mutex<Vec<f64>>> = Arc::default();
    let hop2 = hop.clone();
    let _sub = b
        .declare_subscriber("bench/floor")
        .callback(move |s| {
            let now = wall_us();
            let bytes = s.payload().to_bytes();
            if let Ok(t) = std::str::from_utf8(&bytes).unwrap_or("").parse::<i64>() {
                if let Ok(mut h) = hop2.lock() {
                    h.push((now - t) as f64);
                }
                let _ = udp_tx.send_to(t.to_string().as_bytes(), udp_addr);
            }
        })
        .wait()
        .expect("subscriber");
    std::thread::sleep(Duration::from_millis(500));
    let udp: Arc<Mutex<Vec<f64>>> = Arc::default();
    let udp2 = udp.clone();
    udp_rx
        .set_read_timeout(Some(Duration::from_millis(500)))
        .expect("timeout");
    let rx = std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        while let Ok(n) = udp_rx.recv(&mut buf) {
            let now = wall_us();
            if let Ok(t) = std::str::from_utf8(&buf[..n]).unwrap_or("").parse::<i64>() {
                if let Ok(mut u) = udp2.lock() {
                    u.push((now - t) as f64);
                }
            }
        }
    });
    for _ in 0..3000 {
        a.put("bench/floor", wall_us().to_string())
            .wait()
            .expect("put");
        std::thread::sleep(Duration::from_millis(1));
    }
    let _ = rx.join();
    let out = (
        hop.lock().map(|v| v.clone()).unwrap_or_default(),
        udp.lock().map(|v| v.clone()).unwrap_or_default(),
    );
    let _ = a.close().wait();
    let _ = b.close().wait();
    out
}

const STREAMS: &[StreamSpec] = &[
    StreamSpec {
        input_id: "imu",
        kind: SensorKind::Imu,
        rate_hz: 1000.0,
        delay_s: 0.0,
    },
    StreamSpec {
        input_id: "t265",
        kind: SensorKind::Odometry,
        rate_hz: 200.0,
        delay_s: 0.0,
    },
    StreamSpec {
        input_id: "flow",
        kind: SensorKind::Flow,
        rate_hz: 100.0,
        delay_s: 0.0,
    },
    StreamSpec {
        input_id: "gps",
        kind: SensorKind::Gnss,
        rate_hz: 10.0,
        delay_s: 0.0,
    },
];

fn config(zenoh_port: u16, udp_port: u16) -> String {
    let mut t = format!(
        r#"[service]
vehicle = "bench"
[zenoh]
listen = ["tcp/127.0.0.1:{zenoh_port}"]
multicast_scouting = false
[http]
bind = "127.0.0.1:0"
[mavlink]
endpoints = ["udpout:127.0.0.1:{udp_port}"]
rate_hz = 30.0
"#
    );
    for s in STREAMS {
        t += &format!(
            "[estimator.sources.{id}]\nlatency_ms = 0.0\n",
            id = s.input_id
        );
    }
    for s in STREAMS {
        t += &format!(
            "[[inputs]]\nid = \"{id}\"\nkind = \"{kind}\"\nkey = \"bench/{id}\"\nformat = \"json\"\nrate_hz = {rate}\n",
            id = s.input_id,
            kind = s.kind.as_str(),
            rate = s.rate_hz
        );
    }
    t
}

/// CPU seconds (user + system) and resident memory (kB) of a process.
fn proc_usage(pid: u32) -> Option<(f64, u64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()?;
    Some((ticks / 100.0, rss))
}

fn service() -> (Vec<f64>, f64, u64, usize) {
    let zport = free_port();
    let udp = UdpSocket::bind("127.0.0.1:0").expect("udp");
    let uport = udp.local_addr().expect("addr").port();
    let cfg = std::env::temp_dir().join(format!("skyfuse-latency-{zport}.toml"));
    std::fs::write(&cfg, config(zport, uport)).expect("config");
    // SKYFUSE_BIN: another build to compare (before/after a change), same harness.
    let binary =
        std::env::var_os("SKYFUSE_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_skyfuse").into());
    let mut child = std::process::Command::new(binary)
        .args(["run", "-c", cfg.to_str().expect("path")])
        .env("RUST_LOG", "warn")
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("skyfuse");
    std::thread::sleep(Duration::from_secs(2));
    let pub_session = session(None, Some(zport));
    std::thread::sleep(Duration::from_millis(500));

    udp.set_read_timeout(Some(Duration::from_millis(500)))
        .expect("timeout");
    let lat: Arc<Mutex<Vec<f64>>> = Arc::default();
    let lat2 = lat.clone();
    let warmup_until = wall_us() + 5_000_000;
    let rx = std::thread::spawn(move || {
        let mut buf = [0u8; 300];
        while let Ok(n) = udp.recv(&mut buf) {
            let now = wall_us();
            // MAVLink 2: 0xFD, len, flags ×2, seq, sys, comp, msgid (3 bytes LE), payload.
            let b = &buf[..n];
            if n > 18 && b[0] == 0xFD && u32::from_le_bytes([b[7], b[8], b[9], 0]) == 102 {
                let mut u = [0u8; 8];
                u.copy_from_slice(&b[10..18]);
                let usec = u64::from_le_bytes(u) as i64;
                if now > warmup_until {
                    if let Ok(mut l) = lat2.lock() {
                        l.push((now - usec) as f64);
                    }
                }
            }
        }
    });

    let sim = Simulator::new(STREAMS, 1, 10.0 + RUN_S);
    let start = Instant::now();
    let mav = MavIdentity {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let mut usage_start = None;
    for ev in sim {
        let due = start + Duration::from_secs_f64(ev.publish_t);
        if let Some(d) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        if usage_start.is_none() && ev.publish_t > 5.0 {
            usage_start = proc_usage(child.id()).map(|u| (Instant::now(), u));
        }
        let id = STREAMS[ev.stream].input_id;
        if let Ok(enc) = codec::encode_sample(Format::Json, None, wall_us(), &ev.data, mav) {
            let _ = pub_session.put(format!("bench/{id}"), enc.payload).wait();
        }
    }
    let usage_end = proc_usage(child.id());
    let _ = rx.join();
    let (cpu, rss) = match (usage_start, usage_end) {
        (Some((t0, (c0, _))), Some((c1, rss))) => ((c1 - c0) / t0.elapsed().as_secs_f64(), rss),
        _ => (f64::NAN, 0),
    };
    let _ = child.kill();
    let _ = child.wait();
    let _ = pub_session.close().wait();
    let v = lat.lock().map(|v| v.clone()).unwrap_or_default();
    let n = v.len();
    (v, cpu, rss, n)
}

/// The `p` quantile of sorted `v`.
fn quantile(v: &[f64], p: f64) -> f64 {
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Rounds to run: `-- --rounds N` (default 3): one round's p99 is a few dozen samples
/// from the top, this VM's scheduling noise on both sides, so ratios are judged as
/// medians over rounds.
fn rounds() -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == "--rounds")
        .and_then(|i| args.get(i + 1))
        .map(|n| n.parse().expect("--rounds takes a number"))
        .unwrap_or(3)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    quantile(&v, 0.5)
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("(quick mode: run with `cargo bench --bench latency` for figures)");
        return;
    }
    let n_rounds = rounds();
    println!(
        "## Latency (loopback, {RUN_S} s at IMU 1 kHz, T265 200 Hz, flow 100 Hz, GPS 10 Hz; {n_rounds} rounds)"
    );
    // Per round: (p50 ratio, p99 ratio) of skyfuse against the Zenoh in → UDP out floor.
    let mut ratios = Vec::new();
    for round in 1..=n_rounds {
        let (hop, mut udp) = floors();
        let (mut lat, cpu, rss, n) = service();
        println!("\n### Round {round}\n");
        println!("| path | latency |");
        println!("|---|---|");
        println!(
            "| floor: bare Zenoh hop (put → subscriber callback) | {} |",
            percentiles(hop)
        );
        println!(
            "| floor: Zenoh in → UDP out, no work | {} |",
            percentiles(udp.clone())
        );
        println!(
            "| skyfuse: sample arrival → VISION_POSITION_ESTIMATE received on UDP | {} |",
            percentiles(lat.clone())
        );
        println!(
            "\nService meanwhile: {:.1} % of one core, {} MiB resident; {} VPE at 30 Hz.",
            cpu * 100.0,
            rss / 1024,
            n
        );
        if udp.is_empty() || lat.is_empty() {
            continue;
        }
        udp.sort_by(f64::total_cmp);
        lat.sort_by(f64::total_cmp);
        ratios.push((
            quantile(&lat, 0.5) / quantile(&udp, 0.5),
            quantile(&lat, 0.99) / quantile(&udp, 0.99),
        ));
    }
    if ratios.is_empty() {
        return;
    }
    let list = |f: fn(&(f64, f64)) -> f64| {
        ratios
            .iter()
            .map(|r| format!("{:.2}", f(r)))
            .collect::<Vec<_>>()
            .join(" / ")
    };
    let within =
        |f: fn(&(f64, f64)) -> f64, limit: f64| ratios.iter().filter(|r| f(r) <= limit).count();
    let (p50, p99) = (|r: &(f64, f64)| r.0, |r: &(f64, f64)| r.1);
    println!(
        "\n### Against the Zenoh in → UDP out floor, {} rounds\n",
        ratios.len()
    );
    println!("| | per round | median | rounds within |");
    println!("|---|---|---|---|");
    println!(
        "| p50 / floor's p50 | {} | **{:.2}×** | {} of {} within 1.3× |",
        list(p50),
        median(ratios.iter().map(p50).collect()),
        within(p50, 1.3),
        ratios.len()
    );
    println!(
        "| p99 / floor's p99 | {} | **{:.2}×** | {} of {} within 1.5× |",
        list(p99),
        median(ratios.iter().map(p99).collect()),
        within(p99, 1.5),
        ratios.len()
    );
}
