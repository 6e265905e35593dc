//! The estimator: samples in, fused pose and events out. Pure and deterministic: no
//! clock, no I/O; time comes with the samples.
//!
//! Layout (PX4 ekf2 style, one file per aiding source with the same verbs: `checks`,
//! control (start/continue conditions inside `process`), fuse):
//! [`imu`] (prediction input, gyro bias), [`attitude`] (autopilot attitude or own
//! complementary filter), [`gnss`], [`odometry`], [`flow`], [`range`], `baro`, `ground` (on the
//! ground / unaided constraints), [`ekf`] (the maths), [`wrls`] (seed 002's weighted
//! least squares), [`monitor`] (divergence monitors), [`timing`] (clock mapping),
//! [`config`]. `state` holds the filter state they all act on (`Core`) and the verbs
//! they share; `status` the types the estimator shows the world; this file the
//! [`Estimator`] facade (time-ordered log, snapshots, late measurements).
//!
//! Integrity: the filter ([`ekf`]), the bank ([`bank`]: the main filter and one
//! sub-filter per aiding source without it, every prediction applied to all, every
//! update to those it belongs to) and the monitor ([`integrity`]: solution separation
//! per source, fault exclusion, protection levels; "valid" needs both under the alert
//! limits).
//!
//! Time: every sample gets a host time (`timing`): stamp + windowed-minimum clock offset
//! − configured latency. The filter runs on a delayed time horizon, as PX4's EKF2 does:
//! samples wait in a time-ordered log and are fused when the horizon reaches them, so a
//! measurement that arrives late (a GNSS fix ~100 ms after the IMU of the same moment)
//! takes its place in the log and costs one update. The horizon lags the newest sample
//! by the largest lateness seen recently ([`Lateness`], at most [`MAX_HORIZON_US`]);
//! with every source on time it is zero. The [`output`] predictor brings the state at
//! the horizon to the present with the IMU samples ahead of it, so the pose sent is of
//! now. A sample later still (older than what the filter has fused) restores the
//! snapshot of the whole core before it (kept every 50 ms for `history_ms`) and re-runs
//! from there, so the result is the same as if it had arrived in order (bit for bit: the
//! same operations run in the same order). Events of re-run samples are emitted once.
//!
//! Modes: `ekf` (default), `wrls`, `wrls+ekf` (the WRLS position as the EKF's only
//! position measurement, seed 002's layout). Measured on the simulator (300 s of
//! DEMO_STREAMS, tests `sim_*`): position RMSE ekf 0.12 m, wrls 0.16 m, wrls+ekf 0.17 m
//! in the GNSS-anchored frame (GNSS alone 0.89 m, T265 alone 1.21 m in that frame, 0.06 m
//! with an oracle alignment); without GNSS ekf 0.028 m, wrls 0.069 m, wrls+ekf 0.071 m
//! (T265 0.094 m). Only the EKF's covariance is consistent (position NEES 1.8–2.1, expected
//! 3; WRLS treats its sources as independent and is over-confident), hence the default.

pub mod attitude;
pub mod bank;
mod baro;
pub mod config;
pub mod ekf;
mod flow;
mod gnss;
mod ground;
mod imu;
pub mod integrity;
mod measurement;
pub mod monitor;
mod odometry;
mod output;
mod range;
mod state;
mod status;
pub mod timing;
pub mod wrls;

pub use config::{EstimatorConfig, Mode, SourceConfig};
pub use flow::CalState;
pub use integrity::IntegrityConfig;

use crate::event;
use crate::sample::{Sample, SensorData, SensorKind};
use crate::source_map::SourceMap;
use ekf::{IDX_P, IDX_V};
use nalgebra::{Matrix3, Vector3};
use output::{Base, OutputPredictor};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use timing::SourceClocks;

pub use crate::event::{EstimatorEvent, Event};
pub(crate) use state::{BodyVelocity, Core, Ctx};
pub use status::{
    CalibrationStatus, DebugPoint, DebugSeries, DebugTopic, EstimatorStatus, FusedPose,
    IntegrityStatus, Protection, SourceStatus,
};

/// Order of samples at equal times: prediction inputs first.
pub fn rank(k: SensorKind) -> u8 {
    match k {
        SensorKind::Imu => 0,
        SensorKind::Attitude => 1,
        SensorKind::Range => 2,
        SensorKind::Baro => 2,
        SensorKind::Flow => 3,
        SensorKind::Odometry => 4,
        SensorKind::Gnss => 5,
        SensorKind::VehicleState => 6,
        SensorKind::AutopilotEstimate => 7,
    }
}

