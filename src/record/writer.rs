//! The recorder thread: taps' items → Foxglove SDK channels → MCAP files (rotated) and
//! the Foxglove WebSocket server.

use super::{RecorderStatus, Tap, TapItem, TapStats};
use crate::codec::{Format, RosType};
use crate::config::{FoxgloveConfig, RecordConfig};
use crate::estimator::FusedPose;
use crate::ingest::Ingest;
use foxglove::messages::{
    FrameTransform, LocationFix, Pose, PoseInFrame, Quaternion, Timestamp, Vector3,
};
use foxglove::{Channel, Context, McapWriteOptions, McapWriterHandle, PartialMetadata, RawChannel};
use std::collections::{BTreeMap, HashMap};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum RecordError {
    #[error("recording: cannot create the directory {dir}: {source}")]
    Dir { dir: String, source: std::io::Error },
    #[error("recording: cannot open {file}: {message}")]
    Open { file: String, message: String },
    #[error("foxglove: `bind` {bind:?} is not HOST:PORT")]
    Bind { bind: String },
    #[error("foxglove: cannot start the WebSocket server on {bind}: {message}")]
    Server { bind: String, message: String },
}

/// The running recorder: finish it at shutdown to finalise the file.
pub struct Recorder {
    tx: std::sync::mpsc::SyncSender<TapItem>,
    thread: std::sync::Mutex<Option<std::thread::JoinHandle<()>>>,
    server: std::sync::Mutex<Option<foxglove::WebSocketServerHandle>>,
    pub stats: Arc<TapStats>,
    dir: Option<String>,
    foxglove: Option<String>,
}

impl Recorder {
    pub fn status(&self) -> RecorderStatus {
        let s = &self.stats;
        let foxglove_clients = crate::sync::lock(&self.server)
            .as_ref()
            .map_or(0, |server| server.client_count() as u64);
        RecorderStatus {
            recording: self.dir.is_some(),
            dir: self.dir.clone(),
            file: crate::sync::lock(&s.file).clone(),
            files: s.files.load(Relaxed),
            bytes: s.bytes.load(Relaxed),
            messages: s.logged.load(Relaxed),
            dropped: s.dropped.load(Relaxed),
            error: crate::sync::lock(&s.error).clone(),
            foxglove: self.foxglove.clone(),
            foxglove_clients,
        }
    }

    /// Log what is queued, finalise the MCAP file (summary, footer) and stop the server.
    /// Blocks until the file is written: call it off the async runtime's workers
    /// (`spawn_blocking`) or at the very end.
    pub fn finish(&self) {
        // A blocking send: the thread logs what is queued before it sees this.
        let _ = self.tx.send(TapItem::Finish);
        if let Some(t) = crate::sync::lock(&self.thread).take() {
            let _ = t.join();
        }
        if let Some(server) = crate::sync::lock(&self.server).take() {
            let _ = server.stop();
        }
    }
}

