//! The filter's evolving state ([`Core`]: everything that changes with the samples,
//! snapshotted for late measurements) and the shared verbs the sensor modules use on
//! it: gating and recording updates, events, aiding, validity, initialisation.

use super::attitude::{self, AttitudeState};
use super::bank::Bank;
use super::ekf::{self, Ekf, Measurement, UpdateOutcome, GRAVITY, IDX_BA, IDX_P, IDX_V};
use super::flow::{self, FlowCalibrator, FlowState};
use super::gnss::{self, GnssState};
use super::ground;
use super::imu::{self, ImuState};
use super::integrity::{self, Channels, IntegrityState};
use super::monitor::{MonitorReset, Monitors};
use super::odometry::{self, OdomState};
use super::range;
use super::wrls::{Wrls, WrlsOutput};
use super::{DebugSeries, DebugTopic, EstimatorConfig, EstimatorEvent, Event, Mode, SourceStatus};
use crate::event;
use crate::sample::{SensorData, SensorKind};
use crate::source_map::SourceMap;
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

/// A source counts as used for at most this long after its last sample, µs, however
/// slow it is.
const MAX_USED_GAP_US: i64 = 10_000_000;
/// The longest step the filter predicts in one go, s (see `predict_to`).
const MAX_PREDICT_STEP_S: f64 = 0.1;

/// What a body-frame velocity comes from (see [`Core::fuse_body_velocity`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BodyVelocity {
    /// A flow's two horizontal axes, scaled by `slant` (m, along the body's down
    /// axis); `height_scale`: the filter's own height above the terrain (m) when that
    /// is what scaled it; `gyro_bias_tau_s`: how fast the bias error of the IMU gyro
    /// that compensated it fades (infinite: nothing learns it; none: its own gyro did).
    Flow {
        slant: f64,
        height_scale: Option<f64>,
        gyro_bias_tau_s: Option<f64>,
    },
    /// An odometry's three axes.
    Odometry,
}

/// Read-only context of one processing step.
pub(crate) struct Ctx<'a> {
    pub cfg: &'a EstimatorConfig,
    pub usable: &'a SourceMap<(bool, String)>,
    pub gates: [f64; 7],
    /// Where each anchor of relative navigation put the frame, in order: (filter time,
    /// E, N) (see `integrity::reanchor`).
    pub anchors: &'a [(i64, [f64; 2])],
}

impl Ctx<'_> {
    pub(super) fn gate(&self, dof: usize) -> f64 {
        self.gates[dof.min(6)]
    }
    pub(super) fn usable(&self, source: &str) -> bool {
        self.usable.get(source).is_none_or(|u| u.0)
    }
}

pub(super) fn kind_str(k: SensorKind) -> &'static str {
    k.as_str()
}

/// Everything that evolves with the samples (snapshotted for late measurements).
#[derive(Clone, Debug, Default)]
pub(crate) struct Core {
    pub t: Option<i64>,
    pub pred_t: Option<i64>,
    /// The main filter and its sub-filters ([`Bank`]; reads go to the main one).
    pub ekf: Option<Bank>,
    /// The separation tests, exclusions and protection levels ([`integrity`]).
    pub integrity: IntegrityState,
    /// The slow part of GNSS's error as the first fix said it, for a filter it starts.
    pub gnss_bias_prior: Option<Vector3<f64>>,
    /// After a reset to a refused source: (source, invalid until, accepted since).
    pub converging: Option<(String, i64, bool)>,
    pub att: AttitudeState,
    pub imu: ImuState,
    pub gnss: GnssState,
    pub odom: SourceMap<OdomState>,
    pub flow: SourceMap<FlowState>,
    pub flow_cal: FlowCalibrator,
    /// Latest range per source: (time, slant distance).
    pub range: SourceMap<(i64, f64)>,
    /// Per barometer, its datum.
    pub baro: SourceMap<super::baro::BaroState>,
    /// Per range source, the last reading its sensor flagged invalid or that was at or
    /// beyond its maximum (the quality hysteresis counts from it).
    pub range_bad: SourceMap<i64>,
    /// Per aiding source, the least its delay state may be, s: a sample cannot have
    /// been measured after the time it is given plus its configured latency (that time
    /// is its arrival, or its stamp mapped no later than its arrival), so its delay
    /// beyond that latency is at least −latency, less what has been moved into its
    /// sample times. Unbounded below, a camera 280 ms late and a flow 108 ms late read
    /// −264 and −398 ms at take-off on randomised draw 860 (the state lagging both, each
    /// looked early against it) and the height left by 3 m for good.
    pub delay_floor_s: SourceMap<f64>,
    /// On the ground / at rest, and the constraints without horizontal aiding.
    pub ground: ground::GroundState,
    pub wrls: Wrls,
    /// The ticks [`Wrls::tick`] just ran (kept for its room: no allocation per tick).
    wrls_out: Vec<WrlsOutput>,
    pub wrls_ekf_last: Option<i64>,
    pub monitors: Monitors,
    pub reset_counter: u8,
    pub stats: SourceMap<SourceStatus>,
    pub debug: DebugSeries,
    pub events: Vec<EstimatorEvent>,
    /// When an event of each kind (outer key) was last emitted for each source.
    pub throttle: BTreeMap<&'static str, SourceMap<i64>>,
    pub last_aiding: Option<i64>,
    /// Last accepted measurement of the height (the lock-out rule's clock for it).
    pub last_v_aiding: Option<i64>,
    /// Last horizontal aiding, real or the ground constraint (validity).
    pub last_h_valid: Option<i64>,
    /// Since when the estimate has been dead-reckoning (no position source beyond the
    /// aiding timeout); cleared when an absolute position source takes hold again.
    pub unaided_since: Option<i64>,
    pub used_set: Vec<String>,
    pub mode_wrls: bool,
    pub mode_ekf_direct: bool,
    pub wrls_period_s: f64,
}

pub(super) const AIDING: [&str; 5] = ["gnss", "odometry", "flow", "range", "baro"];
/// The aiding sources that hold the horizontal position or velocity.
pub(super) const HORIZONTAL_AIDING: [&str; 3] = ["gnss", "odometry", "flow"];

impl Core {
    pub(super) fn new(cfg: &EstimatorConfig) -> Self {
        Self {
            mode_wrls: cfg.mode == Mode::Wrls,
            mode_ekf_direct: cfg.mode == Mode::Ekf,
            wrls_period_s: cfg.wrls_period_ms * 1e-3,
            ..Self::default()
        }
    }

    pub fn initialised(&self) -> bool {
        if self.mode_wrls {
            self.wrls.x.is_some()
        } else {
            self.ekf.is_some()
        }
    }

    pub fn position(&self) -> Option<Vector3<f64>> {
        if self.mode_wrls {
            self.wrls.x
        } else {
            self.ekf.as_ref().map(|e| e.pos())
        }
    }

    pub fn velocity(&self) -> Option<Vector3<f64>> {
        if self.mode_wrls {
            self.wrls
                .x
                .map(|_| self.wrls.last_delta / self.wrls_period_s())
        } else {
            self.ekf.as_ref().map(|e| e.vel())
        }
    }

    pub(super) fn wrls_period_s(&self) -> f64 {
        self.wrls_period_s.max(1e-6)
    }

    pub fn ekf_fuses_sensors(&self, _ctx: &Ctx) -> bool {
        self.mode_ekf_direct
    }

    pub fn event(&mut self, t: i64, source: Option<&str>, message: String, what: Event) {
        self.events
            .push(EstimatorEvent::new(t, source, message, what));
    }