#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct Key {
    t: i64,
    rank: u8,
    source: Arc<str>,
    seq: u64,
}

#[derive(Debug, Clone)]
struct Entry {
    key: Key,
    data: SensorData,
    /// The health layer's verdict on the source when the sample arrived: the sample is
    /// judged by it whenever the horizon reaches it (and again on a re-run).
    usable: bool,
}

/// The horizon never lags the present by more than this, µs: a source later than this
/// is fused by a re-run from a snapshot instead of holding every output back.
pub const MAX_HORIZON_US: i64 = 250_000;
/// A source's lateness is its largest over the current and the previous window this
/// long (µs, of sample time), so the horizon comes back down when a late source stops
/// being late.
const LATENESS_WINDOW_US: i64 = 2_000_000;

/// How late one source's samples arrive: the newest sample time already seen minus
/// theirs, its maximum over two windows.
#[derive(Debug, Clone, Default)]
struct Lateness {
    window_start: i64,
    current: i64,
    previous: i64,
}

impl Lateness {
    fn observe(&mut self, now: i64, late_by: i64) {
        if now - self.window_start >= LATENESS_WINDOW_US || now < self.window_start {
            self.previous = if now - self.window_start < 2 * LATENESS_WINDOW_US {
                self.current
            } else {
                0
            };
            self.current = 0;
            self.window_start = now;
        }
        self.current = self.current.max(late_by);
    }

    fn peak(&self) -> i64 {
        self.current.max(self.previous)
    }
}

/// The estimator facade.
pub struct Estimator {
    cfg: EstimatorConfig,
    core: Core,
    /// Samples in time order: the first `fused` have been fused, the rest wait for the
    /// horizon.
    log: VecDeque<Entry>,
    fused: usize,
    /// The newest sample time seen (the present, host clock).
    newest_t: Option<i64>,
    lateness: SourceMap<Lateness>,
    output: OutputPredictor,
    snaps: VecDeque<(Key, Core)>,
    clocks: SourceClocks,
    usable: SourceMap<(bool, String)>,
    gates: [f64; 7],
    seq: u64,
    /// Samples older than this are dropped (history cleared by a command).
    barrier: Option<i64>,
    emitted: BTreeSet<(i64, &'static str, Option<String>, String)>,
    late_dropped: u64,
    late_event_t: Option<i64>,
    /// The caller's clock when it last looked without a sample (see `observe_time`).
    observed_t: Option<i64>,
    invalid_texts: state::InvalidTexts,
    /// EKF2's IMU down-sampling in front of the filter (`predict_period_ms`).
    imu_down: imu::DownSampler,
    imu_passed: Vec<(i64, crate::sample::Imu)>,
    /// Per aiding source, the delay the filter has found beyond its configured latency
    /// and moved into its samples' times, µs (see [`Self::adopt_delays`]), and the
    /// newest time given to one of its samples.
    delay_shift: SourceMap<(i64, i64)>,
    /// Where each anchor of relative navigation put the frame, as first made: (filter
    /// time, E, N). The poses sent since are in that frame, so a re-run of the history
    /// (a late sample) that anchors again puts it at the same place, not where the
    /// re-run has the vehicle (randomised draw 134: re-run four times over a flow back
    /// from a long gap, the anchor moved 0.8 m under poses sent with σ 1 cm).
    anchors: Vec<(i64, [f64; 2])>,
}

/// An estimated delay is moved into the source's sample times once it is this large,
/// µs, and known to within [`DELAY_ADOPT_STD_US`].
const DELAY_ADOPT_US: i64 = 10_000;
const DELAY_ADOPT_STD_US: f64 = 30_000.0;
/// Bounds of the delay moved into a source's sample times, µs: what a sensor, a bridge
/// and a queue plausibly add to (or take from) its configured latency.
const DELAY_SHIFT_MIN_US: i64 = -100_000;
const DELAY_SHIFT_MAX_US: i64 = 600_000;
/// At most this part of the history (`history_ms`), less how late the source arrives,
/// is moved into its sample times: a sample moved earlier than the oldest snapshot is
/// dropped, and a source whose every sample is dropped can never show its delay was
/// wrong. A GNSS arriving 135 ms after its stamps, its delay taken for 440 ms on laps
/// (a delay and a turn look alike there), had its fixes dropped as older than the
/// 500 ms history, for 16 s at a time (randomised draw 488).
const DELAY_SHIFT_HISTORY_PARTS: (i64, i64) = (4, 5);

/// A snapshot of the core at most this often, µs. Any earlier snapshot re-runs to the
/// same state, so the spacing trades the clones (the core is large: maps, series,
/// matrices) against what a late measurement re-runs.
const SNAPSHOT_EVERY_US: i64 = 50_000;

impl Estimator {
    pub fn new(cfg: EstimatorConfig) -> Self {
        let mut gates = [0.0; 7];
        for (k, g) in gates.iter_mut().enumerate().skip(1) {
            *g = ekf::chi2_gate(k, cfg.gate_sigma);
        }
        Self {
            invalid_texts: state::InvalidTexts::new(&cfg),
            core: Core::new(&cfg),
            log: VecDeque::new(),
            fused: 0,
            newest_t: None,
            lateness: SourceMap::new(),
            output: OutputPredictor::new((cfg.imu_timeout_ms * 1000.0) as i64),
            cfg,
            snaps: VecDeque::new(),
            clocks: SourceClocks::default(),
            usable: SourceMap::new(),
            gates,
            seq: 0,
            barrier: None,
            emitted: BTreeSet::new(),
            late_dropped: 0,
            late_event_t: None,
            observed_t: None,
            imu_down: imu::DownSampler::default(),
            imu_passed: Vec::new(),
            delay_shift: SourceMap::new(),
            anchors: Vec::new(),
        }
    }

