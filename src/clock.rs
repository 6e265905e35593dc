//! The host's clock and rates measured on it: the service's only clock reads (the core
//! gets time passed in). Used by ingest, the outputs, the pipeline and the ROS graph.

use crate::sample::Micros;

/// Host clock, µs since the Unix epoch. The service's one clock.
pub fn now_us() -> Micros {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_micros() as Micros)
        .unwrap_or(0)
}

/// Messages per second over one-second windows.
#[derive(Debug, Default, Clone)]
pub struct RateMeter {
    window_start_us: Option<Micros>,
    count: u64,
    rate_hz: f64,
}

const RATE_WINDOW_US: Micros = 1_000_000;

impl RateMeter {
    /// The rate of the last full window (it holds its value until the next one).
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// The rate as of `now`: 0 once no message came for two windows, so a stream that
    /// stopped does not keep showing its last rate.
    pub fn rate_hz_at(&self, now: Micros) -> f64 {
        match self.window_start_us {
            Some(start) if now - start <= 2 * RATE_WINDOW_US => self.rate_hz,
            _ => 0.0,
        }
    }

    pub fn tick(&mut self, now: Micros) {
        let start = *self.window_start_us.get_or_insert(now);
        self.count += 1;
        let elapsed = now - start;
        if elapsed >= RATE_WINDOW_US {
            self.rate_hz = self.count as f64 * 1e6 / elapsed as f64;
            self.window_start_us = Some(now);
            self.count = 0;
        }
    }
}

/// The clock the estimator runs on, as a map from the host's: `fusion = f0 + rate·(host −
/// h0)`, µs (anchored, so the products stay small and exact). The host's own clock
/// (rate 1) unless the vehicle's runs at another rate (a simulator at `--speedup 5`):
/// then the vehicle's, so the filter integrates over the time its sensors lived.
/// Everything outside the estimator stays on the host clock; the pipeline maps at its
/// edges.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TimeBase {
    /// Fusion-clock µs per host µs.
    pub rate: f64,
    h0: Micros,
    f0: Micros,
}

impl TimeBase {
    pub const HOST: Self = Self {
        rate: 1.0,
        h0: 0,
        f0: 0,
    };

    /// The clock whose reading is `f0` at host time `h0` and runs `rate` times as fast.
    pub fn anchored(h0: Micros, f0: Micros, rate: f64) -> Self {
        Self { rate, h0, f0 }
    }

    pub fn is_host(&self) -> bool {
        *self == Self::HOST
    }

    pub fn to_fusion(&self, host: Micros) -> Micros {
        if self.is_host() {
            return host;
        }
        self.f0
            .saturating_add((host.saturating_sub(self.h0) as f64 * self.rate).round() as Micros)
    }

    pub fn to_host(&self, fusion: Micros) -> Micros {
        if self.is_host() {
            return fusion;
        }
        self.h0
            .saturating_add((fusion.saturating_sub(self.f0) as f64 / self.rate).round() as Micros)
    }

    /// A host duration, µs, in fusion-clock µs.
    pub fn scale(&self, host_us: Micros) -> Micros {
        (host_us as f64 * self.rate).round() as Micros
    }
}

/// The time base shared between the pipeline (which sets it) and the outputs (which
/// schedule on it and stamp with it).
#[derive(Debug)]
pub struct SharedTimeBase {
    base: std::sync::Mutex<(TimeBase, Option<String>)>,
    /// The rate's bits, for readers on every sample (ingest's flood limit).
    rate_bits: std::sync::atomic::AtomicU64,
}

impl Default for SharedTimeBase {
    fn default() -> Self {
        Self {
            base: std::sync::Mutex::new((TimeBase::HOST, None)),
            rate_bits: std::sync::atomic::AtomicU64::new(1f64.to_bits()),
        }
    }
}

impl SharedTimeBase {
    /// The estimator's clock against the host's (1 on the host's).
    pub fn rate(&self) -> f64 {
        f64::from_bits(self.rate_bits.load(std::sync::atomic::Ordering::Relaxed))
    }

