//! The estimator task: samples from ingest go through the (pure) estimator; the fused
//! pose goes to the outputs through a `watch` channel (latest value wins, nobody waits),
//! events and live series go to the websocket hub, and a status snapshot is kept for
//! the HTTP API. Controls arrive as [`Command`]s.

use crate::estimator::{
    DebugSeries, DebugTopic, Estimator, EstimatorConfig, EstimatorEvent, EstimatorStatus, Event,
    FusedPose,
};
use crate::fusion::{Fusion, InputList};
use crate::health::{HealthConfig, HealthState, Reason};
use crate::hub::Hub;
use crate::ingest::Ingest;
use crate::protocol::{FlowPlot, ServerFrame, Tick, TickPose};
use crate::sample::{Micros, Sample};
use serde_json::Value;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

/// Live series are sent to the hub at most this often (sample time), µs.
const TICK_INTERVAL_US: i64 = 20_000;

/// A state-changing request from the control API.
#[derive(Debug)]
pub enum Command {
    ResetOrigin,
    StartFlowCalibration,
}

/// What the estimator task shares with the rest of the service.
pub struct PipelineShared {
    pub hub: Arc<Hub>,
    /// Latest estimator status (`None` before the task's first refresh).
    pub status: Mutex<Option<EstimatorStatus>>,
    /// Latest health verdict per sensor.
    pub health: Mutex<BTreeMap<String, SensorVerdict>>,
    pub consumed: AtomicU64,
    pub events: AtomicU64,
    /// Host time of service start: `t` in dashboard frames counts from here.
    pub started_us: Micros,
    /// Events for the outputs (a lagging receiver loses the oldest, counted there).
    pub events_tx: broadcast::Sender<Arc<Value>>,
}

/// Events buffered for slow event consumers.
const EVENT_BUFFER: usize = 256;

impl PipelineShared {
    pub fn new(hub: Arc<Hub>, started_us: Micros) -> Self {
        Self {
            hub,
            status: Mutex::new(None),
            health: Mutex::new(BTreeMap::new()),
            consumed: AtomicU64::new(0),
            events: AtomicU64::new(0),
            started_us,
            events_tx: broadcast::channel(EVENT_BUFFER).0,
        }
    }

    /// `/api/v1/status`'s `estimator` (null before the first refresh).
    /// The estimator's latest status (`None` before the first refresh).
    pub fn estimator_status(&self) -> Option<EstimatorStatus> {
        crate::sync::lock(&self.status).clone()
    }

    pub fn health(&self) -> BTreeMap<String, SensorVerdict> {
        crate::sync::lock(&self.health).clone()
    }
}

/// The health layer's verdict on one sensor, as `/api/v1/status` shows it beside the
/// sensor's ingest counters.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SensorVerdict {
    pub state: HealthState,
    pub reasons: Vec<Reason>,
    /// Time in this state, ms.
    pub since_ms: Option<f64>,
    /// Innovation test ratio of the last update (null if never fused).
    pub test_ratio: Option<f64>,
    /// Fused within the aiding timeout.
    pub used: bool,
    /// The health layer lets the estimator use it.
    pub usable: bool,
}

pub type PoseSender = watch::Sender<Option<Arc<FusedPose>>>;
/// Called with every new pose, in the estimator's task, before it is shared (the
/// MAVLink output sends its VPE from here).
pub type PoseHook = Box<dyn FnMut(&FusedPose) + Send>;
pub type PoseReceiver = watch::Receiver<Option<Arc<FusedPose>>>;
pub type DebugSender = watch::Sender<Arc<DebugSeries>>;
pub type DebugReceiver = watch::Receiver<Arc<DebugSeries>>;
pub type CommandSender = mpsc::Sender<(Command, oneshot::Sender<Vec<EstimatorEvent>>)>;
pub type CommandReceiver = mpsc::Receiver<(Command, oneshot::Sender<Vec<EstimatorEvent>>)>;

