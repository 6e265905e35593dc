//! The output's rate limit: the poses (and debug series) the service sends, on a
//! fixed grid of sample time. Offline runs record through the same limit, so a replay
//! scores the very poses the service would have sent.

/// The service's default `[output] pose_rate_hz`, and the rate offline runs record at
/// unless told the recorded service's.
pub const DEFAULT_POSE_RATE_HZ: f64 = 50.0;

/// At most one item per period of sample time, on a fixed grid: however the samples
/// jitter, the rate never exceeds the limit for long, and does not fall short of it
/// either (as "a period since the last one" would, with samples just short of the
/// period). An item up to a quarter period early takes its slot, so a source at the
/// limit's own rate loses nothing to jitter. The default lets every item through.
#[derive(Debug, Clone, Default)]
pub struct RateLimit {
    period_us: i64,
    /// The last item's time and the next slot on the grid.
    slot: Option<(i64, i64)>,
}

impl RateLimit {
    /// `rate_hz` 0 lets every item through; otherwise it must be positive and finite
    /// (the config checks it).
    pub fn hz(rate_hz: f64) -> Self {
        Self {
            period_us: if rate_hz > 0.0 {
                ((1e6 / rate_hz).round() as i64).max(1)
            } else {
                0
            },
            slot: None,
        }
    }

    /// Whether an item at sample time `t` goes out (and is counted as gone).
    pub fn due(&mut self, t: i64) -> bool {
        let p = self.period_us;
        if p == 0 {
            return true;
        }
        let next = match self.slot {
            Some((last, next)) if t >= last && t < next - p / 4 => return false,
            // On the grid.
            Some((last, next)) if t >= last && t - next < p => next + p,
            // The first, a gap of a period or more, or time went back: a new grid.
            _ => t + p,
        };
        self.slot = Some((t, next));
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_limit_keeps_the_rate_however_samples_jitter() {
        // Poses every 5 ms ± 0.3 ms, limited to 50 Hz: 10 s gives 500, not the ~400
        // of "a whole period since the last one" (which waits for the 25 ms sample
        // whenever the 20 ms one came a little early).
        let mut limit = RateLimit::hz(50.0);
        let mut sent = Vec::new();
        for i in 0..2000_i64 {
            let jitter = [0, 300, -300, 150][(i % 4) as usize];
            let t = 1_000_000 + i * 5_000 + jitter;
            if limit.due(t) {
                sent.push(t);
            }
        }
        assert!((499..=501).contains(&sent.len()), "{} sent", sent.len());
        // Never two much closer than a period.
        let closest = sent.windows(2).map(|w| w[1] - w[0]).min().unwrap_or(0);
        assert!(closest >= 14_000, "{closest} µs apart");
        // Two interleaved 200 Hz sources (a pose with each IMU and each T265 sample).
        let mut limit = RateLimit::hz(50.0);
        let kept = (0..4000_i64)
            .filter(|i| limit.due(1_000_000 + (i / 2) * 5_000 + (i % 2) * 1_700))
            .count();
        assert!((499..=501).contains(&kept), "{kept} kept");
        // A source at the limit's own rate, jittered, loses nothing.
        let mut limit = RateLimit::hz(50.0);
        let kept = (0..500_i64)
            .filter(|i| limit.due(1_000_000 + i * 20_000 + [0, 400, -400, 900][(i % 4) as usize]))
            .count();
        assert_eq!(kept, 500);
    }

    #[test]
    fn the_rate_limit_starts_again_after_a_gap_or_a_clock_going_back() {
        let mut limit = RateLimit::hz(10.0);
        assert!(limit.due(1_000_000));
        assert!(!limit.due(1_050_000));
        assert!(limit.due(1_100_000));
        // A gap: the next sample goes at once.
        assert!(limit.due(5_000_000));
        assert!(!limit.due(5_010_000));
        // Time went back (a clock restart): at once, not a period after the old time.
        assert!(limit.due(2_000_000));
        assert!(!limit.due(2_050_000));
    }

    #[test]
    fn a_rate_limit_of_zero_lets_every_item_through() {
        let mut limit = RateLimit::hz(0.0);
        let times = [1_000_000, 1_000_001, 1_000_001, 1_005_000, 900_000];
        assert!(times.iter().all(|&t| limit.due(t)));
    }
}