    /// An event of `kind` for `source`, unless one was emitted less than the throttle
    /// interval ago: `make` (its message and payload) runs only when it is.
    pub(super) fn throttled_event(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        make: impl FnOnce() -> (String, Event),
        ctx: &Ctx,
    ) {
        let every = (ctx.cfg.event_throttle_ms * 1000.0) as i64;
        let last = self
            .throttle
            .entry(kind)
            .or_default()
            .get_or_insert_with(source, || i64::MIN);
        if *last != i64::MIN && t - *last < every && t >= *last {
            return;
        }
        *last = t;
        let (message, what) = make();
        debug_assert_eq!(what.kind(), kind, "the throttle's kind is the event's");
        self.event(t, Some(source), message, what);
    }

    /// The statistics of `source` (created on its first sample; no allocation after).
    pub(super) fn stat(&mut self, source: &str) -> &mut SourceStatus {
        self.stats.get_or_insert_with(source, SourceStatus::default)
    }

    /// A sample failed its checks.
    pub fn reject(&mut self, t: i64, source: &str, why: &str, ctx: &Ctx) {
        let st = self.stat(source);
        st.last_time_us = Some(t);
        if st.last_reject_reason.as_deref() != Some(why) {
            st.last_reject_reason = Some(why.to_string());
        }
        let make = || {
            let reason = why.to_string();
            (format!("{source}: {why}"), Event::SampleRejected { reason })
        };
        self.throttled_event(t, source, "sample_rejected", make, ctx);
    }

    pub fn debug_point(&mut self, t: i64, topic: DebugTopic, source: &str, v: Vector3<f64>) {
        let p = self.debug.series.entry(topic).or_default();
        p.time_us = t;
        if p.source != source {
            // Into the room it has: sources take turns on a topic.
            p.source.clear();
            p.source.push_str(source);
        }
        p.value = [v.x, v.y, v.z];
    }

    /// A sample arrived that is not a measurement to fuse but was understood (a range
    /// finder on the ground): seen, neither used nor rejected.
    pub fn mark_seen(&mut self, t: i64, source: &str, kind: &'static str) {
        let st = self.stat(source);
        st.kind = kind;
        st.last_time_us = Some(t);
    }

    /// A non-aiding source (IMU, attitude) contributed.
    pub fn mark_used(&mut self, t: i64, source: &str) {
        let st = self.stat(source);
        st.last_time_us = Some(t);
        st.fused(t);
        st.accepted += 1;
    }

    pub(super) fn mark_aiding(&mut self, t: i64, source: &str, kind: &'static str) {
        let st = self.stat(source);
        st.kind = kind;
        st.last_time_us = Some(t);
        st.fused(t);
        st.accepted += 1;
        self.aided(t, kind);
    }

    /// An aiding measurement of `kind` went in at `t` (the ground constraint counts as
    /// horizontal aiding for validity, never for releasing itself).
    pub(super) fn aided(&mut self, t: i64, kind: &str) {
        self.last_aiding = Some(t);
        if HORIZONTAL_AIDING.contains(&kind) {
            self.ground.last_h_aiding = Some(t);
        }
        if HORIZONTAL_AIDING.contains(&kind) || kind == "ground" {
            self.last_h_valid = Some(t);
        }
    }

    pub(super) fn record(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        out: &UpdateOutcome,
        ctx: &Ctx,
    ) {
        let st = self.stat(source);
        let same_sample = st.count_test(t, out.test_ratio);
        st.kind = kind;
        if !same_sample || out.test_ratio > st.test_ratio {
            st.test_ratio = out.test_ratio;
            st.set_innovation(out);
        }
        if out.accepted {
            st.accepted += 1;
            st.fused(t);
            if AIDING.contains(&kind) {
                self.aided(t, kind);
            }
        } else {
            st.rejected += 1;
            st.last_reject_reason = Some(format!("innovation gate, ratio {:.2}", out.test_ratio));
            let ratio = out.test_ratio;
            let make = || {
                (
                    format!("{source}: innovation test ratio {ratio:.2} > 1, measurement rejected"),
                    Event::GateReject {
                        test_ratio: ratio,
                        innovation: out.innovation().to_vec(),
                    },
                )
            };
            self.throttled_event(t, source, "gate_reject", make, ctx);
        }
    }

    pub(super) fn update(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        m: &Measurement,
        ctx: &Ctx,
    ) -> bool {
        self.update_with_rate(t, source, kind, m, [0.0; 3], ctx)
    }

    /// [`Self::update`] of a measurement whose prediction also changes with time by
    /// `extra` per row beyond what the state's own rates make of it (a body-frame
    /// velocity turns with the body): part of what its delay does to it.
    pub(super) fn update_with_rate(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        m: &Measurement,
        extra: [f64; 3],
        ctx: &Ctx,
    ) -> bool {
        let Some(bank) = self.ekf.as_mut() else {
            return false;
        };
        let gate = ctx.gate(m.rows());
        if self.integrity.is_excluded(source) {
            // Excluded by the integrity monitor: tested, not fused, until it agrees
            // again for long enough.
            let out = bank.innovation_test(m, gate);
            // The solutions that kept it take it (see `bank::Shadow`).
            if bank.shadows().iter().any(|s| s.takes(source)) {
                let imu_drives = self.imu_drives(t, ctx);
                let delayed = self.delayed(imu_drives, source, m, extra, ctx);
                if let Some(bank) = self.ekf.as_mut() {
                    bank.update_shadow(delayed.as_ref().unwrap_or(m), gate, source);
                }
            }
            let st = self.stat(source);
            st.count_test(t, out.test_ratio);
            st.kind = kind;
            st.test_ratio = out.test_ratio;
            st.set_innovation(&out);
            st.last_reject_reason = Some("excluded by the integrity monitor".into());
            integrity::excluded_sample(self, ctx, t, source, out.accepted);
            return false;
        }
        // A pseudo-measurement (the ground's constraints) is every filter's; an aiding
        // source has a sub-filter without it.
        let aiding = !matches!(source, "ground" | "wrls");
        if aiding && ctx.cfg.integrity.enabled {
            bank.ensure_sub(source, t);
        }
        // A delay is seen against the IMU's prediction: without one driving it (the
        // constant-velocity stand-in) there is nothing to see it against.
        let imu_drives = self.imu_drives(t, ctx);
        let delayed = if aiding {
            self.delayed(imu_drives, source, m, extra, ctx)
        } else {
            None
        };
        let m = delayed.as_ref().unwrap_or(m);
        if aiding && imu_drives && self.mode_ekf_direct {
            self.doubt_dead_reckoning(t, source, m, gate, ctx.cfg.dead_reckoning_fault_mps2);
        }
        let Some(bank) = self.ekf.as_mut() else {
            return false;
        };
        let out = bank.update(m, gate, aiding.then_some(source));
        if aiding && imu_drives {
            self.learn_prediction_noise(m, &out, ctx);
        }
        let Some(bank) = self.ekf.as_mut() else {
            return false;
        };
        if out.accepted && aiding && ctx.cfg.delay_std_s > 0.0 {
            let max_s = DELAY_BOUND_SIGMAS * ctx.cfg.delay_std_s;
            let floor = &self.delay_floor_s;
            bank.each(|e| {
                e.constrain_delays(max_s, |source| floor.get(source).copied());
            });
        }
        if aiding {
            let ch = Channels::of(m);
            if out.accepted {
                observe_misfit(&mut self.integrity, m, &out);
                if ch.vertical {
                    self.last_v_aiding = Some(t);
                }
                self.integrity.fused(source, ch, t);
                self.integrity.held(ch, t);
                if let Some(c) = self.converging.as_mut().filter(|c| c.0 == source) {
                    c.2 = true;
                }
            } else if let Some((dp, dv)) =
                self.ekf.as_ref().and_then(|b| b.main().shift_if_exact(m))
            {
                self.integrity.refused(ch, t, dp, dv);
            }
        }
        self.record(t, source, kind, &out, ctx);
        if !out.accepted && aiding && self.mode_ekf_direct {
            self.reset_if_locked_out(t, source, m, ctx);
        }
        out.accepted
    }

