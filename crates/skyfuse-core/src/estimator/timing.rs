//! Time alignment: each source's own clock (`stamp_us`) → host time.
//!
//! `arrival_us - stamp_us` is the clock offset plus the transport delay. Its minimum
//! over a sliding window is the offset plus the smallest delay, which is robust to
//! jitter (a late packet only makes the difference larger). The measurement's host time
//! is then `stamp + min_offset - latency`, where `latency` (configured) is the part of
//! the delay the stamps cannot show. Samples without a stamp use `arrival - latency`.
//! A jump of the difference (sensor reboot, clock step) restarts the window.
//!
//! Stamps that are not a clock at the host's rate are not used: the rate of the stamps
//! against arrival is measured over every [`RATE_SPAN_US`], and outside
//! [`RATE_TOLERANCE`] of 1 the source is timed by arrival instead (ArduPilot fills
//! OPTICAL_FLOW's `time_usec` with *milliseconds* since boot, so its stamps advance a
//! thousand times too slowly; GPS_RAW_INT's is 0 without a fix). The windowed minimum
//! would otherwise map such samples seconds into the past.

use super::EstimatorConfig;
use crate::sample::Sample;
use crate::source_map::SourceMap;
use std::collections::VecDeque;

/// Stamps are compared with arrival over this span, µs.
pub const RATE_SPAN_US: i64 = 2_000_000;
/// Stamps advancing at a rate outside 1 ± this (per arrival second) are not a clock.
pub const RATE_TOLERANCE: f64 = 0.2;

/// One source's clock mapping.
#[derive(Debug, Clone, Default)]
pub struct ClockMap {
    /// Start of the current rate measurement: (arrival, stamp).
    rate_anchor: Option<(i64, i64)>,
    /// The stamps' rate against arrival, from the last full span.
    pub stamp_rate: Option<f64>,
    /// (arrival_us, arrival - stamp), with increasing differences (monotone deque for a
    /// windowed minimum).
    window: VecDeque<(i64, i64)>,
    /// Restarts of the mapping (clock jumps).
    pub restarts: u32,
    last_stamp: Option<i64>,
}

impl ClockMap {
    /// Host time of a sample, µs.
    pub fn map(
        &mut self,
        stamp_us: Option<i64>,
        arrival_us: i64,
        latency_us: i64,
        window_us: i64,
        jump_us: i64,
    ) -> i64 {
        let Some(stamp) = stamp_us else {
            return arrival_us - latency_us;
        };
        let diff = arrival_us.saturating_sub(stamp);
        if let Some(&(_, min)) = self.window.front() {
            let backwards = self.last_stamp.is_some_and(|l| stamp < l - jump_us);
            if (diff - min).abs() > jump_us || backwards {
                self.window.clear();
                self.restarts += 1;
            }
        }
        // The rate is measured across window restarts (a stamp clock at the wrong rate
        // restarts the window every second); a stamp going backwards starts anew.
        let stamp_back = self.last_stamp.is_some_and(|l| stamp < l);
        self.last_stamp = Some(stamp);
        match self.rate_anchor {
            _ if stamp_back => self.rate_anchor = Some((arrival_us, stamp)),
            Some((a0, s0)) if arrival_us - a0 >= RATE_SPAN_US => {
                self.stamp_rate = Some((stamp - s0) as f64 / (arrival_us - a0) as f64);
                self.rate_anchor = Some((arrival_us, stamp));
            }
            Some((a0, _)) if arrival_us < a0 => self.rate_anchor = Some((arrival_us, stamp)),
            Some(_) => {}
            None => self.rate_anchor = Some((arrival_us, stamp)),
        }
        // Monotone deque: drop entries that can never be the minimum again.
        while self.window.back().is_some_and(|&(_, d)| d >= diff) {
            self.window.pop_back();
        }
        self.window.push_back((arrival_us, diff));
        while self
            .window
            .front()
            .is_some_and(|&(a, _)| a < arrival_us - window_us)
        {
            self.window.pop_front();
        }
        if !self.stamps_usable() {
            return arrival_us - latency_us;
        }
        let min = self.window.front().map_or(diff, |&(_, d)| d);
        stamp.saturating_add(min) - latency_us
    }

    /// Whether the stamps run at the host's rate (unknown counts as usable).
    pub fn stamps_usable(&self) -> bool {
        self.stamp_rate
            .is_none_or(|r| (r - 1.0).abs() <= RATE_TOLERANCE)
    }

    /// Current offset estimate (host - sensor clock, including the smallest delay), µs.
    pub fn offset_us(&self) -> Option<i64> {
        self.window.front().map(|&(_, d)| d)
    }
}

/// Every source's clock mapping.
#[derive(Debug, Clone, Default)]
pub struct SourceClocks(SourceMap<ClockMap>);

impl SourceClocks {
    /// Host time of `s`, µs: its source's mapping with `cfg`'s latency (per source, else
    /// per kind), offset window and jump threshold.
    pub fn host_time(&mut self, cfg: &EstimatorConfig, s: &Sample) -> i64 {
        let src: &str = &s.source;
        let latency = cfg.latency_us(src, s.data.kind());
        let window = (cfg.clock_window_s * 1e6) as i64;
        let jump = (cfg.clock_jump_s * 1e6) as i64;
        self.0.get_or_insert_with(src, ClockMap::default).map(
            s.stamp_us,
            s.arrival_us,
            latency,
            window,
            jump,
        )
    }

    pub fn iter(&self) -> impl Iterator<Item = (&String, &ClockMap)> {
        self.0.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_is_removed_and_epochs_differ() {
        let mut c = ClockMap::default();
        // Sensor clock = boot time; host = boot + 1e12; delay 5 ms + jitter 0..3 ms.
        let mut out = vec![];
        for i in 0..100i64 {
            let stamp = i * 10_000;
            let jitter = (i * 7919) % 3000;
            let arrival = stamp + 1_000_000_000_000 + 5_000 + jitter;
            out.push(c.map(Some(stamp), arrival, 5_000, 10_000_000, 1_000_000));
        }
        // After a jitter-free sample (jitter 0 at i = 0), every mapping is exact.
        for (i, t) in out.iter().enumerate() {
            assert_eq!(*t, i as i64 * 10_000 + 1_000_000_000_000, "sample {i}");
        }
    }

    #[test]
    fn milliseconds_in_a_microsecond_field_are_timed_by_arrival() {
        // ArduPilot's OPTICAL_FLOW: time_usec holds milliseconds since boot.
        let mut c = ClockMap::default();
        let mut last = 0;
        for i in 0..200i64 {
            let arrival = 1_000_000_000 + i * 20_000;
            last = c.map(Some(38_844 + i * 20), arrival, 5_000, 10_000_000, 1_000_000);
        }
        assert!(!c.stamps_usable());
        let rate = c.stamp_rate.unwrap_or(1.0);
        assert!((rate - 0.001).abs() < 1e-4, "{rate}");
        assert_eq!(last, 1_000_000_000 + 199 * 20_000 - 5_000);
    }

    #[test]
    fn clock_jump_restarts_and_no_stamp_uses_arrival() {
        let mut c = ClockMap::default();
        assert_eq!(c.map(Some(1_000), 11_000, 0, 10_000_000, 1_000_000), 11_000);
        // Sensor rebooted: stamps start again from zero.
        assert_eq!(
            c.map(Some(0), 5_000_000, 0, 10_000_000, 1_000_000),
            5_000_000
        );
        assert_eq!(c.restarts, 1);
        assert_eq!(c.map(None, 7_000, 2_000, 10_000_000, 1_000_000), 5_000);
    }
}
