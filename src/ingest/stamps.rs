//! A sensor's own clock as ingest sees it (pure: stamps and arrival times in, verdicts
//! out). A stamp must move with the arrival clock: never backwards, and never further
//! ahead than the time that passed plus [`AHEAD_SLACK_US`]. One sample that breaks this
//! (a corrupted stamp years in the future, a reordered packet) is rejected and moves
//! nothing, so the genuine samples that follow are still accepted. A *consistent new
//! series* of [`RESTART_CONFIRM`] samples (an autopilot rebooted and its `time_boot_ms`
//! starts again at 1 s, a sensor's clock was stepped) is a clock restart: adopted, so
//! the input carries on without a restart of skyfuse.

use crate::sample::Micros;

/// How far a stamp may run ahead of the arrival clock's progress, µs (a link that
/// buffered samples delivers them in a burst: stamps then advance *less* than arrival,
/// never more; one second covers arrival-time jitter with room to spare).
pub const AHEAD_SLACK_US: Micros = 1_000_000;
/// Samples of a new series, each consistent with the one before, that make a restart.
pub const RESTART_CONFIRM: u32 = 3;

/// What to do with one stamped sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampVerdict {
    Accept,
    /// Behind the newest accepted stamp.
    Backwards {
        previous_us: Micros,
        now_us: Micros,
    },
    /// Further ahead of the newest accepted stamp than the arrival clock moved.
    Ahead {
        previous_us: Micros,
        now_us: Micros,
        elapsed_us: Micros,
    },
    /// A consistent new series replaced the old one: accepted.
    Restart {
        previous_us: Micros,
        now_us: Micros,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Point {
    stamp: Micros,
    arrival: Micros,
}

/// Follows of one input's stamps.
#[derive(Debug, Clone, Default)]
pub struct StampTracker {
    last: Option<Point>,
    /// A different series seen since `last`: its newest point and length.
    candidate: Option<(Point, u32)>,
    pub restarts: u64,
}

/// `next` continues the series whose newest point is `prev`.
fn continues(prev: Point, next: Point) -> bool {
    let elapsed = (next.arrival - prev.arrival).max(0);
    next.stamp >= prev.stamp && next.stamp - prev.stamp <= elapsed.saturating_add(AHEAD_SLACK_US)
}

impl StampTracker {
    /// The newest accepted stamp.
    pub fn last_stamp(&self) -> Option<Micros> {
        self.last.map(|p| p.stamp)
    }

    pub fn check(&mut self, stamp: Micros, arrival: Micros) -> StampVerdict {
        let p = Point { stamp, arrival };
        let Some(last) = self.last else {
            self.last = Some(p);
            return StampVerdict::Accept;
        };
        if continues(last, p) {
            self.last = Some(p);
            self.candidate = None;
            return StampVerdict::Accept;
        }
        let n = match self.candidate {
            Some((c, n)) if continues(c, p) => n + 1,
            _ => 1,
        };
        if n >= RESTART_CONFIRM {
            self.last = Some(p);
            self.candidate = None;
            self.restarts += 1;
            return StampVerdict::Restart {
                previous_us: last.stamp,
                now_us: stamp,
            };
        }
        self.candidate = Some((p, n));
        if stamp < last.stamp {
            StampVerdict::Backwards {
                previous_us: last.stamp,
                now_us: stamp,
            }
        } else {
            StampVerdict::Ahead {
                previous_us: last.stamp,
                now_us: stamp,
                elapsed_us: (arrival - last.arrival).max(0),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 50 Hz series: stamps from `stamp0`, arrivals from `arrival0`.
    fn feed(tr: &mut StampTracker, stamp0: Micros, arrival0: Micros, n: i64) -> Vec<StampVerdict> {
        (0..n)
            .map(|i| tr.check(stamp0 + i * 20_000, arrival0 + i * 20_000))
            .collect()
    }

    #[test]
    fn one_future_stamp_is_rejected_and_moves_nothing() {
        let mut tr = StampTracker::default();
        assert!(feed(&mut tr, 1_000_000, 5_000_000, 10)
            .iter()
            .all(|v| *v == StampVerdict::Accept));
        // Years ahead: rejected.
        let v = tr.check(273_678_336_000_000, 5_200_000);
        assert!(matches!(v, StampVerdict::Ahead { .. }), "{v:?}");
        // The genuine series goes on.
        assert!(feed(&mut tr, 1_220_000, 5_220_000, 10)
            .iter()
            .all(|v| *v == StampVerdict::Accept));
        assert_eq!(tr.restarts, 0);
    }

    #[test]
    fn random_garbage_between_genuine_samples_never_restarts() {
        let mut tr = StampTracker::default();
        let mut x: u64 = 0x2545_f491_4f6c_dd1d;
        for i in 0..10_000i64 {
            assert_eq!(tr.check(i * 20_000, i * 20_000), StampVerdict::Accept);
            // xorshift: a stamp anywhere.
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = tr.check((x >> 1) as i64, i * 20_000 + 1);
            assert_ne!(v, StampVerdict::Accept, "{i}");
        }
        assert_eq!(tr.restarts, 0);
    }

    #[test]
    fn an_autopilot_reboot_is_adopted_after_three_samples() {
        let mut tr = StampTracker::default();
        // Up for 597 s, then time_boot_ms starts again at 1 s.
        feed(&mut tr, 597_000_000, 0, 50);
        let v = feed(&mut tr, 1_000_000, 1_000_000, 5);
        assert!(matches!(v[0], StampVerdict::Backwards { .. }));
        assert!(matches!(v[1], StampVerdict::Backwards { .. }));
        assert_eq!(
            v[2],
            StampVerdict::Restart {
                previous_us: 597_980_000,
                now_us: 1_040_000
            }
        );
        assert_eq!(&v[3..], &[StampVerdict::Accept, StampVerdict::Accept]);
        assert_eq!(tr.restarts, 1);
        assert_eq!(tr.last_stamp(), Some(1_080_000));
    }

    #[test]
    fn a_garbage_first_sample_is_outvoted_by_the_genuine_series() {
        let mut tr = StampTracker::default();
        assert_eq!(tr.check(i64::MAX / 2, 0), StampVerdict::Accept);
        let v = feed(&mut tr, 1_000_000, 20_000, 4);
        assert!(matches!(v[2], StampVerdict::Restart { .. }), "{v:?}");
        assert_eq!(v[3], StampVerdict::Accept);
    }

    #[test]
    fn a_burst_after_a_stall_is_accepted() {
        let mut tr = StampTracker::default();
        feed(&mut tr, 0, 0, 5);
        // The link stalls 2 s; the buffered samples arrive together.
        for i in 5..105 {
            assert_eq!(tr.check(i * 20_000, 2_100_000 + i), StampVerdict::Accept);
        }
    }
}
