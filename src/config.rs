//! Configuration: one TOML file, one serde struct tree, unknown keys rejected by name.
//!
//! Every key is documented in `config/default.toml`, which is also compiled in as the
//! built-in default ([`Config::builtin_default`]). Defaults live here as named
//! constants. Environment variables override the file for container use:
//! `SKYFUSE__<SECTION>__<KEY>=value` (double underscores separate levels, array
//! elements by index: `SKYFUSE__INPUTS__0__KEY=gps/fix`); the value is read as a TOML
//! value when it parses as one (`true`, `10`, `["a","b"]`) and as a string otherwise.

use crate::codec::{Format, RosType};
use crate::sample::SensorKind;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::Path;
use thiserror::Error;

pub const DEFAULT_VEHICLE: &str = "vehicle1";
pub const DEFAULT_HTTP_BIND: &str = "0.0.0.0:8080";
pub const DEFAULT_CHANNEL_CAPACITY: usize = 4096;
pub const DEFAULT_MAV_SYSTEM_ID: u8 = 1;
/// MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY: the onboard component id we send as.
pub const DEFAULT_MAV_COMPONENT_ID: u8 = 197;
/// A sensor is stale after this many expected periods without data…
pub const STALE_PERIODS: f64 = 5.0;
/// …but never sooner than this (slow sensors jitter).
pub const STALE_MIN_MS: f64 = 250.0;
/// Errors of one input are logged at most once per this interval.
pub const ERROR_LOG_INTERVAL_MS: u64 = 5000;
pub const ENV_PREFIX: &str = "SKYFUSE__";
const REDACTED: &str = "<redacted>";

/// The built-in default configuration, the same text as `config/default.toml`.
pub const DEFAULT_TOML: &str = include_str!("../config/default.toml");

#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("environment variable {var}: {message}")]
    Env { var: String, message: String },
    #[error("{origin}: {message}")]
    Invalid { origin: String, message: String },
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    #[serde(default)]
    pub service: ServiceConfig,
    #[serde(default)]
    pub zenoh: ZenohConfig,
    #[serde(default)]
    pub http: HttpConfig,
    #[serde(default)]
    pub ingest: IngestConfig,
    #[serde(default)]
    pub mavlink: MavlinkConfig,
    #[serde(default)]
    pub inputs: Vec<InputConfig>,
    #[serde(default)]
    pub estimator: crate::estimator::EstimatorConfig,
    /// `[integrity]`: protection levels and alert limits (the estimator's; kept in
    /// `estimator.integrity` once loaded).
    #[serde(default)]
    pub integrity: crate::estimator::IntegrityConfig,
    #[serde(default)]
    pub output: OutputConfig,
    #[serde(default)]
    pub health: crate::health::HealthConfig,
    #[serde(default)]
    pub record: RecordConfig,
    #[serde(default)]
    pub foxglove: FoxgloveConfig,
    #[serde(default)]
    pub fleet: FleetConfig,
    #[serde(default)]
    pub discovery: DiscoveryConfig,
}

/// Watch every key on the network (the Network panel, `/api/v1/discovered`).
pub const DEFAULT_DISCOVERY_ENABLED: bool = true;

/// `[discovery]`: what is published on the Zenoh network, shown beside the inputs.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct DiscoveryConfig {
    /// Subscribe to every key (`**`) to list what is published, its rate and what it
    /// would be read as. Every message on the network then reaches this process: turn
    /// it off where large streams (camera images) share the network.
    pub enabled: bool,
}

impl Default for DiscoveryConfig {
    fn default() -> Self {
        Self {
            enabled: DEFAULT_DISCOVERY_ENABLED,
        }
    }
}

/// The output prefixes the fleet view watches: the default `[output] prefix`
/// (`skyfuse/{vehicle}`) under any Zenoh namespace, or none.
pub const DEFAULT_FLEET_WATCH: &str = "**/skyfuse/*";
/// A vehicle with no output for this long is shown as stale.
pub const DEFAULT_FLEET_STALE_S: f64 = 3.0;
/// A vehicle whose liveliness token is gone, or silent for this long, is shown grey.
pub const DEFAULT_FLEET_GONE_S: f64 = 10.0;
/// A grey vehicle is dropped from the fleet after this long.
pub const DEFAULT_FLEET_FORGET_S: f64 = 120.0;
/// Track points kept per vehicle (one a second at most: 10 minutes).
pub const DEFAULT_FLEET_TRACK_POINTS: usize = 600;
/// Vehicles the fleet view keeps at most (more are refused and counted): what bounds the
/// monitor's memory when anything on the network may publish under `watch`.
pub const DEFAULT_FLEET_MAX_VEHICLES: usize = 5000;

/// `[fleet]`: the fleet view (`skyfuse monitor`, and `/fleet` on every vehicle).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct FleetConfig {
    /// Key expression of the vehicles' output prefixes to watch: `<watch>/pose`,
    /// `<watch>/health`, `<watch>/events` and the liveliness token `<watch>/alive`.
    /// The default finds every skyfuse with the default `[output] prefix`, in any Zenoh
    /// namespace.
    pub watch: String,
    pub stale_after_s: f64,
    pub gone_after_s: f64,
    pub forget_after_s: f64,
    pub track_points: usize,
    pub max_vehicles: usize,
    /// Read each vehicle's once-a-second `<watch>/summary` only (true), or also its
    /// full-rate `pose` and full `health` (false: for vehicles older than the summary,
    /// at the cost of every pose of the fleet reaching this process).
    pub summary_only: bool,
}

impl Default for FleetConfig {
    fn default() -> Self {
        Self {
            watch: DEFAULT_FLEET_WATCH.into(),
            stale_after_s: DEFAULT_FLEET_STALE_S,
            gone_after_s: DEFAULT_FLEET_GONE_S,
            forget_after_s: DEFAULT_FLEET_FORGET_S,
            track_points: DEFAULT_FLEET_TRACK_POINTS,
            max_vehicles: DEFAULT_FLEET_MAX_VEHICLES,
            summary_only: true,
        }
    }
}

/// `[record]`: the MCAP flight recorder.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// Directory for the recordings; none (or empty) records nothing.
    pub dir: Option<String>,
    /// A new file when the current one reaches this size, MiB…
    pub max_file_mb: f64,
    /// …or this age, s.
    pub max_file_s: f64,
    /// Chunk size, KiB: what a killed process can lose at most (the last chunk).
    pub chunk_kb: f64,
    /// Items waiting for the recorder thread; beyond it they are dropped and counted.
    pub queue_capacity: usize,
}

pub const DEFAULT_RECORD_MAX_FILE_MB: f64 = 1024.0;
pub const DEFAULT_RECORD_MAX_FILE_S: f64 = 1800.0;
pub const DEFAULT_RECORD_CHUNK_KB: f64 = 256.0;
pub const DEFAULT_RECORD_QUEUE: usize = 16384;

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            dir: None,
            max_file_mb: DEFAULT_RECORD_MAX_FILE_MB,
            max_file_s: DEFAULT_RECORD_MAX_FILE_S,
            chunk_kb: DEFAULT_RECORD_CHUNK_KB,
            queue_capacity: DEFAULT_RECORD_QUEUE,
        }
    }
}

/// `[foxglove]`: the Foxglove WebSocket live view.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields, default)]
pub struct FoxgloveConfig {
    /// HOST:PORT of the Foxglove WebSocket server; none (or empty) runs none.
    pub bind: Option<String>,
}

impl RecordConfig {
    /// The recording directory, if recording is on.
    pub fn dir(&self) -> Option<&str> {
        non_empty(&self.dir)
    }
}

impl FoxgloveConfig {
    /// The server's address, if the live view is on.
    pub fn bind(&self) -> Option<&str> {
        non_empty(&self.bind)
    }
}

/// An optional setting that is set: present and not empty.
fn non_empty(s: &Option<String>) -> Option<&str> {
    s.as_deref().filter(|s| !s.is_empty())
}

/// `HOST:PORT` → (HOST as written, PORT); `[::1]:8765` keeps its brackets.
pub fn split_host_port(addr: &str) -> Option<(&str, u16)> {
    let (host, port) = addr.rsplit_once(':')?;
    Some((host, port.parse().ok()?))
}