/// Start the recorder thread (and the Foxglove server) if either is configured; else
/// the tap is off and there is nothing to finish.
pub async fn spawn(
    record: &RecordConfig,
    foxglove: &FoxgloveConfig,
    vehicle: &str,
    frame_id: &str,
    ingest: Arc<Ingest>,
    any_port_if_taken: bool,
) -> Result<(Tap, Option<Recorder>), RecordError> {
    let dir = record.dir().map(str::to_string);
    let bind = foxglove.bind();
    if dir.is_none() && bind.is_none() {
        return Ok((Tap::off(), None));
    }
    let ctx = Context::new();
    let (server, foxglove_addr) = match bind {
        Some(b) => {
            let (host, port) = crate::config::split_host_port(b)
                .ok_or_else(|| RecordError::Bind { bind: b.into() })?;
            let start = |port: u16| {
                ctx.websocket_server()
                    .name(format!("skyfuse {vehicle}"))
                    .bind(host.trim_matches(['[', ']']), port)
                    .start()
            };
            let handle = match start(port).await {
                Err(e) if any_port_if_taken && port != 0 => {
                    tracing::warn!("Foxglove: {b} unavailable ({e}); taking any free port");
                    start(0).await
                }
                other => other,
            }
            .map_err(|e| RecordError::Server {
                bind: b.into(),
                message: e.to_string(),
            })?;
            // The port it got (the configured one, or any when that was 0 or taken).
            let addr = format!("{host}:{}", handle.port());
            tracing::info!("Foxglove WebSocket server on {addr}");
            (Some(handle), Some(addr))
        }
        None => (None, None),
    };
    let rotation = match &dir {
        Some(d) => {
            std::fs::create_dir_all(d).map_err(|source| RecordError::Dir {
                dir: d.clone(),
                source,
            })?;
            Some(Rotation::new(PathBuf::from(d), vehicle, record))
        }
        None => None,
    };
    let stats = Arc::new(TapStats::default());
    let (tx, rx) = std::sync::mpsc::sync_channel(record.queue_capacity.max(16));
    let mut writer = Writer::new(ctx, ingest, stats.clone(), rotation, frame_id);
    // The first file is opened here so that an unwritable directory fails the start.
    writer.open_first()?;
    let thread = std::thread::Builder::new()
        .name("skyfuse-record".into())
        .spawn(move || writer.run(rx))
        .map_err(|e| RecordError::Open {
            file: "(recorder thread)".into(),
            message: e.to_string(),
        })?;
    Ok((
        Tap::new(tx.clone(), stats.clone()),
        Some(Recorder {
            tx,
            thread: std::sync::Mutex::new(Some(thread)),
            server: std::sync::Mutex::new(server),
            stats,
            dir,
            foxglove: foxglove_addr,
        }),
    ))
}

/// Files of one recording: `<vehicle>-<UTC start>-<NNN>.mcap`, a new one when the
/// current passes `max_file_mb` or `max_file_s`.
struct Rotation {
    dir: PathBuf,
    vehicle: String,
    max_bytes: u64,
    max_age: Duration,
    chunk_bytes: u64,
    seq: u32,
    current: Option<(PathBuf, Instant, McapWriterHandle<BufWriter<std::fs::File>>)>,
    finished_bytes: u64,
}

impl Rotation {
    fn new(dir: PathBuf, vehicle: &str, cfg: &RecordConfig) -> Self {
        Self {
            dir,
            vehicle: super::name_safe(vehicle),
            max_bytes: (cfg.max_file_mb * 1024.0 * 1024.0) as u64,
            max_age: Duration::from_secs_f64(cfg.max_file_s.max(1.0)),
            chunk_bytes: (cfg.chunk_kb * 1024.0) as u64,
            seq: 0,
            current: None,
            finished_bytes: 0,
        }
    }

    fn open(&mut self, ctx: &Arc<Context>) -> Result<PathBuf, RecordError> {
        self.seq += 1;
        let name = format!(
            "{}-{}-{:03}.mcap",
            self.vehicle,
            utc_stamp(crate::clock::now_us()),
            self.seq
        );
        let path = self.dir.join(name);
        let options = McapWriteOptions::new()
            .chunk_size(Some(self.chunk_bytes.max(4096)))
            .compression(Some(foxglove::McapCompression::Zstd))
            .profile("")
            .library(format!("skyfuse {}", env!("CARGO_PKG_VERSION")));
        let handle = ctx
            .mcap_writer_with_options(options)
            .create_new_buffered_file(&path)
            .map_err(|e| RecordError::Open {
                file: path.display().to_string(),
                message: e.to_string(),
            })?;
        tracing::info!(file = %path.display(), "recording");
        self.current = Some((path.clone(), Instant::now(), handle));
        Ok(path)
    }