    /// A source's delay, once the filter knows it, moves from its state into the times
    /// its samples are fused at: the filter then sees each at the moment it measured,
    /// and its delay state only the rest, small, where the first-order model of it is
    /// exact (a camera 0.3 s late on a vehicle turning at a rad/s is not). The shift
    /// is taken out of the state of every filter, in every snapshot too.
    fn adopt_delays(&mut self) {
        let Some(bank) = self.core.ekf.as_ref() else {
            return;
        };
        let mut moves = Vec::new();
        for (source, idx) in &bank.delays {
            let tau_us = bank.x[*idx] * 1e6;
            let std_us = bank.p[(*idx, *idx)].max(0.0).sqrt() * 1e6;
            // Known, and well beyond its own uncertainty.
            if tau_us.abs() < DELAY_ADOPT_US as f64
                || std_us > DELAY_ADOPT_STD_US
                || std_us * 3.0 > tau_us.abs()
            {
                continue;
            }
            let shift = self.delay_shift.get(source).map_or(0, |d| d.0);
            // Never beyond what the history holds (see `DELAY_SHIFT_HISTORY_PARTS`). How
            // late it arrives unshifted: its lateness is measured on shifted times, and a
            // window from before the shift reads less, never more.
            let arrives_late = self
                .lateness
                .get(source)
                .map_or(0, |l| (l.peak() - shift).max(0));
            let (part, whole) = DELAY_SHIFT_HISTORY_PARTS;
            let history_us = (self.cfg.history_ms * 1000.0) as i64;
            let most = (history_us * part / whole - arrives_late).min(DELAY_SHIFT_MAX_US);
            let to = (shift + tau_us.round() as i64)
                .clamp(DELAY_SHIFT_MIN_US, most.max(DELAY_SHIFT_MIN_US));
            if to != shift {
                moves.push((source.clone(), *idx, to, (to - shift) as f64 * 1e-6));
            }
        }
        for (source, idx, to, moved_s) in moves {
            self.delay_shift
                .get_or_insert_with(&source, || (0, i64::MIN))
                .0 = to;
            let adjust = |b: &mut bank::Bank| b.each(|e| e.x[idx] -= moved_s);
            let lower_floor = |c: &mut Core| {
                if let Some(f) = c.delay_floor_s.get_mut(&source) {
                    *f -= moved_s;
                }
            };
            if let Some(b) = self.core.ekf.as_mut() {
                adjust(b);
            }
            lower_floor(&mut self.core);
            for (_, snap) in self.snaps.iter_mut() {
                if let Some(b) = snap.ekf.as_mut().filter(|b| b.n() > idx) {
                    adjust(b);
                }
                lower_floor(snap);
            }
        }
    }