    /// A velocity measurement back after its channel went unaided for
    /// [`DEAD_RECKONING_DOUBT_AFTER_US`] or more, that the gate would refuse: the IMU
    /// carried the estimate alone meanwhile, and an accelerometer that stepped in that
    /// time (a knock, a loose mount) carried it off with σ as small as the noise model
    /// says. The velocity is the one that can tell (a GNSS's multipath moves its
    /// positions, not its Doppler), so a velocity that passes once the filter allows
    /// for such a fault (`fault`, m/s², over the gap) takes that
    /// allowance into every filter and is fused; the position keeps what the fault
    /// could have done to it. Without it, the estimate that dead-reckoned went on as
    /// the truth and the source that came back was refused, excluded, or its
    /// disagreement taken for a GNSS's slow error (randomised flights with an
    /// accelerometer step of 1 m/s² during a flow outage: 19.6 m off with σ 1.2 m).
    fn doubt_dead_reckoning(
        &mut self,
        t: i64,
        source: &str,
        m: &Measurement,
        gate: f64,
        fault: f64,
    ) {
        let ch = Channels::of(m);
        if fault <= 0.0 || ch.position[0] || ch.position[1] || !(ch.horizontal || ch.vertical) {
            return;
        }
        let last = if ch.horizontal {
            self.ground.last_h_aiding
        } else {
            self.last_v_aiding
        };
        let Some(gap) = last
            .map(|l| t - l)
            .filter(|&g| g >= DEAD_RECKONING_DOUBT_AFTER_US)
        else {
            return;
        };
        let Some(bank) = self.ekf.as_mut() else {
            return;
        };
        if bank.main().innovation_test(m, gate).accepted {
            return;
        }
        let gap_s = gap as f64 * 1e-6;
        let axes: &[usize] = if ch.horizontal { &[0, 1] } else { &[2] };
        let mut trial = bank.main().clone();
        trial.add_dead_reckoning_fault(axes, fault, gap_s);
        let out = trial.innovation_test(m, gate);
        if !out.accepted {
            return;
        }
        bank.each(|e| e.add_dead_reckoning_fault(axes, fault, gap_s));
        let channel = if ch.horizontal {
            "horizontal"
        } else {
            "vertical"
        };
        let reach_m = 0.5 * fault * gap_s * gap_s;
        self.event(
            t,
            Some(source),
            format!(
                "{source}: back after {gap_s:.1} s of {channel} dead reckoning and off by more than the IMU's noise allows: the estimate may have been carried {reach_m:.1} m by an accelerometer fault, and takes {source} again"
            ),
            Event::DeadReckoningDoubted {
                gap_s,
                reach_m,
                test_ratio: out.test_ratio,
            },
        );
    }

    /// `m` from an aiding `source` with its delay in it (see [`with_delay`]), where
    /// delays are estimated and an IMU drives the prediction; None otherwise.
    fn delayed(
        &mut self,
        imu_drives: bool,
        source: &str,
        m: &Measurement,
        extra: [f64; 3],
        ctx: &Ctx,
    ) -> Option<Measurement> {
        if !(imu_drives && ctx.cfg.delay_std_s > 0.0) {
            return None;
        }
        let bank = self.ekf.as_mut()?;
        Some(with_delay(bank, source, m, extra, ctx.cfg.delay_std_s))
    }

    /// The velocity rows of `m` (those that read the velocity states) against what
    /// the update said of them: the prediction's noise learns from them (accepted or
    /// not: a model that misses is what makes them refused). The heights that passed
    /// the gate teach the vertical part too: heights that run consistently beyond
    /// their σ are a prediction the filter trusts too much (a real ArduCopter log,
    /// 10-11-2014_103: 365 poses beyond 5σ without, none with). Refused heights do
    /// not: a spurious sonar echo is the sensor's lie, not the model's.
    fn learn_prediction_noise(&mut self, m: &Measurement, out: &ekf::UpdateOutcome, ctx: &Ctx) {
        let (y, s) = (out.innovation(), out.innovation_var());
        let mut changed = false;
        for row in 0..m.rows().min(y.len()) {
            let (pos, reads) = row_reads(m, row);
            let (height, horizontal_position) = (pos[2], pos[0] || pos[1]);
            let vertical = if reads.iter().any(|&r| r) {
                reads[2] && !reads[0] && !reads[1]
            } else if height && !horizontal_position && out.accepted {
                true
            } else {
                continue;
            };
            self.imu.noise.observe(y[row], s[row], vertical);
            changed = true;
        }
        if changed {
            let q = self.imu.noise.per_axis();
            let delay_var = ctx.cfg.delay_std_s * ctx.cfg.delay_std_s;
            let stats = &self.stats;
            let vertical = |s: &str| {
                stats
                    .get(s)
                    .is_some_and(|st| matches!(st.kind, "baro" | "range"))
            };
            if let Some(bank) = self.ekf.as_mut() {
                bank.each(|e| {
                    e.vel_q_extra = q;
                    e.doubt_under_misfit(q, delay_var, vertical);
                });
            }
        }
    }

    /// The rule against locking out the only source: a measurement refused while
    /// nothing has held its channel (the horizontal position or velocity; the height)
    /// for `reject_reset_s` resets the filter to it (the states of that channel it
    /// reads forget what they knew and take it ungated), as EKF2 and EKF3 reset to a
    /// source rejected for a while. The reset is counted, said, and the pose invalid
    /// until it converges.
    fn reset_if_locked_out(&mut self, t: i64, source: &str, m: &Measurement, ctx: &Ctx) {
        let cfg = ctx.cfg;
        let ch = Channels::of(m);
        let horizontal = ch.horizontal;
        if !horizontal && !ch.vertical {
            return;
        }
        let after = (cfg.reject_reset_s * 1e6) as i64;
        // A velocity accepted beside a refused position (a GNSS's own) holds it too:
        // the drift's rate stays bounded, and a receiver's multipath offset lasting
        // longer than `reject_reset_s` is not reset to (the position's own clock did,
        // and broke the promise on 2 of the first 20 randomised flights).
        let last = if horizontal {
            self.ground.last_h_aiding
        } else {
            self.last_v_aiding
        };
        let held = last.is_some_and(|l| t - l < after);
        // Somebody else holds it (another source, or this one a moment ago), or the
        // vehicle is on the ground and held there.
        if held || self.ground.active == Some(ground::Constraint::OnGround) {
            return;
        }
        let Some(bank) = self.ekf.as_mut() else {
            return;
        };
        let from = bank.pos();
        // The channel's states the measurement reads (a flow: the velocity only; its
        // position stays as uncertain as it was).
        let channel: &[usize] = if horizontal {
            &[IDX_P, IDX_P + 1, IDX_V, IDX_V + 1]
        } else {
            &[IDX_P + 2, IDX_V + 2]
        };
        let states: Vec<usize> = channel
            .iter()
            .copied()
            .filter(|&i| reads_any(m, &[i]))
            .collect();
        if !horizontal {
            // The height ran away on the IMU: its vertical bias is what the filter
            // learnt wrong, most likely (a delayed height at take-off teaches it so).
            let k = IDX_BA + 2;
            let var = cfg.init_accel_bias_var;
            bank.each(|e| e.forget(&[k], var));
        }
        // Large against anything a reset could move: the measurement decides.
        bank.reset_to(m, &states, RESET_FORGET_VAR, t);
        let moved = bank.pos() - from;
        let jump = if horizontal {
            moved.xy().norm()
        } else {
            moved.z.abs()
        };
        // The velocity carried the runaway: unless the measurement set it, it is as
        // uncertain as the jump over the time refused (kept, it drove the height of a
        // randomised flight on its only range finder away again within a second of
        // each reset: 1.6 m/s off with σ 0.09).
        let rejected_s = last.map_or(cfg.reject_reset_s, |l| (t - l) as f64 * 1e-6);
        let refused_s = rejected_s.max(cfg.reject_reset_s);
        let axes = if horizontal { 0..2 } else { 2..3 };
        for a in axes {
            let k = IDX_V + a;
            if !states.contains(&k) {
                let dv = moved[a] / refused_s;
                bank.each(|e| e.p[(k, k)] += dv * dv);
            }
        }
        self.integrity.held(ch, t);
        // Which of the two was wrong nobody knows: a GNSS's slow error may be as
        // large as the jump (multipath that came in over seconds looks exactly so),
        // and stays as uncertain until the fixes have shown otherwise.
        if self.stats.get(source).is_some_and(|s| s.kind == "gnss") {
            bank.each(|e| e.widen_gnss_bias(&moved));
        }
        self.reset_counter = self.reset_counter.wrapping_add(1);
        let until = t + (cfg.reset_converge_s * 1e6) as i64;
        self.converging = Some((source.to_string(), until, false));
        if horizontal {
            for st in self.odom.values_mut() {
                if st.align.is_some() {
                    st.need_realign = true;
                }
            }
            self.aided(t, self.stats.get(source).map_or("gnss", |s| s.kind));
        } else {
            self.last_v_aiding = Some(t);
        }
        let what = if horizontal {
            "every horizontal measurement refused"
        } else {
            "every height measurement refused"
        };
        self.event(
            t,
            Some(source),
            format!(
                "{source}: {what} for {rejected_s:.1} s with nothing else holding it: reset to it (moved {jump:.2} m); invalid until it converges"
            ),
            Event::Reset(event::Reset::Rejected {
                reset_counter: self.reset_counter,
                rejected_s,
                jump_m: jump,
            }),
        );
    }

