//! Command line: `run`, `demo`, `check-config`, `sim`. Each command builds a config,
//! binds its listeners and calls into [`crate::app`] or [`crate::sim`].

use crate::app::{self, Listeners};
use crate::config::{Config, ZenohConfig, ZenohMode};
use crate::estimator::Mode;
use crate::ingest::zenoh_in;
use crate::offline;
use crate::sim::{publish, scenario, sensors::DEMO_STREAMS, Simulator};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Debug, Parser)]
#[command(
    name = "skyfuse",
    version,
    about = "Sensor fusion for drones and robots: Zenoh in, fused pose out, live dashboard."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the service (the real deployment).
    #[command(
        after_help = "Example: skyfuse run -c my.toml --connect tcp/192.168.1.10:7447 --mavlink udpout:192.168.1.20:14540"
    )]
    Run {
        /// Config file (TOML); without it the built-in default (config/default.toml).
        #[arg(short, long, env = "SKYFUSE_CONFIG")]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
        #[command(flatten)]
        record: RecordArgs,
        /// MAVLink endpoint for VISION_POSITION_ESTIMATE (repeatable): udpout:HOST:PORT,
        /// udpin:HOST:PORT, tcpout:HOST:PORT, serial:PATH:BAUD. Adds to the config's.
        #[arg(long = "mavlink", value_name = "ADDR")]
        mavlink: Vec<String>,
    },
    /// Run the service with the built-in simulator on loopback and open the dashboard.
    #[command(
        after_help = "Example: skyfuse demo --mavlink udpout:127.0.0.1:14540   (feeding PX4 SITL)"
    )]
    Demo {
        #[command(flatten)]
        net: NetArgs,
        #[command(flatten)]
        record: RecordArgs,
        /// MAVLink endpoint for VISION_POSITION_ESTIMATE (repeatable), as for `run`.
        #[arg(long = "mavlink", value_name = "ADDR")]
        mavlink: Vec<String>,
        /// Simulator seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Where the simulated vehicle flies: LAT,LON[,ALT] (default PX4 SITL's home).
        #[arg(long, value_name = "LAT,LON[,ALT]", value_parser = parse_home)]
        home: Option<(f64, f64, f64)>,
        /// Do not try to open a browser.
        #[arg(long)]
        no_browser: bool,
    },
    /// The fleet view alone, for a ground station: every skyfuse on the Zenoh network on
    /// one page (http://<bind>/fleet). No estimator and no inputs; only `[zenoh]`,
    /// `[http]` and `[fleet]` of the config are used.
    #[command(
        after_help = "Example: skyfuse monitor --connect tcp/192.168.1.10:7447 --http 0.0.0.0:8090"
    )]
    Monitor {
        #[arg(short, long, env = "SKYFUSE_CONFIG")]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
    },
    /// Check a config file and print what it configures.
    #[command(after_help = "Example: skyfuse check-config my.toml")]
    CheckConfig { file: PathBuf },
    /// Ask the running service's /healthz; exit code 0 if it answers 200, else 1
    /// (the container image's HEALTHCHECK). The address comes from the same config
    /// file and environment as `run`.
    #[command(after_help = "Example: skyfuse healthcheck --http 127.0.0.1:8080")]
    Healthcheck {
        #[arg(short, long, env = "SKYFUSE_CONFIG")]
        config: Option<PathBuf>,
        /// Address to ask instead of the config's `[http] bind`, e.g. 127.0.0.1:8080.
        #[arg(long, value_name = "ADDR")]
        http: Option<String>,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 2.0)]
        timeout: f64,
    },
    /// Simulate a flight: publish its sensor samples to Zenoh for another skyfuse
    /// instance, or with `--out` run it offline through the estimator and write TUM files.
    #[command(
        after_help = "Example: skyfuse sim --connect tcp/127.0.0.1:7447   (or offline: skyfuse sim --scenario gps-loss --out out/)"
    )]
    Sim {
        /// Config: its inputs name the keys and formats to publish, its `[estimator]`
        /// table configures offline runs (default: built-in).
        #[arg(short, long)]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Where the simulated vehicle flies: LAT,LON[,ALT] (default PX4 SITL's home).
        #[arg(long, value_name = "LAT,LON[,ALT]", value_parser = parse_home)]
        home: Option<(f64, f64, f64)>,
        /// Seconds of flight (default: until stopped; offline: one 140 s loop).
        #[arg(long)]
        duration: Option<f64>,
        /// Scenario (see `--list`), or `all` with `--out`.
        #[arg(long, default_value = "demo")]
        scenario: String,
        /// Offline: write truth.tum, fused.tum, <sensor>.tum, events.jsonl and
        /// summary.json here instead of publishing.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Offline: fusion mode (wrls, ekf, wrls+ekf, or all); default from the config.
        #[arg(long)]
        fusion: Option<String>,
        /// Offline: write the scenario's sensor samples as a PX4 ULog file (the topics
        /// `skyfuse replay` reads) instead of publishing; `--duration` sets its length.
        #[arg(long, value_name = "FILE", conflicts_with = "out")]
        ulog: Option<PathBuf>,
        /// Offline: write the scenario's sensor samples as an ArduPilot DataFlash log
        /// (`.bin`: IMU, ATT, OF, RFND, GPS, BARO, VISP records) instead of publishing.
        #[arg(long, value_name = "FILE", conflicts_with_all = ["out", "ulog"])]
        dataflash: Option<PathBuf>,
        /// Run this many times faster than real time, as SITL's `--speedup` (the
        /// samples' stamps on the simulator's clock); publishing only.
        #[arg(long, default_value_t = 1.0, value_parser = parse_speedup)]
        speedup: f64,
        /// The simulated IMU's rate, Hz (default: the scenario's, 200 Hz).
        #[arg(long, value_name = "HZ")]
        imu_hz: Option<f64>,
        /// List the scenarios and exit.
        #[arg(long)]
        list: bool,
        /// Instead of one simulated flight: N light stand-in vehicles from this one
        /// process (pose, health, summary, liveliness token on a real skyfuse's keys,
        /// no estimator), for the fleet view at scale. Prints what it published as
        /// one JSON line when it stops.
        #[arg(long, value_name = "N", conflicts_with_all = ["out", "ulog", "dataflash", "monte_carlo"],
              value_parser = clap::value_parser!(u32).range(1..=100_000))]
        fleet: Option<u32>,
        /// With `--fleet`: the first vehicle's number (names v<I>, v<I+1>, …), so fleets
        /// from several processes do not collide.
        #[arg(long, default_value_t = 0, value_name = "I", requires = "fleet")]
        fleet_first: u32,
        /// With `--fleet`: each stand-in's pose rate, Hz (a real skyfuse: `[output]
        /// pose_rate_hz`, 50 by default).
        #[arg(long, default_value_t = 10.0, value_name = "HZ", requires = "fleet", value_parser = parse_pose_hz)]
        pose_hz: f64,
        /// Offline: fly this many randomised vehicles and flights (seeded by `--seed`)
        /// through the configuration and print the integrity table by scenario family;
        /// with `--out`, each run's figures as `runs.jsonl` and the table as
        /// `families.json`.
        #[arg(long, value_name = "N", conflicts_with_all = ["ulog", "dataflash"])]
        monte_carlo: Option<u64>,
        /// With `--monte-carlo`: start at this draw (draws are numbered from 0).
        #[arg(long, default_value_t = 0, value_name = "I", requires = "monte_carlo")]
        first: u64,
        /// With `--monte-carlo`: parallel runs (default: the cores).
        #[arg(long, value_name = "J", requires = "monte_carlo")]
        jobs: Option<usize>,
        /// With `--monte-carlo`: beyond the draw, one flight in five gets an
        /// accelerometer that steps by 1 m/s² at a random time and stays so (a knock
        /// that shifted its mount); the rest of every draw is the same flight.
        #[arg(long, requires = "monte_carlo")]
        accel_steps: bool,
    },
    /// Replay a recorded flight (a PX4 ULog, a directory of its CSV export by pyulog's
    /// ulog2csv, an ArduPilot DataFlash log, a MAVLink telemetry log, a skyfuse
    /// recording or a rosbag2 bag in MCAP)
    /// through the estimator and write TUM files, events and a summary scored on the
    /// whole log.
    #[command(after_help = "Example: skyfuse replay flight.ulg --out out/ --reference ekf2")]
    Replay {
        /// A `.ulg`, `.bin`, `.tlog` or `.mcap` file, or a directory of `<topic>_<instance>.csv[.gz]`
        /// (or a rosbag2 bag directory holding one `.mcap`).
        path: PathBuf,
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Only fuse these sources or kinds (e.g. `flow,range,attitude`); the others are
        /// still written for comparison.
        #[arg(long, value_delimiter = ',')]
        sources: Option<Vec<String>>,
        /// The source the others are scored against (APE, SE(3)-aligned); default: the
        /// log's camera odometry (`vio`), else the autopilot's estimate, else GNSS.
        #[arg(long, default_value = "")]
        reference: String,
        /// Score only this window of the log, seconds from its start: `START:END`.
        #[arg(long, value_parser = parse_window)]
        window: Option<(f64, f64)>,
        /// Fusion mode (wrls, ekf, wrls+ekf); default from the config.
        #[arg(long)]
        fusion: Option<String>,
        /// Config whose `[estimator]` table is used (default: built-in).
        #[arg(short, long)]
        config: Option<PathBuf>,
    },
    /// The corpus: replay every flight log found under PATHS (ULog, PX4 CSV exports,
    /// DataFlash, tlogs, recordings) with one configuration, fusing flow + range +
    /// attitude + barometer and then everything but the reference, and print one table:
    /// fused against each single source, plain flow dead reckoning and the autopilot's
    /// EKF, valid fraction and consistency. Example: `skyfuse eval ../shared/data
    /// --scenarios --out eval`.
    #[command(
        after_help = "Example: skyfuse eval ../shared/data my_logs/ --scenarios --out eval/"
    )]
    Eval {
        /// Flight logs, or directories searched for them.
        paths: Vec<PathBuf>,
        /// Also every simulator scenario, scored against its truth.
        #[arg(long)]
        scenarios: bool,
        /// Where each run's files, `eval.md` and `eval.json` go.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Exit non-zero when a run's fused track is not the best of its row or its valid
        /// poses broke their σ (at least 99 % within 3σ per axis, none beyond 5σ).
        #[arg(long)]
        check: bool,
        /// Config whose `[estimator]` and `[health]` tables are used (default: built-in).
        #[arg(short, long)]
        config: Option<PathBuf>,
    },
    /// List what is published on the Zenoh network: each key, its rate, what it is
    /// (ROS 2 type as a bridge announces it or as its bytes decode, MAVLink message,
    /// raw frames, skyfuse JSON) and which input of the config reads it; with --write, a
    /// starting config with an input for every key skyfuse reads, which `skyfuse run -c`
    /// takes as it is. Example: `skyfuse discover --connect tcp/192.168.1.10:7447
    /// --seconds 5 --write found.toml`.
    #[command(
        after_help = "Example: skyfuse discover --connect tcp/192.168.1.10:7447 --seconds 5 --write found.toml"
    )]
    Discover {
        /// Config whose inputs the keys are matched against (default: built-in).
        #[arg(short, long, env = "SKYFUSE_CONFIG")]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
        /// How long to listen, s.
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Write a starting config (one input per key skyfuse reads) to this file.
        #[arg(long, value_name = "FILE")]
        write: Option<PathBuf>,
        /// Print the table as JSON (as /api/v1/discovered).
        #[arg(long)]
        json: bool,
    },
}