    /// Finalise the current file (summary and footer); its size joins the total.
    fn close(&mut self) -> Result<(), String> {
        if let Some((path, _, handle)) = self.current.take() {
            handle
                .close()
                .map_err(|e| format!("{}: {e}", path.display()))?;
            self.finished_bytes += file_size(&path);
            tracing::info!(file = %path.display(), "recording finished");
        }
        Ok(())
    }

    /// Whether the current file, of `size` bytes, is to be closed for a new one.
    fn due(&self, size: u64) -> bool {
        self.current.as_ref().is_some_and(|(_, opened, _)| {
            opened.elapsed() >= self.max_age || size >= self.max_bytes
        })
    }

    fn current_bytes(&self) -> u64 {
        self.current
            .as_ref()
            .map(|(p, _, _)| file_size(p))
            .unwrap_or(0)
    }
}

fn file_size(p: &Path) -> u64 {
    std::fs::metadata(p).map(|m| m.len()).unwrap_or(0)
}

/// `20261124T120219Z` from µs since the Unix epoch (UTC; days → civil date after
/// Howard Hinnant's algorithm).
pub fn utc_stamp(us: i64) -> String {
    let secs = us.div_euclid(1_000_000);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// How often the rotation limits and the byte count are looked at.
const HOUSEKEEPING: Duration = Duration::from_millis(500);

struct Writer {
    ctx: Arc<Context>,
    ingest: Arc<Ingest>,
    stats: Arc<TapStats>,
    rotation: Option<Rotation>,
    frame_id: String,
    /// Per input index, per key (a key expression input can see many keys).
    inputs: HashMap<usize, HashMap<String, Arc<RawChannel>>>,
    ros2_out: HashMap<String, Arc<RawChannel>>,
    decoded: HashMap<usize, Arc<RawChannel>>,
    pose: Channel<PoseInFrame>,
    tf: Channel<FrameTransform>,
    location: Channel<LocationFix>,
    pose_json: Arc<RawChannel>,
    mavlink_out: Arc<RawChannel>,
    health: Arc<RawChannel>,
    events: Arc<RawChannel>,
    debug: Arc<RawChannel>,
}

/// A raw channel with `encoding` (the builder's only failure is a missing encoding).
fn raw_channel(builder: foxglove::ChannelBuilder, encoding: &str) -> Arc<RawChannel> {
    match builder.message_encoding(encoding).build_raw() {
        Ok(c) => c,
        Err(e) => unreachable!("a channel with an encoding: {e}"),
    }
}

fn json_channel(ctx: &Arc<Context>, topic: &str) -> Arc<RawChannel> {
    raw_channel(ctx.channel_builder(topic), "json")
}

impl Writer {
    fn new(
        ctx: Arc<Context>,
        ingest: Arc<Ingest>,
        stats: Arc<TapStats>,
        rotation: Option<Rotation>,
        frame_id: &str,
    ) -> Self {
        let mavlink_out = raw_channel(
            ctx.channel_builder(super::TOPIC_MAVLINK_OUT),
            super::MAVLINK_ENCODING,
        );
        Self {
            pose: ctx.channel_builder(super::TOPIC_POSE).build(),
            tf: ctx.channel_builder(super::TOPIC_TF).build(),
            location: ctx.channel_builder(super::TOPIC_LOCATION).build(),
            pose_json: json_channel(&ctx, super::TOPIC_POSE_JSON),
            health: json_channel(&ctx, super::TOPIC_HEALTH),
            events: json_channel(&ctx, super::TOPIC_EVENTS),
            debug: json_channel(&ctx, super::TOPIC_DEBUG),
            mavlink_out,
            ctx,
            ingest,
            stats,
            rotation,
            frame_id: frame_id.to_string(),
            inputs: HashMap::new(),
            ros2_out: HashMap::new(),
            decoded: HashMap::new(),
        }
    }

    fn open_first(&mut self) -> Result<(), RecordError> {
        if let Some(r) = &mut self.rotation {
            let path = r.open(&self.ctx)?;
            self.stats.files.store(1, Relaxed);
            *crate::sync::lock(&self.stats.file) = Some(path.display().to_string());
        }
        Ok(())
    }

    fn run(mut self, rx: std::sync::mpsc::Receiver<TapItem>) {
        let mut last_housekeeping = Instant::now();
        loop {
            match rx.recv_timeout(HOUSEKEEPING) {
                Ok(TapItem::Finish) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                Ok(item) => self.log(item),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            }
            if last_housekeeping.elapsed() >= HOUSEKEEPING {
                last_housekeeping = Instant::now();
                self.housekeeping();
            }
        }
        if let Some(r) = &mut self.rotation {
            if let Err(e) = r.close() {
                tracing::error!("recording: cannot finish the file: {e}");
                *crate::sync::lock(&self.stats.error) = Some(e);
            }
            self.stats.bytes.store(r.finished_bytes, Relaxed);
        }
    }

    fn housekeeping(&mut self) {
        let Some(r) = &mut self.rotation else { return };
        let mut current = r.current_bytes();
        if r.due(current) {
            let result = r.close().and_then(|()| {
                r.open(&self.ctx)
                    .map_err(|e| e.to_string())
                    .map(|p| p.display().to_string())
            });
            match result {
                Ok(file) => {
                    self.stats.files.fetch_add(1, Relaxed);
                    *crate::sync::lock(&self.stats.file) = Some(file);
                }
                Err(e) => {
                    // A full disk: say so and stop recording; flying goes on.
                    tracing::error!("recording stopped: {e}");
                    *crate::sync::lock(&self.stats.error) = Some(e);
                    *crate::sync::lock(&self.stats.file) = None;
                }
            }
            current = r.current_bytes();
        }
        self.stats.bytes.store(r.finished_bytes + current, Relaxed);
    }

    fn log(&mut self, item: TapItem) {
        let ns = |us: i64| PartialMetadata {
            log_time: Some(us.max(0) as u64 * 1000),
        };
        let mut logged = 1;
        match item {
            TapItem::Input {
                arrival_us,
                input,
                key,
                payload,
            } => self
                .input_channel(input, &key)
                .log_with_meta(&payload, ns(arrival_us)),
            TapItem::Decoded { input, sample } => {
                let stamp = sample.stamp_us.unwrap_or(sample.arrival_us);
                if let Ok(text) = crate::codec::json::encode(stamp, &sample.data) {
                    self.decoded_channel(input, &text)
                        .log_with_meta(text.as_bytes(), ns(sample.arrival_us));
                }
            }
            TapItem::Pose(p) => logged = self.log_pose(&p),
            TapItem::MavlinkOut { sent_us, frame } => {
                self.mavlink_out.log_with_meta(&frame, ns(sent_us))
            }
            TapItem::Ros2Out {
                t_us,
                key,
                ros_type,
                payload,
            } => self
                .ros2_out_channel(&key, ros_type)
                .log_with_meta(&payload, ns(t_us)),
            TapItem::Health { t_us, json } => log_json(&self.health, &json, ns(t_us)),
            TapItem::Event { t_us, json } => log_json(&self.events, &json, ns(t_us)),
            TapItem::Debug { t_us, series } => {
                if let Ok(v) = serde_json::to_value(&*series) {
                    log_json(&self.debug, &v, ns(t_us));
                }
            }
            TapItem::Finish => logged = 0,
        }
        self.stats.logged.fetch_add(logged, Relaxed);
    }

    fn log_pose(&mut self, p: &FusedPose) -> u64 {
        let t = p.time_us.max(0) as u64 * 1000;
        let meta = PartialMetadata { log_time: Some(t) };
        let stamp = Timestamp::new(
            (p.time_us.max(0) / 1_000_000) as u32,
            (p.time_us.max(0) % 1_000_000) as u32 * 1000,
        );
        let position = Vector3 {
            x: p.position.x,
            y: p.position.y,
            z: p.position.z,
        };
        let q = p.orientation;
        let orientation = Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        };
        self.pose.log_with_meta(
            &PoseInFrame {
                timestamp: Some(stamp),
                frame_id: self.frame_id.clone(),
                pose: Some(Pose {
                    position: Some(position),
                    orientation: Some(orientation),
                }),
            },
            meta,
        );
        self.tf.log_with_meta(
            &FrameTransform {
                timestamp: Some(stamp),
                parent_frame_id: self.frame_id.clone(),
                child_frame_id: "base_link".into(),
                translation: Some(position),
                rotation: Some(orientation),
            },
            meta,
        );
        let message = crate::output::zenoh_out::PoseMessage::of(p, &self.frame_id);
        if let Ok(text) = serde_json::to_vec(&message) {
            self.pose_json.log_with_meta(&text, meta);
        }
        let mut n = 3;
        if let (Some((lat, lon, alt)), true) = (p.origin, p.valid) {
            let (lat, lon, alt) = crate::geo::LocalEnu::new(lat, lon, alt).to_geodetic(p.position);
            self.location.log_with_meta(
                &LocationFix {
                    timestamp: Some(stamp),
                    frame_id: self.frame_id.clone(),
                    latitude: lat,
                    longitude: lon,
                    altitude: alt,
                    position_covariance: enu_cov_rows(&p.position_cov),
                    position_covariance_type: 3, // KNOWN
                    // Clockwise from north; the pose's yaw is counter-clockwise from east.
                    heading: Some(
                        (std::f64::consts::FRAC_PI_2 - crate::estimator::attitude::yaw_of(&q))
                            .rem_euclid(std::f64::consts::TAU),
                    ),
                    velocity: Some(Vector3 {
                        x: p.velocity.x,
                        y: p.velocity.y,
                        z: p.velocity.z,
                    }),
                    color: None,
                    metadata: Vec::new(),
                },
                meta,
            );
            n += 1;
        }
        n
    }

    /// The channel of `input`'s payloads on `key`, made on first use: ROS 2 CDR with its
    /// `ros2msg` schema (Foxglove and rosbag2 readers decode it), JSON as JSON, MAVLink
    /// frames as `mavlink2`, ROS 1 as `ros1`.
    fn input_channel(&mut self, input: usize, key: &str) -> Arc<RawChannel> {
        if let Some(c) = self.inputs.get(&input).and_then(|by_key| by_key.get(key)) {
            return c.clone();
        }
        let mut metadata = BTreeMap::new();
        let mut builder = self.ctx.channel_builder(key);
        if let Some(state) = self.ingest.inputs.get(input) {
            let cfg = &state.config;
            metadata.insert(super::META_INPUT.to_string(), cfg.id.clone());
            metadata.insert(super::META_FORMAT.to_string(), cfg.format.to_string());
            let ros_type = match (cfg.format, cfg.auto_type) {
                (Format::Ros2, true) => self
                    .ingest
                    .announced_type(&cfg.key)
                    .and_then(|a| RosType::from_name(&a)),
                _ => cfg.ros_type,
            };
            builder = builder.message_encoding(super::channel_encoding(cfg.format));
            if let Some(t) = ros_type {
                metadata.insert(super::META_ROS_TYPE.to_string(), t.ros2_name().to_string());
                if cfg.format == Format::Ros2 {
                    builder = builder.schema(super::ros2msg::schema(t));
                }
            }
        }
        let channel = match builder.metadata(metadata).build_raw() {
            Ok(c) => c,
            // An input index the ingest does not know: still recorded, as bytes.
            Err(_) => raw_channel(self.ctx.channel_builder(key), "application/octet-stream"),
        };
        self.inputs
            .entry(input)
            .or_default()
            .insert(key.to_string(), channel.clone());
        channel
    }

    /// A ROS 2 output's channel: its CDR with the `ros2msg` schema, marked as an output.
    fn ros2_out_channel(&mut self, key: &str, t: RosType) -> Arc<RawChannel> {
        if let Some(c) = self.ros2_out.get(key) {
            return c.clone();
        }
        let channel = raw_channel(
            self.ctx
                .channel_builder(key)
                .schema(super::ros2msg::schema(t))
                .add_metadata(super::META_OUTPUT, "ros2"),
            "cdr",
        );
        self.ros2_out.insert(key.to_string(), channel.clone());
        channel
    }

    fn decoded_channel(&mut self, input: usize, first: &str) -> Arc<RawChannel> {
        if let Some(c) = self.decoded.get(&input) {
            return c.clone();
        }
        let id = self
            .ingest
            .inputs
            .get(input)
            .map(|i| i.config.id.clone())
            .unwrap_or_else(|| format!("input{input}"));
        let topic = format!("{}{id}", super::TOPIC_INPUT_PREFIX);
        let schema = serde_json::from_str::<serde_json::Value>(first)
            .map(|v| json_schema_of(&v))
            .unwrap_or_else(|_| serde_json::json!({"type": "object"}));
        let channel = raw_channel(
            self.ctx
                .channel_builder(topic.as_str())
                .schema(foxglove::Schema::new(
                    format!("skyfuse.{id}"),
                    "jsonschema",
                    schema.to_string().into_bytes(),
                )),
            "json",
        );
        self.decoded.insert(input, channel.clone());
        channel
    }
}