/// Where `skyfuse demo` serves Foxglove (Foxglove's own default port, on loopback).
pub const DEMO_FOXGLOVE_BIND: &str = "127.0.0.1:8765";

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    pub vehicle: String,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            vehicle: DEFAULT_VEHICLE.to_string(),
        }
    }
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    Peer,
    Client,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    pub mode: ZenohMode,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub multicast_scouting: bool,
    /// Zenoh's session namespace: every key this session puts or subscribes is prefixed
    /// with it on the network (`bot1` → `bot1/gps/fix`), as zenoh-bridge-ros2dds's
    /// `namespace` does for a robot's ROS topics. Several vehicles share one Zenoh
    /// network this way without renaming their inputs.
    pub namespace: Option<String>,
    /// Optional path to a full Zenoh JSON5 config; the keys above are applied on top.
    pub config_file: Option<String>,
}

impl ZenohConfig {
    /// The namespace, if one is set (an empty string is none).
    pub fn namespace(&self) -> Option<&str> {
        non_empty(&self.namespace)
    }
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: ZenohMode::Peer,
            listen: Vec::new(),
            connect: Vec::new(),
            multicast_scouting: true,
            namespace: None,
            config_file: None,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    pub bind: String,
    /// Token for state-changing controls; empty disables them. Never shown by the API.
    pub token: String,
    /// HTTPS: the certificate chain (PEM, leaf first) and its private key; both or
    /// neither (plain HTTP).
    pub tls_cert: Option<String>,
    pub tls_key: Option<String>,
    /// Where people reach this dashboard (announced to the fleet view), e.g.
    /// `http://drone1.local:8080/`; unset: derived from `bind` and the host name.
    pub public_url: Option<String>,
}

impl HttpConfig {
    /// (certificate, key) when HTTPS is configured.
    pub fn tls(&self) -> Option<(&str, &str)> {
        Some((non_empty(&self.tls_cert)?, non_empty(&self.tls_key)?))
    }
}

impl Default for HttpConfig {
    fn default() -> Self {
        Self {
            bind: DEFAULT_HTTP_BIND.to_string(),
            token: String::new(),
            tls_cert: None,
            tls_key: None,
            public_url: None,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    /// Samples waiting while another thread holds the estimator (they are fused on the
    /// Zenoh thread that receives them otherwise).
    pub channel_capacity: usize,
    /// An input arriving faster than this many times its `rate_hz` (plus 20 Hz) has
    /// the excess shed and counted; 0 disables the limit.
    pub max_rate_factor: f64,
    /// When the first IMU input's stamps run at a steady rate other than the host's
    /// (a simulator at `--speedup 5`), the estimator runs on that clock and the
    /// MAVLink output follows its rate. Off: the host's clock always.
    pub follow_vehicle_clock: bool,
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            channel_capacity: DEFAULT_CHANNEL_CAPACITY,
            max_rate_factor: DEFAULT_MAX_RATE_FACTOR,
            follow_vehicle_clock: true,
        }
    }
}

/// Default `[ingest] max_rate_factor`: real sensors drift a few percent, bridges batch;
/// four times the configured rate is a flood.
pub const DEFAULT_MAX_RATE_FACTOR: f64 = 4.0;

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct MavlinkConfig {
    /// Our MAVLink system id (the vehicle's).
    pub system_id: u8,
    /// Our MAVLink component id; MAVLink input from (system_id, component_id) is our
    /// own output coming back through a bridge and is skipped.
    pub component_id: u8,
    /// Where VISION_POSITION_ESTIMATE goes: `udpout:HOST:PORT`, `udpin:HOST:PORT`,
    /// `tcpout:HOST:PORT`, `serial:PATH:BAUD`, each optionally with
    /// `?messages=vpe,vse,odometry` (its own pose messages).
    pub endpoints: Vec<String>,
    /// Output rate, Hz.
    pub rate_hz: f64,
    pub vision_position_estimate: bool,
    pub vision_speed_estimate: bool,
    pub odometry: bool,
    pub heartbeat: bool,
    /// Also publish raw frames on `mavlink_raw/in` (mavlink-server `zenohraw://`).
    pub zenoh_raw: bool,
    /// Also publish mavlink-server JSON on `mavlink/in` (mavlink-server `zenoh://`).
    pub zenoh_json: bool,
    /// An estimate older than this is not sent, ms.
    pub max_age_ms: f64,
    /// `[lat_deg, lon_deg, alt_m]`: send it to the autopilot as its EKF origin and home
    /// (SET_GPS_GLOBAL_ORIGIN, SET_HOME_POSITION), which a vehicle without GNSS needs
    /// before it can use VISION_POSITION_ESTIMATE. Unset: nothing is sent.
    pub ekf_origin: Option<[f64; 3]>,
    /// The autopilot's system id, the target of the origin messages.
    pub target_system: u8,
    /// MAVLink 2 signing: a file holding the 32-byte secret key (raw, or 64 hex
    /// digits), or a passphrase whose SHA-256 is the key (as MAVProxy's `signing setup`
    /// makes it). Empty: frames go unsigned. The key is never in the config, the
    /// status or the log.
    pub signing_key_file: String,
    /// With a key: refuse (and count) frames the autopilot sends back unsigned or
    /// badly signed. Off: they are taken.
    pub signing_required: bool,
}

/// PX4 wants 30–50 Hz; ArduPilot at least 4 Hz.
pub const DEFAULT_MAV_RATE_HZ: f64 = 30.0;
/// The autopilot is system 1 unless configured otherwise.
pub const DEFAULT_MAV_TARGET_SYSTEM: u8 = 1;
/// The origin messages go with every HEARTBEAT this long after start, then every
/// [`ORIGIN_RESEND_S`] (the EKF origin only: ArduPilot ignores it once set, and a home
/// moved in flight would change where RTL goes).
pub const ORIGIN_BURST_S: f64 = 10.0;
pub const ORIGIN_RESEND_S: f64 = 10.0;
/// PX4 rejects vision data older than 400 ms; stay well inside.
pub const DEFAULT_MAV_MAX_AGE_MS: f64 = 250.0;

impl Default for MavlinkConfig {
    fn default() -> Self {
        Self {
            system_id: DEFAULT_MAV_SYSTEM_ID,
            component_id: DEFAULT_MAV_COMPONENT_ID,
            endpoints: Vec::new(),
            rate_hz: DEFAULT_MAV_RATE_HZ,
            vision_position_estimate: true,
            vision_speed_estimate: false,
            odometry: false,
            heartbeat: true,
            zenoh_raw: false,
            zenoh_json: false,
            max_age_ms: DEFAULT_MAV_MAX_AGE_MS,
            ekf_origin: None,
            target_system: DEFAULT_MAV_TARGET_SYSTEM,
            signing_key_file: String::new(),
            signing_required: false,
        }
    }
}

impl MavlinkConfig {
    /// The signing key from `signing_key_file`, or `None` without one. The error names
    /// the file, never its content.
    pub fn signing_key(&self) -> Result<Option<[u8; 32]>, String> {
        if self.signing_key_file.is_empty() {
            return Ok(None);
        }
        let path = &self.signing_key_file;
        let bytes =
            std::fs::read(path).map_err(|e| format!("[mavlink] signing_key_file {path:?}: {e}"))?;
        signing_key_from(&bytes)
            .map(Some)
            .ok_or_else(|| format!("[mavlink] signing_key_file {path:?}: empty"))
    }
}

/// A key file's bytes → the key: 32 raw bytes; 64 hex digits; else a passphrase
/// (trimmed), hashed with SHA-256 as MAVProxy and pymavlink do.
pub fn signing_key_from(bytes: &[u8]) -> Option<[u8; 32]> {
    if bytes.len() == 32 {
        return bytes.try_into().ok();
    }
    let text = std::str::from_utf8(bytes).ok()?.trim();
    if text.is_empty() {
        return None;
    }
    if text.len() == 64 && text.bytes().all(|b| b.is_ascii_hexdigit()) {
        let mut key = [0u8; 32];
        for (i, k) in key.iter_mut().enumerate() {
            *k = u8::from_str_radix(text.get(2 * i..2 * i + 2)?, 16).ok()?;
        }
        return Some(key);
    }
    use sha2::Digest;
    Some(sha2::Sha256::digest(text.as_bytes()).into())
}

/// QoS part of the ROS 2 liveliness tokens skyfuse declares: keyless, reliable,
/// volatile, keep-last 10 (zenoh-bridge-ros2dds's encoding).
pub const DEFAULT_QOS: &str = ":1::0,10";