    pub fn get(&self) -> TimeBase {
        crate::sync::lock(&self.base).0
    }

    /// The input whose stamps the fusion clock follows (`None`: the host's clock).
    pub fn reference(&self) -> Option<String> {
        crate::sync::lock(&self.base).1.clone()
    }

    pub fn set(&self, base: TimeBase, reference: Option<String>) {
        *crate::sync::lock(&self.base) = (base, reference);
        self.rate_bits
            .store(base.rate.to_bits(), std::sync::atomic::Ordering::Relaxed);
    }
}

/// Stamps are compared with arrival over spans this long (host), µs.
pub const VEHICLE_RATE_SPAN_US: Micros = 2_000_000;
/// Two spans in a row within this fraction of each other make a steady rate.
pub const VEHICLE_RATE_STEADY: f64 = 0.02;
/// A steady rate within this of 1 is the host's own (a real vehicle's crystal is within
/// 1e-4; the estimator's per-source mapping absorbs that).
pub const VEHICLE_RATE_HOST_BAND: f64 = 0.2;

/// Steady rates outside these bounds are a unit slip in the stamps (ArduPilot's
/// OPTICAL_FLOW puts milliseconds in `time_usec`: 0.001), not a clock to fuse on.
pub const VEHICLE_RATE_MIN: f64 = 0.05;
pub const VEHICLE_RATE_MAX: f64 = 50.0;

/// What a [`VehicleClockWatch`] found at the end of a span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RateChange {
    /// The fusion clock must change: the estimator starts again on `0`.
    Rebase(TimeBase),
    /// Same clock, its rate measured again (continuous at the span's end).
    Refine(TimeBase),
}

/// Watches one input's stamps (the vehicle's clock) against their arrival for a clock
/// running at another rate than the host's, as a simulator faster than real time does.
/// Pure: arrival times are passed in.
#[derive(Debug, Clone, Default)]
pub struct VehicleClockWatch {
    /// Start of the current span: (arrival, stamp).
    span: Option<(Micros, Micros)>,
    last_stamp: Option<Micros>,
    /// The previous span's rate.
    previous_rate: Option<f64>,
}