fn log_json(channel: &Arc<RawChannel>, v: &serde_json::Value, meta: PartialMetadata) {
    if let Ok(text) = serde_json::to_vec(v) {
        channel.log_with_meta(&text, meta);
    }
}

/// Row-major 3×3, ENU → the LocationFix's east/north/up order (the same).
fn enu_cov_rows(m: &nalgebra::Matrix3<f64>) -> Vec<f64> {
    (0..3)
        .flat_map(|r| (0..3).map(move |c| m[(r, c)]))
        .collect()
}

/// A JSON schema for the shape of `v` (the first message of a channel): field names and
/// their JSON types, so Foxglove lists the fields before any message arrives.
pub fn json_schema_of(v: &serde_json::Value) -> serde_json::Value {
    use serde_json::{json, Value};
    match v {
        Value::Object(m) => json!({
            "type": "object",
            "properties": m.iter().map(|(k, v)| (k.clone(), json_schema_of(v))).collect::<serde_json::Map<_, _>>(),
        }),
        Value::Array(a) => match a.first() {
            Some(first) => json!({"type": "array", "items": json_schema_of(first)}),
            None => json!({"type": "array"}),
        },
        Value::Number(_) => json!({"type": "number"}),
        Value::String(_) => json!({"type": "string"}),
        Value::Bool(_) => json!({"type": "boolean"}),
        Value::Null => json!({}),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps_are_civil_dates() {
        assert_eq!(utc_stamp(0), "19700101T000000Z");
        // 2026-11-24 12:02:19 UTC.
        assert_eq!(utc_stamp(1_795_521_739_000_000), "20261124T120219Z");
        // A leap day.
        assert_eq!(utc_stamp(951_782_400_000_000), "20000229T000000Z");
    }

    #[test]
    fn a_json_schema_names_every_field_with_its_type() {
        let v = serde_json::json!({"kind": "imu", "gyro": [0.1, 0.2], "ok": true, "x": null});
        let s = json_schema_of(&v);
        assert_eq!(s["properties"]["kind"]["type"], "string");
        assert_eq!(s["properties"]["gyro"]["type"], "array");
        assert_eq!(s["properties"]["gyro"]["items"]["type"], "number");
        assert_eq!(s["properties"]["ok"]["type"], "boolean");
    }
}