/// The `[output]` table: what goes to Zenoh.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Prefix of the JSON keys; `{vehicle}` is replaced by `service.vehicle`.
    pub prefix: String,
    /// Publish `<prefix>/pose`, `<prefix>/health`, `<prefix>/events` as JSON.
    pub json: bool,
    /// Publish ROS 2 CDR for zenoh-bridge-ros2dds.
    pub ros2: bool,
    /// geometry_msgs/PoseStamped of the fused pose.
    pub ros2_pose_key: String,
    /// The seed's debug series as geometry_msgs/PointStamped, each on its own key.
    pub ros2_debug: bool,
    /// Key prefix of the debug series (`data_fusion` gives `data_fusion/OF_sum`, ...).
    pub ros2_debug_prefix: String,
    /// frame_id in the ROS headers.
    pub ros2_frame_id: String,
    /// Largest pose rate on Zenoh (and to the recorder), Hz.
    pub pose_rate_hz: f64,
    /// Largest rate of the debug series on Zenoh, Hz: each series' newest point; 0
    /// sends each point the estimator makes.
    pub debug_rate_hz: f64,
    /// Seconds between two `<prefix>/health` messages (whole, at least 1); the summary
    /// carries its verdict every second.
    pub health_interval_s: u64,
    /// Announce the ROS 2 outputs with zenoh-bridge-ros2dds liveliness tokens, so ROS 2
    /// tools see the topics with their types, and list the bridges' topics.
    pub ros2_announce: bool,
    /// QoS part of the tokens, in the bridge's form.
    pub ros2_qos: String,
    /// ROS 2 distribution of the bridges: `humble`, or a later one (`iron`, `jazzy`,
    /// ...) whose tokens carry the REP 2011 type hash.
    pub ros_distro: String,
    /// Also publish the ROS 2 outputs as rmw_zenoh does (nodes with
    /// `RMW_IMPLEMENTATION=rmw_zenoh_cpp` read them with no bridge): on
    /// `<domain>/<topic>/<type>/<hash>` with the attachment, and skyfuse as node
    /// `/skyfuse` with a liveliness token per publisher.
    pub rmw_zenoh: bool,
    /// The ROS domain of the rmw_zenoh outputs (`ROS_DOMAIN_ID`).
    pub rmw_zenoh_domain_id: u32,
    /// Publish the fused pose as px4_msgs/VehicleOdometry where PX4's EKF2 reads
    /// external vision (`fmu/in/vehicle_visual_odometry`), valid poses only, each
    /// passing px4-ros2-interface-lib's checks.
    pub px4_odometry: bool,
    /// Its key: through zenoh-bridge-ros2dds to uXRCE-DDS, or the key PX4 1.16's zenoh
    /// module subscribes to. With `rmw_zenoh` also on its rmw_zenoh key.
    pub px4_odometry_key: String,
    /// The clock of its `timestamp_sample`: `agent` (this host's Unix time: PX4's
    /// uXRCE-DDS client converts from the agent's clock) or `px4` (PX4's boot clock, for
    /// its zenoh module, which converts nothing: from `px4_timesync_key`, else the
    /// MAVLink TIMESYNC; withheld until one is known).
    pub px4_clock: Px4Clock,
    /// With `px4_clock = "px4"`: px4_msgs/TimesyncStatus (PX4's clock minus the
    /// agent's, which runs on this host's).
    pub px4_timesync_key: String,
    /// How that key carries it (as an input's `transport`).
    pub px4_timesync_transport: RosTransport,
}

/// The clock of the VehicleOdometry `timestamp_sample` skyfuse sends PX4.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Px4Clock {
    #[default]
    Agent,
    Px4,
}

pub const DEFAULT_PX4_ODOMETRY_KEY: &str = "fmu/in/vehicle_visual_odometry";
pub const DEFAULT_PX4_TIMESYNC_KEY: &str = "fmu/out/timesync_status";

pub const DEFAULT_OUTPUT_PREFIX: &str = "skyfuse/{vehicle}";
pub const DEFAULT_POSE_KEY: &str = "data_fusion/pose_msg";
pub const DEFAULT_DEBUG_PREFIX: &str = "data_fusion";
pub const DEFAULT_ROS_FRAME_ID: &str = "map";
pub const DEFAULT_POSE_RATE_HZ: f64 = crate::rate_limit::DEFAULT_POSE_RATE_HZ;
/// Enough for rqt_plot to draw the seed's series smoothly; at 50 Hz the eight series
/// were 370 messages a second (14 KB/s), more messages than all the other outputs.
pub const DEFAULT_DEBUG_RATE_HZ: f64 = 10.0;
/// The full health is ~10 KB (every input's counters, the estimator's detail): once a
/// second it was a fifth of a vehicle's output budget, while the fleet view reads the
/// once-a-second summary and a person the status API.
pub const DEFAULT_HEALTH_INTERVAL_S: u64 = 5;

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_OUTPUT_PREFIX.into(),
            json: true,
            ros2: true,
            ros2_pose_key: DEFAULT_POSE_KEY.into(),
            ros2_debug: true,
            ros2_debug_prefix: DEFAULT_DEBUG_PREFIX.into(),
            ros2_frame_id: DEFAULT_ROS_FRAME_ID.into(),
            pose_rate_hz: DEFAULT_POSE_RATE_HZ,
            debug_rate_hz: DEFAULT_DEBUG_RATE_HZ,
            health_interval_s: DEFAULT_HEALTH_INTERVAL_S,
            ros2_announce: true,
            ros2_qos: DEFAULT_QOS.into(),
            ros_distro: "humble".into(),
            rmw_zenoh: false,
            rmw_zenoh_domain_id: 0,
            px4_odometry: false,
            px4_odometry_key: DEFAULT_PX4_ODOMETRY_KEY.into(),
            px4_clock: Px4Clock::Agent,
            px4_timesync_key: DEFAULT_PX4_TIMESYNC_KEY.into(),
            px4_timesync_transport: RosTransport::Bridge,
        }
    }
}

impl OutputConfig {
    /// The enabled ROS 2 outputs: (Zenoh key, ROS type).
    pub fn ros2_outputs(&self) -> Vec<(String, &'static str)> {
        if !self.ros2 {
            return vec![];
        }
        let mut v = vec![(self.ros2_pose_key.clone(), "geometry_msgs/msg/PoseStamped")];
        if self.ros2_debug {
            for t in crate::estimator::DebugTopic::PUBLISHED {
                v.push((
                    format!("{}/{}", self.ros2_debug_prefix, t.name()),
                    "geometry_msgs/msg/PointStamped",
                ));
            }
        }
        v
    }

    /// Every ROS 2 output a ROS graph should see: [`Self::ros2_outputs`] and the
    /// px4_msgs odometry (a bridge then creates its DDS writer, which PX4's uXRCE-DDS
    /// agent's reader matches).
    pub fn announced_outputs(&self) -> Vec<(String, &'static str)> {
        let mut v = self.ros2_outputs();
        if self.px4_odometry {
            v.push((
                self.px4_odometry_key.clone(),
                crate::codec::ros::px4::Px4Type::VehicleOdometry.ros2_name(),
            ));
        }
        v
    }

    /// The JSON key prefix with the vehicle name in place.
    pub fn prefix_for(&self, vehicle: &str) -> String {
        self.prefix
            .replace("{vehicle}", vehicle)
            .trim_end_matches('/')
            .to_string()
    }
}

fn default_true() -> bool {
    true
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InputConfig {
    /// Unique name of this sensor input (`gps`, `t265`, …).
    pub id: String,
    pub kind: SensorKind,
    /// Zenoh key expression (for `ros1`: the topic; see [`InputConfig::key_exprs`]).
    pub key: String,
    pub format: Format,
    /// ROS message type for `ros2`/`ros1` inputs.
    #[serde(rename = "type", default, skip_serializing_if = "Option::is_none")]
    pub ros_type: Option<RosType>,
    /// Expected rate, Hz: drives the staleness and rate checks.
    pub rate_hz: f64,
    #[serde(default = "default_true")]
    pub enabled: bool,
    /// `type = "auto"` (ros2 only): the type a bridge announces for the key is used.
    #[serde(skip)]
    pub auto_type: bool,
    /// ros2 only: how the topic is on Zenoh. `bridge` (zenoh-bridge-ros2dds: `key` is
    /// the topic's key), `rmw_zenoh` (nodes on ROS 2's Zenoh middleware, and PX4 ≥
    /// 1.17's zenoh module: `<domain_id>/<topic>/<type>/<hash>`, with an attachment per
    /// sample) or `px4_zenoh` (PX4 1.16's zenoh module: px4_msgs on the key its
    /// `zenoh config addpublisher` was given, XCDR2-aligned).
    #[serde(default, skip_serializing_if = "RosTransport::is_bridge")]
    pub transport: RosTransport,
    /// `transport = "rmw_zenoh"`: the ROS domain (`ROS_DOMAIN_ID`).
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub domain_id: u32,
}

/// How a ros2 input's topic reaches Zenoh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RosTransport {
    /// zenoh-bridge-ros2dds (or zenoh-plugin-ros2dds in zenohd) between DDS and Zenoh.
    #[default]
    Bridge,
    /// ROS 2 nodes started with `RMW_IMPLEMENTATION=rmw_zenoh_cpp`: no bridge.
    RmwZenoh,
    /// PX4 1.16's zenoh module: `key` verbatim, no attachment, no token, XCDR2.
    Px4Zenoh,
}

