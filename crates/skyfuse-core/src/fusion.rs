//! The estimator under health supervision: every sample is checked, the health layer's
//! verdicts decide which sources the estimator may fuse, and both produce events. The
//! service (its `pipeline`) and offline runs ([`crate::offline`]) use this same
//! core, so what is measured offline is what flies. Pure: time comes with the samples.

use crate::estimator::{Estimator, EstimatorConfig, EstimatorEvent, Event};
use crate::health::{HealthConfig, HealthMonitor, Transition};
use crate::sample::{Sample, SensorKind};

/// Health is re-evaluated at most this often (host time), µs.
const EVALUATE_EVERY_US: i64 = 20_000;
/// Without an evaluation for this long, the samples have stopped: the host's periodic
/// check takes over (its period is 100 ms; this is half as long again so that a tick
/// never lands between samples that still flow at ≥ 10 Hz).
const IDLE_AFTER_US: i64 = 150_000;

pub struct Fusion {
    pub est: Estimator,
    pub health: HealthMonitor,
    last_eval_us: Option<i64>,
    last_status_us: Option<i64>,
    /// Samples refused before fusion (non-finite or out of bounds).
    pub invalid: u64,
}

pub use crate::health::InputSpec;

/// Every input of a run.
pub type InputList = Vec<InputSpec>;

impl Fusion {
    pub fn new(est: EstimatorConfig, health: HealthConfig, inputs: &InputList) -> Self {
        Self {
            est: Estimator::new(est),
            health: HealthMonitor::new(health, inputs),
            last_eval_us: None,
            last_status_us: None,
            invalid: 0,
        }
    }

    /// Check, fuse, judge. `now_us` is the host time of the sample's arrival.
    pub fn process(&mut self, s: &Sample, now_us: i64) -> Vec<EstimatorEvent> {
        let mut events = Vec::new();
        if let Err(why) = s.data.validate() {
            // Nothing invalid reaches the estimator, whoever produced it.
            self.invalid += 1;
            self.health
                .on_rejected(&s.source, "invalid_value", &why, now_us);
        } else {
            self.health.on_sample(s, now_us);
            if s.data.kind() != SensorKind::AutopilotEstimate {
                for e in self.est.process(s) {
                    if matches!(e.what, Event::MonitorReset(_)) {
                        self.health.on_divergence(&e.message, now_us);
                    }
                    events.push(e);
                }
            }
        }
        events.extend(self.tick(now_us));
        events
    }

    /// A sample rejected by ingest (malformed, wrong type, time backwards).
    pub fn rejected(&mut self, source: &str, code: &'static str, text: &str, now_us: i64) {
        self.health.on_rejected(source, code, text, now_us);
    }

    /// The host's periodic check, for when samples stop coming: staleness and
    /// validity are then judged without data. While samples flow, every sample already
    /// evaluates (every [`EVALUATE_EVERY_US`]), and a timer's tick in between would
    /// only shift when the filter runs behind its horizon: the fused track would then
    /// hang on the host's scheduling, and a replay of the recording could not
    /// reproduce the poses sent live. So it acts only after [`IDLE_AFTER_US`] without
    /// an evaluation (or when the clock went back).
    pub fn tick_idle(&mut self, now_us: i64) -> Vec<EstimatorEvent> {
        if self
            .last_eval_us
            .is_some_and(|l| now_us >= l && now_us - l < IDLE_AFTER_US)
        {
            return vec![];
        }
        self.tick(now_us)
    }

    /// Re-evaluate health (each sample calls it; [`Self::tick_idle`] when none come).
    pub fn tick(&mut self, now_us: i64) -> Vec<EstimatorEvent> {
        if self
            .last_eval_us
            .is_some_and(|l| now_us >= l && now_us - l < EVALUATE_EVERY_US)
        {
            return vec![];
        }
        self.last_eval_us = Some(now_us);
        let mut events = self.est.observe_time(now_us);
        if self
            .last_status_us
            .is_none_or(|l| now_us < l || now_us - l >= 100_000)
        {
            self.last_status_us = Some(now_us);
            let st = self.est.state_summary();
            self.health.on_estimator(&st, now_us);
        }
        for tr in self.health.evaluate(now_us) {
            events.push(transition_event(&tr));
            if tr.sensor != crate::health::ESTIMATOR_ID {
                let reason = tr
                    .reasons
                    .iter()
                    .find(|r| !crate::health::INNOVATION_CODES.contains(&r.code))
                    .map(|r| r.code)
                    .unwrap_or(tr.to.as_str());
                // See `HealthMonitor::fusable`: what the health says of a source's
                // disagreement with the estimate is shown, not acted on here.
                let fusable = self.health.fusable(&tr.sensor);
                events.extend(self.est.set_source_usable(&tr.sensor, fusable, reason));
            }
        }
        events
    }
}

/// A health transition as an event.
pub fn transition_event(tr: &Transition) -> EstimatorEvent {
    EstimatorEvent::new(
        tr.time_us,
        Some(&tr.sensor),
        tr.message(),
        Event::Health {
            from: tr.from,
            to: tr.to,
            reasons: tr.reasons.clone(),
        },
    )
}
