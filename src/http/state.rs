//! What the HTTP handlers read: the service's shared state, and the status views
//! assembled from it (`/api/v1/status`, `/api/v1/ros/topics`, `<prefix>/health`).

use crate::clock::now_us;
use crate::config::Config;
use crate::estimator::EstimatorStatus;
use crate::event::{EstimatorEvent, Event};
use crate::health::{HealthState, Reason};
use crate::hub::{Hub, HubStats};
use crate::ingest::{Ingest, InputStatus};
use crate::output::mavlink_out::MavlinkStats;
use crate::output::zenoh_out::ZenohOutStats;
use crate::output::OutputStatus;
use crate::pipeline::{self, CommandSender, PipelineShared, PoseReceiver};
use crate::sample::Micros;
use crate::sim::faults::FaultSchedule;
use serde::Serialize;
use serde_json::json;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;

/// State shared by the HTTP handlers.
pub struct AppState {
    pub config: Arc<Config>,
    pub ingest: Arc<Ingest>,
    pub pipeline: Arc<PipelineShared>,
    pub hub: Arc<Hub>,
    pub commands: CommandSender,
    pub pose: PoseReceiver,
    pub faults: Option<Arc<FaultSchedule>>,
    pub controls_refused: AtomicU64,
    /// Refused control requests per peer address: (window start, count).
    pub refusals: std::sync::Mutex<std::collections::HashMap<std::net::IpAddr, (Micros, u32)>>,
    pub mavlink_stats: Arc<MavlinkStats>,
    /// The MAVLink output's sender (SETUP_SIGNING on request).
    pub vpe: crate::output::mavlink_out::VpeHandle,
    pub zenoh_out_stats: Arc<ZenohOutStats>,
    pub started_us: Micros,
    pub zenoh_zid: String,
    pub zenoh_locators: Vec<String>,
    pub(crate) inlet: Arc<pipeline::Inlet>,
    pub(crate) zenoh_closed: AtomicBool,
    /// Zenoh routers and peers this session is connected to, refreshed every second.
    pub(crate) zenoh_routers: AtomicU64,
    pub(crate) zenoh_peers: AtomicU64,
    /// The flight recorder and Foxglove live view, when configured.
    pub recorder: Option<Arc<crate::record::writer::Recorder>>,
    /// Where people reach this dashboard (announced in `<prefix>/health`).
    pub dashboard_url: String,
    /// What is published on the network (`[discovery] enabled`).
    pub discovery: Option<Arc<crate::discovery::Discovery>>,
}

impl AppState {
    pub fn zenoh_closed(&self) -> bool {
        self.zenoh_closed.load(Relaxed)
    }

    /// `GET /api/v1/status` (web/PROTOCOL.md).
    pub fn status(&self) -> Status {
        let now = now_us();
        let queue_capacity = self.inlet.capacity();
        let queue_free = match self.inlet.is_closed() {
            false => queue_capacity.saturating_sub(self.inlet.queue_len()),
            true => 0,
        };
        let cfg = &self.config;
        Status {
            service: ServiceInfo {
                name: "skyfuse",
                version: env!("CARGO_PKG_VERSION"),
                vehicle: cfg.service.vehicle.clone(),
                uptime_s: (now - self.started_us) as f64 / 1e6,
                zenoh: ZenohInfo {
                    zid: self.zenoh_zid.clone(),
                    mode: cfg.zenoh.mode,
                    locators: self.zenoh_locators.clone(),
                    connect: cfg.zenoh.connect.clone(),
                    routers: self.zenoh_routers.load(Relaxed),
                    peers: self.zenoh_peers.load(Relaxed),
                },
            },
            ingest: IngestInfo {
                queue_capacity,
                queue_len: queue_capacity - queue_free,
                consumed: self.pipeline.consumed.load(Relaxed),
                clock: ClockInfo::of(&self.pipeline.time),
            },
            sensors: self.sensors(now),
            estimator: self.pipeline.estimator_status(),
            outputs: vec![
                self.mavlink_stats.status(now, cfg.mavlink.rate_hz),
                self.zenoh_out_stats.status(
                    now,
                    &cfg.output,
                    &cfg.output.prefix_for(&cfg.service.vehicle),
                ),
            ],
            websocket: self.hub.stats(),
            controls: Controls {
                enabled: !cfg.http.token.is_empty(),
                refused: self.controls_refused.load(Relaxed),
                fault_injection: self.faults.is_some(),
            },
            recorder: self.recorder.as_ref().map(|r| r.status()),
        }
    }