impl RosTransport {
    pub fn is_bridge(&self) -> bool {
        *self == RosTransport::Bridge
    }

    pub fn as_str(&self) -> &'static str {
        match self {
            RosTransport::Bridge => "bridge",
            RosTransport::RmwZenoh => "rmw_zenoh",
            RosTransport::Px4Zenoh => "px4_zenoh",
        }
    }
}

fn is_zero_u32(x: &u32) -> bool {
    *x == 0
}

/// ROS 2 domain ids are 0–232 (DDS ports; rmw_zenoh keeps the same range).
pub const MAX_ROS_DOMAIN_ID: u32 = 232;

impl InputConfig {
    /// The key expressions to subscribe to. zenoh-plugin-ros1 publishes on
    /// `<hex(type)>/<md5>/<namespace>/<topic>` (namespace chunk `*` by default since
    /// 2025; older releases have none), so a ROS 1 input subscribes to both shapes.
    pub fn key_exprs(&self) -> Vec<String> {
        match self.format {
            Format::Ros2 if self.transport == RosTransport::RmwZenoh => {
                vec![crate::codec::ros::rmw_zenoh::subscription_key(
                    self.domain_id,
                    &self.key,
                    self.ros_type
                        .filter(|_| !self.auto_type)
                        .map(|t| t.ros2_name()),
                )]
            }
            Format::Ros1 => {
                let topic = self.key.trim_start_matches('/');
                vec![format!("*/*/{topic}"), format!("*/*/*/{topic}")]
            }
            _ => vec![self.key.clone()],
        }
    }

    /// Time without data after which this input is stale, ms.
    pub fn stale_after_ms(&self) -> f64 {
        (STALE_PERIODS * 1000.0 / self.rate_hz).max(STALE_MIN_MS)
    }
}

/// Whether what an input's messages become is its `kind`: a ROS type, or the MAVLink
/// message its key names, gives one kind of sample, and a sample of another kind is
/// only ever ignored (an input that counts every message as ignored and reports "no
/// data"). A key that names no MAVLink message at all is a typo.
fn input_kind_matches(input: &InputConfig) -> Result<(), String> {
    let wants = input.kind;
    let gives = match input.format {
        Format::Ros2 | Format::Ros1 => input
            .ros_type
            .map(|t| (t.ros2_name().to_string(), vec![t.kind()])),
        Format::MavlinkJson | Format::MavlinkRaw => {
            let last = input.key.rsplit('/').next().unwrap_or_default();
            let is_name = last.starts_with(|c: char| c.is_ascii_uppercase())
                && last
                    .chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_');
            if !is_name {
                None
            } else {
                use crate::codec::mavlink::MessageKind;
                match crate::codec::mavlink::message_kind(last) {
                    MessageKind::Read(k) => Some((last.to_string(), k.to_vec())),
                    MessageKind::NotRead => {
                        return Err(format!(
                            "`key` {:?} names MAVLink {last}, which carries nothing skyfuse reads (its messages would all be ignored); the {} messages are {}",
                            input.key,
                            wants.as_str(),
                            crate::codec::mavlink::messages_of_kind(wants).join(", ")
                        ))
                    }
                    MessageKind::Unknown => {
                        let near = crate::codec::mavlink::closest_message(last)
                            .map(|m| format!(" (did you mean {m}?)"))
                            .unwrap_or_default();
                        return Err(format!(
                            "`key` {:?} ends in {last}, which is no MAVLink message{near}",
                            input.key
                        ));
                    }
                }
            }
        }
        Format::Json => None,
    };
    match gives {
        Some((what, k)) if !k.contains(&wants) => Err(format!(
            "{what} gives {} samples, but `kind` is \"{}\": its messages would all be ignored (set kind = \"{}\", or the {} input's message type)",
            k[0].as_str(),
            wants.as_str(),
            k[0].as_str(),
            wants.as_str()
        )),
        _ => Ok(()),
    }
}

/// The first `[[inputs]]` entry that does not parse on its own, named by number and
/// id: a serde error inside the array does not say which of the inputs it is in.
fn input_at_fault(value: &toml::Value) -> Option<String> {
    let inputs = value.get("inputs")?.as_array()?;
    inputs.iter().enumerate().find_map(|(i, input)| {
        let e = input.clone().try_into::<InputConfig>().err()?;
        let id = input
            .get("id")
            .and_then(|v| v.as_str())
            .map(|id| format!(", id = {id:?}"))
            .unwrap_or_default();
        Some(format!(
            "[[inputs]] number {} of {}{id}: {}",
            i + 1,
            inputs.len(),
            e.to_string().trim_end()
        ))
    })
}

/// A list given a single string by an environment variable: say how a list is written.
fn with_list_hint(message: String, origin: &str) -> String {
    if !(message.contains("expected a sequence") && origin.contains("with overrides")) {
        return message;
    }
    let value = message
        .split('"')
        .nth(1)
        .unwrap_or("tcp/192.168.1.10:7447")
        .to_string();
    format!(
        "{} (an environment variable gives a list as TOML: '[\"{value}\"]')",
        message.trim_end()
    )
}

impl Config {
    /// What makes this config a vehicle that fuses nothing, or tunes what is not there
    /// (issue 35, item 5): no input enabled (a config's `[[inputs]]` replace the
    /// built-in ones entirely), and `[estimator.sources.ID]` tables that name no input
    /// (a typo falls back to the defaults without a word). Offline runs name their
    /// sources after the log, so only the service asks.
    pub fn vehicle_problems(&self) -> (Vec<String>, Vec<String>) {
        let ids: Vec<&str> = self.inputs.iter().map(|i| i.id.as_str()).collect();
        let typos = self
            .estimator
            .sources
            .keys()
            .filter(|k| !ids.contains(&k.as_str()))
            .map(|k| {
                format!(
                    "[estimator.sources.{k}] names no input (the inputs: {})",
                    if ids.is_empty() {
                        "none".to_string()
                    } else {
                        ids.join(", ")
                    }
                )
            })
            .collect();
        let empty = if self.inputs.iter().any(|i| i.enabled) {
            vec![]
        } else {
            vec![format!(
                "no input is enabled ({} configured): a config's [[inputs]] replace the built-in ones entirely; copy those you want from config/default.toml",
                self.inputs.len()
            )]
        };
        (typos, empty)
    }

    /// The compiled-in default (identical to `config/default.toml`).
    pub fn builtin_default() -> Result<Config, ConfigError> {
        Self::from_toml_str(DEFAULT_TOML, "built-in default config")
    }

