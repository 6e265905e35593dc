//! The built-in simulator: a realistic flight ([`truth`]), sensor models
//! ([`sensors`]), and a scheduler that emits measurements in publication order,
//! each with its measurement time and the ground truth. The service's `sim::publish`
//! puts them on Zenoh in the real bridges' formats, so the demo exercises the same path
//! as a vehicle.

pub mod dataflash;
pub mod faults;
pub mod monte_carlo;
pub mod plan;
pub mod scenario;
pub mod sensors;
pub mod truth;
pub mod ulog;

use crate::sample::SensorData;
use faults::FaultSchedule;
use sensors::{SensorModels, StreamSpec};
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::sync::Arc;
use truth::{Profile, TruthState};

/// One measurement ready to publish.
#[derive(Debug, Clone)]
pub struct SimEvent {
    /// Index into the simulator's streams.
    pub stream: usize,
    /// When the sensor measured, s since the start.
    pub measured_t: f64,
    /// When it is published (measured + latency), s since the start.
    pub publish_t: f64,
    pub data: SensorData,
    pub truth: TruthState,
}

struct Pending(SimEvent);

impl PartialEq for Pending {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Pending {
    // Min-heap on publish time; ties broken by stream so the order is deterministic.
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.publish_t
            .total_cmp(&self.0.publish_t)
            .then_with(|| o.0.stream.cmp(&self.0.stream))
    }
}

/// Emits measurements of every stream in publication order until `duration_s`.
pub struct Simulator {
    pub streams: Vec<StreamSpec>,
    next_measure: Vec<f64>,
    models: SensorModels,
    pending: BinaryHeap<Pending>,
    duration_s: f64,
    profile: Profile,
    faults: Arc<FaultSchedule>,
}

impl Simulator {
    pub fn new(streams: &[StreamSpec], seed: u64, duration_s: f64) -> Self {
        let sensors = streams.iter().map(|s| s.input_id.to_string()).collect();
        Self::with_profile(
            streams,
            seed,
            duration_s,
            Profile::Demo,
            Arc::new(FaultSchedule::new(sensors, vec![])),
        )
    }

    /// A flight of `profile` whose sensors suffer the faults in `faults` (which can
    /// also be changed while it runs).
    pub fn with_profile(
        streams: &[StreamSpec],
        seed: u64,
        duration_s: f64,
        profile: Profile,
        faults: Arc<FaultSchedule>,
    ) -> Self {
        Self {
            streams: streams.to_vec(),
            // Stagger first samples so streams do not all fire on the same tick.
            next_measure: streams
                .iter()
                .enumerate()
                .map(|(i, s)| (i as f64 * 0.37e-3) % (1.0 / s.rate_hz))
                .collect(),
            models: SensorModels::with_profile(seed, profile),
            pending: BinaryHeap::new(),
            duration_s,
            profile,
            faults,
        }
    }

    /// The same flight with other hardware on the vehicle (see [`sensors::Hardware`]).
    pub fn with_hardware(mut self, hardware: sensors::Hardware) -> Self {
        self.models.hardware = hardware;
        self
    }

    pub fn faults(&self) -> Arc<FaultSchedule> {
        self.faults.clone()
    }

    pub fn origin(&self) -> crate::geo::LocalEnu {
        self.models.origin
    }

    /// Flies from another home (default: PX4 SITL's, Zürich), so that several simulated
    /// vehicles fly side by side rather than on top of each other.
    pub fn set_home(&mut self, lat_deg: f64, lon_deg: f64, alt_m: f64) {
        self.models.set_home(lat_deg, lon_deg, alt_m);
    }

    /// Measure every stream whose next sample is due before `horizon`.
    fn measure_until(&mut self, horizon: f64) {
        for i in 0..self.streams.len() {
            while self.next_measure[i] <= horizon && self.next_measure[i] < self.duration_s {
                let spec = self.streams[i];
                let t = self.next_measure[i];
                self.next_measure[i] = t + 1.0 / spec.rate_hz;
                self.faults.set_now(t);
                let truth = truth::truth_of(self.profile, t);
                let started = self.faults.started(spec.input_id, t);
                let active: Vec<_> = started.iter().filter(|f| t < f.end_s).cloned().collect();
                if faults::suppressed(&active) {
                    continue;
                }
                let mut data = self.models.measure_with(spec.kind, &truth, &started);
                faults::apply(&mut data, &active, t);
                self.pending.push(Pending(SimEvent {
                    stream: i,
                    measured_t: t,
                    publish_t: t + spec.delay_s,
                    data,
                    truth,
                }));
            }
        }
    }
}

impl Iterator for Simulator {
    type Item = SimEvent;

    fn next(&mut self) -> Option<SimEvent> {
        loop {
            // Anything measured after the earliest pending publication plus the
            // largest delay cannot be published before it: safe to emit.
            let max_delay = self.streams.iter().map(|s| s.delay_s).fold(0.0, f64::max);
            let earliest_next = self
                .next_measure
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            if let Some(top) = self.pending.peek() {
                if top.0.publish_t <= earliest_next || earliest_next >= self.duration_s {
                    return self.pending.pop().map(|p| p.0);
                }
            } else if earliest_next >= self.duration_s {
                return None;
            }
            self.measure_until(earliest_next + max_delay.max(1e-3));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sensors::DEMO_STREAMS;

    #[test]
    fn emits_in_publication_order_at_the_configured_rates() {
        let sim = Simulator::new(DEMO_STREAMS, 1, 10.0);
        let events: Vec<SimEvent> = sim.collect();
        for w in events.windows(2) {
            assert!(w[0].publish_t <= w[1].publish_t, "out of order");
        }
        for (i, s) in DEMO_STREAMS.iter().enumerate() {
            let count = events.iter().filter(|e| e.stream == i).count() as f64;
            assert!(
                (count - s.rate_hz * 10.0).abs() <= 1.0,
                "{}: {count}",
                s.input_id
            );
        }
        // GPS is late by its delay.
        let gps = events
            .iter()
            .find(|e| DEMO_STREAMS[e.stream].input_id == "gps")
            .expect("gps");
        assert!((gps.publish_t - gps.measured_t - 0.1).abs() < 1e-9);
    }

    #[test]
    fn deterministic_for_a_seed() {
        let a: Vec<SimEvent> = Simulator::new(DEMO_STREAMS, 5, 2.0).collect();
        let b: Vec<SimEvent> = Simulator::new(DEMO_STREAMS, 5, 2.0).collect();
        assert_eq!(a.len(), b.len());
        assert!(a
            .iter()
            .zip(&b)
            .all(|(x, y)| x.data == y.data && x.publish_t == y.publish_t));
    }
}