/// The flight recorder and the Foxglove live view.
#[derive(Debug, Args, Default)]
pub struct RecordArgs {
    /// Record the flight as MCAP files in this directory (`[record] dir`).
    #[arg(long, value_name = "DIR")]
    pub record: Option<PathBuf>,
    /// Serve the Foxglove WebSocket live view here, e.g. 0.0.0.0:8765 (`[foxglove] bind`).
    #[arg(long, value_name = "ADDR")]
    pub foxglove: Option<String>,
}

impl RecordArgs {
    fn apply(&self, c: &mut Config) -> Result<(), String> {
        if let Some(d) = &self.record {
            c.record.dir = Some(d.display().to_string());
        }
        if let Some(b) = &self.foxglove {
            c.foxglove.bind = Some(b.clone());
        }
        c.validate().map_err(|e| format!("command line: {e}"))
    }
}

/// Network and identity overrides shared by the commands.
#[derive(Debug, Args, Default)]
pub struct NetArgs {
    /// Zenoh namespace for every key of this process (`[zenoh] namespace`), e.g. bot1:
    /// several vehicles on one Zenoh network, each with its own inputs.
    #[arg(long, value_name = "NS")]
    pub namespace: Option<String>,
    /// Vehicle name (`[service] vehicle`; the outputs' key prefix skyfuse/<vehicle>).
    #[arg(long, value_name = "NAME")]
    pub vehicle: Option<String>,
    /// Zenoh endpoint to listen on (repeatable), e.g. tcp/0.0.0.0:7447.
    #[arg(long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Zenoh endpoint to connect to (repeatable), e.g. tcp/192.168.1.10:7447.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Zenoh mode: peer (no router needed) or client (of a router).
    #[arg(long, value_parser = parse_mode)]
    pub mode: Option<ZenohMode>,
    /// Disable Zenoh multicast scouting (use explicit endpoints only).
    #[arg(long)]
    pub no_multicast: bool,
    /// HTTP address for the dashboard and API, e.g. 0.0.0.0:8080.
    #[arg(long, value_name = "ADDR")]
    pub http: Option<String>,
}