    /// Time has reached `now_us` (host clock) whether or not samples came: validity is
    /// judged at this time, so an estimate whose sources all went silent (a lost Zenoh
    /// link) turns invalid after `aiding_timeout_ms` instead of staying valid, frozen;
    /// and the horizon moves on, so samples waiting for it are fused.
    pub fn observe_time(&mut self, now_us: i64) -> Vec<EstimatorEvent> {
        self.observed_t = Some(now_us);
        let limit = now_us.saturating_sub(self.horizon_us());
        let out = self.run_to(limit, None);
        self.prune();
        out
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    /// When validity is judged (host clock): the newest sample's time, or the caller's
    /// clock when it has seen time pass without samples.
    fn judged_at(&self) -> Option<i64> {
        self.observed_t.max(self.newest_t)
    }

    /// Why the estimate is not valid now (`None`: valid).
    fn invalid_reason(&self) -> Option<String> {
        self.core
            .validity(&self.cfg, self.judged_at())
            .map(|why| self.invalid_texts.get(why))
    }

    /// How far behind the newest sample the filter fuses, µs.
    pub fn horizon_us(&self) -> i64 {
        let max = MAX_HORIZON_US.min((self.cfg.history_ms * 500.0) as i64);
        self.lateness
            .values()
            .map(Lateness::peak)
            .max()
            .unwrap_or(0)
            .clamp(0, max.max(0))
    }

    /// Feed one sample; returns the events it caused.
    pub fn process(&mut self, s: &Sample) -> Vec<EstimatorEvent> {
        let kind = s.data.kind();
        if kind == SensorKind::AutopilotEstimate {
            return vec![];
        }
        let src: &str = &s.source;
        if self.cfg.sources.get(src).is_some_and(|c| !c.fuse) {
            return vec![];
        }
        let mapped = self.clocks.host_time(&self.cfg, s);
        let mut t = mapped;
        if kind != SensorKind::Imu {
            if self.core.delay_floor_s.get(src).is_none() {
                let floor = -(self.cfg.latency_us(src, kind) as f64) * 1e-6;
                self.core.delay_floor_s.put(src, floor);
                for (_, snap) in self.snaps.iter_mut() {
                    snap.delay_floor_s.put(src, floor);
                }
            }
            let (shift, newest) = self.delay_shift.get_or_insert_with(src, || (0, i64::MIN));
            t -= *shift;
            // A source whose samples were just moved earlier skips those that would
            // land among the ones it already has (they measured the same stretch):
            // two interleaved series of one sensor make its readings jump back and
            // forth, which it never did.
            if *shift != 0 && t <= *newest {
                return vec![];
            }
            *newest = (*newest).max(t);
        }
        let key = Key {
            t,
            rank: rank(kind),
            source: s.source.clone(),
            seq: self.next_seq(),
        };
        // Older than every snapshot: too old, unless the first is of the empty filter
        // (start-up: a slower source's first sample is older than the IMU's first).
        let too_old = self.barrier.is_some_and(|b| t < b)
            || self
                .snaps
                .front()
                .is_some_and(|(k, c)| key < *k && c.t.is_some());
        if too_old {
            self.late_dropped += 1;
            if self.late_event_t.is_none_or(|l| t - l > 1_000_000 || t < l) {
                self.late_event_t = Some(t);
                let ev = EstimatorEvent::new(
                    t,
                    Some(src),
                    format!(
                        "{src}: sample older than the {} ms history dropped",
                        self.cfg.history_ms
                    ),
                    Event::LateDrop {
                        dropped: self.late_dropped,
                    },
                );
                return vec![ev];
            }
            return vec![];
        }
        // The present is the newest time a sample arrived for, not the moment a late
        // source measured (its shift is how late it is).
        let newest = self.newest_t.map_or(mapped, |n| n.max(mapped));
        self.newest_t = Some(newest);
        self.lateness
            .get_or_insert_with(src, || Lateness {
                window_start: newest,
                ..Lateness::default()
            })
            .observe(newest, newest - t);
        let usable = self.usable.get(src).is_none_or(|u| u.0);
        let fused_to = match &s.data {
            SensorData::Imu(imu) if usable && imu::checks(imu).is_ok() => {
                let rate = imu
                    .gyro
                    .map_or(Vector3::zeros(), |g| g - self.core.imu.gyro_bias);
                self.output.push(t, rate, imu.accel);
                // The filter gets the down-sampled IMU; the output predictor had them all.
                let mut passed = std::mem::take(&mut self.imu_passed);
                let period_us = (self.cfg.predict_period_ms * 1000.0) as i64;
                self.imu_down.add(&s.source, t, imu, period_us, &mut passed);
                let mut fused_to = None;
                for (i, (t, imu)) in passed.drain(..).enumerate() {
                    // A second one (what waited, then this sample) is an entry of its own.
                    let seq = if i == 0 { key.seq } else { self.next_seq() };
                    let key = Key {
                        t,
                        seq,
                        ..key.clone()
                    };
                    fused_to = fused_to.max(self.insert(key, SensorData::Imu(imu), usable));
                }
                self.imu_passed = passed;
                fused_to
            }
            data => self.insert(key, data.clone(), usable),
        };
        let limit = newest - self.horizon_us();
        let out = self.run_to(limit, fused_to.as_ref());
        self.prune();
        if kind != SensorKind::Imu {
            self.adopt_delays();
        }
        out
    }

    /// Puts a sample into the log; one later than the horizon restores the snapshot
    /// before it. Returns how far the re-run must fuse (the last sample fused before).
    fn insert(&mut self, key: Key, data: SensorData, usable: bool) -> Option<Key> {
        let pos = self.log.partition_point(|e| e.key < key);
        self.log.insert(
            pos,
            Entry {
                key: key.clone(),
                data,
                usable,
            },
        );
        // A re-run fuses at least as far as before: the horizon never moves back.
        let mut fused_to = None;
        if pos < self.fused {
            // Later than the horizon: restore the snapshot before it and re-run. Before
            // the first one only when that is of the empty filter (else it was too old).
            // The new sample sits before it, so the last fused one is now at `fused`.
            fused_to = self.log.get(self.fused).map(|e| e.key.clone());
            let si = self
                .snaps
                .partition_point(|(k, _)| *k <= key)
                .saturating_sub(1);
            let Some((skey, core)) = self.snaps.get(si).cloned() else {
                self.log.remove(pos);
                return None;
            };
            self.core = core;
            self.snaps.truncate(si);
            let from = skey.min(key);
            self.fused = self.log.partition_point(|e| e.key < from);
        }
        fused_to
    }

    /// Fuse every sample into the filter now, whatever the horizon (the end of a log).
    pub fn flush(&mut self) -> Vec<EstimatorEvent> {
        self.pass_waiting_imu();
        let out = self.run_to(i64::MAX, None);
        self.prune();
        out
    }

    /// The next sample's place among equal times.
    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq - 1
    }