/// Builds the dashboard's `tick` frames from the estimator's debug series.
#[derive(Default)]
pub struct TickBuilder {
    last_tick_us: Option<i64>,
    /// Newest point already sent per (topic, source).
    sent: BTreeMap<(DebugTopic, String), i64>,
}

impl TickBuilder {
    /// A tick if one is due at estimator time `t`.
    pub fn build(&mut self, est: &Estimator, t: i64, started_us: Micros) -> Option<Tick> {
        if let Some(last) = self.last_tick_us {
            if t >= last && t - last < TICK_INTERVAL_US {
                return None;
            }
        }
        self.last_tick_us = Some(t);
        let debug = &est.debug().series;
        let mut fresh = |topic: DebugTopic| -> Option<(&str, [f64; 3])> {
            let p = debug.get(&topic)?;
            let key = (topic, p.source.clone());
            if self.sent.get(&key).is_some_and(|&s| s >= p.time_us) {
                return None;
            }
            self.sent.insert(key, p.time_us);
            Some((p.source.as_str(), p.value))
        };
        let mut sources = BTreeMap::new();
        for topic in DebugTopic::POSITIONS {
            if let Some((src, v)) = fresh(topic) {
                sources.insert(src.to_string(), v);
            }
        }
        let mut deltas = BTreeMap::new();
        for topic in DebugTopic::DELTAS {
            if let Some((src, v)) = fresh(topic) {
                let name = if topic == DebugTopic::FusionDisplace {
                    "fused"
                } else {
                    src
                };
                deltas.insert(name.to_string(), v);
            }
        }
        let flow = match (
            fresh(DebugTopic::OfData),
            fresh(DebugTopic::FlowGyro),
            fresh(DebugTopic::CompensatedOf),
        ) {
            (Some((_, raw)), Some((_, gyro)), Some((_, comp))) => Some(FlowPlot {
                raw: [raw[0], raw[1]],
                gyro: [gyro[0], gyro[1]],
                comp: [comp[0], comp[1]],
            }),
            _ => None,
        };
        Some(Tick {
            t: (t - started_us) as f64 / 1e6,
            pose: est.pose().map(|p| TickPose::of(&p)),
            sources,
            deltas,
            flow,
        })
    }
}

/// Everything the estimator task is built from.
pub struct PipelineConfig {
    pub estimator: EstimatorConfig,
    pub health: HealthConfig,
    pub inputs: InputList,
}

/// Where the estimator task's results go.
pub struct PipelineOutputs {
    pub pose: PoseSender,
    pub debug: DebugSender,
    pub on_pose: PoseHook,
}

/// Health is re-checked, and the status snapshot refreshed, this often (staleness and an
/// estimate turning invalid show without samples).
const HEALTH_TICK: std::time::Duration = std::time::Duration::from_millis(100);