/// `--pose-hz`: a stand-in's pose rate.
fn parse_pose_hz(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if (0.5..=200.0).contains(&x) => Ok(x),
        Ok(_) => Err(format!("{s:?}: between 0.5 and 200")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// `--speedup`: a simulator's rate against real time.
fn parse_speedup(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if (0.1..=20.0).contains(&x) => Ok(x),
        Ok(_) => Err(format!("{s:?}: between 0.1 and 20")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// `LAT,LON[,ALT]` in degrees and metres.
fn parse_home(s: &str) -> Result<(f64, f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{s:?}: {e} (expected LAT,LON[,ALT])"))?;
    let (lat, lon, alt) = match v[..] {
        [lat, lon] => (lat, lon, crate::sim::sensors::HOME_ALT),
        [lat, lon, alt] => (lat, lon, alt),
        _ => return Err(format!("{s:?}: expected LAT,LON[,ALT]")),
    };
    if !(lat.abs() <= 89.0 && lon.abs() <= 180.0 && alt.is_finite()) {
        return Err(format!(
            "{s:?}: latitude within ±89°, longitude within ±180°"
        ));
    }
    Ok((lat, lon, alt))
}

fn parse_mode(s: &str) -> Result<ZenohMode, String> {
    match s {
        "peer" => Ok(ZenohMode::Peer),
        "client" => Ok(ZenohMode::Client),
        other => Err(format!("unknown mode {other:?} (peer or client)")),
    }
}

impl NetArgs {
    fn apply(&self, c: &mut Config) -> Result<(), String> {
        if !self.listen.is_empty() {
            c.zenoh.listen = self.listen.clone();
        }
        if !self.connect.is_empty() {
            c.zenoh.connect = self.connect.clone();
        }
        if let Some(m) = self.mode {
            c.zenoh.mode = m;
        }
        if self.no_multicast {
            c.zenoh.multicast_scouting = false;
        }
        if let Some(h) = &self.http {
            c.http.bind = h.clone();
        }
        if let Some(ns) = &self.namespace {
            c.zenoh.namespace = Some(ns.clone());
        }
        if let Some(v) = &self.vehicle {
            c.service.vehicle = v.clone();
        }
        c.validate().map_err(|e| format!("command line: {e}"))
    }
}

fn env_vars() -> Vec<(String, String)> {
    std::env::vars().collect()
}

/// A simulator's config (`skyfuse sim`, one vehicle or a fleet): told where to connect,
/// it needs no listener of its own, as the config's (tcp/0.0.0.0:7447) would collide
/// with the skyfuse it feeds.
fn sim_config(path: Option<&std::path::Path>, net: &NetArgs) -> Result<Config, String> {
    let mut c = load(path, net)?;
    if !net.connect.is_empty() && net.listen.is_empty() {
        c.zenoh.listen.clear();
    }
    Ok(c)
}

fn load(path: Option<&std::path::Path>, net: &NetArgs) -> Result<Config, String> {
    let mut c = Config::load(path, env_vars()).map_err(|e| e.to_string())?;
    net.apply(&mut c)?;
    Ok(c)
}

pub fn init_logging() {
    init_logging_at("info,zenoh=warn");
}

/// Logging at `default` unless `RUST_LOG` says otherwise.
fn init_logging_at(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    // Colour codes only for a person at a terminal, not in a file, a pipe or journald.
    use std::io::IsTerminal;
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stdout().is_terminal())
        .try_init();
}

/// Entry point of the binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Command::Healthcheck {
        config,
        http,
        timeout,
    } = &cli.command
    {
        // Quiet and quick: no logging, no multi-threaded runtime. Exit code 1, not 2,
        // for unhealthy: Docker reserves 2.
        return match healthcheck(config.as_deref(), http.as_deref(), *timeout) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("unhealthy: {e}");
                ExitCode::FAILURE
            }
        };
    }
    // A listing piped into `head` ends quietly when the reader goes, as Unix tools do,
    // not with a panic on the next println. Only for the commands that print and read
    // files: the service keeps Rust's default, where a closed socket is an error to
    // handle, not the end of the process.
    if matches!(
        cli.command,
        Command::CheckConfig { .. }
            | Command::Replay { .. }
            | Command::Eval { .. }
            | Command::Sim { list: true, .. }
    ) {
        default_sigpipe();
    }
    // Still one thread: the environment may be set.
    zenoh_in::set_zenoh_runtime_default();
    // A corpus run prints its table; what each log held is in its files.
    if matches!(cli.command, Command::Eval { .. } | Command::Discover { .. }) {
        init_logging_at("warn");
    } else {
        init_logging();
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = rt.block_on(dispatch(cli.command));
    // Do not wait for a worker still blocked in Zenoh's open (stopped while waiting for
    // the router): everything that matters has been shut down by now.
    rt.shutdown_timeout(std::time::Duration::from_millis(200));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

/// SIGPIPE's default action (terminate quietly); Rust ignores it at start-up.
fn default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called before any other thread exists; only resets a signal's disposition.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// GET /healthz from the service at `http` (default: the config's bind address, with
/// an unspecified host such as 0.0.0.0 asked on loopback).
fn healthcheck(
    config: Option<&std::path::Path>,
    http: Option<&str>,
    timeout_s: f64,
) -> Result<(), String> {
    use std::io::Read;
    let config = Config::load(config, env_vars());
    let bind = match (http, &config) {
        (Some(h), _) => h.to_string(),
        (None, Ok(c)) => c.http.bind.clone(),
        (None, Err(e)) => return Err(e.to_string()),
    };
    // With HTTPS configured, ask over TLS, trusting exactly the configured certificate.
    let tls_cert = config
        .ok()
        .and_then(|c| c.http.tls().map(|(cert, _)| cert.to_string()));
    let addr = probe_addr(&bind)?;
    let timeout = std::time::Duration::from_secs_f64(timeout_s.clamp(0.1, 60.0));
    let stream = std::net::TcpStream::connect_timeout(&addr, timeout)
        .map_err(|e| format!("cannot connect to {addr}: {e}"))?;
    let io = |e: std::io::Error| format!("{addr}: {e}");
    stream.set_read_timeout(Some(timeout)).map_err(io)?;
    stream.set_write_timeout(Some(timeout)).map_err(io)?;
    let ask = |s: &mut dyn ReadWrite| -> Result<Vec<u8>, String> {
        write!(s, "GET /healthz HTTP/1.0\r\nHost: {addr}\r\n\r\n").map_err(io)?;
        let mut answer = Vec::new();
        s.take(4096).read_to_end(&mut answer).map_err(io)?;
        Ok(answer)
    };
    let answer = match tls_cert {
        Some(cert) => ask(&mut crate::http::tls::pinned_client(&cert, stream)?)?,
        None => ask(&mut { stream })?,
    };
    let answer = String::from_utf8_lossy(&answer);
    match http_status(&answer) {
        Some(200) => Ok(()),
        Some(code) => Err(format!(
            "{addr}/healthz answered {code}: {}",
            answer.split("\r\n\r\n").nth(1).unwrap_or("").trim()
        )),
        None => Err(format!("{addr}/healthz: not an HTTP answer")),
    }
}

/// A byte stream the health check speaks HTTP over (plain TCP or TLS).
trait ReadWrite: std::io::Read + std::io::Write {}
impl<T: std::io::Read + std::io::Write> ReadWrite for T {}

/// The address to probe for a bind address: a wildcard host is asked on loopback.
fn probe_addr(bind: &str) -> Result<std::net::SocketAddr, String> {
    let mut addr: std::net::SocketAddr = bind
        .parse()
        .map_err(|e| format!("http address {bind:?}: {e}"))?;
    if addr.ip().is_unspecified() {
        addr.set_ip(match addr {
            std::net::SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    Ok(addr)
}

/// The status code of an HTTP/1.x response.
fn http_status(response: &str) -> Option<u16> {
    let mut words = response.lines().next()?.split_whitespace();
    words.next().filter(|v| v.starts_with("HTTP/1."))?;
    words.next()?.parse().ok()
}

async fn dispatch(cmd: Command) -> Result<(), String> {
    match cmd {
        Command::Healthcheck { .. } => Err("healthcheck runs before the runtime".into()),
        Command::CheckConfig { file } => {
            let c = Config::load(Some(&file), env_vars()).map_err(|e| e.to_string())?;
            let (typos, empty) = c.vehicle_problems();
            if !(typos.is_empty() && empty.is_empty()) {
                let all: Vec<String> = typos.into_iter().chain(empty).collect();
                return Err(format!("{}: {}", file.display(), all.join("; ")));
            }
            println!(
                "{}: ok ({} inputs, {} enabled)",
                file.display(),
                c.inputs.len(),
                c.inputs.iter().filter(|i| i.enabled).count()
            );
            for i in &c.inputs {
                println!(
                    "  {:<12} {:<18} {:<13} {:<38} {:>6} Hz{}",
                    i.id,
                    i.kind.as_str(),
                    i.format.as_str(),
                    i.key,
                    i.rate_hz,
                    if i.enabled { "" } else { "  (disabled)" }
                );
            }
            Ok(())
        }
        Command::Run {
            config,
            net,
            record,
            mavlink,
        } => {
            let mut c = load(config.as_deref(), &net)?;
            record.apply(&mut c)?;
            add_mavlink(&mut c, &mavlink)?;
            let (typos, empty) = c.vehicle_problems();
            if let Some(t) = typos.first() {
                return Err(t.clone());
            }
            for e in empty {
                tracing::warn!("{e}");
            }
            serve(c, Serve::Vehicle).await
        }
        Command::Demo {
            net,
            record,
            mavlink,
            seed,
            home,
            no_browser,
        } => demo(net, record, mavlink, seed, home, no_browser).await,
        Command::Monitor { config, net } => {
            serve(load(config.as_deref(), &net)?, Serve::Monitor).await
        }
        Command::Sim { list: true, .. } => {
            for (name, description) in scenario::NAMES {
                println!("  {name:<16} {description}");
            }
            Ok(())
        }
        Command::Sim {
            config,
            net,
            home,
            duration,
            fleet: Some(n),
            fleet_first,
            pose_hz,
            ..
        } => {
            let c = sim_config(config.as_deref(), &net)?;
            let mut shutdown = Box::pin(app::shutdown_signal());
            let Some(session) = open_zenoh(&c.zenoh, &mut shutdown).await? else {
                return Ok(());
            };
            let (lat, lon, alt) = home.unwrap_or((
                crate::sim::sensors::HOME_LAT,
                crate::sim::sensors::HOME_LON,
                crate::sim::sensors::HOME_ALT,
            ));
            let sim = crate::sim::fleet::FleetSim {
                vehicles: n as usize,
                first: fleet_first as usize,
                pose_hz,
                home: (lat, lon, alt),
                duration: duration.unwrap_or(f64::INFINITY),
            };
            let report = crate::sim::fleet::run(&session, &sim, shutdown).await;
            let _ = session.close().await;
            let report = report?;
            println!(
                "{}",
                serde_json::to_string(&report).map_err(|e| e.to_string())?
            );
            Ok(())
        }
        Command::Sim {
            config,
            seed,
            monte_carlo: Some(n),
            first,
            jobs,
            accel_steps,
            out,
            ..
        } => {
            let c = Config::load(config.as_deref(), env_vars()).map_err(|e| e.to_string())?;
            let stress = crate::sim::monte_carlo::Stress { accel_steps };
            monte_carlo::run(&c, seed, first, n, stress, jobs, out.as_deref())
        }
        Command::Sim {
            seed,
            duration,
            scenario,
            ulog: Some(file),
            imu_hz,
            ..
        } => sim_log(&scenario, seed, duration, imu_hz, &file, SimLog::Ulog),
        Command::Sim {
            seed,
            duration,
            scenario,
            dataflash: Some(file),
            imu_hz,
            ..
        } => sim_log(&scenario, seed, duration, imu_hz, &file, SimLog::Dataflash),
        Command::Sim {
            config,
            seed,
            duration,
            scenario,
            out: Some(out),
            fusion,
            imu_hz,
            ..
        } => {
            let c = Config::load(config.as_deref(), env_vars()).map_err(|e| e.to_string())?;
            offline_sims(
                &c,
                &scenario,
                fusion.as_deref(),
                seed,
                duration,
                imu_hz,
                &out,
            )
        }
        Command::Discover {
            config,
            net,
            seconds,
            write,
            json,
        } => discover::discover(load(config.as_deref(), &net)?, &net, seconds, write, json).await,
        Command::Eval {
            paths,
            scenarios,
            out,
            check,
            config,
        } => {
            let c = Config::load(config.as_deref(), env_vars()).map_err(|e| e.to_string())?;
            eval::eval(&c, &paths, scenarios, &out, check)
        }
        Command::Replay {
            path,
            out,
            sources,
            reference,
            window,
            fusion,
            config,
        } => {
            let c = Config::load(config.as_deref(), env_vars()).map_err(|e| e.to_string())?;
            replay(
                &c,
                &path,
                &out,
                sources.as_deref(),
                &reference,
                window,
                fusion.as_deref(),
            )
        }
        Command::Sim {
            config,
            net,
            seed,
            home,
            duration,
            scenario,
            imu_hz,
            speedup,
            ..
        } => {
            let scn = scenario_at(&scenario, imu_hz)?;
            let c = sim_config(config.as_deref(), &net)?;
            let mut shutdown = Box::pin(app::shutdown_signal());
            let Some(session) = open_zenoh(&c.zenoh, &mut shutdown).await? else {
                return Ok(());
            };
            let mut sim = scn.simulator(seed, duration.unwrap_or(f64::INFINITY));
            if let Some((lat, lon, alt)) = home {
                sim.set_home(lat, lon, alt);
            }
            let counters = Arc::new(publish::PublishCounters::default());
            let n = publish::run_publisher(
                session.clone(),
                Arc::new(c),
                sim,
                speedup,
                counters,
                shutdown,
            )
            .await;
            tracing::info!(published = n, "sim finished");
            let _ = session.close().await;
            Ok(())
        }
    }
}

/// What `serve` runs once its listeners are open.
enum Serve {
    /// The service (`skyfuse run`).
    Vehicle,
    /// The fleet view alone (`skyfuse monitor`).
    Monitor,
}

/// Bind HTTP, open Zenoh (or stop cleanly if a signal comes first), then run until a
/// signal.
async fn serve(c: Config, what: Serve) -> Result<(), String> {
    let http = tokio::net::TcpListener::bind(&c.http.bind)
        .await
        .map_err(|e| format!("cannot listen for HTTP on {}: {e}", c.http.bind))?;
    let mut shutdown = Box::pin(app::shutdown_signal());
    // Until the session opens (a client waiting for its router), the HTTP port says so
    // instead of holding connections unanswered.
    let waiting = format!(
        "starting: waiting for the Zenoh session ({:?} mode, connect {:?})\n",
        c.zenoh.mode, c.zenoh.connect
    );
    let answering = crate::http::starting::StartingResponder::start(http, waiting)
        .map_err(|e| format!("the HTTP port while starting: {e}"))?;
    let opened = open_zenoh(&c.zenoh, &mut shutdown).await;
    let http = answering
        .finish()
        .await
        .map_err(|e| format!("the HTTP port while starting: {e}"))?;
    let Some(zenoh) = opened? else {
        return Ok(());
    };
    let listeners = Listeners { http, zenoh };
    match what {
        Serve::Vehicle => app::run(c, listeners, shutdown).await,
        Serve::Monitor => app::monitor(c, listeners, shutdown).await,
    }
    .map_err(|e| e.to_string())
}

/// Open the Zenoh session, or give up cleanly if a shutdown signal comes first: a client
/// waits for its router (see `zenoh_in::zenoh_config`), and `docker stop` must still
/// end it with exit code 0.
async fn open_zenoh(
    cfg: &ZenohConfig,
    shutdown: &mut (impl std::future::Future<Output = ()> + Unpin),
) -> Result<Option<zenoh::Session>, String> {
    if cfg.mode == ZenohMode::Client {
        tracing::info!(connect = ?cfg.connect, "connecting to the Zenoh router (retrying until it answers)");
    }
    // The open runs on a thread of its own (see `zenoh_in::open_session`), so this
    // task stays free to see the signal.
    tokio::select! {
        session = zenoh_in::open_session(cfg) => session.map(Some).map_err(|e| e.to_string()),
        _ = shutdown => {
            tracing::info!("stopped before the Zenoh session opened");
            Ok(None)
        }
    }
}

/// The demo: the default config on loopback only (no multicast, Zenoh on a free port),
/// plus the simulator in a second Zenoh session that connects to it, exactly as a
/// vehicle's bridges would.
async fn demo(
    net: NetArgs,
    record: RecordArgs,
    mavlink: Vec<String>,
    seed: u64,
    home: Option<(f64, f64, f64)>,
    no_browser: bool,
) -> Result<(), String> {
    let mut c = Config::load(None, env_vars()).map_err(|e| e.to_string())?;
    // A free loopback port for the service's Zenoh endpoint (the sim connects to it).
    let zport = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .map_err(|e| format!("no free loopback port for Zenoh: {e}"))?;
    c.zenoh.listen = vec![format!("tcp/127.0.0.1:{zport}")];
    c.zenoh.connect.clear();
    c.zenoh.multicast_scouting = false;
    c.http.bind = "127.0.0.1:8080".into();
    c.service.vehicle = "demo".into();
    // Foxglove on its usual port; if that is taken (another demo), any port (logged)
    // rather than no demo: see RunOptions::foxglove_any_port.
    let foxglove_default = c.foxglove.bind.is_none();
    if foxglove_default {
        c.foxglove.bind = Some(crate::config::DEMO_FOXGLOVE_BIND.into());
    }
    net.apply(&mut c)?;
    record.apply(&mut c)?;
    add_mavlink(&mut c, &mavlink)?;

    let http = tokio::net::TcpListener::bind(&c.http.bind)
        .await
        .map_err(|e| {
            format!(
                "cannot listen for HTTP on {}: {e} (try --http 127.0.0.1:0)",
                c.http.bind
            )
        })?;
    let http_addr = http.local_addr().map_err(|e| e.to_string())?;
    let zenoh = zenoh_in::open_session(&c.zenoh)
        .await
        .map_err(|e| e.to_string())?;
    let locators = c.zenoh.listen.clone();

    let mut sim_cfg = c.clone();
    sim_cfg.zenoh.mode = ZenohMode::Peer;
    sim_cfg.zenoh.listen.clear();
    sim_cfg.zenoh.connect = locators.clone();
    sim_cfg.zenoh.multicast_scouting = false;
    // The sim session listens nowhere of its own: it only connects to the service.
    sim_cfg.zenoh.listen = vec!["tcp/127.0.0.1:0".into()];
    let sim_session = zenoh_in::open_session(&sim_cfg.zenoh)
        .await
        .map_err(|e| format!("demo simulator: {e}"))?;

    // Controls need a token; the demo makes one unless the environment set it.
    let generated_token = c.http.token.is_empty();
    if generated_token {
        c.http.token = random_token();
    }
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mut sim = Simulator::new(DEMO_STREAMS, seed, f64::INFINITY);
    if let Some((lat, lon, alt)) = home {
        sim.set_home(lat, lon, alt);
    }
    let faults = sim.faults();
    let counters = Arc::new(publish::PublishCounters::default());
    let mut sim_stop = stop_rx.clone();
    let sim_task = tokio::spawn(publish::run_publisher(
        sim_session.clone(),
        Arc::new(sim_cfg),
        sim,
        1.0,
        counters,
        async move {
            let _ = sim_stop.changed().await;
        },
    ));

    let url = format!("http://{http_addr}/");
    println!("skyfuse demo: dashboard at {url} (simulated vehicle on Zenoh {locators:?}); Ctrl-C to stop");
    if generated_token {
        println!(
            "controls token (reset origin, calibration, fault injection): {}",
            c.http.token
        );
    }
    if !no_browser {
        open_browser(&url);
    }
    let shutdown = async move {
        app::shutdown_signal().await;
        let _ = stop_tx.send(true);
    };
    let options = app::RunOptions {
        faults: Some(faults),
        foxglove_any_port: foxglove_default && record.foxglove.is_none(),
    };
    let result = app::run_with(c, Listeners { http, zenoh }, options, shutdown)
        .await
        .map_err(|e| e.to_string());
    let _ = sim_task.await;
    let _ = sim_session.close().await;
    result
}

/// Best effort: open the dashboard where a desktop is available.
fn open_browser(url: &str) {
    let has_display =
        std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some();
    let opener = if cfg!(target_os = "macos") {
        "open"
    } else {
        "xdg-open"
    };
    if !(has_display || cfg!(target_os = "macos")) {
        return;
    }
    if let Err(e) = std::process::Command::new(opener)
        .arg(url)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
    {
        tracing::info!("could not open a browser ({opener}: {e}); open {url} yourself");
    }
}

fn add_mavlink(c: &mut Config, endpoints: &[String]) -> Result<(), String> {
    c.mavlink.endpoints.extend(endpoints.iter().cloned());
    c.validate().map_err(|e| format!("command line: {e}"))
}

/// A 128-bit random token, hex.
fn random_token() -> String {
    use rand::RngCore;
    let mut b = [0u8; 16];
    rand::rngs::OsRng.fill_bytes(&mut b);
    b.iter().map(|x| format!("{x:02x}")).collect()
}

mod discover;
mod eval;
mod monte_carlo;
mod runs;
use runs::{offline_sims, parse_window, replay, scenario_at, sim_log, SimLog};

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 35: every subcommand's help ends with an example of it.
    #[test]
    fn every_subcommand_has_an_example() {
        use clap::CommandFactory;
        let cli = Cli::command();
        for sub in cli.get_subcommands() {
            let help = sub
                .get_after_help()
                .map(|h| h.to_string())
                .unwrap_or_default();
            let name = sub.get_name();
            assert!(
                help.starts_with("Example: skyfuse ") && help.contains(&format!("skyfuse {name}")),
                "{name}: {help:?}"
            );
        }
    }

    #[test]
    fn healthcheck_asks_a_wildcard_bind_on_loopback() {
        assert_eq!(
            probe_addr("0.0.0.0:8080").unwrap().to_string(),
            "127.0.0.1:8080"
        );
        assert_eq!(probe_addr("[::]:9000").unwrap().to_string(), "[::1]:9000");
        assert_eq!(
            probe_addr("10.1.2.3:80").unwrap().to_string(),
            "10.1.2.3:80"
        );
        let e = probe_addr("dashboard:8080").unwrap_err();
        assert!(e.contains("dashboard:8080"), "{e}");
    }

    #[test]
    fn healthcheck_reads_the_status_code() {
        assert_eq!(http_status("HTTP/1.1 200 OK\r\n\r\nok\n"), Some(200));
        assert_eq!(
            http_status("HTTP/1.0 503 Service Unavailable\r\n\r\nzenoh session closed\n"),
            Some(503)
        );
        assert_eq!(http_status("SSH-2.0-OpenSSH_9.2\r\n"), None);
        assert_eq!(http_status(""), None);
    }
}
