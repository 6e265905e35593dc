//! What the HTTP handlers read: the service's shared state, and the status views
//! assembled from it (`/api/v1/status`, `/api/v1/ros/topics`, `<prefix>/health`).

use crate::clock::now_us;
use crate::config::Config;
use crate::hub::Hub;
use crate::ingest::Ingest;
use crate::output::mavlink_out::MavlinkStats;
use crate::output::zenoh_out::ZenohOutStats;
use crate::pipeline::{self, CommandSender, PipelineShared, PoseReceiver};
use crate::sample::{Micros, Sample};
use crate::sim::faults::FaultSchedule;
use serde_json::json;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use tokio::sync::mpsc;

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
    pub mavlink_stats: Arc<MavlinkStats>,
    pub zenoh_out_stats: Arc<ZenohOutStats>,
    pub started_us: Micros,
    pub zenoh_zid: String,
    pub zenoh_locators: Vec<String>,
    pub(crate) queue: mpsc::WeakSender<Sample>,
    pub(crate) zenoh_closed: AtomicBool,
    /// Zenoh routers and peers this session is connected to, refreshed every second.
    pub(crate) zenoh_routers: AtomicU64,
    pub(crate) zenoh_peers: AtomicU64,
}

impl AppState {
    pub fn zenoh_closed(&self) -> bool {
        self.zenoh_closed.load(Relaxed)
    }

    pub fn status_json(&self) -> serde_json::Value {
        let now = now_us();
        let (queue_capacity, queue_free) = match self.queue.upgrade() {
            Some(tx) => (tx.max_capacity(), tx.capacity()),
            None => (self.config.ingest.channel_capacity, 0),
        };
        json!({
            "service": {
                "name": "skyfuse",
                "version": env!("CARGO_PKG_VERSION"),
                "vehicle": self.config.service.vehicle,
                "uptime_s": (now - self.started_us) as f64 / 1e6,
                "zenoh": {
                    "zid": self.zenoh_zid,
                    "mode": self.config.zenoh.mode,
                    "locators": self.zenoh_locators,
                    "connect": self.config.zenoh.connect,
                    "routers": self.zenoh_routers.load(Relaxed),
                    "peers": self.zenoh_peers.load(Relaxed),
                },
            },
            "ingest": {
                "queue_capacity": queue_capacity,
                "queue_len": queue_capacity - queue_free,
                "consumed": self.pipeline.consumed.load(Relaxed),
            },
            "sensors": self.sensors_json(now),
            "estimator": self.pipeline.status_json(),
            "outputs": [
                self.mavlink_stats.status_json(now, self.config.mavlink.rate_hz),
                self.zenoh_out_stats.status_json(&self.config.output, &self.config.output.prefix_for(&self.config.service.vehicle)),
            ],
            "websocket": self.hub.stats_json(),
            "controls": {
                "enabled": !self.config.http.token.is_empty(),
                "refused": self.controls_refused.load(Relaxed),
                "fault_injection": self.faults.is_some(),
            },
        })
    }

    /// Per-sensor ingest counters with the health verdict: `health` is the sensor's
    /// state (`ok`, `degraded`, `failed`, `stale`, `no_data`, `disabled`), `reasons`
    /// why; `ingest` keeps the transport-level view (arriving, decodable).
    pub fn sensors_json(&self, now: Micros) -> Vec<serde_json::Value> {
        let health = self.pipeline.health_json();
        self.ingest
            .statuses(now)
            .into_iter()
            .map(|st| {
                let mut v = serde_json::to_value(&st).unwrap_or_default();
                let h = &health[st.id.as_str()];
                if let Some(obj) = v.as_object_mut() {
                    let ingest = obj.remove("health").unwrap_or_default();
                    // Before the first verdict (or for a disabled input) the transport view
                    // is all there is.
                    let (state, reasons) = if h.is_null() || !st.enabled {
                        (ingest["state"].clone(), ingest["reasons"].clone())
                    } else {
                        (h["state"].clone(), h["reasons"].clone())
                    };
                    // A bridge announcing another type than configured is a standing
                    // fault, whatever arrived lately.
                    let mismatch =
                        self.config
                            .inputs
                            .iter()
                            .find(|i| i.id == st.id)
                            .and_then(|i| {
                                crate::ingest::type_mismatch(
                                    i,
                                    self.ingest.announced_type(&i.key).as_deref(),
                                )
                            });
                    let (state, reasons) = match mismatch {
                        Some(why) => {
                            let mut r = reasons.as_array().cloned().unwrap_or_default();
                            r.insert(0, json!({"code": "type_mismatch", "text": why}));
                            (json!("failed"), serde_json::Value::Array(r))
                        }
                        None => (state, reasons),
                    };
                    obj.insert("health".into(), state);
                    obj.insert("reasons".into(), reasons);
                    obj.insert("ingest".into(), ingest);
                    for k in ["test_ratio", "used", "usable", "since_ms"] {
                        obj.insert(k.into(), h[k].clone());
                    }
                    obj.insert("quality".into(), serde_json::Value::Null);
                }
                v
            })
            .collect()
    }

    /// An event of the service itself (a control action, the Zenoh link), to the event
    /// log, the outputs and the dashboard.
    pub fn publish_service_event(&self, kind: &'static str, source: Option<&str>, message: &str) {
        let event = crate::estimator::EstimatorEvent {
            time_us: now_us(),
            kind,
            source: source.map(String::from),
            message: message.to_string(),
            data: serde_json::Value::Null,
        };
        pipeline::publish_events(&self.pipeline, &[event]);
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
        json!({ "topics": topics, "announced": self.config.output.ros2_announce.then(|| self.config.output.ros2_outputs().into_iter().map(|(k, t)| json!({"key": k, "type": t})).collect::<Vec<_>>()) })
    }

    /// Health as published on `<prefix>/health`: sensors and the estimator's verdict.
    pub fn health_json(&self) -> serde_json::Value {
        json!({
            "time_us": now_us(),
            "sensors": self.sensors_json(now_us()),
            "estimator": self.pipeline.status_json(),
        })
    }
}