impl VehicleClockWatch {
    /// One stamped sample of the reference input under the current base `now`.
    pub fn observe(
        &mut self,
        arrival: Micros,
        stamp: Micros,
        now: &TimeBase,
    ) -> Option<RateChange> {
        if self.last_stamp.is_some_and(|l| stamp < l) {
            // The vehicle rebooted: measure again.
            self.span = None;
            self.previous_rate = None;
        }
        self.last_stamp = Some(stamp);
        let Some((a0, s0)) = self.span else {
            self.span = Some((arrival, stamp));
            return None;
        };
        if arrival - a0 < VEHICLE_RATE_SPAN_US {
            return None;
        }
        let rate = (stamp - s0) as f64 / (arrival - a0) as f64;
        self.span = Some((arrival, stamp));
        let steady = self
            .previous_rate
            .replace(rate)
            .is_some_and(|p| p > 0.0 && ((rate - p) / p).abs() <= VEHICLE_RATE_STEADY);
        if !steady || !(VEHICLE_RATE_MIN..=VEHICLE_RATE_MAX).contains(&rate) {
            return None;
        }
        let hostlike = (rate - 1.0).abs() <= VEHICLE_RATE_HOST_BAND;
        match (now.is_host(), hostlike) {
            (true, true) => None,
            (false, true) => Some(RateChange::Rebase(TimeBase::HOST)),
            _ if ((rate - now.rate) / now.rate).abs() > VEHICLE_RATE_STEADY => {
                // The zero-delay assumption for this sample: later ones map at most its
                // delay early, which the estimator's per-source clock mapping absorbs.
                Some(RateChange::Rebase(TimeBase::anchored(arrival, stamp, rate)))
            }
            _ => Some(RateChange::Refine(TimeBase::anchored(
                arrival,
                now.to_fusion(arrival),
                rate,
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `secs` host seconds of a 100 Hz (vehicle time) IMU from a vehicle clock running
    /// `rate` times the host's, from host time `h` and vehicle time `v`; the changes.
    fn run(
        w: &mut VehicleClockWatch,
        base: &mut TimeBase,
        rate: f64,
        h: Micros,
        v: Micros,
        secs: f64,
    ) -> Vec<RateChange> {
        let n = (secs * 100.0 * rate) as i64;
        let mut out = vec![];
        for i in 0..n {
            let stamp = v + i * 10_000;
            // Arrival jitter 0–700 µs.
            let arrival = h + (i as f64 * 10_000.0 / rate) as i64 + (i * 7919) % 700;
            if let Some(c) = w.observe(arrival, stamp, base) {
                *base = match c {
                    RateChange::Rebase(b) | RateChange::Refine(b) => b,
                };
                out.push(c);
            }
        }
        out
    }

    #[test]
    fn a_host_rate_clock_never_moves_the_base() {
        let (mut w, mut b) = (VehicleClockWatch::default(), TimeBase::HOST);
        assert!(run(&mut w, &mut b, 1.0, 1_700_000_000_000_000, 5_000_000, 60.0).is_empty());
        assert!(b.is_host());
        // A real crystal's 100 ppm is not a simulator: the per-source mapping deals
        // with it.
        let (mut w, mut b) = (VehicleClockWatch::default(), TimeBase::HOST);
        assert!(run(&mut w, &mut b, 1.0001, 1_700_000_000_000_000, 0, 60.0).is_empty());
        // Nor are milliseconds in a µs field (ArduPilot's OPTICAL_FLOW, rate 0.001).
        let (mut w, b) = (VehicleClockWatch::default(), TimeBase::HOST);
        for i in 0..3_000_i64 {
            assert_eq!(w.observe(1_000_000 + i * 10_000, 40_000 + i * 10, &b), None);
        }
        assert!(b.is_host());
    }

    #[test]
    fn a_clock_five_times_the_hosts_becomes_the_base_and_maps_both_ways() {
        let (mut w, mut b) = (VehicleClockWatch::default(), TimeBase::HOST);
        let h = 1_700_000_000_000_000;
        let changes = run(&mut w, &mut b, 5.0, h, 2_000_000, 10.0);
        assert!(matches!(changes[0], RateChange::Rebase(_)), "{changes:?}");
        assert!((b.rate - 5.0).abs() < 0.005, "{b:?}");
        // After the first span's rebase, only refinements.
        assert!(changes[1..]
            .iter()
            .all(|c| matches!(c, RateChange::Refine(_))));
        // A host instant 10 s in maps to the vehicle's 50 s in, within a few ms.
        let v = b.to_fusion(h + 10_000_000);
        assert!((v - 52_000_000).abs() < 5_000, "{v}");
        assert!((b.to_host(v) - (h + 10_000_000)).abs() <= 1);
        assert!((b.scale(1_000) - 5_000).abs() <= 5, "{}", b.scale(1_000));
    }

    #[test]
    fn back_to_real_time_and_a_reboot_are_followed() {
        let (mut w, mut b) = (VehicleClockWatch::default(), TimeBase::HOST);
        let h = 1_000_000_000;
        run(&mut w, &mut b, 5.0, h, 0, 10.0);
        assert!(!b.is_host());
        // The simulator's speed-up set back to 1 (stamps go on from 50 s).
        let c = run(&mut w, &mut b, 1.0, h + 10_000_000, 50_000_000, 10.0);
        assert!(c.contains(&RateChange::Rebase(TimeBase::HOST)), "{c:?}");
        assert!(b.is_host());
        // Rebooted at 3×: stamps start again near 0.
        let c = run(&mut w, &mut b, 3.0, h + 20_000_000, 1_000_000, 10.0);
        assert!(matches!(c[0], RateChange::Rebase(_)), "{c:?}");
        assert!((b.rate - 3.0).abs() < 0.01, "{b:?}");
    }
}