    /// Puts the IMU samples the down-sampler still holds into the log.
    fn pass_waiting_imu(&mut self) {
        for (source, t, imu) in self.imu_down.take_all() {
            // Already fused past it (a command cleared the history): it is too old.
            if self.barrier.is_some_and(|b| t < b) {
                continue;
            }
            let key = Key {
                t,
                rank: rank(SensorKind::Imu),
                source,
                seq: self.next_seq(),
            };
            self.insert(key, SensorData::Imu(imu), true);
        }
    }

    /// Fuse the waiting samples up to time `limit`, and at least up to `through`.
    fn run_to(&mut self, limit: i64, through: Option<&Key>) -> Vec<EstimatorEvent> {
        let mut out = vec![];
        while let Some(e) = self.log.get(self.fused) {
            if e.key.t > limit && through.is_none_or(|k| e.key > *k) {
                break;
            }
            let snap = self
                .snaps
                .back()
                .is_none_or(|(k, _)| e.key.t - k.t >= SNAPSHOT_EVERY_US);
            if snap {
                self.snaps.push_back((e.key.clone(), self.core.clone()));
            }
            let ctx = Ctx {
                cfg: &self.cfg,
                usable: &self.usable,
                gates: self.gates,
                anchors: &self.anchors,
            };
            self.core
                .process_entry(e.key.t, &e.key.source, &e.data, e.usable, &ctx);
            if let Some((k, t, at)) = self.core.integrity.last_anchor {
                if self.anchors.get(k).map(|a| a.1) != Some(at) {
                    self.anchors.truncate(k);
                    self.anchors.push((t, at));
                }
            }
            for ev in self.core.events.drain(..) {
                let sig = (ev.time_us, ev.kind(), ev.source.clone(), ev.message.clone());
                if self.emitted.insert(sig) {
                    out.push(ev);
                }
            }
            self.fused += 1;
        }
        if let Some(e) = self.fused.checked_sub(1).and_then(|i| self.log.get(i)) {
            self.output.drop_through(e.key.t);
        }
        out
    }