    /// A position measurement (noise `r`), or None without a filter.
    pub(super) fn position_measurement(
        &self,
        kind: &'static str,
        z: Vector3<f64>,
        r: &Matrix3<f64>,
        block: Option<&str>,
    ) -> Option<Measurement> {
        let ekf = self.ekf.as_ref()?;
        // z = p (+ the GNSS slow error) (+ the odometry source's offset).
        let gnss_error = (kind == "gnss").then_some(ekf::IDX_BG);
        let offset = block.and_then(|s| ekf.block(s));
        let added = [gnss_error, offset];
        let mut pred = ekf.pos();
        for first in added.into_iter().flatten() {
            for i in 0..3 {
                pred[i] += ekf.x[first + i];
            }
        }
        let mut m = Measurement::of_states(IDX_P, 3, &(z - pred), r);
        for first in added.into_iter().flatten() {
            for i in 0..3 {
                m.set_jacobian(i, first + i, 1.0);
            }
        }
        Some(m)
    }

    /// Fuse a world position (GNSS) or an odometry position (`block` = its offset).
    #[allow(clippy::too_many_arguments)]
    pub fn fuse_position(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        z: Vector3<f64>,
        r: &Matrix3<f64>,
        block: Option<&str>,
        ctx: &Ctx,
    ) -> bool {
        if !self.mode_ekf_direct {
            self.mark_aiding(t, source, kind);
            return true;
        }
        let Some(m) = self.position_measurement(kind, z, r, block) else {
            return false;
        };
        self.update(t, source, kind, &m, ctx)
    }

    /// The innovation test of a position measurement from a source the health layer
    /// has taken out: computed on a copy, never fused, so health can see when the
    /// source agrees again (otherwise a rejected source could never come back).
    pub fn probe_position(
        &mut self,
        t: i64,
        source: &str,
        kind: &'static str,
        z: Vector3<f64>,
        r: &Matrix3<f64>,
        ctx: &Ctx,
    ) -> Option<f64> {
        let m = self.position_measurement(kind, z, r, None)?;
        let ekf = self.ekf.as_ref()?;
        let out = ekf.innovation_test(&m, ctx.gate(m.rows()));
        let st = self.stat(source);
        st.count_test(t, out.test_ratio);
        st.kind = kind;
        st.test_ratio = out.test_ratio;
        st.set_innovation(&out);
        Some(out.test_ratio)
    }

    /// Fuse the first `rows` components (east, north[, up]) of a world velocity.
    pub fn fuse_world_velocity(
        &mut self,
        t: i64,
        source: &str,
        v: Vector3<f64>,
        r: &Matrix3<f64>,
        rows: usize,
        ctx: &Ctx,
    ) {
        if !self.mode_ekf_direct {
            return;
        }
        let Some(ekf) = self.ekf.as_ref() else { return };
        let m = Measurement::of_states(IDX_V, rows, &(v - ekf.vel()), r);
        self.update(t, source, "gnss", &m, ctx);
    }

    /// The IMU's specific force and its variance held for the prediction at `t`, if a
    /// sample with one is recent enough (`imu_timeout_ms`) to drive it.
    /// An IMU carries the velocity between aiding samples now (else the
    /// constant-velocity stand-in does).
    pub(super) fn imu_drives(&self, t: i64, ctx: &Ctx) -> bool {
        self.att.known() && self.held_imu(t, ctx).is_some()
    }

    fn held_imu(&self, t: i64, ctx: &Ctx) -> Option<(Vector3<f64>, f64)> {
        let timeout = (ctx.cfg.imu_timeout_ms * 1000.0) as i64;
        self.imu
            .last
            .as_ref()
            .filter(|l| t - l.t <= timeout)
            .and_then(|l| l.accel.map(|a| (a, l.accel_var)))
    }

