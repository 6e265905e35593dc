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