    fn prune(&mut self) {
        let Some(newest) = self.newest_t else {
            return;
        };
        let horizon = newest - (self.cfg.history_ms * 1000.0) as i64;
        while self.snaps.len() >= 2 && self.snaps[1].0.t < horizon {
            self.snaps.pop_front();
        }
        // Only fused samples go: every snapshot is of a fused one.
        if let Some((k, _)) = self.snaps.front() {
            while self.fused > 0 && self.log.front().is_some_and(|e| e.key < *k) {
                self.log.pop_front();
                self.fused -= 1;
            }
        }
        let keep = horizon - 1_000_000;
        while self.emitted.first().is_some_and(|s| s.0 < keep) {
            self.emitted.pop_first();
        }
    }

    /// Drop the history (after a command changed the state): later samples older than
    /// now cannot be re-run across the change. Samples still waiting for the horizon
    /// stay.
    fn clear_history(&mut self) {
        self.barrier = self.core.t;
        self.log.drain(..self.fused);
        self.fused = 0;
        self.snaps.clear();
    }

    /// Time of the newest processed sample (host clock, µs).
    pub fn state_time(&self) -> Option<i64> {
        self.core.t
    }

    /// The time [`Self::pose`] would carry, without computing the pose (None when it
    /// would be None): the WRLS tick, or the present the filter's state is brought to.
    pub fn pose_time(&self) -> Option<i64> {
        let c = &self.core;
        if !c.initialised() {
            return None;
        }
        if c.mode_wrls {
            return c.wrls.t;
        }
        c.ekf.as_ref()?;
        let t = c.pred_t?;
        Some(self.newest_t.map_or(t, |n| n.max(t)))
    }

    /// Latest fused estimate (None before initialisation).
    pub fn pose(&self) -> Option<FusedPose> {
        let c = &self.core;
        let present = self.pose_time()?;
        let mut orientation = c.att.q;
        let mut angular_velocity = c.imu.rate.map(|r| r.1);
        let (time_us, position, velocity, position_cov, velocity_cov) = if c.mode_wrls {
            let period = self.cfg.wrls_period_ms * 1e-3;
            (
                present,
                c.wrls.x?,
                c.wrls.last_delta / period,
                Matrix3::from_diagonal(&c.wrls.var),
                Matrix3::from_diagonal(&(c.wrls.last_delta_var / (period * period))),
            )
        } else {
            // The filter's state at the horizon, brought to the present.
            let e = c.ekf.as_ref()?;
            let t = c.pred_t?;
            // The attitude turned back by its heading error: the pose's orientation is
            // in the frame of its position.
            let heading =
                nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -e.yaw_error());
            let base = Base {
                t,
                p: e.pos(),
                v: e.vel(),
                q: heading * c.att.q,
                accel_bias: e.accel_bias(),
                held: c.imu.last.as_ref().map(|l| (l.t, l.accel)),
                attitude_known: c.att.known(),
            };
            let now = self.output.predict(&base, present);
            orientation = now.q;
            angular_velocity = now.rate.or(angular_velocity);
            // The covariance sent: the main filter's, and the solutions' disagreement
            // that no test has resolved (see `integrity`).
            let mut position_cov = e.cov3(IDX_P);
            if self.cfg.integrity.enabled {
                for (a, v) in c.integrity.unresolved_var.iter().enumerate() {
                    position_cov[(a, a)] += v;
                }
            }
            // Brought to the present on the velocity: its uncertainty over the span
            // (the horizon's delay, a few hundred ms) is the position's too, which
            // shows where the position's own is nil (a frame just re-anchored).
            let ahead = (present - t).max(0) as f64 * 1e-6;
            let velocity_cov = e.cov3(IDX_V);
            position_cov += velocity_cov * (ahead * ahead);
            (present, now.p, now.v, position_cov, velocity_cov)
        };
        let mut invalid_reason = self.invalid_reason();
        let finite = position
            .iter()
            .chain(velocity.iter())
            .all(|v| v.is_finite())
            && position_cov.iter().all(|v| v.is_finite())
            && velocity_cov.iter().all(|v| v.is_finite())
            && orientation.coords.iter().all(|v| v.is_finite());
        if !finite && invalid_reason.is_none() {
            invalid_reason = Some("non-finite value in the estimate".into());
        }
        let protection = integrity::protection_at(c, &self.cfg.integrity, time_us, &velocity_cov);
        if invalid_reason.is_none() && !protection.within_alert_limits() {
            invalid_reason = Some(self.invalid_texts.get(state::Invalid::Protection));
        }
        Some(FusedPose {
            time_us,
            position,
            velocity,
            orientation,
            angular_velocity,
            position_cov,
            velocity_cov,
            orientation_cov: c.att.cov,
            sources: c.used_set.clone(),
            reset_counter: c.reset_counter,
            valid: invalid_reason.is_none(),
            invalid_reason,
            origin: c
                .gnss
                .origin
                .map(|o| (o.origin_lat_deg, o.origin_lon_deg, o.origin_alt_m)),
            protection,
        })
    }