    /// Parse and validate TOML text. `origin` names the source in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Config, ConfigError> {
        let value: toml::Value = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?;
        Self::from_value(value, origin)
    }

    fn from_value(mut value: toml::Value, origin: &str) -> Result<Config, ConfigError> {
        // `type = "auto"` is not a ROS type: take it out before the typed parse.
        let mut auto = Vec::new();
        if let Some(inputs) = value.get_mut("inputs").and_then(|v| v.as_array_mut()) {
            for (i, input) in inputs.iter_mut().enumerate() {
                if let Some(t) = input.as_table_mut() {
                    if t.get("type").and_then(|v| v.as_str()) == Some("auto") {
                        t.remove("type");
                        auto.push(i);
                    }
                }
            }
        }
        let mut cfg: Config =
            value
                .clone()
                .try_into()
                .map_err(|e: toml::de::Error| ConfigError::Parse {
                    origin: origin.to_string(),
                    message: input_at_fault(&value)
                        .unwrap_or_else(|| with_list_hint(e.to_string(), origin)),
                })?;
        for i in auto {
            if let Some(input) = cfg.inputs.get_mut(i) {
                input.auto_type = true;
            }
        }
        cfg.estimator.integrity = cfg.integrity.clone();
        cfg.validate().map_err(|message| ConfigError::Invalid {
            origin: origin.to_string(),
            message,
        })?;
        Ok(cfg)
    }

    /// Load a file (or the built-in default when `path` is `None`), then apply
    /// environment overrides from `env`.
    pub fn load(
        path: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Config, ConfigError> {
        let (text, origin) = match path {
            Some(p) => (
                std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.display().to_string(),
                    source,
                })?,
                p.display().to_string(),
            ),
            None => (
                DEFAULT_TOML.to_string(),
                "built-in default config".to_string(),
            ),
        };
        let mut value: toml::Value = toml::from_str(&text).map_err(|e| ConfigError::Parse {
            origin: origin.clone(),
            message: e.to_string(),
        })?;
        let mut overridden = Vec::new();
        for (var, raw) in env {
            let Some(path) = var.strip_prefix(ENV_PREFIX) else {
                continue;
            };
            apply_env_override(&mut value, path, &raw).map_err(|message| ConfigError::Env {
                var: var.clone(),
                message,
            })?;
            overridden.push(var);
        }
        let origin = if overridden.is_empty() {
            origin
        } else {
            format!("{origin} with overrides {}", overridden.join(", "))
        };
        Self::from_value(value, &origin)
    }

    /// Cross-field checks serde cannot express.
    pub fn validate(&self) -> Result<(), String> {
        if self.mavlink.signing_required && self.mavlink.signing_key_file.is_empty() {
            return Err(
                "[mavlink] signing_required needs signing_key_file (the key to check with)".into(),
            );
        }
        self.mavlink.signing_key()?;
        if non_empty(&self.http.tls_cert).is_some() != non_empty(&self.http.tls_key).is_some() {
            return Err("[http] tls_cert and tls_key go together (HTTPS needs both)".into());
        }
        let (r, f) = (&self.record, &self.fleet);
        for (section, name, v) in [
            ("record", "max_file_mb", r.max_file_mb),
            ("record", "max_file_s", r.max_file_s),
            ("record", "chunk_kb", r.chunk_kb),
            ("fleet", "stale_after_s", f.stale_after_s),
            ("fleet", "gone_after_s", f.gone_after_s),
            ("fleet", "forget_after_s", f.forget_after_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "[{section}] {name} must be a positive number, not {v}"
                ));
            }
        }
        if let Some(b) = self.foxglove.bind() {
            if split_host_port(b).is_none() {
                return Err(format!("[foxglove] bind {b:?} is not HOST:PORT"));
            }
        }
        if let Some(ns) = self.zenoh.namespace() {
            let ok = zenoh::key_expr::KeyExpr::try_from(ns)
                .is_ok_and(|k| !k.as_str().contains('*') && !k.as_str().starts_with('@'));
            if !ok {
                return Err(format!(
                    "[zenoh] namespace {ns:?} must be a key expression without wildcards, e.g. \"bot1\""
                ));
            }
        }
        if let Err(e) = zenoh::key_expr::KeyExpr::try_from(f.watch.as_str()) {
            return Err(format!(
                "[fleet] watch {:?} is not a valid Zenoh key expression: {e}",
                f.watch
            ));
        }
        if f.max_vehicles == 0 {
            return Err("[fleet] max_vehicles must be at least 1".into());
        }
        if !(f.stale_after_s <= f.gone_after_s && f.gone_after_s <= f.forget_after_s) {
            return Err("[fleet] needs stale_after_s <= gone_after_s <= forget_after_s".into());
        }
        let mut ids = HashSet::new();
        for (i, input) in self.inputs.iter().enumerate() {
            let name = if input.id.is_empty() {
                format!("inputs[{i}]")
            } else {
                format!("input `{}`", input.id)
            };
            if input.id.is_empty() {
                return Err(format!("{name}: `id` must not be empty"));
            }
            if !ids.insert(input.id.as_str()) {
                return Err(format!("{name}: duplicate input id"));
            }
            if input.key.trim().is_empty() {
                return Err(format!("{name}: `key` must not be empty"));
            }
            for k in input.key_exprs() {
                if let Err(e) = zenoh::key_expr::KeyExpr::try_from(k.as_str()) {
                    return Err(format!(
                        "{name}: `key` {k:?} is not a valid Zenoh key expression: {e}"
                    ));
                }
            }
            if input.transport != RosTransport::Bridge && input.format != Format::Ros2 {
                return Err(format!(
                    "{name}: `transport = \"{}\"` works for ros2 inputs only",
                    input.transport.as_str()
                ));
            }
            if input.transport == RosTransport::Px4Zenoh
                && (input.auto_type || input.ros_type.and_then(|t| t.px4()).is_none())
            {
                return Err(format!(
                    "{name}: `transport = \"px4_zenoh\"` needs a px4_msgs `type` (PX4 1.16's zenoh module announces none), such as \"px4_msgs/msg/SensorCombined\""
                ));
            }
            if input.format == Format::Ros1 && input.ros_type.and_then(|t| t.px4()).is_some() {
                return Err(format!(
                    "{name}: px4_msgs are ROS 2 only: use format = \"ros2\""
                ));
            }
            if input.domain_id > MAX_ROS_DOMAIN_ID {
                return Err(format!(
                    "{name}: `domain_id` = {} must be in 0..={MAX_ROS_DOMAIN_ID}",
                    input.domain_id
                ));
            }
            if input.domain_id != 0 && input.transport != RosTransport::RmwZenoh {
                return Err(format!(
                    "{name}: `domain_id` is only meaningful with `transport = \"rmw_zenoh\"` (a bridge keeps the domain on its side)"
                ));
            }
            if input.auto_type && input.format != Format::Ros2 {
                return Err(format!(
                    "{name}: `type = \"auto\"` works for ros2 inputs only (bridges announce ROS 2 types)"
                ));
            }
            if input.format.needs_ros_type() && input.ros_type.is_none() && !input.auto_type {
                return Err(format!(
                    "{name}: format `{}` needs `type` (a ROS message type such as \"sensor_msgs/msg/NavSatFix\")",
                    input.format
                ));
            }
            if !input.format.needs_ros_type() && input.ros_type.is_some() {
                return Err(format!(
                    "{name}: `type` is only meaningful for ros2/ros1 inputs, not `{}`",
                    input.format
                ));
            }
            input_kind_matches(input).map_err(|e| format!("{name}: {e}"))?;
            if !(input.rate_hz.is_finite() && input.rate_hz > 0.0 && input.rate_hz <= 10_000.0) {
                return Err(format!(
                    "{name}: `rate_hz` = {} must be in (0, 10000]",
                    input.rate_hz
                ));
            }
        }
        self.estimator
            .validate()
            .map_err(|e| format!("estimator: {e}"))?;
        self.integrity.validate()?;
        self.health.validate()?;
        for e in &self.mavlink.endpoints {
            Endpoint::parse_with_messages(e).map_err(|m| format!("mavlink.endpoints: {m}"))?;
        }
        if !(self.mavlink.rate_hz.is_finite()
            && self.mavlink.rate_hz >= 1.0
            && self.mavlink.rate_hz <= 200.0)
        {
            return Err(format!(
                "mavlink.rate_hz = {} must be in [1, 200]",
                self.mavlink.rate_hz
            ));
        }
        if !(self.mavlink.max_age_ms.is_finite() && self.mavlink.max_age_ms > 0.0) {
            return Err(format!(
                "mavlink.max_age_ms = {} must be positive",
                self.mavlink.max_age_ms
            ));
        }
        let pose_rate = self.output.pose_rate_hz;
        if !(pose_rate.is_finite() && pose_rate > 0.0) {
            return Err(format!(
                "output.pose_rate_hz = {pose_rate} must be positive"
            ));
        }
        let debug_rate = self.output.debug_rate_hz;
        if !(debug_rate.is_finite() && debug_rate >= 0.0) {
            return Err(format!(
                "output.debug_rate_hz = {debug_rate} must be positive, or 0 for every point"
            ));
        }
        if self.output.health_interval_s == 0 {
            return Err("output.health_interval_s = 0 must be at least 1".into());
        }
        for (name, key) in [
            (
                "output.prefix",
                self.output.prefix_for(&self.service.vehicle) + "/pose",
            ),
            ("output.ros2_pose_key", self.output.ros2_pose_key.clone()),
            (
                "output.px4_odometry_key",
                self.output.px4_odometry_key.clone(),
            ),
            // A ROS topic (a leading slash) or a key: subscribed to without the slash.
            (
                "output.px4_timesync_key",
                self.output
                    .px4_timesync_key
                    .trim_start_matches('/')
                    .to_string(),
            ),
            (
                "output.ros2_debug_prefix",
                format!("{}/OF_sum", self.output.ros2_debug_prefix),
            ),
        ] {
            if let Err(e) = zenoh::key_expr::KeyExpr::try_from(key.as_str()) {
                return Err(format!("{name}: {key:?} is not a valid Zenoh key: {e}"));
            }
            if key.contains('*') || key.contains('$') {
                return Err(format!("{name}: {key:?} must not contain wildcards"));
            }
        }
        if self.ingest.channel_capacity == 0 {
            return Err("ingest.channel_capacity must be at least 1".into());
        }
        let f = self.ingest.max_rate_factor;
        if !(f.is_finite() && (f == 0.0 || f >= 1.0)) {
            return Err(format!(
                "ingest.max_rate_factor = {f} must be 0 (no limit) or at least 1"
            ));
        }
        if self.http.bind.parse::<std::net::SocketAddr>().is_err() {
            return Err(format!(
                "http.bind = {:?} is not an address such as 0.0.0.0:8080",
                self.http.bind
            ));
        }
        for e in self.zenoh.listen.iter().chain(&self.zenoh.connect) {
            if !e.contains('/') {
                return Err(format!(
                    "zenoh endpoint {e:?} is not of the form proto/address, e.g. tcp/192.168.1.10:7447"
                ));
            }
        }
        Ok(())
    }

    /// The configuration as JSON with secrets replaced, for `GET /api/v1/config`.
    pub fn redacted_json(&self) -> serde_json::Value {
        let mut c = self.clone();
        if !c.http.token.is_empty() {
            c.http.token = REDACTED.to_string();
        }
        serde_json::to_value(&c).unwrap_or(serde_json::Value::Null)
    }
}

