//! Command line: `run`, `demo`, `check-config`, `sim`. Each command builds a config,
//! binds its listeners and calls into [`crate::app`] or [`crate::sim`].

use crate::app::{self, Listeners};
use crate::config::{Config, ZenohMode};
use crate::ingest::zenoh_in;
use crate::sim::{publish, sensors::DEMO_STREAMS, Simulator};
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
    Run {
        /// Config file (TOML); without it the built-in default (config/default.toml).
        #[arg(short, long, env = "SKYFUSE_CONFIG")]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
    },
    /// Run the service with the built-in simulator on loopback and open the dashboard.
    Demo {
        #[command(flatten)]
        net: NetArgs,
        /// Simulator seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Do not try to open a browser.
        #[arg(long)]
        no_browser: bool,
    },
    /// Check a config file and print what it configures.
    CheckConfig { file: PathBuf },
    /// Publish the simulator's sensor samples to Zenoh for another skyfuse instance.
    Sim {
        /// Config whose inputs name the keys and formats to publish (default: built-in).
        #[arg(short, long)]
        config: Option<PathBuf>,
        #[command(flatten)]
        net: NetArgs,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Seconds of flight to publish (default: until stopped).
        #[arg(long)]
        duration: Option<f64>,
    },
}

/// Network overrides shared by the commands.
#[derive(Debug, Args, Default)]
pub struct NetArgs {
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
        c.validate().map_err(|e| format!("command line: {e}"))
    }
}

fn env_vars() -> Vec<(String, String)> {
    std::env::vars().collect()
}

fn load(path: Option<&std::path::Path>, net: &NetArgs) -> Result<Config, String> {
    let mut c = Config::load(path, env_vars()).map_err(|e| e.to_string())?;
    net.apply(&mut c)?;
    Ok(c)
}

pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn"));
    let _ = tracing_subscriber::fmt().with_env_filter(filter).try_init();
}

/// Entry point of the binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging();
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
    match rt.block_on(dispatch(cli.command)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

async fn dispatch(cmd: Command) -> Result<(), String> {
    match cmd {
        Command::CheckConfig { file } => {
            let c = Config::load(Some(&file), env_vars()).map_err(|e| e.to_string())?;
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
        Command::Run { config, net } => {
            let c = load(config.as_deref(), &net)?;
            serve(c, app::shutdown_signal()).await
        }
        Command::Demo {
            net,
            seed,
            no_browser,
        } => demo(net, seed, no_browser).await,
        Command::Sim {
            config,
            net,
            seed,
            duration,
        } => {
            let c = load(config.as_deref(), &net)?;
            let session = zenoh_in::open_session(&c.zenoh)
                .await
                .map_err(|e| e.to_string())?;
            let sim = Simulator::new(DEMO_STREAMS, seed, duration.unwrap_or(f64::INFINITY));
            let counters = Arc::new(publish::PublishCounters::default());
            let n = publish::run_publisher(
                session.clone(),
                Arc::new(c),
                sim,
                counters,
                app::shutdown_signal(),
            )
            .await;
            tracing::info!(published = n, "sim finished");
            let _ = session.close().await;
            Ok(())
        }
    }
}

async fn serve(
    c: Config,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<(), String> {
    let http = tokio::net::TcpListener::bind(&c.http.bind)
        .await
        .map_err(|e| format!("cannot listen for HTTP on {}: {e}", c.http.bind))?;
    let zenoh = zenoh_in::open_session(&c.zenoh)
        .await
        .map_err(|e| e.to_string())?;
    app::run(c, Listeners { http, zenoh }, shutdown)
        .await
        .map_err(|e| e.to_string())
}

/// The demo: the default config on loopback only (no multicast, Zenoh on a free port),
/// plus the simulator in a second Zenoh session that connects to it, exactly as a
/// vehicle's bridges would.
async fn demo(net: NetArgs, seed: u64, no_browser: bool) -> Result<(), String> {
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
    net.apply(&mut c)?;

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

    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let sim = Simulator::new(DEMO_STREAMS, seed, f64::INFINITY);
    let counters = Arc::new(publish::PublishCounters::default());
    let mut sim_stop = stop_rx.clone();
    let sim_task = tokio::spawn(publish::run_publisher(
        sim_session.clone(),
        Arc::new(sim_cfg),
        sim,
        counters,
        async move {
            let _ = sim_stop.changed().await;
        },
    ));

    let url = format!("http://{http_addr}/");
    println!("skyfuse demo: dashboard at {url} (simulated vehicle on Zenoh {locators:?}); Ctrl-C to stop");
    if !no_browser {
        open_browser(&url);
    }
    let shutdown = async move {
        app::shutdown_signal().await;
        let _ = stop_tx.send(true);
    };
    let result = app::run(c, Listeners { http, zenoh }, shutdown)
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
