//! A ROS 2 <-> Zenoh bridge for the end-to-end tests: the crates.io `zenoh-plugin-ros2dds`
//! started as a static plugin of a Zenoh runtime, which is what upstream's
//! `zenoh-bridge-ros2dds` binary is. Only the options the tests use, with that binary's
//! names, so either program can sit behind `tests/py/ros2_bridge_check.py`:
//!
//! ```text
//! skyfuse-ros2dds-bridge [-c CONFIG] [-m router|peer|client] [-e ENDPOINT]... [-l ENDPOINT]...
//!                        [--no-multicast-scouting] [-d DOMAIN] [-n NAMESPACE] [--ros-localhost-only]
//! ```
//!
//! The DDS side follows the environment as the plugin reads it: `ROS_DISTRO` (which
//! `ros_discovery_info` layout), `ROS_DOMAIN_ID` (when `-d` is absent),
//! `CYCLONEDDS_URI`. Zenoh's log goes to stdout under `RUST_LOG` (default `info`):
//! "Zenoh can be reached at: tcp/127.0.0.1:PORT" gives the port a `-l tcp/...:0` got.
//! SIGTERM or SIGINT end it.

use clap::Parser;
use zenoh::config::Config;
use zenoh::internal::plugins::PluginsManager;
use zenoh::internal::runtime::RuntimeBuilder;
use zenoh_plugin_ros2dds::ROS2Plugin;
use zenoh_plugin_trait::Plugin;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Mode {
    Router,
    Peer,
    Client,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Router => "router",
            Mode::Peer => "peer",
            Mode::Client => "client",
        }
    }
}

#[derive(Debug, Parser)]
#[command(
    version,
    about = "Zenoh's ROS 2 / DDS plugin (crates.io) as a standalone bridge, for skyfuse's tests"
)]
struct Args {
    /// A Zenoh configuration file (JSON5); the options below override it.
    #[arg(short, long)]
    config: Option<String>,
    /// The Zenoh mode [default: router, unless the configuration file sets one].
    #[arg(short, long, value_enum)]
    mode: Option<Mode>,
    /// Endpoints to connect to (e.g. tcp/127.0.0.1:7447).
    #[arg(short = 'e', long)]
    connect: Vec<String>,
    /// Endpoints to listen on (e.g. tcp/127.0.0.1:0).
    #[arg(short, long)]
    listen: Vec<String>,
    /// Disable Zenoh's multicast scouting.
    #[arg(long)]
    no_multicast_scouting: bool,
    /// The DDS domain [default: $ROS_DOMAIN_ID, else 0].
    #[arg(short, long, env = "ROS_DOMAIN_ID")]
    domain: Option<u32>,
    /// The ROS 2 namespace of the bridge's node.
    #[arg(short, long)]
    namespace: Option<String>,
    /// CycloneDDS on the loopback interface only (also $ROS_LOCALHOST_ONLY=1).
    #[arg(long, env = "ROS_LOCALHOST_ONLY", value_parser = clap::builder::FalseyValueParser::new())]
    ros_localhost_only: bool,
}

/// `value` as JSON (a JSON5 subset), for `Config::insert_json5`.
fn json(value: impl Into<serde_json::Value>) -> String {
    value.into().to_string()
}

fn set(config: &mut Config, key: &str, value: String) -> Result<(), String> {
    config
        .insert_json5(key, &value)
        .map_err(|e| format!("config {key} = {value}: {e}"))
}

fn config(args: &Args) -> Result<Config, String> {
    let mut c = match &args.config {
        Some(path) => Config::from_file(path).map_err(|e| format!("config {path}: {e}"))?,
        None => Config::default(),
    };
    if let Some(mode) = args.mode {
        set(&mut c, "mode", json(mode.name()))?;
    } else if args.config.is_none() {
        // A file's mode stays; without a file, a router, as upstream's bridge.
        set(&mut c, "mode", json("router"))?;
    }
    if !args.connect.is_empty() {
        set(&mut c, "connect/endpoints", json(args.connect.clone()))?;
    }
    if !args.listen.is_empty() {
        set(&mut c, "listen/endpoints", json(args.listen.clone()))?;
    }
    if args.no_multicast_scouting {
        set(&mut c, "scouting/multicast/enabled", json(false))?;
    }
    // The plugin's routes for TRANSIENT_LOCAL topics cache publications, which needs
    // timestamps; remote bridges query the admin space; static plugins need loading on.
    set(&mut c, "timestamping/enabled", json(true))?;
    set(&mut c, "adminspace/enabled", json(true))?;
    set(&mut c, "plugins_loading/enabled", json(true))?;
    // The plugin does not start without its section, even an empty one.
    if c.get_json("plugins/ros2dds").is_err() {
        set(&mut c, "plugins/ros2dds", "{}".to_string())?;
    }
    if let Some(domain) = args.domain {
        set(&mut c, "plugins/ros2dds/domain", json(domain))?;
    }
    if let Some(ns) = &args.namespace {
        set(&mut c, "plugins/ros2dds/namespace", json(ns.as_str()))?;
    }
    if args.ros_localhost_only {
        set(&mut c, "plugins/ros2dds/ros_localhost_only", json(true))?;
    }
    Ok(c)
}

#[tokio::main]
async fn main() {
    zenoh::init_log_from_env_or("info");
    let args = Args::parse();
    let config = match config(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("skyfuse-ros2dds-bridge: {e}");
            std::process::exit(2);
        }
    };
    eprintln!(
        "skyfuse-ros2dds-bridge {} with zenoh-plugin-ros2dds {}",
        env!("CARGO_PKG_VERSION"),
        ROS2Plugin::PLUGIN_LONG_VERSION
    );

    let mut plugins = PluginsManager::static_plugins_only();
    plugins.declare_static_plugin::<ROS2Plugin, &str>("ros2dds", true);
    // Building the runtime starts the plugin (a failure to start a required one panics).
    let mut runtime = match RuntimeBuilder::new(config)
        .plugins_manager(plugins)
        .build()
        .await
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("skyfuse-ros2dds-bridge: cannot build the Zenoh runtime: {e}");
            std::process::exit(1);
        }
    };
    if let Err(e) = runtime.start().await {
        eprintln!("skyfuse-ros2dds-bridge: cannot start the Zenoh runtime: {e}");
        std::process::exit(1);
    }
    // Runs until a signal ends the process.
    std::future::pending::<()>().await;
}