/// Run until the sample channel closes.
pub async fn run(
    mut samples: mpsc::Receiver<Sample>,
    mut commands: CommandReceiver,
    config: PipelineConfig,
    ingest: Arc<Ingest>,
    shared: Arc<PipelineShared>,
    outputs: PipelineOutputs,
) {
    let PipelineOutputs {
        pose: pose_tx,
        debug: debug_tx,
        mut on_pose,
    } = outputs;
    let mut fusion = Fusion::new(config.estimator, config.health, &config.inputs);
    let mut ticks = TickBuilder::default();
    let mut last_pose_us: Option<i64> = None;
    let mut rejected_seen: BTreeMap<String, u64> = BTreeMap::new();
    let mut restarts_seen: BTreeMap<String, u64> = BTreeMap::new();
    let mut health_timer = tokio::time::interval(HEALTH_TICK);
    health_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let started = shared.started_us;
    loop {
        tokio::select! {
            s = samples.recv() => {
                let Some(s) = s else { break };
                shared.consumed.fetch_add(1, Relaxed);
                let events = fusion.process(&s, s.arrival_us);
                publish_events(&shared, &events);
                let est = &fusion.est;
                let Some(t) = est.state_time() else { continue };
                if **debug_tx.borrow() != *est.debug() {
                    debug_tx.send_replace(Arc::new(est.debug().clone()));
                }
                if let Some(p) = est.pose() {
                    if last_pose_us != Some(p.time_us) {
                        last_pose_us = Some(p.time_us);
                        // The autopilot's copy first, from this task: no hop.
                        on_pose(&p);
                        pose_tx.send_replace(Some(Arc::new(p)));
                    }
                }
                if let Some(tick) = ticks.build(est, t, started) {
                    let frame = ServerFrame::Tick(Box::new(tick));
                    shared.hub.publish(t, &frame);
                }
            }
            _ = health_timer.tick() => {
                let now = crate::clock::now_us();
                // Rejections at ingest count against the sensor's health too.
                for st in ingest.statuses(now) {
                    let seen = rejected_seen.entry(st.id.clone()).or_insert(0);
                    if st.rejected > *seen {
                        *seen = st.rejected;
                        let text = st.last_error.clone().unwrap_or_else(|| "rejected".into());
                        fusion.rejected(&st.id, "input_rejected", &text, now);
                    }
                    let seen = restarts_seen.entry(st.id.clone()).or_insert(0);
                    if st.clock_restarts > *seen {
                        *seen = st.clock_restarts;
                        let text = st.last_clock_restart.clone().unwrap_or_default();
                        let event = EstimatorEvent::new(
                            now,
                            Some(&st.id),
                            format!("{}: {text}", st.id),
                            Event::ClockRestart {
                                clock_restarts: st.clock_restarts,
                            },
                        );
                        publish_events(&shared, &[event]);
                    }
                }
                let events = fusion.tick(now);
                publish_events(&shared, &events);
                // The status snapshot is refreshed here (10 Hz) with samples or without
                // (staleness, an estimate turning invalid), and after a command.
                refresh_status(&shared, &fusion);
            }
            Some((cmd, reply)) = commands.recv() => {
                let now = fusion.est.state_time().unwrap_or_else(crate::clock::now_us);
                let events = match cmd {
                    Command::ResetOrigin => fusion.est.reset_origin(now),
                    Command::StartFlowCalibration => fusion.est.start_flow_calibration(now),
                };
                publish_events(&shared, &events);
                refresh_status(&shared, &fusion);
                let _ = reply.send(events);
            }
        }
    }
    refresh_status(&shared, &fusion);
}

/// Each sensor's health as the status API shows it.
/// The verdict on every sensor the health layer knows.
pub fn verdicts(
    fusion: &Fusion,
    st: &EstimatorStatus,
    now: i64,
) -> BTreeMap<String, SensorVerdict> {
    fusion
        .health
        .sensors()
        .map(|h| {
            let src = st.sources.get(&h.id);
            let v = SensorVerdict {
                state: h.state,
                reasons: h.reasons.clone(),
                since_ms: h.since_us.map(|s| (now - s) as f64 / 1e3),
                test_ratio: src
                    .filter(|s| !s.innovation.is_empty())
                    .map(|s| s.test_ratio),
                used: st.sources_used.contains(&h.id),
                usable: h.state.usable(),
            };
            (h.id.clone(), v)
        })
        .collect()
}

fn refresh_status(shared: &PipelineShared, fusion: &Fusion) {
    let st = fusion.est.state_summary();
    let h = verdicts(fusion, &st, crate::clock::now_us());
    *crate::sync::lock(&shared.status) = Some(st);
    *crate::sync::lock(&shared.health) = h;
}

/// Count, log and send events to the outputs and the websocket hub.
pub fn publish_events(shared: &PipelineShared, events: &[EstimatorEvent]) {
    for e in events {
        shared.events.fetch_add(1, Relaxed);
        tracing::info!(
            kind = e.kind(),
            source = e.source.as_deref().unwrap_or("-"),
            "{}",
            e.message
        );
        let t = (e.time_us - shared.started_us) as f64 / 1e6;
        let event = e.to_json(t, true);
        // No receiver is not an error: outputs may be off.
        let _ = shared.events_tx.send(Arc::new(event.clone()));
        shared.hub.publish(e.time_us, &ServerFrame::Event { event });
    }
}