    /// Fuse the first `rows` components of a body-frame velocity.
    pub fn fuse_body_velocity(
        &mut self,
        t: i64,
        source: &str,
        vb: Vector3<f64>,
        r: &mut Matrix3<f64>,
        what: BodyVelocity,
        ctx: &Ctx,
    ) {
        let (rows, height_scale, gyro_bias) = match what {
            BodyVelocity::Flow {
                slant,
                height_scale,
                gyro_bias_tau_s,
            } => (2, height_scale, gyro_bias_tau_s.map(|tau| (slant, tau))),
            BodyVelocity::Odometry => (3, None, None),
        };
        if !self.mode_ekf_direct {
            if rows == 2 {
                self.mark_aiding(t, source, "flow");
            }
            return;
        }
        let cfg = ctx.cfg;
        let (scale_var, heading_var) = (cfg.flow_scale_std.powi(2), cfg.flow_heading_std.powi(2));
        // Continue condition of the flow's scale and heading errors and of the
        // attitude's heading error, as a flow corrects them: something that sees them,
        // an IMU driving the prediction (metric accelerations beside the flow's velocity
        // changes) or another horizontal source. A flow alone cannot tell a slow sensor
        // from a slow vehicle, nor a turned one from a turning one, and a filter free to
        // choose drifts (4 m/s laps without an IMU: −5 % whatever the sensor's error,
        // and the lag of every turn taken for a heading, 8° in 300 s; the fused track
        // worse than the flow integrated). Otherwise they are consider states: held,
        // their uncertainty carried into every flow sample and, through the covariance,
        // into the position.
        let imu_drives = self.imu_drives(t, ctx);
        let observed = imu_drives || self.other_aiding(t, source, ctx);
        let Some(bank) = self.ekf.as_mut() else {
            return;
        };
        // A flow source reads (1 + k)·Rz(ψ) times the body velocity: k its scale error,
        // ψ its heading error (both states of the filter).
        let errors = (rows == 2 && (scale_var > 0.0 || heading_var > 0.0)).then(|| {
            bank.each_main(|ekf| {
                ekf.scale_state(source, scale_var.max(1e-12), heading_var.max(1e-12))
            })
        });
        let gyro_var = cfg.flow_gyro_bias_std.powi(2);
        let gyro_bias = gyro_bias.filter(|_| gyro_var > 0.0).map(|(slant, tau)| {
            let i = bank.each_main(|ekf| ekf.gyro_bias_state(source, gyro_var, tau));
            (i, slant)
        });
        let ekf = &**bank;
        let (k, psi) = errors.map_or((0.0, 0.0), |i| (ekf.x[i], ekf.x[i + 1]));
        let rot = *self.att.q.to_rotation_matrix().matrix();
        // The body sees the world through the true heading: vb = Rᵀ·Rz(ψ_a)·v.
        let turn = ekf::yaw_rotation(ekf.yaw_error());
        let rt = rot.transpose() * turn;
        let v_turned = turn * ekf.vel();
        let pred = rot.transpose() * v_turned;
        // d(vb)/dψ_a = Rᵀ·(ẑ × Rz(ψ_a)·v).
        let dpred_dyaw = rot.transpose() * Vector3::new(-v_turned.y, v_turned.x, 0.0);
        // Attitude error turns the velocity: |v|²·σ² per axis (the roll and pitch part;
        // the heading's lasting part is ψ).
        let att_var = ekf.vel().norm_squared() * self.att.cov.trace() / 3.0;
        let mut m = odometry::body_velocity_measurement(&(turn.transpose() * rot), rows);
        // h(x) per row: what the measurement is predicted to read.
        let mut predicted = [pred.x, pred.y, pred.z];
        match errors {
            Some(si) => {
                // h = (1 + k)·(p_x − ψ·p_y, p_y + ψ·p_x), p = Rᵀv.
                let turned = [pred.x - psi * pred.y, pred.y + psi * pred.x];
                let dturn_dp = [[1.0, -psi], [psi, 1.0]];
                for i in 0..2 {
                    predicted[i] = (1.0 + k) * turned[i];
                    m.set_innovation(i, vb[i] - predicted[i]);
                    for j in 0..3 {
                        let dp = dturn_dp[i][0] * rt[(0, j)] + dturn_dp[i][1] * rt[(1, j)];
                        m.set_jacobian(i, IDX_V + j, (1.0 + k) * dp);
                    }
                    m.set_jacobian(i, si, turned[i]);
                    let dpsi = if i == 0 { -pred.y } else { pred.x };
                    m.set_jacobian(i, si + 1, (1.0 + k) * dpsi);
                    let dyaw = dturn_dp[i][0] * dpred_dyaw.x + dturn_dp[i][1] * dpred_dyaw.y;
                    m.set_jacobian(i, ekf::IDX_YAW, (1.0 + k) * dyaw);
                }
                if !observed {
                    m.consider(si);
                    m.consider(si + 1);
                    m.consider(ekf::IDX_YAW);
                }
            }
            None => {
                for i in 0..rows {
                    m.set_innovation(i, vb[i] - predicted[i]);
                    m.set_jacobian(i, ekf::IDX_YAW, dpred_dyaw[i]);
                }
            }
        }
        // A flow scaled by the filter's height above the terrain ĥ reads v·ĥ/(p_z − z_t):
        // d/dp_z = −h/ĥ, d/dz_t = h/ĥ. Without an IMU's metric accelerations against it
        // nothing tells a lower vehicle from a slower one (as for the scale error): the
        // height is then considered, not corrected.
        if let Some(h_est) = height_scale.filter(|h| *h > 0.0) {
            for (i, &h) in predicted.iter().enumerate().take(rows) {
                m.set_jacobian(i, ekf::IDX_P + 2, -h / h_est);
                m.set_jacobian(i, ekf::IDX_TERRAIN, h / h_est);
            }
            if !observed {
                m.consider(ekf::IDX_P + 2);
                m.consider(ekf::IDX_TERRAIN);
            }
        }
        // Nor is there anything to hold the flow's velocity against: the stand-in (the
        // last velocity, decaying) cannot turn or keep a cruise, and weighed against
        // it every lap's lasting innovations were smoothed into the position (20 m off
        // the flow integrated in 120 s of 4 m/s laps). The flow's velocity is then the
        // velocity: gated against the prediction, it replaces the horizontal velocity,
        // which the position integrates with its noise and its considered errors.
        if rows == 2 && !observed {
            m.replace(IDX_V);
            m.replace(IDX_V + 1);
        }
        // The compensation's gyro bias error δb reads as (δb_y, −δb_x)·d: considered.
        if let Some((i, d)) = gyro_bias {
            m.set_jacobian(0, i + 1, d);
            m.set_jacobian(1, i, -d);
            m.consider(i);
            m.consider(i + 1);
        }
        for i in 0..rows {
            r[(i, i)] += att_var;
            for j in 0..rows {
                m.set_noise(i, j, r[(i, j)]);
            }
        }
        // The prediction turns with the body: d(Rᵀv)/dt = Rᵀa − ω × Rᵀv, the second term
        // beyond the state's rates (the first is the velocity states' own).
        let omega = self.imu.rate.map_or(Vector3::zeros(), |r| r.1);
        let spin = -omega.cross(&pred);
        let mut extra = [0.0; 3];
        match errors {
            Some(_) => {
                extra[0] = (1.0 + k) * (spin.x - psi * spin.y);
                extra[1] = (1.0 + k) * (spin.y + psi * spin.x);
            }
            None => extra = [spin.x, spin.y, spin.z],
        }
        let kind = if rows == 2 { "flow" } else { "odometry" };
        self.update_with_rate(t, source, kind, &m, extra, ctx);
    }

    /// Fuse a height above the terrain: h = p_z − z_t.
    pub fn fuse_height(&mut self, t: i64, source: &str, z: f64, var: f64, ctx: &Ctx) {
        if !self.mode_ekf_direct {
            self.mark_aiding(t, source, "range");
            return;
        }
        let Some(ekf) = self.ekf.as_ref() else { return };
        let m = Measurement::height(z - ekf.height_above_terrain(), var);
        self.update(t, source, "range", &m, ctx);
    }

    /// Latest range-finder slant distance (within 200 ms).
    pub fn latest_range(&self, t: i64) -> Option<f64> {
        self.latest_range_at(t).map(|(_, d)| d)
    }

    /// Latest range-finder reading within 200 ms: (its time, slant distance).
    pub fn latest_range_at(&self, t: i64) -> Option<(i64, f64)> {
        self.range
            .values()
            .filter(|(tr, _)| (t - tr).abs() < 200_000)
            .max_by_key(|(tr, _)| *tr)
            .copied()
    }

    pub fn latest_height(&self, t: i64) -> Option<f64> {
        self.latest_range(t)
            .map(|d| d * attitude::cos_tilt(&self.att.q))
    }

    /// A range finder was fused (or is being fed) in the last second.
    pub fn range_recent(&self, t: i64, ctx: &Ctx) -> bool {
        self.range
            .iter()
            .any(|(s, (tr, _))| t - tr < 1_000_000 && ctx.usable(s))
    }

    /// Another position/velocity source than `source` was fused within the timeout.
    pub fn other_aiding(&self, t: i64, source: &str, ctx: &Ctx) -> bool {
        let timeout = (ctx.cfg.aiding_timeout_ms * 1000.0) as i64;
        self.stats.iter().any(|(s, st)| {
            s != source
                && matches!(st.kind, "gnss" | "odometry")
                && st.last_fused_us.is_some_and(|f| t - f <= timeout)
        })
    }

    /// Heading from an odometry source in the fused frame (for the own attitude filter).
    pub fn odometry_heading(&self) -> Option<f64> {
        let t = self.t?;
        self.odom
            .values()
            .filter_map(|o| o.heading)
            .filter(|(th, _)| t - th < 200_000)
            .max_by_key(|(th, _)| *th)
            .map(|(_, y)| y)
    }

