//! Time alignment: each source's own clock (`stamp_us`) → host time.
//!
//! `arrival_us - stamp_us` is the clock offset plus the transport delay. Its minimum
//! over a sliding window is the offset plus the smallest delay, which is robust to
//! jitter (a late packet only makes the difference larger). The measurement's host time
//! is then `stamp + min_offset - latency`, where `latency` (configured) is the part of
//! the delay the stamps cannot show. Samples without a stamp use `arrival - latency`.
//! A jump of the difference (sensor reboot, clock step) restarts the window.

use std::collections::VecDeque;

/// One source's clock mapping.
#[derive(Debug, Clone, Default)]
pub struct ClockMap {
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
        self.last_stamp = Some(stamp);
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
        let min = self.window.front().map_or(diff, |&(_, d)| d);
        stamp.saturating_add(min) - latency_us
    }

    /// Current offset estimate (host - sensor clock, including the smallest delay), µs.
    pub fn offset_us(&self) -> Option<i64> {
        self.window.front().map(|&(_, d)| d)
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