/// Apply one `SKYFUSE__A__B=value` override to the TOML tree.
fn apply_env_override(root: &mut toml::Value, path: &str, raw: &str) -> Result<(), String> {
    let parts: Vec<String> = path.split("__").map(|s| s.to_ascii_lowercase()).collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err("empty key segment (use double underscores between levels)".into());
    }
    let new_value = parse_env_value(raw);
    let mut cur = root;
    for (i, part) in parts.iter().enumerate() {
        let last = i + 1 == parts.len();
        match cur {
            toml::Value::Table(t) => {
                if last {
                    t.insert(part.clone(), new_value);
                    return Ok(());
                }
                // Missing sections are created; unknown names are rejected later by
                // deny_unknown_fields, naming the key.
                cur = t
                    .entry(part.clone())
                    .or_insert_with(|| toml::Value::Table(Default::default()));
            }
            toml::Value::Array(a) => {
                let idx: usize = part
                    .parse()
                    .map_err(|_| format!("`{part}` is not an array index"))?;
                let len = a.len();
                let slot = a
                    .get_mut(idx)
                    .ok_or_else(|| format!("index {idx} is past the end (length {len})"))?;
                if last {
                    *slot = new_value;
                    return Ok(());
                }
                cur = slot;
            }
            _ => return Err(format!("`{part}` is below a value that is not a table")),
        }
    }
    Ok(())
}

fn parse_env_value(raw: &str) -> toml::Value {
    // Parse as a TOML value by wrapping it in a one-key document.
    match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(raw.into())),
        Err(_) => toml::Value::String(raw.to_string()),
    }
}

/// Which pose messages go to the autopilot (all of `[mavlink]`'s, or one endpoint's
/// `?messages=`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageSet {
    pub vision_position_estimate: bool,
    pub vision_speed_estimate: bool,
    pub odometry: bool,
}

impl MessageSet {
    /// Whether a message of this id goes; messages other than the pose's always do.
    pub fn passes(&self, msg_id: u32) -> bool {
        use mavlink::dialects::common::{
            ODOMETRY_DATA, VISION_POSITION_ESTIMATE_DATA, VISION_SPEED_ESTIMATE_DATA,
        };
        use mavlink::MessageData;
        match msg_id {
            VISION_POSITION_ESTIMATE_DATA::ID => self.vision_position_estimate,
            VISION_SPEED_ESTIMATE_DATA::ID => self.vision_speed_estimate,
            ODOMETRY_DATA::ID => self.odometry,
            _ => true,
        }
    }

    pub fn union(self, other: MessageSet) -> MessageSet {
        MessageSet {
            vision_position_estimate: self.vision_position_estimate
                || other.vision_position_estimate,
            vision_speed_estimate: self.vision_speed_estimate || other.vision_speed_estimate,
            odometry: self.odometry || other.odometry,
        }
    }

    /// `vpe,odometry` (also the messages' full names, any case).
    fn parse(list: &str, whole: &str) -> Result<MessageSet, String> {
        let mut set = MessageSet {
            vision_position_estimate: false,
            vision_speed_estimate: false,
            odometry: false,
        };
        for item in list.split(',').map(str::trim) {
            match item.to_ascii_lowercase().as_str() {
                "vpe" | "vision_position_estimate" => set.vision_position_estimate = true,
                "vse" | "vision_speed_estimate" => set.vision_speed_estimate = true,
                "odometry" => set.odometry = true,
                other => {
                    return Err(format!(
                        "MAVLink endpoint {whole:?}: unknown message {other:?} in messages= (vpe, vse, odometry)"
                    ))
                }
            }
        }
        Ok(set)
    }
}

/// Where MAVLink goes, parsed from the address strings users know from MAVProxy and
/// mavlink-router.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// Send to HOST:PORT (the autopilot or a router listens there).
    UdpOut(String),
    /// Listen on ADDR:PORT; send to whoever last sent us a datagram.
    UdpIn(String),
    /// Connect to HOST:PORT (SITL's TCP port, mavlink-router's TCP server).
    TcpOut(String),
    /// A serial device at a baud rate.
    Serial { path: String, baud: u32 },
}

impl Endpoint {
    /// An endpoint with its own choice of pose messages:
    /// `udpout:HOST:PORT?messages=odometry` (`vpe`, `vse`, `odometry`, comma-separated);
    /// without `?messages=` the `[mavlink]` booleans choose.
    pub fn parse_with_messages(s: &str) -> Result<(Endpoint, Option<MessageSet>), String> {
        let Some((addr, query)) = s.split_once('?') else {
            return Ok((Endpoint::parse(s)?, None));
        };
        let ep = Endpoint::parse(addr)?;
        let list = query.strip_prefix("messages=").ok_or_else(|| {
            format!("MAVLink endpoint {s:?}: after `?` only messages=LIST (vpe, vse, odometry)")
        })?;
        Ok((ep, Some(MessageSet::parse(list, s)?)))
    }