    /// Feed a gyro sample into every flow source's low-pass.
    pub fn flow_gyro_sample(&mut self, t: i64, w: Vector3<f64>, ctx: &Ctx) {
        for (s, st) in self.flow.iter_mut() {
            let hz = ctx.cfg.source(s).gyro_lpf_hz;
            st.lpf.update(w, t, hz);
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub fn initialise(
        &mut self,
        t: i64,
        source: &str,
        pos: Vector3<f64>,
        pos_var: Vector3<f64>,
        vel: Option<Vector3<f64>>,
        vel_var: Option<Vector3<f64>>,
        ctx: &Ctx,
    ) {
        let cfg = ctx.cfg;
        let vv = vel_var.unwrap_or_else(|| Vector3::repeat(cfg.init_vel_var));
        if !self.mode_wrls {
            let mut ekf = Ekf::new(
                pos,
                vel.unwrap_or_else(Vector3::zeros),
                pos_var,
                vv,
                cfg.init_accel_bias_var,
            );
            ekf.terrain_rw = cfg.terrain_rw;
            ekf.terrain_gradient = cfg.terrain_gradient;
            ekf.scale_rw = cfg.flow_scale_rw;
            ekf.heading_rw = cfg.flow_heading_rw;
            // The slow part of GNSS's error, until a fix says how large it is.
            let (b, bv) = (cfg.gnss_bias_std_m, cfg.gnss_bias_std_v_m);
            let bias = self.gnss_bias_prior.unwrap_or(Vector3::new(b, b, bv));
            ekf.set_gnss_bias_model(bias, cfg.gnss_bias_tau_s);
            ekf.delay_rw = cfg.delay_rw;
            ekf.align_yaw_rw = super::odometry::VO_YAW_RW;
            let geographic = self.stats.get(source).is_some_and(|s| s.kind == "gnss")
                || self.gnss.origin.is_some();
            // Against north (GNSS) the heading is as good as the compass; in a frame of
            // its own that starts at the take-off heading, as good as that instant's.
            let yaw_prior = if geographic {
                cfg.yaw_error_std
            } else {
                super::config::OWN_FRAME_YAW_STD.min(cfg.yaw_error_std)
            };
            ekf.set_yaw_error_model(cfg.yaw_error_std, cfg.yaw_error_tau_s, yaw_prior);
            if geographic {
                // Started from a fix: the ground's height in that frame is as uncertain
                // as the fix's altitude.
                ekf.p[(ekf::IDX_TERRAIN, ekf::IDX_TERRAIN)] = pos_var.z;
            } else {
                ekf.add_drift(cfg.dead_reckoning_drift);
            }
            self.ekf = Some(Bank::new(ekf));
            self.integrity = IntegrityState::default();
        }
        self.pred_t = Some(t);
        self.wrls.init(t, pos, pos_var);
        self.last_aiding = Some(t);
        self.last_h_valid = Some(t);
        if source != "ground" {
            self.ground.last_h_aiding = Some(t);
        }
        self.event(
            t,
            Some(source),
            format!(
                "filter initialised from {source} at ({:.2}, {:.2}, {:.2})",
                pos.x, pos.y, pos.z
            ),
            Event::Initialised {
                position: pos.into(),
            },
        );
    }

    /// Advance WRLS ticks and the prediction to `t`.
    pub(super) fn advance(&mut self, t: i64, ctx: &Ctx) {
        let cfg = ctx.cfg;
        let period_us = (cfg.wrls_period_ms * 1000.0) as i64;
        let mut outs = std::mem::take(&mut self.wrls_out);
        self.wrls
            .tick(t, period_us, cfg.wrls_no_delta_var, &mut outs);
        for o in outs.drain(..) {
            self.debug_point(o.t, DebugTopic::FusionDisplace, "wrls", o.delta);
            if self.mode_wrls {
                self.debug_point(o.t, DebugTopic::PoseMsg, "wrls", o.x);
            }
            if cfg.mode == Mode::WrlsEkf && self.ekf.is_some() {
                let every = (1e6 / cfg.wrls_ekf_rate_hz.max(1e-3)) as i64;
                if self.wrls_ekf_last.is_none_or(|l| o.t - l >= every) {
                    self.wrls_ekf_last = Some(o.t);
                    self.predict_to(o.t, ctx);
                    if let Some(ekf) = self.ekf.as_ref() {
                        let r = Matrix3::from_diagonal(&o.var);
                        let m = Measurement::of_states(IDX_P, 3, &(o.x - ekf.pos()), &r);
                        self.update(o.t, "wrls", "gnss", &m, ctx);
                    }
                }
            }
        }
        self.wrls_out = outs;
        self.predict_to(t, ctx);
    }

    pub(super) fn predict_to(&mut self, t: i64, ctx: &Ctx) {
        let cfg = ctx.cfg;
        let Some(t0) = self.pred_t else { return };
        if t <= t0 {
            return;
        }
        let dt = (t - t0) as f64 * 1e-6;
        self.pred_t = Some(t);
        let rot = *self.att.q.to_rotation_matrix().matrix();
        let tilt_var = 0.5 * (self.att.cov[(0, 0)] + self.att.cov[(1, 1)]);
        let held = self.held_imu(t, ctx);
        let bias_rw = cfg.accel_bias_rw;
        let drift = |s: &str| {
            // A barometer's offset block is named `baro:<source>`.
            let (id, default) = match s.strip_prefix(super::baro::BLOCK_PREFIX) {
                Some(id) => (id, cfg.baro_drift_rw),
                None => (s, cfg.vo_drift_rw),
            };
            cfg.sources
                .get(id)
                .and_then(|c| c.drift_rw)
                .unwrap_or(default)
        };
        let imu_drives = held.is_some() && self.att.known();
        let (f_body, var) = match held {
            Some((a, v)) if self.att.known() => (a, v + GRAVITY * GRAVITY * tilt_var),
            _ => {
                let ba = self
                    .ekf
                    .as_ref()
                    .map_or(Vector3::zeros(), |e| e.accel_bias());
                (
                    rot.transpose() * Vector3::new(0.0, 0.0, GRAVITY) + ba,
                    cfg.no_imu_accel_noise.powi(2),
                )
            }
        };
        let ba = self
            .ekf
            .as_ref()
            .map_or(Vector3::zeros(), |e| e.accel_bias());
        let a_world = rot * (f_body - ba) - Vector3::new(0.0, 0.0, GRAVITY);
        self.monitors.predict(a_world, dt, imu_drives);
        // The stand-in's velocity reverts to rest only where nothing measures it: a
        // flow sample replaces it (see `fuse_body_velocity`), and decaying between two
        // of them read a 9.5 Hz flow 0.5 % slower than it is, on top of its own error.
        let measured = self
            .ground
            .last_h_aiding
            .is_some_and(|l| t - l <= NO_IMU_VELOCITY_HELD_US);
        let velocity_tau_s = if imu_drives || measured {
            f64::INFINITY
        } else {
            NO_IMU_VELOCITY_TAU_S
        };
        // A long span (every input silent, then back) is predicted in short steps: the
        // step's noise model (a constant acceleration over the step) in one 12 s step
        // tied the position to the velocity exactly, and the first velocity measured
        // afterwards then "measured" the position too (σ 216 m → 0.7 m, 8.5 m moved,
        // after a 12 s link loss).
        let steps = (dt / MAX_PREDICT_STEP_S).ceil().max(1.0);
        let h = dt / steps;
        if let Some(bank) = self.ekf.as_mut() {
            bank.each(|ekf| {
                ekf.velocity_tau_s = velocity_tau_s;
                for _ in 0..steps as usize {
                    ekf.predict(f_body, &rot, h, var, bias_rw, drift);
                }
            });
        }
    }

    /// Fuse one sample; `usable`: the health layer's verdict on its source when it
    /// arrived.
    pub(super) fn process_entry(
        &mut self,
        t: i64,
        source: &str,
        data: &SensorData,
        usable: bool,
        ctx: &Ctx,
    ) {
        if !usable {
            if let SensorData::Gnss(g) = data {
                gnss::probe(self, ctx, t, source, g);
            }
            return;
        }
        self.advance(t, ctx);
        match data {
            SensorData::Imu(i) => imu::process(self, ctx, t, source, i),
            SensorData::Attitude(a) => imu::process_attitude(self, ctx, t, source, a),
            SensorData::Gnss(g) => gnss::process(self, ctx, t, source, g),
            SensorData::Flow(f) => flow::process(self, ctx, t, source, f),
            SensorData::Range(r) => range::process(self, ctx, t, source, r),
            SensorData::Odometry(o) => odometry::process(self, ctx, t, source, o),
            SensorData::VehicleState(v) => ground::process_vehicle_state(self, t, source, v),
            SensorData::Baro(b) => super::baro::process(self, ctx, t, source, b),
            SensorData::AutopilotEstimate(_) => {}
        }
        if let Some(st) = self.stats.get_mut(source) {
            if st.kind.is_empty() {
                st.kind = kind_str(data.kind());
            }
        }
        self.t = Some(self.t.map_or(t, |t0| t0.max(t)));
        self.post(t, ctx);
    }

    pub(super) fn post(&mut self, t: i64, ctx: &Ctx) {
        let cfg = ctx.cfg;
        ground::control(self, ctx, t);
        if cfg.integrity.enabled && self.mode_ekf_direct {
            integrity::check(self, ctx, t);
        }
        let timeout = (cfg.aiding_timeout_ms * 1000.0) as i64;
        if self.unaided_since.is_none() && self.initialised() {
            if let Some(l) = self.last_aiding.filter(|l| t - l > timeout) {
                self.unaided_since = Some(l);
            }
        }
        if let Some(ekf) = self.ekf.as_ref() {
            if !ekf.is_finite() {
                self.ekf = None;
                self.wrls = Wrls::default();
                for st in self.odom.values_mut() {
                    st.align = None;
                }
                self.reset_counter = self.reset_counter.wrapping_add(1);
                self.event(
                    t,
                    None,
                    "numerical failure (non-finite state): filter restarted".into(),
                    Event::Reset(event::Reset::Restart {
                        reset_counter: self.reset_counter,
                    }),
                );
                return;
            }
        }
        if let (Some(p), Some(v)) = (self.position(), self.velocity()) {
            // The filter's own horizontal 1σ: a departure within it is no divergence.
            let std_h = self
                .ekf
                .as_ref()
                .map_or(0.0, |e| e.p[(0, 0)].max(e.p[(1, 1)]).max(0.0).sqrt());
            if let Some(r) = self.monitors.check(t, p, v, std_h, cfg) {
                self.apply_monitor_reset(t, r, ctx);
            }
            if !self.mode_wrls {
                self.debug_point(t, DebugTopic::PoseMsg, "ekf", p);
            }
        }
        // Compared in place (this runs for every sample); the list is built on a change.
        if !self.used_sources(t, cfg).eq(self.used_set.iter()) {
            let used: Vec<String> = self.used_sources(t, cfg).cloned().collect();
            let added: Vec<String> = used
                .iter()
                .filter(|s| !self.used_set.contains(s))
                .cloned()
                .collect();
            let removed: Vec<String> = self
                .used_set
                .iter()
                .filter(|s| !used.contains(s))
                .cloned()
                .collect();
            let msg = format!("sources now {used:?} (added {added:?}, removed {removed:?})");
            let what = Event::SourceSwitch(event::SourceSwitch::Fused {
                sources: used.clone(),
                added,
                removed,
            });
            self.event(t, None, msg, what);
            self.used_set = used;
        }
    }

    pub(super) fn apply_monitor_reset(&mut self, t: i64, r: MonitorReset, ctx: &Ctx) {
        let cfg = ctx.cfg;
        let Some(p) = self.position() else { return };
        let v = self.velocity().unwrap_or_else(Vector3::zeros);
        let (pos, vel) = if r.horizontal_only {
            (
                Vector3::new(r.position.x, r.position.y, p.z),
                Vector3::new(r.velocity.x, r.velocity.y, v.z),
            )
        } else {
            (r.position, r.velocity)
        };
        // Never more certain after a reset than before it: the monitor is no better a
        // measurement than the filter's own uncertainty says it was.
        let before = self
            .ekf
            .as_ref()
            .map_or(Vector3::zeros(), |e| e.cov3(IDX_P).diagonal());
        let reset = |i: usize| before[i].max(cfg.reset_pos_var);
        let pos_var = if r.horizontal_only {
            Vector3::new(reset(0), reset(1), before[2].max(0.0))
        } else {
            Vector3::new(reset(0), reset(1), reset(2))
        };
        if let Some(bank) = self.ekf.as_mut() {
            bank.each(|ekf| ekf.reset_pos_vel(pos, Some(vel), pos_var, cfg.reset_vel_var));
        }
        self.wrls.reset(pos, pos_var);
        for st in self.odom.values_mut() {
            st.need_realign = true;
        }
        self.reset_counter = self.reset_counter.wrapping_add(1);
        let from = [p.x, p.y, p.z];
        let to = [pos.x, pos.y, pos.z];
        self.event(
            t,
            None,
            format!("reset to the {} monitor: {}", r.monitor, r.reason),
            Event::MonitorReset(event::MonitorReset {
                monitor: r.monitor,
                reason: r.reason.clone(),
                from,
                to,
                position_departure_m: r.pos_err,
                velocity_departure_mps: r.vel_err,
                reset_counter: self.reset_counter,
            }),
        );
    }

    /// The sources fused within `aiding_timeout_ms` of `t`, in name order.
    pub(super) fn used_sources<'a>(
        &'a self,
        t: i64,
        cfg: &EstimatorConfig,
    ) -> impl Iterator<Item = &'a String> + 'a {
        let timeout = (cfg.aiding_timeout_ms * 1000.0) as i64;
        self.stats
            .iter()
            .filter(move |(_, st)| {
                // A slow source (a 1 Hz HEARTBEAT) counts as used between its samples.
                let own = match (st.prev_fused_us, st.last_fused_us) {
                    (Some(p), Some(l)) => (l - p).saturating_mul(5) / 2,
                    _ => 0,
                };
                st.last_fused_us
                    .is_some_and(|f| t - f <= timeout.max(own.min(MAX_USED_GAP_US)))
            })
            .map(|(s, _)| s)
    }

    /// Why the estimate is not valid at time `now` (None: valid). `now` is at least the
    /// newest sample's time, later when the caller has seen time pass without samples.
    pub(super) fn validity(&self, cfg: &EstimatorConfig, now: Option<i64>) -> Option<Invalid> {
        if !self.initialised() {
            return Some(Invalid::NotInitialised);
        }
        let t = self.t.unwrap_or(0).max(now.unwrap_or(i64::MIN));
        if let Some(ekf) = self.ekf.as_ref() {
            if !ekf.is_finite() {
                return Some(Invalid::NonFinite);
            }
        }
        if !self.att.known() {
            return Some(Invalid::NoAttitude);
        }
        let timeout = (cfg.aiding_timeout_ms * 1000.0) as i64;
        match self.last_aiding {
            Some(l) if t - l <= timeout => {}
            _ => return Some(Invalid::NoAiding),
        }
        if self.ground.handled(t) {
            return Some(Invalid::Carried);
        }
        if self
            .converging
            .as_ref()
            .is_some_and(|(_, until, accepted)| t < *until || !accepted)
        {
            return Some(Invalid::Converging);
        }
        // A height alone (a range finder) leaves the horizontal position dead-reckoned.
        match self.last_h_valid {
            Some(l) if t - l <= timeout => {}
            _ => return Some(Invalid::NoHorizontal),
        }
        // A height measured before and refused or silent since, off the ground: the
        // IMU alone holds it, and a vertical error grows by metres a second (its σ
        // only as the noise says). Twice the aiding timeout: a 1 Hz GNSS's altitude
        // arrives once a second, jitter and all.
        let height_timeout = (HEIGHT_TIMEOUT_FACTOR * cfg.aiding_timeout_ms * 1000.0) as i64;
        if self.mode_ekf_direct
            && self.ground.active != Some(ground::Constraint::OnGround)
            && self.last_v_aiding.is_some_and(|l| t - l > height_timeout)
        {
            return Some(Invalid::NoHeight);
        }
        let var = match (&self.ekf, self.mode_wrls) {
            (Some(e), false) => e.cov3(IDX_P).diagonal(),
            _ => self.wrls.var,
        };
        let max = cfg.max_pos_std_m * cfg.max_pos_std_m;
        if var.iter().any(|v| !v.is_finite() || *v > max) {
            return Some(Invalid::Uncertain);
        }
        let pl = integrity::protection(self, &cfg.integrity);
        if !pl.within_alert_limits() {
            return Some(Invalid::Protection);
        }
        None
    }
}

/// Which position and velocity axes (east, north, up) one row of `m` reads (a
/// non-zero Jacobian entry).
fn row_reads(m: &Measurement, row: usize) -> ([bool; 3], [bool; 3]) {
    let (mut pos, mut vel) = ([false; 3], [false; 3]);
    for (k, h) in m.jacobian_row(row).entries() {
        if h == 0.0 {
            continue;
        }
        if (IDX_P..IDX_P + 3).contains(&k) {
            pos[k - IDX_P] = true;
        }
        if (IDX_V..IDX_V + 3).contains(&k) {
            vel[k - IDX_V] = true;
        }
    }
    (pos, vel)
}

/// Each accepted row of `m` into its channel's misfit (see
/// `IntegrityState::misfit_factor`): horizontal if it reads a horizontal position or
/// velocity, vertical if it reads only the vertical ones.
fn observe_misfit(st: &mut IntegrityState, m: &Measurement, out: &UpdateOutcome) {
    let (y, s) = (out.innovation(), out.innovation_var());
    for row in 0..m.rows().min(y.len()).min(s.len()) {
        let (pos, vel) = row_reads(m, row);
        let horizontal = pos[0] || pos[1] || vel[0] || vel[1];
        if horizontal || pos[2] || vel[2] {
            st.observe_misfit(horizontal, y[row], s[row]);
        }
    }
}

/// `m` from `source` with the source's delay τ in it: it measured the state of τ
/// ago, `h(x(t − τ)) ≈ h(x) − τ·dh/dt`, dh/dt from the velocity (what a position
/// reads) and the last prediction's acceleration (what a velocity reads). The delay
/// is a state of every filter (added with prior 1σ `prior_std` s on first use), seen
/// when what the source measures changes, and its uncertainty is in the innovation's.
fn with_delay(
    bank: &mut Bank,
    source: &str,
    m: &Measurement,
    extra: [f64; 3],
    prior_std: f64,
) -> Measurement {
    let idx = bank.each_main(|e| e.delay_state(source, prior_std * prior_std));
    let (v, a, tau) = (bank.vel(), bank.accel_world, bank.x[idx]);
    let mut out = *m;
    for (row, extra) in extra.iter().enumerate().take(m.rows()) {
        let rate: f64 = extra
            + m.jacobian_row(row)
                .entries()
                .map(|(k, h)| match k {
                    k if (IDX_P..IDX_P + 3).contains(&k) => h * v[k - IDX_P],
                    k if (IDX_V..IDX_V + 3).contains(&k) => h * a[k - IDX_V],
                    _ => 0.0,
                })
                .sum::<f64>();
        out.set_jacobian(row, idx, -rate);
        out.set_innovation(row, m.innovation()[row] + rate * tau);
    }
    out
}

/// Without an IMU, how long a multicopter's velocity stays what it was, s: with the
/// stand-in's acceleration noise (`no_imu_accel_noise`, 3 m/s²) its speed's 1σ at rest is
/// about 3 m/s.
const NO_IMU_VELOCITY_TAU_S: f64 = 10.0;

/// Without an IMU, how long after a horizontal velocity or position was last fused the
/// velocity is held as it is, µs (then it decays with [`NO_IMU_VELOCITY_TAU_S`]): a
/// few samples of the slowest flow.
const NO_IMU_VELOCITY_HELD_US: i64 = 500_000;

/// A delay state is held within this many of its prior 1σ (`delay_std_s`): 0.4 s at
/// the default, beyond the 0–300 ms the randomised flights draw.
const DELAY_BOUND_SIGMAS: f64 = 4.0;

/// The variance the reset states take before the measurement they reset to, m² or
/// (m/s)²: far larger than any jump, so the measurement alone decides.
const RESET_FORGET_VAR: f64 = 1e6;

/// An unaided spell of a channel this long makes its dead reckoning suspect when a
/// velocity comes back refused (see `Core::doubt_dead_reckoning`), µs: the aiding
/// timeout, beyond one sample of the slowest flow or GNSS.
const DEAD_RECKONING_DOUBT_AFTER_US: i64 = 1_000_000;

/// The height's aiding timeout, in aiding timeouts (see [`Invalid::NoHeight`]).
const HEIGHT_TIMEOUT_FACTOR: f64 = 2.0;

/// Why the estimate is not valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Invalid {
    NotInitialised,
    NonFinite,
    NoAttitude,
    NoAiding,
    Carried,
    NoHorizontal,
    NoHeight,
    Uncertain,
    Protection,
    Converging,
}

