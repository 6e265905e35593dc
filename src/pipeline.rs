//! The estimator in the service: samples from ingest go through the (pure) estimator on
//! the thread that brings them ([`Inlet`]); the VPE leaves from there at once, the fused
//! pose goes to the other outputs through a `watch` channel (latest value wins, nobody
//! waits), events and live series go to the websocket hub, and a status snapshot is
//! kept for the HTTP API. The estimator's task ([`run`]) does the periodic health check
//! and the control API's [`Command`]s.

use crate::clock::{RateChange, SharedTimeBase, TimeBase, VehicleClockWatch};
use crate::estimator::{
    DebugSeries, DebugTopic, Estimator, EstimatorConfig, EstimatorEvent, EstimatorStatus, Event,
    FusedPose,
};
use crate::fusion::{Fusion, InputList};
use crate::health::{HealthConfig, HealthState, Reason};
use crate::hub::Hub;
use crate::ingest::{Ingest, InputStatus};
use crate::protocol::{FlowPlot, ServerFrame, Tick, TickPose};
use crate::sample::{Micros, Sample, SensorKind};
use serde_json::Value;
use std::collections::{BTreeMap, VecDeque};
use std::future::Future;
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

/// What the estimator shares with the rest of the service.
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
    /// The clock the estimator runs on (the host's, or a faster simulator's).
    pub time: Arc<SharedTimeBase>,
}

/// Events buffered for slow event consumers.
const EVENT_BUFFER: usize = 256;