    /// The main filter's state and covariance diagonal, with the names of the states
    /// (for a developer looking at one flight).
    pub fn filter_state(&self) -> Option<(Vec<f64>, Vec<f64>, Vec<String>)> {
        let e = self.core.ekf.as_ref()?;
        Some((
            e.x.iter().copied().collect(),
            e.p.diagonal().iter().copied().collect(),
            e.state_names(),
        ))
    }

    /// Per-source debug series of the last update.
    pub fn debug(&self) -> &DebugSeries {
        &self.core.debug
    }

    /// The health layer says whether a source may be fused.
    pub fn set_source_usable(
        &mut self,
        source: &str,
        usable: bool,
        reason: &str,
    ) -> Vec<EstimatorEvent> {
        let before = self.usable.get(source).is_none_or(|u| u.0);
        self.usable.put(source, (usable, reason.to_string()));
        if before == usable {
            return vec![];
        }
        vec![EstimatorEvent::new(
            self.core.t.unwrap_or(0),
            Some(source),
            format!(
                "{source} {} by health: {reason}",
                if usable { "enabled" } else { "disabled" }
            ),
            Event::SourceUsable {
                usable,
                reason: reason.to_string(),
            },
        )]
    }

    /// Make the current horizontal position the new origin (a discontinuity).
    pub fn reset_origin(&mut self, now_us: i64) -> Vec<EstimatorEvent> {
        // The present position (what the outputs show) becomes the origin.
        let Some(p) = self.pose().map(|p| p.position) else {
            return vec![];
        };
        let c = &mut self.core;
        let d = Vector3::new(-p.x, -p.y, 0.0);
        if let Some(bank) = c.ekf.as_mut() {
            bank.each(|ekf| ekf.shift_position(d));
        }
        c.wrls.shift(d);
        c.monitors.shift(d);
        for (_, at) in self.anchors.iter_mut() {
            *at = [at[0] + d.x, at[1] + d.y];
        }
        if let Some((_, _, at)) = c.integrity.last_anchor.as_mut() {
            *at = [at[0] + d.x, at[1] + d.y];
        }
        for st in c.odom.values_mut() {
            if let Some(a) = st.align.as_mut() {
                a.trans += d;
            }
        }
        if let Some(o) = c.gnss.origin {
            let (lat, lon, alt) = o.to_geodetic(Vector3::new(p.x, p.y, 0.0));
            c.gnss.origin = Some(crate::geo::LocalEnu::new(lat, lon, alt));
            for (_, last) in c.gnss.last.values_mut() {
                *last += d;
            }
        }
        c.reset_counter = c.reset_counter.wrapping_add(1);
        let ev = EstimatorEvent::new(
            now_us,
            None,
            format!("origin reset: moved by ({:.2}, {:.2}) m", d.x, d.y),
            Event::Reset(event::Reset::Origin {
                shift: d.into(),
                reset_counter: c.reset_counter,
            }),
        );
        self.clear_history();
        vec![ev]
    }