impl Invalid {
    const ALL: [Invalid; 10] = [
        Invalid::NotInitialised,
        Invalid::NonFinite,
        Invalid::NoAttitude,
        Invalid::NoAiding,
        Invalid::Carried,
        Invalid::NoHorizontal,
        Invalid::NoHeight,
        Invalid::Uncertain,
        Invalid::Protection,
        Invalid::Converging,
    ];

    fn text(self, cfg: &EstimatorConfig) -> String {
        match self {
            Invalid::NotInitialised => "not initialised".into(),
            Invalid::NonFinite => "non-finite state".into(),
            Invalid::NoAttitude => "no attitude".into(),
            Invalid::NoAiding => format!(
                "no position or velocity source fused for more than {} ms",
                cfg.aiding_timeout_ms
            ),
            Invalid::Carried => {
                "disarmed but moving (carried by hand): not valid until set down".into()
            }
            Invalid::NoHorizontal => format!(
                "no horizontal position or velocity source fused for more than {} ms",
                cfg.aiding_timeout_ms
            ),
            Invalid::NoHeight => format!(
                "in the air and no height measurement fused for more than {} ms",
                HEIGHT_TIMEOUT_FACTOR * cfg.aiding_timeout_ms
            ),
            Invalid::Uncertain => {
                format!("position uncertainty above {} m (1σ)", cfg.max_pos_std_m)
            }
            Invalid::Converging => format!(
                "reset to one source's measurement: converging (at least {} s, until it is fused again)",
                cfg.reset_converge_s
            ),
            Invalid::Protection => format!(
                "protection level above the alert limit ({} m horizontal, {} m vertical)",
                cfg.integrity.horizontal_alert_m, cfg.integrity.vertical_alert_m
            ),
        }
    }
}

/// The reasons' texts, with the config's limits in them, made once: a pose is asked for
/// with every sample, and is invalid for whole phases of a flight (on the ground).
#[derive(Debug, Clone)]
pub(super) struct InvalidTexts([String; 10]);

impl InvalidTexts {
    pub(super) fn new(cfg: &EstimatorConfig) -> Self {
        Self(Invalid::ALL.map(|i| i.text(cfg)))
    }

    pub(super) fn get(&self, why: Invalid) -> String {
        self.0[why as usize].clone()
    }
}

/// `m` reads one of `states` (a row's Jacobian has it).
fn reads_any(m: &Measurement, states: &[usize]) -> bool {
    (0..m.rows()).any(|r| {
        m.jacobian_row(r)
            .entries()
            .any(|(k, _)| states.contains(&k))
    })
}