impl PipelineShared {
    /// `time`: the estimator's clock, shared with ingest (its flood limit follows the
    /// vehicle's rate) and the outputs.
    pub fn new(hub: Arc<Hub>, started_us: Micros, time: Arc<SharedTimeBase>) -> Self {
        Self {
            hub,
            status: Mutex::new(None),
            health: Mutex::new(BTreeMap::new()),
            consumed: AtomicU64::new(0),
            events: AtomicU64::new(0),
            started_us,
            events_tx: broadcast::channel(EVENT_BUFFER).0,
            time,
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
/// Called with every new pose, on the thread that fused it, before it is shared (the
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
    /// Per position (topic, source): the newest point's time and the ticks it went in.
    positions: BTreeMap<(DebugTopic, String), (i64, u32)>,
}

/// A source's newest position goes out in this many ticks (300 ms at 50 Hz), not only
/// the one after it is new: a client slower than the ticks skips most of them, and a
/// 10 Hz GPS point that fell in skipped ticks run after run (the phases line up for a
/// whole session) left a page's GPS line cut in 7 places.
const POSITION_REPEAT_TICKS: u32 = 15;

impl TickBuilder {
    /// A tick if one is due at host time `t` (the estimator's, mapped).
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
            let Some(p) = debug.get(&topic) else { continue };
            let key = (topic, p.source.clone());
            let entry = self.positions.entry(key).or_insert((i64::MIN, 0));
            if p.time_us > entry.0 {
                *entry = (p.time_us, 0);
            }
            if entry.1 < POSITION_REPEAT_TICKS {
                entry.1 += 1;
                sources.insert(p.source.clone(), p.value);
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

/// Everything the estimator is built from.
#[derive(Clone)]
pub struct PipelineConfig {
    pub estimator: EstimatorConfig,
    pub health: HealthConfig,
    pub inputs: InputList,
    /// Run the estimator on the vehicle's clock when the reference IMU's stamps run at
    /// another rate than the host's (`[ingest] follow_vehicle_clock`).
    pub follow_vehicle_clock: bool,
}

impl PipelineConfig {
    /// A new estimator under health supervision for these inputs.
    fn fusion(&self) -> Fusion {
        Fusion::new(self.estimator.clone(), self.health.clone(), &self.inputs)
    }

    /// The input whose stamps are the vehicle's clock: the first enabled IMU (it drives
    /// the filter's prediction, and an autopilot stamps it with its own clock).
    pub fn clock_reference(&self) -> Option<&str> {
        self.inputs
            .iter()
            .find(|i| i.enabled && i.kind == SensorKind::Imu)
            .map(|i| i.id.as_str())
    }
}

/// Where the estimator's results go.
pub struct PipelineOutputs {
    /// Called with every new pose before anything else (the VPE leaves from here).
    pub on_pose: PoseHook,
    /// The newest pose, replaced with every pose; read when wanted (status API, the
    /// MAVLink output's staleness check), not waited on.
    pub pose: PoseSender,
    /// Poses at the output rate (`[output] pose_rate_hz`), for the outputs that wait
    /// for each one (Zenoh, the recorder).
    pub pose_out: PoseSender,
    pub pose_rate: RateLimit,
    /// The debug series at `[output] debug_rate_hz` (0: with every sample).
    pub debug: DebugSender,
    pub debug_rate: RateLimit,
}

pub use crate::rate_limit::RateLimit;

/// Health is re-checked, and the status snapshot refreshed, this often (staleness and an
/// estimate turning invalid show without samples).
const HEALTH_TICK: std::time::Duration = std::time::Duration::from_millis(100);

/// The estimator and where its results go: everything a sample touches. Whichever
/// thread holds it fuses (see [`Inlet`]).
pub struct Pipeline {
    config: PipelineConfig,
    fusion: Fusion,
    /// The estimator's clock (see [`TimeBase`]); samples, ticks and commands are mapped
    /// onto it, and poses, events and series back to the host's as they leave.
    base: TimeBase,
    clock_reference: Option<String>,
    clock_watch: VehicleClockWatch,
    ticks: TickBuilder,
    last_pose_us: Option<i64>,
    outputs: PipelineOutputs,
    shared: Arc<PipelineShared>,
    /// Ingest's rejection and clock-restart counters already reported, per input.
    rejected_seen: BTreeMap<String, u64>,
    restarts_seen: BTreeMap<String, u64>,
}

impl Pipeline {
    pub fn new(
        config: PipelineConfig,
        shared: Arc<PipelineShared>,
        outputs: PipelineOutputs,
    ) -> Self {
        let clock_reference = config
            .follow_vehicle_clock
            .then(|| config.clock_reference().map(str::to_string))
            .flatten();
        Self {
            fusion: config.fusion(),
            config,
            base: TimeBase::HOST,
            clock_reference,
            clock_watch: VehicleClockWatch::default(),
            ticks: TickBuilder::default(),
            last_pose_us: None,
            outputs,
            shared,
            rejected_seen: BTreeMap::new(),
            restarts_seen: BTreeMap::new(),
        }
    }

    /// Fuse one sample and hand on what it changed: the autopilot's copy of a new pose
    /// first, then the rest.
    fn sample(&mut self, s: &Sample) {
        self.shared.consumed.fetch_add(1, Relaxed);
        if let (Some(stamp), Some(reference)) = (s.stamp_us, &self.clock_reference) {
            if **reference == *s.source {
                if let Some(change) = self.clock_watch.observe(s.arrival_us, stamp, &self.base) {
                    self.rebase(change, s.arrival_us);
                }
            }
        }
        let mapped;
        let s = if self.base.is_host() {
            s
        } else {
            mapped = Sample {
                arrival_us: self.base.to_fusion(s.arrival_us),
                ..s.clone()
            };
            &mapped
        };
        let mut events = self.fusion.process(s, s.arrival_us);
        self.events_to_host(&mut events);
        let base = self.base;
        let est = &self.fusion.est;
        let out = &mut self.outputs;
        if let Some(mut p) = est.pose() {
            if self.last_pose_us != Some(p.time_us) {
                self.last_pose_us = Some(p.time_us);
                p.time_us = base.to_host(p.time_us);
                // From this thread, before anything else: no hop, no wait.
                (out.on_pose)(&p);
                let p = Arc::new(p);
                if out.pose_rate.due(p.time_us) {
                    out.pose_out.send_replace(Some(p.clone()));
                }
                out.pose.send_replace(Some(p));
            }
        }
        publish_events(&self.shared, &events);
        let Some(t) = est.state_time() else { return };
        // Dashboards and debug topics at their rates on the host's clock, whatever the
        // estimator's runs at.
        let t = base.to_host(t);
        // The debug series change with nearly every sample: shared at their own rate,
        // so nobody is woken (and nothing copied) per sample.
        if out.debug_rate.due(t) {
            if base.is_host() {
                // Compared before copied: most ticks change nothing.
                if **out.debug.borrow() != *est.debug() {
                    out.debug.send_replace(Arc::new(est.debug().clone()));
                }
            } else {
                let mut debug = est.debug().clone();
                for pt in debug.series.values_mut() {
                    pt.time_us = base.to_host(pt.time_us);
                }
                if **out.debug.borrow() != debug {
                    out.debug.send_replace(Arc::new(debug));
                }
            }
        }
        if let Some(tick) = self.ticks.build(est, t, self.shared.started_us) {
            let frame = ServerFrame::Tick(Box::new(tick));
            self.shared.hub.publish(t, &frame);
        }
    }

    /// The reference input's clock changed rate: follow it (a new rate means a new
    /// estimator, since its state was integrated over the other clock's time).
    fn rebase(&mut self, change: RateChange, arrival_us: Micros) {
        let reference = self.clock_reference.clone().unwrap_or_default();
        match change {
            RateChange::Refine(b) => {
                self.base = b;
                self.shared.time.set(b, Some(reference));
            }
            RateChange::Rebase(b) => {
                let message = if b.is_host() {
                    format!("{reference}'s clock runs at the host's rate again: the estimator starts again on the host's clock")
                } else {
                    format!(
                        "{reference}'s clock runs {:.2}× the host's (a simulator faster than real time?): the estimator starts again on it, and the outputs follow its rate",
                        b.rate
                    )
                };
                tracing::warn!("{message}");
                self.base = b;
                self.shared
                    .time
                    .set(b, (!b.is_host()).then_some(reference.clone()));
                self.fusion = self.config.fusion();
                self.last_pose_us = None;
                self.ticks = TickBuilder::default();
                let event = EstimatorEvent::new(
                    arrival_us,
                    Some(&reference),
                    message,
                    Event::TimeBase {
                        rate: b.rate,
                        reference: reference.clone(),
                    },
                );
                publish_events(&self.shared, &[event]);
            }
        }
    }

    /// Events leave on the host's clock.
    fn events_to_host(&self, events: &mut [EstimatorEvent]) {
        if !self.base.is_host() {
            for e in events {
                e.time_us = self.base.to_host(e.time_us);
            }
        }
    }

    /// The periodic health check (with or without samples), ingest's rejections and
    /// clock restarts counted against the sensors, and the status snapshot refreshed.
    fn health_tick(&mut self, inputs: &[InputStatus], now: i64) {
        let host_now = now;
        let now = self.base.to_fusion(now);
        for st in inputs {
            let seen = self.rejected_seen.entry(st.id.clone()).or_insert(0);
            if st.rejected > *seen {
                *seen = st.rejected;
                let text = st.last_error.clone().unwrap_or_else(|| "rejected".into());
                self.fusion.rejected(&st.id, "input_rejected", &text, now);
            }
            let seen = self.restarts_seen.entry(st.id.clone()).or_insert(0);
            if st.clock_restarts > *seen {
                *seen = st.clock_restarts;
                let text = st.last_clock_restart.clone().unwrap_or_default();
                let event = EstimatorEvent::new(
                    host_now,
                    Some(&st.id),
                    format!("{}: {text}", st.id),
                    Event::ClockRestart {
                        clock_restarts: st.clock_restarts,
                    },
                );
                publish_events(&self.shared, &[event]);
            }
        }
        let mut events = self.fusion.tick_idle(now);
        self.events_to_host(&mut events);
        publish_events(&self.shared, &events);
        self.refresh_status();
    }

    fn command(&mut self, cmd: Command) -> Vec<EstimatorEvent> {
        let base = self.base;
        let est = &mut self.fusion.est;
        let now = est
            .state_time()
            .unwrap_or_else(|| base.to_fusion(crate::clock::now_us()));
        let mut events = match cmd {
            Command::ResetOrigin => est.reset_origin(now),
            Command::StartFlowCalibration => est.start_flow_calibration(now),
        };
        self.events_to_host(&mut events);
        publish_events(&self.shared, &events);
        self.refresh_status();
        events
    }

    fn refresh_status(&self) {
        let st = self.fusion.est.state_summary();
        let h = verdicts(
            &self.fusion,
            &st,
            self.base.to_fusion(crate::clock::now_us()),
        );
        *crate::sync::lock(&self.shared.status) = Some(st);
        *crate::sync::lock(&self.shared.health) = h;
    }
}

/// Why a sample did not get in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum InletError {
    #[error("the estimator's queue is full")]
    Full,
    #[error("the estimator has stopped")]
    Closed,
}

/// The way samples reach the estimator, from any thread. A sample is fused at once on
/// the thread that brings it (Zenoh's receiving thread) when the estimator is free, so
/// the sample's trip to the VPE has no thread hop; when another thread is fusing, it
/// waits in a bounded queue and that thread fuses it before letting go (a full queue
/// refuses, and the caller counts the drop: nothing waits on the estimator).
pub struct Inlet {
    queue: Mutex<VecDeque<Sample>>,
    capacity: usize,
    pipeline: Mutex<Option<Pipeline>>,
    /// Set by [`Inlet::close`]: later samples are refused without waiting on the lock.
    closed: std::sync::atomic::AtomicBool,
}

impl Inlet {
    pub fn new(pipeline: Pipeline, capacity: usize) -> Self {
        Self {
            queue: Mutex::new(VecDeque::with_capacity(capacity.min(1024))),
            capacity,
            pipeline: Mutex::new(Some(pipeline)),
            closed: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Hand over a sample; it is fused before this returns unless another thread holds
    /// the estimator (which then fuses it).
    pub fn push(&self, s: Sample) -> Result<(), InletError> {
        self.queue(s)?;
        self.fuse_queued_if_free()
    }

    /// Queue a sample without fusing it, never waiting on the estimator: callers that
    /// keep an order across threads queue under their own lock, then fuse outside it.
    pub fn queue(&self, s: Sample) -> Result<(), InletError> {
        if self.closed.load(Relaxed) {
            return Err(InletError::Closed);
        }
        let mut q = crate::sync::lock(&self.queue);
        if q.len() >= self.capacity {
            return Err(InletError::Full);
        }
        q.push_back(s);
        Ok(())
    }

    /// Run `f` on the pipeline, waiting while another thread fuses; then what was queued
    /// meanwhile is fused (here, or by a thread that took the pipeline first). `None`
    /// once closed.
    pub fn with<R>(&self, f: impl FnOnce(&mut Pipeline) -> R) -> Option<R> {
        let r = crate::sync::lock(&self.pipeline).as_mut().map(f);
        // Ignored: closed is closed for the samples pushed meanwhile as well.
        let _ = self.fuse_queued_if_free();
        r
    }

    /// Samples waiting (the estimator is busy on another thread).
    pub fn queue_len(&self) -> usize {
        crate::sync::lock(&self.queue).len()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    pub fn is_closed(&self) -> bool {
        self.closed.load(Relaxed)
    }

    /// Stop: the pipeline is taken out (its pose and debug channels close with it, so
    /// the outputs end); later samples are refused.
    pub fn close(&self) -> Option<Pipeline> {
        self.closed.store(true, Relaxed);
        crate::sync::lock(&self.pipeline).take()
    }

    /// Whoever holds the pipeline fuses the queue until it is empty, and looks again
    /// after letting go: a sample queued by a thread that found the pipeline held is
    /// then always fused by the holder (it was queued before the holder let go).
    fn fuse_queued_if_free(&self) -> Result<(), InletError> {
        while let Some(mut held) = crate::sync::try_lock(&self.pipeline) {
            if held.is_none() {
                crate::sync::lock(&self.queue).clear();
                return Err(InletError::Closed);
            }
            self.fuse_queued(&mut held);
            drop(held);
            if crate::sync::lock(&self.queue).is_empty() {
                break;
            }
        }
        Ok(())
    }

    fn fuse_queued(&self, held: &mut Option<Pipeline>) {
        let Some(p) = held.as_mut() else { return };
        // The queue's lock is not held while fusing: pushers never wait on the filter.
        while let Some(s) = crate::sync::lock(&self.queue).pop_front() {
            p.sample(&s);
        }
    }
}

impl crate::ingest::zenoh_in::SampleSink for Inlet {
    fn queue(&self, s: Sample) -> bool {
        Inlet::queue(self, s).is_ok()
    }

    fn fuse_queued(&self) {
        // Closed: the samples queued meanwhile are cleared, as `push` would refuse them.
        let _ = self.fuse_queued_if_free();
    }
}

/// The estimator's own task: the periodic health check and the control API's
/// commands (samples are fused by the threads that bring them, through the [`Inlet`]).
/// Runs until `stop` resolves, then closes the inlet.
pub async fn run(
    inlet: Arc<Inlet>,
    mut commands: CommandReceiver,
    ingest: Arc<Ingest>,
    stop: impl Future<Output = ()>,
) {
    let mut health_timer = tokio::time::interval(HEALTH_TICK);
    health_timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = health_timer.tick() => {
                let now = crate::clock::now_us();
                // Read before taking the estimator: its holder keeps samples waiting.
                let inputs = ingest.statuses(now);
                inlet.with(|p| p.health_tick(&inputs, now));
            }
            Some((cmd, reply)) = commands.recv() => {
                let events = inlet.with(|p| p.command(cmd)).unwrap_or_default();
                let _ = reply.send(events);
            }
            _ = &mut stop => break,
        }
    }
    if let Some(p) = inlet.close() {
        p.refresh_status();
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::{Imu, SensorData};
    use nalgebra::Vector3;

    fn imu(t: i64) -> Sample {
        Sample {
            source: "imu".into(),
            stamp_us: Some(t),
            arrival_us: t,
            data: SensorData::Imu(Imu::from_rates(
                Some(Vector3::zeros()),
                Some(Vector3::new(0.0, 0.0, 9.81)),
            )),
        }
    }

    /// An inlet with a real pipeline (one IMU input).
    fn inlet(capacity: usize) -> (Arc<Inlet>, Arc<PipelineShared>) {
        let shared = Arc::new(PipelineShared::new(
            Arc::new(Hub::default()),
            0,
            Default::default(),
        ));
        let config = PipelineConfig {
            estimator: EstimatorConfig::default(),
            health: HealthConfig::default(),
            inputs: vec![crate::fusion::InputSpec {
                id: "imu".into(),
                kind: SensorKind::Imu,
                rate_hz: 200.0,
                enabled: true,
            }],
            follow_vehicle_clock: true,
        };
        let outputs = PipelineOutputs {
            on_pose: Box::new(|_| {}),
            pose: watch::channel(None).0,
            pose_out: watch::channel(None).0,
            pose_rate: RateLimit::hz(50.0),
            debug: watch::channel(Arc::new(DebugSeries::default())).0,
            debug_rate: RateLimit::hz(50.0),
        };
        let p = Pipeline::new(config, shared.clone(), outputs);
        (Arc::new(Inlet::new(p, capacity)), shared)
    }

    /// Runs `f` on another thread, to its end, while this thread holds the pipeline.
    fn while_held(inlet: &Arc<Inlet>, f: impl FnOnce(&Inlet) + Send + 'static) {
        let other = inlet.clone();
        inlet.with(|_| {
            let handle = std::thread::spawn(move || f(&other));
            if let Err(panic) = handle.join() {
                std::panic::resume_unwind(panic);
            }
        });
    }

    #[test]
    fn an_imu_clock_at_five_times_the_hosts_becomes_the_estimators() {
        let (inlet, shared) = inlet(8);
        let mut events = shared.events_tx.subscribe();
        // 6 host seconds of a 200 Hz IMU whose stamps run 5× the host's.
        for i in 0..6_000_i64 {
            let mut s = imu(0);
            s.stamp_us = Some(3_000_000 + i * 5_000);
            s.arrival_us = 1_700_000_000_000_000 + i * 1_000;
            inlet.push(s).unwrap();
        }
        let base = shared.time.get();
        assert!((base.rate - 5.0).abs() < 0.01, "{base:?}");
        assert_eq!(shared.time.reference().as_deref(), Some("imu"));
        // Said once, as an event on the host's clock.
        let mut seen = vec![];
        while let Ok(e) = events.try_recv() {
            if e["kind"] == "time_base" {
                seen.push(e);
            }
        }
        assert_eq!(seen.len(), 1, "{seen:?}");
        let t = seen[0]["time_us"].as_i64().unwrap_or(0);
        assert!((t - 1_700_000_004_000_000).abs() < 100_000, "{}", seen[0]);
        assert_eq!(seen[0]["data"]["reference"], "imu");
        // The estimator runs on the IMU's clock: its state time is the stamps'.
        let now = inlet
            .with(|p| p.fusion.est.state_time())
            .flatten()
            .unwrap_or(0);
        assert!((now - (3_000_000 + 5_999 * 5_000)).abs() < 50_000, "{now}");
    }

    #[test]
    fn a_sample_is_fused_on_the_thread_that_brings_it() {
        let (inlet, shared) = inlet(8);
        inlet.push(imu(1_000_000)).unwrap();
        assert_eq!(shared.consumed.load(Relaxed), 1);
        assert_eq!(inlet.queue_len(), 0);
    }

    #[test]
    fn samples_brought_while_another_thread_fuses_are_fused_by_that_thread() {
        // The task holds the pipeline; samples pushed meanwhile from another thread
        // return at once (queued), and are fused before the holder lets go.
        let (inlet, shared) = inlet(8);
        let consumed = shared.clone();
        while_held(&inlet, move |other| {
            for i in 0..3 {
                other.push(imu(1_000_000 + i * 5_000)).unwrap();
            }
            assert_eq!(consumed.consumed.load(Relaxed), 0, "fused while held");
        });
        assert_eq!(shared.consumed.load(Relaxed), 3);
        assert_eq!(inlet.queue_len(), 0);
    }

    #[test]
    fn many_threads_at_once_lose_nothing() {
        let (inlet, shared) = inlet(100_000);
        let threads: Vec<_> = (0..4_i64)
            .map(|k| {
                let inlet = inlet.clone();
                std::thread::spawn(move || {
                    for i in 0..2_000 {
                        inlet.push(imu(1_000_000 + k * 100 + i * 5_000)).unwrap();
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(shared.consumed.load(Relaxed), 8_000);
        assert_eq!(inlet.queue_len(), 0);
    }

    #[test]
    fn a_full_queue_or_a_closed_estimator_refuses() {
        let (inlet, shared) = inlet(1);
        while_held(&inlet, |other| {
            assert_eq!(other.push(imu(1_000_000)), Ok(()));
            assert_eq!(other.push(imu(1_005_000)), Err(InletError::Full));
        });
        assert_eq!(shared.consumed.load(Relaxed), 1);
        assert!(inlet.close().is_some());
        assert_eq!(inlet.push(imu(1_010_000)), Err(InletError::Closed));
        assert!(inlet.with(|_| ()).is_none());
        assert_eq!(shared.consumed.load(Relaxed), 1);
    }
}