    pub fn status_json(&self) -> serde_json::Value {
        serde_json::to_value(self.status()).unwrap_or_default()
    }

    /// Per-sensor ingest counters with the health verdict: `health` is the sensor's
    /// state, `reasons` why; `ingest` keeps the transport-level view (arriving,
    /// decodable). Before the first verdict (or for a disabled input) the transport view
    /// is all there is; a bridge announcing another type than configured is a standing
    /// fault, whatever arrived lately.
    pub fn sensors(&self, now: Micros) -> Vec<SensorView> {
        let verdicts = self.pipeline.health();
        self.ingest
            .statuses(now)
            .into_iter()
            .map(|input| {
                let verdict = verdicts
                    .get(input.id.as_str())
                    .filter(|_| input.enabled)
                    .cloned();
                let (mut health, mut reasons) = match &verdict {
                    Some(v) => (v.state, v.reasons.clone()),
                    None => (input.ingest.state, input.ingest.reasons.clone()),
                };
                let mismatch = self
                    .config
                    .inputs
                    .iter()
                    .find(|i| i.id == input.id)
                    .and_then(|i| {
                        crate::ingest::type_mismatch(
                            i,
                            self.ingest.announced_type(&i.key).as_deref(),
                        )
                    });
                if let Some(why) = mismatch {
                    health = HealthState::Failed;
                    reasons.insert(
                        0,
                        Reason {
                            code: "type_mismatch",
                            text: why,
                        },
                    );
                }
                SensorView {
                    health,
                    reasons,
                    test_ratio: verdict.as_ref().and_then(|v| v.test_ratio),
                    used: verdict.as_ref().map(|v| v.used),
                    usable: verdict.as_ref().map(|v| v.usable),
                    since_ms: verdict.as_ref().and_then(|v| v.since_ms),
                    quality: None,
                    input,
                }
            })
            .collect()
    }

    /// An event of the service itself (a control action, the Zenoh link), to the event
    /// log, the outputs and the dashboard.
    pub fn publish_service_event(&self, what: Event, source: Option<&str>, message: &str) {
        let event = EstimatorEvent::new(now_us(), source, message.to_string(), what);
        pipeline::publish_events(&self.pipeline, &[event]);
    }

    /// `GET /api/v1/discovered`: every key on the network against the inputs; `None`
    /// with discovery off.
    pub fn discovered(&self) -> Option<crate::discovery::Discovered> {
        let d = self.discovery.as_ref()?;
        Some(d.snapshot(
            now_us(),
            &self.config.inputs,
            &crate::discovery::announced(&self.ingest.ros_topics),
            &crate::discovery::own_outputs(&self.config),
        ))
    }

    /// `GET /api/v1/ros/topics`: what bridges announce, with the inputs that use each.
    pub fn ros_topics_json(&self) -> serde_json::Value {
        let table = crate::sync::lock(&self.ingest.ros_topics).clone();
        let topics: Vec<serde_json::Value> = table
            .values()
            .map(|e| {
                let used_by: Vec<&str> = self
                    .config
                    .inputs
                    .iter()
                    .filter(|i| i.enabled && i.key.trim_start_matches('/') == e.key)
                    .map(|i| i.id.as_str())
                    .collect();
                let decodable = crate::codec::RosType::from_name(&e.ros_type).is_some();
                json!({
                    "key": e.key, "topic": e.topic, "type": e.ros_type, "qos": e.qos,
                    "zid": e.zid, "alive": e.alive, "since_us": e.since_us,
                    "used_by": used_by, "decodable": decodable,
                })
            })
            .collect();
        json!({ "topics": topics, "announced": self.config.output.ros2_announce.then(|| self.config.output.announced_outputs().into_iter().map(|(k, t)| json!({"key": k, "type": t})).collect::<Vec<_>>()) })
    }