    pub fn parse(s: &str) -> Result<Endpoint, String> {
        let (scheme, rest) = s.split_once(':').ok_or_else(|| {
            format!("MAVLink endpoint {s:?}: expected udpout:HOST:PORT, udpin:HOST:PORT, tcpout:HOST:PORT or serial:PATH:BAUD")
        })?;
        let host_port = |rest: &str| -> Result<String, String> {
            let (host, port) = rest
                .rsplit_once(':')
                .ok_or_else(|| format!("MAVLink endpoint {s:?}: missing :PORT"))?;
            if host.is_empty() {
                return Err(format!("MAVLink endpoint {s:?}: missing host"));
            }
            port.parse::<u16>().map_err(|_| {
                format!("MAVLink endpoint {s:?}: port {port:?} is not a number 0-65535")
            })?;
            Ok(rest.to_string())
        };
        match scheme {
            "udpout" => Ok(Endpoint::UdpOut(host_port(rest)?)),
            // pymavlink and MAVProxy read `udp:` as listen, MAVSDK and QGC as send: a
            // guess either way loses the link without a word.
            "udp" => Err(format!(
                "MAVLink endpoint {s:?}: `udp:` means listen to pymavlink and MAVProxy but send to others; write udpin:{rest} to listen or udpout:{rest} to send"
            )),
            "udpin" => Ok(Endpoint::UdpIn(host_port(rest)?)),
            "tcpout" | "tcp" => Ok(Endpoint::TcpOut(host_port(rest)?)),
            "serial" => {
                let (path, baud) = rest
                    .rsplit_once(':')
                    .ok_or_else(|| format!("MAVLink endpoint {s:?}: expected serial:PATH:BAUD"))?;
                let baud = baud.parse::<u32>().map_err(|_| {
                    format!("MAVLink endpoint {s:?}: baud {baud:?} is not a number")
                })?;
                if path.is_empty() {
                    return Err(format!("MAVLink endpoint {s:?}: missing device path"));
                }
                Ok(Endpoint::Serial {
                    path: path.to_string(),
                    baud,
                })
            }
            other => Err(format!(
                "MAVLink endpoint {s:?}: unknown scheme {other:?} (udpout, udpin, tcpout, serial)"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn px4_msgs_inputs_and_the_px4_odometry_output_are_checked() {
        let input = |kind: &str, extra: &str| {
            Config::from_toml_str(
                &format!("[[inputs]]\nid = \"imu\"\nkind = \"{kind}\"\nkey = \"fmu/out/sensor_combined\"\nrate_hz = 200.0\n{extra}"),
                "t.toml",
            )
        };
        let c = input(
            "imu",
            "format = \"ros2\"\ntype = \"px4_msgs/msg/SensorCombined\"\ntransport = \"px4_zenoh\"\n",
        )
        .expect("config");
        // PX4 1.16's module publishes on the key it was given, verbatim.
        assert_eq!(c.inputs[0].key_exprs(), vec!["fmu/out/sensor_combined"]);
        let c = input(
            "imu",
            "format = \"ros2\"\ntype = \"px4_msgs/msg/SensorCombined\"\ntransport = \"rmw_zenoh\"\n",
        )
        .expect("config");
        assert_eq!(
            c.inputs[0].key_exprs(),
            vec!["0/fmu/out/sensor_combined/px4_msgs::msg::dds_::SensorCombined_/*"]
        );
        for (kind, extra, says) in [
            (
                "imu",
                "format = \"ros2\"\ntype = \"auto\"\ntransport = \"px4_zenoh\"\n",
                "needs a px4_msgs `type`",
            ),
            (
                "imu",
                "format = \"ros2\"\ntype = \"sensor_msgs/msg/Imu\"\ntransport = \"px4_zenoh\"\n",
                "needs a px4_msgs `type`",
            ),
            (
                "imu",
                "format = \"ros1\"\ntype = \"px4_msgs/msg/SensorCombined\"\n",
                "ROS 2 only",
            ),
            (
                "gnss",
                "format = \"ros2\"\ntype = \"px4_msgs/msg/SensorCombined\"\n",
                "gives imu samples",
            ),
            // A clock, not a sensor: the odometry output reads it.
            (
                "imu",
                "format = \"ros2\"\ntype = \"px4_msgs/msg/TimesyncStatus\"\n",
                "unknown ROS message type",
            ),
        ] {
            let e = input(kind, extra).expect_err(extra).to_string();
            assert!(e.contains(says), "{extra}: {e}");
        }
        // The output: a ROS topic for the TimesyncStatus key, an unknown clock refused.
        let c = Config::from_toml_str(
            "[output]\npx4_odometry = true\npx4_clock = \"px4\"\npx4_timesync_key = \"/fmu/out/timesync_status\"\npx4_timesync_transport = \"rmw_zenoh\"\n",
            "t.toml",
        )
        .expect("config");
        assert_eq!(c.output.px4_clock, Px4Clock::Px4);
        let e = Config::from_toml_str("[output]\npx4_clock = \"gps\"\n", "t.toml")
            .expect_err("unknown clock")
            .to_string();
        assert!(e.contains("px4_clock") || e.contains("agent"), "{e}");
    }

    #[test]
    fn rmw_zenoh_inputs_subscribe_to_its_keys_and_bad_settings_are_named() {
        let input = |extra: &str| {
            Config::from_toml_str(
                &format!("[[inputs]]\nid = \"imu\"\nkind = \"imu\"\nkey = \"imu/data\"\nrate_hz = 100.0\n{extra}"),
                "t.toml",
            )
        };
        let c =
            input("format = \"ros2\"\ntype = \"auto\"\ntransport = \"rmw_zenoh\"\ndomain_id = 7\n")
                .expect("config");
        assert_eq!(c.inputs[0].key_exprs(), vec!["7/imu/data/*/*".to_string()]);
        let c =
            input("format = \"ros2\"\ntype = \"sensor_msgs/msg/Imu\"\ntransport = \"rmw_zenoh\"\n")
                .expect("config");
        assert_eq!(
            c.inputs[0].key_exprs(),
            vec!["0/imu/data/sensor_msgs::msg::dds_::Imu_/*".to_string()]
        );
        for (extra, says) in [
            (
                "format = \"json\"\ntransport = \"rmw_zenoh\"\n",
                "ros2 inputs only",
            ),
            (
                "format = \"ros2\"\ntype = \"auto\"\ntransport = \"rmw_zenoh\"\ndomain_id = 300\n",
                "0..=232",
            ),
            (
                "format = \"ros2\"\ntype = \"auto\"\ndomain_id = 3\n",
                "only meaningful",
            ),
            (
                "format = \"ros2\"\ntype = \"auto\"\ntransport = \"dds\"\n",
                "transport",
            ),
        ] {
            let e = input(extra).expect_err(extra).to_string();
            assert!(e.contains(says), "{extra}: {e}");
        }
    }

    #[test]
    fn an_endpoint_chooses_its_own_messages() {
        let (ep, set) =
            Endpoint::parse_with_messages("udpout:127.0.0.1:14540?messages=odometry").unwrap();
        assert_eq!(ep, Endpoint::UdpOut("127.0.0.1:14540".into()));
        let set = set.unwrap();
        assert!(set.odometry && !set.vision_position_estimate && !set.vision_speed_estimate);
        assert!(set.passes(0) && set.passes(331) && !set.passes(102));
        let (_, set) =
            Endpoint::parse_with_messages("serial:/dev/ttyUSB0:921600?messages=VPE, vse").unwrap();
        let set = set.unwrap();
        assert!(set.vision_position_estimate && set.vision_speed_estimate && !set.odometry);
        assert_eq!(
            Endpoint::parse_with_messages("tcpout:h:5760").unwrap().1,
            None
        );
        for (bad, says) in [
            ("udpout:h:1?messages=pose", "unknown message \"pose\""),
            ("udpout:h:1?messages=", "unknown message \"\""),
            ("udpout:h:1?rate=10", "only messages=LIST"),
            ("udpout:h?messages=vpe", "missing :PORT"),
        ] {
            let e = Endpoint::parse_with_messages(bad).expect_err(bad);
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn endpoint_strings() {
        assert_eq!(
            Endpoint::parse("udpout:127.0.0.1:14540"),
            Ok(Endpoint::UdpOut("127.0.0.1:14540".into()))
        );
        assert_eq!(
            Endpoint::parse("udpin:0.0.0.0:14550"),
            Ok(Endpoint::UdpIn("0.0.0.0:14550".into()))
        );
        assert_eq!(
            Endpoint::parse("tcpout:px4.local:5760"),
            Ok(Endpoint::TcpOut("px4.local:5760".into()))
        );
        assert_eq!(
            Endpoint::parse("serial:/dev/ttyACM0:921600"),
            Ok(Endpoint::Serial {
                path: "/dev/ttyACM0".into(),
                baud: 921_600
            })
        );
        let e = Endpoint::parse("udp:127.0.0.1:14550").expect_err("ambiguous");
        assert!(
            e.contains("udpin:127.0.0.1:14550") && e.contains("udpout:127.0.0.1:14550"),
            "{e}"
        );
        for bad in [
            "udpout:1.2.3.4",
            "udpout::14540",
            "udpout:host:99999",
            "ftp:host:1",
            "serial:/dev/ttyS0:fast",
            "nothing",
        ] {
            let e = Endpoint::parse(bad).expect_err(bad);
            assert!(e.contains(bad), "{e}");
        }
    }

    fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    }

    #[test]
    fn default_file_parses_and_has_the_seed_topics() {
        let c = Config::builtin_default().expect("default config");
        let keys: Vec<&str> = c.inputs.iter().map(|i| i.key.as_str()).collect();
        for k in ["gps/fix", "camera/odom/sample", "mavros/imu/data"] {
            assert!(keys.contains(&k), "default config lacks {k}: {keys:?}");
        }
        assert!(keys.iter().any(|k| k.starts_with("mavlink/")));
        assert_eq!(c.mavlink.component_id, 197);
    }

    /// Issue 35, item 4: an input whose message type gives another kind of sample than
    /// its `kind` (every message would be ignored, the input "no data" forever) or whose
    /// key names no MAVLink message is refused by check-config, saying what to change.
    #[test]
    fn an_input_whose_messages_are_not_its_kind_is_refused() {
        let input = |kind: &str, key: &str, format: &str, ty: &str| {
            format!(
                "[[inputs]]\nid = \"x\"\nkind = \"{kind}\"\nkey = \"{key}\"\nformat = \"{format}\"\n{ty}rate_hz = 10\n"
            )
        };
        let refused = |toml: String, says: &[&str]| {
            let e = Config::from_toml_str(&toml, "t.toml")
                .unwrap_err()
                .to_string();
            for s in says {
                assert!(e.contains(s), "{e}");
            }
        };
        refused(
            input(
                "imu",
                "gps/fix",
                "ros2",
                "type = \"sensor_msgs/msg/NavSatFix\"\n",
            ),
            &[
                "input `x`",
                "NavSatFix gives gnss samples",
                "kind = \"gnss\"",
            ],
        );
        refused(
            input(
                "attitude",
                "mavlink/*/*/ATTITUDE_QUATERNON",
                "mavlink-json",
                "",
            ),
            &["no MAVLink message", "did you mean ATTITUDE_QUATERNION?"],
        );
        refused(
            input("attitude", "mavlink/*/*/SYS_STATUS", "mavlink-json", ""),
            &[
                "carries nothing skyfuse reads",
                "ATTITUDE, ATTITUDE_QUATERNION",
            ],
        );
        refused(
            input("baro", "mavlink/*/*/ATTITUDE", "mavlink-json", ""),
            &["ATTITUDE gives attitude samples"],
        );
        // What matches is accepted; a wildcard or a raw stream key names no message.
        for ok in [
            input(
                "gnss",
                "gps/fix",
                "ros2",
                "type = \"sensor_msgs/msg/NavSatFix\"\n",
            ),
            input("baro", "mavlink/*/*/SCALED_PRESSURE2", "mavlink-json", ""),
            // HIGHRES_IMU carries PX4's barometer beside the IMU.
            input("baro", "mavlink/*/*/HIGHRES_IMU", "mavlink-json", ""),
            input("imu", "mavlink/*/*/HIGHRES_IMU", "mavlink-json", ""),
            input("imu", "mavlink/**", "mavlink-json", ""),
            input("flow", "mavlink_raw/out", "mavlink-raw", ""),
        ] {
            Config::from_toml_str(&ok, "t.toml").unwrap_or_else(|e| panic!("{ok}: {e}"));
        }
    }

    /// Issue 35, item 5: a config with no input (its `[[inputs]]` replace the built-in
    /// ones) and an `[estimator.sources.ID]` naming no input are what check-config and
    /// `run` report, not "ok (0 inputs)".
    #[test]
    fn a_vehicle_with_no_input_or_a_misspelt_source_is_reported() {
        let only_service = Config::from_toml_str("[service]\n", "t.toml").expect("parses");
        let (typos, empty) = only_service.vehicle_problems();
        assert!(typos.is_empty());
        assert!(empty[0].contains("replace the built-in ones"), "{empty:?}");
        let mut c = Config::builtin_default().expect("default");
        assert_eq!(c.vehicle_problems(), (vec![], vec![]));
        c.estimator
            .sources
            .insert("t256".into(), Default::default());
        let (typos, _) = c.vehicle_problems();
        assert!(
            typos[0].contains("[estimator.sources.t256] names no input")
                && typos[0].contains("t265"),
            "{typos:?}"
        );
    }

    /// Issue 35, item 8: a list set from the environment with a bare string says how a
    /// list is written there.
    #[test]
    fn an_environment_list_given_a_string_says_how_to_write_one() {
        let err = Config::load(
            None,
            env(&[("SKYFUSE__ZENOH__CONNECT", "tcp/127.0.0.1:7447")]),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("SKYFUSE__ZENOH__CONNECT") && err.contains("'[\"tcp/127.0.0.1:7447\"]'"),
            "{err}"
        );
        let ok = Config::load(
            None,
            env(&[("SKYFUSE__ZENOH__CONNECT", "[\"tcp/127.0.0.1:7447\"]")]),
        );
        assert!(ok.is_ok(), "{ok:?}");
    }

    #[test]
    fn unknown_key_is_named() {
        let err = Config::from_toml_str("[zenoh]\nmode = \"peer\"\nlisten_to = []\n", "test.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("listen_to"), "{err}");
        assert!(err.contains("test.toml"), "{err}");
        let err = Config::from_toml_str(
            "[[inputs]]\nid=\"a\"\nkind=\"imu\"\nkey=\"k\"\nformat=\"json\"\nrate_hz=1\nrat_hz=2\n",
            "t",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("rat_hz"), "{err}");
        // Which input (issue 35, item 8): the second of two, by number and id.
        let two = "[[inputs]]\nid=\"a\"\nkind=\"imu\"\nkey=\"k\"\nformat=\"json\"\nrate_hz=1\n\
                   [[inputs]]\nid=\"b\"\nkind=\"imu\"\nkey=\"k2\"\nformat=\"json\"\nrat_hz=2\n";
        let err = Config::from_toml_str(two, "t").unwrap_err().to_string();
        assert!(
            err.contains("[[inputs]] number 2 of 2, id = \"b\"") && err.contains("rat_hz"),
            "{err}"
        );
    }

    #[test]
    fn ros_input_without_type_is_rejected() {
        let err = Config::from_toml_str(
            "[[inputs]]\nid=\"gps\"\nkind=\"gnss\"\nkey=\"gps/fix\"\nformat=\"ros2\"\nrate_hz=10\n",
            "t",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("input `gps`") && err.contains("type"), "{err}");
    }

    #[test]
    fn output_rates_must_be_positive_and_finite() {
        for (key, value) in [
            ("pose_rate_hz", "0.0"),
            ("debug_rate_hz", "nan"),
            ("debug_rate_hz", "-1.0"),
        ] {
            let err = Config::from_toml_str(&format!("[output]\n{key} = {value}\n"), "t")
                .unwrap_err()
                .to_string();
            assert!(err.contains(&format!("output.{key}")), "{err}");
        }
        let ok = Config::from_toml_str("[output]\ndebug_rate_hz = 25.0\n", "t").unwrap();
        assert_eq!(ok.output.debug_rate_hz, 25.0);
        // 0: every point.
        let every = Config::from_toml_str("[output]\ndebug_rate_hz = 0\n", "t").unwrap();
        assert_eq!(every.output.debug_rate_hz, 0.0);
        let err = Config::from_toml_str("[output]\nhealth_interval_s = 0\n", "t")
            .unwrap_err()
            .to_string();
        assert!(err.contains("output.health_interval_s"), "{err}");
    }

    #[test]
    fn bad_key_expression_and_duplicate_ids_are_rejected() {
        let base = "[[inputs]]\nid=\"a\"\nkind=\"imu\"\nformat=\"json\"\nrate_hz=1\n";
        let err = Config::from_toml_str(&format!("{base}key=\"a/**b\"\n"), "t")
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a valid Zenoh key expression"), "{err}");
        let two = format!("{base}key=\"a\"\n{base}key=\"b\"\n");
        let err = Config::from_toml_str(&two, "t").unwrap_err().to_string();
        assert!(err.contains("duplicate"), "{err}");
    }

    #[test]
    fn env_overrides_apply_and_unknown_env_keys_are_named() {
        let c = Config::load(
            None,
            env(&[
                ("SKYFUSE__ZENOH__MODE", "client"),
                ("SKYFUSE__ZENOH__CONNECT", "[\"tcp/10.0.0.1:7447\"]"),
                ("SKYFUSE__HTTP__TOKEN", "s3cret"),
                ("SKYFUSE__INPUTS__0__RATE_HZ", "42"),
                ("PATH", "/usr/bin"),
            ]),
        )
        .expect("overrides");
        assert_eq!(c.zenoh.mode, ZenohMode::Client);
        assert_eq!(c.zenoh.connect, vec!["tcp/10.0.0.1:7447".to_string()]);
        assert_eq!(c.inputs[0].rate_hz, 42.0);
        assert_eq!(c.http.token, "s3cret");
        let red = c.redacted_json().to_string();
        assert!(!red.contains("s3cret"), "{red}");

        let err = Config::load(None, env(&[("SKYFUSE__ZENOH__MODEE", "client")]))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("modee") && err.contains("SKYFUSE__ZENOH__MODEE"),
            "{err}"
        );
        let err = Config::load(None, env(&[("SKYFUSE__INPUTS__99__KEY", "x")]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("past the end"), "{err}");
    }

    #[test]
    fn missing_file_names_the_path() {
        let err = Config::load(Some(Path::new("/nonexistent/skyfuse.toml")), Vec::new())
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/skyfuse.toml"), "{err}");
    }

    #[test]
    fn ros1_inputs_subscribe_with_and_without_namespace_chunk() {
        let c = Config::from_toml_str(
            "[[inputs]]\nid=\"gps\"\nkind=\"gnss\"\nkey=\"/gps/fix\"\nformat=\"ros1\"\ntype=\"sensor_msgs/NavSatFix\"\nrate_hz=10\n",
            "t",
        )
        .expect("ros1 config");
        assert_eq!(
            c.inputs[0].key_exprs(),
            vec!["*/*/gps/fix", "*/*/*/gps/fix"]
        );
    }
}