    /// Start the flow scale calibration (ArduPilot style); the result comes as a
    /// `calibration_result` event.
    pub fn start_flow_calibration(&mut self, now_us: i64) -> Vec<EstimatorEvent> {
        self.core.flow_cal.start(now_us);
        for (_, s) in self.snaps.iter_mut() {
            s.flow_cal.start(now_us);
        }
        vec![EstimatorEvent::new(
            now_us,
            None,
            "flow scale calibration started: fly with horizontal motion".into(),
            Event::CalibrationStarted {
                samples_per_axis: self.cfg.flow_cal_samples,
            },
        )]
    }

    /// Innovation test ratio of the last update per source: 0..; > 1 rejected.
    pub fn test_ratios(&self) -> impl Iterator<Item = (&str, f64)> {
        self.core
            .stats
            .iter()
            .filter(|(_, s)| !s.innovation.is_empty())
            .map(|(k, s)| (k.as_str(), s.test_ratio))
    }

    pub fn state_summary(&self) -> EstimatorStatus {
        let c = &self.core;
        let invalid_reason = self.invalid_reason();
        let sources: BTreeMap<String, SourceStatus> = c
            .stats
            .iter()
            .map(|(s, st)| {
                let mut st = st.clone();
                st.usable = self.usable.get(s).is_none_or(|u| u.0);
                st.segment = c.odom.get(s).map(|o| o.segment);
                (s.clone(), st)
            })
            .collect();
        let (trace, std, bias) = match (&c.ekf, c.mode_wrls) {
            (Some(e), false) => {
                let d = e.cov3(IDX_P).diagonal();
                let b = e.accel_bias();
                (
                    Some(e.p.trace()),
                    Some([d.x.sqrt(), d.y.sqrt(), d.z.sqrt()]),
                    Some([b.x, b.y, b.z]),
                )
            }
            _ => (
                c.wrls.x.map(|_| c.wrls.var.sum()),
                c.wrls.x.map(|_| {
                    [
                        c.wrls.var.x.sqrt(),
                        c.wrls.var.y.sqrt(),
                        c.wrls.var.z.sqrt(),
                    ]
                }),
                None,
            ),
        };
        EstimatorStatus {
            mode: self.cfg.mode.as_str(),
            initialised: c.initialised(),
            valid: invalid_reason.is_none(),
            invalid_reason,
            time_us: c.t,
            origin: c
                .gnss
                .origin
                .map(|o| (o.origin_lat_deg, o.origin_lon_deg, o.origin_alt_m)),
            reset_counter: c.reset_counter,
            sources_used: c.used_set.clone(),
            attitude_source: c.att.source.as_str(),
            covariance_trace: trace,
            position_std: std,
            accel_bias: bias,
            gyro_bias: [c.imu.gyro_bias.x, c.imu.gyro_bias.y, c.imu.gyro_bias.z],
            sources,
            calibration: CalibrationStatus {
                state: c.flow_cal.state,
                source: c.flow_cal.source.clone(),
                samples: [c.flow_cal.samples[0].len(), c.flow_cal.samples[1].len()],
                result: c.flow_cal.result.map(|r| [r.x, r.y]),
            },
            monitor: c.monitors.last,
            history_len: self.log.len(),
            late_dropped: self.late_dropped,
            clock_offsets_us: self
                .clocks
                .iter()
                .filter_map(|(s, c)| c.offset_us().map(|o| (s.clone(), o)))
                .collect(),
            timed_by_arrival: self
                .clocks
                .iter()
                .filter(|(_, c)| !c.stamps_usable())
                .filter_map(|(s, c)| c.stamp_rate.map(|r| (s.clone(), r)))
                .collect(),
            integrity: status::IntegrityStatus {
                protection: integrity::protection(c, &self.cfg.integrity),
                tests: c.integrity.tests.clone(),
                excluded: c
                    .integrity
                    .excluded
                    .iter()
                    .map(|(s, _)| s.clone())
                    .collect(),
                exclusions: c.integrity.exclusions,
                // The one farthest from the estimate, of those the exclusions set aside.
                set_aside: c.ekf.as_ref().and_then(|b| {
                    let (s, d) = b
                        .shadows()
                        .iter()
                        .map(|s| (s, b.main().pos() - s.ekf.pos()))
                        .max_by(|x, y| x.1.norm().total_cmp(&y.1.norm()))?;
                    Some(status::SetAside {
                        source: s.with.clone(),
                        separation: [d.x, d.y, d.z],
                    })
                }),
            },
        }
    }
}

#[cfg(test)]
mod tests;