    /// Health as published on `<prefix>/health`: sensors and the estimator's verdict.
    /// `<prefix>/health`, every `[output] health_interval_s` (the summary is built from it
    /// every second): the sensors and the estimator as in the status,
    /// plus what the fleet view shows of this vehicle (who it is, where its dashboard is,
    /// whether the autopilot gets poses, its Zenoh link).
    pub fn health_json(&self) -> serde_json::Value {
        let now = now_us();
        let cfg = &self.config;
        let vpe = self.mavlink_stats.status(now, cfg.mavlink.rate_hz);
        let withheld = match vpe.detail {
            crate::output::OutputDetail::Mavlink { withheld, .. } => Some(withheld),
            _ => None,
        };
        json!({
            "time_us": now,
            "service": {
                "vehicle": cfg.service.vehicle,
                "version": env!("CARGO_PKG_VERSION"),
                "started_us": self.started_us,
                "dashboard": self.dashboard_url,
            },
            "vpe": {
                "endpoints": self.mavlink_stats.links.len(),
                "sending": vpe.sending,
                "sent": vpe.sent,
                "withheld": withheld,
                "reason": vpe.not_sending_reason,
            },
            "zenoh": {
                "routers": self.zenoh_routers.load(Relaxed),
                "peers": self.zenoh_peers.load(Relaxed),
            },
            "sensors": self.sensors(now),
            "estimator": self.pipeline.estimator_status(),
        })
    }
}

/// `GET /api/v1/status`: every part typed, each view from the module that owns it.
#[derive(Debug, Clone, Serialize)]
pub struct Status {
    pub service: ServiceInfo,
    pub ingest: IngestInfo,
    pub sensors: Vec<SensorView>,
    /// Null before the estimator's first refresh.
    pub estimator: Option<EstimatorStatus>,
    /// The MAVLink output, then the Zenoh output.
    pub outputs: Vec<OutputStatus>,
    pub websocket: HubStats,
    pub controls: Controls,
    /// The MCAP recorder and the Foxglove server; null when neither runs.
    pub recorder: Option<crate::record::RecorderStatus>,
}

#[derive(Debug, Clone, Serialize)]
pub struct ServiceInfo {
    pub name: &'static str,
    pub version: &'static str,
    pub vehicle: String,
    pub uptime_s: f64,
    pub zenoh: ZenohInfo,
}

#[derive(Debug, Clone, Serialize)]
pub struct ZenohInfo {
    pub zid: String,
    pub mode: crate::config::ZenohMode,
    pub locators: Vec<String>,
    pub connect: Vec<String>,
    /// Routers and peers connected now (refreshed every second).
    pub routers: u64,
    pub peers: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct IngestInfo {
    pub queue_capacity: usize,
    pub queue_len: usize,
    pub consumed: u64,
    /// The clock the estimator runs on.
    pub clock: ClockInfo,
}

/// `ingest.clock`: `"host"`, or `"vehicle"` when the reference IMU's stamps run at
/// another rate (a simulator faster than real time) and the estimator follows them.
#[derive(Debug, Clone, Serialize)]
pub struct ClockInfo {
    pub base: &'static str,
    /// The estimator's clock against the host's (5.0 for SITL at `--speedup 5`).
    pub rate: f64,
    /// The input whose stamps are that clock (null on the host's).
    pub reference: Option<String>,
}

impl ClockInfo {
    pub fn of(time: &crate::clock::SharedTimeBase) -> Self {
        let base = time.get();
        Self {
            base: if base.is_host() { "host" } else { "vehicle" },
            rate: (base.rate * 1e4).round() / 1e4,
            reference: time.reference(),
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Controls {
    /// A token is configured (controls need it).
    pub enabled: bool,
    /// Control requests refused (bad or missing token).
    pub refused: u64,
    pub fault_injection: bool,
}

/// One sensor: its ingest counters (`ingest`: the transport's own verdict) and the
/// health layer's verdict.
#[derive(Debug, Clone, Serialize)]
pub struct SensorView {
    #[serde(flatten)]
    pub input: InputStatus,
    pub health: HealthState,
    pub reasons: Vec<Reason>,
    pub test_ratio: Option<f64>,
    pub used: Option<bool>,
    pub usable: Option<bool>,
    pub since_ms: Option<f64>,
    /// Not tracked per sensor yet (the page copes with null).
    pub quality: Option<u8>,
}
